"""Reading a file that ``torch.save`` wrote (checkpoints, state dicts) from a user's path, with
the project's error instead of torch's: one :class:`~facegeo.errors.InputError` naming the file."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch

from facegeo.errors import InputError

__all__ = ["read_torch_file"]


def read_torch_file(path: str | os.PathLike[str], what: str) -> Any:
    """The object in the torch file ``path``, loaded on the CPU with ``weights_only=True``
    (tensors, containers and plain values only; no code runs).

    Args:
        path: the file. what: what it should be, for the error (e.g. ``"regressor checkpoint"``).
    Raises:
        InputError: naming the file and ``what`` when it is missing, truncated or not a torch file.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(p, what, "an existing file", "no such file")
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises RuntimeError, EOFError, UnpicklingError, zipfile errors...
        first_line = str(exc).splitlines()[0] if str(exc) else "truncated"
        raise InputError(p, what, "a complete torch.save file", f"unreadable ({type(exc).__name__}: {first_line})") from None
