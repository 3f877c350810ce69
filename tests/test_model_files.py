"""Reading model files: the bundled ICT-FaceKit model, Tencent's .mat layouts, and bad files."""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial import ConvexHull

from facegeo.assets import asset_path
from facegeo.errors import ModelFileError
from facegeo.model_files import (
    DEFAULT_MODEL_ASSET,
    MODEL_ENV_VAR,
    ModelFileWarning,
    _ibug68_from_tencent86,
    load_model,
)
from facegeo.landmarks.scheme import CHIN, EYES, IBUG68, JAW_ENDS, LEFT_EYE, LIP_POINTS, MOUTH, OUTER_EYE_CORNERS, RIGHT_EYE

NPZ = asset_path(DEFAULT_MODEL_ASSET)
README = Path(__file__).resolve().parents[1] / "assets" / "ict_facekit" / "README.md"


# ------------------------------------------------------------------------------- bundled model
def test_bundled_model_counts(model):
    assert model.n_vertices == 11248
    assert (model.n_id, model.n_exp, model.n_tex) == (100, 53, 0)
    assert model.landmark_indices.shape == (88,)
    np.testing.assert_array_equal(model.landmark_indices[LIP_POINTS], model.landmark_indices[MOUTH])
    assert len(model.expression_names) == 53 and "jawOpen" in model.expression_names
    assert model.id_basis.dtype == np.float32 and model.exp_basis.dtype == np.float32
    assert model.triangles.shape == (22288, 3) and model.uv_triangles.shape == (22288, 3)
    assert model.uv.min() >= 0.0 and model.uv.max() <= 1.0
    assert model.face_mask.sum() == 9409
    np.testing.assert_allclose(model.mean_albedo, 0.5)


def test_default_is_cached(model):
    assert load_model() is model


def test_bundled_model_size_in_mm_and_axes(model):
    p = model.mean_shape[model.landmark_indices]
    eye_centres = np.linalg.norm(p[RIGHT_EYE].mean(0) - p[LEFT_EYE].mean(0))
    assert 55.0 < eye_centres < 75.0  # interpupillary distance, adults ~ 54-74 mm
    assert 80.0 < np.linalg.norm(np.subtract(*p[OUTER_EYE_CORNERS])) < 105.0  # outer eye corners (biocular width)
    assert 95.0 < np.linalg.norm(p[27] - p[8]) < 135.0  # nasion to chin
    assert p[EYES, 1].mean() > p[MOUTH, 1].mean() > p[CHIN, 1]  # +Y up
    ears = p[JAW_ENDS]  # the top of the jaw contour, in front of the ears
    assert p[30, 2] > ears[:, 2].max() + 50.0  # +Z out of the face
    assert p[36, 0] < 0.0 < p[45, 0]  # +X towards the subject's left
    # the jaw contour runs from the subject's right (-X) down to the chin and up to the left
    assert np.all(p[0:8, 0] < 0) and np.all(p[9:17, 0] > 0)
    assert np.all(np.diff(p[0:9, 1]) < 0) and np.all(np.diff(p[8:17, 1]) > 0)


def test_bundled_normals_point_outwards(model):
    n = model.vertex_normals(model.tensor("mean_shape")).numpy()
    v = model.mean_shape
    tip = int(np.argmax(v[:, 2]))
    assert n[tip, 2] > 0.9
    top = int(np.argmax(v[:, 1]))
    assert n[top, 1] > 0.9
    ears = model.landmark_indices[JAW_ENDS]  # top of the jaw contour, beside the ears
    assert n[ears[0], 0] < -0.5 and n[ears[1], 0] > 0.5
    # most face-region normals point away from the head's centre (eye sockets, nostrils and
    # lip corners are concave)
    centre = v.mean(axis=0)
    outward = np.sum(n * (v - centre), axis=1) > 0
    assert outward[model.face_mask].mean() > 0.8  # ~0.15 if the winding were reversed


def test_float16_error_recorded_and_consistent():
    """The README's float16 error matches the npz's record and the rounding of its bases.

    float32 originals are not shipped, but every stored float16 value is the original rounded to
    nearest, so the error of each basis entry is uniform within half a float16 spacing. That
    model predicts the RMS vertex error over alpha, delta ~ N(0, 1) from the shipped data alone.
    """
    with np.load(NPZ) as data:
        err_max, err_rms = data["float16_error_mm"]
        assert data["id_basis"].dtype == np.float16 and data["exp_basis"].dtype == np.float16
        half_step_sq = 0.0
        for key in ("id_basis", "exp_basis"):
            b = data[key].astype(np.float32)
            half = np.spacing(np.abs(data[key])).astype(np.float32) / 2.0
            half_step_sq = half_step_sq + np.sum(half.astype(np.float64) ** 2, axis=(0, 2))
            assert np.all(np.isfinite(b))
    predicted_rms = float(np.sqrt(np.mean(half_step_sq / 3.0)))
    assert err_rms < 0.01 and err_max < 0.2  # mm
    assert 0.8 * predicted_rms < err_rms < 1.25 * predicted_rms
    text = README.read_text()
    assert f"{err_max:.3f} mm" in text and f"{err_rms:.4f} mm" in text


def test_shape_batched_and_differentiable(model):
    alpha = torch.randn(2, 3, model.n_id, requires_grad=True)
    delta = torch.rand(2, 3, model.n_exp, requires_grad=True)
    s = model.shape(alpha, delta, vertex_indices=model.landmark_indices)
    assert s.shape == (2, 3, 88, 3)
    s.sum().backward()
    assert alpha.grad is not None and delta.grad is not None
    np.testing.assert_allclose(
        model.shape(alpha[1, 2], delta[1, 2]).detach()[model.landmark_indices].numpy(),
        s[1, 2].detach().numpy(),
        atol=1e-3,
    )


def test_the_numpy_shape_equals_the_torch_shape(model):
    rng = np.random.default_rng(4)
    alpha, delta = rng.normal(size=model.n_id).astype(np.float32), rng.uniform(size=model.n_exp).astype(np.float32)
    for a, d in ((None, None), (alpha, None), (None, delta), (alpha, delta)):
        np.testing.assert_allclose(model.shape_numpy(a, d), model.shape(a, d).numpy(), atol=2e-4, rtol=0)
        np.testing.assert_allclose(model.shape_numpy(a, d, vertex_indices=model.landmark_indices),
                                   model.shape_numpy(a, d)[model.landmark_indices], atol=1e-5, rtol=0)
    with pytest.raises(ValueError, match="alpha"):
        model.shape_numpy(alpha[:3])


# ------------------------------------------------------------------------------- synthetic meshes
def _head_mesh(n: int, seed: int, radii=(8.0, 11.0, 9.5)) -> tuple[np.ndarray, np.ndarray]:
    """n points on an ellipsoid (cm, head sized) and outward CCW triangles."""
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    pts = d / np.linalg.norm(d, axis=1, keepdims=True) * np.array(radii)
    tri = ConvexHull(pts).simplices.astype(np.int64)
    a, b, c = (pts[tri[:, k]] for k in range(3))
    inward = np.sum(np.cross(b - a, c - a) * (a + b + c), axis=1) < 0
    tri[inward] = tri[inward][:, [0, 2, 1]]
    return pts, tri


def _save_mat(path: Path, **arrays: np.ndarray) -> Path:
    scipy.io.savemat(str(path), arrays)
    return path


def _hifi3dpp(
    tmp: Path,
    n: int = 24,
    k_id: int = 5,
    k_exp: int = 3,
    base: int = 0,
    seed: int = 0,
    orthonormal: bool = False,
    name: str = "HIFI3D++.mat",
) -> dict:
    """A tiny file in REALY's HIFI3D++.mat layout; returns the arrays it holds and its path."""
    rng = np.random.default_rng(seed)
    pts, tri = _head_mesh(n, seed)
    if orthonormal:
        q, _ = np.linalg.qr(rng.standard_normal((3 * n, k_id)))
        basis_shape = q.T  # unit-norm rows
    else:
        basis_shape = rng.standard_normal((k_id, 3 * n)) * 0.3
    arrays = {
        "mu_shape": pts.reshape(1, -1),
        "basis_shape": basis_shape,
        "basis_exp": rng.standard_normal((k_exp, 3 * n)) * 0.2,
        "EVs": rng.uniform(0.5, 4.0, (k_id, 1)),
        "tri": (tri + base).astype(np.float64),  # MATLAB doubles
        "mask_face": (rng.random((1, n)) < 0.6).astype(np.float64),
        "keypoints": (rng.choice(n, 68, replace=True) + base).reshape(1, -1).astype(np.float64),
    }
    path = _save_mat(tmp / name, **arrays)
    return {"path": path, "pts": pts, **arrays, "tri0": tri}


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(12, 40),
    k_id=st.integers(1, 6),
    k_exp=st.integers(0, 4),
    base=st.sampled_from([0, 1]),
    seed=st.integers(0, 10_000),
)
def test_hifi3dpp_layout_round_trip(tmp_path, n, k_id, k_exp, base, seed):
    f = _hifi3dpp(tmp_path, n, k_id, k_exp, base, seed)
    with pytest.warns(ModelFileWarning):  # no UVs in REALY's documented keys
        m = load_model(f["path"])
    assert (m.n_vertices, m.n_id, m.n_exp, m.n_tex) == (n, k_id, k_exp, 0)
    np.testing.assert_allclose(m.mean_shape, f["pts"] * 10.0, rtol=1e-5, atol=1e-4)  # cm -> mm
    np.testing.assert_array_equal(m.triangles, f["tri0"])
    kp = f["keypoints"].reshape(-1).astype(np.int64) - base
    np.testing.assert_array_equal(m.landmark_indices[IBUG68], kp)
    np.testing.assert_array_equal(m.landmark_indices[LIP_POINTS], kp[MOUTH])
    np.testing.assert_array_equal(m.face_mask, f["mask_face"].reshape(-1) != 0)
    # coefficients in sigma units: the basis is already scaled, EVs unused
    for k in range(k_id):
        e = np.zeros(k_id)
        e[k] = 1.0
        d = (m.shape(alpha=torch.tensor(e)) - m.tensor("mean_shape", torch.float64)).numpy()
        np.testing.assert_allclose(d, f["basis_shape"][k].reshape(n, 3) * 10.0, rtol=1e-5, atol=1e-5)
    if k_exp:
        d = m.shape(delta=np.eye(k_exp)[-1]).numpy() - m.mean_shape
        np.testing.assert_allclose(d, f["basis_exp"][-1].reshape(n, 3) * 10.0, rtol=1e-4, atol=1e-4)
    assert m.uv.shape[1] == 2 and m.uv.min() >= 0 and m.uv.max() <= 1 and m.uv_triangles.max() < len(m.uv)


def test_hifi3dpp_orthonormal_basis_is_scaled_by_sqrt_evs(tmp_path):
    f = _hifi3dpp(tmp_path, orthonormal=True, k_id=4)
    with pytest.warns(ModelFileWarning):
        m = load_model(f["path"])
    std = np.sqrt(f["EVs"].reshape(-1))
    for k in range(4):
        np.testing.assert_allclose(
            m.id_basis[k], f["basis_shape"][k].reshape(-1, 3) * std[k] * 10.0, rtol=1e-5, atol=1e-6
        )


def test_hifi3dpp_winding_fixed_and_units_override(tmp_path):
    f = _hifi3dpp(tmp_path)
    scipy.io.savemat(
        str(f["path"]),
        {
            **{k: f[k] for k in ("mu_shape", "basis_shape", "basis_exp", "EVs", "mask_face", "keypoints")},
            "tri": f["tri0"][:, [0, 2, 1]].astype(np.float64),
        },
    )
    with pytest.warns(ModelFileWarning):
        m = load_model(f["path"], units="m")
    np.testing.assert_array_equal(m.triangles, f["tri0"])  # made counter-clockwise again
    np.testing.assert_allclose(m.mean_shape, f["pts"] * 1000.0, rtol=1e-5)


def _srgb_to_linear(s):
    s = np.asarray(s, dtype=np.float64)
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4)


def _ai_next(
    tmp: Path, n: int = 30, k_id: int = 4, k_exp: int = 2, k_tex: int = 3, seed: int = 1, albedo: bool = True
) -> dict:
    """Tiny files in Tencent AI-NExT's layout: shape .mat (0-based, UVs) and UV albedo .mat."""
    rng = np.random.default_rng(seed)
    pts, tri = _head_mesh(n, seed, radii=(80.0, 110.0, 95.0))  # mm
    size = 8  # UV image of 8 x 8 pixels; one UV per vertex at a pixel centre, vt order reversed
    pix = rng.choice(size * size, n, replace=False)
    rows, cols = pix // size, pix % size
    vt_of_vertex = np.arange(n)[::-1].copy()
    vt = np.zeros((n, 2))
    vt[vt_of_vertex] = np.stack([(cols + 0.5) / size, 1.0 - (rows + 0.5) / size], axis=1)
    shape = {
        "mu_shape": pts.reshape(1, -1),
        "basis_shape": rng.standard_normal((k_id, 3 * n)),
        "basis_exp": rng.standard_normal((k_exp, 3 * n)),
        "tri": tri.astype(np.int32),
        "keypoints": rng.choice(n, 86).reshape(1, -1).astype(np.int32),
        "vt_list": vt,
        "tri_vt": vt_of_vertex[tri].astype(np.int32),
    }
    out = {"path": _save_mat(tmp / "AI-NExT-Shape.mat", **shape), "pts": pts, "tri": tri, **shape}
    if albedo:
        all_pix = np.stack(np.meshgrid(np.arange(size), np.arange(size), indexing="ij"), -1).reshape(-1, 2)
        n_pix = len(all_pix)
        mu = rng.uniform(60, 200, (1, 3 * n_pix))
        basis = rng.standard_normal((3 * n_pix, k_tex))  # stored (3N, K): transposed on reading
        sigma = rng.uniform(1.0, 5.0, (1, k_tex))
        out["albedo"] = {"mu": mu, "basis": basis, "sigma": sigma, "indices": all_pix.astype(np.int32)}
        out["albedo_path"] = _save_mat(tmp / "AI-NExT-Albedo-Global.mat", **out["albedo"])
        lin = rows * size + cols  # index row of each vertex's pixel in all_pix
        out["vertex_mu"] = mu.reshape(-1, 3)[lin]
        out["vertex_basis"] = (basis * sigma).T.reshape(k_tex, n_pix, 3)[:, lin]
    return out


def test_ai_next_layout_with_albedo_beside(tmp_path):
    f = _ai_next(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelFileWarning)  # random keypoints: axes warning
        m = load_model(f["path"])  # the albedo file is found in the same folder
    n = len(f["pts"])
    assert (m.n_vertices, m.n_id, m.n_exp, m.n_tex) == (n, 4, 2, 3)
    np.testing.assert_allclose(m.mean_shape, f["pts"], rtol=1e-5)  # already mm
    np.testing.assert_array_equal(m.triangles, f["tri"])
    np.testing.assert_array_equal(m.uv_triangles, f["tri_vt"])
    np.testing.assert_allclose(m.uv, f["vt_list"], atol=1e-6)
    assert set(m.landmark_indices.tolist()) <= set(f["keypoints"].reshape(-1).tolist())
    np.testing.assert_allclose(m.id_basis[2], f["basis_shape"][2].reshape(n, 3), rtol=1e-5, atol=1e-6)
    # albedo: exact linear mean; the basis is the first-order (about the mean) sRGB -> linear map
    s_mean = f["vertex_mu"] / 255.0
    np.testing.assert_allclose(m.mean_albedo, _srgb_to_linear(s_mean), rtol=1e-5, atol=1e-6)
    eps = 1e-3
    for k in range(3):
        beta = np.zeros(3)
        beta[k] = eps
        exact = _srgb_to_linear(s_mean + eps * f["vertex_basis"][k] / 255.0)
        np.testing.assert_allclose(m.albedo(beta).numpy(), exact, atol=1e-6)
        np.testing.assert_allclose(m.albedo_numpy(beta), m.albedo(beta).numpy(), atol=1e-7)  # the texture stages' twin


def test_ai_next_explicit_albedo_path_and_missing_albedo_keys(tmp_path):
    f = _ai_next(tmp_path)
    other = tmp_path / "elsewhere"
    other.mkdir()
    moved = f["albedo_path"].rename(other / "my_albedo.mat")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ModelFileWarning)
        assert load_model(f["path"]).n_tex == 0  # nothing beside it now: grey, no basis
        assert load_model(f["path"], albedo_path=moved).n_tex == 3
        broken = _save_mat(other / "broken.mat", **{k: v for k, v in f["albedo"].items() if k != "sigma"})
        with pytest.raises(ModelFileError, match=r"broken\.mat: sigma"):
            load_model(f["path"], albedo_path=broken)


def test_tencent86_keypoints_map_to_ibug68(model):
    """Tencent's 86 groups built from ICT's iBUG vertices (shuffled within groups) map back."""
    ib = model.landmark_indices[IBUG68]
    spare = iter(range(7000, 7100))  # unrelated vertices for 86-only points
    kp = np.array([next(spare) for _ in range(86)])
    kp[0:17] = ib[16::-1]  # contour given from the subject's left
    kp[17:22] = ib[[26, 24, 22, 23, 25]]  # brows swapped and shuffled
    kp[26:31] = ib[[17, 18, 19, 20, 21]]
    kp[[35, 38]] = ib[[45, 42]]  # eye groups swapped; lower lid given first
    kp[[36, 41, 37]] = ib[[47, 46, 46]]  # (a, middle, b); the middle is not an iBUG point
    kp[[39, 42, 40]] = ib[[44, 43, 43]]
    kp[[43, 46]] = ib[[39, 36]]
    kp[[44, 49, 45]] = ib[[38, 37, 37]]
    kp[[47, 50, 48]] = ib[[41, 40, 40]]
    kp[51:55] = ib[[30, 28, 29, 27]]
    kp[61:66] = ib[[35, 34, 33, 32, 31]]
    kp[[66, 70]] = ib[[54, 48]]
    kp[[72, 67, 68, 69, 73]] = ib[[55, 56, 57, 58, 59]]  # lower lip given as the first lip
    kp[[77, 80, 79, 78, 76]] = ib[[53, 52, 51, 50, 49]]
    kp[[74, 75]] = ib[[64, 60]]
    kp[[81, 82, 83]] = ib[[61, 62, 63]]
    kp[[85, 71, 84]] = ib[[67, 66, 65]]
    mapped = _ibug68_from_tencent86(kp, model.mean_shape.astype(np.float64))
    np.testing.assert_array_equal(mapped, ib)


def test_matlab_v73_file_read_with_h5py(tmp_path):
    h5py = pytest.importorskip("h5py")
    f = _hifi3dpp(tmp_path, base=1)
    path = tmp_path / "v73.mat"
    with h5py.File(path, "w", userblock_size=512) as handle:
        for key in ("mu_shape", "basis_shape", "basis_exp", "EVs", "tri", "mask_face", "keypoints"):
            handle.create_dataset(key, data=np.asarray(f[key]).T)  # MATLAB v7.3 is column-major
    with path.open("r+b") as handle:
        handle.write(b"MATLAB 7.3 MAT-file".ljust(124, b" ") + b"\x00\x02IM")
    with pytest.warns(ModelFileWarning):
        ref, m = load_model(f["path"]), load_model(path)
    np.testing.assert_array_equal(m.triangles, ref.triangles)
    np.testing.assert_array_equal(m.landmark_indices, ref.landmark_indices)
    np.testing.assert_allclose(m.id_basis, ref.id_basis)


def test_gradcheck_on_tiny_model(tmp_path):
    f = _hifi3dpp(tmp_path, n=10, k_id=3, k_exp=2)
    with pytest.warns(ModelFileWarning):
        m = load_model(f["path"])
    alpha = torch.randn(2, 3, dtype=torch.float64, requires_grad=True)
    delta = torch.randn(2, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, d: m.shape(a, d), (alpha, delta))


# ------------------------------------------------------------------------------- npz and env var
def _tiny_npz(path: Path, **override) -> Path:
    pts, tri = _head_mesh(12, 3, radii=(80.0, 110.0, 95.0))
    rng = np.random.default_rng(3)
    v = len(pts)
    arrays = {
        "format_version": np.array(1),
        "name": np.array("tiny"),
        "mean_shape": pts.astype(np.float32),
        "id_basis": rng.standard_normal((2, v, 3)).astype(np.float16),
        "exp_basis": rng.standard_normal((1, v, 3)).astype(np.float16),
        "expression_names": np.array(["smile"]),
        "triangles": tri,
        "uv": rng.random((v, 2)).astype(np.float32),
        "uv_triangles": tri,
        "landmark_indices": rng.integers(0, v, 88),
        "face_mask": np.ones(v, dtype=bool),
        "mean_albedo": np.full((v, 3), 0.5, dtype=np.float32),
        "tex_basis": np.zeros((0, v, 3), dtype=np.float32),
    }
    arrays.update(override)
    arrays = {k: a for k, a in arrays.items() if a is not None}
    np.savez_compressed(path, **arrays)
    return path


def test_npz_round_trip_and_env_var(tmp_path, monkeypatch):
    path = _tiny_npz(tmp_path / "tiny.npz")
    with np.load(path) as raw:
        m = load_model(str(path))
        np.testing.assert_array_equal(m.id_basis, raw["id_basis"].astype(np.float32))
    assert m.name == "tiny" and m.expression_names == ["smile"] and m.id_basis.dtype == np.float32
    monkeypatch.setenv(MODEL_ENV_VAR, str(path))
    assert load_model().name == "tiny"
    assert load_model() is load_model()


# ------------------------------------------------------------------------------- failures
def _bad_cases(tmp: Path) -> list[tuple[Path, str]]:
    f = _hifi3dpp(tmp)
    base = {k: f[k] for k in ("mu_shape", "basis_shape", "basis_exp", "EVs", "tri", "mask_face", "keypoints")}
    nan_mu = f["mu_shape"].copy()
    nan_mu[0, 5] = np.nan
    png = tmp / "photo.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64)
    text = tmp / "notes.mat"
    text.write_text("not a model")
    empty = tmp / "empty.npz"
    empty.write_bytes(b"")
    v73 = tmp / "v73.mat"  # a MATLAB v7.3 header (HDF5 content follows in real files)
    v73.write_bytes(b"MATLAB 7.3 MAT-file".ljust(124, b" ") + b"\x00\x02IM" + b"\0" * 400)
    bad_mat = tmp / "truncated.mat"
    bad_mat.write_bytes(f["path"].read_bytes()[:300])
    bad_zip = tmp / "broken.npz"
    bad_zip.write_bytes(b"PK\x03\x04" + b"\0" * 50)
    return [
        (tmp / "does_not_exist.npz", "no such file"),
        (png, "unrecognised content"),
        (text, "unrecognised content"),
        (empty, "empty file"),
        (bad_mat, "readable MATLAB"),
        (bad_zip, "readable .npz"),
        (_save_mat(tmp / "no_tri.mat", **{k: v for k, v in base.items() if k != "tri"}), "tri"),
        (
            _save_mat(tmp / "no_basis.mat", **{k: v for k, v in base.items() if k != "basis_shape"}),
            "basis_shape",
        ),
        (
            _save_mat(tmp / "wide_basis.mat", **{**base, "basis_shape": f["basis_shape"][:, :-3]}),
            "basis_shape",
        ),
        (_save_mat(tmp / "odd_mu.mat", **{**base, "mu_shape": f["mu_shape"][:, :-1]}), "mu_shape"),
        (_save_mat(tmp / "nan_mu.mat", **{**base, "mu_shape": nan_mu}), "NaN"),
        (_save_mat(tmp / "tri_range.mat", **{**base, "tri": f["tri"] + 5.0}), "tri"),
        (_save_mat(tmp / "tri_float.mat", **{**base, "tri": f["tri"] + 0.5}), "integer"),
        (_save_mat(tmp / "kp_count.mat", **{**base, "keypoints": f["keypoints"][:, :50]}), "keypoints"),
        (_save_mat(tmp / "evs_count.mat", **{**base, "EVs": f["EVs"][:-1]}), "EVs"),
        (_save_mat(tmp / "mask_count.mat", **{**base, "mask_face": f["mask_face"][:, :-1]}), "mask_face"),
        (_save_mat(tmp / "tiny_units.mat", **{**base, "mu_shape": f["mu_shape"] * 1e-4}), "head-sized"),
        (v73, "h5py"),
        (_tiny_npz(tmp / "no_mean.npz", mean_shape=None), "mean_shape"),
        (_tiny_npz(tmp / "flat_mean.npz", mean_shape=np.zeros((12, 2), np.float32)), "mean_shape"),
        (_tiny_npz(tmp / "nan_basis.npz", id_basis=np.full((2, 12, 3), np.nan, np.float16)), "NaN"),
        (_tiny_npz(tmp / "float_tri.npz", triangles=np.zeros((4, 3))), "integer"),
        (_tiny_npz(tmp / "version.npz", format_version=np.array(7)), "format_version"),
        (_tiny_npz(tmp / "few_landmarks.npz", landmark_indices=np.zeros(68, np.int64)), "landmark_indices"),
    ]


def test_malformed_files_raise_model_file_error(tmp_path):
    h5py_present = True
    try:
        import h5py  # noqa: F401
    except ImportError:
        h5py_present = False
    for path, fragment in _bad_cases(tmp_path):
        if path.name == "v73.mat" and h5py_present:
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ModelFileWarning)
            with pytest.raises(ModelFileError) as info:
                load_model(path)
        message = str(info.value)
        assert path.name in message, message
        assert re.search(re.escape(fragment), message), (path.name, message)
