"""Which array library an argument belongs to, decided without importing torch.

Functions that take NumPy arrays or torch tensors (the projection, the SH basis) compute with the
argument's own library. Importing torch costs about two seconds, and ``facegeo fit`` never needs
it: a value can only be a tensor if torch is already imported, so ``sys.modules`` is asked first.
"""

from __future__ import annotations

import sys
from types import ModuleType
from typing import Any

import numpy as np

__all__ = ["is_tensor", "array_namespace"]


def is_tensor(value: Any) -> bool:
    """True when ``value`` is a ``torch.Tensor`` (False, without importing torch, when torch has
    not been imported)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(value, torch.Tensor)


def array_namespace(value: Any) -> ModuleType:
    """``torch`` for a tensor, else ``numpy``: the module whose functions (``stack``, ``einsum``,
    ``ones_like``, ``swapaxes``, ...) compute on ``value`` in its own type."""
    return sys.modules["torch"] if is_tensor(value) else np
