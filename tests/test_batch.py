"""Batch processing on a real Dask ``LocalCluster`` (2 worker processes, one thread each):
facegeo.batch and the batch forms of ``facegeo fit``."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("distributed")

from facegeo.batch import (FAILURES_FILE, ITEMS_FILE, SUMMARY_FILE, dask_client, expand_inputs, fit_many,
                           folder_names)
from facegeo.cli import main
from facegeo.errors import InputError
from facegeo.eval.realy import evaluate
from realy_synthetic import make_dataset  # tools/ (pytest pythonpath)
from facegeo.jobs import FIT_FILES, FitOptions, JobRecord, fit_into_folder
from facegeo.staged_output import MANIFEST, TEMP_PREFIX, StagedOutput

PHOTO = Path(__file__).resolve().parents[1] / "assets" / "photos" / "astronaut.png"
#: The environment's MALLOC_TRIM_THRESHOLD_ before any cluster started (a nanny sets its workers'
#: variables in the process that runs it).
TRIM_THRESHOLD_AT_START = os.environ.get("MALLOC_TRIM_THRESHOLD_")
FAST = FitOptions(photometric=False, landmarks="mediapipe")  # the quickest fit: no dlib to load per worker
ITEM_FILES = sorted([*FIT_FILES, MANIFEST])  # an item folder: the fit's files and the run's manifest


@pytest.fixture(scope="module")
def client():
    """One embedded cluster for the module: 2 processes, 1 thread each, one worker death allowed per task."""
    with dask_client(workers=2, allowed_failures=1) as c:
        c.wait_for_workers(2)
        yield c


@pytest.fixture
def own_client():
    """A cluster of its own for a test that kills workers: a nanny that cannot restart its worker
    on a loaded machine must not leave the other tests one worker short."""
    with dask_client(workers=2, allowed_failures=1) as c:
        c.wait_for_workers(2)
        yield c


@pytest.fixture(scope="module")
def photos(tmp_path_factory) -> Path:
    """The bundled photo flipped, scaled, rotated, as JPEG, in a sub-folder under the same name,
    plus two bad files: 8 good + 2 bad."""
    root = tmp_path_factory.mktemp("photos")
    im = Image.open(PHOTO).convert("RGB")
    im.save(root / "astronaut.png")
    im.transpose(Image.Transpose.FLIP_LEFT_RIGHT).save(root / "flipped.png")
    im.resize((384, 384), Image.Resampling.LANCZOS).save(root / "scaled.png")
    im.resize((700, 700), Image.Resampling.BICUBIC).save(root / "upscaled.png")
    im.rotate(10, resample=Image.Resampling.BICUBIC, fillcolor=(128, 128, 128)).save(root / "rotated.png")
    im.rotate(-90, expand=True).save(root / "quarter.png")
    im.save(root / "astronaut.jpg", quality=92)  # same stem as astronaut.png
    (root / "sub").mkdir()
    im.transpose(Image.Transpose.FLIP_LEFT_RIGHT).rotate(-8, resample=Image.Resampling.BICUBIC,
                                                         fillcolor=(90, 90, 90)).save(root / "sub" / "flipped.png")
    (root / "bad").mkdir()
    (root / "bad" / "text.png").write_bytes(b"this is not an image")
    data = (root / "astronaut.png").read_bytes()
    (root / "bad" / "truncated.png").write_bytes(data[: len(data) // 3])
    return root


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def _no_temporaries(out: Path) -> bool:
    return not list(out.rglob(f"{TEMP_PREFIX}*"))


# --------------------------------------------------------------------------------- pure parts
def test_embedded_workers_keep_glibcs_adaptive_trimming(client) -> None:
    """Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536; the embedded cluster's do not
    get it (a reconstruction spent 2.2-2.9 s of system time a photo under it), and keep the
    single-thread pools."""
    environ = client.run(lambda: {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS")})
    assert len(environ) == 2
    # (the nanny sets its variables in this process too, so the value to expect is the one from before any cluster)
    assert all(e == {"MALLOC_TRIM_THRESHOLD_": TRIM_THRESHOLD_AT_START, "OMP_NUM_THREADS": "1"} for e in environ.values())


def test_inputs_from_paths_folders_globs_and_manifests(photos: Path, tmp_path: Path) -> None:
    manifest = tmp_path / "list.txt"
    manifest.write_text(f"# two bad files\n\n{photos}/bad/text.png\n{os.path.relpath(photos / 'bad' / 'truncated.png', tmp_path)}\n")
    found = expand_inputs([photos, f"{photos}/sub/*.png", manifest, photos / "flipped.png"])
    names = [p.relative_to(photos).as_posix() for p in found]
    assert names == ["astronaut.jpg", "astronaut.png", "flipped.png", "quarter.png", "rotated.png", "scaled.png",
                     "upscaled.png", "sub/flipped.png", "bad/text.png", "bad/truncated.png"]  # each once, in order
    with pytest.raises(InputError, match="glob pattern"):
        expand_inputs([f"{photos}/*.tiff"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="input folder"):
        expand_inputs([tmp_path / "empty"])


def test_folder_names_resolve_collisions_and_keep_earlier_ones() -> None:
    photos = [Path("/a/face.jpg"), Path("/b/face.png"), Path("/c/FACE.png"), Path("/d/.hidden.png"), Path("/e/summary.csv.png")]
    names = folder_names(photos)
    assert [n for n, _ in names] == ["face", "face-2", "FACE-3", "_.hidden", "_summary.csv"]
    assert names[1][1] == "renamed from face: taken by /a/face.jpg" and names[0][1] == ""
    # an earlier batch's names win, whatever the order now
    again = folder_names([Path("/b/face.png"), Path("/z/face.png")], known={"/a/face.jpg": "face", "/b/face.png": "face-2"})
    assert [n for n, _ in again] == ["face-2", "face-3"]


def test_output_folder_rules(tmp_path: Path, photos: Path, capsys: pytest.CaptureFixture[str]) -> None:
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    code = main(["fit", str(photos / "bad"), "-o", str(foreign), "--workers", "1"])
    assert code == 2 and "output folder" in capsys.readouterr().err and (foreign / "notes.txt").read_text() == "mine"
    earlier = tmp_path / "earlier"
    earlier.mkdir()
    (earlier / ITEMS_FILE).write_text("photo,folder,note\n")
    code = main(["fit", str(photos / "bad"), "-o", str(earlier), "--workers", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "--resume" in err and err.count("\n") == 1
    code = main(["fit", str(photos / "bad"), "-o", str(photos), "--workers", "1"])
    assert code == 2 and "does not hold the input photos" in capsys.readouterr().err


# ------------------------------------------------------------------------------ on the cluster
def _fit_json(folder: Path) -> dict:
    return json.loads((folder / "fit.json").read_text())


def _same_fit(batch: Path, single: Path) -> None:
    a, b = _fit_json(batch), _fit_json(single)
    assert a["landmark_rms_px"] == pytest.approx(b["landmark_rms_px"], rel=1e-4, abs=1e-4)
    for key in ("identity", "expression", "rotation", "translation"):
        if key in a:
            np.testing.assert_allclose(np.asarray(a[key], float), np.asarray(b[key], float), rtol=1e-4, atol=1e-4)
    va = np.array([line.split()[1:] for line in (batch / "mesh.obj").read_text().splitlines() if line.startswith("v ")], float)
    vb = np.array([line.split()[1:] for line in (single / "mesh.obj").read_text().splitlines() if line.startswith("v ")], float)
    np.testing.assert_allclose(va, vb, atol=1e-3)  # mm


def test_cli_batch_equals_single_runs(client, photos: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    manifest = tmp_path / "bad.lst"
    manifest.write_text(f"{photos}/bad/text.png\n{photos}/bad/truncated.png\n")
    out = tmp_path / "out"
    code = main(["fit", str(photos), f"{photos}/sub/*.png", str(manifest), "-o", str(out), "--no-photometric",
                 "--landmarks", "mediapipe", "--scheduler", client.scheduler.address])
    captured = capsys.readouterr()
    assert code == 3, captured.err  # documented: some photos failed
    assert "10 photo(s)" in captured.out and "8 done" in captured.out and "2 failed" in captured.out
    assert captured.err.count("facegeo: failed:") == 2
    failures = _rows(out / FAILURES_FILE)
    assert sorted(Path(r["photo"]).name for r in failures) == ["text.png", "truncated.png"]
    assert all(r["error"] and "\n" not in r["error"] for r in failures)
    summary = {Path(r["photo"]).relative_to(photos).as_posix(): r for r in _rows(out / SUMMARY_FILE)}
    assert len(summary) == 10 and sum(r["status"] == "done" for r in summary.values()) == 8
    items = {Path(r["photo"]).relative_to(photos).as_posix(): r for r in _rows(out / ITEMS_FILE)}
    assert items["astronaut.jpg"]["folder"] == "astronaut" and items["astronaut.png"]["folder"] == "astronaut-2"
    assert items["sub/flipped.png"]["folder"] == "flipped-2" and "taken by" in items["sub/flipped.png"]["note"]
    for name, row in summary.items():
        if row["status"] == "done":
            assert 0 < float(row["landmark_rms_percent_iod"]) < 8 and float(row["seconds_total"]) > 0
            assert float(row["peak_memory_mib"]) > 50
            assert sorted(p.name for p in (out / items[name]["folder"]).iterdir()) == ITEM_FILES
    assert not (out / "text").exists() and _no_temporaries(out)
    # the same outputs as single runs, item by item (each photo fitted in this process)
    for name in ("rotated.png", "sub/flipped.png"):  # all of them: test_every_batch_item_equals_its_single_run
        fit_into_folder(photos / name, tmp_path / "single" / name.replace("/", "_"), FAST)
        _same_fit(out / items[name]["folder"], tmp_path / "single" / name.replace("/", "_"))


@pytest.mark.slow
def test_every_batch_item_equals_its_single_run(client, photos: Path, tmp_path: Path) -> None:
    records = fit_many([photos], tmp_path / "out", client, FAST)
    assert [r.status for r in records] == ["done"] * 7
    for record in records:
        fit_into_folder(record.photo, tmp_path / "single" / Path(record.output).name, FAST)
        _same_fit(Path(record.output), tmp_path / "single" / Path(record.output).name)


def test_files_sent_back_to_the_client(client, photos: Path, tmp_path: Path) -> None:
    records = fit_many([photos / "scaled.png"], tmp_path / "out", client, FAST, files="client")
    folder = Path(records[0].output)
    assert records[0].status == "done" and sorted(p.name for p in folder.iterdir()) == ITEM_FILES
    assert _fit_json(folder)["landmark_rms_px"] == pytest.approx(records[0].landmark_rms_px)
    assert records[0].job is not None and records[0].job.output == str(folder)


def _quick_job(marks: Path, pause: float = 0.0):
    """A job for the batch mechanics, no fitting: marks ``<stem>-<pid>`` in ``marks`` once inside
    its staged output folder, pauses there, writes fit.json and mesh.obj, marks ``done-<stem>``."""

    def job(photo, output, options):
        stem = Path(photo).stem
        with StagedOutput(output, replace=True) as stage:
            stage.path("fit.json").write_text(json.dumps({"photo": str(photo)}))
            (marks / f"{stem}-{os.getpid()}").touch()
            time.sleep(pause)
            stage.path("mesh.obj").write_text("v 0 0 0\n")
        (marks / f"done-{stem}").touch()
        return JobRecord(photo=str(photo), output=str(output), landmark_rms_px=1.0, landmark_rms_percent_iod=2.0,
                         timings={"total": pause}, files=["fit.json", "mesh.obj"])

    return job


def _started(marks: Path, stem: str) -> list[int]:
    return sorted(int(p.name.rsplit("-", 1)[1]) for p in marks.iterdir() if p.name.rsplit("-", 1)[0] == stem)


def test_worker_killed_mid_item_is_retried_elsewhere(own_client, tmp_path: Path) -> None:
    marks = tmp_path / "marks"
    marks.mkdir()
    killed: list[int] = []

    def kill_when_staging() -> None:  # SIGKILL the worker while b's files are half staged
        for _ in range(1200):
            if pids := _started(marks, "b"):
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])
                return
            time.sleep(0.02)

    killer = threading.Thread(target=kill_when_staging)
    killer.start()
    out = tmp_path / "out"
    records = fit_many([tmp_path / f"{n}.png" for n in "abc"], out, own_client, job=_quick_job(marks, pause=1.0))
    killer.join()
    assert killed and [r.status for r in records] == ["done"] * 3
    runs = _started(marks, "b")
    assert len(runs) == 2 and killed[0] in runs  # run again, by another process
    assert records[1].worker and all(sorted(p.name for p in (out / n).iterdir()) == [MANIFEST, "fit.json", "mesh.obj"]
                                     for n in "abc")
    assert _no_temporaries(out)  # the dead worker's staging folder is gone


def test_interrupted_batch_resumes_with_only_what_was_missing(client, tmp_path: Path) -> None:
    marks = tmp_path / "marks"
    marks.mkdir()
    inputs = [tmp_path / f"p{i}.png" for i in range(6)]
    out = tmp_path / "out"

    seen: dict[str, object] = {}

    def interrupt_after_two() -> None:  # Ctrl-C once two items are complete: a real SIGINT to this process
        while sum(p.name.startswith("done-") for p in marks.iterdir()) < 2:
            time.sleep(0.02)
        seen["handler"] = signal.getsignal(signal.SIGINT)
        seen["done"] = sorted(p.name for p in marks.iterdir() if p.name.startswith("done-"))
        os.kill(os.getpid(), signal.SIGINT)

    # Python's own SIGINT handler, also when this process was started with SIGINT ignored (as a
    # background job of a non-interactive shell is: then Python installs none)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        interrupter = threading.Thread(target=interrupt_after_two, daemon=True)
        interrupter.start()
        with pytest.raises(KeyboardInterrupt):
            records = fit_many(inputs, out, client, job=_quick_job(marks, pause=0.5))
            interrupter.join(timeout=5)
            pytest.fail(f"the batch ended before the interrupt: {[(r.status, r.error) for r in records]}, {seen}")
        interrupter.join()
    finally:
        signal.signal(signal.SIGINT, previous)
    deadline = time.monotonic() + 30  # cancelled jobs already running on the cluster still finish
    while any(not (marks / f"done-{p.stem}").exists() for p in inputs if _started(marks, p.stem)):
        assert time.monotonic() < deadline
        time.sleep(0.05)
    complete = {p.stem for p in inputs if (out / p.stem / "fit.json").is_file()}
    assert 2 <= len(complete) < len(inputs)
    assert {p.name for p in out.iterdir() if p.is_dir()} == complete  # only complete item folders
    assert {r["photo"] for r in _rows(out / SUMMARY_FILE)} <= {str(p) for p in inputs}
    with pytest.raises(InputError, match="--resume"):
        fit_many(inputs, out, client, job=_quick_job(marks))
    for p in marks.iterdir():
        p.unlink()
    records = fit_many(inputs, out, client, resume=True, job=_quick_job(marks))
    assert {Path(r.photo).stem for r in records if r.status == "skipped"} == complete
    assert {Path(r.photo).stem for r in records if r.status == "done"} == {p.stem for p in inputs} - complete
    assert {p.stem for p in inputs if _started(marks, p.stem)} == {p.stem for p in inputs} - complete
    assert [r["status"] for r in _rows(out / SUMMARY_FILE)] == [r.status for r in records]


#: A batch of one photo into OUT on a one-worker cluster of its own, whose job holds its item
#: folder's lock and waits for FLAG to go.
HELD_BATCH = """
import pathlib, sys, time
from facegeo.batch import fit_many
from facegeo.jobs import JobRecord
from facegeo.staged_output import StagedOutput, locked_output
out, flag, photo = sys.argv[1:4]
def job(photo, output, options):
    with locked_output(output):
        marker = pathlib.Path(flag)
        marker.write_text("inside")
        while marker.exists():
            time.sleep(0.05)
        with StagedOutput(output, replace=True) as stage:
            stage.path("fit.json").write_text("{}")
    return JobRecord(photo=photo, output=output, landmark_rms_px=1.0, landmark_rms_percent_iod=2.0, timings={}, files=["fit.json"])
records = fit_many([photo], out, workers=1, job=job)
sys.exit(0 if [r.status for r in records] == ["done"] else 1)
"""


def test_a_second_batch_or_a_run_into_an_item_is_refused_at_once(client, tmp_path: Path) -> None:
    out, flag = tmp_path / "out", tmp_path / "flag"
    batch = subprocess.Popen([sys.executable, "-c", HELD_BATCH, str(out), str(flag), str(tmp_path / "a.png")],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 180
        while not flag.exists() and batch.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert flag.exists(), batch.communicate()[1]
        start = time.monotonic()
        with pytest.raises(InputError, match=rf"no other facegeo run .* \(process {batch.pid}\)"):
            fit_many([tmp_path / "b.png"], out, client, job=_quick_job(tmp_path))
        with pytest.raises(InputError, match=r"out/a: output folder: expected no other facegeo run"):
            fit_into_folder(PHOTO, out / "a", FAST)  # the item the batch's worker is writing
        assert time.monotonic() - start < 10  # refused at once, nothing run
        flag.unlink()
        assert batch.wait(180) == 0, batch.communicate()[1]
    finally:
        if batch.poll() is None:  # pragma: no cover
            batch.kill()
        batch.communicate()
    assert sorted(p.name for p in out.iterdir()) == sorted(["a", FAILURES_FILE, ITEMS_FILE, SUMMARY_FILE])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no lock file left beside OUT


def test_photo_that_kills_every_worker_fails_after_bounded_tries(own_client, photos: Path, tmp_path: Path) -> None:
    tries = tmp_path / "tries"
    tries.mkdir()

    def crashing_fitter(photo, output, options):  # a fitter that ends its process on this one photo
        if Path(photo).name == "text.png":
            (tries / str(os.getpid())).touch()
            os._exit(1)
        return fit_into_folder(photo, output, options)

    records = fit_many([photos / "bad" / "text.png"], tmp_path / "out", own_client, FAST, job=crashing_fitter)
    assert records[0].status == "failed" and records[0].tries == 2
    assert "ended the worker process each of the 2 times" in records[0].error
    assert len(list(tries.iterdir())) == 2  # allowed_failures=1: two tries in two processes, not forever
    assert [r["photo"] for r in _rows(tmp_path / "out" / FAILURES_FILE)] == [str(photos / "bad" / "text.png")]


def test_realy_on_the_cluster_gives_the_single_process_numbers(client, tmp_path: Path) -> None:
    data = make_dataset(tmp_path, 1, seed=1, subdivisions=0)
    single = evaluate(data.pred_dir, data.realy_root)
    distributed = evaluate(data.pred_dir, data.realy_root, client=client)
    assert distributed.text == single.text and distributed.per_subject == single.per_subject
    assert main(["realy", str(data.pred_dir), "--realy-root", str(data.realy_root), "-o", str(tmp_path / "cli"),
                 "--scheduler", client.scheduler.address]) == 0
    assert (tmp_path / "cli" / "REALY_error.txt").read_text() == single.error_txt()


@pytest.mark.slow
def test_killed_worker_during_a_fit_is_retried_elsewhere(own_client, photos: Path, tmp_path: Path) -> None:
    marks = tmp_path / "marks"
    marks.mkdir()

    def slow_start(photo, output, options):  # runs on the workers: says where it runs, then works
        (marks / f"{Path(photo).stem}-{os.getpid()}").touch()
        time.sleep(2.0)
        return fit_into_folder(photo, output, options)

    killed: list[int] = []

    def kill_first_worker() -> None:
        for _ in range(600):
            started = [p for p in marks.iterdir() if p.name.startswith("rotated-")]
            if started:
                pid = int(started[0].name.split("-")[-1])
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_first_worker)
    killer.start()
    out = tmp_path / "out"
    records = fit_many([photos / "rotated.png", photos / "scaled.png"], out, own_client, FAST, job=slow_start)
    killer.join()
    assert killed, "the rotated photo never started"
    assert [r.status for r in records] == ["done", "done"]
    rotated = records[0]
    runs = sorted(p.name for p in marks.iterdir() if p.name.startswith("rotated-"))
    assert len(runs) == 2 and f"rotated-{killed[0]}" in runs  # started again, in another process
    assert rotated.worker and _fit_json(Path(rotated.output))["landmark_rms_px"] == pytest.approx(rotated.landmark_rms_px)
    assert sorted(p.name for p in Path(rotated.output).iterdir()) == ITEM_FILES
    assert _no_temporaries(out)



@pytest.mark.slow
def test_ctrl_c_on_the_command_then_resume(client, photos: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    inputs = [photos / "bad" / "text.png", photos / "scaled.png", photos / "flipped.png", photos / "quarter.png"]
    command = [sys.executable, "-m", "facegeo.cli", "fit", *map(str, inputs), "-o", str(out), "--no-photometric",
               "--workers", "1"]  # its own embedded cluster, stopped by the Ctrl-C
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 240
    while not any((out / n / "fit.json").is_file() for n in ("scaled", "flipped", "quarter")) and time.monotonic() < deadline:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the command and its workers
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    # one line: the workers ignore the terminal's SIGINT (batch.dask_setup); each used to die with a
    # KeyboardInterrupt traceback and the nanny's and the worker's error lines
    lines = err.strip().splitlines()  # text.png's failure, perhaps, and the interruption: nothing else
    assert lines[-1] == f"facegeo: interrupted (SIGINT); complete item folders kept in {out}, finish with --resume", err
    assert all(line.startswith(f"facegeo: failed: {inputs[0]}: ") for line in lines[:-1]), err
    complete = {n for n in ("scaled", "flipped", "quarter") if (out / n / "fit.json").is_file()}
    assert complete and all(sorted(p.name for p in (out / n).iterdir()) == ITEM_FILES for n in complete)
    assert {p.name for p in out.iterdir() if p.is_dir()} == complete and _no_temporaries(out)  # nothing half-written
    assert main(["fit", *map(str, inputs), "-o", str(out), "--no-photometric", "--scheduler", client.scheduler.address]) == 2
    code = main(["fit", *map(str, inputs), "-o", str(out), "--no-photometric", "--resume", "--scheduler", client.scheduler.address])
    assert code == 3  # text.png fails again
    summary = {Path(r["photo"]).stem: r["status"] for r in _rows(out / SUMMARY_FILE)}
    assert {n for n, s in summary.items() if s == "skipped"} == complete
    assert {n for n, s in summary.items() if s == "done"} == {"scaled", "flipped", "quarter"} - complete
    assert summary["text"] == "failed" and _no_temporaries(out)


