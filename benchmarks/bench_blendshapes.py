"""Blendshape export benchmark (issue 28): file sizes and writing time with and without the targets.

    python benchmarks/bench_blendshapes.py [--asset DIR] [--levels 0,1,2,3] [--repeats 5]

The asset is a ``facegeo reconstruct`` output folder (default: the bundled photo reconstructed
with the default options into a temporary folder first). For each ``--subdiv`` level the scenes
``facegeo reconstruct`` writes (``face.glb`` and ``face.usdz``, the maps it carries: the
displacement only at level > 0) are written with the ARKit blendshapes (the default) and without
(``--blendshapes none``), and their sizes compared. At level 0 (the default) the export stage of
``facegeo reconstruct`` is timed ``--repeats`` times (min and median of the process CPU time and
of the wall time): the asset folder's files (``blendshapes.npz`` included or not) and both scenes
as the job writes them (:func:`facegeo.export.writers.export_scenes`, the targets computed once):
the time the targets add to ``facegeo reconstruct``. Then the checks: the Khronos
glTF-Validator on the glb with all targets, and UsdSkel's evaluation of the usdz against the posed
mesh (ICT and ARKit names). Threads: one (OMP/MKL/OpenBLAS, as the tests).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402


def load_average() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg())


def timed(functions: list, repeats: int) -> list[tuple[list[float], list[float]]]:
    """(CPU seconds, wall seconds) of ``repeats`` calls of each function, interleaved (A, B, A,
    B, ...) so that a change of the machine's load falls on both alike."""
    out = [([], []) for _ in functions]
    for _ in range(repeats):
        for function, (cpu, wall) in zip(functions, out):
            c, w = time.process_time(), time.perf_counter()
            function()
            cpu.append(time.process_time() - c)
            wall.append(time.perf_counter() - w)
    return out


def stats(values: list[float]) -> str:
    return f"{min(values):.2f} / {float(np.median(values)):.2f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--asset", type=Path, default=None, help="a facegeo reconstruct output folder (default: the bundled photo's)")
    parser.add_argument("--levels", default="0,1,2,3")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    from facegeo.export.asset_io import load_asset, write_asset_files
    from facegeo.export.writers import export_asset, export_scenes

    print(f"# bench_blendshapes: {' '.join(sys.argv[1:]) or '(defaults)'}; {load_average()}")
    with tempfile.TemporaryDirectory(prefix="facegeo-bench-bs-") as tmp:
        work = Path(tmp)
        folder = args.asset
        if folder is None:
            from facegeo.assets import asset_path
            from facegeo.jobs import ReconstructOptions, reconstruct_into_folder

            folder = work / "astronaut"
            reconstruct_into_folder(asset_path("photos/astronaut.png"), folder, ReconstructOptions(formats=("glb",), preview=False))
        asset = load_asset(folder)
        static_asset = load_asset(folder)
        static_asset.blendshapes = None
        for part in static_asset.parts:
            part.blendshapes = None

        print("\n## Sizes (bytes): the scenes of facegeo reconstruct, with the 51 ARKit targets and without\n")
        print("| --subdiv | glb static | glb with targets | ratio | usdz static | usdz with targets | ratio |")
        print("|---|---|---|---|---|---|---|")
        for level in (int(x) for x in args.levels.split(",")):
            carried = [m for m in asset.maps if m != "displacement" or level > 0]
            row = [str(level)]
            for fmt in ("glb", "usdz"):
                sizes = []
                for naming in (None, "arkit"):
                    path = export_asset(asset, work / f"l{level}_{naming}.{fmt}", level=level, maps=carried, blendshapes=naming)
                    sizes.append(path.stat().st_size)
                    path.unlink()
                row += [f"{sizes[0]:,}", f"{sizes[1]:,}", f"{sizes[1] / sizes[0]:.2f}×"]
            print("| " + " | ".join(row) + " |", flush=True)

        print(f"\n## Time at --subdiv 0, {args.repeats} repeats, seconds min / median ({load_average()})\n")
        print("| writer | CPU static | CPU with targets | CPU added (min) | wall static | wall with targets | wall added (min) |")
        print("|---|---|---|---|---|---|---|")
        carried = [m for m in asset.maps if m != "displacement"]
        added_cpu, added_wall = 0.0, 0.0
        writers = {
            "asset folder": lambda a: write_asset_files(a, work / ("folder_s" if a.blendshapes is None else "folder_t")),
            "face.glb + face.usdz": lambda a: export_scenes(a, [(work / "t.glb", None), (work / "t.usdz", None)], maps=carried,
                                                            blendshapes=None if a.blendshapes is None else "arkit"),
        }
        (work / "folder_s").mkdir()
        (work / "folder_t").mkdir()
        for name, write in writers.items():
            write(asset)  # warm caches and imports
            (cpu_s, wall_s), (cpu_t, wall_t) = timed([lambda: write(static_asset), lambda: write(asset)], args.repeats)
            added_cpu += min(cpu_t) - min(cpu_s)
            added_wall += min(wall_t) - min(wall_s)
            print(f"| {name} | {stats(cpu_s)} | {stats(cpu_t)} | {min(cpu_t) - min(cpu_s):+.2f} | {stats(wall_s)} | "
                  f"{stats(wall_t)} | {min(wall_t) - min(wall_s):+.2f} |", flush=True)
        print(f"| **export stage (sum)** | | | **{added_cpu:+.2f}** | | | **{added_wall:+.2f}** |")
        npz = work / "folder_t" / "blendshapes.npz"
        print(f"\nblendshapes.npz in the asset folder: {npz.stat().st_size:,} bytes")

        print("\n## Checks\n")
        glb = export_asset(asset, work / "check.glb", maps=carried)
        try:
            from facegeo.export.gltf import validate_glb

            issues = validate_glb(glb)["issues"]
            print(f"Khronos glTF-Validator, glb with all targets: {issues['numErrors']} errors, {issues['numWarnings']} warnings, "
                  f"{issues['numInfos']} infos, {issues['numHints']} hints")
        except Exception as exc:  # the validator is optional here
            print(f"Khronos glTF-Validator: not run ({exc})")
        from facegeo.arkit import target_naming
        from facegeo.export.usd import skel_points, validate_usd
        from facegeo.parts import load_parts, part_vertices
        from facegeo.model_files import load_model

        model = load_model()
        fit_alpha = np.asarray(asset.metadata["fit"]["alpha"], np.float32)
        delta = asset.blendshapes.weights
        for naming in ("ict", "arkit"):
            usdz = export_asset(asset, work / f"check_{naming}.usdz", maps=carried, blendshapes=naming)
            errors = [e for e in validate_usd(usdz) if e[0] == "Error"]
            names = target_naming(asset.blendshapes.names, naming)
            shown = names.combine.T @ names.target_weights(delta)
            expected = {"/face/mesh": model.shape(fit_alpha, shown).numpy()}
            expected.update({f"/face/parts/{k}": v for k, v in part_vertices(load_parts(model), model, fit_alpha, shown).items()})
            points = skel_points(usdz)
            worst = max(float(np.abs(points[k] - expected[k]).max()) for k in points)
            fit_gap = float(np.abs(points["/face/mesh"] - asset.vertices).max())
            print(f"usdz ({naming} names): {len(errors)} validator errors; UsdSkel evaluation vs the posed mesh (skin and "
                  f"{len(points) - 1} parts): max |Δ| = {worst:.2e} mm; skin vs the fit's mesh: {fit_gap:.2e} mm")
    print(f"\n# done; {load_average()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
