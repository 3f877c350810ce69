"""Independent pieces of work on a few threads, with the native thread pools sized together.

:func:`run_concurrently` runs callables on ``workers`` threads (the export stage of
``facegeo reconstruct`` writes its asset folder, scenes and preview this way: most of that work is
PNG encoding, zlib and NumPy, which release the GIL). While it runs, :func:`native_threads` holds
each native pool at one thread, so that two workers use two cores instead of each library's pool
taking every core per worker:

* torch's intra-op pool (``torch.set_num_threads``; each new thread takes torch's global count
  at its first parallel operation, so the workers get it too), only when torch is already
  imported (nothing here imports it);
* OpenCV's pool (``cv2.setNumThreads``, global);
* the BLAS pools that threadpoolctl finds (OpenBLAS's count is global). OpenMP's count is per
  thread and new threads do not inherit the caller's, so it is not set here; torch sets its own.

Failure: the first task (in list order) that raised has its exception raised to the caller, but
only after every task that had started has finished and those not started are dropped, so no
worker is still writing when the caller cleans up (a :class:`facegeo.staged_output.StagedOutput`
rolls back). An exception in the calling thread while it waits (KeyboardInterrupt, or the
``facegeo`` command's SIGTERM) waits for the started tasks the same way before it propagates;
further interrupts during that wait (at most the longest task) are held back until it ends.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_EXCEPTION, Future, ThreadPoolExecutor, wait
from typing import Any

__all__ = ["run_concurrently", "native_threads", "numpy_blas_threads", "one_blas_thread_by_default", "usable_threads", "EXPORT_WORKERS"]

#: Worker threads of the export stage (issue 29: two cores).
EXPORT_WORKERS = 2


def usable_threads() -> int:
    """The threads this process may keep busy: torch's intra-op count when torch is imported (it
    follows ``OMP_NUM_THREADS`` and ``torch.set_num_threads``), else ``OMP_NUM_THREADS`` when set
    (1 in a Dask worker), else the CPUs this process may run on (nothing here imports torch)."""
    torch = sys.modules.get("torch")
    if torch is not None:
        return max(1, int(torch.get_num_threads()))
    try:
        return max(1, int(os.environ["OMP_NUM_THREADS"]))
    except (KeyError, ValueError):
        return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def one_blas_thread_by_default() -> None:
    """For a process that has not imported NumPy yet (the ``facegeo`` command, before anything):
    OpenBLAS starts with one thread unless ``OPENBLAS_NUM_THREADS`` is set. Its worker threads
    busy-wait about 0.1 s after each call, and are made again, spinning, in both processes at
    every fork: on 2 cores they took ~0.9 s of the CPU of ``facegeo reconstruct`` on the bundled
    photo (perf: ``blas_thread_server``) from the forked child and the other worker, while none of
    the pipeline's BLAS calls (at most ~9 columns) ran faster on two threads: the texture stages
    took the same time either way, and the fit's landmark solve is held at one already
    (``LANDMARK_FIT_THREADS``). Measured in benchmarks/RESULTS.md ("the BLAS pools' spinning")."""
    global _BLAS_STARTED_ON_ONE
    if "OPENBLAS_NUM_THREADS" not in os.environ and "numpy" not in sys.modules:
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        _BLAS_STARTED_ON_ONE = True


_NUMPY_BLAS: Any = None  # threadpoolctl's controller of the BLAS libraries loaded with NumPy
#: OpenBLAS was started on one thread here (:func:`one_blas_thread_by_default`).
_BLAS_STARTED_ON_ONE = False
#: The :func:`native_threads` holds above one thread under way (they raise the BLAS pools).
_BLAS_RAISED = 0
_BLAS_RAISED_LOCK = threading.Lock()


def numpy_blas_threads(count: int) -> contextlib.AbstractContextManager[Any]:
    """A context that holds the BLAS pools NumPy loaded at ``count`` threads (restored on exit),
    for NumPy code called many times (a tracked video's per-frame solves): the libraries are found
    once a process (threadpoolctl scans the loaded libraries for each ``threadpool_limits``, about
    a millisecond), so a BLAS loaded later (torch's) is not held; :func:`native_threads` holds them all.
    Where OpenBLAS was started on one thread (:func:`one_blas_thread_by_default`) and no
    :func:`native_threads` raises it, a hold at one thread changes nothing and is not made: the
    scan (~4.5 ms, and threadpoolctl's import) was 3 % of ``facegeo fit``."""
    global _NUMPY_BLAS
    if count == 1 and _BLAS_STARTED_ON_ONE and _BLAS_RAISED == 0:
        return contextlib.nullcontext()
    if _NUMPY_BLAS is None:
        import numpy  # noqa: F401  (its BLAS is loaded with it)
        from threadpoolctl import ThreadpoolController

        _NUMPY_BLAS = ThreadpoolController()
    return _NUMPY_BLAS.limit(limits=count, user_api="blas")


@contextlib.contextmanager
def native_threads(count: int) -> Iterator[None]:
    """Hold torch's (when imported), OpenCV's and the BLAS thread pools at ``count`` threads each
    (see the module docstring); each is restored on exit."""
    import cv2
    from threadpoolctl import threadpool_limits

    global _BLAS_RAISED
    torch = sys.modules.get("torch")
    torch_threads = torch.get_num_threads() if torch is not None else None
    cv2_threads = cv2.getNumThreads()
    cv2.setNumThreads(count)
    if torch is not None:
        torch.set_num_threads(count)
    raised = count > 1
    if raised:
        with _BLAS_RAISED_LOCK:
            _BLAS_RAISED += 1
    try:
        with threadpool_limits(limits=count, user_api="blas"):
            yield
    finally:
        if raised:
            with _BLAS_RAISED_LOCK:
                _BLAS_RAISED -= 1
        if torch is not None:
            torch.set_num_threads(torch_threads)
        cv2.setNumThreads(cv2_threads)


def run_concurrently(tasks: Sequence[Callable[[], Any]], workers: int = EXPORT_WORKERS) -> list[Any]:
    """Run ``tasks`` (no arguments each) on ``workers`` threads, started in list order as threads
    come free, with every native pool at one thread meanwhile; returns their results in list
    order. ``workers`` 1 (or one task) runs them one after the other in this thread. Failure and
    interrupts: module docstring."""
    if workers <= 1 or len(tasks) <= 1:
        return [task() for task in tasks]
    with native_threads(1):
        # The tasks wait at a gate until all are submitted: a worker thread joins the executor's
        # list only once its start() returns, and an interrupt may come while the main thread
        # waits in it; with the gate, every thread that may run a task is listed before any does.
        # After a failure (or an interrupt while submitting) no further task starts.
        gate, dropped = threading.Event(), threading.Event()

        def gated(task: Callable[[], Any]) -> Callable[[], Any]:
            def run() -> Any:
                gate.wait()
                if dropped.is_set():
                    return None
                try:
                    return task()
                except BaseException:
                    dropped.set()
                    raise
            return run

        executor = ThreadPoolExecutor(max_workers=min(workers, len(tasks)), thread_name_prefix="facegeo-worker")
        futures: list[Future[Any]] = []
        try:
            for task in tasks:
                futures.append(executor.submit(gated(task)))
            gate.set()
            while True:  # short waits: a signal that the kernel gave a worker thread is handled here within 50 ms
                finished, running = wait(futures, timeout=0.05, return_when=FIRST_EXCEPTION)
                if not running or any(not f.cancelled() and f.exception() is not None for f in finished):
                    break
        finally:
            _finish(executor, futures, dropped, gate)
    failed = next((f for f in futures if f.done() and not f.cancelled() and f.exception() is not None), None)
    if failed is not None:
        raise failed.exception()  # type: ignore[misc]
    return [f.result() for f in futures]


def _finish(executor: ThreadPoolExecutor, futures: list[Future[Any]], dropped: threading.Event, gate: threading.Event) -> None:
    """Let no further task start (``dropped``, then open the ``gate``; normally none is left),
    drop those queued and wait for the started ones, holding back any exception raised in this
    thread meanwhile (a second Ctrl-C) until they are done. (It waits for the futures, not the
    threads: Python 3.11's ``Thread.join`` interrupted by an exception takes the thread for
    finished, and a second join returns at once.)"""
    held: BaseException | None = None
    while True:
        try:
            dropped.set()
            gate.set()
            executor.shutdown(wait=False, cancel_futures=True)
            wait([f for f in futures if not f.cancelled()])  # a future cancelled in the queue is never "done" to wait()
            break
        except BaseException as exc:  # noqa: BLE001 - re-raised below, once the workers are done
            held = held or exc
    if held is not None:
        raise held
