"""Export benchmark: displaced-mesh error against run time, and writer timings.

    python benchmarks/bench_export.py [--size 1024] [--reference-level 5] [--repeats 3]
                                      [--plot benchmarks/out/export_error_vs_time.png]

The asset is the bundled ICT-FaceKit mean shape (11,248 vertices, face-varying UVs) with a
synthetic "skin" displacement map (band-limited noise at three scales, σ = 2, 8 and 32 texels,
RMS 0.30 mm; deterministic). For levels 0…3, ``facegeo.export.displace`` (Loop subdivision with
UVs + baking along smoothed normals) is timed (median of ``--repeats``) and its result compared
with the level-``--reference-level`` displaced mesh (the converged surface):

* RMS: sqrt(mean d²) over the reference's vertices (a dense, near-uniform sample of the
  reference surface: 11.4 M points at level 5) of their distance to the level-k surface;
* Hausdorff: max of that and of the distance of the level-k vertices to the reference surface.

Distances are exact point-to-triangle distances (libigl AABB trees). The same is reported for
the undisplaced surface (plain Loop) to separate subdivision convergence from displacement
sampling. Then the writers (usdz, usdc and glb of an asset with all five 1K maps, level 0
and 1) and the validator matrix: every validator usd-core registers on usda/usdc/usdz and the
Khronos glTF-Validator on glb, over map subsets, constants and subdivision levels.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from facegeo.asset import Asset
from facegeo.export.displacement import displace
from facegeo.export.subdivision import subdivide_arrays
from facegeo.model_files import load_model


def skin_displacement(size: int, seed: int = 8) -> np.ndarray:
    """(size, size) float32 mm: noise at three scales (pores, fine lines, folds), RMS 0.30 mm."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng(seed)
    out = np.zeros((size, size))
    for sigma_at_1k, amplitude in ((2, 0.08), (8, 0.15), (32, 0.25)):
        sigma = sigma_at_1k * size / 1024
        layer = gaussian_filter(rng.standard_normal((size, size)), sigma, mode="wrap")
        out += amplitude * layer / layer.std()
    return (out * 0.30 / out.std()).astype(np.float32)


class Surface:
    """A triangle mesh with its libigl AABB tree, for exact point-to-surface distances."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray):
        import igl

        self.v = np.ascontiguousarray(vertices, dtype=np.float64)
        self.f = np.ascontiguousarray(triangles, dtype=np.int64)
        self.tree = igl.AABB()
        self.tree.init(self.v, self.f)

    def distances(self, points: np.ndarray, chunk: int = 2_000_000) -> np.ndarray:
        out = np.empty(len(points))
        for start in range(0, len(points), chunk):
            p = np.ascontiguousarray(points[start:start + chunk], dtype=np.float64)
            d2, _, _ = self.tree.squared_distance(self.v, self.f, p)
            out[start:start + chunk] = np.sqrt(np.maximum(d2, 0.0))
        return out


def validation_table(full: Asset, size: int) -> None:
    """Every usd-core validator and the Khronos glTF-Validator on a matrix of options."""
    from facegeo.export.gltf import GltfValidatorMissing, validate_glb
    from facegeo.export.usd import validate_usd
    from facegeo.export.writers import export_asset

    constants = Asset(full.vertices, full.triangles, full.uv, full.uv_triangles, maps={},
                      constants={"albedo": (0.72, 0.55, 0.47), "roughness": 0.45, "specular": 0.5})
    cases = [
        ("all five maps", full, None, 0, "bake"),
        ("all five maps", full, None, 1, "bake"),
        ("all five maps", full, None, 2, "bake"),
        ("all five maps, displacement input (USD)", full, None, 1, "texture"),
        ("albedo + normal", full, ["albedo", "normal"], 1, "bake"),
        ("roughness + specular + displacement", full, ["roughness", "specular", "displacement"], 3, "bake"),
        ("albedo only", full, ["albedo"], 0, "bake"),
        ("constants only (factors)", constants, None, 0, "bake"),
    ]
    print(f"\nvalidators ({size}² maps): usd-core = every validator pxr.UsdValidation registers; glTF = Khronos glTF-Validator")
    print("| scene | level | usda E/W | usdc E/W | usdz E/W | glb errors/warnings/infos/hints |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for k, (label, asset, maps, level, disp) in enumerate(cases):
            cells = []
            for fmt in ("usda", "usdc", "usdz"):
                path = export_asset(asset, Path(tmp) / f"c{k}.{fmt}", level=level, maps=maps, displacement=disp)
                issues = validate_usd(path)
                cells.append(f"{sum(i[0] == 'Error' for i in issues)}/{sum(i[0] == 'Warn' for i in issues)}")
            if disp == "bake":
                path = export_asset(asset, Path(tmp) / f"c{k}.glb", level=level, maps=maps)
                try:
                    i = validate_glb(path)["issues"]
                    cells.append(f"{i['numErrors']}/{i['numWarnings']}/{i['numInfos']}/{i['numHints']}")
                except GltfValidatorMissing as exc:
                    cells.append(f"not run ({exc})")
            else:
                cells.append("n/a (glTF has no displacement input)")
            print(f"| {label} | {level} | " + " | ".join(cells) + " |", flush=True)


def load_average() -> str:
    try:
        return "load average " + " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "load average unknown"


SECTIONS = ("errors", "timing", "writers", "uv", "validate")


def timings(asset: Asset, levels: list[int], repeats: int) -> dict[int, tuple[Asset, float]]:
    """displace() at each level: (the last result, median seconds), after one warm-up call."""
    timed = {}
    for level in levels:
        displace(asset, level=level)
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            mesh = displace(asset, level=level)
            times.append(time.perf_counter() - t)
        timed[level] = (mesh, float(np.median(times)))
        print(f"level {level}: displace() median {timed[level][1]:.3f} s over {repeats} ({load_average()})", flush=True)
    return timed


def error_table(asset: Asset, levels: list[int], args: argparse.Namespace) -> None:
    timed = timings(asset, levels, args.repeats)  # first, while this process is the only heavy one it runs
    t0 = time.perf_counter()
    reference = displace(asset, level=args.reference_level)
    print(f"reference: level {args.reference_level}, {len(reference.vertices):,} vertices, {time.perf_counter() - t0:.1f} s")
    reference_surface = Surface(reference.vertices, reference.triangles)
    plain_ref = None
    if not args.no_plain:
        v, f, _, _ = subdivide_arrays(asset.vertices, asset.triangles, None, None, args.reference_level)
        plain_ref = (v, Surface(v, f))

    rows = []
    for level in levels:
        mesh, seconds = timed[level]
        d_ref = Surface(mesh.vertices, mesh.triangles).distances(reference.vertices)
        d_own = reference_surface.distances(mesh.vertices)
        row = {"level": level, "vertices": len(mesh.vertices), "triangles": len(mesh.triangles), "seconds": seconds,
               "rms": float(np.sqrt(np.mean(d_ref ** 2))), "hausdorff": float(max(d_ref.max(), d_own.max())),
               "p99": float(np.percentile(d_ref, 99))}
        if plain_ref is not None:
            pv, pf, _, _ = subdivide_arrays(asset.vertices, asset.triangles, None, None, level)
            pd = Surface(pv, pf).distances(plain_ref[0])
            po = plain_ref[1].distances(pv)
            row["plain_rms"] = float(np.sqrt(np.mean(pd ** 2)))
            row["plain_hausdorff"] = float(max(pd.max(), po.max()))
        rows.append(row)
        print(f"level {level}: {row['vertices']:,} vertices, RMS {row['rms']:.4f} mm, Hausdorff {row['hausdorff']:.3f} mm", flush=True)

    last = rows[-1]["seconds"]
    print(f"\ndisplaced mesh against the level-{args.reference_level} reference ({args.size}² synthetic skin displacement, "
          f"RMS 0.30 mm); time: displace() median of {args.repeats}")
    header = "| level | vertices | triangles | displace() s | time / last level | RMS mm | p99 mm | Hausdorff mm |"
    if plain_ref is not None:
        header += " plain Loop RMS mm | plain Hausdorff mm |"
    print(header)
    print("|" + "---|" * (header.count("|") - 1))
    for r in rows:
        line = (f"| {r['level']} | {r['vertices']:,} | {r['triangles']:,} | {r['seconds']:.3f} | {r['seconds'] / last:.2f} | "
                f"{r['rms']:.4f} | {r['p99']:.4f} | {r['hausdorff']:.3f} |")
        if plain_ref is not None:
            line += f" {r['plain_rms']:.4f} | {r['plain_hausdorff']:.3f} |"
        print(line)
    if args.plot:
        plot(rows, plain_ref is not None, args)


def plot(rows: list[dict], plain: bool, args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    args.plot.parent.mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    t = [r["seconds"] for r in rows]
    ax.loglog(t, [r["rms"] for r in rows], "o-", label="RMS")
    ax.loglog(t, [r["hausdorff"] for r in rows], "s-", label="Hausdorff")
    if plain:
        ax.loglog(t, [r["plain_rms"] for r in rows], "o--", alpha=0.6, label="RMS, no displacement")
    for r in rows:
        ax.annotate(f"level {r['level']}\n{r['vertices']:,} v", (r["seconds"], r["rms"]), textcoords="offset points", xytext=(4, -22), fontsize=8)
    ax.set_xlabel("displace() time, s (2-core CPU)")
    ax.set_ylabel(f"distance to level-{args.reference_level} reference, mm")
    ax.set_title("Displaced mesh: error against run time")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.plot, dpi=120)
    print(f"\nplot: {args.plot}")


def writer_table(full: Asset, size: int, repeats: int) -> None:
    from facegeo.export.gltf import write_glb
    from facegeo.export.usd import write_usd

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for level in (0, 1):
            for suffix, write in (("usdz", write_usd), ("usdc", write_usd), ("glb", write_glb)):
                write(full, Path(tmp) / f"face.{suffix}", level=level)  # warm-up
                times = []
                for _ in range(repeats):
                    t = time.perf_counter()
                    path = write(full, Path(tmp) / f"face.{suffix}", level=level)
                    times.append(time.perf_counter() - t)
                rows.append((suffix, level, float(np.median(times)), path.stat().st_size))
    print(f"\nwriters: all five maps at {size}² (displacement baked), median of {repeats}; {load_average()}")
    print("| format | level | seconds | file MB |")
    print("|---|---|---|---|")
    for suffix, level, seconds, nbytes in rows:
        print(f"| {suffix} | {level} | {seconds:.2f} | {nbytes / 1e6:.1f} |")


def uv_drift_table(model, levels: list[int]) -> None:
    """How far the coarse-surface point addressed by each subdivided UV is from the subdivided
    vertex (mm): the texture 'swimming' of each UV rule."""
    from test_export_subdivision import _uv_implied_positions  # noqa: E402  (one definition)

    from facegeo.export.facevarying import wedges

    v0, f0 = model.mean_shape.astype(np.float64), model.triangles
    uv0, ut0 = model.uv.astype(np.float64), model.uv_triangles
    print("\nUV drift: distance (mm) between a subdivided vertex and the coarse-surface point its UV addresses")
    print("| level | UV rule | mean | p99 | max | UVs outside the coarse charts |")
    print("|---|---|---|---|---|---|")
    for level in [lv for lv in levels if lv > 0]:
        for rule in ("surface", "linear"):
            v, f, uv, ut = subdivide_arrays(v0, f0, uv0, ut0, level, uv_interpolation=rule)
            vw, tw, _ = wedges(f, ut)
            implied, score = _uv_implied_positions(v0, f0, uv0, ut0, uv[tw])
            err = np.linalg.norm(implied - v[vw], axis=1)
            print(f"| {level} | {rule} | {err.mean():.3f} | {np.percentile(err, 99):.3f} | {err.max():.3f} | "
                  f"{int((score < -1e-9).sum())} of {len(err):,} |", flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=1024, help="map size (texels)")
    parser.add_argument("--reference-level", type=int, default=5)
    parser.add_argument("--levels", default="0,1,2,3")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--plot", type=Path, default=Path("benchmarks/out/export_error_vs_time.png"))
    parser.add_argument("--no-plain", action="store_true", help="skip the undisplaced (plain Loop) comparison")
    parser.add_argument("--sections", default=",".join(SECTIONS),
                        help=f"comma-separated among {', '.join(SECTIONS)} (timing = the displace() timings alone)")
    args = parser.parse_args()
    levels = [int(x) for x in args.levels.split(",")]
    sections = [x.strip() for x in args.sections.split(",") if x.strip()]
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    from test_export_support import synthetic_maps  # noqa: E402

    print(f"machine: {os.cpu_count()} CPUs, {load_average()} at start")
    model = load_model()
    dmap = skin_displacement(args.size)
    asset = Asset(model.mean_shape, model.triangles, model.uv, model.uv_triangles, maps={"displacement": dmap})
    print(f"asset: {len(asset.vertices)} vertices, {len(asset.triangles)} triangles; displacement {args.size}² "
          f"RMS {float(np.sqrt(np.mean(dmap ** 2))):.3f} mm, range [{float(dmap.min()):.2f}, {float(dmap.max()):.2f}] mm")
    maps = synthetic_maps(args.size)
    maps["displacement"] = dmap
    full = Asset(model.mean_shape, model.triangles, model.uv, model.uv_triangles, maps=maps)
    if "errors" in sections:
        error_table(asset, levels, args)
    elif "timing" in sections:
        timings(asset, levels, args.repeats)
    if "writers" in sections:
        writer_table(full, args.size, args.repeats)
    if "uv" in sections:
        uv_drift_table(model, levels)
    if "validate" in sections:
        validation_table(full, args.size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
