"""The GGX shader of the paper's appendix A.1 evaluated forward in NumPy, for renders that need
no gradient, and the guard constants it shares with the differentiable
:func:`facegeo.texturing.shading.shade_ggx` (whose module docstring is the spec: formulas, guards).

Why a NumPy twin: the relit preview of ``facegeo reconstruct`` is the command's only use of the
shader, and importing torch for it took about 2 s of a 7 s command on two cores (issue 29).
:func:`ggx_shaded` takes per-point arrays channel-last (deferred shading: one row per pixel),
computes in their dtype, and follows ``shade_ggx`` step for step with the same guards, so the two
agree to rounding (tests/test_shading.py compares them, guards included).
"""

from __future__ import annotations

import math

import numpy as np

from facegeo.asset import SPECULAR_F0_SCALE
from facegeo.errors import check_finite

__all__ = ["ggx_shaded", "environment_brdf", "ALPHA_MIN", "EPS_NORM", "EPS_PARALLEL", "EPS_HALF", "EPS_SMITH"]

#: Lower bound of α = roughness² (roughness ≈ 0.0447); then D ≤ 1/(π ALPHA_MIN²) ≈ 8e4 and
#: (n·l)⁺ V ≤ 0.5/ALPHA_MIN = 250. α, not roughness, is clamped.
ALPHA_MIN = 2e-3
#: normalize(x) = x / max(|x|, EPS_NORM): shorter vectors shrink to 0 instead (units of x).
EPS_NORM = 1e-12
#: sin of the angle between tangent and normal below which the fallback tangent blends in.
EPS_PARALLEL = 1e-3
#: Lower bound of |l + v| before normalising the half vector.
EPS_HALF = 1e-6
#: Lower bound of the Smith denominator (n·v)√(…) + (n·l)√(…).
EPS_SMITH = 1e-8


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return (a * b).sum(axis=-1, keepdims=True)


def _normalize(x: np.ndarray) -> np.ndarray:
    """x / max(|x|, EPS_NORM) along the last axis; where |x|² overflows, x is first divided by
    max_i |x_i| (as shade_ggx)."""
    n2 = _dot(x, x)
    overflow = np.isinf(n2)
    if overflow.any():
        x = x / np.where(overflow, np.abs(x).max(axis=-1, keepdims=True), 1.0)
        n2 = _dot(x, x)
    return x / np.sqrt(np.maximum(n2, EPS_NORM**2))


def _perpendicular(n: np.ndarray) -> np.ndarray:
    """A fixed unit vector ⟂ n (Duff et al. 2017); finite for n = 0 (gives e_x)."""
    nx, ny, nz = n[..., 0], n[..., 1], n[..., 2]
    sign = np.where(nz >= 0, 1.0, -1.0).astype(n.dtype)
    a = -1.0 / (sign + nz)
    return np.stack([1.0 + sign * nx * nx * a, sign * nx * ny * a, -sign * nx], axis=-1)


def ggx_shaded(
    albedo: np.ndarray,
    normal_ts: np.ndarray,
    roughness: np.ndarray,
    specular: np.ndarray,
    position: np.ndarray,
    geo_normal: np.ndarray,
    geo_tangent: np.ndarray,
    light_dirs: np.ndarray,
    light_radiance: np.ndarray,
    camera_pos: np.ndarray,
    ambient: float,
) -> np.ndarray:
    """``shade_ggx(...).shaded`` for points without displacement and with mask 1, in NumPy.

    Every per-point argument is channel-last, ``(..., N, C)``, and they broadcast together (e.g.
    a batch of materials over one geometry); float32 or float64 (the result keeps the dtype of
    the broadcast inputs). Units and meanings as in :func:`facegeo.texturing.shading.shade_ggx`.

    Args:
        albedo: (..., N, 3) linear RGB base colour.
        normal_ts: (..., N, 3) decoded tangent-space normal in [-1, 1], any length.
        roughness: (..., N, 1) perceptual roughness (α = roughness², clamped ≥ ALPHA_MIN).
        specular: (..., N, 1) specular level (F0 = 0.08 · specular).
        position: (..., N, 3) surface points, any length unit (that of ``camera_pos``).
        geo_normal, geo_tangent: (..., N, 3) geometric normal and tangent, any non-zero length.
        light_dirs: (K, 3) directions towards each directional light (normalised here).
        light_radiance: (K, 3) linear RGB radiance of each light.
        camera_pos: (3,) camera centre.
        ambient: I_amb.
    Returns:
        (..., N, 3) linear RGB radiance, ``diffuse + glossy + I_amb · albedo``.
    Raises:
        InputError: NaN or ±inf in an input, naming the argument.
    """
    inputs = {"albedo": albedo, "normal_ts": normal_ts, "roughness": roughness, "specular": specular, "position": position,
              "geo_normal": geo_normal, "geo_tangent": geo_tangent, "light_dirs": light_dirs,
              "light_radiance": light_radiance, "camera_pos": camera_pos, "ambient": ambient}
    check_finite(inputs, "ggx_shaded")
    n_g = _normalize(geo_normal)
    t_g = _normalize(geo_tangent)
    c = np.cross(n_g, t_g)
    sin2 = _dot(c, c)
    degenerate = sin2 < EPS_PARALLEL**2
    if degenerate.any():  # the tangent parallel to the normal: blend towards a fixed ⟂ axis
        w = np.maximum(1.0 - sin2 / EPS_PARALLEL**2, 0.0) ** 2
        t_g = np.where(degenerate, _normalize(t_g + w * _perpendicular(n_g)), t_g)
        c = np.cross(n_g, t_g)
    b_g = _normalize(c)
    n_s = _normalize(normal_ts[..., 0:1] * t_g + normal_ts[..., 1:2] * b_g + normal_ts[..., 2:3] * n_g)
    v = _normalize(camera_pos - position)
    lights = light_dirs / np.sqrt(np.maximum((light_dirs * light_dirs).sum(axis=-1, keepdims=True), EPS_NORM**2))
    alpha = np.maximum(roughness * roughness, ALPHA_MIN)
    a2 = alpha * alpha
    oma = 1.0 - a2
    f0 = SPECULAR_F0_SCALE * specular
    nv_raw = _dot(n_s, v)
    nv = np.clip(nv_raw, 0.0, 1.0)
    lam_v = np.sqrt(a2 + oma * nv * nv)
    vv = _dot(v, v)
    shading = glossy = 0.0
    for light, radiance in zip(lights, light_radiance):
        nl_raw = _dot(n_s, light)
        lv = _dot(v, light)
        ll = float(light @ light)
        inv = 1.0 / np.sqrt(np.maximum(vv + ll + 2.0 * lv, EPS_HALF**2))  # 1/|l + v|
        nh = np.clip((nl_raw + nv_raw) * inv, 0.0, 1.0)
        lh = np.clip((lv + ll) * inv, 0.0, 1.0)
        nl = np.clip(nl_raw, 0.0, 1.0)
        den = np.maximum(nv * np.sqrt(a2 + oma * nl * nl) + nl * lam_v, EPS_SMITH)
        d = 1.0 - nh * nh * oma
        fresnel = f0 + (1.0 - f0) * (1.0 - lh) ** 5
        shading = shading + radiance * nl
        glossy = glossy + radiance * (nl * fresnel * (a2 * (0.5 / math.pi)) / (d * d * den))
    return shading * albedo * (1.0 / math.pi) + glossy + ambient * albedo


def environment_brdf(n_dot_v: np.ndarray, roughness: np.ndarray, f0: np.ndarray) -> np.ndarray:
    """The GGX specular reflectance under a uniform white environment, ∫ f_spec (n·l) dω over the
    hemisphere, as a function of n·v: Karis's analytic fit of the split-sum lookup table ("Physically
    Based Shading on Mobile", 2014), F0 · A + B. The specular radiance of a surface under a
    uniform environment of radiance L is this × L; its diffuse radiance is albedo × L.

    Args:
        n_dot_v: (...) cosine between normal and view direction (clipped to [0, 1]).
        roughness: (...) perceptual roughness. f0: (...) reflectance at normal incidence.
    Returns:
        (...) float array, broadcast of the inputs: for skin (roughness 0.5, F0 0.04) 0.03
        facing the camera, 0.05 at n·v = 0.5, 0.15 at grazing angles (Fresnel).
    """
    nv = np.clip(n_dot_v, 0.0, 1.0)
    r = np.asarray(roughness)
    x = r * -1.0 + 1.0
    y = r * -0.0275 + 0.0425
    z = r * -0.572 + 1.04
    w = r * 0.022 - 0.04
    a004 = np.minimum(x * x, np.exp2(-9.28 * nv)) * x + y
    return f0 * (-1.04 * a004 + z) + (1.04 * a004 + w)
