"""The UV-space GGX shader (paper A.1) against a plain per-texel float64 evaluation, its gradients,
energy sanity checks and the singular cases."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

import facegeo.texturing.shading as shading_module
from facegeo.texturing.ggx import environment_brdf
from facegeo.texturing.shading import (
    ALPHA_MIN,
    EPS_PARALLEL,
    ShadingResult,
    local_frame,
    shade_ggx,
)

FIELDS = ("shaded", "diffuse", "glossy", "shading", "visibility")
MAP_NAMES = (
    "albedo", "normal_ts", "roughness", "specular", "displacement",
    "position", "geo_normal", "geo_tangent", "mask",
)  # fmt: skip
ALL_NAMES = MAP_NAMES + ("light_dirs", "light_radiance", "camera_pos", "ambient")


# --------------------------------------------------------------------------------------------
# The reference: the formulas of appendix A.1 written out per texel and per light, NumPy float64,
# with the explicit Gram-Schmidt local frame and half vector (no guards: inputs avoid them).
# --------------------------------------------------------------------------------------------


def _unit(x):
    return x / math.sqrt(float(x @ x))


def reference_texel(albedo, nt, rough, spec, disp, pos, gn, gt, m, lights, radiance, cam, amb, s_disp=0.01):
    """One texel: all arguments are NumPy float64 vectors/scalars; returns the five outputs."""
    n_g = _unit(gn)
    t_g = _unit(gt)
    b_g = _unit(np.cross(n_g, t_g))
    n_s = _unit(nt[0] * t_g + nt[1] * b_g + nt[2] * n_g)
    t_l = _unit(gt - (gt @ n_s) * n_s)
    b_l = _unit(np.cross(n_s, t_l))
    frame = np.stack([t_l, b_l, n_s])  # rows: the local basis; frame @ x = local coordinates
    p = pos + s_disp * disp * n_g
    v_world = _unit(cam - p)
    v = frame @ v_world
    alpha = rough**2
    a2 = alpha**2
    f0 = 0.08 * spec
    diffuse = np.zeros(3)
    glossy = np.zeros(3)
    shading = np.zeros(3)
    for l_world, radiance_k in zip(lights, radiance):
        l = frame @ l_world
        h = _unit(l + v)
        nl = min(max(l[2], 0.0), 1.0)
        nv = min(max(v[2], 0.0), 1.0)
        nh = min(max(h[2], 0.0), 1.0)
        lh = min(max(l @ h, 0.0), 1.0)
        d = a2 / (math.pi * ((nh * nh) * (a2 - 1.0) + 1.0) ** 2)
        f = f0 + (1.0 - f0) * (1.0 - lh) ** 5
        vis = 0.5 / (nv * math.sqrt(a2 + (1.0 - a2) * nl * nl) + nl * math.sqrt(a2 + (1.0 - a2) * nv * nv))
        f_s = d * f * vis
        f_d = albedo / math.pi
        shading += radiance_k * nl
        diffuse += radiance_k * nl * f_d
        glossy += radiance_k * nl * f_s
    shaded = m * (diffuse + glossy + amb * albedo)
    visibility = m * min(max(n_g @ v_world, 0.0), 1.0)
    return shaded, diffuse, glossy, shading, np.array([visibility])


def reference(inputs, s_disp=0.01):
    """The reference over whole (B, C, H, W) inputs (dict of tensors), as NumPy arrays."""
    a = {k: (v.detach().double().numpy() if isinstance(v, torch.Tensor) else v) for k, v in inputs.items()}
    batch, _, height, width = a["albedo"].shape
    out = {f: np.zeros((batch, 1 if f == "visibility" else 3, height, width)) for f in FIELDS}
    amb = np.broadcast_to(np.asarray(a["ambient"], dtype=np.float64).reshape(-1), (batch,))
    for b in range(batch):
        for i in range(height):
            for j in range(width):
                texel = [a[name][b if a[name].shape[0] > 1 else 0, :, i, j] for name in MAP_NAMES]
                texel = [t if len(t) == 3 else float(t[0]) for t in texel]
                res = reference_texel(
                    *texel, a["light_dirs"][b], a["light_radiance"][b], a["camera_pos"][b], float(amb[b]), s_disp
                )
                for f, r in zip(FIELDS, res):
                    out[f][b, :, i, j] = r
    return out


def make_inputs(seed=0, batch=2, height=4, width=5, n_lights=3, dtype=torch.float64, below=True):
    """Generic inputs, away from every guard: roughness ≥ 0.2, tangents far from the normals,
    the camera well above every texel, lights in the upper hemisphere (one below if ``below``)."""
    rng = np.random.default_rng(seed)

    def u(lo, hi, *shape):
        return rng.uniform(lo, hi, size=shape)

    shape = (batch, 1, height, width)
    geo_n = np.concatenate([u(-0.4, 0.4, batch, 2, height, width), np.ones(shape)], axis=1) * u(0.5, 2, *shape)
    geo_t = np.concatenate([np.ones(shape), u(-0.3, 0.3, batch, 2, height, width)], axis=1) * u(0.5, 2, *shape)
    dirs = np.stack([u(-0.6, 0.6, batch, n_lights), u(-0.6, 0.6, batch, n_lights), u(0.5, 1, batch, n_lights)], -1)
    if below:
        dirs[:, -1, 2] = -0.7  # a light below every texel's horizon
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    raw = {
        "albedo": u(0.05, 0.95, batch, 3, height, width),
        "normal_ts": np.concatenate([u(-0.4, 0.4, batch, 2, height, width), u(0.7, 1.0, *shape)], axis=1),
        "roughness": u(0.2, 0.9, *shape),
        "specular": u(0.0, 1.0, *shape),
        "displacement": u(-1, 1, *shape),
        "position": u(-60, 60, batch, 3, height, width),
        "geo_normal": geo_n,
        "geo_tangent": geo_t,
        "mask": u(0.0, 1.0, *shape),
        "light_dirs": dirs,
        "light_radiance": u(0.2, 3.0, batch, n_lights, 3),
        "camera_pos": np.concatenate([u(-30, 30, batch, 2), u(400, 600, batch, 1)], axis=1),
    }
    inputs = {k: torch.tensor(v, dtype=dtype) for k, v in raw.items()}
    inputs["ambient"] = 0.2
    return inputs


def call(inputs, **kwargs):
    return shade_ggx(*(inputs[name] for name in ALL_NAMES), **kwargs)


# ---------------------------------------------------------------- agreement with the reference


def test_agrees_with_the_per_texel_reference_in_float64():
    inputs = make_inputs(seed=1)
    inputs["ambient"] = torch.tensor([0.15, 0.3], dtype=torch.float64)
    result = call(inputs)
    ref = reference(inputs)
    assert isinstance(result, ShadingResult)
    for f in FIELDS:
        out = getattr(result, f)
        assert out.dtype == torch.float64
        assert out.shape == ref[f].shape
        np.testing.assert_allclose(out.numpy(), ref[f], rtol=1e-10, atol=1e-12, err_msg=f)
    assert ref["glossy"].max() > 1e-3 and ref["diffuse"].max() > 1e-2  # both lobes exercised


def test_relative_agreement_where_no_clamp_is_active():
    # Every light above every horizon, camera above: no dot product reaches 0 or 1.
    inputs = make_inputs(seed=2, below=False)
    dots, ngv = _clamped_dots(inputs)
    for x in (*dots, ngv):
        assert 0 < x.min() and x.max() < 1
    result = call(inputs)
    ref = reference(inputs)
    for f in FIELDS:
        rel = np.abs(getattr(result, f).numpy() - ref[f]) / np.abs(ref[f])
        assert rel.max() < 1e-6, f  # the bar
        assert rel.max() < 1e-12, f  # what float64 actually gives


def test_s_disp_moves_the_point_along_the_geometric_normal():
    inputs = make_inputs(seed=3, batch=1, height=2, width=3)
    inputs["displacement"] = inputs["displacement"] * 2000  # a visible change of the view vector
    for s_disp in (0.0, 0.01, 0.05):
        result = call(inputs, s_disp=s_disp)
        ref = reference(inputs, s_disp=s_disp)
        for f in FIELDS:
            np.testing.assert_allclose(getattr(result, f).numpy(), ref[f], rtol=1e-10, atol=1e-12, err_msg=f)


def test_dtype_is_kept_and_float32_is_close_to_float64():
    inputs64 = make_inputs(seed=4)
    inputs32 = {k: v.float() if isinstance(v, torch.Tensor) else v for k, v in inputs64.items()}
    r64, r32 = call(inputs64), call(inputs32)
    for f in FIELDS:
        assert getattr(r64, f).dtype == torch.float64
        assert getattr(r32, f).dtype == torch.float32
        a, b = getattr(r32, f).double(), getattr(r64, f)
        assert ((a - b).abs() / (b.abs() + 1e-3)).max() < 1e-4, f


def test_batch_one_maps_and_lights_broadcast():
    inputs = make_inputs(seed=5, batch=2)
    shared = dict(inputs)
    for name in ("position", "geo_normal", "geo_tangent", "mask"):
        shared[name] = inputs[name][:1]
    shared["camera_pos"] = inputs["camera_pos"][:1]
    expanded = dict(shared)
    for name in ("position", "geo_normal", "geo_tangent", "mask"):
        expanded[name] = shared[name].expand(2, -1, -1, -1)
    expanded["camera_pos"] = shared["camera_pos"].expand(2, -1)
    a, b = call(shared), call(expanded)
    for f in FIELDS:
        assert getattr(a, f).shape == getattr(b, f).shape
        torch.testing.assert_close(getattr(a, f), getattr(b, f), rtol=0, atol=1e-14)


def test_batch_one_maps_get_the_gradient_summed_over_the_batch():
    inputs = make_inputs(seed=19, batch=2, height=2, width=3)
    shared = {**inputs, "geo_normal": inputs["geo_normal"][:1], "roughness": inputs["roughness"][:1]}
    _, grads = _values_and_grads(shared)
    per_item = [
        _values_and_grads({k: (v[b : b + 1] if isinstance(v, torch.Tensor) and v.shape[0] == 2 else v)
                           for k, v in shared.items()})[1]
        for b in range(2)
    ]  # fmt: skip
    for name in ("geo_normal", "roughness", "albedo", "light_dirs"):
        expected = per_item[0][name] + per_item[1][name] if shared[name].shape[0] == 1 else torch.cat(
            [per_item[0][name], per_item[1][name]]
        )
        torch.testing.assert_close(grads[name], expected, rtol=1e-12, atol=1e-12, msg=name)


def test_chunking_does_not_change_values_or_gradients(monkeypatch):
    inputs = make_inputs(seed=6, batch=2, height=3, width=5)
    leaves = {k: v.clone().requires_grad_() for k, v in inputs.items() if isinstance(v, torch.Tensor)}

    def run():
        for leaf in leaves.values():
            leaf.grad = None
        result = call({**inputs, **leaves})
        sum((getattr(result, f) * (i + 1)).sum() for i, f in enumerate(FIELDS)).backward()
        return result, {k: v.grad.clone() for k, v in leaves.items()}

    one, grads_one = run()
    monkeypatch.setattr(shading_module, "CHUNK_TEXELS", 4)  # 15 texels in chunks of 4, 4, 4, 3
    many, grads_many = run()
    for f in FIELDS:
        torch.testing.assert_close(getattr(one, f), getattr(many, f), rtol=1e-13, atol=1e-13)
    for k in leaves:
        torch.testing.assert_close(grads_one[k], grads_many[k], rtol=1e-12, atol=1e-12, msg=k)


def _values_and_grads(inputs):
    leaves = {k: v.clone().requires_grad_() for k, v in inputs.items() if isinstance(v, torch.Tensor)}
    result = call({**inputs, **leaves})
    sum((getattr(result, f) * (i + 1)).sum() for i, f in enumerate(FIELDS)).backward()
    return result, {k: v.grad for k, v in leaves.items()}


def test_the_torch_compile_code_path_matches(monkeypatch):
    # Under torch.compile shade_ggx takes one pass over all texels, always evaluates the guards'
    # branches (torch.where instead of a data-dependent skip) and leaves the BRDF gradient to
    # autograd. Simulate that path in eager mode: same values and gradients, guards active or not.
    for inputs in (make_inputs(seed=17), _extreme_inputs(torch.float64)):
        eager, grads = _values_and_grads(inputs)
        with monkeypatch.context() as m:
            m.setattr(torch.compiler, "is_compiling", lambda: True)
            traced, grads_traced = _values_and_grads(inputs)
        for f in FIELDS:
            torch.testing.assert_close(getattr(traced, f), getattr(eager, f), rtol=1e-12, atol=1e-12)
        for k in grads:
            torch.testing.assert_close(grads_traced[k], grads[k], rtol=1e-9, atol=1e-9, msg=k)


@pytest.mark.slow
def test_torch_compile_matches_eager():
    inputs = make_inputs(seed=18, dtype=torch.float32)
    compiled = torch.compile(shade_ggx, dynamic=False)
    eager = call(inputs)
    result = compiled(*(inputs[name] for name in ALL_NAMES))
    for f in FIELDS:
        torch.testing.assert_close(getattr(result, f), getattr(eager, f), rtol=1e-5, atol=1e-5)


def test_local_frame_is_orthonormal_and_keeps_the_dot_products():
    inputs = make_inputs(seed=7)
    t_l, b_l, n_s = local_frame(inputs["normal_ts"], inputs["geo_normal"], inputs["geo_tangent"])
    frame = torch.stack([t_l, b_l, n_s], dim=1)  # (B, 3 vectors, 3 components, H, W)
    gram = torch.einsum("biphw,bjphw->bijhw", frame, frame)
    eye = torch.eye(3, dtype=torch.float64)[None, :, :, None, None]
    torch.testing.assert_close(gram, eye.expand_as(gram), rtol=0, atol=1e-14)
    assert (torch.linalg.det(frame.permute(0, 3, 4, 1, 2)) > 0).all()  # right-handed
    # T_l lies in the plane of the geometric tangent and N_s (Gram-Schmidt, not an arbitrary axis)
    t_g = torch.nn.functional.normalize(inputs["geo_tangent"], dim=1)
    assert ((t_l * t_g).sum(1) > 0).all()
    torch.testing.assert_close(
        torch.linalg.cross(t_l, n_s, dim=1).mul(t_g).sum(1), torch.zeros_like(t_g[:, 0]), rtol=0, atol=1e-14
    )


# ---------------------------------------------------------------- gradients


def _clamped_dots(inputs, s_disp=0.01):
    """The unclamped n·l, n·v, n·h, l·h (B, K, H, W) and N_g·v (B, H, W), from plain NumPy."""
    a = {k: v.detach().numpy() for k, v in inputs.items() if isinstance(v, torch.Tensor)}
    unit = lambda x, axis=1: x / np.linalg.norm(x, axis=axis, keepdims=True)  # noqa: E731
    n_g, t_g = unit(a["geo_normal"]), unit(a["geo_tangent"])
    b_g = unit(np.cross(n_g, t_g, axis=1))
    nt = a["normal_ts"]
    n_s = unit(nt[:, 0:1] * t_g + nt[:, 1:2] * b_g + nt[:, 2:3] * n_g)
    v = unit(a["camera_pos"][:, :, None, None] - (a["position"] + s_disp * a["displacement"] * n_g))
    l = a["light_dirs"][:, :, :, None, None]  # (B, K, 3, 1, 1)
    h = unit(l + v[:, None], axis=2)
    dots = [(l * n_s[:, None]).sum(2), (v * n_s).sum(1)[:, None], (h * n_s[:, None]).sum(2), (l * h).sum(2)]
    return dots, (n_g * v).sum(1)


def _gradcheck_inputs(seed, below):
    inputs = make_inputs(seed=seed, batch=1, height=3, width=3, n_lights=2, below=below)
    inputs["ambient"] = torch.tensor([0.25], dtype=torch.float64)
    # Away from the kinks: no clamped dot product within 0.02 of 0 (1 is never reached).
    (nl, nv, nh, lh), ngv = _clamped_dots(inputs)
    lit = nl > 0
    for x in (nl, nv, ngv):
        assert np.abs(x).min() > 0.02
    assert nh[lit].min() > 0.02 and lh[lit].min() > 0.02
    return inputs


@pytest.mark.parametrize("below", [False, True])
@pytest.mark.parametrize("chunk", [None, 4])
def test_gradcheck_every_input(below, chunk, monkeypatch):
    if chunk is not None:
        monkeypatch.setattr(shading_module, "CHUNK_TEXELS", chunk)
    inputs = _gradcheck_inputs(seed=8, below=below)
    names = [n for n in ALL_NAMES if isinstance(inputs[n], torch.Tensor)]
    leaves = [inputs[n].clone().requires_grad_() for n in names]

    def fn(*args):
        return tuple(call(dict(inputs, **dict(zip(names, args)))))

    assert torch.autograd.gradcheck(fn, leaves, eps=1e-6, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("name", MAP_NAMES)
def test_gradcheck_each_map_alone(name):
    # One map at a time (the others constant), so a wrong gradient is attributed to its input.
    inputs = _gradcheck_inputs(seed=9, below=True)
    leaf = inputs[name].clone().requires_grad_()
    assert torch.autograd.gradcheck(lambda x: tuple(call(dict(inputs, **{name: x}))), (leaf,), eps=1e-6, atol=1e-6)


def test_gradient_of_s_disp():
    inputs = _gradcheck_inputs(seed=10, below=False)
    inputs["displacement"] = inputs["displacement"] * 1000
    s = torch.tensor(0.01, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda s_: tuple(call(inputs, s_disp=s_)), (s,), eps=1e-7, atol=1e-6)


# ---------------------------------------------------------------- energy sanity


def _hemisphere_grid(n_mu, n_phi, dtype=torch.float64):
    """Midpoint rule over the upper hemisphere: directions (N, 3) and solid-angle weights (N,)."""
    mu = (torch.arange(n_mu, dtype=dtype) + 0.5) / n_mu
    phi = (torch.arange(n_phi, dtype=dtype) + 0.5) / n_phi * 2 * math.pi
    mu, phi = torch.meshgrid(mu, phi, indexing="ij")
    s = (1 - mu**2).sqrt()
    dirs = torch.stack([s * phi.cos(), s * phi.sin(), mu], dim=-1).reshape(-1, 3)
    return dirs, torch.full((dirs.shape[0],), 2 * math.pi / (n_mu * n_phi), dtype=dtype)


def _flat_texel(roughness, specular, view_dir, albedo=0.5):
    """One texel at the origin with N_g = N_s = +z, camera 1000 units along view_dir."""
    f64 = torch.float64
    one = torch.ones(1, 1, 1, 1, dtype=f64)
    vec = lambda x: torch.tensor(x, dtype=f64).reshape(1, 3, 1, 1)  # noqa: E731
    return {
        "albedo": vec([albedo] * 3),
        "normal_ts": vec([0.0, 0.0, 1.0]),
        "roughness": roughness * one,
        "specular": specular * one,
        "displacement": 0 * one,
        "position": vec([0.0, 0.0, 0.0]),
        "geo_normal": vec([0.0, 0.0, 1.0]),
        "geo_tangent": vec([1.0, 0.0, 0.0]),
        "mask": one,
        "camera_pos": 1000 * torch.tensor(view_dir, dtype=f64).reshape(1, 3) / np.linalg.norm(view_dir),
        "ambient": 0.0,
    }


def test_lambertian_part_integrates_to_the_albedo_under_uniform_light():
    # White furnace for the diffuse lobe: radiance 1 from every direction of the hemisphere,
    # Σ_k L_k (n·l_k) albedo/π dω_k → albedo; and shading → π (∫ cos dω).
    dirs, weights = _hemisphere_grid(200, 64)
    texel = _flat_texel(0.5, 0.5, [0.3, 0.1, 1.0], albedo=0.7)
    texel["light_dirs"] = dirs[None]
    texel["light_radiance"] = weights[None, :, None].expand(1, -1, 3)
    result = call(texel)
    np.testing.assert_allclose(result.diffuse.numpy().ravel(), 0.7, rtol=2e-5)
    np.testing.assert_allclose(result.shading.numpy().ravel(), math.pi, rtol=2e-5)


def test_ggx_distribution_of_a1_is_normalised():
    # ∫ D(h) (n·h) dω_h = 1 for the Trowbridge-Reitz D of A.1 (with its 1/π); the reference test
    # above shows the shader computes exactly this D.
    for roughness in (0.3, 0.5, 0.8, 1.0):
        a2 = roughness**4
        # substitute t = (n·h)² (a2 − 1)+1 ... integrate in μ = n·h with a fine midpoint rule
        mu = (np.arange(2_000_000) + 0.5) / 2_000_000
        d = a2 / (math.pi * (mu**2 * (a2 - 1) + 1) ** 2)
        integral = 2 * math.pi * np.mean(d * mu)
        assert integral == pytest.approx(1.0, abs=1e-6), roughness


def _specular_albedo(roughness, view_z, n_mu=1200, n_phi=240):
    """E(v) = ∫ f_s (n·l) dω_l with F ≡ 1 (F0 = 0.08 · 12.5 = 1), by the shader, quadrature over l."""
    dirs, weights = _hemisphere_grid(n_mu, n_phi)
    texel = _flat_texel(roughness, 12.5, [math.sqrt(1 - view_z**2), 0.0, view_z])
    texel["light_dirs"] = dirs[None]
    texel["light_radiance"] = weights[None, :, None].expand(1, -1, 3)
    return float(call(texel).glossy[0, 0, 0, 0])


@pytest.mark.parametrize("roughness", [0.2, 0.3, 0.5, 0.7, 1.0])
@pytest.mark.parametrize("view_z", [1.0, 0.5, 0.15])
def test_specular_albedo_at_f0_one_is_at_most_one(roughness, view_z):
    # White furnace for the glossy lobe: single-scattering GGX with the height-correlated Smith
    # term loses energy (no multiple scattering) and never creates it: E(v) ≤ 1.
    albedo = _specular_albedo(roughness, view_z)
    assert 0.3 < albedo <= 1.0 + 1e-3


@pytest.mark.parametrize("view_z", [1.0, 0.5, 0.15, 0.02])
def test_specular_albedo_at_roughness_one_is_analytic(view_z):
    # α = 1: D = 1/π is uniform and V = 0.5/(n·l + n·v), so with F ≡ 1
    # E(μ_v) = ∫₀¹ μ/(μ + μ_v) dμ = 1 − μ_v ln(1 + 1/μ_v)  (1 − ln 2 head-on).
    expected = 1 - view_z * math.log(1 + 1 / view_z)
    assert _specular_albedo(1.0, view_z, 2000, 16) == pytest.approx(expected, abs=2e-6)


def test_glossy_peaks_in_the_mirror_direction():
    texel = _flat_texel(0.3, 0.5, [0.6, 0.0, 0.8])
    angles = torch.linspace(-1.2, 1.2, 241, dtype=torch.float64)
    texel["light_dirs"] = torch.stack([angles.sin(), 0 * angles, angles.cos()], -1)[None]
    texel["light_radiance"] = torch.ones(1, 241, 3, dtype=torch.float64)
    # one light at a time: K lights on one texel give the sum, so shade K texels instead
    glossy = [
        float(call({**texel, "light_dirs": texel["light_dirs"][:, k : k + 1],
                    "light_radiance": texel["light_radiance"][:, k : k + 1]}).glossy[0, 0, 0, 0])
        for k in range(241)
    ]  # fmt: skip
    mirror = -math.asin(0.6)
    assert abs(float(angles[int(np.argmax(glossy))]) - mirror) < 0.02


# ---------------------------------------------------------------- singular cases


def _extreme_inputs(dtype):
    """A 2×6 map where each texel hits a different singular case (see the comments)."""
    inputs = make_inputs(seed=11, batch=1, height=2, width=6, n_lights=3, dtype=dtype, below=True)
    tiny = torch.finfo(dtype).tiny
    huge = 1e30 if dtype == torch.float32 else 1e300
    inp = {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in inputs.items()}
    # light 0 exactly opposite the view of texel (0, 0); light 1 grazing (in the tangent plane of +z)
    inp["light_dirs"][0, 1] = torch.tensor([1.0, 0.0, 0.0], dtype=dtype)
    inp["roughness"][0, 0, 0, 0] = 0.0  # roughness 0
    inp["roughness"][0, 0, 0, 1] = 1e-9
    inp["camera_pos"][0] = torch.tensor([0.0, 0.0, 500.0], dtype=dtype)
    inp["position"][0, :, 0, 2] = torch.tensor([-1000.0, 0.0, 500.0], dtype=dtype)  # grazing view
    inp["geo_normal"][0, :, 0, 2] = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)
    inp["normal_ts"][0, :, 0, 2] = torch.tensor([0.0, 0.0, 1.0], dtype=dtype)
    inp["displacement"][0, 0, 0, 2] = 0.0
    inp["geo_tangent"][0, :, 0, 3] = inp["geo_normal"][0, :, 0, 3] * 3  # tangent ∥ normal
    inp["geo_tangent"][0, :, 0, 4] = -inp["geo_normal"][0, :, 0, 4]  # tangent antiparallel
    inp["geo_tangent"][0, :, 0, 5] = 0.0  # zero tangent
    inp["geo_normal"][0, :, 1, 0] = 0.0  # zero normal
    inp["geo_normal"][0, :, 1, 1] = 0.0  # zero normal and zero tangent
    inp["geo_tangent"][0, :, 1, 1] = 0.0
    inp["normal_ts"][0, :, 1, 2] = 0.0  # zero tangent-space normal
    inp["displacement"][0, 0, 1, 3] = huge  # huge displacement
    inp["position"][0, :, 1, 4] = inp["camera_pos"][0]  # camera on the surface point: v = 0
    inp["displacement"][0, 0, 1, 4] = 0.0
    inp["mask"][0, 0, 1, 5] = 0.0  # mask 0
    inp["geo_normal"][0, :, 1, 5] = tiny  # denormal-small normal
    # texel (0, 0): make light 0 exactly opposite to its view direction
    p = inp["position"][0, :, 0, 0] + 0.01 * inp["displacement"][0, 0, 0, 0] * torch.nn.functional.normalize(
        inp["geo_normal"][0, :, 0, 0], dim=0
    )
    inp["light_dirs"][0, 0] = -torch.nn.functional.normalize(inp["camera_pos"][0] - p, dim=0)
    return inp


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_singular_cases_are_finite_in_value_and_gradient(dtype):
    inputs = _extreme_inputs(dtype)
    leaves = {k: v.clone().requires_grad_() for k, v in inputs.items() if isinstance(v, torch.Tensor)}
    result = call({**inputs, **leaves})
    for f in FIELDS:
        out = getattr(result, f)
        assert out.dtype == dtype
        assert torch.isfinite(out).all(), f
    assert float(result.shaded[0, :, 1, 5].detach().abs().max()) == 0.0  # mask 0
    assert float(result.visibility[0, 0, 0, 2].detach()) == pytest.approx(0.0, abs=1e-6)  # grazing view
    assert float(result.visibility[0, 0, 1, 3].detach()) == 0.0  # displaced far above the camera
    loss = sum((getattr(result, f) * (i + 1)).sum() for i, f in enumerate(FIELDS))
    loss.backward()
    for name, leaf in leaves.items():
        assert leaf.grad is not None, name
        assert torch.isfinite(leaf.grad).all(), name


def test_roughness_zero_is_the_clamped_alpha():
    inputs = make_inputs(seed=12, batch=1, height=2, width=2)
    r0 = call({**inputs, "roughness": torch.zeros_like(inputs["roughness"])})
    r_min = call({**inputs, "roughness": torch.full_like(inputs["roughness"], math.sqrt(ALPHA_MIN))})
    torch.testing.assert_close(r0.glossy, r_min.glossy, rtol=1e-14, atol=0)
    assert torch.isfinite(r0.glossy).all()


def test_guards_do_not_touch_regular_texels():
    # A degenerate texel (tangent ∥ normal) switches the tangent guard on for its chunk; the other
    # texels must come out bit for bit as without it.
    inputs = make_inputs(seed=13, batch=1, height=3, width=4)
    regular = call(inputs)
    bad = {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in inputs.items()}
    bad["geo_tangent"][0, :, 1, 2] = bad["geo_normal"][0, :, 1, 2]
    bad["geo_normal"][0, :, 2, 3] = 0.0
    bad["displacement"][0, 0, 0, 0] = 1e300
    guarded = call(bad)
    keep = torch.ones(3, 4, dtype=torch.bool)
    keep[1, 2] = keep[2, 3] = keep[0, 0] = False
    for f in FIELDS:
        a, b = getattr(regular, f)[..., keep], getattr(guarded, f)[..., keep]
        assert torch.equal(a, b), f


def test_tangent_guard_is_continuous():
    # The shading normal changes smoothly as the tangent turns into the normal across EPS_PARALLEL.
    inputs = make_inputs(seed=14, batch=1, height=1, width=1, below=False)
    n_g = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    inputs["geo_normal"] = n_g.reshape(1, 3, 1, 1)
    values = []
    sines = [EPS_PARALLEL * f for f in (0.9, 0.99, 0.999, 1.001, 1.01, 1.1)]
    for s in sines:
        t = torch.tensor([s, 0.0, math.sqrt(1 - s * s)], dtype=torch.float64)
        values.append(call({**inputs, "geo_tangent": t.reshape(1, 3, 1, 1)}).shaded.flatten())
    jumps = [float((b - a).abs().max()) for a, b in zip(values, values[1:])]
    assert max(jumps) < 1e-2 * float(values[0].abs().max())


def test_light_below_the_horizon_contributes_nothing():
    inputs = make_inputs(seed=15, batch=1, height=2, width=2, n_lights=1, below=True)
    result = call(inputs)
    assert float(result.shading.abs().max()) == 0.0
    assert float(result.glossy.abs().max()) == 0.0
    torch.testing.assert_close(result.shaded, inputs["mask"] * 0.2 * inputs["albedo"], rtol=1e-15, atol=0)


# ---------------------------------------------------------------- random inputs


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    roughness=st.floats(0.0, 1.5),
    ambient=st.floats(0.0, 1.0),
    scale=st.floats(1e-3, 1e3),
)
def test_random_inputs_are_finite_and_consistent(seed, roughness, ambient, scale):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=g, dtype=torch.float64)  # noqa: E731
    n = lambda *s: torch.randn(*s, generator=g, dtype=torch.float64)  # noqa: E731
    batch, k = 2, 3
    light = n(batch, k, 3)
    inputs = {
        "albedo": r(batch, 3, 3, 4),
        "normal_ts": 2 * r(batch, 3, 3, 4) - 1,
        "roughness": roughness * r(batch, 1, 3, 4),
        "specular": r(batch, 1, 3, 4),
        "displacement": n(batch, 1, 3, 4),
        "position": scale * n(batch, 3, 3, 4),
        "geo_normal": scale * n(batch, 3, 3, 4),
        "geo_tangent": n(batch, 3, 3, 4),
        "mask": (r(batch, 1, 3, 4) > 0.3).double(),
        "light_dirs": light / light.norm(dim=-1, keepdim=True),
        "light_radiance": 3 * r(batch, k, 3),
        "camera_pos": scale * 5 * n(batch, 3),
        "ambient": ambient,
    }
    leaves = {k_: v.clone().requires_grad_() for k_, v in inputs.items() if isinstance(v, torch.Tensor)}
    result = call({**inputs, **leaves})
    for f in FIELDS:
        assert torch.isfinite(getattr(result, f)).all(), f
        assert (getattr(result, f) >= 0).all(), f
    assert (result.visibility <= inputs["mask"]).all()
    assert (result.shading <= inputs["light_radiance"].sum(1)[:, :, None, None] * (1 + 1e-12)).all()
    torch.testing.assert_close(result.diffuse, result.shading * inputs["albedo"] / math.pi, rtol=1e-14, atol=0)
    torch.testing.assert_close(
        result.shaded, inputs["mask"] * (result.diffuse + result.glossy + ambient * inputs["albedo"]),
        rtol=1e-14, atol=1e-300,
    )  # fmt: skip
    sum(getattr(result, f).sum() for f in FIELDS).backward()
    for name, leaf in leaves.items():
        assert torch.isfinite(leaf.grad).all(), name


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_random_regular_inputs_match_the_reference(seed):
    inputs = make_inputs(seed=seed, batch=1, height=2, width=3, n_lights=2, below=bool(seed % 2))
    result = call(inputs)
    ref = reference(inputs)
    for f in FIELDS:
        np.testing.assert_allclose(getattr(result, f).numpy(), ref[f], rtol=1e-10, atol=1e-12, err_msg=f)


# ---------------------------------------------------------------- input checks


def test_input_checks():
    inputs = make_inputs(seed=16, batch=2, height=2, width=2)
    with pytest.raises(TypeError, match="dtype"):
        call({**inputs, "roughness": inputs["roughness"].float()})
    with pytest.raises(ValueError, match="roughness"):
        call({**inputs, "roughness": inputs["roughness"].expand(2, 3, 2, 2)})
    with pytest.raises(ValueError, match="position"):
        call({**inputs, "position": inputs["position"][..., :1]})
    with pytest.raises(ValueError, match="light_radiance"):
        call({**inputs, "light_radiance": inputs["light_radiance"][:, :2]})
    with pytest.raises(ValueError, match="camera_pos"):
        call({**inputs, "camera_pos": inputs["camera_pos"][:, :2]})
    with pytest.raises(ValueError, match="ambient"):
        call({**inputs, "ambient": torch.zeros(3, dtype=torch.float64)})
    half = {k: v.half() if isinstance(v, torch.Tensor) else v for k, v in inputs.items()}
    with pytest.raises(TypeError, match="float32 or float64"):
        call(half)
    with pytest.raises(TypeError, match="Tensor"):
        call({**inputs, "albedo": inputs["albedo"].numpy()})


# ---------------------------------------------------------------- the NumPy twin (texturing.ggx)


def _ggx_numpy(inputs, batch_item=0):
    """facegeo.texturing.ggx.ggx_shaded on one batch item of shade_ggx's inputs -> (3, H, W)."""
    from facegeo.texturing.ggx import ggx_shaded

    def rows(name):  # (C, H, W) of the item -> (H·W, C)
        t = inputs[name]
        t = t[batch_item if t.shape[0] > 1 else 0]
        return t.detach().numpy().reshape(t.shape[0], -1).T

    shaded = ggx_shaded(*(rows(n) for n in ("albedo", "normal_ts", "roughness", "specular", "position", "geo_normal", "geo_tangent")),
                        inputs["light_dirs"][batch_item].numpy(), inputs["light_radiance"][batch_item].numpy(),
                        inputs["camera_pos"][batch_item].numpy(), float(inputs["ambient"]))
    height, width = inputs["albedo"].shape[2:]
    return shaded.T.reshape(3, height, width)


def _flat(inputs):
    """No displacement, mask 1: the case ggx_shaded covers."""
    return {**inputs, "displacement": torch.zeros_like(inputs["displacement"]), "mask": torch.ones_like(inputs["mask"])}


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_the_numpy_twin_matches_the_reference_and_shade_ggx(seed):
    inputs = _flat(make_inputs(seed=seed, batch=2, height=3, width=4, below=bool(seed % 2)))
    inputs["ambient"] = 0.2
    ref = reference(inputs)["shaded"]
    torch_shaded = call(inputs).shaded.numpy()
    for b in range(2):
        mine = _ggx_numpy(inputs, b)
        assert mine.dtype == np.float64
        np.testing.assert_allclose(mine, ref[b], rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(mine, torch_shaded[b], rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_numpy_twin_keeps_the_guards(dtype):
    # every singular texel of _extreme_inputs but the displacement and mask ones: roughness 0,
    # tangent parallel, antiparallel or zero, zero normals, the camera on the point, light
    # opposite the view, a denormal normal; finite and equal to shade_ggx within float rounding
    inputs = {**_flat(_extreme_inputs(dtype)), "ambient": 0.15}
    mine = _ggx_numpy(inputs)
    assert mine.dtype == (np.float64 if dtype == torch.float64 else np.float32) and np.isfinite(mine).all()
    tol = dict(rtol=1e-10, atol=1e-12) if dtype == torch.float64 else dict(rtol=2e-4, atol=1e-5)
    np.testing.assert_allclose(mine, call(inputs).shaded[0].numpy(), **tol)


def test_the_numpy_twin_broadcasts_materials_over_one_geometry_and_refuses_nan():
    from facegeo.errors import InputError
    from facegeo.texturing.ggx import ggx_shaded

    rng = np.random.default_rng(5)
    n = 7
    geometry = [rng.normal(size=(1, n, 3)) + [0, 0, -300], rng.normal(size=(1, n, 3)) * 0.2 + [0, 0, 1], rng.normal(size=(1, n, 3)) * 0.2 + [1, 0, 0]]
    materials = [rng.uniform(size=(2, n, 3)), rng.uniform(-0.3, 0.3, size=(2, n, 3)) + [0, 0, 1], rng.uniform(0.2, 1, size=(2, n, 1)), rng.uniform(size=(2, n, 1))]
    light = (np.array([[0.3, 0.4, 0.8]]), np.array([[2.0, 2.0, 2.0]]), np.zeros(3), 0.1)
    both = ggx_shaded(*materials, *geometry, *light)
    assert both.shape == (2, n, 3)
    for b in range(2):
        np.testing.assert_array_equal(both[b], ggx_shaded(*(m[b] for m in materials), *(g[0] for g in geometry), *light))
    materials[0][1, 3, 0] = np.nan
    with pytest.raises(InputError, match="albedo"):
        ggx_shaded(*materials, *geometry, *light)


@pytest.mark.parametrize("roughness", [0.3, 0.5, 0.7])
@pytest.mark.parametrize("view_z", [1.0, 0.5, 0.2])
def test_environment_brdf_fit_agrees_with_the_shaders_integral(roughness, view_z):
    # Karis's analytic fit (made for UE4's separable Smith term) against our shader's glossy lobe
    # integrated by quadrature (height-correlated Smith), F0 = 0.04 as skin: within 30 %, the
    # trend with n·v and roughness kept (the de-lighting's prior on the skin's albedo is coarser)
    dirs, weights = _hemisphere_grid(1200, 240)
    texel = _flat_texel(roughness, 0.5, [math.sqrt(1 - view_z**2), 0.0, view_z])
    texel["light_dirs"] = dirs[None]
    texel["light_radiance"] = weights[None, :, None].expand(1, -1, 3)
    integral = float(call(texel).glossy[0, 0, 0, 0])
    assert float(environment_brdf(np.float64(view_z), roughness, 0.04)) == pytest.approx(integral, rel=0.3)


def test_environment_brdf_rises_towards_grazing_angles():
    nv = np.linspace(1.0, 0.05, 20)
    e = environment_brdf(nv, 0.5, 0.04)
    assert np.all(np.diff(e) >= 0) and np.all(np.diff(e[nv > 0.25]) > 0)  # flat where the fit saturates (n·v < 0.2)
    assert e[0] == pytest.approx(0.031, abs=0.002) and e[-1] > 4 * e[0]
