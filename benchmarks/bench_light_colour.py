"""Issue 49: the light's colour as the default backend estimates it, on a head whose eyes are white.

    python benchmarks/bench_light_colour.py [--samples 16] [--threads 2] [--json OUT.json] [--write OUT.md]

The albedo benchmark's scans cannot test the white reference (the sclera, the teeth) that the
light's estimate leans on: James's scanned scleras are yellow and Lee Perry-Smith has skin for
eyes (RESULTS.md). This head has real ones: ``bench_track_truth.py``'s animated ICT face (the
bundled photo reconstructed with its parts: white eyeballs with an iris, teeth), at three frames
of its take (0: frontal, at rest; 400 and 470: the head turned 35° to each side), rendered by
``blender_render_take.py`` under every light of ``blender_render_scan.LIGHTS`` (Cycles, CPU;
cached in ``~/.cache/facegeo/light_colour``, one folder per light and frame, about 5 s each),
and under a warm light: the ``soft`` render's linear RGB × :data:`WARM` (a ~3200 K light, exact
for one light colour), clipped and 8-bit sRGB again.

Per render:

* **rendered**: the light's chroma (log R/G, log B/G) as the skin shows it: the median over the
  face's skin pixels (``facegeo.skin_mask`` of the ``soft`` render, neither clipped nor black in
  either) of the render's chroma less the ``soft`` render's (the same surface under the white
  environment: their ratio is the light's colour wherever the surface is diffuse; a sun and a
  sky of two colours give the mix each pixel sees);
* **estimated**: what ``facegeo reconstruct``'s default backend estimates (the texture report's
  ``illuminant``: the mean light's chroma after its shrinkage towards neutral, whether a white
  reference was used and its chroma), from the render alone with the camera's focal given;
* the error's length and its part along the Planckian direction (> 0: estimated warmer).

Also, from the ``soft`` renders: the white reference's chroma under a white light (what the eyes'
albedo is as ``facegeo.skin_mask.white_reference`` reads it), against
``facegeo.texturing.illuminant.SCLERA_CHROMA``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_track_truth as take_truth  # noqa: E402

from facegeo import load_model  # noqa: E402
from facegeo.camera import Camera  # noqa: E402
from facegeo.colour import linear_to_srgb, srgb8_to_linear  # noqa: E402
from facegeo.fitting import fit  # noqa: E402
from facegeo.pipeline import reconstruct_with_fit  # noqa: E402
from facegeo.skin_mask import skin_mask  # noqa: E402
from facegeo.texturing.illuminant import PLANCKIAN, SCLERA_CHROMA, chroma  # noqa: E402

BENCH = Path(__file__).resolve().parent
CACHE = Path.home() / ".cache" / "facegeo" / "light_colour"
#: The take's frames rendered: frontal at rest, and turned 35° to the subject's right and left.
FRAMES = {"0°": 0, "+35°": 400, "−35°": 470}
#: blender_render_scan.LIGHTS' recipes, ``soft`` first (the white reference render).
LIGHTS = ("soft", "key-fill", "window", "hard-side", "sun-sky", "ring")
#: von Kries gains (linear sRGB, G = 1) of a ~3200 K light (bench_albedo_scans.WARM).
WARM = np.array([1.0, 0.76, 0.52], np.float32)


def render(glb: Path, camera_mm: list[float], light: str, frame: int, samples: int, threads: int, blender: str) -> np.ndarray:
    """(H, W, 3) uint8 sRGB: the take's ``frame`` under ``light`` (cached)."""
    settings = {"fps": take_truth.FPS, "frames": [frame, frame], "width": take_truth.WIDTH, "height": take_truth.HEIGHT,
                "focal_px": take_truth.FOCAL_PX, "camera_mm": camera_mm, "light": light, "samples": samples}
    folder = CACHE / f"{light}-{frame}-{take_truth._digest(take_truth._file_digest(glb), settings)}"
    target = folder / "frames" / f"frame_{frame:05d}.png"
    if not target.exists():
        folder.mkdir(parents=True, exist_ok=True)
        job = {**settings, "glb": str(glb), "out": str(folder / "frames"), "probe": str(folder / "probe.json")}
        (folder / "job.json").write_text(json.dumps(job, indent=1))
        with open(folder / "render.log", "w") as log:
            subprocess.run([blender, "-b", "--factory-startup", "-noaudio", "-t", str(threads), "--python",
                            str(BENCH / "blender_render_take.py"), "--", str(folder / "job.json")],
                           stdout=log, stderr=subprocess.STDOUT, check=True)
    import cv2

    return np.ascontiguousarray(cv2.imread(str(target), cv2.IMREAD_COLOR)[:, :, ::-1])


def warm(soft: np.ndarray) -> np.ndarray:
    """The ``soft`` render (uint8 sRGB) under :data:`WARM`'s light: linear RGB × the gains, clipped."""
    return np.round(linear_to_srgb(np.clip(srgb8_to_linear(soft) * WARM, 0.0, 1.0)) * 255.0).astype(np.uint8)


def rendered_light(image: np.ndarray, soft: np.ndarray, skin: np.ndarray) -> list[float]:
    """The light's chroma on the ``skin`` (H, W) bool pixels: median of chroma(image) − chroma(soft)."""
    a, b = srgb8_to_linear(image)[skin], srgb8_to_linear(soft)[skin]
    ok = np.all((a > 0.01) & (a < 0.98) & (b > 0.01) & (b < 0.98), axis=1)
    return np.median(chroma(a[ok]) - chroma(b[ok]), axis=0).tolist()


def estimate(image: np.ndarray, model) -> dict:
    """The default backend's light estimate from ``image`` alone (the camera's focal given)."""
    camera = Camera(take_truth.FOCAL_PX, take_truth.WIDTH / 2.0, take_truth.HEIGHT / 2.0, take_truth.WIDTH, take_truth.HEIGHT)
    fitted = fit(image, model=model, camera=camera)
    mask = skin_mask(image, fitted.landmarks)
    asset, _ = reconstruct_with_fit(image, model, camera=camera, skin=mask, parts=False, fitter=lambda *args, **kwargs: fitted)
    return dict(asset.metadata["texture_report"]["illuminant"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=16, help="Cycles samples a pixel (default 16)")
    parser.add_argument("--threads", type=int, default=2, help="Blender's render threads (default 2)")
    parser.add_argument("--blender", default=shutil.which("blender") or "blender", help="Blender 3.4's executable")
    parser.add_argument("--json", type=Path, help="write every number here")
    parser.add_argument("--write", type=Path, help="write the Markdown tables here")
    args = parser.parse_args()

    asset = take_truth.make_asset(take_truth.PHOTO, take_truth.CACHE)
    _, csv = take_truth.make_truth(take_truth.CACHE)
    glb = take_truth.make_animated(asset, csv, take_truth.CACHE)
    camera_mm = take_truth.camera_mm(asset)
    model = load_model()
    rows, whites = [], []
    for view, frame in FRAMES.items():
        soft = render(glb, camera_mm, "soft", frame, args.samples, args.threads, args.blender)
        mask = skin_mask(soft, fit(soft, model=model).landmarks)
        skin = (mask.occlusion < 0.5) & (mask.skin_probability > 0.5)
        if mask.white_reference is not None:
            whites.append({"view": view, "white_chroma": chroma(np.asarray(mask.white_reference)).tolist(), "pixels": mask.white_pixels})
        images = {light: render(glb, camera_mm, light, frame, args.samples, args.threads, args.blender) for light in LIGHTS[1:]}
        images["warm"] = warm(soft)
        for light, image in images.items():
            found = estimate(image, model)
            truth = rendered_light(image, soft, skin)
            error = np.asarray(found.get("light_chroma", [np.nan, np.nan])) - np.asarray(truth)
            rows.append({"view": view, "light": light, "rendered": truth, "estimated": found.get("light_chroma"),
                         "error": float(np.linalg.norm(error)), "warmer_by": float(error @ PLANCKIAN),
                         "white_used": bool(found.get("white_used")), "white_chroma": found.get("white_chroma")})
            print(json.dumps(rows[-1]), file=sys.stderr)

    pair = lambda c: "—" if c is None else f"({c[0]:+.2f}, {c[1]:+.2f})"  # noqa: E731
    lines = ["The white reference under the soft (white) light, against SCLERA_CHROMA "
             f"{pair(SCLERA_CHROMA)} (log R/G, log B/G):", "", "| view | white reference | pixels |", "|---|---|---|"]
    lines += [f"| {w['view']} | {pair(w['white_chroma'])} | {w['pixels']} |" for w in whites]
    lines += ["", "The light's chroma per render: rendered (the render over the soft one, median over the skin) against the "
              "default backend's estimate; the error's length and its part along the Planckian direction (> 0: estimated "
              "warmer than rendered):", "", "| view | light | rendered | estimated | error | warmer by | white reference used |",
              "|---|---|---|---|---|---|---|"]
    lines += [f"| {r['view']} | {r['light']} | {pair(r['rendered'])} | {pair(r['estimated'])} | {r['error']:.2f} | "
              f"{r['warmer_by']:+.2f} | {'yes' if r['white_used'] else 'no'} |" for r in rows]
    errors = [r["error"] for r in rows]
    lines += ["", f"Error over the {len(rows)} renders: median {statistics.median(errors):.2f}, worst {max(errors):.2f}; "
              f"white reference used in {sum(r['white_used'] for r in rows)} of {len(rows)}."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.write:
        args.write.write_text(text)
    if args.json:
        args.json.write_text(json.dumps({"rows": rows, "whites": whites}, indent=1))


if __name__ == "__main__":
    main()
