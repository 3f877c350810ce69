"""Benchmark of ``facegeo.texturing.shading.shade_ggx``: torch float32 forward + backward against a
float64 NumPy forward of the same formulas (paper A.1), in the same run.

    python benchmarks/bench_shading.py [--size 1024] [--lights 3] [--repeats 5] [--threads N] [--compile]

Prints the timings (median of ``--repeats``: wall clock, and the process CPU time, which is less
disturbed by other jobs on a shared machine), the speed ratio, the peak memory of each variant, the
float32-vs-float64 error, and Markdown tables (for benchmarks/RESULTS_shading.md). NumPy runs its
element-wise work on one thread; torch uses ``--threads`` (default: torch's default).

Variants:
- ``numpy f64 literal``: the formulas as written in A.1 (Gram-Schmidt local frame, l and v projected
  into it, explicit half vector), vectorised over texels, one light at a time.
- ``numpy f64 lean``: the same values with the algebra shade_ggx uses (world-space dot products with
  N_s, n·h and l·h from n·l, n·v, l·v), i.e. NumPy's best effort at the same computation.
- ``torch f32 eager``: shade_ggx forward, then backward of a scalar loss to the five material maps
  (albedo, normal_ts, roughness, specular, displacement), as in training.
- ``torch f32 compiled`` (``--compile``): the same under ``torch.compile`` (first call excluded).

Peak memory is measured in a fresh subprocess per variant: the largest resident-set growth over the
inputs while the call runs (sampled every 0.5 ms from /proc/self/statm), and for NumPy also the
tracemalloc peak (exact for NumPy buffers).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import threading
import time
import tracemalloc

import numpy as np

ALPHA_MIN = 2e-3  # as facegeo.texturing.shading.ALPHA_MIN (inactive for these inputs: roughness ≥ 0.2)
MAP_NAMES = (
    "albedo", "normal_ts", "roughness", "specular", "displacement",
    "position", "geo_normal", "geo_tangent", "mask",
)  # fmt: skip
TRAINED = ("albedo", "normal_ts", "roughness", "specular", "displacement")
FIELDS = ("shaded", "diffuse", "glossy", "shading", "visibility")


def make_inputs(size: int, n_lights: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Regular float64 inputs (B = 1): a curved patch seen from 500 mm, maps (C, H, W)."""
    rng = np.random.default_rng(seed)
    h = w = size
    y, x = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
    # a bump of radius ~100 mm: position, normal and tangent from its height field
    z = 40 * np.exp(-(x**2 + y**2))
    dzdx, dzdy = -2 * x * z / 100, -2 * y * z / 100
    position = np.stack([100 * x, 100 * y, z])
    geo_normal = np.stack([-dzdx, -dzdy, np.ones_like(z)])
    geo_tangent = np.stack([np.ones_like(z), np.zeros_like(z), dzdx])
    noise = lambda c, s: s * rng.standard_normal((c, h, w))  # noqa: E731
    dirs = np.stack([rng.uniform(-0.6, 0.6, n_lights), rng.uniform(-0.6, 0.6, n_lights), np.ones(n_lights)], -1)
    return {
        "albedo": np.clip(0.5 + noise(3, 0.1), 0.05, 0.95),
        "normal_ts": np.concatenate([noise(2, 0.15), np.ones((1, h, w))]),
        "roughness": np.clip(0.5 + noise(1, 0.1), 0.2, 0.9),
        "specular": np.clip(0.5 + noise(1, 0.1), 0.0, 1.0),
        "displacement": noise(1, 1.0),
        "position": position,
        "geo_normal": geo_normal,
        "geo_tangent": geo_tangent,
        "mask": (rng.uniform(size=(1, h, w)) > 0.1).astype(np.float64),
        "light_dirs": dirs / np.linalg.norm(dirs, axis=-1, keepdims=True),
        "light_radiance": rng.uniform(0.5, 2.0, (n_lights, 3)),
        "camera_pos": np.array([20.0, -30.0, 500.0]),
        "ambient": np.array(0.2),
    }


# ------------------------------------------------------------------ NumPy float64 evaluations


def _unit(x):
    return x / np.sqrt((x * x).sum(0, keepdims=True))


def _dot(a, b):
    return (a * b).sum(0, keepdims=True)


def numpy_literal(i, s_disp=0.01):
    """A.1 as written: frames, projection into {T_l, B_l, N_s}, explicit h. Maps (C, H, W)."""
    n_g, t_g = _unit(i["geo_normal"]), _unit(i["geo_tangent"])
    b_g = _unit(np.cross(n_g, t_g, axis=0))
    nt = i["normal_ts"]
    n_s = _unit(nt[0:1] * t_g + nt[1:2] * b_g + nt[2:3] * n_g)
    t_l = _unit(i["geo_tangent"] - _dot(i["geo_tangent"], n_s) * n_s)
    b_l = _unit(np.cross(n_s, t_l, axis=0))
    p = i["position"] + s_disp * i["displacement"] * n_g
    v_w = _unit(i["camera_pos"][:, None, None] - p)
    v = np.concatenate([_dot(t_l, v_w), _dot(b_l, v_w), _dot(n_s, v_w)])
    alpha = np.maximum(i["roughness"] ** 2, ALPHA_MIN)
    a2 = alpha * alpha
    f0 = 0.08 * i["specular"]
    shading = np.zeros_like(i["albedo"])
    glossy = np.zeros_like(i["albedo"])
    for l_w, radiance in zip(i["light_dirs"], i["light_radiance"]):
        l_w = l_w[:, None, None]
        l = np.concatenate([_dot(t_l, l_w), _dot(b_l, l_w), _dot(n_s, l_w)])
        h = _unit(l + v)
        nl = np.clip(l[2:3], 0, 1)
        nv = np.clip(v[2:3], 0, 1)
        nh = np.clip(h[2:3], 0, 1)
        lh = np.clip(_dot(l, h), 0, 1)
        d = a2 / (math.pi * (nh * nh * (a2 - 1) + 1) ** 2)
        f = f0 + (1 - f0) * (1 - lh) ** 5
        vis = 0.5 / (nv * np.sqrt(a2 + (1 - a2) * nl * nl) + nl * np.sqrt(a2 + (1 - a2) * nv * nv))
        shading += radiance[:, None, None] * nl
        glossy += radiance[:, None, None] * (nl * d * f * vis)
    diffuse = shading * i["albedo"] / math.pi
    shaded = i["mask"] * (diffuse + glossy + i["ambient"] * i["albedo"])
    visibility = i["mask"] * np.clip(_dot(n_g, v_w), 0, 1)
    return shaded, diffuse, glossy, shading, visibility


def numpy_lean(i, s_disp=0.01):
    """The same values with shade_ggx's algebra: world-space dots, scalar per-light maps."""
    n_g, t_g = _unit(i["geo_normal"]), _unit(i["geo_tangent"])
    b_g = _unit(np.cross(n_g, t_g, axis=0))
    nt = i["normal_ts"]
    n_s = _unit(nt[0:1] * t_g + nt[1:2] * b_g + nt[2:3] * n_g)
    v = _unit(i["camera_pos"][:, None, None] - (i["position"] + s_disp * i["displacement"] * n_g))
    nv_raw = _dot(n_s, v)[0]
    nv = np.clip(nv_raw, 0, 1)
    alpha = np.maximum(i["roughness"][0] ** 2, ALPHA_MIN)
    a2 = alpha * alpha
    lam_v = np.sqrt(a2 + (1 - a2) * nv * nv)
    f0 = 0.08 * i["specular"][0]
    shading = np.zeros_like(i["albedo"])
    glossy = np.zeros_like(i["albedo"])
    for l, radiance in zip(i["light_dirs"], i["light_radiance"]):
        nl_raw = l[0] * n_s[0] + l[1] * n_s[1] + l[2] * n_s[2]
        lv = l[0] * v[0] + l[1] * v[1] + l[2] * v[2]
        inv = 1 / np.sqrt(2 + 2 * lv)
        nh = np.clip((nl_raw + nv_raw) * inv, 0, 1)
        lh = np.clip((1 + lv) * inv, 0, 1)
        nl = np.clip(nl_raw, 0, 1)
        d = nh * nh * (a2 - 1) + 1
        spec = nl * (f0 + (1 - f0) * (1 - lh) ** 5) * a2 / (math.pi * d * d)
        spec *= 0.5 / (nv * np.sqrt(a2 + (1 - a2) * nl * nl) + nl * lam_v)
        shading += radiance[:, None, None] * nl
        glossy += radiance[:, None, None] * spec
    diffuse = shading * i["albedo"] / math.pi
    shaded = i["mask"] * (diffuse + glossy + i["ambient"] * i["albedo"])
    return shaded, diffuse, glossy, shading, i["mask"] * np.clip(_dot(n_g, v), 0, 1)


# ------------------------------------------------------------------ torch


def torch_inputs(i, dtype, requires_grad=True):
    import torch

    t = {k: torch.tensor(i[k], dtype=dtype)[None] for k in MAP_NAMES}
    for k in TRAINED:
        t[k].requires_grad_(requires_grad)
    t["light_dirs"] = torch.tensor(i["light_dirs"], dtype=dtype)[None]
    t["light_radiance"] = torch.tensor(i["light_radiance"], dtype=dtype)[None]
    t["camera_pos"] = torch.tensor(i["camera_pos"], dtype=dtype)[None]
    t["ambient"] = float(i["ambient"])
    return t


def torch_step(fn, t, backward=True):
    """Forward (+ backward of a loss touching every output) -> (outputs, forward s, backward s)."""
    args = [t[k] for k in MAP_NAMES] + [t["light_dirs"], t["light_radiance"], t["camera_pos"], t["ambient"]]
    for k in TRAINED:
        t[k].grad = None
    start = time.perf_counter()
    out = fn(*args)
    mid = time.perf_counter()
    if backward:
        loss = sum((o * (n + 1)).mean() for n, o in enumerate(out))
        loss.backward()
    return out, mid - start, time.perf_counter() - mid


# ------------------------------------------------------------------ memory (subprocess)


def _rss_bytes():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class _PeakRSS:
    """Largest RSS seen while the block runs (sampled every 0.5 ms), minus the RSS at entry."""

    def __enter__(self):
        self.base = self.peak = _rss_bytes()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, _rss_bytes())
            time.sleep(0.0005)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, _rss_bytes())
        self.growth = self.peak - self.base


def measure_memory(variant: str, size: int, n_lights: int) -> dict:
    inputs = make_inputs(size, n_lights)
    result: dict = {}
    if variant.startswith("numpy"):
        fn = numpy_literal if variant == "numpy_literal" else numpy_lean
        fn(make_inputs(16, n_lights))  # warm imports
        tracemalloc.start()
        with _PeakRSS() as rss:
            out = fn(inputs)
        result["tracemalloc_peak"] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        del out
    else:
        import torch

        from facegeo.texturing.shading import shade_ggx

        t = torch_inputs(inputs, torch.float32)
        torch_step(shade_ggx, torch_inputs(make_inputs(16, n_lights), torch.float32))  # warm up
        with _PeakRSS() as rss:
            out = torch_step(shade_ggx, t)
    result["rss_growth"] = rss.growth
    return result


# ------------------------------------------------------------------ main


def _errors(approx, exact):
    rows = {}
    for name, a, e in zip(FIELDS, approx, exact):
        a = np.asarray(a, dtype=np.float64).reshape(e.shape)
        scale = np.abs(e).max()
        big = np.abs(e) > 1e-3 * scale
        rows[name] = (float(np.abs(a - e).max() / scale), float((np.abs(a - e)[big] / np.abs(e[big])).max()))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--lights", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, help="torch intra-op threads (default: torch's default)")
    parser.add_argument("--compile", action="store_true", help="also time torch.compile(shade_ggx)")
    parser.add_argument("--memory-variant", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_variant:
        print(json.dumps(measure_memory(args.memory_variant, args.size, args.lights)))
        return

    import torch

    from facegeo.texturing import shading

    if args.threads:
        torch.set_num_threads(args.threads)
    load_start = os.getloadavg()
    inputs = make_inputs(args.size, args.lights)
    n = args.size * args.size
    print(f"shade_ggx benchmark: {args.size}x{args.size} texels, K = {args.lights}, "
          f"torch {torch.__version__} ({torch.get_num_threads()} threads), numpy {np.__version__}, "
          f"CHUNK_TEXELS = {shading.CHUNK_TEXELS}, load average at start {load_start[0]:.2f}")  # fmt: skip

    times: dict[str, list[float]] = {}
    cpu: dict[str, list[float]] = {}
    ref = None
    for name, fn in (("numpy f64 literal", numpy_literal), ("numpy f64 lean", numpy_lean)):
        fn(inputs)  # warm (page faults of first allocations)
        times[name], cpu[name] = [], []
        for _ in range(args.repeats):
            start, start_cpu = time.perf_counter(), time.process_time()
            out = fn(inputs)
            times[name].append(time.perf_counter() - start)
            cpu[name].append(time.process_time() - start_cpu)
        if ref is None:
            ref = out
    lean_vs_literal = max(np.abs(a - b).max() for a, b in zip(out, ref))

    t32 = torch_inputs(inputs, torch.float32)
    variants = [("torch f32 eager", shading.shade_ggx)]
    compile_s = None
    if args.compile:
        compiled = torch.compile(shading.shade_ggx, dynamic=False)
        start = time.perf_counter()
        torch_step(compiled, t32)
        compile_s = time.perf_counter() - start
        variants.append(("torch f32 compiled", compiled))
    fwd_bwd: dict[str, tuple[float, float]] = {}
    outputs32 = {}
    for name, fn in variants:
        torch_step(fn, t32)
        runs, cpus = [], []
        for _ in range(args.repeats):
            start_cpu = time.process_time()
            runs.append(torch_step(fn, t32))
            cpus.append(time.process_time() - start_cpu)
        outputs32[name] = [o.detach().numpy()[0] for o in runs[-1][0]]
        times[name] = [f + b for _, f, b in runs]
        cpu[name] = cpus
        fwd_bwd[name] = (statistics.median(f for _, f, _ in runs), statistics.median(b for _, _, b in runs))
        no_grad = torch_inputs(inputs, torch.float32, False)
        times[name + " (forward only)"], cpu[name + " (forward only)"] = [], []
        with torch.no_grad():
            for _ in range(args.repeats):
                start_cpu = time.process_time()
                times[name + " (forward only)"].append(torch_step(fn, no_grad, False)[1])
                cpu[name + " (forward only)"].append(time.process_time() - start_cpu)

    t64 = torch_inputs(inputs, torch.float64)
    out64 = [o.detach().numpy()[0] for o in torch_step(shading.shade_ggx, t64, backward=False)[0]]
    err64 = _errors(out64, ref)
    err32 = _errors(outputs32["torch f32 eager"], ref)

    memory = {}
    for variant in ("numpy_literal", "numpy_lean", "torch"):
        proc = subprocess.run(
            [sys.executable, __file__, "--memory-variant", variant, "--size", str(args.size), "--lights", str(args.lights)],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        memory[variant] = json.loads(proc.stdout.strip().splitlines()[-1])
    load_end = os.getloadavg()

    mib = 2**20
    med = {k: statistics.median(v) for k, v in times.items()}
    med_cpu = {k: statistics.median(v) for k, v in cpu.items()}
    base, lean = med["numpy f64 literal"], med["numpy f64 lean"]
    print(f"load average at end {load_end[0]:.2f}; lean NumPy vs literal NumPy max |diff| {lean_vs_literal:.1e}")
    print("\n| variant | what is timed | wall s (median) | speed-up vs NumPy literal / lean | CPU s (median) | CPU-time ratio vs literal / lean | peak memory MiB |")
    print("|---|---|---|---|---|---|---|")
    rows = [
        ("numpy f64 literal", "forward", f"{memory['numpy_literal']['rss_growth'] / mib:.0f} (tracemalloc {memory['numpy_literal']['tracemalloc_peak'] / mib:.0f})"),
        ("numpy f64 lean", "forward", f"{memory['numpy_lean']['rss_growth'] / mib:.0f} (tracemalloc {memory['numpy_lean']['tracemalloc_peak'] / mib:.0f})"),
    ]  # fmt: skip
    for name, _ in variants:
        f, b = fwd_bwd[name]
        mem = f"{memory['torch']['rss_growth'] / mib:.0f}" if name.endswith("eager") else "-"
        rows.append((name, f"forward + backward (fwd {f:.3f} + bwd {b:.3f})", mem))
        rows.append((name + " (forward only)", "forward, no grad", "-"))
    for name, what, mem in rows:
        s, c = med[name], med_cpu[name]
        print(f"| {name} | {what} | {s:.3f} | {base / s:.1f}x / {lean / s:.1f}x | {c:.3f} | "
              f"{med_cpu['numpy f64 literal'] / c:.1f}x / {med_cpu['numpy f64 lean'] / c:.1f}x | {mem} |")  # fmt: skip
    if compile_s is not None:
        print(f"\ntorch.compile first call (compilation + one step): {compile_s:.1f} s")
    print("\nerror against the NumPy float64 literal evaluation (max |diff| / max |ref|; max relative where |ref| > 1e-3 max):")
    print("| output | torch f32: abs/scale | torch f32: rel | torch f64: abs/scale | torch f64: rel |")
    print("|---|---|---|---|---|")
    for name in FIELDS:
        print(f"| {name} | {err32[name][0]:.1e} | {err32[name][1]:.1e} | {err64[name][0]:.1e} | {err64[name][1]:.1e} |")


if __name__ == "__main__":
    main()
