"""facegeo.concurrency: tasks on two threads, native pools sized together, failures and
interrupts that wait for the started tasks (so a StagedOutput rolls back with no writer left)."""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path

import cv2
import pytest
import torch
from threadpoolctl import threadpool_info

from facegeo.concurrency import native_threads, run_concurrently
from facegeo.staged_output import TEMP_PREFIX, StagedOutput


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_results_in_order_on_two_threads():
    barrier = threading.Barrier(2, timeout=10)  # both tasks must be running at once to pass it

    def task(k: int):
        def run():
            barrier.wait()
            return k, threading.current_thread().name
        return run

    results = run_concurrently([task(0), task(1)], workers=2)
    assert [k for k, _ in results] == [0, 1] and len({name for _, name in results}) == 2
    assert run_concurrently([threading.current_thread], workers=2) == [threading.current_thread()]  # one task: here
    assert run_concurrently([lambda: 1, lambda: 2], workers=1) == [1, 2]


def test_native_pools_hold_one_thread_each_while_two_workers_run_and_are_restored():
    before = (torch.get_num_threads(), cv2.getNumThreads(), _blas_threads())
    torch.set_num_threads(2)
    cv2.setNumThreads(2)
    try:
        seen = run_concurrently([lambda: (torch.get_num_threads(), cv2.getNumThreads(), _blas_threads())] * 2, workers=2)
        assert seen == [(1, 1, [1] * len(before[2]))] * 2
        assert (torch.get_num_threads(), cv2.getNumThreads()) == (2, 2) and _blas_threads() == before[2]
        with native_threads(1):
            assert (torch.get_num_threads(), cv2.getNumThreads()) == (1, 1)
        assert (torch.get_num_threads(), cv2.getNumThreads()) == (2, 2)
    finally:
        torch.set_num_threads(before[0])
        cv2.setNumThreads(before[1])


def test_a_failure_waits_for_the_started_task_and_drops_the_rest():
    finished, started = [], []
    slow_started = threading.Event()

    def slow():
        started.append("slow")
        slow_started.set()
        time.sleep(0.3)
        finished.append("slow")

    def fail():
        started.append("fail")
        assert slow_started.wait(10)
        raise ValueError("writer failed")

    def never():
        started.append("never")

    with pytest.raises(ValueError, match="writer failed"):
        run_concurrently([slow, fail, never], workers=2)
    assert finished == ["slow"] and "never" not in started


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.rglob(f"{TEMP_PREFIX}*"))


def test_a_failing_writer_rolls_back_the_staged_output(tmp_path):
    out = tmp_path / "out"

    def fail():
        raise OSError("disk on fire")

    with pytest.raises(OSError, match="disk on fire"), StagedOutput(out, replace=True) as stage:
        target = stage.path("slow.txt")
        run_concurrently([lambda: (time.sleep(0.2), target.write_text("done")), fail], workers=2)
    assert not out.exists() and _leftovers(tmp_path) == []


@pytest.mark.parametrize("interrupts", [1, 2], ids=["ctrl-c", "ctrl-c twice"])
def test_ctrl_c_while_workers_write_leaves_nothing(tmp_path, interrupts):
    """SIGINT (KeyboardInterrupt in the waiting main thread), as Ctrl-C gives it: the staged output is
    rolled back only once the workers are done, so none writes into the removed staging folder;
    a second Ctrl-C meanwhile is held back until then."""
    out = tmp_path / "out"
    started, done = [], []
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)  # Ctrl-C's KeyboardInterrupt, whatever ran before

    def writer(name: str, stage: StagedOutput):
        def run():
            started.append(name)
            stage.path(f"{name}-1.bin").write_bytes(b"x")
            if name == "a":
                for _ in range(interrupts):
                    os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C: handled in the main thread, which waits for us
                    time.sleep(0.1)
            time.sleep(0.4)
            stage.path(f"{name}-2.bin").write_bytes(b"y")  # still writing after the interrupt
            done.append(name)
        return run

    try:
        with pytest.raises(KeyboardInterrupt), StagedOutput(out, replace=True) as stage:
            run_concurrently([writer("a", stage), writer("b", stage), writer("c", stage)], workers=2)
    finally:
        signal.signal(signal.SIGINT, handler)
    # every writer that had started (b may not have, then it never does) finished before the
    # rollback; c, queued behind them, never starts
    assert "a" in done and sorted(done) == sorted(started) and "c" not in started
    time.sleep(0.2)
    assert not out.exists() and _leftovers(tmp_path) == [] and sorted(p.name for p in tmp_path.iterdir()) == []


NO_IMPORT_ON_WORKERS = """
import importlib.abc, sys, tempfile, threading
from pathlib import Path
imported = []
class Record(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if threading.current_thread() is not threading.main_thread():
            imported.append(name)
        return None
sys.meta_path.insert(0, Record())
from facegeo.jobs import ReconstructOptions, reconstruct_into_folder
out = Path(tempfile.mkdtemp()) / "out"
reconstruct_into_folder({photo!r}, out, ReconstructOptions(size=256))
assert (out / "face.usdz").exists() and (out / "face.glb").exists()
print(sorted(imported))
"""


def test_the_export_threads_import_nothing():
    # pxr's extension modules let go of the GIL inside dlopen: imported on one export thread
    # while another imported pygltflib's uuid, the process deadlocked (GIL against the loader's
    # lock). scene_writers imports the writers' libraries first, in the caller's thread. A fresh
    # interpreter, so that neither library is imported yet.
    import subprocess
    import sys

    from facegeo.assets import asset_path

    code = NO_IMPORT_ON_WORKERS.format(photo=str(asset_path("photos/astronaut.png")))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip().splitlines()[-1] == "[]"


ONE_BLAS_THREAD = """
import facegeo.cli  # noqa: F401  (sets the default before NumPy is imported)
import numpy  # noqa: F401
from threadpoolctl import threadpool_info
print(sorted({pool["num_threads"] for pool in threadpool_info() if pool["internal_api"] == "openblas"}))
"""


@pytest.mark.parametrize("setting, expected", [(None, "[1]"), ("2", "[2]")])
def test_the_command_starts_openblas_on_one_thread_unless_told(setting, expected):
    # OpenBLAS's idle workers spin: on two cores they took ~0.9 s of a reconstruct's CPU from its
    # forked child. A fresh interpreter: the pool's size is read when the library loads.
    import subprocess
    import sys

    env = {key: value for key, value in os.environ.items() if key != "OPENBLAS_NUM_THREADS"}
    if setting is not None:
        env["OPENBLAS_NUM_THREADS"] = setting
    done = subprocess.run([sys.executable, "-c", ONE_BLAS_THREAD], capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == expected


HOLD_WITHOUT_SCAN = """
import sys
import facegeo.cli  # noqa: F401  (starts OpenBLAS on one thread)
import numpy  # noqa: F401
from facegeo.concurrency import native_threads, numpy_blas_threads
with numpy_blas_threads(1):
    pass
print("threadpoolctl" in sys.modules)
from threadpoolctl import threadpool_info
def numpy_pool():
    return [p["num_threads"] for p in threadpool_info() if "numpy" in p["filepath"]]
with native_threads(2):  # raises the pools: a hold at one is made then
    with numpy_blas_threads(1):
        inside = numpy_pool()
    print(numpy_pool(), inside)
print(numpy_pool())
"""


def test_a_hold_at_one_blas_thread_is_skipped_where_openblas_started_on_one():
    # the landmark fit holds NumPy's BLAS at one thread; in the facegeo command it starts on one,
    # so the hold is not made (threadpoolctl's scan was 3 % of a fit) unless a wider hold raised it
    import subprocess
    import sys

    env = {key: value for key, value in os.environ.items() if key != "OPENBLAS_NUM_THREADS"}
    done = subprocess.run([sys.executable, "-c", HOLD_WITHOUT_SCAN], capture_output=True, text=True, timeout=120, env=env)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.split("\n")[:3] == ["False", "[2] [1]", "[1]"]
