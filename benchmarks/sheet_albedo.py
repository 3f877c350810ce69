"""Contact sheet of the default backend on real photos (issue 14): per photo, the photo with its
skin mask (occluded pixels tinted magenta), the albedo in UV, and the asset relit from the front
(``relit_preview``'s middle panel), one row per photo.

Photos: the bundled astronaut and every real face photo a pip dependency ships (matplotlib's
``grace_hopper.jpg``).

    python benchmarks/sheet_albedo.py                       # writes docs/albedo_real_photos.jpg
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import cv2
import matplotlib
import numpy as np

import facegeo
from facegeo.assets import asset_path
from facegeo.photo import load_photo
from facegeo.pipeline import reconstruct_with_fit, relit_preview
from facegeo.skin_mask import skin_mask

ROOT = Path(__file__).resolve().parents[1]
PHOTOS = [asset_path("photos/astronaut.png"), Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"]


def row(path: Path, model, size: int, height: int) -> tuple[np.ndarray, str]:
    photo = load_photo(path)
    t = time.perf_counter()
    skin = skin_mask(photo.image, source=str(path))
    asset, fit = reconstruct_with_fit(photo, model, size=size, skin=skin)
    seconds = time.perf_counter() - t
    preview = relit_preview(photo.image, asset, fit, model, height=height)
    width = preview.shape[1] // 4
    photo_panel, front = preview[:, :width], preview[:, 2 * width:3 * width]
    # the same crop of the photo with the mask: occluded pixels tinted magenta
    tinted = photo.image.astype(np.float32) / 255
    occ = skin.occlusion[..., None]
    tinted = (tinted * (1 - 0.6 * occ) + 0.6 * occ * np.array([1.0, 0.0, 1.0])) * 255
    crop = _same_crop(photo.image, photo_panel.shape, tinted.astype(np.uint8), fit, model)
    albedo = cv2.resize((np.clip(asset.maps["albedo"], 0, 1) * 255).astype(np.uint8), (height, height), interpolation=cv2.INTER_AREA)
    report = asset.metadata["texture_report"]
    note = (f"{path.name}: {seconds:.1f} s, occluded {100 * skin.occlusion.mean():.0f} % of the photo, "
            f"seen {100 * report['inpaint']['seen']:.0f} % of the layout, highlights "
            f"{100 * report['analyse']['highlight_fraction_of_seen_skin']:.1f} % of the seen skin")
    return np.concatenate([photo_panel, crop, albedo, front], axis=1), note


def _same_crop(image: np.ndarray, shape: tuple[int, ...], tinted: np.ndarray, fit, model) -> np.ndarray:
    """``tinted`` cropped and resized as ``relit_preview`` crops the photo (mesh bounds + 10 %)."""
    from facegeo.uv import render

    view = render(fit.vertices, model, fit.camera)
    ys, xs = np.nonzero(view.mask)
    pad = int(0.1 * max(np.ptp(ys), np.ptp(xs)))
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad, image.shape[0])
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad, image.shape[1])
    return cv2.resize(tinted[y0:y1, x0:x1], (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024, help="map size S")
    ap.add_argument("--height", type=int, default=300, help="row height in pixels")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "albedo_real_photos.jpg")
    args = ap.parse_args(argv)
    model = facegeo.load_model()
    rows, notes = [], []
    for path in PHOTOS:
        r, note = row(path, model, args.size, args.height)
        rows.append(r)
        notes.append(note)
        print(note)
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows], axis=0)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
