"""Batch throughput on an embedded Dask cluster: 1 against 2 worker processes in one run.

    python benchmarks/bench_batch.py [--items 12] [--rounds 2] [--kind fit|reconstruct]
                                     [--no-photometric] [--size 512] [--out /tmp/bench_batch]

Inputs: the bundled photo and matplotlib's Grace Hopper portrait, each as is, mirrored, scaled
to 80 % and rotated by 6° (8 photos, repeated to ``--items``). Per round and per worker count
(the order alternates between rounds, so that the neighbours' load hits both alike):

* start-up: ``LocalCluster`` + ``Client`` until every worker is up, then the first item of each
  worker (imports, model, landmark detectors: the once-per-worker cost), timed apart;
* steady state: ``fit_many`` / ``reconstruct_many`` of the ``--items`` photos on the warmed
  workers: wall time, items per minute, and the CPU seconds the worker processes used
  (``getrusage`` in each worker, before and after): CPU s per item and the cores the workers got;
* memory: each worker's resident set after the batch and the largest per-item peak (VmHWM).

Printed: one line per round and worker count, then min / median over the rounds and the
2-worker / 1-worker throughput ratio measured in the same run, and the ratio that the CPU-time
figures predict for an otherwise idle 2-core machine: 2 x (CPU s per item with 1 worker) /
(CPU s per item with 2 workers) — below 2 only by the per-item cost that running two workers
side by side adds (memory bandwidth, caches).
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path

from PIL import Image

from facegeo.batch import _run_item, dask_client, fit_many, reconstruct_many
from facegeo.jobs import FitOptions, ReconstructOptions, fit_into_folder, reconstruct_into_folder

ROOT = Path(__file__).resolve().parents[1]


def make_photos(folder: Path, n: int) -> list[Path]:
    import matplotlib.cbook

    sources = [ROOT / "assets" / "photos" / "astronaut.png", Path(matplotlib.cbook.get_sample_data("grace_hopper.jpg", asfileobj=False))]
    variants = []
    for src in sources:
        im = Image.open(src).convert("RGB")
        variants += [(f"{src.stem}", im), (f"{src.stem}_mirror", im.transpose(Image.Transpose.FLIP_LEFT_RIGHT)),
                     (f"{src.stem}_small", im.resize((im.width * 4 // 5, im.height * 4 // 5), Image.Resampling.LANCZOS)),
                     (f"{src.stem}_rot", im.rotate(6, resample=Image.Resampling.BICUBIC, fillcolor=(128, 128, 128)))]
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for i in range(n):
        name, im = variants[i % len(variants)]
        path = folder / f"{i:03d}_{name}.png"
        im.save(path)
        paths.append(path)
    return paths


def _cpu_seconds() -> float:
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def _rss_mib() -> float:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def one(workers: int, photos: list[Path], warm: list[Path], out: Path, kind: str, options) -> dict[str, float]:
    many = fit_many if kind == "fit" else reconstruct_many
    job = fit_into_folder if kind == "fit" else reconstruct_into_folder
    t0 = time.perf_counter()
    with dask_client(workers=workers) as client:
        client.wait_for_workers(workers)
        up = time.perf_counter() - t0
        t1 = time.perf_counter()
        # one item per worker, at once: each worker's imports, model and detectors
        futures = [client.submit(_run_item, job, str(p), str(out / f"warm{workers}_{i}"), options, False, pure=False,
                                 workers=[w]) for i, (p, w) in enumerate(zip(warm, client.scheduler_info()["workers"]))]
        assert all("record" in outcome for outcome in client.gather(futures))
        first = time.perf_counter() - t1
        cpu0 = sum(client.run(_cpu_seconds).values())
        t2 = time.perf_counter()
        records = many(photos, out / f"run{workers}", client, options)
        wall = time.perf_counter() - t2
        cpu = sum(client.run(_cpu_seconds).values()) - cpu0
        rss = max(client.run(_rss_mib).values())
    assert all(r.status == "done" for r in records), [r.error for r in records if r.status != "done"]
    peak = max(r.peak_memory_mib or 0.0 for r in records)
    return {"workers": workers, "startup_s": up, "first_item_s": first, "wall_s": wall,
            "items_per_min": 60.0 * len(photos) / wall, "cpu_s_per_item": cpu / len(photos), "cores_used": cpu / wall,
            "rss_mib": rss, "peak_item_mib": peak}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--items", type=int, default=12)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--kind", choices=["fit", "reconstruct"], default="fit")
    parser.add_argument("--no-photometric", action="store_true")
    parser.add_argument("--size", type=int, default=512, help="reconstruct: UV map size")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    options = (FitOptions(photometric=not args.no_photometric) if args.kind == "fit"
               else ReconstructOptions(size=args.size))
    base = args.out or Path(tempfile.mkdtemp(prefix="bench_batch_"))
    photos = make_photos(base / "photos", args.items)
    warm = make_photos(base / "warm", 2)
    print(f"# {args.kind} {options}\n# {args.items} items, {args.rounds} round(s); load average at start: "
          f"{os.getloadavg()}; {os.cpu_count()} CPUs", flush=True)
    rows: dict[int, list[dict[str, float]]] = {1: [], 2: []}
    for r in range(args.rounds):
        for workers in ((1, 2) if r % 2 == 0 else (2, 1)):
            row = one(workers, photos, warm, base / f"round{r}", args.kind, options)
            rows[workers].append(row)
            print(f"round {r} " + " ".join(f"{k}={v:.2f}" for k, v in row.items()), flush=True)
    print(f"# load average at end: {os.getloadavg()}")
    keys = ["startup_s", "first_item_s", "items_per_min", "cpu_s_per_item", "cores_used", "rss_mib", "peak_item_mib"]
    print("| workers | " + " | ".join(keys) + " |  (min / median over rounds)")
    for w in (1, 2):
        cells = [f"{min(x[k] for x in rows[w]):.2f} / {statistics.median(x[k] for x in rows[w]):.2f}" for k in keys]
        print(f"| {w} | " + " | ".join(cells) + " |")
    ratios = [b["items_per_min"] / a["items_per_min"] for a, b in zip(rows[1], rows[2])]
    cpu_ratio = [2.0 * a["cpu_s_per_item"] / b["cpu_s_per_item"] for a, b in zip(rows[1], rows[2])]
    print(f"throughput 2 workers / 1 worker, same round: {', '.join(f'{x:.2f}' for x in ratios)}; "
          f"from CPU s per item (idle 2-core machine): {', '.join(f'{x:.2f}' for x in cpu_ratio)}")


if __name__ == "__main__":
    sys.exit(main())
