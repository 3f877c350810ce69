"""The skin's specular reflection, taken out of the de-lit texture.

* **An environment's sheen** (:func:`environment_specular`): the GGX reflection of the environment
  (or of the directional model's ambient) with generic skin's roughness and F0, a sheen strongest
  where the skin turns away from the camera, in the photo's units through an assumed mean skin
  albedo (``settings.skin_albedo``), is subtracted from the de-lit texture once the light's colour
  is out (the sheen is white then), at most 1 − ``settings.specular_floor`` of a texel
  (:func:`without_specular`); the light's colour is estimated from the skin without it.
* **The directional light's sheen** (:func:`without_sun_sheen`, under the directional model):
  seen skin near the light's mirror direction (:func:`sun_lobe`: the angle between the normal and
  the half vector of light and view, a Gaussian of σ = ``settings.sun_sheen_lobe_deg``: GGX's lobe
  for skin widened by the fitted mesh's normal error, times the texel's lit share of its shading)
  is taken as the skin's diffuse colour plus white (the dichromatic model, once the light's colour
  is out); the white part, smoothed over ``settings.sheen_smooth_mm``, is subtracted there. Where
  the de-lit colour is as saturated as the skin away from the lobe nothing is taken, so a lobe the
  fitted normals misplace takes out no colour.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from facegeo.asset import SPECULAR_F0_SCALE
from facegeo.colour import channel_min
from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.settings import DEFAULT_SETTINGS, DefaultSettings
from facegeo.texturing.default.texels import subsample
from facegeo.texturing.ggx import environment_brdf
from facegeo.texturing.image_filters import masked_blur

__all__ = ["environment_specular", "sun_lobe", "without_specular", "without_sun_sheen"]


def environment_specular(delit_lum: np.ndarray, reference: np.ndarray, seen: np.ndarray, ctx: TextureContext,
                         ambient_share: np.ndarray | None, constants: Mapping[str, float], settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32: the skin's specular reflection of an environment light in the units of
    the de-lit luminance ``delit_lum`` (S, S), on the ``seen`` (S, S) bool texels (0 elsewhere).

    Per texel, photo = (albedo + q) · D: D is the diffuse radiance of a unit albedo, q the
    ratio of the specular radiance to it. For skin (GGX with generic skin's roughness and
    specular level, ``constants``: the backend's, :data:`~facegeo.texturing.backend.SKIN_CONSTANTS`)
    under an even environment, q = E(n·v), the environment BRDF (:func:`facegeo.texturing.ggx.environment_brdf`:
    ~0.03 facing the camera, ~0.15 at grazing angles); under the directional model only its
    ambient part, q = E(n·v) · ``ambient_share`` (S, S) (ambient / shading). The directional
    light's own lobe is not modelled here: placed by the fitted mesh's normals it took colour
    from the wrong skin (Lee Perry-Smith's hard-light views up to 0.4 CIEDE2000 worse); its
    sheen is told by its colour instead (:func:`without_sun_sheen`). D in de-lit units: the
    ``reference`` (S, S) bool texels' mean de-lit luminance is D · (``settings.skin_albedo`` +
    their mean q; None: nothing removed). Subtracting D · q takes out
    the sheen that a white environment leaves on skin turned away from the camera, which made
    skin look greyer and bluer than it is (stubble most)."""
    cover = ctx.coverage
    out = np.zeros(cover.shape, np.float32)
    rows = np.flatnonzero((seen & cover).ravel())
    reference = reference & seen & cover
    if len(rows) == 0 or not reference.any() or settings.skin_albedo is None:
        return out
    n = ctx.normal_camera.reshape(-1, 3)[rows]
    if ctx.position_camera is not None:
        position = ctx.position_camera.reshape(-1, 3)[rows]
        n_dot_v = -(n * position).sum(axis=1) / np.maximum(np.linalg.norm(position, axis=1), 1e-6)
    else:  # no posed mesh: an orthographic view
        n_dot_v = n[:, 2]
    q = environment_brdf(n_dot_v, constants["roughness"], SPECULAR_F0_SCALE * constants["specular"])
    if ambient_share is not None:
        q = q * ambient_share.reshape(-1)[rows]
    out.reshape(-1)[rows] = q
    unit = float(delit_lum[reference].mean()) / (settings.skin_albedo + float(out[reference].mean()))
    return (unit * out).astype(np.float32)


def without_specular(delit: np.ndarray, specular: np.ndarray, settings: DefaultSettings) -> np.ndarray:
    """``delit`` (S, S[, 3]) less ``specular`` (broadcasting; white), keeping at least
    ``settings.specular_floor`` of each value."""
    return np.maximum(delit - specular, settings.specular_floor * delit).astype(np.float32)


def sun_lobe(light: np.ndarray, lit: np.ndarray, ctx: TextureContext, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 in [0, 1]: where the directional light's sheen may be, for a unit
    camera-space ``light`` direction (3,): a Gaussian of σ = ``settings.sun_sheen_lobe_deg`` over
    the angle between the texel's normal and the half vector of light and view, times ``lit``
    (S, S) (the de-lighting strength × the light's share of the texel's shading: no sheen in
    a shadow), on covered texels facing the camera."""
    rows = np.flatnonzero((ctx.coverage & (lit > 0)).ravel())
    n = ctx.normal_camera.reshape(-1, 3)[rows]
    position = ctx.position_camera.reshape(-1, 3)[rows]
    view = -position / np.maximum(np.linalg.norm(position, axis=-1, keepdims=True), 1e-6)
    half = light.astype(np.float32) + view
    half /= np.maximum(np.linalg.norm(half, axis=-1, keepdims=True), 1e-6)
    angle = np.arccos(np.clip((n * half).sum(axis=-1), -1.0, 1.0))
    lobe = np.zeros(lit.size, np.float32)
    lobe[rows] = np.where((n * view).sum(axis=-1) > 0, np.exp(-0.5 * (angle / np.radians(settings.sun_sheen_lobe_deg)) ** 2), 0.0)
    return (lobe.reshape(lit.shape) * lit).astype(np.float32)


def without_sun_sheen(delit: np.ndarray, lobe: np.ndarray, seen: np.ndarray, reference: np.ndarray, smooth: float, *,
                      settings: DefaultSettings = DEFAULT_SETTINGS) -> np.ndarray:
    """(S, S, 3) de-lit, white-balanced linear RGB ``delit`` with a directional light's sheen
    taken out of the ``seen`` (S, S) bool texels, in proportion to ``lobe`` (S, S) in [0, 1]
    (how much of the light's mirror reflection a texel may show).

    The dichromatic model: a texel is k · c + w · (1, 1, 1), c the skin's diffuse colour (the
    median of the ``reference`` (S, S) bool texels outside the lobe, lobe < 0.5, or of all of
    them when fewer than ``settings.sheen_reference_texels`` are outside), w ≥ 0 the white of the
    sheen (least squares per texel; a texel more saturated than c has none). w is smoothed over
    ``smooth`` texels (masked Gaussian σ) and kept under 0.9 of the texel's smallest channel
    (what remains is never negative and keeps some of its own colour); lobe · w is subtracted.
    Returns ``delit`` itself when there are too few reference texels, or when their colour is
    grey (within 1 % of white's direction: no chroma to tell the sheen by)."""
    rows = reference & (lobe < 0.5)
    if rows.sum() < settings.sheen_reference_texels:
        rows = reference
    if rows.sum() < settings.sheen_reference_texels:
        return delit
    diffuse = np.median(delit.reshape(-1, 3)[subsample(np.flatnonzero(rows.ravel()))], axis=0).astype(np.float64)
    if diffuse.sum() / max(np.sqrt(3.0) * float(np.linalg.norm(diffuse)), 1e-12) > 0.9999:  # cos(diffuse, white)
        return delit
    basis = np.stack([diffuse, np.ones(3)], axis=1)  # (3, 2): the diffuse colour and white
    white_of = (basis @ np.linalg.inv(basis.T @ basis))[:, 1].astype(np.float32)  # least squares: the white coefficient
    white = np.maximum(delit @ white_of, 0.0)
    white = np.minimum(masked_blur(white, seen, smooth), 0.9 * channel_min(delit))
    return np.where(seen[..., None], delit - (lobe * white)[..., None], delit).astype(np.float32)
