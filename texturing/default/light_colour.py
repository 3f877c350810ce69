"""The light's colour, taken out of the de-lit texture.

Estimated from the reliably seen skin's mean chroma (the skin locus) and the photo's white
references (sclera, teeth: ``ctx.white_reference``) and divided out of the whole map, luminance
kept (:func:`light_colour`, :mod:`facegeo.texturing.illuminant`); under the directional light
model, the ambient term's colour apart from the directional light's where the shade is the cooler
(a sun and its blue sky): the light's chroma per texel moves with its ambient share of the shading
as the de-lit skin's does along the Planckian locus (:func:`light_colour_map`,
:func:`~facegeo.texturing.illuminant.ambient_chroma_trend`). A greyscale photo gets a generic skin
chroma (:func:`~facegeo.texturing.illuminant.invent_chroma`), and ``report["notes"]`` says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from facegeo.texturing.backend import TextureContext
from facegeo.texturing.illuminant import ambient_chroma_trend, chroma, estimate_illuminant

__all__ = ["light_colour", "light_colour_map"]


def light_colour(free: np.ndarray, weight: np.ndarray, ctx: TextureContext) -> tuple[np.ndarray, dict[str, Any]]:
    """The light's chroma (2,) and its report (:func:`~facegeo.texturing.illuminant.estimate_illuminant`)
    from the ``weight`` (S, S)-weighted mean of ``free`` (S, S, 3) linear, the de-lit texture
    without its sheen (white before the light's colour is known: the sheen made skin look less
    saturated, which the skin locus took for a cooler light), and the context's white reference."""
    mean_skin = (free * weight[..., None]).reshape(-1, 3).sum(0) / weight.sum()
    white = None if ctx.white_reference is None else chroma(np.asarray(ctx.white_reference))
    return estimate_illuminant(chroma(mean_skin), white)


def light_colour_map(light: np.ndarray, free: np.ndarray, ambient: np.ndarray, weight: np.ndarray,
                     report: dict[str, Any]) -> np.ndarray:
    """(S, S, 2) the light's chroma per texel (``light`` itself where Δ is 0): the mean
    light's ``light`` (2,) plus (a − ā) · Δ, ``ambient`` (S, S) the texels' ambient share a of
    the shading (clipped to the 5–95 % range of the fitted texels' shares) and Δ its slope
    (:func:`~facegeo.texturing.illuminant.ambient_chroma_trend`) over the texels of ``weight``
    (S, S) > 0.5, on ``free`` (S, S, 3) linear, the de-lit texture without its sheen;
    ``report`` gets Δ and the share's spread."""
    rows = weight > 0.5
    delta, mean, trend = ambient_chroma_trend(chroma(free[rows]), ambient[rows], weight[rows])
    report.update(trend)
    if not delta.any():  # one light colour (the sample photos so far): no map
        return light
    # not extrapolated beyond the shares that the fit saw (a neck under the jaw, wholly in shade)
    share = np.clip(ambient.astype(np.float64), *np.quantile(ambient[rows], [0.05, 0.95]))
    return (np.asarray(light, np.float64) + (share - mean)[..., None] * delta).astype(np.float32)
