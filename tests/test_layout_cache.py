"""The on-disk layout cache (facegeo.layout_cache): the UV raster and the layout priors stored once,
loaded bit-identical, damaged entries rewritten, an unwritable cache harmless, the code in the key."""

from __future__ import annotations

import json
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest

from facegeo import layout_cache
from facegeo.layout_cache import CODE_MODULES, LAYOUT_CACHE_ENV, code_version, entry_folder, load_entry
from facegeo.texturing import context
from facegeo.texturing.context import _compute_layout_priors, layout_priors
from facegeo.uv import raster as raster_module
from facegeo.uv.raster import rasterize_uv

SIZE = 128


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    """An empty layout cache of the test's own, and empty in-process caches."""
    root = tmp_path / "layout"
    monkeypatch.setenv(LAYOUT_CACHE_ENV, str(root))
    forget(monkeypatch)
    return root


def forget(monkeypatch) -> None:
    """Empty the in-process caches of rasters and priors (as in a new process)."""
    monkeypatch.setattr(raster_module, "_CACHE", OrderedDict())
    monkeypatch.setattr(context, "_LAYOUT_CACHE", OrderedDict())


def entries(root: Path) -> list[Path]:
    """Everything under ``root``, sorted."""
    return sorted(root.rglob("*")) if root.exists() else []


def assert_same_array(loaded: np.ndarray, fresh: np.ndarray) -> None:
    assert loaded.dtype == fresh.dtype and loaded.shape == fresh.shape and np.array_equal(loaded, fresh)
    assert loaded.flags.c_contiguous == fresh.flags.c_contiguous and not loaded.flags.writeable


def assert_same_raster(loaded, fresh) -> None:
    assert (loaded.size, loaded.padding, loaded.n_triangles, loaded.key) == (fresh.size, fresh.padding, fresh.n_triangles, fresh.key)
    for name in ("texels", "texel_triangle", "texel_barycentric", "texel_inside", "inside", "mask", "triangle", "barycentric"):
        assert_same_array(getattr(loaded, name), getattr(fresh, name))


def assert_same_priors(loaded, fresh) -> None:
    for name in ("coverage", "mirror", "skin", "mean_texture"):
        assert_same_array(getattr(loaded, name), getattr(fresh, name))
    assert list(loaded.regions) == list(fresh.regions)
    for name, region in fresh.regions.items():
        assert_same_array(loaded.regions[name], region)
    assert_same_array(loaded.surface.texels, fresh.surface.texels)
    for name in ("interpolation", "laplacian"):
        a, b = getattr(loaded.surface, name), getattr(fresh.surface, name)
        assert type(a) is type(b) and a.shape == b.shape and a.has_canonical_format == b.has_canonical_format
        for part in ("data", "indices", "indptr"):  # (computed ones are writeable, loaded ones not)
            x, y = getattr(a, part), getattr(b, part)
            assert x.dtype == y.dtype and np.array_equal(x, y)


def fresh(model):
    raster = rasterize_uv(model, size=SIZE, cache=False)
    return raster, _compute_layout_priors(model, raster)


def test_a_cold_call_stores_and_a_warm_one_memory_maps_the_same_arrays(model, cache, monkeypatch):
    cold = rasterize_uv(model, size=SIZE)
    cold_priors = layout_priors(model, cold)
    version = cache / code_version()
    assert sorted(p.name for p in version.iterdir()) == sorted([
        f"raster-{cold.key}-{SIZE}-2", f"priors-{context._model_digest(model)}-{cold.key}-{SIZE}-2"])
    assert not [p for p in entries(cache) if p.name.startswith(".")]
    forget(monkeypatch)
    warm = rasterize_uv(model, size=SIZE)
    warm_priors = layout_priors(model, warm)
    assert warm is not cold and warm_priors is not cold_priors
    assert isinstance(warm.texels.base, np.memmap) and isinstance(warm.inside.base, np.memmap)
    assert warm_priors.coverage is warm.inside and warm_priors.surface.texels is warm.texels
    reference, reference_priors = fresh(model)
    assert_same_raster(warm, reference)
    assert_same_priors(warm_priors, reference_priors)
    assert rasterize_uv(model, size=SIZE) is warm and layout_priors(model, warm) is warm_priors  # then from memory


@pytest.mark.parametrize("damage", ["truncated array", "missing array", "other shape", "no manifest", "bad manifest"])
def test_a_damaged_entry_is_recomputed_and_rewritten(model, cache, monkeypatch, damage):
    layout_priors(model, rasterize_uv(model, size=SIZE))
    folders = sorted((cache / code_version()).iterdir())
    for folder in folders:
        victim = folder / ("texel_barycentric.npy" if folder.name.startswith("raster") else "interpolation_indices.npy")
        if damage == "truncated array":
            victim.write_bytes(victim.read_bytes()[:-100])
        elif damage == "missing array":
            victim.unlink()
        elif damage == "other shape":
            np.save(victim, np.load(victim)[:-1])
        elif damage == "no manifest":
            (folder / "manifest.json").unlink()
        else:
            (folder / "manifest.json").write_text("{\"arrays\": {")
        assert load_entry(folder) is None
    reference, reference_priors = fresh(model)
    for stored in (False, True):  # recomputed and rewritten, then loaded from the new entry
        forget(monkeypatch)
        raster = rasterize_uv(model, size=SIZE)
        priors = layout_priors(model, raster)
        assert isinstance(raster.texels.base, np.memmap) == stored
        assert_same_raster(raster, reference)
        assert_same_priors(priors, reference_priors)
        assert sorted((cache / code_version()).iterdir()) == folders and all(load_entry(f) is not None for f in folders)
    assert not [p for p in entries(cache) if p.name.startswith(".")]


@pytest.mark.parametrize("failure", ["root is a file", "disk full"])
def test_an_unwritable_cache_leaves_nothing_behind_and_the_values_are_computed(model, tmp_path, monkeypatch, failure):
    root = tmp_path / "cache"
    if failure == "root is a file":
        root.write_text("not a folder")  # mkdir fails (chmod would not stop root)
    else:
        def full(*args, **kwargs):
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(layout_cache.np, "save", full)
    monkeypatch.setenv(LAYOUT_CACHE_ENV, str(root))
    forget(monkeypatch)
    raster = rasterize_uv(model, size=SIZE)
    priors = layout_priors(model, raster)
    reference, reference_priors = fresh(model)
    assert_same_raster(raster, reference)
    assert_same_priors(priors, reference_priors)
    if failure == "root is a file":
        assert sorted(tmp_path.iterdir()) == [root] and root.read_text() == "not a folder"
    else:
        assert [p.name for p in entries(root)] == [code_version()]  # the version's folder, empty


@pytest.fixture
def recomputed_code_version(monkeypatch):
    """Clears :func:`code_version`'s memo after the test (patches are undone after this)."""
    yield
    code_version.cache_clear()


def test_the_code_version_is_in_the_key_and_a_new_version_replaces_the_old_entries(model, cache, monkeypatch, tmp_path,
                                                                                   recomputed_code_version):
    """Editing a module that computes the arrays, or another SciPy, gives another code version and
    so other entries; storing one removes the old version's folder."""
    assert all(layout_cache._source_file(m).is_file() for m in CODE_MODULES)
    before, folder = code_version(), entry_folder("raster-x")
    assert folder.parent.name == before
    rasterize_uv(model, size=SIZE)
    edited = tmp_path / "skin_mask.py"
    edited.write_bytes(layout_cache._source_file("facegeo.skin_mask").read_bytes() + b"\n# edited\n")
    real_source = layout_cache._source_file
    monkeypatch.setattr(layout_cache, "_source_file", lambda m: edited if m == "facegeo.skin_mask" else real_source(m))
    code_version.cache_clear()
    after = code_version()
    assert after != before and entry_folder("raster-x") != folder
    forget(monkeypatch)
    rasterize_uv(model, size=SIZE)  # a miss under the new version: stored, the old version's folder removed
    assert [p.name for p in cache.iterdir()] == [after]
    # another SciPy: its version.py (read, not imported) differs
    other_scipy = tmp_path / "version.py"
    other_scipy.write_bytes(real_source("scipy.version").read_bytes().replace(b"version = ", b"version = '0.0.1' or "))
    monkeypatch.setattr(layout_cache, "_source_file", lambda m: other_scipy if m == "scipy.version" else real_source(m))
    code_version.cache_clear()
    assert code_version() not in (before, after)


def test_a_manifest_names_every_array_with_its_dtype_and_shape(model, cache):
    raster = rasterize_uv(model, size=SIZE)
    manifest = json.loads((entry_folder(f"raster-{raster.key}-{SIZE}-2") / "manifest.json").read_text())
    assert manifest["arrays"]["inside"] == {"dtype": "|b1", "shape": [SIZE, SIZE]}
    assert manifest["meta"] == {"n_triangles": raster.n_triangles}


def test_the_default_model_is_stored_once_and_loaded_as_read(cache, monkeypatch):
    from facegeo import model_files
    from facegeo.model_files import _MODEL_ARRAYS, _default_path, _load, load_model

    monkeypatch.setattr(model_files, "_default_cache", {})
    stored = load_model()  # read from the file, then stored
    [entry] = [p for p in (cache / code_version()).iterdir() if p.name.startswith("model-")]
    monkeypatch.setattr(model_files, "_default_cache", {})
    loaded = load_model()  # as a new process: from the cache, memory-mapped
    read = _load(_default_path(), albedo_path=None, units="auto")
    for model in (stored, loaded):
        for name in _MODEL_ARRAYS:
            a, b = getattr(model, name), getattr(read, name)
            assert a.dtype == b.dtype and np.array_equal(a, b), name
        assert (model.name, model.expression_kind, model.expression_names, model.source) == (
            read.name, read.expression_kind, read.expression_names, read.source)
    assert not loaded.id_basis.flags.writeable  # shared, as the in-process default always was ("do not modify it")
    # a damaged entry is read from the file again and replaced
    (entry / "id_basis.npy").write_bytes(b"\x93NUMPY damaged")
    monkeypatch.setattr(model_files, "_default_cache", {})
    again = load_model()
    assert np.array_equal(again.id_basis, read.id_basis) and load_entry(entry) is not None


def test_an_obj_layouts_lines_are_stored_once_and_read_back_the_same(model, cache):
    """The ``vt`` and ``f`` lines of a mesh's UV layout are made once, kept under a key of the
    three arrays, and read back as the same text; another layout gets its own entry, and a damaged
    entry is made again."""
    from facegeo.mesh_io import obj_text

    def layout_entries() -> list[Path]:
        return sorted(p for p in (cache / code_version()).iterdir() if p.name.startswith("obj-layout-")) if cache.exists() else []

    v, t, uv, ut = model.mean_shape, model.triangles, model.uv, model.uv_triangles
    made = obj_text(v, t, uv, ut)
    [entry] = layout_entries()
    assert obj_text(v + 1.0, t, uv, ut).split("vt ", 1)[1] == made.split("vt ", 1)[1]  # other vertices, the same layout lines
    assert obj_text(v, t, uv, ut) == made and layout_entries() == [entry]
    flipped = obj_text(v, t, uv[:, ::-1], ut)
    assert len(layout_entries()) == 2 and flipped != made
    assert flipped.replace("\nvt ", "\n").splitlines()[len(v) + 1].split() == [f"{uv[0, 1]:.6f}", f"{uv[0, 0]:.6f}"]
    (entry / "text.npy").write_bytes(b"\x93NUMPY damaged")
    assert obj_text(v, t, uv, ut) == made and load_entry(entry) is not None
