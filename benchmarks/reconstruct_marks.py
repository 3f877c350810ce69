"""The critical path of one ``facegeo reconstruct`` drawn as marks: when each piece of work ends,
in seconds from this process's start, for the version installed where ``PYTHONPATH`` points
(``pip install --no-deps --target SITE .``, as ``bench_end_to_end.py`` does).

    PYTHONPATH=SITE python benchmarks/reconstruct_marks.py [--runs 3] [PHOTO]

Marks are taken by wrapping the job's own seams (the skin mask, the export job's start and
completion; the export's spans are its child's, on the same monotonic clock), so the job runs
as the command runs it (forked fit, forked export)."""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

START = time.perf_counter()


def one_run(photo: Path, output: Path) -> tuple[dict[str, float], dict[str, float]]:
    """(mark name -> seconds since this process started, the job's stage timings)."""
    import facegeo.export_job as export_job
    import facegeo.jobs as jobs

    marks: dict[str, float] = {}
    complete, begin, photo_skin = export_job.ExportJob.complete, export_job.ExportJob.__init__, jobs._photo_skin

    def completed(self, asset, beside):
        marks["maps handed over (export's 2nd half starts)"] = time.perf_counter()
        spans = complete(self, asset, beside)
        marks["export child: imports done, 1st half starts"] = spans["geometry"][0]
        labels = {"geometry": "export child: 1st half's geometry done", "preview views": "export child: preview views done (1st half)"}
        for name, (_, end) in spans.items():
            marks[labels.get(name, f"{name} written")] = end
        return spans

    def started(self, *args, **kwargs):
        marks["fit and parts ready: export child forked"] = time.perf_counter()
        begin(self, *args, **kwargs)

    def skin(*args):
        marks["model, photo: fit child forked"] = time.perf_counter()
        mask = photo_skin(*args)
        marks["skin mask done (parent)"] = time.perf_counter()
        return mask

    export_job.ExportJob.complete, export_job.ExportJob.__init__, jobs._photo_skin = completed, started, skin
    try:
        shutil.rmtree(output, ignore_errors=True)
        marks["imports done"] = time.perf_counter()
        record = jobs.reconstruct_into_folder(photo, output, jobs.ReconstructOptions(), fork=True)
        marks["all written and committed"] = time.perf_counter()
    finally:
        export_job.ExportJob.complete, export_job.ExportJob.__init__, jobs._photo_skin = complete, begin, photo_skin
    return {name: t - START for name, t in marks.items()}, record.timings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("photo", nargs="?", type=Path, default=Path(__file__).resolve().parents[1] / "assets" / "photos" / "astronaut.png")
    parser.add_argument("--runs", type=int, default=3, help="runs in this process (the first includes the imports)")
    args = parser.parse_args()
    import facegeo
    from facegeo.concurrency import one_blas_thread_by_default

    one_blas_thread_by_default()  # as the facegeo command does, before NumPy is imported
    print(f"facegeo from {Path(facegeo.__file__).parent}")
    with tempfile.TemporaryDirectory() as tmp:
        for run in range(args.runs):
            marks, timings = one_run(args.photo.resolve(), Path(tmp) / "out")
            print(f"run {run + 1}: " + " | ".join(f"{name} {t:.2f}" for name, t in sorted(marks.items(), key=lambda kv: kv[1])))
            print("   stages: " + ", ".join(f"{k} {v:.2f}" for k, v in timings.items()))
            global START
            START = time.perf_counter()


if __name__ == "__main__":
    main()
