"""The light's colour in a photo of a face, and its removal from the albedo.

Chroma is the pair ``c = (log R/G, log B/G)`` of linear RGB. A light of chroma ``L`` multiplies
every surface's RGB by ``exp(L)`` channel-wise (von Kries), so it adds ``L`` to every chroma.
Three pieces of evidence, each a Gaussian, are combined by least squares
(:func:`estimate_illuminant`):

* **the skin**: the seen skin's mean chroma is ``SKIN_CHROMA + t·SKIN_LOCUS + L``: skin of any
  tone lies near one line (the skin locus: more melanin is redder and less blue), ``t`` its
  position along it (prior σ :data:`SKIN_TONE_SIGMA`), σ :data:`SKIN_SIGMA` across it;
* **the white references** (the sclera, teeth: :func:`facegeo.skin_mask.white_reference`), when
  there are any: their chroma is ``SCLERA_CHROMA + L`` (σ :data:`WHITE_SIGMA`); a reference that
  disagrees with the skin by more than :data:`WHITE_GATE` (reddish lids picked for a small eye)
  is not used. Lid skin mixed in only makes a reference warmer, more skin-like, than the skin
  predicts: the part of the miss that makes it cooler along the Planckian locus counts
  :data:`WHITE_COOL_SHARE` of its length (a skin whose colour lies off the locus, yellower than
  the locus's skin, is otherwise taken for skin under a warm light and its neutral sclera for
  lid skin). Nor is a reference used whose tint (its chroma's green–magenta part, across the
  Planckian locus through a white) is both beyond :data:`WHITE_TINT_GATE`, more than a real
  light has, and less than :data:`WHITE_SKIN_TINT_GAP` below the skin's own (or above it): that is skin, a shut eye's
  lid (two lights of two colours move a lid in shade along the locus, away from the lit skin,
  where the miss takes it for a sclera; neither moves it across);
* **the light itself**: real lights lie near the Planckian locus (warm–cool, the direction
  :data:`PLANCKIAN`, σ :data:`LIGHT_SIGMA`), with little green–magenta (σ :data:`TINT_SIGMA`).

Warm light and darker skin both raise R/G; the locus's and the Planckian direction differ
(darker skin barely lowers B/G, a warm light does strongly), and the sclera tells them apart
where it is seen. The numbers are linear sRGB of skin under a neutral (D65) light: the
ColorChecker's light and dark skin patches lie at (0.57, −0.31) and (0.71, −0.38); the
constants put the locus's centre between lighter skin and them.

**Two lights of two colours.** Where the texture backend fits a directional light and an ambient
term (a sun and its blue sky), the skin in the directional light's shadow is lit by another
colour than the lit skin: the light's chroma at a texel is then ``L + (a − ā)·Δ``, ``a`` the
texel's ambient share of its shading, ``ā`` its mean over the skin that ``L`` was estimated from
(:func:`ambient_chroma_trend`: ``Δ`` is the slope of the de-lit skin's chroma against ``a`` along
the Planckian direction, where the shade is the cooler: skin's own colour is redder in shade).

:func:`remove_cast` divides the cast out and keeps each texel's luminance. A greyscale photo
carries no chroma at all: :func:`invent_chroma` gives the albedo a generic skin chroma (lips a
redder one) and the pipeline notes it.
"""

from __future__ import annotations

import numpy as np

from facegeo.colour import luminance

__all__ = ["estimate_illuminant", "remove_cast", "invent_chroma", "chroma", "SKIN_CHROMA", "SKIN_LOCUS",
           "PLANCKIAN", "SCLERA_CHROMA", "LIPS_CHROMA", "SKIN_SIGMA", "SKIN_TONE_SIGMA", "WHITE_SIGMA", "WHITE_GATE", "WHITE_COOL_SHARE",
           "WHITE_TINT_GATE", "WHITE_SKIN_TINT_GAP",
           "LIGHT_SIGMA", "TINT_SIGMA", "NEUTRAL_TOLERANCE", "FIRM_FACTOR", "firm_shrinkage", "ambient_chroma_trend",
           "AMBIENT_SHARE_SPREAD", "AMBIENT_CHROMA_TOLERANCE", "cast_gains"]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


#: Chroma (log R/G, log B/G) of the middle of the skin locus under a neutral light.
SKIN_CHROMA = np.array([0.50, -0.32])
#: Direction of the skin locus (towards darker, redder skin).
SKIN_LOCUS = _unit([0.9, -0.43])
#: Direction of warmer light along the Planckian locus (6500 K → 3200 K in linear sRGB).
PLANCKIAN = _unit([0.39, -0.53])
#: Chroma of the sclera and teeth under a neutral light (slightly warm whites).
SCLERA_CHROMA = np.array([0.08, -0.10])
#: Chroma given to the lips of a greyscale photo (redder than the skin).
LIPS_CHROMA = np.array([0.78, -0.28])
#: σ of the seen skin's mean chroma across the locus.
SKIN_SIGMA = 0.12
#: σ of the skin's position along the locus (lightest to darkest skin spans about ±2σ).
SKIN_TONE_SIGMA = 0.15
#: σ of a white reference's chroma.
WHITE_SIGMA = 0.05
#: A white reference further than this from what the skin alone predicts is not used.
WHITE_GATE = 0.45
#: The share of a white reference's miss that counts where it is cooler than the skin predicts
#: (along the Planckian locus): bench_albedo_scans' James scan, whose colour map is yellower
#: than the skin locus, had neutral scleras at misses of 0.46-0.50 under the ring and sun + sky
#: lights, rejected, and its albedo made bluish (82-86 % of the skin off the scan's colours).
WHITE_COOL_SHARE = 0.4
#: The tint (chroma less :data:`SCLERA_CHROMA`, across the Planckian locus: green–magenta) beyond
#: which a white reference is not lit by a real light alone (lights lie within a few
#: :data:`TINT_SIGMA` of the locus). The scans' scleras lie within 0.08 of it under every light of
#: bench_albedo_scans; the sample photos' whites at up to 0.31 (lid skin mixed into small scleras).
WHITE_TINT_GATE = 0.2
#: A white reference tinted beyond :data:`WHITE_TINT_GATE` whose tint is less than this below the
#: skin's own (or above it) is skin (a lid), not used. The sample photos' skins are 0.13-0.25 more magenta than their
#: whites where those are tinted near or beyond the gate (Biden, Obama at the lectern, a Breaking
#: Bad still); Lee Perry-Smith's shut lid in a sky's shade 0.02 (it had passed the miss gate and
#: cast magenta over his albedo: bench_albedo_scans' sun + sky −40°).
WHITE_SKIN_TINT_GAP = 0.1
#: σ of the light's chroma along the Planckian locus (from the prior of a neutral light).
LIGHT_SIGMA = 0.35
#: σ of the light's chroma across it (green–magenta tints are rare).
TINT_SIGMA = 0.06
#: A light estimated within this of neutral is not corrected (a sclera's chroma alone varies
#: about as much: the estimate under a white light came out 0.10 off on the benchmark's scan,
#: 0.20 under a hard side light whose sclera lies in shadow; a pink skin with no sclera in view,
#: 0.10). Firm threshold on the estimate's length: 0 up to the tolerance, the estimate itself
#: from :data:`FIRM_FACTOR` × the tolerance, linear between. A soft threshold (the estimate
#: shortened by the tolerance) left a third to a half of a 3200 K light's cast in the albedo
#: (bench_albedo_scans, warm views: Lee Perry-Smith's chroma error 10.1 → 5.3).
NEUTRAL_TOLERANCE = 0.12
#: Where the firm threshold stops shrinking, in units of :data:`NEUTRAL_TOLERANCE`.
FIRM_FACTOR = 2.0
#: The ambient share's weighted σ over the skin below which its light's colour is not told apart
#: (one light does nearly all the lighting: the scans' turned views under the sun + sky light,
#: 0.01–0.04).
AMBIENT_SHARE_SPREAD = 0.05
#: The chroma spread (the slope × the share's σ) that skin's own colour shows with its shading,
#: not taken for the lights' colours: the scans' colour maps under one white light (the even and
#: hard side views of bench_albedo_scans) show at most 0.032 (0.027 along the Planckian
#: direction); their sun + sky views 0.15–0.19.
AMBIENT_CHROMA_TOLERANCE = 0.03


def chroma(linear: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB -> (..., 2) float64 (log R/G, log B/G), values floored at 1e-4."""
    x = np.maximum(np.asarray(linear, np.float64), 1e-4)
    return np.stack([np.log(x[..., 0] / x[..., 1]), np.log(x[..., 2] / x[..., 1])], axis=-1)


def estimate_illuminant(skin: np.ndarray, white: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """The light's chroma ``L`` (2,) float64 from the seen skin's mean chroma ``skin`` (2,) and
    optionally a white reference's ``white`` (2,) (module docstring). Returns ``(L, report)``;
    the report says whether the white reference was used and the skin's place on the locus."""
    skin = np.asarray(skin, np.float64)
    normal = np.array([-PLANCKIAN[1], PLANCKIAN[0]])
    # unknowns x = (L_1, L_2, t); rows are whitened equations a·x = b
    rows = [np.r_[np.eye(2)[i], SKIN_LOCUS[i]] / SKIN_SIGMA for i in range(2)]
    rhs = [(skin - SKIN_CHROMA)[i] / SKIN_SIGMA for i in range(2)]
    rows += [np.r_[0.0, 0.0, 1.0] / SKIN_TONE_SIGMA, np.r_[PLANCKIAN, 0.0] / LIGHT_SIGMA, np.r_[normal, 0.0] / TINT_SIGMA]
    rhs += [0.0, 0.0, 0.0]
    x, *_ = np.linalg.lstsq(np.asarray(rows), np.asarray(rhs), rcond=None)
    report = {"skin_chroma": skin.tolist(), "white_chroma": None, "white_used": False}
    if white is not None and np.all(np.isfinite(white)):
        white = np.asarray(white, np.float64)
        report["white_chroma"] = white.tolist()
        white_light = white - SCLERA_CHROMA  # the light that the white alone says
        offset = white_light - x[:2]
        along = float(offset @ PLANCKIAN)
        miss = float(np.hypot(along if along > 0 else WHITE_COOL_SHARE * along, float(offset @ normal)))
        tint = float(white_light @ normal)
        skin_tint = float((skin - SCLERA_CHROMA) @ normal)
        report["white_miss"] = miss
        report["white_tint"] = tint
        lid = abs(tint) > WHITE_TINT_GATE and tint > skin_tint - WHITE_SKIN_TINT_GAP
        if miss <= WHITE_GATE and not lid:
            rows += [np.r_[np.eye(2)[i], 0.0] / WHITE_SIGMA for i in range(2)]
            rhs += [white_light[i] / WHITE_SIGMA for i in range(2)]
            x, *_ = np.linalg.lstsq(np.asarray(rows), np.asarray(rhs), rcond=None)
            report["white_used"] = True
    norm = float(np.linalg.norm(x[:2]))
    x[:2] *= firm_shrinkage(norm)
    report["light_chroma"] = x[:2].tolist()
    report["skin_tone"] = float(x[2])
    return x[:2], report


def firm_shrinkage(length: float, tolerance: float = NEUTRAL_TOLERANCE) -> float:
    """The factor (in [0, 1]) that an estimate of this chroma ``length`` is scaled by: 0 within
    ``tolerance`` (default :data:`NEUTRAL_TOLERANCE`, the light's), 1 beyond :data:`FIRM_FACTOR`
    × that, continuous between."""
    lo, hi = tolerance, FIRM_FACTOR * tolerance
    if length <= lo:
        return 0.0
    if length >= hi:
        return 1.0
    return (length - lo) * hi / ((hi - lo) * length)


def ambient_chroma_trend(skin_chroma: np.ndarray, ambient_share: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, float, dict]:
    """How the light's chroma changes with the ambient term's share of the shading: the skin
    texels' chroma ``skin_chroma`` (N, 2) (already without the mean light's), their ambient share
    ``ambient_share`` (N,) in [0, 1] and weight ``weight`` (N,) -> (``Δ`` (2,) float64, the
    weighted mean share ``ā``, report). ``Δ`` is the weighted least-squares slope of the chroma
    against the share along the Planckian direction (lights lie near its locus), where it makes
    the more ambient-lit skin cooler (a sky, a window's daylight): skin's own colour goes the
    other way in shade (light scattered under the skin comes out redder, and the lit side keeps
    some sheen), so a warmer shade is not told from it and is left as it is. Firmly shrunk
    (:func:`firm_shrinkage`) by the chroma spread that skin's own colour shows with its shading:
    the slope × the share's σ against :data:`AMBIENT_CHROMA_TOLERANCE`. 0 where the share's
    weighted σ is below :data:`AMBIENT_SHARE_SPREAD` (one light does nearly all the lighting)."""
    c = np.asarray(skin_chroma, np.float64)
    a = np.asarray(ambient_share, np.float64)
    w = np.asarray(weight, np.float64)
    if len(a) < 2 or w.sum() <= 0:
        return np.zeros(2), 0.0, {"ambient_share_spread": 0.0, "ambient_chroma": [0.0, 0.0]}
    mean = float(np.average(a, weights=w))
    spread = float(np.sqrt(np.average((a - mean) ** 2, weights=w)))
    report = {"ambient_share_spread": spread, "ambient_chroma": [0.0, 0.0]}
    if spread < AMBIENT_SHARE_SPREAD:
        return np.zeros(2), mean, report
    centred = c - np.average(c, axis=0, weights=w)
    slope = (w[:, None] * (a - mean)[:, None] * centred).sum(axis=0) / (w * (a - mean) ** 2).sum()
    along = float(slope @ PLANCKIAN)  # > 0: warmer with more ambient light
    report["ambient_chroma_slope"] = slope.tolist()
    if along >= 0.0:
        return np.zeros(2), mean, report
    delta = firm_shrinkage(-along * spread, AMBIENT_CHROMA_TOLERANCE) * along * PLANCKIAN
    report["ambient_chroma"] = delta.tolist()
    return delta, mean, report


def cast_gains(light: np.ndarray) -> np.ndarray:
    """The channel gains (..., 3) float32 ``exp(L_1), 1, exp(L_2)`` by which a light of chroma
    ``light`` ((2,), or (..., 2) per texel) multiplies linear RGB (green kept)."""
    light = np.asarray(light, np.float64)
    return np.exp(np.stack([light[..., 0], np.zeros_like(light[..., 0]), light[..., 1]], axis=-1)).astype(np.float32)


def remove_cast(linear: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(..., 3) linear RGB with the light's chroma ``light`` ((2,), or (..., 2) per texel) divided
    out channel-wise, each colour's luminance kept. float32."""
    out = np.asarray(linear, np.float32) / cast_gains(light)
    return out * (luminance(linear) / np.maximum(luminance(out), 1e-8))[..., None]


def invent_chroma(lum: np.ndarray, lips: np.ndarray | None = None) -> np.ndarray:
    """(..., 3) linear RGB of luminance ``lum`` (...) with a generic skin chroma
    (:data:`SKIN_CHROMA`), blended towards :data:`LIPS_CHROMA` by the soft mask ``lips`` (...) in
    [0, 1]: the albedo of a greyscale photo."""
    c = np.broadcast_to(SKIN_CHROMA, (*np.shape(lum), 2))
    if lips is not None:
        c = c + np.clip(lips, 0.0, 1.0)[..., None] * (LIPS_CHROMA - SKIN_CHROMA)
    rgb = np.stack([np.exp(c[..., 0]), np.ones(c.shape[:-1]), np.exp(c[..., 1])], axis=-1)
    return (rgb * (np.asarray(lum) / luminance(rgb))[..., None]).astype(np.float32)
