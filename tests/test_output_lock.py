"""facegeo.output_lock and the re-run rules of facegeo.staged_output, with real processes: one run
at a time per output location, stale locks of killed runs taken over, a re-run that keeps the
user's files, and a commit killed half way rolled back by the next run."""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from facegeo.errors import InputError, OutputError
from facegeo.output_lock import LOCK_PREFIX, OutputLock, lock_file
from facegeo.staged_output import MANIFEST, TEMP_PREFIX, StagedOutput, locked_output, remove_stale_temporaries

#: Holds ``StagedOutput(OUT, replace=True)`` open with one staged file, touches FLAG, then waits
#: until FLAG is removed (or is killed).
HOLD = """
import pathlib, sys, time
from facegeo.staged_output import StagedOutput
out, flag = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
with StagedOutput(out, replace=True) as stage:
    stage.path("fit.json").write_text("held")
    flag.write_text("staged")
    while flag.exists():
        time.sleep(0.05)
"""


#: Removes the unheld lock files of FOLDER in a loop while STOP exists.
CLEAN = """
import pathlib, sys
from facegeo.output_lock import LOCK_PREFIX, remove_stale_lock_file
folder, stop = pathlib.Path(sys.argv[1]), pathlib.Path(sys.argv[2])
while stop.exists():
    for entry in folder.iterdir():
        if entry.name.startswith(LOCK_PREFIX):
            remove_stale_lock_file(entry)
"""


def _start(script: str, *args: object) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", script, *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)


def _wait_for(flag: Path, proc: subprocess.Popen, seconds: float = 60.0) -> None:
    deadline = time.monotonic() + seconds
    while not flag.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert flag.exists(), proc.communicate()[1]


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.communicate()


def _tree(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` (hidden ones too) with its text."""
    return {p.relative_to(folder).as_posix(): p.read_text() for p in sorted(folder.rglob("*")) if p.is_file()}


def _clutter(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob("*") if p.name.startswith((TEMP_PREFIX, LOCK_PREFIX)))


# -- the lock ---------------------------------------------------------------------------------


def test_a_second_run_into_the_same_folder_is_refused_at_once(tmp_path):
    out, flag = tmp_path / "out", tmp_path / "flag"
    holder = _start(HOLD, out, flag)
    try:
        _wait_for(flag, holder)
        start = time.monotonic()
        with pytest.raises(InputError) as refused, StagedOutput(out, replace=True) as stage:
            stage.path("fit.json").write_text("second")  # pragma: no cover - refused on entry
        assert time.monotonic() - start < 5
        message = str(refused.value)
        assert str(out) in message and f"process {holder.pid})" in message and "no other facegeo run" in message
        assert not out.exists()  # nothing written by the refused run
        flag.unlink()
        assert holder.wait(60) == 0
    finally:
        _stop(holder)
    assert _tree(out)["fit.json"] == "held" and _clutter(tmp_path) == []


def test_a_killed_runs_lock_is_taken_over_and_its_leftovers_removed(tmp_path):
    out, flag = tmp_path / "out", tmp_path / "flag"
    with StagedOutput(out, replace=True) as stage:
        stage.path("fit.json").write_text("earlier")
    (out / "keep.txt").write_text("mine")
    holder = _start(HOLD, out, flag)
    try:
        _wait_for(flag, holder)
        holder.send_signal(signal.SIGKILL)
        holder.wait(60)
    finally:
        _stop(holder)
    assert (tmp_path / (LOCK_PREFIX + "out")).is_file()  # the killed run's lock file and staging folder stay...
    assert any(name.startswith(f"{TEMP_PREFIX}{holder.pid}-") for name in _clutter(tmp_path))
    with StagedOutput(out, replace=True) as stage:  # ...until the next run into the same place
        stage.path("fit.json").write_text("next")
    assert _clutter(tmp_path) == []
    assert _tree(out) == {MANIFEST: _tree(out)[MANIFEST], "fit.json": "next", "keep.txt": "mine"}


def test_the_lock_is_reentrant_in_a_thread_but_not_across_threads(tmp_path):
    out = tmp_path / "out"
    seen: list[str] = []

    def other_thread() -> None:
        try:
            with OutputLock(out):
                seen.append("locked")  # pragma: no cover - must not happen
        except InputError as exc:
            seen.append(str(exc))

    with locked_output(out):
        with StagedOutput(out, replace=True) as stage:  # the job's own StagedOutput: the same lock
            stage.path("a.txt").write_text("a")
        worker = threading.Thread(target=other_thread)
        worker.start()
        worker.join()
        assert lock_file(out).is_file()
    assert len(seen) == 1 and f"process {os.getpid()})" in seen[0]
    assert not lock_file(out).exists() and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def _hold_without_record(file: Path) -> int:
    """Lock ``file`` from another open file without writing a record, as a cleaning run's
    remove_stale_lock_file does for a moment; the descriptor."""
    fd = os.open(file, os.O_RDWR | os.O_CREAT, 0o666)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


def test_a_cleaner_holding_a_fresh_lock_file_for_a_moment_does_not_refuse_the_run(tmp_path):
    out = tmp_path / "out"
    fd = _hold_without_record(lock_file(out))

    def clean() -> None:  # what remove_stale_lock_file does once it holds an unheld file
        time.sleep(0.15)
        os.unlink(lock_file(out))
        os.close(fd)

    cleaner = threading.Thread(target=clean)
    cleaner.start()
    try:
        with locked_output(out) as lock:  # waited for, then taken under the same name
            assert lock.held and lock_file(out).read_text().split()[0] == str(os.getpid())
    finally:
        cleaner.join()
    assert list(tmp_path.iterdir()) == []


def test_a_holder_that_never_writes_its_record_is_refused_after_a_second(tmp_path):
    out = tmp_path / "out"
    fd = _hold_without_record(lock_file(out))
    try:
        start = time.monotonic()
        with pytest.raises(InputError, match=r"found one running \(process unknown\)"), OutputLock(out):
            pass  # pragma: no cover - refused on entry
        assert 0.9 < time.monotonic() - start < 5
    finally:
        os.close(fd)


def test_cleaning_runs_never_refuse_a_run_into_the_same_folder(tmp_path):
    """Two processes cleaning the folder in a loop (as batch items do on entry) while this one
    takes and gives back an item's lock: a lock file it has just created may be locked and removed
    by a cleaner, which must not be taken for another run (before the fix, ~1 refusal in 1,000)."""
    folder = tmp_path / "out"
    folder.mkdir()
    stop = tmp_path / "stop"
    stop.write_text("")
    cleaners = [_start(CLEAN, folder, stop) for _ in range(2)]
    try:
        deadline = time.monotonic() + 3.0
        tries = 0
        while time.monotonic() < deadline:
            with OutputLock(folder / "item"):
                tries += 1
        stop.unlink()
        assert all(c.wait(60) == 0 for c in cleaners), [c.communicate()[1] for c in cleaners]
    finally:
        for c in cleaners:
            _stop(c)
    assert tries > 500 and list(folder.iterdir()) == []


def test_a_refused_lock_leaves_no_parent_folders(tmp_path):
    out = tmp_path / "a" / "b" / "out"
    with locked_output(out):
        assert (tmp_path / "a" / "b").is_dir()
    assert list(tmp_path.iterdir()) == []  # created for the lock file, removed with it


def test_lock_file_of_a_name_too_long_for_a_prefix(tmp_path):
    name = "x" * 250  # fits NAME_MAX, but not with the lock prefix
    path = lock_file(tmp_path / name)
    assert path.parent == tmp_path and path.name.startswith(LOCK_PREFIX) and len(path.name) < 100
    with locked_output(tmp_path / name):
        assert path.is_file()
    assert not path.exists()


FORK_AND_DIE = """
import os, pathlib, sys, time
from facegeo.output_lock import OutputLock
out, flag = sys.argv[1], pathlib.Path(sys.argv[2])
lock = OutputLock(out)
lock.acquire()
child = os.fork()
if child == 0:
    time.sleep(60)  # a forked helper outliving its parent
    os._exit(0)
pending = flag.with_name(flag.name + ".part")
pending.write_text(str(child))
os.replace(pending, flag)  # whole: the test reads the pid as soon as the flag exists
time.sleep(60)
"""


def test_a_forked_child_does_not_keep_a_dead_runs_lock(tmp_path):
    out, flag = tmp_path / "out", tmp_path / "flag"
    proc = _start(FORK_AND_DIE, out, flag)
    child = None
    try:
        _wait_for(flag, proc)
        child = int(flag.read_text())
        proc.send_signal(signal.SIGKILL)
        proc.wait(60)
        with locked_output(out):  # the child's copy of the descriptor was closed at fork
            pass
    finally:
        if child is not None:  # first: it holds the pipes of its parent open
            try:
                os.kill(child, signal.SIGKILL)
            except ProcessLookupError:
                pass
        _stop(proc)
    assert _clutter(tmp_path) == []


# -- re-runs keep the user's files ---------------------------------------------------------------


def test_a_rerun_replaces_only_the_earlier_runs_files(tmp_path):
    out = tmp_path / "out"
    with StagedOutput(out, replace=True) as stage:
        for name in ("fit.json", "face.usdz", "textures/albedo.png", "parts/eyes.png"):
            stage.path(name).write_text("old")
    (out / "keep.txt").write_text("mine")
    (out / "parts" / "notes.md").write_text("mine too")
    (out / "mine").mkdir()
    (out / "mine" / "data.csv").write_text("1,2")
    with StagedOutput(out, replace=True) as stage:
        stage.path("fit.json").write_text("new")
        stage.path("mesh.obj").write_text("new")
    tree = _tree(out)
    assert json.loads(tree.pop(MANIFEST))["files"] == ["fit.json", "mesh.obj"]
    assert tree == {"fit.json": "new", "mesh.obj": "new", "keep.txt": "mine", "parts/notes.md": "mine too",
                    "mine/data.csv": "1,2"}
    assert not (out / "textures").exists()  # emptied by the removal of the earlier run's file
    assert _clutter(tmp_path) == []


def test_an_earlier_output_without_manifest_loses_only_what_is_rewritten(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "fit.json").write_text("old")  # written by a facegeo without manifests
    (out / "overlay.png").write_text("old")
    (out / "keep.txt").write_text("mine")
    with StagedOutput(out, replace=True) as stage:
        stage.path("fit.json").write_text("new")
    tree = _tree(out)
    tree.pop(MANIFEST)
    assert tree == {"fit.json": "new", "overlay.png": "old", "keep.txt": "mine"}


def test_a_manifest_cannot_name_files_outside_the_folder(tmp_path):
    out, elsewhere = tmp_path / "out", tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "x.txt").write_text("precious")
    (tmp_path / "victim.txt").write_text("precious")
    out.mkdir()
    (out / "linked").symlink_to(elsewhere, target_is_directory=True)
    (out / MANIFEST).write_text(json.dumps({"files": ["../victim.txt", str(tmp_path / "victim.txt"), "linked/x.txt",
                                                      f"{TEMP_PREFIX}1-x", 3]}))
    with StagedOutput(out, replace=True) as stage:
        stage.path("fit.json").write_text("new")
    assert (tmp_path / "victim.txt").read_text() == "precious" and (elsewhere / "x.txt").read_text() == "precious"


def test_a_commit_that_fails_half_way_is_rolled_back(tmp_path, monkeypatch):
    out = tmp_path / "out"
    with StagedOutput(out, replace=True) as stage:
        for name in ("a.txt", "b.txt", "sub/c.txt"):
            stage.path(name).write_text("old")
    (out / "keep.txt").write_text("mine")
    before = _tree(out)
    real_replace = os.replace
    calls = []

    def failing(src, dst, *args, **kwargs):
        calls.append(dst)
        if len(calls) == 3:
            raise OSError(5, "Input/output error", str(dst))
        return real_replace(src, dst, *args, **kwargs)

    monkeypatch.setattr("facegeo.staged_output.os.replace", failing)
    with pytest.raises(OutputError, match="input/output error"), StagedOutput(out, replace=True) as stage:
        for name in ("a.txt", "new/d.txt", "z.txt"):
            stage.path(name).write_text("new")
    monkeypatch.undo()
    assert len(calls) > 3  # it failed after moving two files in, and rolled them back
    assert _tree(out) == before and not (out / "new").exists() and _clutter(tmp_path) == []


#: Commits into OUT and SIGKILLs itself after the second file moved in.
KILLED_COMMIT = """
import os, pathlib, signal, sys
import facegeo.staged_output as so
out = pathlib.Path(sys.argv[1])
real = os.replace
moved = []
def replace(src, dst):
    real(src, dst)
    moved.append(dst)
    if len(moved) == 2:
        os.kill(os.getpid(), signal.SIGKILL)
so.os.replace = replace
with so.StagedOutput(out, replace=True) as stage:
    for name in ("fit.json", "mesh.obj", "sub/new.txt"):
        stage.path(name).write_text("new")
"""


def test_a_commit_killed_half_way_is_rolled_back_by_the_next_run(tmp_path):
    out = tmp_path / "out"
    with StagedOutput(out, replace=True) as stage:
        for name in ("fit.json", "mesh.obj", "overlay.png"):
            stage.path(name).write_text("old")
    (out / "keep.txt").write_text("mine")
    before = _tree(out)
    proc = subprocess.run([sys.executable, "-c", KILLED_COMMIT, str(out)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert _tree(out) != before  # killed with two files moved in: mixed until...
    assert (out / "keep.txt").read_text() == "mine"
    removed = remove_stale_temporaries(tmp_path)  # ...the next run into the same place rolls it back
    assert any(p.name.startswith(TEMP_PREFIX) for p in removed)
    assert _tree(out) == before and _clutter(tmp_path) == []


def test_a_file_system_without_locks_lets_runs_go_on(tmp_path, monkeypatch):
    import errno
    import fcntl

    def no_locks(fd, operation):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", no_locks)
    with StagedOutput(tmp_path / "out", replace=True) as stage:
        stage.path("fit.json").write_text("{}")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # written, lock file removed
