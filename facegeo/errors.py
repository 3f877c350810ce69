"""The one error type a user sees, and the input checks that raise it.

Every failure caused by bad input (an unreadable photo, a malformed model file, a missing face)
is a :class:`FacegeoError` whose message names the file, the field and what was expected. The CLI
prints that message alone (no traceback) and exits with status 2.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from facegeo.array_namespace import is_tensor  # asks sys.modules: errors.py never imports torch

__all__ = ["FacegeoError", "InputError", "ModelFileError", "NoFaceError", "OutputError", "check_finite"]


class FacegeoError(Exception):
    """Base class of the errors facegeo raises for bad input or failed stages."""


class InputError(FacegeoError):
    """Bad input data: ``InputError(source, field, expected, found)``.

    ``source`` is the file (or ``"<array>"`` for in-memory data), ``field`` what was read,
    ``expected`` what was required and ``found`` what was there instead.
    """

    def __init__(self, source: str | Path, field: str, expected: str, found: str | None = None):
        self.source = str(source)
        self.field = field
        self.expected = expected
        self.found = found
        message = f"{self.source}: {field}: expected {expected}"
        if found is not None:
            message += f", found {found}"
        super().__init__(message)

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled with its four fields (a forked fit or a batch worker sends it to the parent)."""
        return type(self), (self.source, self.field, self.expected, self.found)


class ModelFileError(InputError):
    """A morphable-model file is missing, unreadable or has wrong keys, shapes or values."""


class NoFaceError(InputError):
    """No face (or no usable face) was found in an image."""


class OutputError(FacegeoError):
    """Writing an output failed for a reason outside facegeo: ``OutputError(path, problem)``
    (a full disk, the file size limit, a read-only or failing file system, a folder that does
    not let this user write). Nothing partial is left behind."""

    def __init__(self, path: str | Path, problem: str):
        self.path = str(path)
        self.problem = problem
        super().__init__(f"{self.path}: output file: expected to be able to write it, found {problem}")

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled with its two fields."""
        return type(self), (self.path, self.problem)


def check_finite(values: Mapping[str, Any], source: str = "<array>") -> None:
    """Raise :class:`InputError` naming the first entry of ``values`` (name -> NumPy array, torch
    tensor or number) that holds NaN or ±inf: the one finiteness check at facegeo's public API
    boundaries. Fast path: one sum per value (NaN and ±inf survive a sum); only when the total
    is not finite are the values inspected one by one (a finite overflow passes)."""
    total = 0.0
    for value in values.values():
        total += float(value.detach().sum()) if is_tensor(value) else float(np.sum(_numeric(value), dtype=np.float64))
    if math.isfinite(total):
        return
    for name, value in values.items():
        if is_tensor(value):
            finite = value.detach().isfinite()
            bad, count = int((~finite).sum()), finite.numel()
        else:
            array = _numeric(value)
            bad, count = int((~np.isfinite(array)).sum()), array.size
        if bad:
            raise InputError(source, name, "finite values", f"{bad} of {count} values NaN or infinite")


def _numeric(value: Any) -> np.ndarray:
    array = np.asarray(value)
    return array if np.issubdtype(array.dtype, np.number) else np.zeros(0)
