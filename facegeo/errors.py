"""The one error type a user sees, and the input checks that raise it.

Every failure caused by bad input (an unreadable photo, a malformed model file, a missing face)
is a :class:`FacegeoError` whose message names the file, the field and what was expected. The CLI
prints that message alone (no traceback) and exits with status 2.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["FacegeoError", "InputError", "ModelFileError", "NoFaceError"]


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


class ModelFileError(InputError):
    """A morphable-model file is missing, unreadable or has wrong keys, shapes or values."""


class NoFaceError(InputError):
    """No face (or no usable face) was found in an image."""
