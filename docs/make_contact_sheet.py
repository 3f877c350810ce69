"""Contact sheet of reconstructions: per photo, ``facegeo reconstruct``'s ``preview.png`` (the photo,
then the asset from the front, three-quarter and profile, textured above and clay below, eyes and
mouth interior included), one row per photo, as a small JPEG.

Usage (from the repository root, in the project's virtual environment)::

    python docs/make_contact_sheet.py [PHOTO ...] [-o docs/contact_sheet_parts.jpg]

Without photos: the bundled ``assets/photos/astronaut.png`` and matplotlib's
``sample_data/grace_hopper.jpg``. Each photo is reconstructed with ``facegeo reconstruct PHOTO -o
WORK/<stem> --size 512 --format glb`` (the command a user runs; WORK is a temporary folder unless
``--work`` is given); about a minute per photo on a loaded 2-core machine.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np


def default_photos() -> list[Path]:
    """The bundled photo and matplotlib's Grace Hopper portrait."""
    import matplotlib

    from facegeo.assets import asset_path

    return [asset_path("photos/astronaut.png"), Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"]


def preview_of(photo: Path, work: Path, size: int) -> np.ndarray:
    """Run ``facegeo reconstruct`` on ``photo`` and return its preview.png (RGB uint8)."""
    out = work / photo.stem
    command = ["facegeo", "reconstruct", str(photo), "-o", str(out), "--size", str(size), "--format", "glb"]
    if shutil.which("facegeo") is None:
        command = [sys.executable, "-m", "facegeo.cli", *command[1:]]
    subprocess.run(command, check=True)
    image = cv2.imread(str(out / "preview.png"), cv2.IMREAD_COLOR)
    if image is None:
        raise SystemExit(f"{out / 'preview.png'}: not written")
    return image[:, :, ::-1]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("photos", nargs="*", type=Path, help="photos (default: the bundled one and Grace Hopper)")
    parser.add_argument("-o", "--output", type=Path, default=Path("docs/contact_sheet_parts.jpg"))
    parser.add_argument("--work", type=Path, default=None, help="keep the reconstructions here")
    parser.add_argument("--size", type=int, default=512, help="UV map size for reconstruct (default 512)")
    parser.add_argument("--scale", type=float, default=0.75, help="scale of the previews in the sheet")
    parser.add_argument("--quality", type=int, default=85, help="JPEG quality")
    args = parser.parse_args(argv)
    photos = args.photos or default_photos()
    with tempfile.TemporaryDirectory(prefix="facegeo-sheet-") as tmp:
        work = args.work or Path(tmp)
        rows = []
        for photo in photos:
            row = preview_of(photo, work, args.size)
            row = cv2.resize(row, None, fx=args.scale, fy=args.scale, interpolation=cv2.INTER_AREA)
            cv2.putText(row, photo.name, (6, row.shape[0] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
            rows.append(row)
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows], axis=0)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.output), sheet[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, args.quality])
    print(f"wrote {args.output} ({sheet.shape[1]}x{sheet.shape[0]}, {args.output.stat().st_size} bytes)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
