"""The ``facegeo`` console command's entry point (pyproject: ``facegeo = "facegeo.cli:run"``;
also ``python -m facegeo.cli``). The commands, their parser and :func:`main` live in
:mod:`facegeo.commands`."""

from __future__ import annotations

import os
import sys
import threading
from typing import NoReturn

from facegeo.concurrency import one_blas_thread_by_default

one_blas_thread_by_default()  # before NumPy is imported

from facegeo.commands import build_parser, main  # noqa: E402  (after the BLAS default)

__all__ = ["main", "build_parser", "run"]


def run() -> NoReturn:
    """The console command: :func:`main`, then the process ends with its exit status.

    Where nothing is left to finish (no thread alive but this one and daemons, which exit would
    stop anyway; no child process, once the forked children that answered are reaped; every
    output already committed by the command), it ends at once after flushing stdout and stderr instead
    of unloading the interpreter's modules one by one, which takes about half a second once
    torch is loaded; otherwise the usual ``sys.exit``.
    """
    status = main()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except OSError:  # a closed pipe: nothing more can be said
        pass
    forked = sys.modules.get("facegeo.forked_call")
    if forked is not None:  # the children that answered, reaped while this process finished its files
        forked.wait_for_exits()
    children = sys.modules.get("multiprocessing")
    others = [t for t in threading.enumerate() if t is not threading.current_thread() and not t.daemon]
    if not others and (children is None or not children.active_children()):
        os._exit(status)
    sys.exit(status)


if __name__ == "__main__":
    run()
