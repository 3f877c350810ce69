"""Keeping what native libraries print out of facegeo's stderr.

Some libraries write to file descriptor 2 from C/C++ code, past Python's ``sys.stderr``: libpng
("libpng error: Read Error" on a truncated PNG, which facegeo then reports itself as an
:class:`~facegeo.errors.InputError`) and LiteRT ("INFO: Created TensorFlow Lite XNNPACK delegate
for CPU." whenever an interpreter is created). :func:`silenced_native_stderr` points descriptor 2
at ``/dev/null`` around such a call, so an error stays the one line the ``facegeo`` command
promises.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from typing import Iterator

__all__ = ["silenced_native_stderr"]

_LOCK = threading.RLock()  # descriptor 2 is process-wide: one silenced section at a time


@contextlib.contextmanager
def silenced_native_stderr() -> Iterator[None]:
    """Discard everything written to file descriptor 2 inside the ``with`` block (Python's own
    ``sys.stderr`` output of the block included; exceptions still propagate)."""
    with _LOCK:
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError, OSError):
            pass
        try:
            saved = os.dup(2)
        except OSError:  # no descriptor 2 (a daemon, a closed stderr): nothing to silence
            yield
            return
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 2)
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            os.close(devnull)
