"""Benchmark of ``preview.png`` (:func:`facegeo.texturing.preview.relit_preview`) and the parts stage.

    python benchmarks/bench_preview.py [--repeat 5]

Reconstructs the bundled photo once (maps at 512²), then times, ``--repeat`` times each:
``relit_preview`` at the default panel size (256: a 512 × 1280 image, 3 views × textured + clay),
the parts stage alone (``load_parts`` + iris colour + ``part_assets``), and as a reference measured
in the same run, one z-buffer render of the skin from the photo's camera (``facegeo.uv.render``,
what the old single-view preview rasterised once). Prints min and median seconds, the ratios of
the minima to the reference, and the load average (the machine is shared).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time



def timed(fn, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    import facegeo
    from facegeo.assets import asset_path
    from facegeo.landmarks.iris import IrisDetector, iris_colour
    from facegeo.parts import load_parts, part_assets
    from facegeo.pipeline import reconstruct_with_fit
    from facegeo.texturing.preview import relit_preview
    from facegeo.uv import render

    photo = facegeo.load_photo(asset_path("photos/astronaut.png"))
    model = facegeo.load_model()
    asset, fit = reconstruct_with_fit(photo, model, size=512)
    detector = IrisDetector()

    def parts_stage() -> None:
        colour, _ = iris_colour(photo.image, fit.landmarks, detector)
        part_assets(load_parts(model), model, fit.alpha, fit.delta, colour)

    rows = {
        "reference: render(skin, photo camera)": timed(lambda: render(fit.vertices, model, fit.camera), args.repeat),
        "relit_preview(panel=256)": timed(lambda: relit_preview(photo.image, asset, fit), args.repeat),
        "parts stage (load, iris, part_assets)": timed(parts_stage, args.repeat),
    }
    reference = min(next(iter(rows.values())))
    print(f"load average {os.getloadavg()}, {args.repeat} runs each")
    print("| what | min s | median s | min / reference |")
    print("| --- | --- | --- | --- |")
    for name, times in rows.items():
        print(f"| {name} | {min(times):.3f} | {statistics.median(times):.3f} | {min(times) / reference:.1f} |")


if __name__ == "__main__":
    main()
