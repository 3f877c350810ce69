"""A call in a forked child (facegeo.forked_call), as reconstruct uses it for the fit and the
export: the same answer as in this process, its errors raised in the caller, Ctrl-C ending both, and
used only where it helps. The forks run in fresh interpreters (this test process has torch
imported, where :func:`can_fork` is False by design)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from facegeo.assets import asset_path
from facegeo.forked_call import can_fork

PHOTO = str(asset_path("photos/astronaut.png"))

SAME_ANSWER = f"""
import sys
import numpy as np
from facegeo.forked_call import can_fork, fork_call
import dataclasses
from facegeo.jobs import FitOptions, _fitted_and_skin
from facegeo.photo import load_photo

assert can_fork()
photo = load_photo({PHOTO!r})
forked, seconds, forked_skin = fork_call(_fitted_and_skin, photo, "astronaut", FitOptions()).result()
assert "torch" not in sys.modules and seconds > 0
inline, _, skin = _fitted_and_skin(photo, "astronaut", FitOptions())
for name in ("alpha", "delta", "beta", "gamma", "rotation", "translation", "vertices", "landmarks", "landmarks_fitted"):
    assert np.array_equal(getattr(forked, name), getattr(inline, name)), name
assert forked.info == inline.info and forked.camera == inline.camera
for field in dataclasses.fields(skin):  # the skin mask the child makes after its fit, as this process makes it
    mine, theirs = getattr(skin, field.name), getattr(forked_skin, field.name)
    assert np.array_equal(mine, theirs) if isinstance(mine, np.ndarray) else mine == theirs, field.name
print("same")
"""

NO_FACE = """
import numpy as np
from facegeo.errors import NoFaceError
from facegeo.forked_call import fork_call
from facegeo.jobs import FitOptions, _fitted
from facegeo.photo import load_photo
import cv2, tempfile, pathlib
path = pathlib.Path(tempfile.mkdtemp()) / "grey.png"
cv2.imwrite(str(path), np.full((240, 320, 3), 128, np.uint8))
try:
    fork_call(_fitted, load_photo(path), str(path), FitOptions()).result()
except NoFaceError as error:
    print(type(error).__name__, str(path) in str(error))
"""


def _python(code: str, timeout: float = 300) -> str:
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.strip()


def test_the_forked_fit_equals_the_fit_in_this_process():
    assert _python(SAME_ANSWER) == "same"


def test_the_childs_error_is_raised_in_the_parent():
    assert _python(NO_FACE) == "NoFaceError True"


def test_no_fork_once_torch_is_imported():
    import torch  # noqa: F401

    assert not can_fork()


def test_facegeo_errors_survive_pickling_with_their_fields():
    import pickle

    from facegeo.errors import InputError, ModelFileError, NoFaceError, OutputError

    for error in (InputError("a.png", "image", "RGB", "CMYK"), ModelFileError("m.npz", "id_basis", "(n, V, 3)"),
                  NoFaceError("b.png", "face", "one face", "no face"), OutputError("/out/x.glb", "a full disk")):
        copy = pickle.loads(pickle.dumps(error))
        assert type(copy) is type(error) and str(copy) == str(error) and copy.__dict__ == error.__dict__


def _children(pid: int) -> list[int]:
    """The live child processes of ``pid`` (from /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid and fields[0] != "Z":
            found.append(int(stat.parent.name))
    return found


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_ctrl_c_while_the_child_fits_ends_both_with_one_line_and_no_files(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "facegeo.cli", "reconstruct", PHOTO, "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while not (children := _children(proc.pid)) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert children, "no forked fit seen"
    os.killpg(proc.pid, signal.SIGINT)  # a terminal's Ctrl-C reaches the whole process group
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert err.strip().splitlines() == ["facegeo: interrupted (SIGINT); no output written"]
    assert not any(Path(f"/proc/{pid}").exists() for pid in children)
    assert not out.exists() and list(tmp_path.iterdir()) == []


OTHER_ERROR = """
from facegeo.forked_call import fork_call
def broken(x):
    return {}[x]
try:
    fork_call(broken, "missing").result()
except RuntimeError as error:
    print("broken failed in a forked process" in str(error), "KeyError: 'missing'" in str(error))
"""


def test_an_unexpected_error_carries_the_childs_traceback():
    assert _python(OTHER_ERROR) == "True True"


AFTER_OPENCV_POOL = """
import cv2, numpy as np
from facegeo.forked_call import fork_call
image = np.random.default_rng(0).random((2000, 2000, 3)).astype(np.float32)
threads = cv2.getNumThreads()
cv2.GaussianBlur(image, (31, 31), 5)  # OpenCV's pool threads now wait in this process
def child():
    return float(cv2.GaussianBlur(image, (31, 31), 5).sum())
print(fork_call(child).result() == float(cv2.GaussianBlur(image, (31, 31), 5).sum()), cv2.getNumThreads() == threads)
"""


def test_a_fork_after_opencv_used_its_thread_pool_does_not_hang():
    # a photo larger than max_side is downscaled with cv2.resize before the fork: before the fix
    # the child hung for ever in cv2.setNumThreads (OpenCV's pool does not survive a fork)
    assert _python(AFTER_OPENCV_POOL, timeout=60) == "True True"


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "facegeo.cli", *args], capture_output=True, text=True, timeout=300)


def test_a_photo_the_child_refuses_gets_the_same_line_from_reconstruct_as_from_fit(tmp_path):
    # the child's error is raised from result(), which has already waited for the child: the
    # job's clean-up (abandon) must not wait again (it printed "No child processes" instead)
    import cv2
    import numpy as np

    noise = tmp_path / "noise.png"
    cv2.imwrite(str(noise), np.random.default_rng(0).integers(0, 256, (300, 400, 3), dtype=np.uint8))
    transparent = tmp_path / "transparent.png"
    bgr = cv2.imread(PHOTO)
    cv2.imwrite(str(transparent), np.dstack([bgr, np.zeros(bgr.shape[:2], np.uint8)]))
    for photo in (noise, transparent):
        fitted = _cli("fit", str(photo), "-o", str(tmp_path / "fit_out"))
        made = _cli("reconstruct", str(photo), "-o", str(tmp_path / "out"))
        assert fitted.returncode == made.returncode == 2, made.stderr[-2000:]
        assert made.stderr == fitted.stderr and len(made.stderr.strip().splitlines()) == 1, made.stderr
        assert made.stderr.startswith(f"facegeo: error: {photo}: "), made.stderr
        assert not (tmp_path / "out").exists() and not (tmp_path / "fit_out").exists()


LOST = """
import os, signal
from facegeo.forked_call import ChildLost, fork_call
pending = fork_call(lambda: os.kill(os.getpid(), signal.SIGKILL))
try:
    pending.result()
except ChildLost as lost:
    pending.abandon()  # already reaped: nothing to wait for
    print(lost.how)
"""


def test_a_child_killed_without_an_answer_is_reported_as_lost():
    assert _python(LOST) == "by signal SIGKILL"


REAPED = """
import os
from facegeo.forked_call import fork_call, wait_for_exits
pending = fork_call(lambda: 5)
answer = pending.result()  # the exit is collected on a thread, after the answer
pending.abandon()  # answered: nothing to stop
wait_for_exits()
try:
    os.waitpid(-1, os.WNOHANG)
    print(answer, "a child is left")
except ChildProcessError:
    print(answer, "no child is left")
"""


def test_a_child_that_answered_is_reaped_after_its_answer_and_before_the_process_ends():
    assert _python(REAPED) == "5 no child is left"


INTERRUPTED = """
import os, signal
from facegeo.forked_call import fork_call
pending = fork_call(lambda: os.kill(os.getpid(), signal.SIGTERM))
try:
    pending.result()
except KeyboardInterrupt as stop:
    print(stop)
"""


def test_a_child_ended_by_an_interruption_interrupts_the_caller():
    # never fitted again in the caller: the user's Ctrl-C or a service manager's SIGTERM means stop
    assert _python(INTERRUPTED) == "the forked process ended by signal SIGTERM"


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_a_killed_forked_fit_is_fitted_again_in_the_main_process(tmp_path):
    # e.g. the kernel's out-of-memory killer chose the child: the user still gets the asset
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "facegeo.cli", "reconstruct", PHOTO, "-o", str(out), "--size", "256"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (children := _children(proc.pid)) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert children, "no forked fit seen"
    os.kill(children[0], signal.SIGKILL)
    said, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-3000:]
    assert "note: the forked fit ended by signal SIGKILL without an answer; fitted again in the main process" in said
    assert {"fit.json", "asset.json", "face.glb", "face.usdz", "preview.png"} <= {p.name for p in out.iterdir()}


INBOX = """
import numpy as np
from facegeo.forked_call import fork_call
def work(x, receive):
    first, second = receive(), receive()
    try:
        receive()
    except EOFError:
        return x + float(first.sum()), second, "no more"
pending = fork_call(work, 1.0, inbox=True)
pending.send(np.ones((1000, 1000, 3), np.float32))  # larger than a pipe's buffer
pending.send("second")
print(pending.result())
def fails_first(receive):
    raise ValueError("x" * 300000)  # an answer larger than a pipe's buffer, before reading anything
pending = fork_call(fails_first, inbox=True)
pending.send(np.ones((2000, 2000, 3), np.float32))
try:
    pending.result()
except RuntimeError as error:
    print("ValueError" in str(error))
"""


def test_what_the_caller_sends_reaches_the_child_in_order_and_a_child_that_fails_first_does_not_block_it():
    assert _python(INBOX, timeout=60).splitlines() == ["(3000001.0, 'second', 'no more')", "True"]


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_ctrl_c_while_the_export_child_works_ends_all_with_one_line_and_no_files(tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "facegeo.cli", "reconstruct", PHOTO, "-o", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    seen: set[int] = set()
    deadline = time.monotonic() + 120
    while len(seen) < 2 and proc.poll() is None and time.monotonic() < deadline:  # the fit's child, then the export's
        seen.update(_children(proc.pid))
        time.sleep(0.01)
    assert len(seen) == 2, "no forked export seen"
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert err.strip().splitlines() == ["facegeo: interrupted (SIGINT); no output written"]
    assert not any(Path(f"/proc/{pid}").exists() for pid in seen)
    assert not out.exists() and list(tmp_path.iterdir()) == []


BESIDE = """
import os, signal, time
from facegeo.concurrency import usable_threads
from facegeo.forked_call import beside_child, beside_children, fork_call
import cv2

def lost():
    os.kill(os.getpid(), signal.SIGKILL)

cv2.setNumThreads(2)
starts = [lambda: fork_call(lambda: "first"), lambda: fork_call(lost), lambda: None, lambda: fork_call(lambda: None)]
seen = []
mine, theirs = beside_children(starts, lambda: seen.append(cv2.getNumThreads()) or "mine",
                               lambda k, why: f"here {k} {why.how if why else None}")
print(mine, theirs, seen == [max(1, usable_threads() - 3)], cv2.getNumThreads())
print(beside_child(lambda: None, lambda: cv2.getNumThreads(), lambda why: why))
print(beside_child(lambda: fork_call(lambda: 3), lambda: 1, lambda why: 0, answer=lambda n: n * 2))
try:
    beside_child(lambda: fork_call(lambda: 1 / 0), lambda: 1, lambda why: 0)
except RuntimeError as error:
    print("ZeroDivisionError" in str(error))
started = []
def second_fails():
    raise KeyboardInterrupt  # e.g. Ctrl-C while the second child is forked: the first is stopped, not left behind
try:
    beside_children([lambda: started.append(fork_call(time.sleep, 30)) or started[-1], second_fails], lambda: 1, lambda k, why: 0)
except KeyboardInterrupt:
    print(started[0]._reaped)
"""


def test_beside_children_takes_each_childs_answer_or_does_its_work_here():
    said = _python(BESIDE).splitlines()
    # the lost child's and the refused (None) answer's work is done here; this process's pools
    # one thread fewer a child while they work, restored afterwards
    assert said[0] == "mine ['first', 'here 1 by signal SIGKILL', 'here 2 None', 'here 3 None'] True 2", said
    assert said[1:] == ["(2, None)", "(1, 6)", "True", "True"], said


def test_the_views_are_shared_so_that_no_process_waits_for_the_others():
    from facegeo.pipeline import _view_shares

    # two cores, five photos: the reference (weighing 1.8 others) and one other here, three in a child
    assert _view_shares(5, 0, 2) == [[0, 3], [1, 2, 4]]
    assert _view_shares(5, 3, 2) == [[3, 2], [0, 1, 4]]
    assert _view_shares(2, 0, 2) == [[0], [1]]
    assert _view_shares(5, 0, 1) == [[0, 1, 2, 3, 4]]  # no children: every view here
    assert _view_shares(5, 0, 8) == [[0], [1], [2], [3], [4], [], [], []]  # a child each
