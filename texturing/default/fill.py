"""The fill: what the photo does not show (and its highlights), in log RGB, on the de-lit,
white-balanced texture, as a **gradient-domain blend** (:func:`fill`).

Every seen texel has a reliability r (:func:`~facegeo.texturing.default.reliability.reliability`
× the shading's confidence). The fill's fine detail D (finer than ~S/128 texels, ~2.5 mm at 1K;
:func:`fill_detail`) is the seen texel's own detail away from the seen region's edge, else the
mirror texel's where that was reliably seen (not its moles and specks: ``settings.speck_sigmas``),
else the finest detail (~1 mm at 1K: pores, stubble) of the reliably seen skin quilted in blocks
(:func:`~facegeo.texturing.default.quilting.quilted_detail`: this face's own texture at its own
contrast, each block from the seen skin near the block's nearest seen place) plus, away from the
seen skin, the octaves up to S/32 texels (~12 mm at 1K) as colour noise with the seen skin's own
covariance per octave (:func:`~facegeo.texturing.default.noise.band_noise`: its mottling; 3-D
value noise of the model-space position only where no whole block of skin was seen).

The low frequencies B solve a screened Poisson problem on the mesh's vertices
(:func:`fill_base`), min Σ r (B − (log seen − D))² + λ Σ_edges |∇B|² (+ a weak pull to the seen
skin's mean far from anything seen), so the filled skin takes its tone from the reliable seen skin
next to it and B + D has the seen skin's values wherever r is high (under the directional light
model the data weight is r / (1 + (a · ``settings.ambient_log_error`` /
``settings.fill_tone_tolerance``)²), a the texel's ambient share of its shading times the
de-lighting strength: skin lit by the ambient term alone carries that term's error whole, and the
fill would take its tone from it). The result's tone is r · (log seen − D_own) + (1 − r) · (B +
M), M the seen texel's own band from D's scale to ``settings.own_mid_band_coarsest`` × S (its
mottling, :func:`own_mottling`) less B's, where its colour is trusted (kept weight × shading
confidence) away from the seen edge, and the texel's own chroma by its reliability without the
shading's confidence (:func:`own_chroma`: a scalar shading puts only the luminance in doubt), and
over the lips the chroma they did not take from the photo their own seen texels' (:func:`region_chroma`:
the base is the skin's around them); its
detail the texel's own D_own and the fill's other detail
D_fill mixed with weights a = r + (1 − r) · (the own detail's share of D) and 1 − a, divided by
√(a² + (1 − a)²) (:func:`mix_keeping_contrast`: two independent layers mixed linearly lose up to
half their variance, a band of smoother skin along the seen edge): no edge where the seen skin
ends, continuous across UV seams and the mirror line because B lives on the vertices.

The mirror's low frequencies are data for B too (:func:`with_mirror_tone`: weight (1 − r) × the
mirror's reliability × a trust from the seen skin's own symmetry, ``settings.mirror_asymmetry``):
where both sides are seen and agree (a stubbled jaw, a red cheek on both sides), the hidden side
takes the mirror's tone; where they differ (one side still lit or shadowed after de-lighting, a
scanner's light baked in), only fine detail crosses the mirror. Without
:class:`~facegeo.texturing.backend.SurfaceOperators` B is a UV-space push-pull (masked blurs at
growing scales, :func:`~facegeo.texturing.image_filters.push_pull`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from facegeo.colour import channel_sum, luminance
from facegeo.concurrency import run_concurrently, usable_threads
from facegeo.texturing.backend import TextureContext
from facegeo.texturing.default.noise import NoiseLayers, coloured_noise, noise_layers, value_noise
from facegeo.texturing.default.quilting import quilted_detail
from facegeo.texturing.default.settings import DefaultSettings
from facegeo.texturing.default.texels import mirror_index, skin_texels, smoothstep
from facegeo.texturing.image_filters import euclidean_distance, gaussian_blur, masked_blur, push_pull

__all__ = ["Fill", "chroma_trust", "detail_contrast", "fill", "fill_base", "fill_detail", "mix_keeping_contrast", "own_chroma", "own_mottling",
           "region_chroma", "specks", "with_mirror_tone"]


@dataclass
class Fill:
    """What :func:`fill` gives: the filled texture and what the backend reports of it."""

    log_rgb: np.ndarray  # (S, S, 3) float32 log linear RGB of every covered texel (seen kept by its reliability)
    via_mirror: np.ndarray  # (S, S) float32: the mirror texel's weight in the fill's detail
    mirror_asymmetry: float | None  # the seen skin's RMS left–right difference (None: too little seen on both sides)
    mirror_tone: float  # the trust in the mirror's tone, in [0, 1]
    detail_contrast: float  # robust σ of the seen skin's fine log-luminance detail


def fill(log_seen: np.ndarray, seen: np.ndarray, kept: np.ndarray, inner: np.ndarray, reliable: np.ndarray,
         confidence: np.ndarray, ambient_dependence: np.ndarray | None, mean: np.ndarray, ctx: TextureContext,
         settings: DefaultSettings) -> Fill:
    """Every covered texel of the de-lit, white-balanced log linear RGB ``log_seen`` (S, S, 3),
    known on the ``seen`` (S, S) bool texels (kept weight ``kept`` (S, S), ``inner`` their
    distance in mm to the unseen, ``reliable`` (S, S) their reliability × ``confidence`` (S, S),
    the shading's): the gradient-domain blend of the module docstring. ``ambient_dependence`` (S,
    S): the directional light model's ambient share × strength, or None; ``mean`` (3,) linear RGB,
    the seen skin's mean colour (where nothing is near, the fill settles on it)."""
    cover = ctx.coverage
    skin = skin_texels(ctx)
    own, own_detail, other, via_mirror, amp = fill_detail(log_seen, seen & cover, inner, reliable, ctx, settings)
    detail_fill = own * own_detail + (1 - own) * other
    # the gradient-domain blend: the low frequencies of the seen skin minus the fill's detail,
    # solved on the surface with the reliability as data weight (a screened Poisson problem),
    # less where the light model's ambient term lights the texel (settings.ambient_log_error), plus the
    # fill's detail; the seen texels kept by their reliability
    data = reliable
    if ambient_dependence is not None:
        data = reliable / (1.0 + (ambient_dependence * (settings.ambient_log_error / settings.fill_tone_tolerance)) ** 2)
    values, data, asymmetry, trust = with_mirror_tone(log_seen - detail_fill, data, reliable, via_mirror, skin, ctx, settings)
    base = fill_base(values, data, np.log(np.maximum(mean, 1e-4)), ctx, settings.fill_smoothness, settings)
    # in the base's place, the seen texel's own mottling where its colour is trusted (kept
    # weight × shading confidence) away from the seen edge, whatever its foreshortening and its
    # distance to the edge: near an edge the base has too little of it, and its noise is not the photo's
    mottling = own * (kept * confidence)[..., None] * own_mottling(log_seen, own_detail, base, seen & cover, ctx.size, settings)
    # the tone blended by the reliability; the detail by the same weights made to keep its
    # contrast (mixed linearly, a band of smoother skin along the seen edge)
    r = reliable[..., None]
    out_log = r * (log_seen - own_detail) + (1 - r) * (base + mottling) + mix_keeping_contrast(r + (1 - r) * own, own_detail, other)
    out_log = own_chroma(out_log, log_seen, seen & cover, reliable, confidence)
    return Fill(region_chroma(out_log, log_seen, seen & cover, reliable, confidence, ctx.regions.get("lips"), settings),
                via_mirror, asymmetry, trust, amp)


def chroma_trust(reliable: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """How far a seen texel's own chroma is trusted: its ``reliable`` (reliability × the shading's
    ``confidence``, same shape) without the ``confidence`` (a scalar shading puts only the
    luminance in doubt); 0 where the confidence is 0. Same shape, float."""
    return np.where(confidence > 1e-6, reliable / np.maximum(confidence, 1e-6), 0.0)


def own_chroma(out_log: np.ndarray, log_seen: np.ndarray, seen: np.ndarray, reliable: np.ndarray,
               confidence: np.ndarray) -> np.ndarray:
    """``out_log`` (S, S, 3) log linear RGB, the blend of the fill, with the chroma of each
    ``seen`` (S, S) bool texel taken from its own ``log_seen`` (S, S, 3) by its reliability
    without the shading's ``confidence`` (S, S) (``reliable`` (S, S) is reliability × confidence):
    the shading is one scalar a texel, so where it is steep (a misplaced shadow's edge, the lips
    under a key light) only the de-lit luminance is in doubt, not the colour. The chroma is the
    log RGB less its channel mean; the texel's own chroma gets the weight r_c = reliable /
    confidence in all (the blend gave it ``reliable``). float32."""
    r_c = chroma_trust(reliable, confidence)
    extra = np.where(seen, np.clip((r_c - reliable) / np.maximum(1.0 - reliable, 1e-6), 0.0, 1.0), 0.0)[..., None]
    if not extra.any():
        return out_log
    chroma_seen = log_seen - log_seen.mean(axis=-1, keepdims=True)
    chroma_out = out_log - out_log.mean(axis=-1, keepdims=True)
    return (out_log + extra * (chroma_seen - chroma_out)).astype(np.float32)


def region_chroma(out_log: np.ndarray, log_seen: np.ndarray, seen: np.ndarray, reliable: np.ndarray, confidence: np.ndarray,
                  region: np.ndarray | None, settings: DefaultSettings) -> np.ndarray:
    """``out_log`` (S, S, 3) log linear RGB (:func:`own_chroma`'s) with, over a ``region`` (S,
    S) soft mask in [0, 1] of a colour of its own (the lips; None: unchanged), the chroma that
    its texels did not take from the photo moved to the region's own: the fill's base comes from
    the skin around, so a lip texel trusted at 0.3 (thin, its shading steep, near the mouth's
    edge) would be 70 % skin-coloured and the lips lose their red. The region's chroma is the
    mean of its ``seen`` (S, S) bool texels' own (``log_seen`` (S, S, 3) less its channel mean),
    weighted by region × their own chroma's trust c (:func:`chroma_trust` of ``reliable`` and
    ``confidence``, (S, S) each, as :func:`own_chroma` weighs it); each region texel's chroma
    moves by region × (1 − c) × (that mean − the mean chroma the fill gave the region: its
    chroma less c × its own, over region × (1 − c)).
    Where the region's trusted texels weigh less than ``settings.region_chroma_min_share`` of the
    map, unchanged. float32; the input is not changed."""
    if region is None:
        return out_log
    at = np.flatnonzero(region.reshape(-1) > 0)  # the region's texels only (the lips: ~1 % of the map)
    weight = region.reshape(-1)[at].astype(np.float64)
    trust = chroma_trust(reliable.reshape(-1)[at], confidence.reshape(-1)[at])
    own = np.where(seen.reshape(-1)[at], np.clip(trust, 0.0, 1.0), 0.0)
    trusted, untrusted = weight * own, weight * (1.0 - own)
    if float(trusted.sum()) < settings.region_chroma_min_share * region.size or float(untrusted.sum()) <= 0.0:
        return out_log
    flat_seen, flat_out = log_seen.reshape(-1, 3)[at].astype(np.float64), out_log.reshape(-1, 3)[at].astype(np.float64)
    chroma_seen = flat_seen - flat_seen.mean(axis=-1, keepdims=True)
    chroma_out = flat_out - flat_out.mean(axis=-1, keepdims=True)
    target = trusted @ chroma_seen / float(trusted.sum())
    # the fill's share of a texel's chroma is chroma_out − own · chroma_seen (own_chroma's blend)
    given = weight @ (chroma_out - own[:, None] * chroma_seen) / float(untrusted.sum())
    out = np.array(out_log, dtype=np.float32)
    out.reshape(-1, 3)[at] = (flat_out + untrusted[:, None] * (target - given)).astype(np.float32)
    return out


def fill_detail(log_seen: np.ndarray, seen: np.ndarray, inner: np.ndarray, reliable: np.ndarray, ctx: TextureContext,
                settings: DefaultSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """The fill's detail in log RGB (zero mean) as ``own`` (S, S, 1) × the seen texel's own
    detail (S, S, 3; finer than ~S/128 texels, ~2.5 mm at 1K; 0 where not ``seen``) + (1 −
    ``own``) × the other detail (S, S, 3): the mirror texel's where that was reliably seen,
    and where not, blocks of the reliably seen skin's finest detail (above ~S ·
    ``settings.detail_sigma_fraction`` texels⁻¹: pores, stubble;
    :func:`~facegeo.texturing.default.quilting.quilted_detail`) plus, away from the seen skin, the
    octaves above it up to ``settings.mid_band_coarsest`` × S texels as
    :func:`~facegeo.texturing.default.noise.band_noise` (the skin's grain and mottling, which the
    fill's smooth base lacks, less what the blocks carry), or 3-D value noise of the model-space position with the
    seen skin's contrast where no whole block was seen; the mirror's and the synthesised
    mixed with weights that keep their contrast. ``own`` is 1 inside the seen region and fades
    out over ``settings.detail_edge_mm`` towards its edge (lashes, halos). Also the mirror's weight
    (S, S) and that contrast. ``inner``: :func:`~facegeo.texturing.default.reliability.inner_distance` of
    ``seen`` (S, S) mm."""
    cover = ctx.coverage
    size = ctx.size
    detail = np.where(seen[..., None], log_seen - masked_blur(log_seen, seen, max(1.0, size * settings.own_detail_coarsest)), 0.0)
    amp = detail_contrast(log_seen, seen & skin_texels(ctx), size, settings)
    has, mirror = mirror_index(ctx)
    # a mole or speck is not mirrored (a face's marks are not symmetric): where the source's
    # detail is an outlier (and a little around it), the mirror is not used, quilting is
    source_weight = reliable * (1.0 - specks(detail, seen & (reliable > 0.5), size, settings))
    w_m = np.where(has, source_weight.reshape(-1)[mirror], 0.0).astype(np.float32)
    mirrored = detail.reshape(-1, 3)[mirror]
    own = smoothstep(inner / settings.detail_edge_mm)[..., None] * seen[..., None]
    # the fill's detail is needed where the texel's own is not wholly used: unseen, and the seen edge
    need = cover & (own[..., 0] < 1.0 - 1e-3) & (w_m < 1.0 - 1e-3)
    synthesised = None
    if need.any():  # pores and stubble only: quilted wrinkles and blotches made waves on a bald scalp
        finest = max(1.0, size * settings.detail_sigma_fraction)
        source = seen & skin_texels(ctx) & (reliable > 0.99) & (inner > settings.detail_edge_mm)

        def quilted() -> np.ndarray | None:
            fine = np.where(seen[..., None], log_seen - masked_blur(log_seen, seen, finest), 0.0)
            return quilted_detail(fine, source, need, settings=settings)

        def layers() -> NoiseLayers | None:  # and the noise's octaves: the skin's grain and mottling
            return noise_layers(log_seen, source, need & ~seen, ctx.position, cover, euclidean_distance(~seen), finest,
                                size * settings.mid_band_coarsest, ctx.median_texel_mm, settings.mid_band_strength,
                                whole_below=size * settings.grain_coarsest, settings=settings)

        # independent until the noise counts the quilted detail: on two threads where the process may use two
        synthesised, octave_layers = run_concurrently([quilted, layers], workers=usable_threads())
        if synthesised is not None:
            synthesised += coloured_noise(octave_layers, synthesised, synthesised.shape)
    if synthesised is None:  # no whole block of reliable skin was seen: value noise with its contrast
        noise = np.zeros(cover.shape, np.float32)
        if need.any() and amp > 0:
            pos = ctx.position[need]
            n = value_noise(pos, 0.35) + 0.7 * value_noise(pos, 0.7, seed=1) + 0.4 * value_noise(pos, 1.5, seed=2)
            noise[need] = amp * n / max(float(n.std()), 1e-6)
        synthesised = noise[..., None]
    other = mix_keeping_contrast(w_m[..., None], mirrored, synthesised)
    return (own.astype(np.float32), np.where(cover[..., None], detail, 0.0).astype(np.float32),
            np.where(cover[..., None], other, 0.0).astype(np.float32), w_m, amp)


def own_mottling(log_seen: np.ndarray, own_detail: np.ndarray, base: np.ndarray, seen: np.ndarray, size: int,
                 settings: DefaultSettings) -> np.ndarray:
    """(S, S, 3) float32: on the ``seen`` (S, S) bool texels, the band of their log RGB
    ``log_seen`` (S, S, 3) between the fine ``own_detail`` (S, S, 3; ``settings.own_detail_coarsest``)
    and ``settings.own_mid_band_coarsest`` × S texels (the skin's mottling) less the same band of
    the fill's ``base`` (S, S, 3) log RGB: added to the base, it replaces the base's band by
    the photo's; 0 elsewhere."""
    coarsest = size * settings.own_mid_band_coarsest
    # band(x) = blur_fine(x) − blur_coarse(x), and blur_fine(log_seen) = log_seen − own_detail
    band = log_seen - own_detail - masked_blur(base, seen, max(1.0, size * settings.own_detail_coarsest)) - masked_blur(log_seen - base, seen, coarsest)
    return np.where(seen[..., None], band, 0.0).astype(np.float32)


def specks(detail: np.ndarray, region: np.ndarray, size: int, settings: DefaultSettings) -> np.ndarray:
    """(S, S) float32 in [0, 1]: 1 on the marks of the fine detail (S, S, 3) log RGB, texels
    whose channel-mean detail is beyond ``settings.speck_sigmas`` robust σ of ``region``'s (S, S)
    bool, grown by a Gaussian of S/512 texels (the mark's rim); 0 elsewhere."""
    d = channel_sum(detail) / 3  # (detail.mean(-1))
    if region.sum() < 100:
        return np.zeros(region.shape, np.float32)
    sigma = 1.4826 * float(np.median(np.abs(d[region]))) + 1e-6
    marks = (np.abs(d) > settings.speck_sigmas * sigma).astype(np.float32)
    return np.clip(gaussian_blur(marks, max(1.0, size / 512.0)) * 3.0, 0.0, 1.0).astype(np.float32)


def fill_base(values: np.ndarray, w: np.ndarray, mean: np.ndarray, ctx: TextureContext, smoothness: float,
              settings: DefaultSettings) -> np.ndarray:
    """(S, S, C) smooth field: ``values`` (S, S, C) known with weight ``w`` (S, S) extended
    over the surface by a screened Poisson problem on the mesh's vertices (continuous across
    UV seams): minimise Σ_v w_v (x_v − values_v)² + ``smoothness`` Σ_edges (x_a − x_b)² +
    ε Σ_v (x_v − mean)², so that far from anything seen it settles on ``mean`` (C,), and
    near the seen skin it takes that skin's own values. Without surface operators: a UV
    push-pull."""
    size = ctx.size
    if ctx.surface is None:
        return push_pull(values, w, size, size / 64.0 * np.sqrt(smoothness / settings.fill_smoothness), mean)
    surf = ctx.surface
    vertex_values, vw = surf.to_vertices(values, w)
    eps = 1e-3
    system = (sp.diags(vw + eps) + smoothness * surf.laplacian).tocsc()
    rhs = vw[:, None] * np.nan_to_num(vertex_values) + eps * np.asarray(mean, np.float64)[None, :]
    x = spla.splu(system).solve(rhs)
    return surf.to_texels(x, size)


def detail_contrast(log_rgb: np.ndarray, seen: np.ndarray, size: int, settings: DefaultSettings) -> float:
    """Robust σ of the seen skin's fine log-luminance detail (above ~S ·
    ``settings.detail_sigma_fraction`` texels⁻¹, the band the fill quilts): ``log_rgb`` (S, S, 3) log linear RGB, ``seen`` (S, S) bool."""
    if seen.sum() < 100:
        return 0.0
    log_l = np.log(np.maximum(luminance(np.exp(log_rgb)), 1e-4))
    detail = log_l - masked_blur(log_l, seen, max(1.0, size * settings.detail_sigma_fraction))
    d = detail[seen]
    return float(1.4826 * np.median(np.abs(d - np.median(d))))


def with_mirror_tone(values: np.ndarray, data: np.ndarray, reliable: np.ndarray, via_mirror: np.ndarray,
                     skin: np.ndarray, ctx: TextureContext, settings: DefaultSettings) -> tuple[np.ndarray, np.ndarray, float | None, float]:
    """The fill's data (``values`` (S, S, 3) log RGB without the fill's detail, weight ``data``
    (S, S)) with the mirror texel's values added where the texel is not wholly ``reliable``
    (S, S), at weight (1 − reliable) × ``via_mirror`` (S, S, the mirror's reliability) × the
    trust ``settings.mirror_asymmetry`` gives the seen ``skin``'s (S, S) bool symmetry; also that
    asymmetry (None where too little skin is seen on both sides: trust 0) and the trust."""
    size = ctx.size
    _, mirror = mirror_index(ctx)
    region = (reliable > 0.5) & skin
    both = region & (via_mirror > 0.5)  # (via_mirror is 0 where a texel has no mirror)
    if both.sum() < settings.mirror_overlap * size * size:
        return values, data, None, 0.0
    low = masked_blur(values, region, size / 64.0)
    difference = (low - low.reshape(-1, 3)[mirror])[both]
    asymmetry = float(np.sqrt(np.mean(difference ** 2)))
    lo, hi = settings.mirror_asymmetry
    trust = float(1.0 - smoothstep(np.float64((asymmetry - lo) / (hi - lo))))
    if trust <= 0.0:
        return values, data, asymmetry, 0.0
    extra = ((1.0 - reliable) * via_mirror * trust).astype(np.float32)
    total = data + extra
    mixed = (data[..., None] * values + extra[..., None] * values.reshape(-1, 3)[mirror]) / np.maximum(total, 1e-12)[..., None]
    return np.where(total[..., None] > 0, mixed, values).astype(np.float32), total.astype(np.float32), asymmetry, trust


def mix_keeping_contrast(a: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(a · x + (1 − a) · y) / √(a² + (1 − a)²) for weights ``a`` in [0, 1] and zero-mean detail
    layers ``x``, ``y`` (broadcast): two independent layers mixed linearly keep only a² + (1 − a)²
    of their variance (half at a = ½), so this keeps their contrast where the mix changes."""
    return (a * x + (1 - a) * y) / np.sqrt(a * a + (1 - a) ** 2)
