"""REALY evaluation: time per subject of facegeo against the official REALY code, same inputs.

Builds synthetic REALY data sets (facegeo.eval.realy_synthetic: 3 subjects each, regions of
about 600-1600 vertices with ``--subdivisions 0`` and 2300-6200 with ``1``), times
``facegeo.eval.realy.evaluate`` with one worker (and with two), then runs the official code's
``main.py`` on the same folders as a subprocess and prints a Markdown table.

The official code is not part of facegeo. Point the benchmark at a checkout of
github czh-98/REALY and at a Python environment where it runs (NumPy < 2, trimesh 3.12, rtree,
scikit-sparse or a stand-in, opencv, tqdm) with ``--official-src`` / ``--official-python`` or
the environment variables REALY_OFFICIAL_SRC / REALY_OFFICIAL_PYTHON; without them that part is
skipped with a message. The official time per subject is (time of main.py on all subjects -
time to start Python and import main.py's modules) / subjects. The table also gives the time
facegeo spends in its sparse factorisations and solves, and the speed-up it would have if
everything else took no time: the ceiling that the sparse solver sets.

    python benchmarks/bench_realy.py [--subdivisions 0 1] [--subjects 3] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REGIONS = ("nose", "mouth", "forehead", "cheek")


def _official(src: Path, python: Path, data_root: Path, pred: Path, out: Path) -> tuple[float, float, dict]:
    """(seconds for all subjects, seconds to start and import, {subject: [4 values]})."""
    cmd = [str(python), str(src / "main.py"),
           "--REALY_HIFI3D_keypoints", "data/REALY_HIFI3D_keypoints", "--REALY_scan_region", "data/REALY_scan_region",
           "--prediction", str(pred), "--template_topology", "ICT-FaceKit",
           "--scale_path", "data/metrical_scale.txt", "--save", str(out)]
    start = time.perf_counter()
    subprocess.run(cmd, cwd=data_root, check=True, capture_output=True)
    total = time.perf_counter() - start
    imports = f"import sys; sys.path.insert(0, {str(src)!r}); import main"
    start = time.perf_counter()
    subprocess.run([str(python), "-c", imports], cwd=data_root, check=True, capture_output=True)
    startup = time.perf_counter() - start
    values = {}
    for line in (out / "REALY_error.txt").read_text().splitlines():
        fields = line.split("\t")
        values[fields[0]] = [float(x) for x in fields[2:]]
    return total, startup, values


def _best(times: list[float]) -> str:
    return f"{min(times):.2f}" if len(times) == 1 else f"{min(times):.2f} ({min(times):.2f}-{max(times):.2f})"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--subdivisions", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--subjects", type=int, default=3)
    parser.add_argument("--repeat", type=int, default=1, help="runs of each timing; the table gives the best and the range")
    parser.add_argument("--official-src", type=Path, default=Path(os.environ.get("REALY_OFFICIAL_SRC", "/tmp/realy_src")))
    parser.add_argument("--official-python", type=Path,
                        default=Path(os.environ.get("REALY_OFFICIAL_PYTHON", "/tmp/realy_env/bin/python")))
    args = parser.parse_args(argv)

    from facegeo.eval.realy import evaluate
    from facegeo.eval.realy_io import read_obj
    from facegeo.eval.realy_synthetic import make_dataset

    have_official = (args.official_src / "main.py").is_file() and args.official_python.is_file()
    if not have_official:
        print(f"note: official REALY code not found ({args.official_src}/main.py with {args.official_python}); "
              "timing facegeo only", file=sys.stderr)
    print(f"load average before: {os.getloadavg()[0]:.2f}; {os.cpu_count()} CPUs", file=sys.stderr)

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for sub in args.subdivisions:
            data = make_dataset(Path(tmp) / f"sub{sub}", args.subjects, seed=0, subdivisions=sub)
            sizes = [len(read_obj(p).vertices) for p in sorted((data.realy_root / "data" / "REALY_scan_region").rglob("*.obj"))]
            row = {"sub": sub, "vertices": f"{min(sizes)}-{max(sizes)}", "ours_1": [], "ours_2": [], "solve": [],
                   "official": []}
            for run in range(args.repeat):
                start = time.perf_counter()
                ours = evaluate(data.pred_dir, data.realy_root, workers=1, progress=False)
                row["ours_1"].append((time.perf_counter() - start) / args.subjects)
                row["solve"].append(sum(d[r]["solve_seconds"] for d in ours.details.values() for r in REGIONS)
                                    / args.subjects)
                start = time.perf_counter()
                evaluate(data.pred_dir, data.realy_root, workers=2, progress=False)
                row["ours_2"].append((time.perf_counter() - start) / args.subjects)
                if have_official:
                    total, startup, values = _official(args.official_src, args.official_python, data.realy_root,
                                                       data.pred_dir, Path(tmp) / f"official{sub}_{run}")
                    row["official"].append((total - startup) / args.subjects)
                    row["diff"] = max(abs(float(ours.text[k][r]) - v) / v
                                      for k, vals in values.items() for r, v in zip(REGIONS, vals))
            rows.append(row)
            print(f"done: subdivisions {sub}: {row}", file=sys.stderr)
    print(f"load average after: {os.getloadavg()[0]:.2f}", file=sys.stderr)

    print("| synthetic set | region vertices | official (s/subject) | facegeo, 1 worker (s/subject) | speed-up | "
          "of which sparse factorisations (s/subject) | speed-up if all else were free | "
          "facegeo, 2 workers (s/subject) | max rel. difference of REALY_error.txt |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        official = min(r["official"]) if r["official"] else None
        off = _best(r["official"]) if official else "n/a"
        speed = f"{official / min(r['ours_1']):.1f}x" if official else "n/a"
        ceiling = f"{official / min(r['solve']):.1f}x" if official else "n/a"
        diff = f"{r['diff']:.1e}" if "diff" in r else "n/a"
        print(f"| {args.subjects} subjects, subdivisions {r['sub']} | {r['vertices']} | {off} | {_best(r['ours_1'])} | "
              f"{speed} | {_best(r['solve'])} | {ceiling} | {_best(r['ours_2'])} | {diff} |")


if __name__ == "__main__":
    main()
