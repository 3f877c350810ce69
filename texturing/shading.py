"""The differentiable UV-space GGX shader of the paper's appendix A.1 (``S_GGX``), exactly.

Everything is evaluated per texel of the UV square; there is no rasterisation. For each texel u:

1. Geometry. ``N_g = normalize(geo_normal)``, ``T_g = normalize(geo_tangent)``,
   ``P = position + s_disp · displacement · N_g`` (the displacement moves the point along the
   geometric normal; it does not bend the normal).
2. Shading normal. ``B_g = normalize(N_g × T_g)``,
   ``N_s = normalize(n_x T_g + n_y B_g + n_z N_g)`` with ``(n_x, n_y, n_z) = normal_ts``.
   ``T_g`` is used as given (normalised, not re-orthogonalised against ``N_g``), as in A.1.
3. Local frame (Gram–Schmidt). ``T_l = normalize(T_g − (T_g·N_s) N_s)``,
   ``B_l = normalize(N_s × T_l)``; ``l`` and ``v`` are expressed in ``{T_l, B_l, N_s}``, where the
   normal is ``n = (0, 0, 1)``. The BRDF below is isotropic, so it only depends on ``n·l``, ``n·v``,
   ``n·h`` and ``l·h``; a change to an orthonormal basis keeps dot products, hence these equal the
   world-space products with ``N_s`` and ``shade_ggx`` evaluates them in world space (same values up
   to rounding, and no failure where the local frame itself degenerates). :func:`local_frame`
   returns the frame for callers that need it; the tests check the equality explicitly.
4. BRDF. ``v = normalize(camera_pos − P)``, ``h = normalize(l + v)``, every dot product clamped
   to [0, 1]; ``α = roughness²``, ``a2 = α²``;
   ``D = a2 / (π ((n·h)² (a2 − 1) + 1)²)`` (Trowbridge–Reitz with its 1/π);
   ``F = F0 + (1 − F0)(1 − l·h)⁵`` (Schlick) with ``F0 = 0.08 · specular``;
   ``V = 0.5 / ((n·v) √(a2 + (1 − a2)(n·l)²) + (n·l) √(a2 + (1 − a2)(n·v)²))`` — the
   height-correlated Smith masking-shadowing term with the 1/(4 (n·l)(n·v)) of Cook–Torrance folded
   in, written exactly as in A.1; ``f_s = D F V``, ``f_d = albedo / π``.
5. Sums over the K directional lights:
   ``shading = Σ_k L_k (n·l_k)⁺``, ``diffuse = shading · f_d``,
   ``glossy = Σ_k L_k (n·l_k)⁺ f_s(l_k)`` (none of the three masked),
   ``shaded = M · (diffuse + glossy + I_amb · albedo)``, ``visibility = M · (N_g·v)⁺``
   (A.1 writes ``M · (1/K) Σ_k (N_g·v)⁺``, which does not depend on k).

Guards. Each guard is a clamp or a switch that is inactive (bit-for-bit no effect) unless its
condition holds, so results agree with the plain formulas wherever no guard is active; where one is
active, values and gradients stay finite:

- :data:`ALPHA_MIN` = 2e-3: ``α = max(roughness², ALPHA_MIN)`` (roughness 0 makes D a delta and
  0/0 at n·h = 1). Active for |roughness| < 0.0447; there the roughness gradient is 0.
- :data:`EPS_NORM` = 1e-12: ``normalize(x) = x / max(|x|, EPS_NORM)``: a vector shorter than
  EPS_NORM (in its own units; a zero normal outside the UV charts, the camera on the surface point)
  shrinks linearly to 0 instead of being normalised (gradient ``1/EPS_NORM``). Where ``|x|²``
  overflows (e.g. a huge displacement), x is first divided by ``max_i |x_i|``.
- :data:`EPS_PARALLEL` = 1e-3: where ``sin∠(N_g, T_g) < EPS_PARALLEL`` (tangent parallel to the
  normal, or a zero tangent), the tangent is replaced by ``normalize(T_g + w T_fb)`` with
  ``w = (1 − sin²/EPS_PARALLEL²)²`` (so value and first derivative are continuous at the
  threshold) and ``T_fb`` the fixed unit vector perpendicular to ``N_g`` of Duff et al. 2017
  ("Building an orthonormal basis, revisited"; it switches sign convention across ``N_g,z = 0``).
  The same rule keeps ``T_l`` defined in :func:`local_frame`.
- :data:`EPS_HALF` = 1e-6: ``|l + v|`` is clamped below at EPS_HALF (light exactly opposite the view).
- :data:`EPS_SMITH` = 1e-8: the denominator of V is clamped below at EPS_SMITH (it is 0 only where
  n·l = n·v = 0; with ``α ≥ ALPHA_MIN`` it is otherwise ≥ ALPHA_MIN·max(n·l, n·v)).

Inputs must be finite; texels whose geometry maps are zero (outside the UV charts) get finite but
meaningless values and should have mask 0.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from facegeo.asset import SPECULAR_F0_SCALE
from facegeo.errors import check_finite
from facegeo.texturing.ggx import ALPHA_MIN, EPS_HALF, EPS_NORM, EPS_PARALLEL, EPS_SMITH  # the guards' constants, shared with the NumPy twin

__all__ = [
    "ShadingResult",
    "shade_ggx",
    "local_frame",
    "ALPHA_MIN",
    "EPS_NORM",
    "EPS_PARALLEL",
    "EPS_HALF",
    "EPS_SMITH",
    "CHUNK_TEXELS",
]

#: Texels evaluated together on the CPU: every temporary of a chunk stays in the cache, and the
#: backward recomputes a chunk instead of keeping its temporaries (memory: inputs and outputs only).
#: On other devices the whole map is one chunk. Results do not depend on it (up to rounding).
CHUNK_TEXELS = 32768


class ShadingResult(NamedTuple):
    """Outputs of :func:`shade_ggx`, channel-first, dtype and device of the inputs.

    shaded, diffuse, glossy, shading: (B, 3, H, W) linear RGB radiance (units of light_radiance;
    shading is the irradiance-like Σ L_k (n·l_k)⁺). visibility: (B, 1, H, W), in [0, 1]·mask.
    """

    shaded: Tensor
    diffuse: Tensor
    glossy: Tensor
    shading: Tensor
    visibility: Tensor


Vec = tuple[Tensor, Tensor, Tensor]  # a 3-vector map as its components, each (B, H, W)


def _dot(a: Vec, b: Vec) -> Tensor:
    return torch.addcmul(torch.addcmul(a[0] * b[0], a[1], b[1]), a[2], b[2])


def _cross(a: Vec, b: Vec) -> Vec:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _normalize(x: Vec, bounded: bool = False) -> Vec:
    """x / max(|x|, EPS_NORM), overflow-safe (``bounded``: the caller knows |x| ≤ 2, skip the check).

    Where |x|² overflows, x is first divided by s = max_i |x_i| (detached: the result does not
    depend on s, so the gradient stays exact); other texels are computed by the plain formula.
    """
    n2 = _dot(x, x)
    if not bounded and (torch.compiler.is_compiling() or bool(torch.isinf(n2.detach().amax()))):
        overflow = torch.isinf(n2)
        scale = torch.maximum(torch.maximum(x[0].detach().abs(), x[1].detach().abs()), x[2].detach().abs())
        scale = torch.where(overflow, scale, torch.ones_like(scale))
        x = (x[0] / scale, x[1] / scale, x[2] / scale)
        n2 = _dot(x, x)
    inv = n2.clamp_min(EPS_NORM**2).rsqrt()
    return (x[0] * inv, x[1] * inv, x[2] * inv)


def _perpendicular(n: Vec) -> Vec:
    """A fixed unit vector ⟂ n (Duff et al. 2017); finite for n = 0 (gives e_x)."""
    nx, ny, nz = n
    sign = (nz >= 0).to(nz.dtype) * 2.0 - 1.0
    a = -1.0 / (sign + nz)  # |sign + nz| ≥ 1
    b = nx * ny * a
    return (1.0 + sign * nx * nx * a, sign * b, -sign * nx)


def _tangent_and_cross(t: Vec, n: Vec) -> tuple[Vec, Vec]:
    """The unit tangent t, blended towards a fixed ⟂ axis where sin∠(t, n) < EPS_PARALLEL, and n × t.

    Returns t itself (bit for bit) at every texel where the guard is inactive.
    """
    c = _cross(n, t)
    sin2 = _dot(c, c)
    degenerate = sin2 < EPS_PARALLEL**2
    if torch.compiler.is_compiling() or bool(degenerate.any()):
        w = (1.0 - sin2 / EPS_PARALLEL**2).clamp_min(0.0) ** 2
        blended = _normalize(tuple(torch.addcmul(t_i, w, p_i) for t_i, p_i in zip(t, _perpendicular(n))), True)
        t = tuple(torch.where(degenerate, b_i, t_i) for b_i, t_i in zip(blended, t))
        c = _cross(n, t)
    return t, c


def _shading_normal(normal_ts: Vec, n_g: Vec, t_g: Vec) -> tuple[Vec, Vec]:
    """N_s = normalize(n_x T_g + n_y B_g + n_z N_g), B_g = normalize(N_g × T_g), and the T_g used."""
    t_g, c = _tangent_and_cross(t_g, n_g)
    b_g = _normalize(c, bounded=True)  # |N_g × T_g| ≤ 1
    nx, ny, nz = normal_ts
    lifted = tuple(torch.addcmul(torch.addcmul(nx * t_i, ny, b_i), nz, n_i) for t_i, b_i, n_i in zip(t_g, b_g, n_g))
    return _normalize(lifted), t_g


def local_frame(normal_ts: Tensor, geo_normal: Tensor, geo_tangent: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The corrected local shading frame (T_l, B_l, N_s) of A.1, each (B, 3, H, W) unit vectors.

    ``normal_ts`` (B, 3, H, W) decoded tangent-space normal in [-1, 1]; ``geo_normal``,
    ``geo_tangent`` (B, 3, H, W) world space, any length. T_l is the Gram–Schmidt tangent
    normalize(T_g − (T_g·N_s) N_s), B_l = normalize(N_s × T_l). Guards as in the module docstring
    (EPS_PARALLEL applies to T_g ∥ N_g and again to T_g ∥ N_s). :func:`shade_ggx` needs only N_s.
    """
    n_g = _normalize(geo_normal.unbind(1))
    n_s, t_g = _shading_normal(normal_ts.unbind(1), n_g, _normalize(geo_tangent.unbind(1)))
    t_g, _ = _tangent_and_cross(t_g, n_s)
    along = _dot(t_g, n_s)
    t_l = _normalize(tuple(torch.addcmul(t_i, along, n_i, value=-1.0) for t_i, n_i in zip(t_g, n_s)), True)
    b_l = _normalize(_cross(n_s, t_l), bounded=True)
    return torch.stack(t_l, 1), torch.stack(b_l, 1), torch.stack(n_s, 1)


def _clamp_mask(x: Tensor) -> Tensor:
    """Where clamp(x, 0, 1) passes the gradient (torch's convention: the bounds included)."""
    return (x >= 0) & (x <= 1)


def _project(lights: Tensor, x: Tensor) -> Tensor:
    """l_k · x for lights (B, K, 3) and vectors x (B, 3, N) -> (B, K, N)."""
    if torch.compiler.is_compiling():  # pointwise, so that the compiler fuses it with its users
        return sum(lights[:, :, i : i + 1] * x[:, i : i + 1] for i in range(3))
    return torch.bmm(lights, x)


def _brdf_terms(n: Tensor, v: Tensor, a2: Tensor, f0: Tensor, lights: Tensor) -> dict[str, Tensor]:
    """Per-light BRDF quantities. n, v: (B, 3, N); a2, f0: (B, 1, N); lights (B, K, 3).

    Returns (B, K, N) maps (texel maps (B, 1, N), light maps (B, K, 1)), the intermediates that
    :class:`_LightSums` needs for its backward; ``nl`` is (n·l)⁺ and ``spec`` is (n·l)⁺ f_s.
    """
    t: dict[str, Tensor] = {}
    t["nl_raw"] = nl_raw = _project(lights, n)
    t["lv"] = lv = _project(lights, v)
    t["nv_raw"] = nv_raw = torch.addcmul(torch.addcmul(n[:, 0:1] * v[:, 0:1], n[:, 1:2], v[:, 1:2]), n[:, 2:3], v[:, 2:3])
    vv = torch.addcmul(torch.addcmul(v[:, 0:1] * v[:, 0:1], v[:, 1:2], v[:, 1:2]), v[:, 2:3], v[:, 2:3])
    t["ll"] = ll = (lights * lights).sum(dim=2, keepdim=True)  # (B, K, 1)
    # h = (l + v)/|l + v|: n·h = (n·l + n·v)/|l + v|, l·h = (l·l + l·v)/|l + v|
    t["hh"] = hh = torch.add(vv + ll, lv, alpha=2.0)
    t["inv"] = inv = hh.clamp_min(EPS_HALF**2).rsqrt()
    t["p"] = p = nl_raw + nv_raw
    t["q"] = q = lv + ll
    t["nh_raw"] = nh_raw = p * inv
    t["lh_raw"] = lh_raw = q * inv
    t["nh"] = nh = nh_raw.clamp(0.0, 1.0)
    lh = lh_raw.clamp(0.0, 1.0)
    t["nl"] = nl = nl_raw.clamp(0.0, 1.0)
    t["nv"] = nv = nv_raw.clamp(0.0, 1.0)
    t["oma"] = oma = 1.0 - a2
    t["sl"] = sl = torch.addcmul(a2, oma, nl * nl).sqrt()  # √(a2 + (1 − a2)(n·l)²) ≥ ALPHA_MIN
    t["lam_v"] = lam_v = torch.addcmul(a2, oma, nv * nv).sqrt()
    t["den_raw"] = den_raw = torch.addcmul(nv * sl, nl, lam_v)
    t["den"] = den = den_raw.clamp_min(EPS_SMITH)
    t["d"] = d = 1.0 - nh * nh * oma  # ≥ a2 > 0 since n·h ≤ 1
    x = 1.0 - lh
    x2 = x * x
    t["x4"] = x4 = x2 * x2
    t["x5"] = x5 = x4 * x
    t["fresnel"] = fresnel = torch.addcmul(f0, 1.0 - f0, x5)
    t["q_dv"] = q_dv = (a2 * (0.5 / math.pi)) / (d * d * den)  # = D · V
    t["spec"] = nl * fresnel * q_dv
    return t


def _light_sums_autograd(n, v, a2, f0, lights, radiance):
    """:class:`_LightSums` with the gradient left to autograd (for torch.compile, which fuses it)."""
    t = _brdf_terms(n, v, a2, f0, lights)
    r = radiance[:, :, :, None]  # (B, K, 3, 1)
    return (r * t["nl"][:, :, None]).sum(dim=1), (r * t["spec"][:, :, None]).sum(dim=1)


class _LightSums(torch.autograd.Function):
    """shading = Σ_k L_k (n·l_k)⁺ and glossy = Σ_k L_k (n·l_k)⁺ f_s(l_k), with an analytic backward.

    Inputs n, v (B, 3, N) unit vectors (N = H·W), a2 = α², f0 (B, 1, N), lights (B, K, 3) unit,
    radiance (B, K, 3). Outputs (B, 3, N) each. The forward keeps its per-light terms for the
    backward (one chunk of texels at a time, see :class:`_Chunked`), which returns gradients for all
    six inputs.
    """

    @staticmethod
    def forward(ctx, n, v, a2, f0, lights, radiance):
        t = _brdf_terms(n, v, a2, f0, lights)
        ctx.keys = list(t)
        ctx.save_for_backward(n, v, a2, f0, lights, radiance, *t.values())
        radiance_t = radiance.transpose(1, 2)
        return torch.bmm(radiance_t, t["nl"]), torch.bmm(radiance_t, t["spec"])

    @staticmethod
    def backward(ctx, g_shading, g_glossy):
        n, v, a2, f0, lights, radiance, *terms = ctx.saved_tensors
        t = dict(zip(ctx.keys, terms))
        nl, spec, nv = t["nl"], t["spec"], t["nv"]
        oma, sl, lam_v = t["oma"], t["sl"], t["lam_v"]
        zero = torch.zeros((), dtype=n.dtype, device=n.device)

        g_radiance = torch.zeros_like(radiance)
        g_nl = torch.zeros_like(nl)
        if g_shading is not None:
            g_nl = torch.bmm(radiance, g_shading)  # dL/d(n·l)⁺_k = Σ_c L_k,c g_c
            g_radiance = g_radiance + torch.bmm(nl, g_shading.transpose(1, 2))
        if g_glossy is not None:
            g_spec = torch.bmm(radiance, g_glossy)
            g_radiance = g_radiance + torch.bmm(spec, g_glossy.transpose(1, 2))
        else:
            g_spec = torch.zeros_like(spec)

        # spec = nl · F · q_dv, q_dv = c a2 / (d² den)
        gs = g_spec * spec
        g_a2 = gs / a2
        g_d = -2.0 * gs / t["d"]
        g_den = torch.where(t["den_raw"] > EPS_SMITH, -gs / t["den"], zero)
        g_fresnel = g_spec * nl * t["q_dv"]
        g_nl = g_nl + g_spec * t["fresnel"] * t["q_dv"]
        # F = f0 + (1 − f0) x⁵, x = 1 − l·h
        g_f0 = (g_fresnel * (1.0 - t["x5"])).sum(dim=1, keepdim=True)
        g_lh = -5.0 * (1.0 - f0) * t["x4"] * g_fresnel
        # d = 1 − (n·h)² (1 − a2)
        nh = t["nh"]
        g_nh = -2.0 * oma * nh * g_d
        g_a2 = g_a2 + g_d * nh * nh
        # den = nv sl + nl λv, sl² = a2 + (1 − a2) nl², λv² = a2 + (1 − a2) nv²
        g_nv = g_den * (sl + nl * oma * nv / lam_v)
        g_nl = g_nl + g_den * (lam_v + nv * oma * nl / sl)
        g_a2 = g_a2 + g_den * (nv * (1.0 - nl * nl) / (2.0 * sl) + nl * (1.0 - nv * nv) / (2.0 * lam_v))
        g_a2 = g_a2.sum(dim=1, keepdim=True)
        # clamps to [0, 1]
        g_nh_raw = torch.where(_clamp_mask(t["nh_raw"]), g_nh, zero)
        g_lh_raw = torch.where(_clamp_mask(t["lh_raw"]), g_lh, zero)
        g_nl_raw = torch.where(_clamp_mask(t["nl_raw"]), g_nl, zero)
        g_nv_raw = torch.where(_clamp_mask(t["nv_raw"]), g_nv.sum(dim=1, keepdim=True), zero)
        # n·h = p · inv, l·h = q · inv, inv = 1/√max(hh, EPS_HALF²), hh = ll + vv + 2 lv
        inv = t["inv"]
        g_p = g_nh_raw * inv
        g_q = g_lh_raw * inv
        g_inv = g_nh_raw * t["p"] + g_lh_raw * t["q"]
        g_hh = torch.where(t["hh"] > EPS_HALF**2, -0.5 * inv * inv * inv * g_inv, zero)
        g_nl_raw = g_nl_raw + g_p
        g_nv_raw = g_nv_raw + g_p.sum(dim=1, keepdim=True)
        g_lv = g_q + 2.0 * g_hh
        g_ll = (g_q + g_hh).sum(dim=2, keepdim=True)  # (B, K, 1)
        g_vv = g_hh.sum(dim=1, keepdim=True)
        # n·l = l · n, l·v = l · v, n·v, v·v, l·l
        lights_t = lights.transpose(1, 2)
        g_n = torch.baddbmm(g_nv_raw * v, lights_t, g_nl_raw)
        g_v = torch.baddbmm(torch.addcmul(g_nv_raw * n, 2.0 * g_vv, v), lights_t, g_lv)
        g_lights = (
            torch.bmm(g_nl_raw, n.transpose(1, 2)) + torch.bmm(g_lv, v.transpose(1, 2)) + 2.0 * g_ll * lights
        )
        return g_n, g_v, g_a2, g_f0, g_lights, g_radiance


def _check_inputs(maps: dict[str, tuple[Tensor, int]], light_dirs, light_radiance, camera_pos) -> tuple[int, int, int, int]:
    tensors = {name: t for name, (t, _) in maps.items()}
    tensors.update(light_dirs=light_dirs, light_radiance=light_radiance, camera_pos=camera_pos)
    ref = maps["albedo"][0]
    for name, t in tensors.items():
        if not isinstance(t, Tensor):
            raise TypeError(f"shade_ggx: {name} must be a torch.Tensor, got {type(t).__name__}")
        if not t.is_floating_point() or t.dtype != ref.dtype or t.device != ref.device:
            raise TypeError(
                f"shade_ggx: {name} must be a floating tensor of albedo's dtype and device "
                f"({ref.dtype}, {ref.device}), got {t.dtype}, {t.device}"
            )
    if ref.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"shade_ggx: float32 or float64 tensors expected (the guards need them), got {ref.dtype}")
    if ref.dim() != 4:
        raise ValueError(f"shade_ggx: albedo must be (B, 3, H, W), got {tuple(ref.shape)}")
    height, width = ref.shape[2:]
    batches = {t.shape[0] for t in tensors.values() if t.dim() > 0}
    batch = max(batches)
    for name, (t, channels) in maps.items():
        if t.dim() != 4 or t.shape[1] != channels or tuple(t.shape[2:]) != (height, width) or t.shape[0] not in (1, batch):
            raise ValueError(
                f"shade_ggx: {name} must be ({batch} or 1, {channels}, {height}, {width}), got {tuple(t.shape)}"
            )
    if light_dirs.dim() != 3 or light_dirs.shape[2] != 3 or light_dirs.shape[0] not in (1, batch):
        raise ValueError(f"shade_ggx: light_dirs must be ({batch} or 1, K, 3), got {tuple(light_dirs.shape)}")
    n_lights = light_dirs.shape[1]
    if tuple(light_radiance.shape[1:]) != (n_lights, 3) or light_radiance.dim() != 3 or light_radiance.shape[0] not in (1, batch):
        raise ValueError(f"shade_ggx: light_radiance must be ({batch} or 1, {n_lights}, 3), got {tuple(light_radiance.shape)}")
    if camera_pos.dim() != 2 or camera_pos.shape[1] != 3 or camera_pos.shape[0] not in (1, batch):
        raise ValueError(f"shade_ggx: camera_pos must be ({batch} or 1, 3), got {tuple(camera_pos.shape)}")
    return batch, n_lights, height, width


def shade_ggx(
    albedo: Tensor,
    normal_ts: Tensor,
    roughness: Tensor,
    specular: Tensor,
    displacement: Tensor,
    position: Tensor,
    geo_normal: Tensor,
    geo_tangent: Tensor,
    mask: Tensor,
    light_dirs: Tensor,
    light_radiance: Tensor,
    camera_pos: Tensor,
    ambient: float | Tensor,
    *,
    s_disp: float | Tensor = 0.01,
) -> ShadingResult:
    """Shade UV-space PBR maps with the GGX microfacet model of the paper's A.1 (module docstring).

    All tensors share one dtype, float32 or float64 (the outputs keep it), and one device; maps are
    channel-first (B, C, H, W); a map, light or camera tensor with batch size 1 is broadcast over
    the batch. Units: ``position``, ``camera_pos`` and ``s_disp · displacement`` in one length unit
    (e.g. mm); directions are dimensionless; radiance in any unit (the outputs are in it).

    Cost: on the CPU the texels are shaded in chunks of :data:`CHUNK_TEXELS` and the backward
    recomputes each chunk, so memory beyond inputs and outputs stays at one chunk's temporaries;
    on a GPU, or under ``torch.compile`` (which fuses the loops; first call compiles for about a
    minute on the CPU), all texels go in one pass. First derivatives only (no double backward).

    Args:
        albedo: (B, 3, H, W) base colour, **linear** RGB (decode sRGB first), usually in [0, 1].
        normal_ts: (B, 3, H, W) decoded tangent-space normal (n_x, n_y, n_z) in [-1, 1] (not the
            0..1 texture encoding); need not be unit length (N_s is normalised).
        roughness: (B, 1, H, W) perceptual roughness; α = roughness² (clamped ≥ ALPHA_MIN).
        specular: (B, 1, H, W) specular level; F0 = 0.08 · specular.
        displacement: (B, 1, H, W) displacement along N_g; ``s_disp · displacement`` is in the
            units of ``position`` (A.1's s_disp = 0.01 belongs to its normalised maps: pass
            ``s_disp=1.0`` for a displacement map in the units of ``position``).
        position: (B, 3, H, W) world-space position of the surface at each texel.
        geo_normal: (B, 3, H, W) world-space geometric normal, any non-zero length.
        geo_tangent: (B, 3, H, W) world-space geometric tangent, any non-zero length.
        mask: (B, 1, H, W) texel mask M (usually 0/1; multiplies ``shaded`` and ``visibility``).
        light_dirs: (B, K, 3) world-space unit vectors from the surface towards each directional
            light (normalised again here).
        light_radiance: (B, K, 3) linear RGB radiance L_k of each light.
        camera_pos: (B, 3) camera centre, world space, units of ``position``.
        ambient: I_amb, a float, a 0-d tensor or a (B,) tensor.
        s_disp: displacement scale (A.1: 0.01), float or 0-d tensor.

    Returns:
        :class:`ShadingResult` ``(shaded, diffuse, glossy, shading, visibility)``: the first four
        (B, 3, H, W) linear RGB, ``visibility`` (B, 1, H, W). ``diffuse``, ``glossy`` and
        ``shading`` are not masked.

    Raises:
        InputError: NaN or ±inf in any input, naming the argument (not checked under
            ``torch.compile``); ValueError: shapes, dtypes or devices that do not match.

    Guards (module docstring): ALPHA_MIN = 2e-3, EPS_NORM = 1e-12, EPS_PARALLEL = 1e-3,
    EPS_HALF = 1e-6, EPS_SMITH = 1e-8. None changes a result where its condition does not hold.
    """
    maps = {
        "albedo": (albedo, 3),
        "normal_ts": (normal_ts, 3),
        "roughness": (roughness, 1),
        "specular": (specular, 1),
        "displacement": (displacement, 1),
        "position": (position, 3),
        "geo_normal": (geo_normal, 3),
        "geo_tangent": (geo_tangent, 3),
        "mask": (mask, 1),
    }
    batch, n_lights, height, width = _check_inputs(maps, light_dirs, light_radiance, camera_pos)
    if not torch.compiler.is_compiling():  # one NaN texel would make every gradient NaN: refuse it
        check_finite({**{name: t for name, (t, _) in maps.items()}, "light_dirs": light_dirs, "light_radiance": light_radiance,
                      "camera_pos": camera_pos, "ambient": ambient, "s_disp": s_disp}, "shade_ggx")
    dtype = albedo.dtype
    if isinstance(ambient, Tensor):
        if ambient.dim() > 1 or (ambient.dim() == 1 and ambient.shape[0] not in (1, batch)):
            raise ValueError(f"shade_ggx: ambient must be a float, 0-d or ({batch},), got {tuple(ambient.shape)}")
        ambient = ambient.to(dtype=dtype, device=albedo.device).reshape(-1, 1, 1, 1)
    else:
        ambient = float(ambient)

    n_texels = height * width
    lights = light_dirs * (light_dirs * light_dirs).sum(dim=2, keepdim=True).clamp_min(EPS_NORM**2).rsqrt()
    args = (
        *(t.reshape(t.shape[0], t.shape[1], n_texels) for t, _ in maps.values()),
        lights.expand(batch, n_lights, 3),
        light_radiance.expand(batch, n_lights, 3),
        camera_pos.expand(batch, 3),
        ambient.reshape(-1, 1, 1) if isinstance(ambient, Tensor) else ambient,
        s_disp,
    )
    if albedo.device.type == "cpu" and not torch.compiler.is_compiling():
        outputs = _Chunked.apply(_shade_texels, CHUNK_TEXELS, len(maps), *args)
    else:  # one pass over all texels (GPU; or torch.compile, which fuses the loops itself)
        outputs = _shade_texels(*args)
    return ShadingResult(*(o.view(batch, o.shape[1], height, width) for o in outputs))


def _shade_texels(
    albedo, normal_ts, roughness, specular, displacement, position, geo_normal, geo_tangent, mask,
    lights, radiance, camera, ambient, s_disp,
):  # fmt: skip
    """shade_ggx on flattened texels: maps (B or 1, C, n), lights/radiance (B, K, 3), camera (B, 3)."""
    batch, n_texels = lights.shape[0], albedo.shape[-1]
    n_g = _normalize(geo_normal.unbind(1))
    n_s, _ = _shading_normal(normal_ts.unbind(1), n_g, _normalize(geo_tangent.unbind(1)))
    # v = normalize(camera_pos − P), P = position + s_disp · displacement · N_g
    offset = s_disp * displacement.squeeze(1)
    v = _normalize(
        tuple(
            torch.addcmul(camera[:, i : i + 1] - p_i, offset, n_i, value=-1.0)
            for i, (p_i, n_i) in enumerate(zip(position.unbind(1), n_g))
        )
    )
    visibility = mask * _dot(n_g, v).clamp(0.0, 1.0).unsqueeze(1)
    alpha = (roughness * roughness).clamp_min(ALPHA_MIN)
    light_sums = _light_sums_autograd if torch.compiler.is_compiling() else _LightSums.apply
    shading, glossy = light_sums(
        torch.stack(n_s, dim=1).expand(batch, 3, n_texels),
        torch.stack(v, dim=1).expand(batch, 3, n_texels),
        (alpha * alpha).expand(batch, 1, n_texels),
        (SPECULAR_F0_SCALE * specular).expand(batch, 1, n_texels),
        lights,
        radiance,
    )
    diffuse = shading * albedo * (1.0 / math.pi)
    shaded = mask * (diffuse + glossy + ambient * albedo)
    return shaded.expand(batch, 3, n_texels), diffuse, glossy, shading, visibility.expand(batch, 1, n_texels)


class _Chunked(torch.autograd.Function):
    """Evaluate ``fn`` over chunks of the last (texel) dimension; the backward recomputes each chunk.

    ``args[:n_maps]`` are (b, C, N) maps sliced per chunk; the remaining ``args`` (tensors or
    plain numbers) are passed whole to every chunk and their gradients summed over chunks. Only the
    inputs are kept for the backward; each chunk's graph exists only while its gradient is taken.
    """

    @staticmethod
    def forward(ctx, fn, chunk, n_maps, *args):
        ctx.fn, ctx.chunk, ctx.n_maps = fn, chunk, n_maps
        ctx.is_tensor = [isinstance(a, Tensor) for a in args]
        ctx.constants = [None if t else a for a, t in zip(args, ctx.is_tensor)]
        ctx.save_for_backward(*(a for a in args if isinstance(a, Tensor)))
        ctx.set_materialize_grads(False)
        maps, shared = args[:n_maps], args[n_maps:]
        n_texels = maps[0].shape[-1]
        outputs = None
        for start in range(0, n_texels, chunk):
            piece = slice(start, start + chunk)
            results = fn(*(m[..., piece] for m in maps), *shared)
            if outputs is None:
                outputs = [r.new_empty(r.shape[:-1] + (n_texels,)) for r in results]
            for out, r in zip(outputs, results):
                out[..., piece] = r
        return tuple(outputs)

    @staticmethod
    def backward(ctx, *grad_outputs):
        saved = iter(ctx.saved_tensors)
        args = [next(saved) if t else c for t, c in zip(ctx.is_tensor, ctx.constants)]
        needs = ctx.needs_input_grad[3:]
        maps, shared = args[: ctx.n_maps], args[ctx.n_maps :]
        grads = [torch.zeros_like(a) if need else None for a, need in zip(args, needs)]
        wanted = [i for i, need in enumerate(needs) if need]
        used = [i for i, g in enumerate(grad_outputs) if g is not None]
        n_texels = maps[0].shape[-1]
        for start in range(0, n_texels if wanted and used else 0, ctx.chunk):
            piece = slice(start, start + ctx.chunk)
            with torch.enable_grad():
                inputs = [m[..., piece].detach().requires_grad_(need) for m, need in zip(maps, needs)]
                inputs += [
                    a.detach().requires_grad_(need) if isinstance(a, Tensor) else a
                    for a, need in zip(shared, needs[ctx.n_maps :])
                ]
                results = ctx.fn(*inputs)
                pairs = [(results[i], grad_outputs[i][..., piece]) for i in used if results[i].requires_grad]
                if not pairs:
                    break
                chunk_grads = torch.autograd.grad(
                    [r for r, _ in pairs], [inputs[i] for i in wanted], [g for _, g in pairs], allow_unused=True
                )
            for i, g in zip(wanted, chunk_grads):
                if g is None:
                    continue
                if i < ctx.n_maps:
                    grads[i][..., piece] = g
                else:
                    grads[i] += g
        return (None, None, None, *grads)
