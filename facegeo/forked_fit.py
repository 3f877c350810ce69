"""The first half of a reconstruction (skin mask and fit) in a forked process, beside the second's imports.

The fit needs NumPy, OpenCV, MediaPipe's LiteRT models and dlib; the texture stages need torch,
whose import alone takes about two seconds on two cores. One process cannot overlap them: an
import and the fit's Python both hold the GIL. So :func:`start_fit` forks a child that computes the
photo's skin mask and the fit while the parent imports the texture stages and loads the model,
and :meth:`PendingFit.result` collects them: the wall time of the slower half instead of the sum.

It only pays where torch is not imported yet (the first photo of a process) and only works where
``fork`` does (POSIX) and the process may have children (not a daemonic worker): :func:`can_fork_fit`
says so; elsewhere the caller computes both itself. The child inherits the parent's modules, the
loaded model and the photo; it pickles back through a pipe the :class:`facegeo.fitting.Fit`
(NumPy arrays and a dict), the :class:`facegeo.skin_mask.SkinMask` and its own seconds, or the
exception it raised (a :class:`facegeo.errors.FacegeoError` reaches the user as the same clear
error). The child takes the default action on SIGINT and SIGTERM (it ends without a word; the
parent reports the interruption) and writes no file; a parent that fails first kills it.
os.fork by hand rather than a ProcessPoolExecutor: the executor's idle worker would print a
traceback on Ctrl-C, and Python 3.11's executor cannot end a worker that is still fitting.
"""

from __future__ import annotations

import multiprocessing
import os
import pickle
import signal
import sys
import time
import traceback
from typing import TYPE_CHECKING

from facegeo.errors import FacegeoError

if TYPE_CHECKING:
    from facegeo.fitting import Fit
    from facegeo.jobs import FitOptions
    from facegeo.photo import Photo
    from facegeo.skin_mask import SkinMask

__all__ = ["can_fork_fit", "start_fit", "PendingFit", "fit_and_skin"]


def can_fork_fit() -> bool:
    """Whether :func:`start_fit` helps here: ``fork`` exists, this process may have children, and
    torch is not imported yet (once it is, the parent has nothing left to overlap)."""
    return ("fork" in multiprocessing.get_all_start_methods() and not multiprocessing.current_process().daemon
            and "torch" not in sys.modules)


def fit_and_skin(photo: Photo, source: str, options: FitOptions) -> tuple[Fit, SkinMask | None, float]:
    """The torch-free half of a reconstruction, in this process: ``(fit, skin mask or None when
    MediaPipe finds no face, seconds of the fit alone)``."""
    from facegeo.errors import NoFaceError
    from facegeo.fitting import fit
    from facegeo.jobs import loaded_resources, photo_camera
    from facegeo.skin_mask import skin_mask

    model, predictor = loaded_resources(options.model, options.regressor, options.refine, options.landmarks)
    try:  # the skin mask needs MediaPipe's mesh; without it the pipeline builds one from the fit's landmarks
        skin = skin_mask(photo.image, source=source)
    except NoFaceError:
        skin = None
    start = time.perf_counter()
    result = (predictor or fit)(photo, model=model, detector=options.landmarks,
                                camera=photo_camera(photo, options.focal, options.principal_point))
    return result, skin, time.perf_counter() - start


class PendingFit:
    """A fit under way in a forked child (:func:`start_fit`): collect it once with :meth:`result`,
    or :meth:`abandon` it."""

    def __init__(self, pid: int, pipe: int):
        self._pid, self._pipe = pid, pipe

    def result(self) -> tuple[Fit, SkinMask | None, float]:
        """Wait for the child: :func:`fit_and_skin`'s answer, or its exception raised here."""
        chunks = []
        with os.fdopen(self._pipe, "rb") as pipe:
            while chunk := pipe.read(1 << 20):
                chunks.append(chunk)
        _, status = os.waitpid(self._pid, 0)
        if not chunks:
            raise RuntimeError(f"the fit's process ended without an answer ({_ended(status)})")
        kind, value = pickle.loads(b"".join(chunks))
        if kind == "error":
            raise value
        return value

    def abandon(self) -> None:
        """Stop the child (the parent failed first or was interrupted): nothing is collected."""
        try:
            os.kill(self._pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(self._pid, 0)
        try:
            os.close(self._pipe)
        except OSError:  # result() had closed it
            pass


def _ended(status: int) -> str:
    if os.WIFSIGNALED(status):
        return f"signal {signal.Signals(os.WTERMSIG(status)).name}"
    return f"exit status {os.WEXITSTATUS(status)}"


def start_fit(photo: Photo, source: str, options: FitOptions) -> PendingFit:
    """Fork a child that runs :func:`fit_and_skin` (check :func:`can_fork_fit` first)."""
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid:
        os.close(write_end)
        return PendingFit(pid, read_end)
    code = 1
    try:  # the child: never returns into the caller's code
        os.close(read_end)
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, signal.SIG_DFL)
        import cv2
        from threadpoolctl import threadpool_limits

        cv2.setNumThreads(1)  # the parent keeps the other core busy with its imports: one thread each
        try:
            with threadpool_limits(limits=1):
                payload = pickle.dumps(("ok", fit_and_skin(photo, source, options)))
        except Exception as error:  # raised in the parent: the user's clear error, or the failure with its traceback
            if not isinstance(error, FacegeoError):
                error = RuntimeError(f"the fit failed in its forked process:\n{traceback.format_exc()}")
            payload = pickle.dumps(("error", error))
        with os.fdopen(write_end, "wb") as pipe:
            pipe.write(payload)
        code = 0
    finally:
        os._exit(code)
