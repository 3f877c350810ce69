"""The on-disk cache of what depends only on a UV layout, a model and a map size: the UV raster
(:func:`facegeo.uv.rasterize_uv`) and the layout priors (:func:`facegeo.texturing.context.layout_priors`),
the default model's arrays as loaded (:func:`facegeo.model_files.load_model`), and the OBJ text
of a mesh's UV layout (its ``vt`` and ``f`` lines, :func:`facegeo.mesh_io.obj_text`).

Computing the first two for the bundled model at S = 1024 takes ~0.7 s, reading the model ~0.1 s;
loading them from here takes milliseconds, since the arrays are memory-mapped read-only (``np.load(..., mmap_mode="r")``),
which forked children share page for page. The folder is ``$FACEGEO_LAYOUT_CACHE`` where that is
set, else ``layout/`` under :func:`facegeo.cache_dir.cache_dir`::

    layout/<code version>/<entry>/manifest.json    {"arrays": {name: {"dtype", "shape"}}, "meta": {...}}
    layout/<code version>/<entry>/<name>.npy       one C-ordered array per name

The entry's name is its key (the layout's, the model's digest, the size and padding; the model file's
path, modification time and size; chosen by the caller); the code version (:func:`code_version`) is a digest of the source of
:data:`CODE_MODULES`, which compute the arrays, and of the versions of NumPy, SciPy and OpenCV,
so an edited algorithm or an upgrade never reads an entry made by other code. Storing an entry
removes the folders of other code versions (a process still mapping one keeps its files until it
exits).

An entry is written into a temporary sibling folder and renamed into place, so a reader never
sees half of one; where the entry appeared meanwhile (another process) the new copy is dropped.
An entry that cannot be read (a missing or truncated file, a shape or dtype other than its
manifest's, an unreadable manifest) is a miss, and is replaced when stored again. Writing never
fails a run: an ``OSError`` (read-only home, full disk) leaves nothing behind and the caller keeps
the values it computed.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.machinery
import importlib.util
import json
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from facegeo.cache_dir import cache_dir
from facegeo.errors import InputError

T = TypeVar("T")

__all__ = ["CODE_MODULES", "LAYOUT_CACHE_ENV", "code_version", "entry_folder", "load_entry", "store_entry", "load_or_make"]

#: Environment variable naming another folder for the cache (the tests point it at a temporary one).
LAYOUT_CACHE_ENV = "FACEGEO_LAYOUT_CACHE"
#: The modules whose code computes or stores the cached arrays: the rasteriser and its texel
#: geometry, the layout priors (mirror map, surface operators), the region and skin masks and the
#: iBUG indices they use, the sRGB encoding of the mean texture, the model's reading and
#: validation, the OBJ writer, and this module (the format).
CODE_MODULES = (
    "facegeo.uv.raster",
    "facegeo.uv._triangles",
    "facegeo.uv.texels",
    "facegeo.texturing.context",
    "facegeo.skin_mask",
    "facegeo.landmarks.scheme",
    "facegeo.colour",
    "facegeo.model_files",
    "facegeo.morphable_model",
    "facegeo.mesh_io",
    "facegeo.layout_cache",
)
_MANIFEST = "manifest.json"
_VERSION_NAME = re.compile(r"[0-9a-f]{32}")


def _layout_cache_dir() -> Path:
    override = os.environ.get(LAYOUT_CACHE_ENV, "").strip()
    return Path(override).expanduser() if override else cache_dir() / "layout"


def _source_file(module: str) -> Path:
    """The source file of ``module``, found without importing it (only its parent packages)."""
    package, _, name = module.rpartition(".")
    spec = importlib.machinery.PathFinder.find_spec(name, importlib.util.find_spec(package).submodule_search_locations)
    return Path(spec.origin)


@functools.cache
def code_version() -> str:
    """32 hex digits: a digest of the source bytes of :data:`CODE_MODULES`, of the NumPy and
    OpenCV versions and of SciPy's ``scipy/version.py`` (its version and git revision; read, not
    imported: importing scipy is 20 ms of a command that may not need it), computed once per process."""
    import cv2

    h = hashlib.blake2b(digest_size=16)
    for module in CODE_MODULES:
        h.update(module.encode() + b"\0" + _source_file(module).read_bytes() + b"\0")
    h.update(f"numpy {np.__version__} opencv {cv2.__version__}\0".encode())
    h.update(_source_file("scipy.version").read_bytes())
    return h.hexdigest()


def entry_folder(name: str) -> Path:
    """The folder of the entry ``name`` (its key, a valid file name) for the current code."""
    return _layout_cache_dir() / code_version() / name


def _manifest(folder: Path) -> Any:
    """The parsed manifest of the entry ``folder`` (raises OSError or ValueError)."""
    return json.loads((folder / _MANIFEST).read_text(encoding="utf-8"))


def load_entry(folder: Path) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
    """The arrays (name -> read-only, C-contiguous plain ndarray views of memory maps, in the
    manifest's order) and the ``meta`` dictionary stored in ``folder``; None when the entry is
    missing, incomplete or damaged."""
    try:
        manifest = _manifest(folder)
        arrays = {}
        for name, spec in manifest["arrays"].items():
            a = np.load(folder / f"{name}.npy", mmap_mode="r", allow_pickle=False)
            if a.dtype.str != spec["dtype"] or list(a.shape) != spec["shape"] or not a.flags.c_contiguous:
                return None
            arrays[name] = np.asarray(a)  # (np.memmap's subclass costs time on every operation)
        return arrays, dict(manifest["meta"])
    except (OSError, EOFError, ValueError, KeyError, TypeError, AttributeError):
        return None


def store_entry(folder: Path, arrays: Mapping[str, np.ndarray], meta: Mapping[str, Any]) -> None:
    """Write ``arrays`` (name -> array; names are file stems) and the JSON-serialisable ``meta``
    as the entry ``folder`` (see the module's docstring: atomic; an existing entry is kept where it
    loads and its manifest equals this one, i.e. another process stored the same, else replaced;
    any ``OSError`` swallowed with nothing left behind), then remove the folders of other code
    versions."""
    staging: Path | None = None
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", dir=folder.parent))
        described: dict[str, dict[str, Any]] = {}
        for name, a in arrays.items():
            a = np.ascontiguousarray(a)
            np.save(staging / f"{name}.npy", a, allow_pickle=False)
            described[name] = {"dtype": a.dtype.str, "shape": list(a.shape)}
        manifest = json.dumps({"arrays": described, "meta": dict(meta)})
        (staging / _MANIFEST).write_text(manifest, encoding="utf-8")
        try:
            os.rename(staging, folder)
        except OSError:  # the entry exists: the same from another process (kept) or a damaged one (replaced)
            try:
                if load_entry(folder) is not None and _manifest(folder) == json.loads(manifest):
                    return
            except ValueError:
                pass
            shutil.rmtree(folder, ignore_errors=True)
            os.rename(staging, folder)
        staging = None
        version = folder.parent
        for other in version.parent.iterdir():
            if other != version and _VERSION_NAME.fullmatch(other.name) and other.is_dir():
                shutil.rmtree(other, ignore_errors=True)
    except OSError:
        pass
    finally:
        if staging is not None:
            shutil.rmtree(staging, ignore_errors=True)


def load_or_make(folder: Path, rebuild: Callable[[dict[str, np.ndarray], dict[str, Any]], T | None], make: Callable[[], T],
                 entry: Callable[[T], tuple[Mapping[str, np.ndarray], Mapping[str, Any]]]) -> T:
    """The object stored in the entry ``folder``, rebuilt from its arrays and meta by ``rebuild``;
    where there is none or it is unusable (:func:`load_entry` finds none, or ``rebuild`` returns
    None or refuses it with a KeyError, TypeError, ValueError or the object's own
    :class:`facegeo.errors.InputError`: a damaged entry), ``make()``'s, stored as ``entry(made)``
    (:func:`store_entry`)."""
    found = load_entry(folder)
    if found is not None:
        try:
            rebuilt = rebuild(*found)
        except (KeyError, TypeError, ValueError, InputError):
            rebuilt = None
        if rebuilt is not None:
            return rebuilt
    made = make()
    store_entry(folder, *entry(made))
    return made
