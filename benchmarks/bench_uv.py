"""Benchmark of facegeo.uv: time and round-trip error of rasterise + geometry maps + unwrap against
the map size S, cold (empty caches) and warm (cached UV raster and tangent topology).

Round trip: a smooth texture painted on the surface (a function of the model-space position, so
continuous across seams) is rendered with the z-buffer renderer into a ``--photo``-pixel image of
the posed ICT-FaceKit mean shape, unwrapped again at size S, and compared with the painted texture
on the texels with M_vis > 0.5 (PSNR; the bar is ≥ 35 dB at S = 1024). Times are wall-clock
(perf_counter) and CPU (process_time) seconds; ratios are against S = 1024 warm, measured in the
same run. A last table times the same stages on the bundled photo after a real fit.

    python benchmarks/bench_uv.py                       # prints the tables
    python benchmarks/bench_uv.py --write benchmarks/RESULTS_uv.md
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

import facegeo
from facegeo.camera import Camera, rotation_from_euler
from facegeo.uv import clear_raster_cache, geometry_maps, rasterize_uv, render, unwrap
from facegeo.uv import tangents as _tangents

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_uv_support import painted_texture  # noqa: E402  (one definition of the test texture)

SIZES = (256, 512, 1024, 2048, 4096)
REFERENCE_SIZE = 1024


def load() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "n/a"


def pipeline(model, fit, image, size):
    """(raster, maps, T_inc, M_vis, {stage: (wall, cpu)}) for one run of the three stages."""
    times = {}

    def stage(name, fn):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        times[name] = (time.perf_counter() - w, time.process_time() - c)
        return out

    raster = stage("rasterize", lambda: rasterize_uv(model, size=size))
    maps = stage("maps", lambda: geometry_maps(fit.vertices, model, raster))
    t_inc, m_vis = stage("unwrap", lambda: unwrap(image, fit, model, maps=maps))
    times["total"] = tuple(sum(v[i] for v in times.values()) for i in (0, 1))
    return raster, maps, t_inc, m_vis, times


def cold_caches() -> None:
    clear_raster_cache()
    _tangents._TOPO_CACHE.clear()


def oracle_table(model, photo: int) -> list[dict]:
    """Agreement of unwrap's geometric visibility with ray casting for a few poses."""
    import open3d as o3d

    from facegeo.uv import unwrap_details

    raster = rasterize_uv(model, size=REFERENCE_SIZE)
    rows = []
    for yaw, pitch in ((0, 0), (45, 0), (80, 0), (90, 0), (-90, 0), (0, 60), (0, -60)):
        R = rotation_from_euler(yaw, pitch, 0.0)
        V = (model.mean_shape.astype(np.float64) @ R.T + np.array([0.0, 0.0, -700.0])).astype(np.float32)
        fit = SimpleNamespace(vertices=V, camera=Camera.for_image(photo, photo, 40.0))
        t = time.perf_counter()
        u = unwrap_details(np.zeros((photo, photo, 3), np.uint8), fit, model, raster=raster)
        seconds = time.perf_counter() - t
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(V), o3d.core.Tensor(model.triangles.astype(np.uint32)))
        inside = raster.inside
        P = geometry_maps(V, model, raster, tangents=False).position[inside]
        dist = np.linalg.norm(P, axis=1)
        rays = np.concatenate([np.zeros_like(P), P / dist[:, None]], axis=1).astype(np.float32)
        first = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy() >= dist * (1 - 1e-5) - 1e-3
        oracle = first & u.front[inside] & u.in_image[inside]
        ours = u.visible[inside]
        rows.append(dict(yaw=yaw, pitch=pitch, agree=100.0 * float((oracle == ours).mean()),
                         fp=int((ours & ~oracle).sum()), fn=int((~ours & oracle).sum()),
                         visible=int(oracle.sum()), seconds=seconds))
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="comma-separated map sizes")
    ap.add_argument("--photo", type=int, default=1024, help="side of the rendered square image in pixels")
    ap.add_argument("--repeats", type=int, default=3, help="warm runs per size (median)")
    ap.add_argument("--yaw", type=float, default=25.0)
    ap.add_argument("--no-real", action="store_true", help="skip the real-photo table")
    ap.add_argument("--write", type=Path, default=None, help="also write the report (markdown) here")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",")]
    model = facegeo.load_model()
    load_start = load()

    R = rotation_from_euler(args.yaw, 10.0, 0.0)
    V = (model.mean_shape.astype(np.float64) @ R.T + np.array([0.0, 0.0, -700.0])).astype(np.float32)
    fit = SimpleNamespace(vertices=V, camera=Camera.for_image(args.photo, args.photo, 40.0))

    rows = []
    for S in sizes:
        cold_caches()
        raster = rasterize_uv(model, size=S)
        texture = painted_texture(model, raster)
        image = render(V, model, fit.camera, texture=texture).image
        del raster
        cold_caches()
        _, _, t_inc, m_vis, cold = pipeline(model, fit, image, S)
        warm_runs = [pipeline(model, fit, image, S)[4] for _ in range(args.repeats)]
        warm = {k: tuple(statistics.median(r[k][i] for r in warm_runs) for i in (0, 1)) for k in cold}
        sel = m_vis > 0.5
        mse = float(((t_inc - texture)[sel] ** 2).mean())
        rows.append(dict(S=S, cold=cold, warm=warm, psnr=10 * np.log10(1.0 / mse),
                         rmse=np.sqrt(mse) * 255.0, texels=int(sel.sum())))
        print(f"S={S}: cold {cold['total'][0]:.3f} s, warm {warm['total'][0]:.3f} s, "
              f"PSNR {rows[-1]['psnr']:.2f} dB on {rows[-1]['texels']} texels", file=sys.stderr)
        del t_inc, m_vis, texture, image

    ref = next((r for r in rows if r["S"] == REFERENCE_SIZE), rows[0])
    lines = []
    lines.append(f"synthetic round trip: ICT-FaceKit mean shape, yaw {args.yaw:g}° pitch 10°, 700 mm, "
                 f"{args.photo}x{args.photo} render, 40° field of view")
    lines.append("")
    lines.append("| S | rasterise cold s | maps cold s | unwrap cold s | total cold s (cpu) | rasterise warm s | maps warm s "
                 "| unwrap warm s | total warm s (cpu) | warm ratio to S=1024 | PSNR dB (M_vis>0.5) | RMSE /255 | texels compared |")
    lines.append("|" + "---|" * 13)
    for r in rows:
        c, w = r["cold"], r["warm"]
        lines.append(
            f"| {r['S']} | {c['rasterize'][0]:.3f} | {c['maps'][0]:.3f} | {c['unwrap'][0]:.3f} | "
            f"{c['total'][0]:.3f} ({c['total'][1]:.3f}) | {w['rasterize'][0]:.4f} | {w['maps'][0]:.3f} | "
            f"{w['unwrap'][0]:.3f} | {w['total'][0]:.3f} ({w['total'][1]:.3f}) | "
            f"{w['total'][0] / ref['warm']['total'][0]:.2f} | {r['psnr']:.2f} | {r['rmse']:.2f} | {r['texels']} |")

    # visibility against ray casting (Open3D RaycastingScene), S = 1024
    agreement = oracle_table(model, args.photo)
    lines.append("")
    lines.append(f"visibility against ray casting (Open3D RaycastingScene), S = {REFERENCE_SIZE}, {args.photo}x{args.photo} image; "
                 "agreement over all inside texels; false visible / false hidden texels")
    lines.append("")
    lines.append("| yaw ° | pitch ° | agreement % | false visible | false hidden | oracle-visible texels | unwrap s |")
    lines.append("|---|---|---|---|---|---|---|")
    for row in agreement:
        lines.append("| {yaw:g} | {pitch:g} | {agree:.3f} | {fp} | {fn} | {visible} | {seconds:.3f} |".format(**row))

    if not args.no_real:
        from facegeo.assets import asset_path
        from facegeo.fitting import fit as fit_photo
        from facegeo.photo import load_photo

        photo = load_photo(asset_path("photos/astronaut.png"))
        h, w = photo.image.shape[:2]
        result = fit_photo(photo, model=model, camera=Camera.for_image(w, h))
        cold_caches()
        _, _, _, m_vis, cold = pipeline(model, result, photo.image, REFERENCE_SIZE)
        warm_runs = [pipeline(model, result, photo.image, REFERENCE_SIZE)[4] for _ in range(args.repeats)]
        warm = {k: tuple(statistics.median(r[k][i] for r in warm_runs) for i in (0, 1)) for k in cold}
        lines.append("")
        lines.append(f"real photo astronaut.png ({w}x{h}) after facegeo.fit (hybrid landmarks), S = {REFERENCE_SIZE}")
        lines.append("")
        lines.append("| stage | cold s (cpu) | warm s (cpu), median of %d |" % args.repeats)
        lines.append("|---|---|---|")
        for k in ("rasterize", "maps", "unwrap", "total"):
            lines.append(f"| {k} | {cold[k][0]:.3f} ({cold[k][1]:.3f}) | {warm[k][0]:.3f} ({warm[k][1]:.3f}) |")
        lines.append(f"visible texels (M_vis > 0): {int((m_vis > 0).sum())}")
        real = (warm["total"][0], cold["total"][0])
    else:
        real = None

    r1024 = next((r for r in rows if r["S"] == REFERENCE_SIZE), None)
    if r1024 is not None:
        lines.append("")
        real_text = "" if real is None else f"; on the 512-pixel photo {real[0]:.3f} s warm, {real[1]:.3f} s cold"
        lines.append(f"Bars (issue 6), S = {REFERENCE_SIZE}: round-trip PSNR {r1024['psnr']:.2f} dB (bar ≥ 35); rasterise + maps + "
                     f"unwrap (bar ≤ 0.5 s) {r1024['warm']['total'][0]:.3f} s warm, {r1024['cold']['total'][0]:.3f} s cold "
                     f"with a {args.photo}-pixel image{real_text}; visibility agreement with ray casting "
                     f"{min(r['agree'] for r in agreement):.2f} % at worst over the poses above (bar ≥ 99 %).")

    load_end = load()
    header = [
        f"Machine: {platform.machine()} CPU, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"numpy {np.__version__}; load average (1, 5, 15 min) at start {load_start}, at end {load_end}.",
        "",
    ]
    report = "\n".join(header + lines) + "\n"
    print(report)
    if args.write is not None:
        cmd = "python benchmarks/bench_uv.py " + " ".join(argv if argv is not None else sys.argv[1:])
        args.write.write_text(
            "# facegeo.uv benchmark: rasterise + geometry maps + unwrap against the map size\n\n"
            f"Command: `{cmd.strip()}`\n\n" + report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
