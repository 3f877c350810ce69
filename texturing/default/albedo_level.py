"""The albedo's level: what the photo's exposure does not decide.

A photo's pixels are albedo × irradiance × exposure; the de-lighting divides out the shading's
variation over the face (normalised to 1 on the median seen skin), so the de-lit albedo still
carries the exposure and the light's intensity: a photo one stop darker gave an albedo half as
bright (bench_albedo_scans' exposure series). Its level is set instead, by one factor ``k``, from
evidence that does not scale with the exposure, each a Gaussian on ``log k`` combined by their
precisions (:func:`albedo_level`):

* **the skin-reflectance prior**: skin's luminance falls as melanin makes it redder and less
  blue, along the skin locus of :mod:`facegeo.texturing.illuminant`; the skin's place ``t`` on the
  locus as the light's colour estimate found it (its posterior mean: chroma is a ratio of
  channels, the same at any exposure) gives its log-luminance, linear in ``t`` through the middle
  of the ColorChecker's *light skin* and *dark skin* patches (:data:`SKIN_PATCHES`), the slope
  between them shrunk by ``settings.level_tone_share`` (a warm light still reads partly as darker
  skin where no sclera tells them apart) and flat beyond them, bounded to
  ``settings.level_skin_range``, σ ``settings.level_skin_sigma`` in log;
* **the white references** (the sclera, teeth: :func:`facegeo.skin_mask.white_reference`), where the
  light's colour estimate used them: their luminance in the photo over the shading of the skin
  around the eyes is their albedo in the de-lit texture's units; what photos show of them
  (``settings.level_white_reflectance``, σ ``settings.level_white_sigma``) gives ``k``; one that
  the skin prior contradicts by more than ``settings.level_gate`` σ is not used.

The seen skin's mean luminance (weighted by how far each texel is trusted; the weighted mean moved
less with the exposure than the median on bench_albedo_scans' series) stays within
``settings.level_skin_range`` after the factor.

A greyscale photo has no chroma: its prior is the patches' middle (linear luminance 0.19). The
report (the backend's ``report["albedo_level"]``, written in ``fit.json``'s ``texture_report``)
gives each cue's ``k`` and σ, the factor used and the skin's mean luminance before and after.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from facegeo.colour import luminance, srgb_to_linear
from facegeo.texturing.illuminant import SKIN_CHROMA, SKIN_LOCUS, chroma
from facegeo.texturing.default.settings import DefaultSettings

__all__ = ["albedo_level", "skin_prior_luminance", "SKIN_PATCHES"]

#: The ColorChecker's *light skin* and *dark skin* patches, sRGB 8-bit (its published D65 values):
#: linear luminance 0.35 and 0.10, chroma (0.57, −0.31) and (0.71, −0.38) on the skin locus.
SKIN_PATCHES = ((194, 150, 130), (115, 82, 68))


def _locus_place(linear_rgb: np.ndarray) -> float:
    """The place ``t`` on the skin locus (:data:`~facegeo.texturing.illuminant.SKIN_LOCUS`, from
    :data:`~facegeo.texturing.illuminant.SKIN_CHROMA`) of a linear RGB colour (3,) under a neutral light."""
    return float((chroma(np.asarray(linear_rgb, np.float64)) - SKIN_CHROMA) @ SKIN_LOCUS)


def skin_prior_luminance(t: float | None, settings: DefaultSettings) -> float:
    """Skin's linear albedo luminance at place ``t`` on the skin locus (None: unknown, a greyscale
    photo): log-linear in ``t`` through the middle of the :data:`SKIN_PATCHES` (their mean place
    and geometric-mean luminance, 0.19), with the slope between them times
    ``settings.level_tone_share``, and flat beyond the patches' places (``t`` clipped to their
    span: redder than dark skin is not darker skin but a ruddy face or a warm light that the
    light's colour estimate left in, and the darkest skin is less saturated, not more); bounded
    to ``settings.level_skin_range``; the middle where ``t`` is None."""
    patches = [srgb_to_linear(np.asarray(p, np.float32) / 255.0) for p in SKIN_PATCHES]
    (t_light, t_dark), (y_light, y_dark) = [_locus_place(p) for p in patches], [float(luminance(p)) for p in patches]
    log_mid = 0.5 * (np.log(y_light) + np.log(y_dark))
    if t is None:
        return float(np.exp(log_mid))
    slope = settings.level_tone_share * np.log(y_dark / y_light) / (t_dark - t_light)
    lo, hi = settings.level_skin_range
    t = float(np.clip(t, t_light, t_dark))
    return float(np.clip(np.exp(log_mid + slope * (t - 0.5 * (t_light + t_dark))), lo, hi))


def albedo_level(albedo: np.ndarray, skin_weight: np.ndarray, shading: np.ndarray, eyes: np.ndarray | None,
                 white: np.ndarray | None, skin_tone: float | None, settings: DefaultSettings) -> tuple[float, dict[str, Any]]:
    """The factor ``k`` (float > 0) that sets the de-lit albedo's level (module docstring), and its report.

    Args:
        albedo: (S, S, 3) float32 linear RGB, de-lit, the light's colour and the sheen taken out.
        skin_weight: (S, S) float32 in [0, 1], how far each texel is trusted as seen skin; the
            texels > 0.5, weighted by it, are the skin that the prior is judged on.
        shading: (S, S) float32, the shading the albedo was divided by (1 on the median seen skin).
        eyes: (S, S) float32 soft mask of the lids and canthi (the context's ``eyes`` region), or
            None: where the shading of the white references is read.
        white: (3,) linear RGB mean of the photo's white references, or None (not seen, or not
            used by the light's colour estimate).
        skin_tone: the skin's place on the locus (the light's colour estimate's ``skin_tone``), or
            None (a greyscale photo).
        settings: ``level_*`` knobs.
    """
    skin = skin_weight > 0.5
    if skin.sum() < 10:
        return 1.0, {"k": 1.0, "cues": {}, "note": "too little seen skin: the photo's exposure kept"}
    y_seen = float((luminance(albedo) * skin_weight)[skin].sum() / skin_weight[skin].sum())
    y_prior = skin_prior_luminance(skin_tone, settings)
    cues = {"skin_prior": {"k": y_prior / max(y_seen, 1e-6), "sigma": settings.level_skin_sigma,
                           "skin_tone": skin_tone, "skin_luminance": y_prior}}
    if white is not None:
        around = skin & (eyes > 0.5) if eyes is not None else skin
        s_eye = float(np.median(shading[around])) if around.sum() >= 10 else float(np.median(shading[skin]))
        y_white = float(luminance(np.asarray(white, np.float32))) / max(s_eye, 1e-6)
        if y_white > 1e-4:
            cue = {"k": settings.level_white_reflectance / y_white, "sigma": settings.level_white_sigma, "eye_shading": s_eye}
            # a "white" that the skin prior contradicts beyond level_gate σ is not one (a scan's grey
            # eyes, lid skin in shade): what it would make of the skin is no skin's albedo
            prior = cues["skin_prior"]
            cue["miss_sigma"] = abs(float(np.log(cue["k"] / prior["k"]))) / float(np.hypot(cue["sigma"], prior["sigma"]))
            cues["white_reference"] = cue
    used = [name for name, cue in cues.items() if cue.get("miss_sigma", 0.0) <= settings.level_gate]
    precision = {name: cues[name]["sigma"] ** -2 for name in used}
    log_k = sum(precision[name] * np.log(cues[name]["k"]) for name in used) / sum(precision.values())
    lo, hi = settings.level_skin_range  # and skin stays skin
    k = float(np.clip(np.exp(log_k), lo / max(y_seen, 1e-6), hi / max(y_seen, 1e-6)))
    report = {"k": k, "cues": cues, "used": used, "skin_luminance_before": y_seen, "skin_luminance": y_seen * k}
    return k, report
