"""REALY evaluation: time per subject of facegeo against the official REALY code, same inputs.

Builds synthetic REALY data sets (tools/realy_synthetic.py: 3 subjects each, regions of
about 600-1600 vertices with ``--subdivisions 0`` and 2300-6200 with ``1``) and, in one run so
that the machine's load is shared alike:

* times ``facegeo.eval.realy.evaluate`` with one worker and with ``--workers`` (default 2), and
  splits facegeo's time per subject into sparse factorisations, solves (triangular solves and
  conjugate gradients), closest-point queries on the prediction, the re-runs of turned decisions
  (the uncertainty) and the rest; a summary table gives per set the official and facegeo CPU
  time, the part following decisions, both wall times and the speed-up with the workers;
* with ``--baseline-eval DIR`` (an older ``eval/`` folder, e.g. ``git archive <commit> eval``
  unpacked), the same split for that code, run in a child process in which ``facegeo.eval`` is
  that folder (its factorisations, solves and queries timed by wrapping them);
* runs the official code's ``main.py`` on the same folders (``--official-src`` /
  ``--official-python`` or the environment variables REALY_OFFICIAL_SRC /
  REALY_OFFICIAL_PYTHON: a checkout of github czh-98/REALY and a Python with NumPy < 2,
  trimesh 3.12, rtree, scikit-sparse, opencv, tqdm; skipped with a message without them); its
  time per subject is (time of main.py on all subjects - time to start Python and import
  main.py's modules) / subjects, and the largest relative difference of REALY_error.txt is given
  with the largest numerical uncertainty facegeo reports;
* with ``--knobs``, instead, the error against time of the speed knobs and of the SuperLU
  solver (facegeo.eval.realy_settings.Settings) on the first set: the largest and mean relative
  deviation from the exact numbers and the time per subject of each setting, as a table and a
  text plot;
* with ``--compare-seeds A-B``, instead, facegeo against the official code value by value on
  the sets of seeds A..B (each set once, no timing): the relative difference of every value of
  REALY_error.txt, whether it lies within facegeo's reported uncertainty, and how many values
  are flagged (``--keep DIR`` keeps the sets and the official outputs, and reuses them);
* with ``--perturb A-B``, instead, a test of the reported uncertainty against other
  implementations' round-off, without the official code: each set evaluated ``--runs`` times
  with the non-rigid ICP's vertices nudged by ``--noise`` (relative, per coordinate) after every
  step, each value against the plain one and its uncertainty.

facegeo runs with its default solver (CHOLMOD when CVXOPT is installed; the table names it).

Every timing is repeated ``--repeat`` times; the tables give the minimum and the median. Wall
times count the machine's other load; CPU times (facegeo's own process with one worker, the
official process's user + system time, the split from facegeo's ``details``) much less.

    python benchmarks/bench_realy.py [--subdivisions 0 1] [--subjects 3] [--seed 0] [--repeat 3] [--workers 2]
                                     [--baseline-eval DIR] [--knobs | --compare-seeds A-B [--keep DIR]
                                     | --perturb A-B [--runs 4] [--noise 2**-23]] [--topology NAME]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REGIONS = ("nose", "mouth", "forehead", "cheek")

#: the knob settings of ``--knobs`` (name, Settings keyword arguments)
KNOBS = (
    ("exact (default: CHOLMOD every step)", {}),
    ("exact, turned decisions not followed", {"follow_decisions": False}),
    ("SuperLU, factor reuse", {"solver": "superlu"}),
    ("SuperLU, no factor reuse", {"solver": "superlu", "factor_reuse": False}),
    ("SuperLU, reuse, rtol 1e-6", {"solver": "superlu", "solver_rtol": 1e-6}),
    ("SuperLU, reuse, rtol 1e-3", {"solver": "superlu", "solver_rtol": 1e-3}),
    ("nicp epsilon x4", {"nicp_epsilon_scale": 4.0}),
    ("nicp epsilon x16", {"nicp_epsilon_scale": 16.0}),
    ("nicp max 4 steps / stage", {"nicp_max_steps": 4}),
    ("nicp max 2 steps / stage", {"nicp_max_steps": 2}),
    ("rigid tol 1e-4", {"rigid_tolerance": 1e-4}),
    ("rigid max 5 updates", {"rigid_max_updates": 5}),
    ("all fast: rigid 1e-4, eps x4, 4 steps", {"rigid_tolerance": 1e-4, "nicp_epsilon_scale": 4.0, "nicp_max_steps": 4}),
)


def _children_cpu() -> float:
    """CPU seconds (user + system) of this process's finished child processes."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _official(src: Path, python: Path, data_root: Path, pred: Path, out: Path,
              topology: str = "ICT-FaceKit") -> tuple[float, float, dict]:
    """(wall seconds for all subjects, CPU seconds for all subjects, {subject: [4 values]}), both
    less the time to start Python and import main.py's modules."""
    cmd = [str(python), str(src / "main.py"),
           "--REALY_HIFI3D_keypoints", "data/REALY_HIFI3D_keypoints", "--REALY_scan_region", "data/REALY_scan_region",
           "--prediction", str(pred), "--template_topology", topology,
           "--scale_path", "data/metrical_scale.txt", "--save", str(out)]
    cpu = _children_cpu()
    start = time.perf_counter()
    subprocess.run(cmd, cwd=data_root, check=True, capture_output=True)
    total = time.perf_counter() - start
    total_cpu = _children_cpu() - cpu
    imports = f"import sys; sys.path.insert(0, {str(src)!r}); import main"
    cpu = _children_cpu()
    start = time.perf_counter()
    subprocess.run([str(python), "-c", imports], cwd=data_root, check=True, capture_output=True)
    startup = time.perf_counter() - start
    startup_cpu = _children_cpu() - cpu
    return total - startup, total_cpu - startup_cpu, _official_values(out / "REALY_error.txt")


def _official_values(path: Path) -> dict[str, list[float]]:
    """{subject: [nose, mouth, forehead, cheek]} from an official REALY_error.txt."""
    values = {}
    for line in path.read_text().splitlines():
        fields = line.split("\t")
        values[fields[0]] = [float(x) for x in fields[2:]]
    return values


def _compare_seeds(args: argparse.Namespace, seeds: list[int], have_official: bool) -> None:
    """``--compare-seeds``: facegeo against the official code, value by value, on synthetic sets of
    many seeds: the relative difference of each REALY_error.txt value and facegeo's reported
    uncertainty, whether every difference is within it, and how many values are flagged. With
    ``--keep DIR`` the data sets and the official outputs stay in DIR and are reused."""
    from facegeo.eval.realy import UNCERTAINTY_FLAG, evaluate
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from realy_synthetic import make_dataset

    if not have_official:
        raise SystemExit("--compare-seeds needs the official code (--official-src, --official-python)")
    keep = args.keep or Path(tempfile.mkdtemp(prefix="bench_realy_"))
    load_before = os.getloadavg()
    rows, cpu, cpu_uncertainty = [], 0.0, 0.0
    print("| set | seed | values | max rel. difference (where) | differences > 1e-6 | of them within the uncertainty | "
          "flagged (> 1e-6) | largest uncertainty |")
    print("|---|---:|---:|---|---:|---:|---:|---:|")
    for sub in args.subdivisions:
        for seed in seeds:
            base = keep / f"s{seed}_d{sub}_{args.topology}"
            if not (base / "pred").is_dir():
                make_dataset(base, args.subjects, seed=seed, subdivisions=sub, topology=args.topology)
            ours = evaluate(base / "pred", base / "realy", topology=args.topology, workers=args.workers)
            cpu += sum(ours.seconds.values())
            cpu_uncertainty += sum(d[r]["rerun_seconds"] for d in ours.details.values() for r in REGIONS)
            official = base / "official" / "REALY_error.txt"
            if not official.is_file():
                _official(args.official_src, args.official_python, base / "realy", base / "pred", base / "official",
                          args.topology)
            here = []
            for name, values in _official_values(official).items():
                for region, theirs in zip(REGIONS, values):
                    diff = abs(float(ours.text[name][region]) - theirs) / theirs
                    here.append({"set": sub, "seed": seed, "subject": name, "region": region, "diff": diff,
                                 "uncertainty": ours.uncertainty[name][region], "official": theirs,
                                 "facegeo": ours.per_subject[name][region]})
            rows += here
            worst = max(here, key=lambda r: r["diff"])
            big = [r for r in here if r["diff"] > 1e-6]
            covered = sum(r["diff"] <= max(r["uncertainty"], 1e-6) for r in big)
            print(f"| subdivisions {sub} | {seed} | {len(here)} | {worst['diff']:.1e} (subject {worst['subject']} "
                  f"{worst['region']}) | {len(big)} | {covered} | {sum(r['uncertainty'] > UNCERTAINTY_FLAG for r in here)} | "
                  f"{max(r['uncertainty'] for r in here):.1e} |", flush=True)
    load_after = os.getloadavg()
    big = [r for r in rows if r["diff"] > 1e-6]
    uncovered = [r for r in big if r["diff"] > max(r["uncertainty"], 1e-6)]
    flagged = [r for r in rows if r["uncertainty"] > UNCERTAINTY_FLAG]
    print(f"\n{len(rows)} values on {len(seeds)} seed(s) x {len(args.subdivisions)} set(s); largest relative difference "
          f"{max(r['diff'] for r in rows):.1e}; {len(big)} differences above 1e-6 ({sum(r['diff'] > 1e-5 for r in rows)} "
          f"above 1e-5), {len(uncovered)} of them outside the reported uncertainty; {len(flagged)} values flagged "
          f"({len(flagged) / len(rows):.0%}). facegeo CPU {cpu:.1f} s, of which {cpu_uncertainty:.1f} s following "
          f"turned decisions. Load average before {load_before[0]:.2f}, after {load_after[0]:.2f}.")
    for r in sorted(big, key=lambda r: -r["diff"]):
        print(f"  set {r['set']} seed {r['seed']} subject {r['subject']} {r['region']}: official {r['official']:.7f}, "
              f"facegeo {r['facegeo']:.7f}, difference {r['diff']:.1e}, uncertainty {r['uncertainty']:.1e}")


def _perturbed(args: argparse.Namespace, seeds: list[int]) -> None:
    """``--perturb A-B``: a test of the reported uncertainty against other implementations'
    round-off. Each set is evaluated once as it is, then ``--runs`` times with the deformed
    vertices of every non-rigid ICP step nudged by uniform relative noise of ``--noise`` per
    coordinate (another correct implementation's rounding: float32 roundings of the vertices are
    2**-24); each perturbed value is compared with the plain one and its uncertainty."""
    import numpy as np

    from facegeo.eval import realy_error
    from facegeo.eval.realy import UNCERTAINTY_FLAG, evaluate
    from facegeo.eval.realy_settings import Settings
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from realy_synthetic import make_dataset

    plain_step = realy_error.NonRigidICP._step
    rng = np.random.default_rng(0)

    def nudged(self, *a, **k):
        x, x_perm, new, near = plain_step(self, *a, **k)
        return x, x_perm, new * (1.0 + args.noise * rng.uniform(-1.0, 1.0, size=new.shape)), near

    keep = args.keep or Path(tempfile.mkdtemp(prefix="bench_realy_"))
    rows = []
    print(f"| set | seed | values | runs | largest change (where, its uncertainty) | changes > 1e-6 | of them within the uncertainty |")
    print("|---|---:|---:|---:|---|---:|---:|")
    for sub in args.subdivisions:
        for seed in seeds:
            base = keep / f"s{seed}_d{sub}_{args.topology}"
            if not (base / "pred").is_dir():
                make_dataset(base, args.subjects, seed=seed, subdivisions=sub, topology=args.topology)
            plain = evaluate(base / "pred", base / "realy", topology=args.topology, workers=1)
            here = []
            realy_error.NonRigidICP._step = nudged
            try:
                for _ in range(args.runs):
                    other = evaluate(base / "pred", base / "realy", topology=args.topology, workers=1,
                                     settings=Settings(follow_decisions=False))
                    for name, values in other.per_subject.items():
                        for region, value in values.items():
                            a = plain.per_subject[name][region]
                            here.append({"set": sub, "seed": seed, "subject": name, "region": region,
                                         "change": abs(value - a) / a, "uncertainty": plain.uncertainty[name][region]})
            finally:
                realy_error.NonRigidICP._step = plain_step
            rows += here
            worst = max(here, key=lambda r: r["change"])
            big = [r for r in here if r["change"] > UNCERTAINTY_FLAG]
            print(f"| subdivisions {sub} | {seed} | {len(plain.per_subject) * 4} | {args.runs} | {worst['change']:.1e} (subject "
                  f"{worst['subject']} {worst['region']}, {worst['uncertainty']:.1e}) | {len(big)} | "
                  f"{sum(r['change'] <= max(r['uncertainty'], UNCERTAINTY_FLAG) for r in big)} |", flush=True)
    big = [r for r in rows if r["change"] > UNCERTAINTY_FLAG]
    outside = [r for r in big if r["change"] > max(r["uncertainty"], UNCERTAINTY_FLAG)]
    print(f"\n{len(rows)} perturbed values (noise {args.noise:.2g}); largest change {max(r['change'] for r in rows):.1e}; "
          f"{len(big)} changes above 1e-6 ({sum(r['change'] > 1e-5 for r in rows)} above 1e-5), {len(outside)} of them "
          "outside the reported uncertainty")
    for r in sorted(outside, key=lambda r: -r["change"])[:20]:
        print(f"  outside: set {r['set']} seed {r['seed']} subject {r['subject']} {r['region']}: change {r['change']:.1e}, "
              f"uncertainty {r['uncertainty']:.1e}")


def _split(result, subjects: int) -> dict[str, float]:
    """Seconds per subject: factorisations, solves, closest points, the uncertainty's re-runs of
    turned decisions, rest, total (processing)."""
    details = [d[r] for d in result.details.values() for r in REGIONS]
    row = {"factor": sum(d["factor_seconds"] for d in details) / subjects,
           "solve": sum(d["solve_seconds"] for d in details) / subjects,
           "closest": sum(d["closest_seconds"] for d in details) / subjects,
           "uncertainty": sum(d.get("rerun_seconds", 0.0) for d in details) / subjects,
           "total": sum(result.seconds.values()) / subjects}
    row["rest"] = row["total"] - row["factor"] - row["solve"] - row["closest"] - row["uncertainty"]
    return row


def _baseline_child(eval_dir: str, pred: str, realy_root: str) -> None:
    """Child-process mode: evaluate with an older facegeo.eval, print the split as JSON."""
    import facegeo.eval

    facegeo.eval.__path__[:] = [eval_dir]
    import scipy.sparse.linalg as sla
    from threadpoolctl import threadpool_limits

    from facegeo.eval import realy_geometry
    from facegeo.eval.realy import evaluate

    threadpool_limits(1)
    acc = {"factor": 0.0, "solve": 0.0, "closest": 0.0}
    splu = sla.splu

    class Timed:
        def __init__(self, lu):
            self.lu = lu

        def solve(self, b):
            start = time.process_time()
            x = self.lu.solve(b)
            acc["solve"] += time.process_time() - start
            return x

    def timed_splu(*args, **kwargs):
        start = time.process_time()
        lu = splu(*args, **kwargs)
        acc["factor"] += time.process_time() - start
        return Timed(lu)

    sla.splu = timed_splu
    call = realy_geometry.SurfaceQuery.__call__

    def timed_call(self, vertices, queries, *args, **kwargs):
        start = time.process_time()
        out = call(self, vertices, queries, *args, **kwargs)
        acc["closest"] += time.process_time() - start
        return out

    realy_geometry.SurfaceQuery.__call__ = timed_call
    start = time.process_time()
    result = evaluate(pred, realy_root, workers=1)
    acc["total"] = time.process_time() - start
    acc["values"] = result.per_subject
    print(json.dumps(acc))


def _baseline(eval_dir: Path, pred: Path, realy_root: Path, subjects: int) -> tuple[dict[str, float], dict]:
    out = subprocess.run([sys.executable, __file__, "--_baseline-child", str(eval_dir), str(pred), str(realy_root)],
                         check=True, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    acc = json.loads(out.stdout.strip().splitlines()[-1])
    row = {k: acc[k] / subjects for k in ("factor", "solve", "closest", "total")}
    row["uncertainty"] = 0.0
    row["rest"] = row["total"] - row["factor"] - row["solve"] - row["closest"]
    return row, acc["values"]


def _stats(times: list[float]) -> str:
    if not times:
        return "n/a"
    if len(times) == 1:
        return f"{times[0]:.2f}"
    return f"{min(times):.2f} / {statistics.median(times):.2f}"


def _split_cells(rows: list[dict[str, float]]) -> str:
    best = min(rows, key=lambda r: r["total"])
    cells = [f"{best[k]:.2f}" for k in ("factor", "solve", "closest", "uncertainty", "rest", "total")]
    return " | ".join(cells + [f"{best['closest'] + best['rest']:.2f}"])


def _deviation(values: dict, exact: dict) -> tuple[float, float]:
    devs = [abs(values[n][r] - exact[n][r]) / exact[n][r] for n in exact for r in REGIONS]
    return max(devs), sum(devs) / len(devs)


def _text_plot(points: list[tuple[str, float, float]], width: int = 60, height: int = 16) -> str:
    """A scatter plot in text: x = seconds per subject, y = log10 of the largest deviation."""
    floor = 1e-12
    xs = [p[1] for p in points]
    ys = [math.log10(max(p[2], floor)) for p in points]
    x0, x1 = 0.0, max(xs) * 1.05
    y0, y1 = math.floor(min(ys)), math.ceil(max(ys)) if max(ys) > math.floor(min(ys)) else math.floor(min(ys)) + 1
    grid = [[" "] * width for _ in range(height)]
    for k, (x, y) in enumerate(zip(xs, ys)):
        col = min(width - 1, int((x - x0) / (x1 - x0) * (width - 1)))
        row = min(height - 1, int((y1 - y) / (y1 - y0) * (height - 1)))
        grid[row][col] = chr(ord("A") + k)
    lines = []
    for r, cells in enumerate(grid):
        label = y1 - r * (y1 - y0) / (height - 1)
        lines.append(f"1e{label:+5.1f} |" + "".join(cells))
    lines.append(" " * 8 + "+" + "-" * width)
    lines.append(" " * 9 + f"0 s{'':{width - 16}}{x1:.2f} s/subject")
    legend = [f"{chr(ord('A') + k)}: {name}" for k, (name, _, _) in enumerate(points)]
    return "\n".join(lines + legend) + f"\n(deviations below {floor:g} drawn at {floor:g})"


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--_baseline-child"]:
        _baseline_child(*argv[1:4])
        return
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--subdivisions", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--subjects", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic data sets")
    parser.add_argument("--repeat", type=int, default=1, help="runs of each timing; the tables give min / median")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--baseline-eval", type=Path, default=None, metavar="DIR",
                        help="an older eval/ folder to split the time of, for comparison")
    parser.add_argument("--knobs", action="store_true",
                        help="instead: the error against time of the speed knobs, on the first set")
    parser.add_argument("--compare-seeds", default=None, metavar="A-B",
                        help="instead: facegeo against the official code value by value on the sets of seeds A..B")
    parser.add_argument("--perturb", default=None, metavar="A-B",
                        help="instead: --runs evaluations of the sets of seeds A..B with the non-rigid ICP's vertices "
                        "nudged by --noise after every step, each value against the plain one and its uncertainty")
    parser.add_argument("--runs", type=int, default=4, help="with --perturb: perturbed evaluations per set")
    parser.add_argument("--noise", type=float, default=2.0 ** -23, help="with --perturb: relative noise per coordinate")
    parser.add_argument("--topology", default="ICT-FaceKit", help="topology name the data sets are written under")
    parser.add_argument("--keep", type=Path, default=None, metavar="DIR",
                        help="with --compare-seeds: keep (and reuse) the data sets and official outputs in DIR")
    parser.add_argument("--official-src", type=Path, default=Path(os.environ.get("REALY_OFFICIAL_SRC", "/tmp/realy_src")))
    parser.add_argument("--official-python", type=Path,
                        default=Path(os.environ.get("REALY_OFFICIAL_PYTHON", "/tmp/realy_env/bin/python")))
    args = parser.parse_args(argv)

    from threadpoolctl import threadpool_limits

    from facegeo.eval.realy import evaluate
    from facegeo.eval.realy_settings import Settings
    from facegeo.eval.realy_io import read_obj
    from facegeo.eval.realy_solver import cholmod_available
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from realy_synthetic import make_dataset

    cholmod_available()  # CVXOPT's BLAS is loaded first, so that the limit reaches it too
    threadpool_limits(1)  # one core per worker, in the 1-worker run too
    have_official = (args.official_src / "main.py").is_file() and args.official_python.is_file()
    if not have_official:
        print(f"note: official REALY code not found ({args.official_src}/main.py with {args.official_python}); "
              "timing facegeo only", file=sys.stderr)
    if args.perturb:
        first, _, last = args.perturb.partition("-")
        _perturbed(args, list(range(int(first), int(last or first) + 1)))
        return
    if args.compare_seeds:
        first, _, last = args.compare_seeds.partition("-")
        _compare_seeds(args, list(range(int(first), int(last or first) + 1)), have_official)
        return
    load_before = os.getloadavg()
    n = args.subjects
    rows = []
    knob_rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for index, sub in enumerate(args.subdivisions):
            data = make_dataset(Path(tmp) / f"sub{sub}", n, seed=args.seed, subdivisions=sub)
            sizes = [len(read_obj(p).vertices) for p in sorted((data.realy_root / "data" / "REALY_scan_region").rglob("*.obj"))]
            row = {"sub": sub, "vertices": f"{min(sizes)}-{max(sizes)}", "one": [], "many": [], "split": [],
                   "base": [], "base_split": [], "official": [], "diff": 0.0, "unc": 0.0, "loads": [],
                   "one_cpu": [], "official_cpu": []}
            for run in range(0 if args.knobs else args.repeat):
                row["loads"].append(os.getloadavg()[0])
                cpu = time.process_time()
                ours = evaluate(data.pred_dir, data.realy_root, workers=1)
                row["one_cpu"].append((time.process_time() - cpu) / n)
                row["one"].append(ours.wall_seconds / n)
                row["split"].append(_split(ours, n))
                row["solver"] = ours.settings.solver
                many = evaluate(data.pred_dir, data.realy_root, workers=args.workers)
                row["many"].append(many.wall_seconds / n)
                assert many.per_subject == ours.per_subject, "the numbers depend on the number of workers"
                row["unc"] = max(u for d in ours.uncertainty.values() for u in d.values())
                if args.baseline_eval is not None:
                    split, _ = _baseline(args.baseline_eval, data.pred_dir, data.realy_root, n)
                    row["base"].append(split["total"])
                    row["base_split"].append(split)
                if have_official:
                    wall, cpu, values = _official(args.official_src, args.official_python, data.realy_root,
                                                  data.pred_dir, Path(tmp) / f"official{sub}_{run}")
                    row["official"].append(wall / n)
                    row["official_cpu"].append(cpu / n)
                    row["diff"] = max(abs(float(ours.text[k][r]) - v) / v
                                      for k, vals in values.items() for r, v in zip(REGIONS, vals))
                    row["diff_full"] = ours.per_subject
            if not args.knobs:
                rows.append(row)
                print(f"done: subdivisions {sub}: {json.dumps(row, default=str)[:2000]}", file=sys.stderr)
            if args.knobs and index == 0:
                exact = None
                for name, kwargs in KNOBS:
                    times = []
                    for _ in range(args.repeat):
                        res = evaluate(data.pred_dir, data.realy_root, workers=1, settings=Settings(**kwargs))
                        times.append(res.wall_seconds / n)
                    if exact is None:
                        exact = res.per_subject
                    solves = sum(d[r]["solves"] for d in res.details.values() for r in REGIONS) / n
                    factors = sum(d[r]["factorisations"] for d in res.details.values() for r in REGIONS) / n
                    knob_rows.append((name, times, *_deviation(res.per_subject, exact), solves, factors))
                    print(f"knob {name}: {knob_rows[-1]}", file=sys.stderr)
    load_after = os.getloadavg()

    print(f"load average (1, 5, 15 min) before: {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}; "
          f"after: {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}; {os.cpu_count()} CPUs; "
          f"{args.repeat} run(s) of each timing, cells min / median\n")
    if not rows:
        _print_knobs(args, knob_rows)
        return
    print("\nCPU time per subject (s; wall time also counts the machine's other load), "
          "1 worker, min / median:\n")
    print("| synthetic set | official | facegeo | ratio (min / min) |")
    print("|---|---:|---:|---:|")
    for r in rows:
        ratio = f"{min(r['official_cpu']) / min(r['one_cpu']):.1f}x" if r["official_cpu"] else "n/a"
        print(f"| subdivisions {r['sub']} | {_stats(r['official_cpu'])} | {_stats(r['one_cpu'])} | {ratio} |")
    print("\nWall time per subject (s), min / median:\n")
    print(f"| synthetic set | region vertices | official (s/subject) | facegeo, 1 worker | facegeo, {args.workers} workers | "
          f"speed-up, 1 worker | speed-up, {args.workers} workers | max rel. diff of REALY_error.txt | "
          "largest reported uncertainty |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        official = min(r["official"]) if r["official"] else None
        one = f"{official / min(r['one']):.1f}x" if official else "n/a"
        many = f"{official / min(r['many']):.1f}x" if official else "n/a"
        diff = f"{r['diff']:.1e}" if r["official"] else "n/a"
        print(f"| {n} subjects, subdivisions {r['sub']} | {r['vertices']} | {_stats(r['official'])} | {_stats(r['one'])} | "
              f"{_stats(r['many'])} | {one} | {many} | {diff} | {r['unc']:.1e} |")
    print("\nSummary, per subject, min / median (CPU: 1 worker; of which following decisions: the fastest run's "
          "re-runs of turned decisions; speed-up: official wall / facegeo wall, min / min):\n")
    print(f"| synthetic set | official, CPU s | facegeo, CPU s | of which following decisions | official, wall s | "
          f"facegeo, {args.workers} workers, wall s | speed-up, {args.workers} workers |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        follow = min(r["split"], key=lambda x: x["total"])["uncertainty"]
        many = f"{min(r['official']) / min(r['many']):.1f}x" if r["official"] else "n/a"
        print(f"| subdivisions {r['sub']} ({r['vertices']} vertices) | {_stats(r['official_cpu'])} | {_stats(r['one_cpu'])} | "
              f"{follow:.2f} | {_stats(r['official'])} | {_stats(r['many'])} | {many} |")
    print("\nPer subject, 1 worker, fastest run (CPU s): factorisations | solves (of the run itself) | closest points"
          " | uncertainty (re-runs of turned decisions) | rest | total | outside the solver (closest points + rest)\n")
    print("| synthetic set | code | factorisations | solves | closest points | uncertainty | rest | total | outside the solver |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        if r["base_split"]:
            print(f"| subdivisions {r['sub']} | before ({args.baseline_eval}) | {_split_cells(r['base_split'])} |")
        print(f"| subdivisions {r['sub']} | now ({r['solver']}) | {_split_cells(r['split'])} |")



def _print_knobs(args, knob_rows) -> None:
    if knob_rows:
        print(f"\nSpeed knobs, subdivisions {args.subdivisions[0]}, 1 worker: deviation from the exact numbers "
              "(relative, over all values) against time\n")
        print("| setting | s/subject (min / median) | max deviation | mean deviation | solves / subject | "
              "factorisations / subject |")
        print("|---|---:|---:|---:|---:|---:|")
        for name, times, worst, mean, solves, factors in knob_rows:
            print(f"| {name} | {_stats(times)} | {worst:.1e} | {mean:.1e} | {solves:.0f} | {factors:.0f} |")
        print("\n```text")
        print(_text_plot([(name, min(times), worst) for name, times, worst, _, _, _ in knob_rows]))
        print("```")


if __name__ == "__main__":
    main()
