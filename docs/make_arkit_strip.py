"""A strip of the exported face at a few ARKit poses, rendered from the exported file.

Usage (from the repository root, in the project's virtual environment)::

    python docs/make_arkit_strip.py [ASSET_DIR] [-o docs/arkit_poses.jpg]

ASSET_DIR is a ``facegeo reconstruct`` output folder (default: the bundled photo is reconstructed
into a temporary folder first, about half a minute). The asset is exported to ``face.usdz`` with
its ARKit blend shapes (``facegeo export``), and every pose is UsdSkel's own evaluation of that
file (:func:`facegeo.export.usd.skel_points`, usd-core's ``UsdSkel.BlendShapeQuery``) at the pose's
weights: the fitted expression (the file's own weights), neutral (all 0), then ``jawOpen``,
``eyeBlinkLeft``, ``mouthSmileLeft`` and ``browInnerUp`` at 1. Each column is the front view of
the posed meshes with the asset's maps, relit (top) and as clay (bottom), by the renderer of
``preview.png`` (:func:`facegeo.texturing.preview.relit_preview`); the eyes and mouth interior
are the file's too.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np

#: The poses: a title and the ARKit weights (None: the file's own, fitted weights).
POSES = (("fitted", None), ("neutral", {}), ("jawOpen", {"jawOpen": 1.0}), ("eyeBlinkLeft", {"eyeBlinkLeft": 1.0}),
         ("mouthSmileLeft", {"mouthSmileLeft": 1.0}), ("browInnerUp", {"browInnerUp": 1.0}))


def facegeo_command(*args: str) -> None:
    command = ["facegeo", *args] if shutil.which("facegeo") else [sys.executable, "-m", "facegeo.cli", *args]
    subprocess.run(command, check=True)


def posed_asset(asset, points: dict[str, np.ndarray]):
    """The asset with the file's evaluated points (the skin at /face/mesh, parts under /face/parts)."""
    from facegeo.asset import Asset

    def moved(surface, path):
        return Asset(points[path].astype(np.float32), surface.triangles, surface.uv, surface.uv_triangles, maps=surface.maps,
                     constants=dict(surface.constants), name=surface.name, face_triangles=surface.face_triangles)

    out = moved(asset, "/face/mesh")
    out.parts = [moved(p, f"/face/parts/{p.name}") for p in asset.parts]
    return out


def main(argv: list[str] | None = None) -> int:
    from facegeo.export.asset_io import load_asset
    from facegeo.export.usd import skel_points
    from facegeo.texturing.preview import relit_preview

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("asset_dir", nargs="?", type=Path, default=None, help="a facegeo reconstruct output folder")
    parser.add_argument("-o", "--output", type=Path, default=Path("docs/arkit_poses.jpg"))
    parser.add_argument("--panel", type=int, default=224, help="panel size in pixels")
    parser.add_argument("--quality", type=int, default=85, help="JPEG quality")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="facegeo-arkit-") as tmp:
        folder = args.asset_dir
        if folder is None:
            from facegeo.assets import asset_path

            folder = Path(tmp) / "astronaut"
            facegeo_command("reconstruct", str(asset_path("photos/astronaut.png")), "-o", str(folder), "--format", "glb", "--no-preview")
        usdz = Path(tmp) / "face.usdz"
        facegeo_command("export", str(folder), "-o", str(usdz), "--maps", "albedo,normal,roughness,specular")
        asset = load_asset(folder)
        fit = json.loads((folder / "fit.json").read_text())
        photo = np.zeros((8, 8, 3), np.uint8)  # the preview's photo panel (framed by the landmarks) is cut away below
        no_photo = SimpleNamespace(landmarks=np.array([[0.0, 0.0], [8.0, 8.0]] * 44))
        columns = []
        for title, weights in POSES:
            points = skel_points(usdz, weights=weights)
            sheet = relit_preview(photo, posed_asset(asset, points), no_photo, panel=args.panel)
            front = sheet[:, 2 * args.panel:3 * args.panel]  # photo panel (2 × panel wide), then the front view
            front = np.ascontiguousarray(front)
            cv2.putText(front, title, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (235, 235, 235), 1, cv2.LINE_AA)
            columns.append(front)
        strip = np.concatenate(columns, axis=1)
        args.output.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(args.output), strip[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, args.quality])
        print(f"wrote {args.output} ({strip.shape[1]}×{strip.shape[0]}) from {usdz.name} of {folder} "
              f"(landmark RMS {fit.get('landmark_rms_px', float('nan')):.2f} px)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
