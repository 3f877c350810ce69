"""One function call in a forked child process, beside the caller's own work.

The reconstruction's first half (skin mask and fit) needs NumPy, OpenCV, MediaPipe's LiteRT
models and dlib; meanwhile the second half can import its modules and make the model's UV raster
and layout priors. One process cannot overlap them: imports and the fit's Python both hold the
GIL. So :func:`facegeo.jobs.reconstruct_into_folder` forks the first half with
:func:`fork_call`, does the rest meanwhile, then collects the answer with
:meth:`PendingCall.result`: the wall time of the slower half instead of the sum.

It only pays where torch is not imported yet (a fresh process: once a caller has loaded torch it
has other work in flight, and torch's pools do not survive a fork) and only works where ``fork``
does (POSIX) and the process may have children (not a daemonic worker): :func:`can_fork` says
so; elsewhere the caller runs the function itself. The child inherits the caller's modules and
data (the loaded model, the photo); it pickles back through a pipe the function's answer or the
exception it raised (a :class:`facegeo.errors.FacegeoError` reaches the user as the same clear
error; any other as a RuntimeError carrying the child's traceback; a child that ends without an
answer, e.g. killed when memory ran out, as :class:`ChildLost`, and the job fits in the caller
instead). OpenCV's pthreads pool does
not survive a fork either: it is stopped (one thread) while forking and the caller gets its count
back. The child runs its OpenCV and BLAS pools on one thread (the caller keeps the other core),
takes the default action on SIGINT and SIGTERM (it ends without a word; the caller reports the
interruption), and must write no named file (it may fill an unnamed one that the caller made
before the fork and reads afterwards: :class:`facegeo.observed_frames.ObservedFrames`); a caller
that fails first kills it.
A call forked with ``inbox=True`` also receives what the caller sends it later
(:meth:`PendingCall.send`, :func:`facegeo.jobs.reconstruct_into_folder`'s export: it starts on
the fit's geometry and receives the maps when the texture stages end): the function gets one more
argument, ``receive``, that waits for the next object sent.
os.fork by hand rather than a ProcessPoolExecutor: the executor's idle worker prints a traceback
on Ctrl-C, and Python 3.11's executor cannot end a worker that is still working.
:func:`beside_child` (:func:`beside_children`) is the pattern every caller follows: this process's part while the child
works, then the child's answer, or the same work here where there is no child or it was lost.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import signal
import struct
import sys
import threading
import traceback
from collections.abc import Callable
from typing import Any, TypeVar

from facegeo.errors import FacegeoError

__all__ = ["can_fork", "fork_call", "beside_child", "beside_children", "wait_for_exits", "PendingCall", "ChildLost"]

Here = TypeVar("Here")
Theirs = TypeVar("Theirs")


class ChildLost(RuntimeError):
    """The forked child ended without an answer (killed by a signal, e.g. by the kernel when
    memory ran out): the caller may run the function itself instead. ``how``: e.g. "by signal SIGKILL"."""

    def __init__(self, how: str):
        self.how = how
        super().__init__(f"the forked process ended {how} without an answer")


def can_fork() -> bool:
    """Whether :func:`fork_call` helps here: ``fork`` exists, this process may have children, and
    torch is not imported yet (once it is, the caller has nothing left to overlap)."""
    return ("fork" in multiprocessing.get_all_start_methods() and not multiprocessing.current_process().daemon
            and "torch" not in sys.modules)


class PendingCall:
    """A call under way in a forked child (:func:`fork_call`): collect it once with
    :meth:`result`, or :meth:`abandon` it."""

    def __init__(self, pid: int, pipe: int, inbox: int | None = None):
        self._pid, self._pipe, self._inbox = pid, pipe, inbox
        self._reaped = False  # the child's exit collected, or left to a thread after its answer: its pid is not ours to signal
        self._sending: list[threading.Thread] = []

    def send(self, value: Any) -> None:
        """Send ``value`` (it must pickle) to the child's ``receive`` (a call forked with
        ``inbox=True``), on a thread of its own, so that this process goes on while the child
        reads; a child that has ended meanwhile is reported by :meth:`result`, not here."""
        if self._inbox is None:
            raise RuntimeError("send: the call was forked without an inbox")
        payload = pickle.dumps(value, protocol=pickle.HIGHEST_PROTOCOL)
        inbox = self._inbox

        def write() -> None:
            try:
                os.write(inbox, struct.pack("<Q", len(payload)))
                view = memoryview(payload)
                while view:
                    view = view[os.write(inbox, view):]
            except OSError:  # the child is gone (EPIPE): result() says how
                pass

        # one sender at a time, in order
        previous = self._sending[-1] if self._sending else None
        thread = threading.Thread(target=lambda: (previous.join() if previous else None, write()), daemon=True,
                                  name="facegeo-send")
        self._sending.append(thread)
        thread.start()

    def _close_inbox(self) -> None:
        for thread in self._sending:
            thread.join()
        if self._inbox is not None:
            try:
                os.close(self._inbox)
            except OSError:
                pass
            self._inbox = None

    def result(self) -> Any:
        """Wait for the child: the function's answer, or its exception raised here
        (:class:`ChildLost` when the child ended without one; KeyboardInterrupt when SIGINT or
        SIGTERM ended it: an interruption meant for the caller too, even where the caller's own
        handler missed it)."""
        chunks = []
        self._close_inbox()  # after what was sent: a child that waits for more gets EOFError
        with os.fdopen(self._pipe, "rb") as pipe:
            while chunk := pipe.read(1 << 20):
                chunks.append(chunk)
        if chunks:  # answered: its exit status says nothing more, and the exit (the kernel freeing
            # its memory) took 15-35 ms after the answer of the reconstruct's export child: reaped on a thread
            self._reaped = True
            _Reaper(self._pid).start()
            kind, value = pickle.loads(b"".join(chunks))
            if kind == "error":
                raise value
            return value
        _, status = os.waitpid(self._pid, 0)
        self._reaped = True
        if os.WIFSIGNALED(status) and os.WTERMSIG(status) in (signal.SIGINT, signal.SIGTERM):
            raise KeyboardInterrupt(f"the forked process ended {_ended(status)}")  # the user's interruption reached it
        raise ChildLost(_ended(status))

    def abandon(self) -> None:
        """Stop the child (the parent failed first or was interrupted): nothing is collected. A
        call whose :meth:`result` already waited for the child (it raised the child's error) has
        nothing left to stop: the caller's exception stands as it is."""
        if self._reaped:
            return
        try:
            os.kill(self._pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(self._pid, 0)
        self._reaped = True
        self._close_inbox()
        try:
            os.close(self._pipe)
        except OSError:  # result() had closed it
            pass


class _Reaper(threading.Thread):
    """A daemon thread collecting the exit of the child ``pid``, which has answered
    (:meth:`PendingCall.result`)."""

    def __init__(self, pid: int):
        super().__init__(daemon=True, name="facegeo-reap")
        self.pid = pid

    def run(self) -> None:
        try:
            os.waitpid(self.pid, 0)
        except ChildProcessError:  # collected already (a caller's own os.waitpid(-1, ...))
            pass


def wait_for_exits() -> None:
    """Wait until every child that answered has been reaped: before this process ends, so that
    none is left to the system (the ``facegeo`` command's quick exit, :func:`facegeo.cli.run`,
    and its CPU counted with this process's children). The reapers are the live threads of
    their kind, so a long-lived process keeps none that has ended."""
    for thread in threading.enumerate():
        if isinstance(thread, _Reaper):
            thread.join()


def _receiver(inbox: int) -> Callable[[], Any]:
    """The child's ``receive``: the next object sent through the pipe ``inbox`` (length-framed
    pickles, :meth:`PendingCall.send`); EOFError once the caller has closed it."""

    def read(size: int) -> bytes:
        chunks, left = [], size
        while left:
            chunk = os.read(inbox, min(left, 1 << 22))
            if not chunk:
                raise EOFError("the caller sent nothing more")
            chunks.append(chunk)
            left -= len(chunk)
        return b"".join(chunks)

    def receive() -> Any:
        (size,) = struct.unpack("<Q", read(8))
        return pickle.loads(read(size))

    return receive


def _ended(status: int) -> str:
    if os.WIFSIGNALED(status):
        return f"by signal {signal.Signals(os.WTERMSIG(status)).name}"
    return f"with exit status {os.WEXITSTATUS(status)}"


def fork_call(function: Callable[..., Any], *args: Any, inbox: bool = False) -> PendingCall:
    """Fork a child that runs ``function(*args)`` (check :func:`can_fork` first); the answer and
    any exception must pickle. ``inbox``: call ``function(*args, receive)`` instead, where
    ``receive()`` returns the next object the caller sends (:meth:`PendingCall.send`) and raises
    EOFError once the caller can send no more."""
    # OpenCV's pthreads pool does not survive a fork: a child whose parent's pool threads were
    # waiting hangs for ever in its first parallel call or cv2.setNumThreads (a photo downscaled
    # by cv2.resize was enough). With one thread the pool is stopped, so the child inherits none
    # and runs OpenCV in its own thread; the caller gets its count back once the child exists.
    cv2 = sys.modules.get("cv2")
    cv2_threads = cv2.getNumThreads() if cv2 is not None else 0
    if cv2 is not None:
        cv2.setNumThreads(1)
    read_end, write_end = os.pipe()
    inbox_read, inbox_write = os.pipe() if inbox else (None, None)
    try:
        pid = os.fork()
    except BaseException:
        for end in (read_end, write_end, inbox_read, inbox_write):
            if end is not None:
                os.close(end)
        if cv2 is not None:  # the caller: its count back
            cv2.setNumThreads(cv2_threads)
        raise
    if pid:
        try:
            if cv2 is not None:  # the caller: its count back
                cv2.setNumThreads(cv2_threads)
            os.close(write_end)
            if inbox_read is not None:
                os.close(inbox_read)
            return PendingCall(pid, read_end, inbox_write)
        except BaseException:  # interrupted before the caller holds the child: stop it here
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            raise
    code = 1
    try:  # the child: never returns into the caller's code
        os.close(read_end)
        if inbox_write is not None:
            os.close(inbox_write)
            args = (*args, _receiver(inbox_read))
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, signal.SIG_DFL)
        from facegeo.concurrency import native_threads

        try:
            with native_threads(1):  # the caller keeps the other core busy: one thread each
                payload = pickle.dumps(("ok", function(*args)))
        except Exception as error:  # raised in the caller: the user's clear error, or the failure with its traceback
            if not isinstance(error, FacegeoError):
                error = RuntimeError(f"{getattr(function, '__name__', 'the call')} failed in a forked process:\n{traceback.format_exc()}")
            payload = pickle.dumps(("error", error))
        if inbox_read is not None:  # a caller still sending gets EPIPE instead of waiting for a reader
            os.close(inbox_read)
        with os.fdopen(write_end, "wb") as pipe:
            pipe.write(payload)
        code = 0
    finally:
        os._exit(code)


def beside_child(start: Callable[[], PendingCall | None], here: Callable[[], Here],
                 instead: Callable[[ChildLost | None], Theirs],
                 answer: Callable[[Any], Theirs | None] | None = None) -> tuple[Here, Theirs]:
    """``(here(), theirs)``: :func:`beside_children` with one child, started by ``start`` (which
    returns its :class:`PendingCall`, or None for none), and its ``instead(lost)``."""
    mine, (theirs,) = beside_children([start], here, lambda _, lost: instead(lost), answer)
    return mine, theirs


def beside_children(starts: list[Callable[[], PendingCall | None]], here: Callable[[], Here],
                    instead: Callable[[int, ChildLost | None], Theirs],
                    answer: Callable[[Any], Theirs | None] | None = None) -> tuple[Here, list[Theirs]]:
    """``(here(), [theirs, ...])``: this process's part, run while the children that ``starts``
    fork work (each returns its :class:`PendingCall`, usually :func:`fork_call`'s, or None for
    none there), with this process's native pools at as many threads fewer meanwhile (each child
    runs on one: :func:`facegeo.concurrency.native_threads`), and each child's part, in order:
    its answer (``answer`` of what it returned, where given; None refuses it), else
    ``instead(k, lost)``, the same work here, where there is no child (``lost`` None), its answer
    was refused (None) or it ended without one (``lost`` the :class:`ChildLost`, which says how).
    A child's own error is raised here. The children are started here, so that every one started
    is stopped if this process fails or is interrupted first (a Ctrl-C between a fork and the
    caller's guard left the child behind)."""
    import contextlib

    from facegeo.concurrency import native_threads, usable_threads

    pendings: list[PendingCall | None] = []
    try:
        for start in starts:
            pendings.append(start())
        children = sum(pending is not None for pending in pendings)
        with native_threads(max(1, usable_threads() - children)) if children else contextlib.nullcontext():
            mine = here()
        parts = []
        for k, pending in enumerate(pendings):
            lost: ChildLost | None = None
            theirs: Theirs | None = None
            if pending is not None:
                try:
                    returned = pending.result()
                    theirs = answer(returned) if answer is not None else returned
                except ChildLost as error:
                    lost = error
            parts.append(instead(k, lost) if theirs is None else theirs)
        return mine, parts
    except BaseException:
        for pending in pendings:
            if pending is not None:
                pending.abandon()
        raise
