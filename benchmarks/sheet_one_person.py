"""Contact sheet of ``facegeo reconstruct --one-person`` against one photo alone: the command's own
preview.png (the reference photo beside the asset from the front, three-quarter and profile,
textured and as clay) for renders of two real head scans (yaw 0°, ±20°, ±40°; ``scan_renders.py``)
and two real photos of one person (``sample_photos.white_house_photos``: obama.jpg, obama2.jpg; kept out of the
fusion's tuning).

    python benchmarks/sheet_one_person.py [--out docs/one_person_fusion.jpg]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sample_photos import white_house_photos  # noqa: E402
from scan_renders import load_view, render_views  # noqa: E402

import facegeo  # noqa: E402

YAWS = ("yaw+00", "yaw+20", "yaw-20", "yaw+40", "yaw-40")


def render_files(scan: str) -> list[Path]:
    """The five yaw renders of ``scan`` (rendered first where missing), as files."""
    try:
        view = load_view(scan, YAWS[0])
    except facegeo.errors.InputError:
        render_views(scan)
        view = load_view(scan, YAWS[0])
    return [view.image_path.with_name(f"{name}.png") for name in YAWS]


def preview(photos: list[Path], out: Path) -> np.ndarray:
    """preview.png of ``facegeo reconstruct`` (one photo) or ``--one-person`` (several)."""
    args = [sys.executable, "-m", "facegeo.cli", "reconstruct", *(["--one-person"] if len(photos) > 1 else []), *map(str, photos),
            "-o", str(out)]
    subprocess.run(args, check=True, capture_output=True, text=True)
    return cv2.imread(str(out / "preview.png"))


def labelled(image: np.ndarray, label: str, width: int) -> np.ndarray:
    image = cv2.resize(image, (width, round(image.shape[0] * width / image.shape[1])), interpolation=cv2.INTER_AREA)
    bar = np.full((30, width, 3), 255, np.uint8)
    cv2.putText(bar, label, (8, 21), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([bar, image])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "one_person_fusion.jpg")
    ap.add_argument("--width", type=int, default=900)
    args = ap.parse_args()
    samples = {p.name: p for p in white_house_photos()}
    cases = [(f"{name}: yaw 0 alone", files[:1]) for name, files in (("James (3dMD scan)", render_files("james")),
                                                                    ("Lee Perry-Smith (IR scan)", render_files("lee_perry_smith")))]
    cases = [cases[0], ("James: yaw 0, +-20, +-40 fused", render_files("james")), cases[1],
             ("Lee Perry-Smith: yaw 0, +-20, +-40 fused", render_files("lee_perry_smith")),
             ("obama.jpg alone (held out)", [samples["obama.jpg"]]),
             ("obama.jpg + obama2.jpg fused (held out)", [samples["obama.jpg"], samples["obama2.jpg"]])]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, photos) in enumerate(cases):
            rows.append(labelled(preview(photos, Path(tmp) / f"out{k}"), label, args.width))
            print(label, file=sys.stderr)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.vstack(rows), [cv2.IMWRITE_JPEG_QUALITY, 82])
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
