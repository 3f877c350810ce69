"""The texture stages' faster pieces give the bits of the computations they replace (issues 29, 26).

Each optimised piece is compared with the plain computation it stands for, and the default
backend's maps with every piece swapped back for its reference: equal to the last bit, not within
a tolerance (``benchmarks/bench_texture_stages.py`` compares whole runs with the code before).
"""

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp
import torch
from scipy import ndimage

from facegeo import Camera, fit_landmarks, load_model, project
from facegeo.lighting import sh_basis
from facegeo.skin_mask import skin_vertex_mask, vertex_regions
from facegeo.texturing import image_filters
from facegeo.texturing.context import build_context, layout_priors, surface_operators
from facegeo.texturing.default import DefaultBackend
from facegeo.texturing.default import backend as backend_module
from facegeo.texturing.default import delighting, fill, reliability
from facegeo.texturing.default.noise import value_noise
from facegeo.uv import rasterize_uv, render, unwrap


def _bits_equal(a: np.ndarray, b: np.ndarray) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(np.ascontiguousarray(a).view(np.uint8),
                                                                        np.ascontiguousarray(b).view(np.uint8))


def _reference_value_noise(position_mm: np.ndarray, cell_mm: float, seed: int = 0) -> np.ndarray:
    """The value noise as first written: one pass over all points per lattice corner."""
    g = position_mm.astype(np.float32) / np.float32(cell_mm)
    base = np.floor(g)
    f = g - base
    f = f * f * (3 - 2 * f)
    base = base.astype(np.int32)
    out = np.zeros(len(g), np.float32)
    for corner in range(8):
        o = ((corner >> 2) & 1, (corner >> 1) & 1, corner & 1)
        h = ((base[:, 0] + o[0]) * 73856093) ^ ((base[:, 1] + o[1]) * 19349663) ^ ((base[:, 2] + o[2]) * 83492791) ^ (seed * 2654435)
        h = (h ^ (h >> 13)) * 1274126177
        h = h ^ (h >> 16)
        value = (h & 0xFFFF).astype(np.float32) * np.float32(2.0 / 65535.0) - 1.0
        weight = (f[:, 0] if o[0] else 1 - f[:, 0]) * (f[:, 1] if o[1] else 1 - f[:, 1]) * (f[:, 2] if o[2] else 1 - f[:, 2])
        out += weight * value
    return out


def _reference_surface_operators(model, raster):
    """The interpolation matrix through SciPy's COO -> CSR conversion."""
    corners = np.asarray(model.triangles)[raster.texel_triangle]
    n = len(raster.texels)
    rows = np.repeat(np.arange(n), 3)
    return sp.csr_matrix((raster.texel_barycentric.astype(np.float64).ravel(), (rows, corners.ravel())), shape=(n, model.n_vertices))


@pytest.fixture(scope="module")
def scene():
    """A landmark fit of the bundled model at S = 256, its context and a rendered, unwrapped photo."""
    model = load_model()
    camera = Camera.for_image(512, 512)
    R = np.array([[0.94, 0.0, 0.34], [0.0, 1.0, 0.0], [-0.34, 0.0, 0.94]])  # ~20° yaw: part of the face unseen
    lm = project(model.mean_shape[model.landmark_indices].astype(np.float64), R, np.array([0, 0, -600.0]), camera)
    fit = fit_landmarks(model, lm, camera)
    raster = rasterize_uv(model, size=256)
    ctx = build_context(model, fit, raster)
    rng = np.random.default_rng(0)
    texture = np.clip(0.6 + 0.08 * rng.normal(size=(256, 256, 3)), 0, 1).astype(np.float32)
    photo = np.clip(render(fit.vertices, model, camera, texture=texture).image, 0, 1)
    t_inc, m_vis = unwrap(photo, fit, model, raster=raster)
    return model, fit, raster, ctx, t_inc, m_vis


def test_euclidean_distance_is_scipys_edt():
    rng = np.random.default_rng(0)
    masks = [rng.random((s, s)) > d for s in (31, 256, 1024) for d in (0.001, 0.05, 0.5, 0.95)]
    yy, xx = np.mgrid[:700, :700]
    masks += [(xx - 350.3) ** 2 + (yy - 120.7) ** 2 > 90.0**2, np.abs(xx - 0.6 * yy - 40) > 0.7, np.ones((64, 64), bool)]
    masks.append(np.pad(np.zeros((1, 1), bool), ((0, 2999), (0, 2999)), constant_values=True))  # d² beyond float32's reach
    for mask in masks:
        assert _bits_equal(image_filters.euclidean_distance(mask), ndimage.distance_transform_edt(mask))


def test_value_noise_is_the_per_corner_computation():
    p = np.random.default_rng(1).uniform(-400, 400, (50_001, 3)).astype(np.float32)
    for cell, seed in ((0.35, 0), (0.7, 1), (1.5, 2)):
        assert _bits_equal(value_noise(p, cell, seed), _reference_value_noise(p, cell, seed))


def test_surface_operators_are_the_coo_construction(scene):
    model, _, raster, _, _, _ = scene
    fast, slow = surface_operators(model, raster).interpolation, _reference_surface_operators(model, raster)
    for name in ("indptr", "indices", "data"):
        assert _bits_equal(getattr(fast, name), getattr(slow, name)), name
    # a degenerate triangle (a vertex used twice): SciPy sums the repeated corner
    flat = SimpleNamespace(n_vertices=4, triangles=np.array([[0, 1, 2], [2, 3, 3]]))
    raster2 = rasterize_uv(np.array([[0.1, 0.1], [0.9, 0.1], [0.1, 0.9], [0.9, 0.9]]), np.array([[0, 1, 2], [2, 1, 3]]), size=16)
    fast, slow = surface_operators(flat, raster2).interpolation, _reference_surface_operators(flat, raster2)
    assert (fast != slow).nnz == 0 and _bits_equal(fast.indices, slow.indices) and _bits_equal(fast.data, slow.data)


def test_layout_priors_are_shared_read_only_and_the_direct_interpolation(scene):
    model, fit, raster, ctx, _, _ = scene
    again = build_context(model, fit, raster)
    assert again.surface is ctx.surface and again.mirror is ctx.mirror and again.regions["lips"] is ctx.regions["lips"]
    assert not ctx.mirror.flags.writeable and not ctx.skin.flags.writeable
    assert layout_priors(model, raster) is layout_priors(model, raster)

    def to_uv(per_vertex):
        per_vertex = np.asarray(per_vertex, np.float32).reshape(model.n_vertices, -1)
        return raster.scatter(raster.interpolate(per_vertex[model.triangles]))

    for name, mask in vertex_regions(model).items():
        assert _bits_equal(ctx.regions[name], to_uv(mask)[..., 0]), name
    assert _bits_equal(ctx.skin, to_uv(skin_vertex_mask(model).astype(np.float32))[..., 0])


def test_default_backend_maps_are_those_of_the_reference_pieces(scene, monkeypatch):
    """The maps with the fast pieces equal, bit for bit, the maps with each piece swapped back for
    the computation it replaces (SciPy's EDT, the per-corner noise, torch's SH basis, a median per
    call, the COO-built operators)."""
    model, _, raster, ctx, t_inc, m_vis = scene
    assert (m_vis > 0.5).mean() > 0.2 and (ctx.coverage & (m_vis == 0)).any()  # seen and unseen skin

    def maps() -> dict[str, np.ndarray]:
        backend = DefaultBackend()
        return backend.materials(backend.homogenise(backend.inpaint(t_inc, m_vis, ctx), ctx), ctx)

    fast = maps()
    for module in (reliability, fill):  # the pieces where the stages look them up
        monkeypatch.setattr(module, "euclidean_distance", ndimage.distance_transform_edt)
    monkeypatch.setattr(fill, "value_noise", _reference_value_noise)
    for module in (delighting, backend_module):
        monkeypatch.setattr(module, "sh_basis", lambda n: sh_basis(torch.from_numpy(np.asarray(n))).numpy())
    monkeypatch.setattr(type(ctx), "median_texel_mm", property(lambda c: float(np.median(c.texel_size_mm[c.coverage]))))
    surface = ctx.surface
    monkeypatch.setattr(surface, "interpolation", _reference_surface_operators(model, raster))
    slow = maps()
    assert fast.keys() == slow.keys() == {"albedo", "normal", "roughness", "specular", "displacement"}
    for name in fast:
        assert _bits_equal(fast[name], slow[name]), name
