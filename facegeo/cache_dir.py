"""The folder of facegeo's on-disk caches (the converted dlib predictor, the layout cache)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["cache_dir"]


def cache_dir() -> Path:
    """``$XDG_CACHE_HOME/facegeo``, or ``~/.cache/facegeo`` where that variable is unset or
    empty (not created here: writers make the subfolders they need)."""
    root = os.environ.get("XDG_CACHE_HOME", "").strip()
    return (Path(root).expanduser() if root else Path.home() / ".cache") / "facegeo"
