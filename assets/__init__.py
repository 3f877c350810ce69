"""Bundled run-time data (installed as ``facegeo.assets``); see ``assets/README.md``.

Each sub-folder holds the data, its licence and the script that made it.
"""

from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["asset_path"]


def asset_path(relative: str) -> Path:
    """Absolute path of a bundled file, e.g. ``asset_path("ict_facekit/ict_face_model.npz")``.

    Raises FileNotFoundError naming the file when the installation lacks it.
    """
    path = Path(str(files(__name__).joinpath(relative)))
    if not path.is_file():
        raise FileNotFoundError(f"bundled asset missing: {path} (reinstall facegeo)")
    return path
