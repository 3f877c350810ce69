"""The default backend's class: the four stages of :class:`~facegeo.texturing.backend.TextureBackend`
over the modules of :mod:`facegeo.texturing.default`, with its settings and its report.

* **inpaint**: the photo texture's clipped channels restored
  (:mod:`~facegeo.texturing.default.clipping`), the texture analysed
  (:mod:`~facegeo.texturing.default.delighting`), de-lit, the light's
  colour (:mod:`~facegeo.texturing.default.light_colour`) and the skin's sheen
  (:mod:`~facegeo.texturing.default.sheen`) taken out, filled
  (:mod:`~facegeo.texturing.default.fill`), and relit with the estimated shading and light colour.
* **homogenise**: the filled texture divided by the shading and the light's colour.
* **delight** (not a :class:`~facegeo.texturing.backend.TextureBackend` stage): inpaint's first
  half, what one photo of several says of the texels it saw (no fill).
* **materials**: :mod:`~facegeo.texturing.default.materials`.
* **upscale**: Lanczos (OpenCV ``INTER_LANCZOS4``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import cv2
import numpy as np

from facegeo.asset import MAP_NAMES
from facegeo.colour import channel_max, is_greyscale, linear_to_srgb, luminance, srgb_to_linear
from facegeo.lighting import sh_basis
from facegeo.texturing.backend import SKIN_CONSTANTS, TextureContext
from facegeo.texturing.default.albedo_level import albedo_level
from facegeo.texturing.default.clipping import restore_clipped
from facegeo.texturing.default.delighting import Analysis, analyse
from facegeo.texturing.default.fill import fill
from facegeo.texturing.default.light_colour import ambient_trend, light_colour, light_colour_map
from facegeo.texturing.default.materials import materials as pbr_maps
from facegeo.texturing.default.reliability import inner_distance, reliability, shading_confidence
from facegeo.texturing.default.settings import DEFAULT_SETTINGS, DefaultSettings
from facegeo.texturing.default.sheen import without_specular, without_sun_sheen
from facegeo.texturing.default.texels import skin_texels, subsample
from facegeo.texturing.illuminant import cast_gains, invent_chroma, remove_cast
from facegeo.texturing.image_filters import pad_outside, pad_width

__all__ = ["DefaultBackend"]


@dataclass(frozen=True)
class _Delit:
    """What :meth:`DefaultBackend._delit` found of one photo texture (all (S, S[, 3]) float32 or
    bool): the analysis, its kept weight, the seen texels (weight > 0.5), their distance inside
    the seen region, their reliability and the shading's confidence, the de-lit linear albedo,
    the light's colour (its two chroma coordinates, or a map), whether the photo is greyscale,
    notes, the illuminant's report and the factor that set the albedo's level
    (:func:`~facegeo.texturing.default.albedo_level.albedo_level`)."""

    analysis: Analysis
    weight: np.ndarray
    seen: np.ndarray
    inner: np.ndarray
    reliable: np.ndarray
    confidence: np.ndarray
    albedo: np.ndarray
    light: Any
    greyscale: bool
    notes: list[str]
    illuminant: dict[str, Any]
    level: float


@dataclass
class DefaultBackend:
    """Weight-free texture backend. ``settings``
    (:class:`~facegeo.texturing.default.settings.DefaultSettings`, default
    :data:`~facegeo.texturing.default.settings.DEFAULT_SETTINGS`) holds every knob: the
    detail band and depth, the skin's mean albedo that scales the specular removal (None for a
    photo without specular reflection), the de-lighting's, the fill's and the materials'.
    ``report`` holds statistics of the last calls; ``constants``
    (:data:`~facegeo.texturing.backend.SKIN_CONSTANTS`) the maps not asked for."""

    constants: ClassVar[Mapping[str, float]] = SKIN_CONSTANTS
    name: str = "default"
    settings: DefaultSettings = DEFAULT_SETTINGS
    report: dict[str, Any] = field(default_factory=dict)
    _analysis: tuple[TextureContext, Analysis] | None = field(default=None, repr=False)
    _filled: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    _reliable: tuple[TextureContext, np.ndarray] | None = field(default=None, repr=False)

    # ---------------------------------------------------------------------------------- analysis
    def analyse(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> Analysis:
        """Shading, highlights and kept weight of a photo texture ``T_inc`` (S, S, 3) sRGB seen
        with visibility ``M_vis`` (S, S), its clipped channels restored first (:meth:`_linear`;
        :func:`~facegeo.texturing.default.delighting.analyse`); cached for ``ctx`` until the next call."""
        return self._analyse(T_inc, self._linear(T_inc, M_vis, ctx), M_vis, ctx)

    def _linear(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) float32 linear RGB of the photo texture ``T_inc`` (S, S, 3) sRGB, its clipped
        channels restored from the seen skin's (``M_vis`` (S, S) > 0.5) colour ratios
        (:func:`~facegeo.texturing.default.clipping.restore_clipped`) before any analysis: a
        key-lit cheek clipped in red is then fitted as the skin it is. (Left out, the light fits
        saw only the fill side: Lee Perry-Smith's key + fill render at +1 EV came out 3.6 ΔE00
        from 0 EV, against 1.1 restored first; benchmarks/RESULTS.md.)"""
        return restore_clipped(srgb_to_linear(T_inc), (M_vis > 0.5) & skin_texels(ctx) & ctx.coverage, ctx.size,
                               settings=self.settings)

    def _analyse(self, T_inc: np.ndarray, lin: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> Analysis:
        """:meth:`analyse` of the texture ``T_inc`` (S, S, 3) sRGB already linearised: ``lin`` (S, S, 3)
        float32 linear RGB; the report's ``light`` (the directional light model's, where used) and
        ``analyse`` entries."""
        self.report.pop("light", None)
        analysis, light, statistics = analyse(T_inc, lin, M_vis, ctx, self.constants, self.settings)
        self._analysis = (ctx, analysis)
        if light is not None:
            self.report["light"] = light
        self.report["analyse"] = statistics
        return analysis

    def reliability(self, weight: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S) float32 in [0, 1]: how far each seen texel of kept ``weight`` (S, S) is trusted
        (:func:`~facegeo.texturing.default.reliability.reliability`, with the distance to the
        texels of ``weight`` ≤ 0.5)."""
        return reliability(weight, inner_distance(weight > 0.5, ctx), ctx, self.settings)

    # ---------------------------------------------------------------------------------- inpaint
    def inpaint(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB + (S, S) visibility -> (S, S, 3) sRGB, every texel filled, under the
        photo's lighting (the estimated shading and light colour applied to the filled albedo)."""
        cover = ctx.coverage
        d = self._delit(T_inc, M_vis, ctx)
        skin = skin_texels(ctx)
        if d.reliable[skin].sum() >= 10:
            mean = (d.albedo * d.reliable[..., None]).reshape(-1, 3).sum(0) / d.reliable.sum()
        elif (d.weight > 0).any():
            mean = (d.albedo * d.weight[..., None]).reshape(-1, 3).sum(0) / d.weight.sum()
        else:  # nothing seen at all: the model's texture
            mean = srgb_to_linear(ctx.mean_texture)[cover].mean(0)
        filled = fill(np.log(np.maximum(d.albedo, 1e-4)), d.seen, d.weight, d.inner, d.reliable, d.confidence,
                      d.analysis.ambient_dependence, mean, ctx, self.settings)
        out = np.where(cover[..., None], np.exp(filled.log_rgb), 0.0)
        if d.greyscale:
            out = invent_chroma(luminance(out), ctx.regions.get("lips"))
        peak = channel_max(out)
        out = np.where(peak > 1.0, out / np.maximum(peak, 1e-6), out).astype(np.float32)  # keeps chroma
        self.report["inpaint"] = {
            "seen": float(M_vis[cover].mean()) if cover.any() else 0.0,
            "kept_as_seen": float(d.reliable[cover].mean()) if cover.any() else 0.0,
            "via_mirror": float(((1 - d.reliable) * filled.via_mirror)[cover].mean()) if cover.any() else 0.0,
            "mirror_asymmetry": filled.mirror_asymmetry,
            "mirror_tone": filled.mirror_tone,
            "detail_contrast": filled.detail_contrast,
        }
        self.report["illuminant"] = d.illuminant
        self.report["notes"] = d.notes
        self._reliable = (ctx, np.where(cover, d.reliable, 0.0).astype(np.float32))
        # under the photo's light and exposure again: the albedo's level (d.level) is not the photo's
        relit = linear_to_srgb(np.clip(out * (cast_gains(d.light) / d.level) * d.analysis.shading[..., None], 0.0, None))
        result = self._pad(relit.astype(np.float32), cover)
        self._filled = (result, out)
        return result

    def delight(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> tuple[np.ndarray, np.ndarray]:
        """The first half of :meth:`inpaint` without the fill: ``(albedo (S, S, 3) float32 linear
        RGB, de-lit, the light's colour and the sheen taken out, channel peaks limited to 1 as
        :meth:`inpaint` limits them; reliable (S, S) float32 in [0, 1], how far each texel's
        albedo is trusted, 0 where the photo did not see it)``: what one photo of several says
        of the texels it saw (:func:`facegeo.pipeline.reconstruct_views`). A greyscale photo's
        albedo is grey."""
        d = self._delit(T_inc, M_vis, ctx)
        albedo = np.where(ctx.coverage[..., None], d.albedo, 0.0)
        peak = channel_max(albedo)
        albedo = np.where(peak > 1.0, albedo / np.maximum(peak, 1e-6), albedo).astype(np.float32)
        self.report["illuminant"] = d.illuminant
        self.report["notes"] = d.notes
        return albedo, np.where(ctx.coverage, d.reliable, 0.0).astype(np.float32)

    def seen_reliability(self, ctx: TextureContext) -> np.ndarray:
        """(S, S) float32 in [0, 1]: how far the last :meth:`inpaint` of ``ctx`` trusted each
        texel as seen (the ``reliable`` of :meth:`delight`; 0 where the photo did not see it).

        Raises:
            ValueError: no inpaint of ``ctx`` was made by this backend."""
        if self._reliable is None or self._reliable[0] is not ctx:
            raise ValueError("seen_reliability: inpaint this context first")
        return self._reliable[1]

    def _delit(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> _Delit:
        """Analyse the photo texture and de-light what it saw (:meth:`inpaint`'s first half)."""
        settings = self.settings
        skin = skin_texels(ctx)
        lin = self._linear(T_inc, M_vis, ctx)
        an = self._analyse(T_inc, lin, M_vis, ctx)
        w = an.weight
        seen = w > 0.5
        delit = lin / an.shading[..., None]
        inner = inner_distance(seen, ctx)  # the reliability's edge ramp and the fill's own-detail ramp
        # where the estimated shading is steep (a shadow's edge, a hard light's terminator) a
        # misplacement of the fitted mesh by settings.shadow_softness_mm changes it by slope × that:
        # such de-lit texels are trusted less and the fill takes over (below: (1 - reliable) · fill)
        confidence = shading_confidence(an.shading, ctx, settings)
        reliable = reliability(w, inner, ctx, settings) * confidence
        notes: list[str] = []
        greyscale = an.greyscale
        # the light's colour: from the reliably seen skin and the photo's white references
        light = np.zeros(2)
        skin_weight = reliable * skin
        illuminant_report: dict[str, Any] = {"greyscale": greyscale}
        if not greyscale and skin_weight.sum() >= 10:
            free = without_specular(delit, an.specular[..., None], settings)  # the light's colour is judged without the sheen
            # two lights: the ambient term's colour told apart (and the white reference lit at its share)
            trend = None if an.ambient_dependence is None else ambient_trend(free, an.ambient_dependence, skin_weight)
            light, illuminant_report = light_colour(free, skin_weight, ctx, trend)
            illuminant_report["greyscale"] = False
            if trend is not None:
                light = light_colour_map(light, trend, illuminant_report)
            delit = remove_cast(delit, light)
        elif greyscale:
            delit = np.repeat(luminance(delit)[..., None], 3, axis=-1)
            notes.append("the photo is greyscale: the albedo's chroma is invented (a generic skin tone, redder lips)")
        delit = without_specular(delit, an.specular[..., None], settings)  # white once the light's colour is out
        if an.sun_lobe is not None and not greyscale:  # (a greyscale photo has no chroma to tell the sheen by)
            delit = without_sun_sheen(delit, an.sun_lobe, w > 0, (reliable > 0.5) & skin, settings.sheen_smooth_mm / ctx.median_texel_mm,
                                      settings=settings)
        # the level: the exposure does not set it (the skin-reflectance prior, the white references)
        white = ctx.white_reference if illuminant_report.get("white_used") else None
        level, self.report["albedo_level"] = albedo_level(delit, skin_weight, an.shading, ctx.regions.get("eyes"), white,
                                                          illuminant_report.get("skin_tone"), settings)
        delit = delit * np.float32(level)
        return _Delit(an, w, seen, inner, reliable, confidence, delit, light, greyscale, notes, illuminant_report, level)

    # ---------------------------------------------------------------------------------- homogenise
    def homogenise(self, T_full: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB -> (S, S, 3) sRGB albedo: divided by the shading (luminance only) and the
        light's colour; after :meth:`inpaint` of the same context, its filled albedo, else the
        texture analysed as if everything were seen."""
        cover = ctx.coverage
        skin = skin_texels(ctx)
        if self._filled is not None and self._filled[0] is T_full and self._analysis is not None and self._analysis[0] is ctx:
            shading, albedo = self._analysis[1].shading, self._filled[1]
        else:  # called on its own: analyse the texture as if everything were seen
            an = self.analyse(T_full, cover.astype(np.float32), ctx)
            shading = an.shading
            albedo = srgb_to_linear(T_full) / shading[..., None]
            weight = self.reliability(cover.astype(np.float32), ctx) * skin
            if weight.sum() >= 10 and not is_greyscale(T_full[cover]):
                light, self.report["illuminant"] = light_colour(without_specular(albedo, an.specular[..., None], self.settings),
                                                                weight, ctx)
                albedo = remove_cast(albedo, light)
            albedo = without_specular(albedo, an.specular[..., None], self.settings)
            peak = channel_max(albedo)
            albedo = np.where(peak > 1.0, albedo / np.maximum(peak, 1e-6), albedo)
        before = self._shading_variance(T_full, ctx.normal_camera, skin, srgb=True)
        after = self._shading_variance(albedo, ctx.normal_camera, skin)
        self.report["homogenise"] = {
            "shading_variance_before": before,
            "shading_variance_after": after,
            "remaining_fraction": after / max(before, 1e-12),
        }
        return self._pad(linear_to_srgb(np.where(cover[..., None], albedo, 0.0)), cover)

    @staticmethod
    def _shading_variance(colour: np.ndarray, normals: np.ndarray, skin: np.ndarray, srgb: bool = False) -> float:
        """Variance of the ``skin`` (S, S) bool texels' log-luminance explained by the SH basis of
        the camera-space ``normals`` (S, S, 3) (``colour`` (S, S, 3) linear RGB, or sRGB with ``srgb``)."""
        rows = subsample(np.flatnonzero(skin.ravel()))
        if len(rows) < 10:
            return 0.0
        values = colour.reshape(-1, 3)[rows]
        log_l = np.log(np.maximum(luminance(srgb_to_linear(values) if srgb else values), 1e-4))
        basis = sh_basis(normals.reshape(-1, 3)[rows].astype(np.float32))
        coeffs, *_ = np.linalg.lstsq(basis, log_l - log_l.mean(), rcond=None)
        return float(np.var(basis @ coeffs))

    # ---------------------------------------------------------------------------------- materials
    def materials(self, T_hom: np.ndarray, ctx: TextureContext, maps: frozenset[str] | set[str] = frozenset(MAP_NAMES)) -> dict[str, np.ndarray]:
        """PBR maps (see :mod:`facegeo.asset`) from the homogenised texture; only ``maps``
        (:func:`~facegeo.texturing.default.materials.materials`; the highlights of the last
        analysis of ``ctx`` make the skin glossier)."""
        highlight = self._analysis[1].highlight if self._analysis is not None and self._analysis[0] is ctx else None
        return pbr_maps(T_hom, ctx, maps, highlight, self.settings)

    # ---------------------------------------------------------------------------------- upscale
    def upscale(self, map_: np.ndarray, factor: int) -> np.ndarray:
        """Lanczos upscaling by an integer ``factor`` (1 returns the map unchanged)."""
        if factor == 1:
            return map_
        if factor < 1:
            raise ValueError(f"upscale factor: expected an integer ≥ 1, got {factor}")
        h, w = map_.shape[:2]
        return cv2.resize(map_, (w * factor, h * factor), interpolation=cv2.INTER_LANCZOS4)

    def _pad(self, map_: np.ndarray, cover: np.ndarray) -> np.ndarray:
        """``map_`` (S, S[, C]) padded outside ``cover`` (S, S) bool over ``settings.pad_fraction`` × S
        texels (:func:`~facegeo.texturing.image_filters.pad_outside`)."""
        return pad_outside(map_, cover, pad_width(cover.shape[0], self.settings.pad_fraction))
