"""Reading morphable-model files into :class:`~facegeo.morphable_model.MorphableModel`.

:func:`load_model` reads, by content (not by name):

1. facegeo's own ``.npz`` (the bundled ICT-FaceKit model is one; the layout is described in
   ``assets/ict_facekit/README.md``): float16 bases are widened to float32.
2. Tencent's Hifi3D-family MATLAB files, as their authors distribute them:

   * REALY's ``HIFI3D++.mat`` (keys ``mu_shape``, ``basis_shape``, ``basis_exp``, ``EVs``, ``tri``,
     ``mask_face``, ``keypoints``; the copies in circulation also hold ``vt_list``/``tri_vt``);
   * Tencent AI-NExT's ``AI-NExT-Shape*.mat`` (``mu_shape``, ``basis_shape``, ``basis_exp``,
     ``tri``, ``keypoints``, ``vt_list``, ``tri_vt``), optionally with the UV-space albedo basis
     ``AI-NExT-Albedo-Global.mat`` (``mu``, ``basis``, ``sigma``, ``indices``), passed as
     ``albedo_path=`` or found in the same folder.

How the Tencent layouts are read (sources: REALY ``HIFI3D++/demo.py`` and README; hifi3dface
``3DMM/scripts/test_basis_io.py``, ``utils/basis.py``, ``third_party/ply.py``,
``optimization/rgb/run_RGB_opt.py``, ``optimization/rgbd/RGBD_utils/AddHeadTool.py``; HRN's
Hifi3D++ face model for Deep3DFaceRecon):

* ``mu_shape`` is ``(1, 3V)`` and the bases ``(K, 3V)``, xyz interleaved per vertex
  (``reshape(V, 3)``); a ``(3V, K)`` basis is accepted and transposed.
* ``basis_shape`` is already scaled by the standard deviations (Tencent's code samples
  ``N(0, 1)`` coefficients against it and regularises all AI-NExT coefficients with equal
  weights), so coefficients are in σ units as they are. ``EVs`` (REALY: "eigenvalue", ``(K, 1)``)
  is only used when the basis turns out orthonormal (unit-norm rows): then row k is multiplied
  by ``sqrt(EVs[k])`` (eigenvalues of the covariance are variances). ``basis_exp`` is used as
  stored (coefficient 1 = one stored basis vector; HRN rescales it by 1/16 for conditioning).
* ``tri``, ``tri_vt`` and ``keypoints`` are used by Tencent's code as 0-based indices (``write_obj``
  adds 1, ``tf.gather`` uses them directly). The base is nevertheless detected: if ``tri`` holds
  the value V and no 0 it is 1-based, and ``keypoints`` follow ``tri``'s base; ``tri_vt`` is
  detected the same way against the number of UVs. Ambiguous cases are read as 0-based.
* ``keypoints`` are Tencent's 86-point markup (17 contour, 2x9 brows, 2x8 eyes, 4 nose bridge,
  11 nose outline, 20 mouth; groups and mirror pairs from hifi3dface ``utils/const.py``). They
  are mapped to iBUG-68 group by group; which member of a group is left/right or upper/lower is
  decided from the mean shape's coordinates, not assumed (see :func:`_ibug68_from_tencent86`).
  Eyelids and nose wing points are approximations (86 has 3 points per lid where iBUG has 2).
  A 68-point ``keypoints`` is taken as iBUG order. The 20 lip points of our 88 re-use 48..67.
* Units: the mean shape's largest bounding-box side decides (``units="auto"``): mm if in
  [80, 800), cm if in [8, 80), dm if in [0.8, 8), m if in [0.08, 0.8); REALY's HIFI3D template
  is about 35 units tall (cm). Axes are taken as they are (+Y up, +Z out of the face, as in
  REALY's HIFI3D template); a warning is given when the keypoints contradict that.
* Triangles are re-oriented counter-clockwise seen from outside when the file's winding is the
  other way (decided by the area-weighted outward flux).
* ``vt_list`` is ``(T, 2)`` with the origin bottom left (OBJ): Tencent samples a UV map at row
  ``(1 - v) * S``, column ``u * S``. A file with no UVs gets a cylindrical projection (seam at the
  back of the head) and a :class:`ModelFileWarning`; an albedo basis then cannot be used.
* The albedo ``indices`` are *not* vertices: they are the ``(row, column)`` pixels, 0-based, of an
  ``S x S`` UV image (S = 512 for the global basis; taken as the smallest power of two above the
  largest index) where ``mu`` (``3N`` values, 0..255 sRGB) and ``basis * sigma`` are defined.
  Each vertex takes the value at its UV pixel (the nearest defined pixel if its own is not),
  averaged over its UV corners; the result is converted to linear [0, 1] RGB, exactly for the
  mean and to first order (about the mean) for the basis.
* ``face_mask`` is ``mask_face != 0`` when present, else all vertices.

Every failure raises :class:`~facegeo.errors.ModelFileError` naming the file, the field and what
was expected.
"""

from __future__ import annotations

import os
import threading
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from facegeo.colour import srgb_to_linear_slope
from facegeo.errors import ModelFileError
from facegeo.landmarks.scheme import EYES, MOUTH, N_IBUG
from facegeo.morphable_model import MorphableModel
from facegeo.uv.texels import nearest_texel

__all__ = [
    "load_model",
    "ModelFileWarning",
    "MODEL_ENV_VAR",
    "DEFAULT_MODEL_ASSET",
    "NPZ_FORMAT_VERSION",
]

#: Environment variable naming the model file used when ``load_model()`` gets no path.
MODEL_ENV_VAR = "FACEGEO_MODEL"
#: The bundled default model, relative to ``facegeo.assets``.
DEFAULT_MODEL_ASSET = "ict_facekit/ict_face_model.npz"
#: The version of facegeo's own ``.npz`` layout that this module reads.
NPZ_FORMAT_VERSION = 1

_UNIT_SCALES = {"mm": 1.0, "cm": 10.0, "dm": 100.0, "m": 1000.0}
_NPZ_REQUIRED = (
    "format_version",
    "mean_shape",
    "id_basis",
    "exp_basis",
    "mean_albedo",
    "tex_basis",
    "triangles",
    "uv",
    "uv_triangles",
    "landmark_indices",
    "face_mask",
)
_NPZ_INDEX_KEYS = ("triangles", "uv_triangles", "landmark_indices")
_TENCENT_REQUIRED = ("mu_shape", "basis_shape", "tri", "keypoints")

_cache_lock = threading.Lock()
_default_cache: dict[tuple[str, int, int], MorphableModel] = {}


class ModelFileWarning(UserWarning):
    """A model file was read with a fallback (e.g. no UVs in the file)."""


# ---------------------------------------------------------------------------------------- public
def load_model(
    path: str | Path | None = None,
    *,
    albedo_path: str | Path | None = None,
    units: str = "auto",
) -> MorphableModel:
    """Read a morphable model file.

    Args:
        path: a facegeo ``.npz`` or a Tencent Hifi3D-family ``.mat``. None: the file named by the
            environment variable ``FACEGEO_MODEL`` if set, else the bundled ICT-FaceKit model;
            that default is read once and cached in memory (the same object is returned again,
            so do not modify it).
        albedo_path: for Tencent ``.mat`` files, the UV-space albedo basis
            (``AI-NExT-Albedo-Global.mat``). None: such a file in the same folder is used when
            present; without one the mean albedo is a uniform linear grey 0.5 and the texture
            basis is empty.
        units: length unit of a ``.mat`` file's coordinates: ``"auto"`` (from the mean shape's
            size), ``"mm"``, ``"cm"``, ``"dm"`` or ``"m"``. facegeo ``.npz`` files are always mm.

    Returns:
        The model, in mm, +Y up, +Z out of the face, coefficients in σ units.

    Raises:
        ModelFileError: the file is missing, not a model file, or has missing keys, wrong shapes
            or non-finite values.
    """
    if units not in ("auto", *_UNIT_SCALES):
        raise ValueError(f"units must be 'auto' or one of {sorted(_UNIT_SCALES)}, got {units!r}")
    if path is None and albedo_path is None and units == "auto":
        return _load_default()
    if path is None:
        path = _default_path()
    return _load(Path(path), albedo_path=albedo_path, units=units)


# ---------------------------------------------------------------------------------------- default
def _default_path() -> Path:
    env = os.environ.get(MODEL_ENV_VAR, "").strip()
    if env:
        return Path(env).expanduser()
    from facegeo.assets import asset_path

    try:
        return asset_path(DEFAULT_MODEL_ASSET)
    except FileNotFoundError as exc:
        raise ModelFileError(
            DEFAULT_MODEL_ASSET, "file", "the bundled default model (reinstall facegeo)", str(exc)
        ) from None


def _load_default() -> MorphableModel:
    path = _default_path()
    try:
        st = path.stat()
    except OSError:
        raise ModelFileError(path, "file", "an existing model file", "no such file") from None
    key = (str(path.resolve()), st.st_mtime_ns, st.st_size)
    with _cache_lock:
        cached = _default_cache.get(key)
        if cached is None:
            cached = _stored_default(path, key)
            _default_cache.clear()
            _default_cache[key] = cached
        return cached


#: The arrays of a :class:`MorphableModel` (its other fields are names).
_MODEL_ARRAYS = _NPZ_REQUIRED[1:]


def _stored_default(path: Path, key: tuple[str, int, int]) -> MorphableModel:
    """The default model read from ``path`` as it was stored in the layout cache
    (:mod:`facegeo.layout_cache`: its arrays as loaded and validated, memory-mapped read-only;
    an entry per install of the file, ``key`` = its path, modification time and size), or read
    and stored there: each process pays milliseconds instead of the archive's decompression and
    float16 conversion (~0.1 s for the bundled model)."""
    import hashlib

    from facegeo.layout_cache import entry_folder, load_or_make

    return load_or_make(
        entry_folder("model-" + hashlib.blake2b(repr(key).encode(), digest_size=16).hexdigest()),
        lambda arrays, meta: MorphableModel(source=str(path), name=str(meta["name"]), expression_kind=str(meta["expression_kind"]),
                                            expression_names=[str(n) for n in meta["expression_names"]],
                                            **{name: arrays[name] for name in _MODEL_ARRAYS}),
        lambda: _load(path, albedo_path=None, units="auto"),
        lambda model: ({name: getattr(model, name) for name in _MODEL_ARRAYS},
                       {"name": model.name, "expression_kind": model.expression_kind,
                        "expression_names": list(model.expression_names)}))


# ---------------------------------------------------------------------------------------- dispatch
def _load(path: Path, albedo_path: str | Path | None, units: str) -> MorphableModel:
    kind = _sniff(path)
    if kind == "npz":
        return _load_npz(path)
    data = _read_mat(path, kind)
    return _load_tencent(path, data, albedo_path=albedo_path, units=units)


def _sniff(path: Path) -> str:
    """'npz', 'mat5' or 'mat73' from the file's first bytes; ModelFileError otherwise."""
    if not path.exists():
        raise ModelFileError(path, "file", "an existing model file", "no such file")
    if not path.is_file():
        raise ModelFileError(path, "file", "a regular file", "a directory or special file")
    try:
        with path.open("rb") as handle:
            head = handle.read(528)
    except OSError as exc:
        raise ModelFileError(path, "file", "a readable file", str(exc)) from None
    if head.startswith(b"PK\x03\x04") or head.startswith(b"PK\x05\x06"):
        return "npz"
    if head[512:520] == b"\x89HDF\r\n\x1a\n" or head.startswith(b"\x89HDF\r\n\x1a\n"):
        return "mat73"
    if head.startswith(b"MATLAB") and len(head) >= 128:
        version = head[124:126]
        if version in (b"\x00\x02", b"\x02\x00"):
            return "mat73"
        return "mat5"
    found = "an empty file" if not head else f"unrecognised content starting {head[:16]!r}"
    raise ModelFileError(path, "file", "a facegeo .npz model or a MATLAB .mat model file", found)


# ---------------------------------------------------------------------------------------- npz
def _load_npz(path: Path) -> MorphableModel:
    try:
        archive = np.load(path, allow_pickle=False)
    except Exception as exc:  # zipfile.BadZipFile, ValueError, OSError ...
        raise ModelFileError(
            path, "file", "a readable .npz archive", f"{type(exc).__name__}: {exc}"
        ) from None
    with archive:
        keys = set(archive.files)
        for key in _NPZ_REQUIRED:
            if key not in keys:
                raise ModelFileError(path, key, "this key in a facegeo model .npz", "missing")
        try:
            arrays = {key: archive[key] for key in keys}
        except Exception as exc:
            raise ModelFileError(
                path, "arrays", "plain numeric arrays (no pickled objects)", str(exc)
            ) from None

    version = arrays["format_version"]
    if version.shape != () or version.dtype.kind not in "iu" or int(version) != NPZ_FORMAT_VERSION:
        raise ModelFileError(path, "format_version", f"{NPZ_FORMAT_VERSION}", repr(version.tolist()))
    for key in _NPZ_REQUIRED[1:]:
        arr = arrays[key]
        if key in _NPZ_INDEX_KEYS:
            if arr.dtype.kind not in "iu":
                raise ModelFileError(path, key, "an integer array", f"dtype {arr.dtype}")
        elif key == "face_mask":
            if arr.dtype.kind not in "biu":
                raise ModelFileError(path, key, "a boolean array", f"dtype {arr.dtype}")
        elif arr.dtype.kind not in "fiu":
            raise ModelFileError(path, key, "a floating-point array", f"dtype {arr.dtype}")
    names = arrays.get("expression_names", np.zeros(0, dtype=str))
    if names.dtype.kind not in "U" and names.size:
        raise ModelFileError(path, "expression_names", "an array of strings", f"dtype {names.dtype}")
    name = str(arrays["name"][()]) if "name" in arrays else path.stem
    # An npz states its expression kind; without the key, named expressions are blendshapes
    # (the bundled ICT-FaceKit model: ARKit-style weights on [0, 1]) and unnamed ones PCA.
    kind = str(arrays["expression_kind"][()]) if "expression_kind" in arrays else ("blendshape" if names.size else "pca")
    return _build(
        path,
        name=name,
        expression_kind=kind,
        expression_names=[str(n) for n in names.reshape(-1)],
        **{key: arrays[key] for key in _NPZ_REQUIRED[1:]},
    )


def _build(path: Path, **fields: Any) -> MorphableModel:
    try:
        return MorphableModel(source=str(path), **fields)
    except ModelFileError:
        raise
    except (ValueError, TypeError, OverflowError) as exc:
        raise ModelFileError(path, "arrays", "numeric arrays of the documented shapes", str(exc)) from None


# ---------------------------------------------------------------------------------------- mat files
def _read_mat(path: Path, kind: str) -> dict[str, np.ndarray]:
    """The numeric variables of a MATLAB file, in MATLAB's (row, column) orientation."""
    if kind == "mat73":
        return _read_mat73(path)
    import scipy.io

    try:
        raw = scipy.io.loadmat(str(path), squeeze_me=False, mat_dtype=False)
    except NotImplementedError:  # scipy's answer to v7.3 files it did not sniff as such
        return _read_mat73(path)
    except Exception as exc:
        raise ModelFileError(
            path, "file", "a readable MATLAB .mat file", f"{type(exc).__name__}: {exc}"
        ) from None
    return {k: v for k, v in raw.items() if not k.startswith("__") and isinstance(v, np.ndarray)}


def _read_mat73(path: Path) -> dict[str, np.ndarray]:
    try:
        import h5py
    except ImportError:
        raise ModelFileError(
            path,
            "file",
            "a MATLAB v5 .mat file, or h5py installed to read this MATLAB v7.3 (HDF5) file "
            "(pip install h5py, or re-save it in MATLAB with save(..., '-v7'))",
            "a v7.3 (HDF5) file and no h5py",
        ) from None
    out: dict[str, np.ndarray] = {}
    try:
        with h5py.File(path, "r") as handle:
            for key, item in handle.items():
                if isinstance(item, h5py.Dataset) and item.dtype.kind in "fiub":
                    out[key] = np.asarray(item[()]).T  # HDF5 stores MATLAB arrays transposed
    except Exception as exc:
        raise ModelFileError(
            path, "file", "a readable MATLAB v7.3 (HDF5) file", f"{type(exc).__name__}: {exc}"
        ) from None
    return out


def _get(path: Path, data: dict[str, np.ndarray], key: str, expected: str) -> np.ndarray:
    if key not in data:
        raise ModelFileError(path, key, expected, "missing")
    arr = np.asarray(data[key])
    if arr.dtype.kind not in "fiub":
        raise ModelFileError(path, key, expected, f"dtype {arr.dtype}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ModelFileError(path, key, "finite values", f"{int(np.sum(~np.isfinite(arr)))} NaN/inf entries")
    return arr


def _basis(path: Path, key: str, arr: np.ndarray, n_values: int) -> np.ndarray:
    """A (K, n) or (n, K) basis matrix -> (K, n)."""
    if arr.ndim == 2 and arr.shape[1] == n_values:
        return arr
    if arr.ndim == 2 and arr.shape[0] == n_values:
        return arr.T
    if arr.size == 0:
        return np.zeros((0, n_values), dtype=np.float64)
    raise ModelFileError(path, key, f"a (K, {n_values}) matrix (K components x 3V)", str(arr.shape))


def _indices(path: Path, key: str, arr: np.ndarray, columns: int | None) -> np.ndarray:
    """An integer-valued (N, columns) (or (columns, N)) / flat array as int64."""
    if columns is not None:
        if arr.ndim == 2 and arr.shape[1] != columns and arr.shape[0] == columns:
            arr = arr.T
        if arr.ndim != 2 or arr.shape[1] != columns:
            raise ModelFileError(path, key, f"an (N, {columns}) index array", str(arr.shape))
    else:
        arr = arr.reshape(-1)
    if arr.dtype.kind == "f":
        if not np.all(arr == np.round(arr)):
            raise ModelFileError(path, key, "integer indices", "non-integer values")
    return arr.astype(np.int64)


def _index_base(values: np.ndarray, count: int) -> int:
    """0 or 1: 1 when the indices contain ``count`` and no 0, else 0."""
    if values.size and values.min() >= 1 and values.max() == count:
        return 1
    return 0


def _check_range(path: Path, key: str, values: np.ndarray, count: int, base: int) -> np.ndarray:
    out = values - base
    if out.size and (out.min() < 0 or out.max() >= count):
        raise ModelFileError(
            path,
            key,
            f"{base}-based indices in [{base}, {count + base})",
            f"range [{values.min()}, {values.max()}]",
        )
    return out


def _load_tencent(
    path: Path, data: dict[str, np.ndarray], albedo_path: str | Path | None, units: str
) -> MorphableModel:
    for key in _TENCENT_REQUIRED:
        if key not in data:
            raise ModelFileError(
                path, key, "this key of a Tencent Hifi3D/AI-NExT or REALY HIFI3D++ model .mat", "missing"
            )
    mu = _get(path, data, "mu_shape", "a (1, 3V) float array")
    if mu.size == 0 or mu.size % 3 or (mu.ndim == 2 and min(mu.shape) != 1) or mu.ndim > 2:
        raise ModelFileError(path, "mu_shape", "a (1, 3V) float array", str(mu.shape))
    n_vertices = mu.size // 3
    n_values = 3 * n_vertices
    mean = mu.reshape(n_vertices, 3).astype(np.float64)

    id_basis = _basis(path, "basis_shape", _get(path, data, "basis_shape", "a (K, 3V) float array"), n_values)
    if "basis_exp" in data:
        exp_basis = _basis(
            path, "basis_exp", _get(path, data, "basis_exp", "a (K, 3V) float array"), n_values
        )
    else:
        warnings.warn(
            f"{path}: no basis_exp; the model has no expression components", ModelFileWarning, stacklevel=3
        )
        exp_basis = np.zeros((0, n_values))
    id_basis = id_basis.astype(np.float64)
    if "EVs" in data:
        evs = _get(path, data, "EVs", f"({id_basis.shape[0]}, 1) eigenvalues").reshape(-1).astype(np.float64)
        if evs.size != id_basis.shape[0]:
            raise ModelFileError(
                path, "EVs", f"{id_basis.shape[0]} values (one per basis_shape row)", str(evs.size)
            )
        norms = np.linalg.norm(id_basis, axis=1)
        if id_basis.shape[0] and np.all(np.abs(norms - 1.0) < 1e-3):
            if np.any(evs < 0):
                raise ModelFileError(path, "EVs", "non-negative eigenvalues", f"min {evs.min()}")
            id_basis = id_basis * np.sqrt(evs)[:, None]

    # ---- units
    extent = float(np.max(mean.max(axis=0) - mean.min(axis=0)))
    scale = _unit_scale(path, extent, units)
    mean *= scale
    id_basis = id_basis.reshape(-1, n_vertices, 3) * scale
    exp_basis = exp_basis.astype(np.float64).reshape(-1, n_vertices, 3) * scale

    # ---- mesh
    tri_raw = _indices(path, "tri", _get(path, data, "tri", "an (F, 3) index array"), 3)
    base = _index_base(tri_raw, n_vertices)
    triangles = _check_range(path, "tri", tri_raw, n_vertices, base)
    if triangles.shape[0] == 0:
        raise ModelFileError(path, "tri", "at least one triangle", "none")
    keypoints = _check_range(
        path,
        "keypoints",
        _indices(path, "keypoints", _get(path, data, "keypoints", "a (1, K) index array"), None),
        n_vertices,
        base,
    )

    has_uv = "vt_list" in data and "tri_vt" in data
    if has_uv:
        uv = _get(path, data, "vt_list", "a (T, 2) float array").astype(np.float64)
        if uv.ndim == 2 and uv.shape[1] != 2 and uv.shape[0] == 2:
            uv = uv.T
        if uv.ndim != 2 or uv.shape[1] != 2 or uv.shape[0] == 0:
            raise ModelFileError(path, "vt_list", "a (T, 2) float array", str(uv.shape))
        tri_vt_raw = _indices(path, "tri_vt", _get(path, data, "tri_vt", "an (F, 3) index array"), 3)
        if tri_vt_raw.shape[0] != triangles.shape[0]:
            raise ModelFileError(
                path, "tri_vt", f"({triangles.shape[0]}, 3), one row per tri row", str(tri_vt_raw.shape)
            )
        if tri_vt_raw.min() == 0:
            vt_base = 0
        elif tri_vt_raw.max() == uv.shape[0]:
            vt_base = 1
        else:
            vt_base = base  # ambiguous: follow tri
        uv_triangles = _check_range(path, "tri_vt", tri_vt_raw, uv.shape[0], vt_base)
    else:
        warnings.warn(
            f"{path}: no vt_list/tri_vt (UVs) in the file; using a cylindrical UV projection with a "
            "seam at the back of the head (texture maps will not match Tencent's UV layout)",
            ModelFileWarning,
            stacklevel=3,
        )
        uv, uv_triangles = _cylindrical_uv(mean, triangles)

    if _outward_flux(mean, triangles) < 0:
        triangles = triangles[:, [0, 2, 1]]
        uv_triangles = uv_triangles[:, [0, 2, 1]]

    # ---- landmarks, mask
    if keypoints.size == N_IBUG:
        ibug = keypoints
    elif keypoints.size == 86:
        ibug = _ibug68_from_tencent86(keypoints, mean)
    else:
        raise ModelFileError(
            path, "keypoints", "68 (iBUG) or 86 (Tencent) vertex indices", f"{keypoints.size}"
        )
    _check_axes(path, mean, ibug)
    landmark_indices = np.concatenate([ibug, ibug[MOUTH]])  # the lip points re-use the mouth's vertices

    if "mask_face" in data:
        mask = _get(path, data, "mask_face", f"a (1, {n_vertices}) 0/1 array").reshape(-1)
        if mask.size != n_vertices:
            raise ModelFileError(path, "mask_face", f"{n_vertices} values (one per vertex)", str(mask.size))
        face_mask = mask != 0
    else:
        face_mask = np.ones(n_vertices, dtype=bool)

    # ---- albedo
    mean_albedo = np.full((n_vertices, 3), 0.5)
    tex_basis = np.zeros((0, n_vertices, 3))
    albedo_file = Path(albedo_path) if albedo_path is not None else _find_albedo(path)
    if albedo_file is not None:
        if not has_uv:
            if albedo_path is not None:
                raise ModelFileError(
                    path, "vt_list", "UVs (vt_list, tri_vt) to map the albedo basis onto vertices", "missing"
                )
            warnings.warn(
                f"{path}: no UVs, so {albedo_file.name} is not used", ModelFileWarning, stacklevel=3
            )
        else:
            mean_albedo, tex_basis = _vertex_albedo(albedo_file, n_vertices, triangles, uv_triangles, uv)

    layout = "HIFI3D++ (REALY)" if "EVs" in data else "Tencent AI-NExT"
    name = (
        f"{path.stem} ({layout}: {id_basis.shape[0]} id, {exp_basis.shape[0]} exp, {tex_basis.shape[0]} tex)"
    )
    return _build(
        path,
        mean_shape=mean,
        id_basis=id_basis,
        exp_basis=exp_basis,
        mean_albedo=mean_albedo,
        tex_basis=tex_basis,
        triangles=triangles,
        uv=uv,
        uv_triangles=uv_triangles,
        landmark_indices=landmark_indices,
        face_mask=face_mask,
        expression_names=[],
        expression_kind="pca",
        name=name,
    )


def _unit_scale(path: Path, extent: float, units: str) -> float:
    if units != "auto":
        return _UNIT_SCALES[units]
    for scale in _UNIT_SCALES.values():
        if 80.0 <= extent * scale < 800.0:
            return scale
    raise ModelFileError(
        path,
        "mu_shape",
        "a head-sized mean shape (largest side 80-800 mm, 8-80 cm, 0.8-8 dm or 0.08-0.8 m; "
        "pass units= to override)",
        f"largest side {extent:.4g} units",
    )


def _outward_flux(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Σ over triangles of (b-a)x(c-a) · (centroid - mesh centre): > 0 for outward winding."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    centre = vertices[np.unique(triangles)].mean(axis=0)
    return float(np.sum(normals * ((a + b + c) / 3.0 - centre)))


def _check_axes(path: Path, mean: np.ndarray, ibug: np.ndarray) -> None:
    p = mean[ibug]
    eyes_above_mouth = p[EYES, 1].mean() > p[MOUTH, 1].mean()
    nose_in_front = p[30, 2] > max(p[0, 2], p[16, 2])
    if not (eyes_above_mouth and nose_in_front):
        warnings.warn(
            f"{path}: the keypoints suggest the axes are not +Y up / +Z out of the face "
            f"(eyes above mouth: {eyes_above_mouth}, nose tip in front of the jaw ends: {nose_in_front}); "
            "the coordinates are used as they are",
            ModelFileWarning,
            stacklevel=4,
        )


# ---------------------------------------------------------------------------------------- landmarks
#: Tencent's 86-point markup, 0-based, by group (hifi3dface utils/const.py: lmk86_region and
#: flip_vtx_map86). Pairs are mirror images of each other.
_T86_CONTOUR = np.arange(0, 17)
_T86_BROW_UPPER = (np.arange(17, 22), np.arange(26, 31))  # 5 points along each brow
_T86_EYES = (  # (corners, lid 1 (a, middle, b), lid 2 (a, middle, b))
    ((35, 38), (36, 41, 37), (39, 42, 40)),
    ((43, 46), (44, 49, 45), (47, 50, 48)),
)
_T86_NOSE_BRIDGE = np.arange(51, 55)
_T86_NOSE_BOTTOM = np.arange(61, 66)  # the part of the nose outline that crosses the midline
_T86_MOUTH_OUTER = ((66, 70), (72, 67, 68, 69, 73), (77, 80, 79, 78, 76))  # corners, lip, lip
_T86_MOUTH_INNER = ((74, 75), (81, 82, 83), (85, 71, 84))


def _ibug68_from_tencent86(kp: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """Vertex indices of the iBUG-68 points from Tencent's 86 keypoint vertices.

    Group membership comes from Tencent's markup; the geometry of the mean shape (+X towards
    the subject's left, +Y up) decides sides, upper/lower and order within each group:
    iBUG runs jaw 0..16 from the subject's right (-X) to left, brows 17..26 and the nose wing
    31..35 in +X order, each eye from its -X corner along the upper lid, and the lips from the
    -X corner along the upper lip (48..54 / 60..64) and back along the lower lip.
    """
    x, y = mean[kp, 0], mean[kp, 1]

    def by_x(idx: Any, reverse: bool = False) -> list[int]:
        idx = list(idx)
        order = sorted(idx, key=lambda i: x[i], reverse=reverse)
        return order

    def loop(
        corners: tuple[int, int], lid_a: tuple[int, ...], lid_b: tuple[int, ...], middle: bool
    ) -> list[int]:
        """Corner (-X), upper lid by +X, corner (+X), lower lid by -X."""
        lo, hi = sorted(corners, key=lambda i: x[i])
        upper, lower = (lid_a, lid_b) if y[list(lid_a)].mean() >= y[list(lid_b)].mean() else (lid_b, lid_a)
        if not middle:  # iBUG has 2 points per eyelid: drop the 86 markup's middle one
            upper, lower = (upper[0], upper[2]), (lower[0], lower[2])
        return [lo, *by_x(upper), hi, *by_x(lower, reverse=True)]

    jaw = list(_T86_CONTOUR)
    if x[jaw[0]] > x[jaw[-1]]:
        jaw = jaw[::-1]
    brows = sorted(_T86_BROW_UPPER, key=lambda g: x[g].mean())
    eyes = sorted(_T86_EYES, key=lambda e: x[list(e[0])].mean())
    order = (
        jaw
        + by_x(brows[0])
        + by_x(brows[1])
        + sorted(_T86_NOSE_BRIDGE, key=lambda i: -y[i])
        + by_x(_T86_NOSE_BOTTOM)
        + loop(*eyes[0], middle=False)
        + loop(*eyes[1], middle=False)
        + loop(*_T86_MOUTH_OUTER, middle=True)
        + loop(*_T86_MOUTH_INNER, middle=True)
    )
    assert len(order) == N_IBUG
    return kp[np.array(order, dtype=np.int64)]


# ---------------------------------------------------------------------------------------- UVs
def _cylindrical_uv(mean: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex cylindrical UVs (seam at the back, -Z), with seam triangles given wrapped copies."""
    centre = (mean.max(axis=0) + mean.min(axis=0)) / 2.0
    p = mean - centre
    u = (np.arctan2(p[:, 0], p[:, 2]) + np.pi) / (2.0 * np.pi)
    height = max(float(np.ptp(p[:, 1])), 1e-12)
    v = (p[:, 1] - p[:, 1].min()) / height
    uv = [np.stack([u, v], axis=1)]
    uv_tri = triangles.copy()
    tri_u = u[triangles]
    crossing = np.ptp(tri_u, axis=1) > 0.5
    extra: list[np.ndarray] = []
    next_index = mean.shape[0]
    for f in np.nonzero(crossing)[0]:
        for k in range(3):
            if tri_u[f, k] < 0.5:
                vertex = triangles[f, k]
                extra.append(np.array([u[vertex] + 1.0, v[vertex]]))
                uv_tri[f, k] = next_index
                next_index += 1
    if extra:
        uv.append(np.stack(extra))
    coords = np.concatenate(uv)
    coords[:, 0] /= max(1.0, float(coords[:, 0].max()))
    return coords, uv_tri


# ---------------------------------------------------------------------------------------- albedo
def _find_albedo(path: Path) -> Path | None:
    try:
        candidates = sorted(p for p in path.parent.iterdir() if p.is_file() and p.suffix.lower() == ".mat")
    except OSError:
        return None
    for p in candidates:
        if "albedo-global" in p.name.lower() and p.resolve() != path.resolve():
            return p
    return None


def _vertex_albedo(
    path: Path, n_vertices: int, triangles: np.ndarray, uv_triangles: np.ndarray, uv: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex linear mean albedo (V, 3) and basis (K, V, 3) from a UV-space albedo .mat."""
    data = _read_mat(path, _sniff(path))
    for key in ("mu", "basis", "sigma", "indices"):
        if key not in data:
            raise ModelFileError(path, key, "this key of a Tencent UV albedo basis .mat", "missing")
    raw_idx = _get(path, data, "indices", "an (N, 2) array of (row, column) pixels")
    if raw_idx.ndim == 2 and raw_idx.shape[1] not in (2, 3) and raw_idx.shape[0] in (2, 3):
        raw_idx = raw_idx.T
    if raw_idx.ndim != 2 or raw_idx.shape[1] < 2:
        raise ModelFileError(path, "indices", "an (N, 2) array of (row, column) pixels", str(raw_idx.shape))
    pixels = _indices(path, "indices", raw_idx[:, :2], 2)
    if pixels.size == 0 or pixels.min() < 0:
        raise ModelFileError(path, "indices", "non-negative 0-based (row, column) pixels", "negative or none")
    n_pixels = pixels.shape[0]
    mu = _get(path, data, "mu", f"{3 * n_pixels} values (RGB per index row)").astype(np.float64).reshape(-1)
    if mu.size != 3 * n_pixels:
        raise ModelFileError(path, "mu", f"{3 * n_pixels} values (RGB per index row)", str(mu.size))
    sigma = _get(path, data, "sigma", "one standard deviation per component").astype(np.float64).reshape(-1)
    basis = _basis(path, "basis", _get(path, data, "basis", "a (K, 3N) float array"), 3 * n_pixels)
    if sigma.size != basis.shape[0]:
        raise ModelFileError(
            path, "sigma", f"{basis.shape[0]} values (one per basis component)", str(sigma.size)
        )
    scale = 255.0 if mu.max() > 1.5 else 1.0

    size = 1 << int(np.ceil(np.log2(max(2, int(pixels.max()) + 1))))
    lookup = np.full((size, size), -1, dtype=np.int64)
    lookup[pixels[:, 0], pixels[:, 1]] = np.arange(n_pixels)

    corners = np.unique(np.stack([triangles.reshape(-1), uv_triangles.reshape(-1)], axis=1), axis=0)
    vert, vt = corners[:, 0], corners[:, 1]
    rows, cols = nearest_texel(uv[vt], size, size)
    sample = lookup[rows, cols]
    missing = sample < 0
    if np.any(missing):
        from scipy.spatial import cKDTree

        _, nearest = cKDTree(pixels.astype(np.float64)).query(
            np.stack([rows[missing], cols[missing]], axis=1)
        )
        sample[missing] = nearest

    counts = np.bincount(vert, minlength=n_vertices).astype(np.float64)
    mean_s = np.zeros((n_vertices, 3))
    np.add.at(mean_s, vert, mu.reshape(-1, 3)[sample])
    k = basis.shape[0]
    basis_s = np.zeros((k, n_vertices, 3))
    if k:
        cols3 = (3 * sample[:, None] + np.arange(3)).reshape(-1)
        picked = (basis[:, cols3].astype(np.float64) * sigma[:, None]).reshape(k, -1, 3)  # basis x sigma
        for c in range(3):
            basis_s[:, :, c] = np.stack(
                [np.bincount(vert, weights=picked[j, :, c], minlength=n_vertices) for j in range(k)]
            )
    covered = counts > 0
    mean_s[covered] /= counts[covered, None]
    basis_s[:, covered] /= counts[covered, None]
    if np.any(~covered) and np.any(covered):
        mean_s[~covered] = mean_s[covered].mean(axis=0)
    mean_lin, slope = srgb_to_linear_slope(mean_s / scale)
    return mean_lin, basis_s / scale * slope[None]
