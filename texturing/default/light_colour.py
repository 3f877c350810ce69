"""The light's colour, taken out of the de-lit texture.

Estimated from the reliably seen skin's mean chroma (the skin locus) and the photo's white
references (sclera, teeth: ``ctx.white_reference``) and divided out of the whole map, luminance
kept (:func:`light_colour`, :mod:`facegeo.texturing.illuminant`); under the directional light
model, the ambient term's colour apart from the directional light's where the shade is the cooler
(a sun and its blue sky): the light's chroma per texel moves with its ambient share of the shading
as the de-lit skin's does along the Planckian locus (:func:`ambient_trend`, :func:`light_colour_map`,
:func:`~facegeo.texturing.illuminant.ambient_chroma_trend`), and the white reference is read as
lit at the eyes' share. A greyscale photo gets a generic skin
chroma (:func:`~facegeo.texturing.illuminant.invent_chroma`), and ``report["notes"]`` says so.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from facegeo.texturing.backend import TextureContext
from facegeo.texturing.illuminant import ambient_chroma_trend, chroma, estimate_illuminant

__all__ = ["AmbientTrend", "ambient_trend", "light_colour", "light_colour_map"]


@dataclass(frozen=True)
class AmbientTrend:
    """How the light's chroma moves with the ambient term's share of the shading (two lights of
    two colours: :func:`ambient_trend`): ``delta`` (2,) float64 the chroma per unit of share (0
    where one colour lights the face), ``mean`` the skin's weighted mean share, ``share`` (S, S)
    float64 each texel's share clipped to the 5–95 % range of the skin's (not extrapolated beyond
    the shares that the fit saw: a neck under the jaw, wholly in shade; None where Δ is 0) and
    ``report`` the trend's figures (:func:`~facegeo.texturing.illuminant.ambient_chroma_trend`)."""

    delta: np.ndarray
    mean: float
    share: np.ndarray | None
    report: dict[str, Any]


def ambient_trend(free: np.ndarray, ambient: np.ndarray, weight: np.ndarray) -> AmbientTrend:
    """The :class:`AmbientTrend` of ``free`` (S, S, 3) linear, the de-lit texture without its
    sheen, against ``ambient`` (S, S), the texels' ambient share of the shading, over the texels
    of ``weight`` (S, S) > 0.5 (the slope does not depend on the mean light: the chroma is centred)."""
    rows = weight > 0.5
    delta, mean, report = ambient_chroma_trend(chroma(free[rows]), ambient[rows], weight[rows])
    share = np.clip(ambient.astype(np.float64), *np.quantile(ambient[rows], [0.05, 0.95])) if delta.any() else None
    return AmbientTrend(delta, mean, share, report)


def light_colour(free: np.ndarray, weight: np.ndarray, ctx: TextureContext,
                 trend: AmbientTrend | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """The light's chroma (2,) and its report (:func:`~facegeo.texturing.illuminant.estimate_illuminant`)
    from the ``weight`` (S, S)-weighted mean of ``free`` (S, S, 3) linear, the de-lit texture
    without its sheen (white before the light's colour is known: the sheen made skin look less
    saturated, which the skin locus took for a cooler light), and the context's white reference.
    With a ``trend`` of two lights, the white reference is taken as lit at the eyes' ambient share
    (the eye region's texels, ``ctx.regions["eyes"]``), not at the skin's mean: a sclera in its
    socket's shade under a sun is lit by the sky, and read as the mean light it made the whole
    face's light look as cool as the sky (``benchmarks/bench_light_colour.py``: the frontal sun +
    sky render's error 0.24 → 0.09); ``report["white_ambient_shift"]`` is the chroma taken off it."""
    mean_skin = (free * weight[..., None]).reshape(-1, 3).sum(0) / weight.sum()
    white = None if ctx.white_reference is None else chroma(np.asarray(ctx.white_reference))
    shift = np.zeros(2)
    if white is not None and trend is not None and trend.delta.any():
        eyes = (ctx.regions["eyes"] > 0.5) & ctx.coverage if "eyes" in ctx.regions else np.zeros(ctx.coverage.shape, bool)
        if eyes.any():
            shift = (float(trend.share[eyes].mean()) - trend.mean) * trend.delta
            white = white - shift
    light, report = estimate_illuminant(chroma(mean_skin), white)
    report["white_ambient_shift"] = shift.tolist()
    return light, report


def light_colour_map(light: np.ndarray, trend: AmbientTrend, report: dict[str, Any]) -> np.ndarray:
    """(S, S, 2) the light's chroma per texel (``light`` itself where the ``trend``'s Δ is 0): the
    mean light's ``light`` (2,) plus (a − ā) · Δ, a the texel's clipped ambient share and ā the
    skin's mean; ``report`` gets the trend's figures."""
    report.update(trend.report)
    if not trend.delta.any():  # one light colour (the sample photos so far): no map
        return light
    return (np.asarray(light, np.float64) + (trend.share - trend.mean)[..., None] * trend.delta).astype(np.float32)
