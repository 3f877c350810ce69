"""The export and preview stages of ``facegeo reconstruct`` alone (issue 29): the job with the
pipeline's result given, so that two checkouts (or one with 1 and 2 export workers) can be
timed against each other on the same asset.

    python benchmarks/bench_export_stage.py make-fixture /tmp/fixture.pkl     # the pipeline once
    python benchmarks/bench_export_stage.py time /tmp/fixture.pkl --repeats 3 [--workers 1]

``make-fixture`` runs the pipeline on the bundled photo (default options) and pickles the photo,
the skin mask, the asset and the fit. ``time`` runs ``facegeo.jobs.reconstruct_into_folder``
with ``reconstruct_with_fit`` and ``skin_mask`` replaced by the pickled results: what remains is
reading the photo, the export and preview stages and the staged commit. One warm-up run, then
``--repeats`` runs, each printed as a JSON line (``wall`` and process ``cpu`` seconds; the job's
``export`` and ``preview`` timings). ``--workers``: the export stage's threads (checkouts that have
``facegeo.concurrency``). The script imports facegeo from wherever Python finds it, so the same
file times any checkout: alternate the checkouts in one shell loop and compare the ratios
(RESULTS.md, "Issue 29: export").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pickle
import sys
import tempfile
import time
from pathlib import Path


def make_fixture(path: Path) -> None:
    from facegeo.assets import asset_path
    from facegeo.fitting import fit
    from facegeo.jobs import ReconstructOptions, loaded_resources, photo_camera
    from facegeo.photo import load_photo
    from facegeo.pipeline import reconstruct_with_fit
    from facegeo.skin_mask import skin_mask

    options = ReconstructOptions()
    model, _ = loaded_resources(None, None, False, options.landmarks)
    photo = load_photo(asset_path("photos/astronaut.png"), max_side=options.max_side)
    skin = skin_mask(photo.image, source="astronaut.png")
    asset, result = reconstruct_with_fit(photo, model, size=options.size, maps=options.maps, detector=options.landmarks, skin=skin,
                                         camera=photo_camera(photo, None), fitter=fit)
    path.write_bytes(pickle.dumps((photo, skin, asset, result)))
    print(f"wrote {path}")


def time_stage(path: Path, repeats: int, workers: int | None) -> None:
    import facegeo.pipeline
    import facegeo.skin_mask
    from facegeo.assets import asset_path

    photo, skin, asset, result = pickle.loads(path.read_bytes())
    def reconstruct_with_fit(*args, geometry_ready=None, **kwargs):
        if geometry_ready is not None:  # the export job begins on the geometry, as in the pipeline
            geometry_ready(dataclasses.replace(asset, maps={}, constants={}, metadata={}))
        return asset, result

    facegeo.pipeline.reconstruct_with_fit = reconstruct_with_fit
    facegeo.skin_mask.skin_mask = lambda *args, **kwargs: skin
    if workers is not None:
        import facegeo.concurrency

        facegeo.concurrency.EXPORT_WORKERS = workers
    from facegeo.jobs import reconstruct_into_folder

    with tempfile.TemporaryDirectory() as tmp:
        reconstruct_into_folder(asset_path("photos/astronaut.png"), Path(tmp) / "warm-up")
        for k in range(repeats):
            start, cpu = time.perf_counter(), time.process_time()
            record = reconstruct_into_folder(asset_path("photos/astronaut.png"), Path(tmp) / f"run{k}")
            print(json.dumps({"wall": time.perf_counter() - start, "cpu": time.process_time() - cpu,
                              "export": record.timings.get("export"), "preview": record.timings.get("preview")}), flush=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("make-fixture").add_argument("fixture", type=Path)
    timing = sub.add_parser("time")
    timing.add_argument("fixture", type=Path)
    timing.add_argument("--repeats", type=int, default=3)
    timing.add_argument("--workers", type=int, default=None)
    args = parser.parse_args()
    if args.command == "make-fixture":
        make_fixture(args.fixture)
    else:
        time_stage(args.fixture, args.repeats, args.workers)
    return 0


if __name__ == "__main__":
    sys.exit(main())
