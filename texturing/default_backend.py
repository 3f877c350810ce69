"""The weight-free, deterministic default texture backend.

Colour textures are sRGB in [0, 1], float32, S × S, image-style rows (see
:mod:`facegeo.texturing.backend`). Every step below works on linear RGB.

* **Shading** (:meth:`DefaultBackend.analyse`): one scalar per texel. Order-1 spherical harmonics
  (:data:`SH_TERMS`) of the camera-space normal are fitted to the luminance of the reliably seen
  skin (:meth:`DefaultBackend.reliability` > 0.5; iteratively trimmed least squares: texels whose
  log-ratio to the fit is beyond 2.5 robust σ, highlights, creases, stray occluders, are left out)
  and applied as shading^strength, the strength rising with how directional the fitted light is
  (:data:`DIRECTIONAL_RANGE`) or how far its irradiance would vary over the whole sphere of normals
  (:data:`CONTRAST_RANGE`: a hard light whose shadowed side the skin mask left out shows little
  variation over the lit skin that is kept, but a steep one): under an even light the fit finds
  only albedo that correlates with the normals and leaves it alone; then the cast shadows and
  occlusion SH cannot explain: dips of the de-lit log-luminance at ~S/128 texels below the brighter
  of its ~S/12 and ~S/5 neighbourhoods (~25 and ~60 mm; broad shadows such as the jaw's on the
  neck), deeper than :data:`SHADOW_TOLERANCE`, and where the context has the posed mesh no
  deeper than its occlusion allows: the log of its sky visibility (:func:`facegeo.uv.sky_visibility`,
  the irradiance an even environment leaves a texel) at its lowest within :data:`SHADOW_EDGE_MM`
  (the nostrils, the eyes' and mouth's corners; on open skin a dip is albedo, a beard). The de-lighting gain 1/shading is bounded to [1/g,
  g] with g = :data:`MAX_GAIN` where the surface faces the camera, falling to :data:`GRAZING_GAIN`
  at grazing angles (SH fits underestimate grazing irradiance; unbounded gains made metallic
  streaks).
* **A directional light** (where the SH fit's strength is above 0 and the context has the posed
  mesh): the SH shading is replaced by a physical model fitted to the same skin,
  luminance ≈ albedo · (ambient + L · max(n·l, 0) · V_l) (:meth:`DefaultBackend._directional_shading`),
  V_l the texel's visibility from the light by a shadow map of the posed mesh
  (:func:`facegeo.uv.light_visibility`: the nose's, brow's and jaw's cast shadows), blurred over
  :data:`SHADOW_SOFTNESS_MM`; dips are then looked for only within ~:data:`SHADOW_EDGE_MM` of a
  cast shadow's edge (which the fitted mesh misplaces by a few mm; elsewhere what is left is
  albedo, a beard), and the gains are bounded by :data:`LIGHT_GAIN` (a hard light's shadowed
  side is 5–15× darker).
* **The skin's specular reflection** (:meth:`DefaultBackend._specular`): the GGX reflection of
  the environment (or of the directional model's ambient) with generic skin's roughness and F0,
  a sheen strongest where the skin turns away from the camera, in the photo's units through an
  assumed mean skin albedo (:data:`SKIN_ALBEDO`), is subtracted from the de-lit texture once
  the light's colour is out (the sheen is white then), at most 1 − :data:`SPECULAR_FLOOR` of a
  texel; the light's colour is estimated from the skin without it.
* **The directional light's sheen** (:func:`without_sun_sheen`, under the directional model):
  seen skin near the light's mirror direction (the angle between the normal and the half vector
  of light and view, a Gaussian of σ = :data:`SUN_SHEEN_LOBE_DEG`: GGX's lobe for skin widened by
  the fitted mesh's normal error, times the texel's lit share of its shading) is taken as the
  skin's diffuse colour plus white (the dichromatic model, once the light's colour is out); the
  white part, smoothed over :data:`SHEEN_SMOOTH_MM`, is subtracted there. Where the de-lit colour
  is as saturated as the skin away from the lobe nothing is taken, so a lobe the fitted normals
  misplace takes out no colour.
* **Highlights**: de-lit luminance above :data:`HIGHLIGHT_RATIO` × its neighbourhood's (Gaussian,
  σ = S/48 texels, ~6 mm at 1K, re-estimated without the first pass's candidates; the reliable
  skin's, and the seen texels' where no reliable skin is near: :data:`HIGHLIGHT_REFERENCE_SUPPORT`),
  over a patch (:data:`HIGHLIGHT_PATCH_MM`) or, on a narrower spot, whiter than the neighbourhood
  (:func:`white_share`, :data:`HIGHLIGHT_WHITE_SHARE`: not the skin between a beard's hairs);
  they are treated as unseen (filled) and are the specular map's evidence.
* **Clipped texels** (a channel at :data:`CLIPPED_LEVEL`, over-exposed skin) are left out of
  every fit: their values are lower bounds. Where only some channels are clipped, those are raised
  to what the others and the surrounding skin's colour ratios imply (:func:`restore_clipped`).
* **An occluder's fringe** (:meth:`DefaultBackend._occluder_fringe`): seen skin within
  :data:`FRINGE_MM` of the unseen whose de-lit colour the reliably seen skin's robust Gaussian
  (log RGB) puts beyond its :data:`FRINGE_SIGNIFICANCE` χ² quantile is what the photo's mask let
  through at its edge (a sideburn's last strands, a frame's rim) and is treated as unseen too; in
  a greyscale photo, whose mask has no chroma to keep hair out, wherever it is seen.
* **The light's colour** (:mod:`facegeo.texturing.illuminant`): estimated from the reliably seen
  skin's mean chroma (the skin locus) and the photo's white references (sclera, teeth:
  ``ctx.white_reference``) and divided out of the whole map, luminance kept; under the
  directional light model, the ambient term's colour apart from the directional light's where
  the shade is the cooler (a sun and its blue sky): the light's chroma per texel moves with its
  ambient share of the shading as the de-lit skin's does along the Planckian locus
  (:func:`~facegeo.texturing.illuminant.ambient_chroma_trend`). A greyscale photo
  gets a generic skin chroma, and ``report["notes"]`` says so (the pipeline copies the notes
  into ``fit.json``).
* **inpaint** (fill of what the photo does not show, and of the highlights), on the de-lit,
  white-balanced texture in log RGB, as a **gradient-domain blend**: every seen texel has a
  reliability r (:meth:`DefaultBackend.reliability`: its kept visibility × a foreshortening ramp ×
  a ramp over :data:`EDGE_MM` mm from the nearest unseen texel: silhouettes, occluders, highlights;
  × a ramp down where the estimated shading is steep: :data:`SHADING_ERROR`); the fill's fine
  detail D (finer than ~S/128 texels, ~2.5 mm at 1K) is the seen texel's own detail away from the
  seen region's edge, else the mirror texel's where that was reliably seen (not its moles and
  specks: :data:`SPECK_SIGMAS`), else the finest detail (~1 mm at 1K: pores, stubble) of the
  reliably seen skin quilted in blocks (:func:`quilted_detail`: this face's own texture at its own
  contrast, each block from the seen skin near the block's nearest seen place) plus, away from
  the seen skin, the octaves up to S/32 texels (~12 mm at 1K) as colour noise with the seen
  skin's own covariance per octave (:func:`band_noise`: its mottling; 3-D
  value noise of the model-space position only where no whole block of skin was seen); the low
  frequencies B solve a screened Poisson problem on the mesh's vertices,
  min Σ r (B − (log seen − D))² + λ Σ_edges |∇B|² (+ a weak pull to the seen skin's mean far from
  anything seen), so the filled skin takes its tone from the reliable seen skin next to it and
  B + D has the seen skin's values wherever r is high (under the directional light model the
  data weight is r / (1 + (a · :data:`AMBIENT_LOG_ERROR` / :data:`FILL_TONE_TOLERANCE`)²), a
  the texel's ambient share of its shading times the de-lighting strength: skin lit by the
  ambient term alone carries that term's error whole, and the fill would take its tone from it);
  the result's tone is r · (log seen − D_own) + (1 − r) · (B + M), M the seen texel's own band
  from D's scale to :data:`OWN_MID_BAND_COARSEST` × S (its mottling) less B's, where its colour
  is trusted (kept weight × shading confidence) away from the seen edge; its detail the texel's own D_own
  and the fill's other detail D_fill mixed with weights a = r + (1 − r) · (the own detail's
  share of D) and 1 − a, divided by √(a² + (1 − a)²) (two independent layers mixed linearly
  lose up to half their variance: a band of smoother skin along the seen edge): no edge where
  the seen skin ends, continuous across UV seams and the mirror line because B lives on the
  vertices. The mirror's low frequencies are data for B too (weight
  (1 − r) × the mirror's reliability × a trust from the seen skin's own symmetry,
  :data:`MIRROR_ASYMMETRY`): where both sides are seen and agree (a stubbled jaw, a red cheek on
  both sides), the hidden side takes the mirror's tone; where they differ (one side still lit or
  shadowed after de-lighting, a scanner's light baked in), only fine detail crosses the mirror.
  Without :class:`SurfaceOperators` B is a UV-space push-pull (masked blurs at growing scales).
* **homogenise**: the filled texture divided by the shading and the light's colour.
* **materials**: albedo = homogenised texture; displacement (mm) and tangent-space normal from its
  high-frequency log-luminance detail at :data:`DETAIL_DEPTH_MM` mm per unit (±
  :data:`DETAIL_LIMIT_MM`); occluders never reach it (they are filled before); roughness and
  specular from facial-region priors blurred to smooth anatomical shapes (σ = S/64 texels, ~8 mm)
  and raised/lowered by the highlight evidence.
* **upscale**: Lanczos (OpenCV ``INTER_LANCZOS4``).
* **Padding** (:func:`pad_outside`, every map): outside the UV islands the edge value over
  S/256 texels, then the map's median, flat (no streaks in texture viewers).

The context's fitted SH lighting (``ctx.gamma``) is not used: it is fitted per RGB channel to the
model's albedo, and dividing by it put its colour errors into the albedo (casts). The model's
texture (``ctx.mean_texture``) is used only when no texel is seen at all.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import cv2
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy import ndimage

from facegeo.asset import MAP_NAMES, SPECULAR_F0_SCALE
from facegeo.colour import channel_max, channel_min, channel_sum, is_greyscale, linear_to_srgb, luminance, srgb_to_linear
from facegeo.lighting import sh_basis
from facegeo.robust_gaussian import chi2_quantile, mahalanobis_squared, robust_gaussian
from facegeo.texturing.backend import SKIN_CONSTANTS, TextureContext
from facegeo.texturing.ggx import environment_brdf
from facegeo.texturing.illuminant import ambient_chroma_trend, cast_gains, chroma, estimate_illuminant, invent_chroma, remove_cast
from facegeo.uv.renderer import light_visibility, sky_visibility, sphere_directions

__all__ = ["DefaultBackend", "REGION_PRIORS", "pad_outside", "masked_blur", "gaussian_blur", "value_noise", "MAX_GAIN",
           "GRAZING_GAIN", "QUILT_BLOCK", "QUILT_ENERGY_CAP", "QUILT_NEIGHBOURHOOD", "QUILT_TRIES", "quilted_detail", "restore_clipped", "band_noise", "gradient_noise", "nonnegative_least_squares", "GRAIN_COARSEST", "MID_BAND_COARSEST", "OWN_DETAIL_COARSEST", "OWN_MID_BAND_COARSEST", "MID_BAND_STRENGTH", "NOISE_CELL_PER_SIGMA", "SPECK_SIGMAS", "SHADOW_TOLERANCE", "SHADOW_EDGE_MM", "AMBIENT_LOG_ERROR", "FILL_TONE_TOLERANCE", "HIGHLIGHT_RATIO", "HIGHLIGHT_REFERENCE_SUPPORT", "HIGHLIGHT_PATCH_MM", "HIGHLIGHT_WHITE_SHARE", "white_share", "CLIPPED_LEVEL", "DETAIL_DEPTH_MM", "DETAIL_LIMIT_MM", "SH_TERMS",
           "DIRECTIONAL_RANGE", "CONTRAST_RANGE", "SHADING_ERROR", "FORESHORTENING", "EDGE_MM", "DETAIL_EDGE_MM", "PAD_FRACTION",
           "SKIN_ALBEDO", "SPECULAR_FLOOR", "without_sun_sheen", "SUN_SHEEN_LOBE_DEG", "SHEEN_SMOOTH_MM"]

#: (roughness, specular) priors per facial region; oily T-zone glossier, brows matte, lips smooth
#: and less specular (values in the range of measured facial BRDF fits, e.g. Weyrich et al. 2006).
REGION_PRIORS: dict[str, tuple[float, float]] = {
    "forehead": (0.45, 0.60),
    "nose": (0.40, 0.65),
    "cheeks": (0.55, 0.45),
    "chin": (0.50, 0.50),
    "lips": (0.35, 0.40),
    "brows": (0.75, 0.25),
    "eyes": (0.30, 0.70),
}
#: Roughness and specular where no region mask says otherwise (skin on the head and neck).
DEFAULT_PRIOR = (SKIN_CONSTANTS["roughness"], SKIN_CONSTANTS["specular"])
#: Largest de-lighting gain (and 1/smallest) where the surface faces the camera.
MAX_GAIN = 2.0
#: Largest gain at grazing angles (camera-space normal z → 0).
GRAZING_GAIN = 1.25
#: SH terms of the shading fit: order 1 (constant + the three linear terms). Order 2 over the
#: half-sphere of normals a photo shows is ill-conditioned: on renders of a real head scan under
#: an even light it fitted a dark centre and bright sides (the albedo's beard zone and cheeks),
#: anti-correlated with the true shading (benchmarks/bench_albedo_scans.py, RESULTS.md).
SH_TERMS = 4
#: (none, full): the shading is applied as shading^strength, the strength rising from 0 to 1 as the
#: fit's directional part (the standard deviation of its linear terms over the fitted skin over
#: its mean) goes from the first value to the second: an even light's fit finds 0.15–0.21 there
#: (albedo that correlates with the normals), a hard side light 0.29–0.33.
DIRECTIONAL_RANGE = (0.2, 0.3)
#: (none, full): the strength also rises from 0 to 1 as the fit's irradiance contrast over the
#: sphere of normals, |linear part| / constant (E(n) = c·(1 + κ·n·d): κ ≥ 1 puts part of the head
#: in the dark), goes from the first value to the second; the strength is the larger of the two.
#: A hard light whose shadowed side is too dark for the skin mask leaves only lit skin to fit,
#: whose normals span too little for :data:`DIRECTIONAL_RANGE` (0.17 on bench_albedo_scans'
#: Lee Perry-Smith scan, hard side 0°) while κ is large (the constant term near or below 0). An
#: even light: κ 0.3–0.5 on both scans' frontal renders, 0.4–0.9 on the contact sheet's photos
#: (benchmarks/sheet_albedo.py); the James scan's colour map, whose capture light is baked in,
#: reads as a hard light at ±40° (4.4, and a constant term below 0).
CONTRAST_RANGE = (1.0, 2.0)
#: κ reported (and used) where the constant term is ≤ 0 or smaller than the linear part over this.
CONTRAST_CAP = 100.0
#: Candidate light directions of the directional fit (a Fibonacci sphere; those below
#: :data:`LIGHT_MIN_Z` are left out: a light from behind the head shows the camera no skin).
LIGHT_CANDIDATES = 400
#: Smallest camera-space z of a candidate light direction.
LIGHT_MIN_Z = -0.3
#: Texels the directional fit uses at most (evenly spaced over the reliably seen skin).
LIGHT_FIT_TEXELS = 20000
#: Shadow-map pixel size at the mesh, mm (:func:`facegeo.uv.light_visibility`).
SHADOW_MAP_MM = 1.0
#: The shadow map's visibility is blurred over this many mm of surface (σ): the fitted mesh is
#: only near the true one, and a hard shadow edge of the wrong shape would be drawn into the albedo.
SHADOW_SOFTNESS_MM = 3.0
#: (trusted, not trusted): a seen texel's de-lit log-albedo error if the estimated shading were
#: misplaced by :data:`SHADOW_SOFTNESS_MM` on the surface; between the two its reliability falls
#: to 0 (:meth:`DefaultBackend._shading_confidence`: shadow edges, a hard light's terminator).
#: bench_albedo_scans, hard side views of both scans: seen ΔE2000 on Lee Perry-Smith +40°
#: 3.13 -> 2.90, off-skin 3.26 -> 2.68 %; filled, Lee Perry-Smith 0° 4.47 -> 4.26, James −40°
#: 12.55 -> 12.10; the other hard views within 0.13.
SHADING_ERROR = (0.1, 0.4)
#: (grazing, facing) largest de-lighting gains (as :data:`GRAZING_GAIN`, :data:`MAX_GAIN`) where
#: the directional light model is used: it is a physical model, and the shadowed side of a face
#: under a hard light is 5–15× darker than the lit side (bench_albedo_scans, hard side 0°: seen
#: ΔE2000 7.45 with (8, 16), 7.84 with (8, 8), 9.33 with (4, 4)).
LIGHT_GAIN = (8.0, 16.0)
#: Log-luminance dips (local vs neighbourhood) shallower than this are albedo, deeper ones shadow.
SHADOW_TOLERANCE = 0.15
#: Under the directional light model, dips of the de-lit luminance count as shadow only within
#: about this many mm of a cast shadow's edge (where the fitted mesh misplaces it); elsewhere they
#: are albedo (a beard). bench_albedo_scans: James hard side 0° seen ΔE2000 7.49 → 7.12, Lee
#: Perry-Smith hard +40° filled 5.34 → 5.07 and off-skin 2.46 → 2.07 %. The terminator too (within 6
#: mm of any steep shading) did more there (2.87 → 2.75 seen, 1.26 % off-skin) but took James's
#: stubble at the face's sides for shadow where his scan's baked light reads as a frontal one.
#: Under an even light, a dip is bounded by the posed mesh's lowest sky visibility within this
#: distance (:meth:`DefaultBackend._occlusion_floor`): James even 0° seen ΔE2000 2.00 → 1.80,
#: filled 10.21 → 9.69, gradient ratio 0.789 → 0.812 (his beard had been taken for shadow); Lee
#: Perry-Smith's even views within 0.02.
SHADOW_EDGE_MM = 6.0
#: How far (log) the directional light model's ambient term may be off: it is the fit's least
#: constrained part (a hard light's shadowed side is mostly left out by the skin mask, and what is
#: left of it is grazing or occluded); on bench_albedo_scans' hard side light it came out 2–10× the
#: render's. A seen texel's de-lit log-albedo is off by its ambient share of the shading times that.
AMBIENT_LOG_ERROR = 0.7
#: The de-lit error (log) at which a seen texel's weight as the fill's data is halved: under the
#: directional model the fill's base weights each texel by 1 / (1 + (strength · ambient share ·
#: :data:`AMBIENT_LOG_ERROR` / this)²), so that the filled skin takes its tone from the lit skin, not
#: from the shadowed fringe the skin mask left in. bench_albedo_scans, filled ΔE2000 of the hard side
#: views 0° / −40° / +40°: Lee Perry-Smith 4.58 / 4.54 / 4.21 -> 4.15 / 3.72 / 4.04; James (whose
#: colour map has the scanner's light baked in: his shadowed fringe is darker in the truth too)
#: 10.74 / 11.98 / 7.92 -> 11.36 / 11.48 / 7.92; seen skin within 0.1. A ratio of 4 or 8 in place
#: of 7: Lee Perry-Smith 4.26 / 3.54 / 4.18 and 4.14 / 3.79 / 3.99.
FILL_TONE_TOLERANCE = 0.1
#: (trusted, not trusted): the RMS left–right difference of the seen skin's de-lit log colour
#: (Gaussian σ = S/64 texels, ~6 mm at 1K; over the skin seen reliably on both sides) up to which
#: the hidden side takes the mirror's tone as the fill's data, and from which it does not
#: (smoothstep between). A face's own asymmetry is below the first; a side still lit or shadowed
#: after de-lighting, or a colour map with the scanner's light baked in, above the second.
#: bench_albedo_scans (even and hard side views): Lee Perry-Smith 0.05–0.10, James 0.19–0.42.
MIRROR_ASYMMETRY = (0.06, 0.15)
#: The share of the S × S texels that must be seen reliably on both sides to judge the symmetry.
MIRROR_OVERLAP = 1.0 / 1024.0
#: (start, full): a texel is a highlight where its de-lit luminance exceeds its neighbourhood's by these ratios.
HIGHLIGHT_RATIO = (1.3, 1.6)
#: A highlight's neighbourhood is the reliable skin's where that skin has at least this share of
#: the neighbourhood's Gaussian weight, else the seen texels' around it. (Without it, seen texels
#: beyond the Gaussian's reach of the reliable skin, ~3σ = 24 mm at 1K, had a neighbourhood mean
#: of 0 and were all highlights: filled, and glossier in the specular map.)
HIGHLIGHT_REFERENCE_SUPPORT = 0.01
#: A highlight at the photo's scale is a patch: a texel is one by its luminance alone where its
#: neighbourhood within this σ (mm of surface) is as bright (that patch's evidence reaching 2σ
#: over its rim, which the blur darkens); a brighter texel on a narrower spot is one only as far
#: as it is whiter than its neighbourhood (:data:`HIGHLIGHT_WHITE_SHARE`). The skin between a
#: beard's or stubble's hairs is 1.8–2 × a neighbourhood mean that the hairs drag down and no
#: whiter than it: it was filled, smooth holes in the stubble. bench_albedo_scans, James's nine
#: even, warm and hard side views: gradient ratio +0.004–0.017 (even −40° 0.768 → 0.776), seen
#: ΔE2000 −0.14 … +0.07 (even 0° 1.76 → 1.62); Lee Perry-Smith (no beard) unchanged. At 2.5 mm
#: James even −40° 0.783, at 1.0 mm 0.775; without the rim's reach the highlights' rims stayed
#: (pale-pink smears by Breaking Bad's mouth), and at 4 mm without it a lower lip's wet shine
#: under warm light (``obama2.jpg``: the specular is the light's colour, not white).
HIGHLIGHT_PATCH_MM = 1.5
#: (start, full): the share of a texel's luminance excess over its neighbourhood that a white
#: component explains (the dichromatic model: a specular reflection adds the light's colour, white
#: under a neutral light) at which a bright spot narrower than :data:`HIGHLIGHT_PATCH_MM` starts to
#: be, and is wholly, a highlight. James's flagged beard texels explain none (their saturation
#: −0.006 … −0.016 against the neighbourhood; a white specular of that strength takes ~0.2).
HIGHLIGHT_WHITE_SHARE = (0.2, 0.5)
#: A photo texel with a channel at or above this sRGB level is clipped (the sensor's or the grade's
#: ceiling): its brightness and chroma are lower bounds, not measurements, and it is left out of
#: the light fits (and of the sheen's and the fringe's reference skin). bench_albedo_scans' hard
#: side light clips 37 % and 13 % of Lee Perry-Smith's seen skin at 0° and +40°: seen ΔE2000 2.44 →
#: 2.18 and 3.02 → 2.69 (0.98 → 0.87 of the flat colour's), filled +0.1. Its de-lit value is kept
#: as the albedo there: filled instead, 0° went to 3.51 (the fill is further off than a value a
#: little under the truth). 240 / 255: 2.28 and 2.90. With the clipped channel (red) restored
#: from the others (:func:`restore_clipped`): 0° 2.18 → 1.89, off-skin 0.30 → 0.00 %, filled +0.09.
CLIPPED_LEVEL = 250.0 / 255.0
#: Seen skin this close (mm of surface) to a texel not seen whose de-lit colour is beyond the
#: :data:`FRINGE_SIGNIFICANCE` χ² quantile of the reliably seen skin's is an occluder's fringe
#: (hair strands, a frame's rim, background at the silhouette that the photo's mask let through)
#: and is treated as unseen. bench_albedo_scans: off-skin texels of James even −40° (a
#: sideburn's edge) 5.35 → 1.17 %, Lee Perry-Smith hard side +40°'s seam 1.44 → 0.86.
FRINGE_MM = 4.0
#: The probability of the χ² quantile (3 degrees of freedom) beyond which a colour is not skin's.
FRINGE_SIGNIFICANCE = 0.999
#: Texels of reliably seen skin the fringe's colour Gaussian is fitted to, at most (evenly spaced;
#: a 3 × 3 covariance needs far fewer, and 65536 cost 36 ms).
FRINGE_SAMPLES = 16384
#: Displacement in mm per unit of high-frequency log-luminance detail (dark = deeper), clipped to
#: ±DETAIL_LIMIT_MM: skin detail of 3 % contrast (the typical σ of a photo's fine skin detail) is
#: 0.03 mm of relief, a crease that darkens the skin by a quarter 0.29 mm (pores are 0.05–0.1 mm
#: deep, fine wrinkles 0.1–0.3 mm). The issue's old gain (0.5 mm, ±0.5 mm) changed a Blender
#: render by 0.6/255 on average.
DETAIL_DEPTH_MM = 1.0
#: Largest displacement either way (mm).
DETAIL_LIMIT_MM = 0.3
#: Weight of the edge Laplacian in the screened Poisson fill (vertex data terms have weight ≤ 1).
FILL_SMOOTHNESS = 2.0
#: (start, full): the reliability of a seen texel rises from 0 to 1 as its camera-space normal's z
#: goes from the first value to the second (foreshortened, resampled texels are trusted less).
FORESHORTENING = (0.1, 0.4)
#: The reliability rises over this many mm of surface from the nearest unseen texel.
EDGE_MM = 4.0
#: The seen texels' own fine detail is used from this many mm inside the seen region (nearer its
#: edge, the mirror's or noise: the edge's texels carry lashes, frame shadows, highlight halos).
DETAIL_EDGE_MM = 2.0
#: A seen texel's own fine detail (the fill's D_own, mirrored to the other side) is its band finer
#: than this fraction of S (8 texels, ~3 mm at 1K: pores, stubble, fine wrinkles).
OWN_DETAIL_COARSEST = 1.0 / 128.0
#: A seen texel's own band from its fine detail (:data:`OWN_DETAIL_COARSEST`) up to this fraction
#: of S (16 texels, ~6 mm at 1K: mottling, small wrinkles) replaces the fill base's wherever its
#: colour is trusted (kept weight × shading confidence, from :data:`DETAIL_EDGE_MM` inside the seen
#: region), instead of fading into that smooth base with the reliability's foreshortening and edge ramps: the seen
#: skin with reliability ≤ 0.95 (a third of it on James even −40°: highlight holes, the far
#: cheek) had 0.70 of the scan's gradient there, its de-lit photo 1.02. bench_albedo_scans (12 even
#: and hard side views): James's gradient ratio 0.76–0.88 → 0.77–0.89 (hard side 0° 0.797 → 0.805),
#: seen ΔE2000 −0.04 … +0.01, filled within ±0.02; Lee Perry-Smith's gradient +0.01, seam ratio
#: at most 1.10. Seen skin at 50 % reliability from foreshortening alone keeps 0.94 of its
#: mottling instead of 0.73 (the test's hemisphere). At S/32 (an earlier form, without the base's
#: band taken out): Lee Perry-Smith's seam ratio up to 1.27.
OWN_MID_BAND_COARSEST = 1.0 / 64.0
#: Side of the blocks of seen skin detail that the fill's detail is quilted from, as a fraction of
#: S (16 texels, ~6 mm at 1K: a few pores). bench_albedo_scans, the filled skin's gradient ratio
#: over the even and hard views: 0.29–0.43 with value noise, 0.41–0.53 with these blocks of the
#: finest band; blocks of S/32 with the fill's whole detail band (~3 mm) reached 0.56–0.66 but
#: drew waves of copied wrinkles over Grace Hopper's scalp.
QUILT_BLOCK = 1.0 / 64.0
#: A block of seen skin is quilted from only where its detail's mean square is at most this × the
#: median block's of its neighbourhood (:data:`QUILT_NEIGHBOURHOOD`): a mole, a lash, a speck or a
#: wrinkle copied over the scalp shows as a repeated mark (the contact sheet's astronaut and Grace
#: Hopper); bench_albedo_scans' gradient ratio loses 0.03 to it.
QUILT_ENERGY_CAP = 2.5
#: The fill's blocks come from the seen skin near the block's nearest seen place: a place drawn
#: uniformly within half this fraction of S (32 texels, ~10 mm at 1K) of it, and a block is too
#: busy by the median of its square of this side (64 texels; one with fewer places than a block
#: has texels: by the whole source's). A stubbled jaw goes on under the chin and a smooth forehead
#: onto the scalp; with blocks from anywhere on the face, James's fill (a full beard) was as calm
#: as his cheeks. bench_albedo_scans, even and hard views: James's gradient ratio 0.75–0.86 →
#: 0.76–0.88, Lee Perry-Smith's within ±0.03, filled median 5.91 → 5.97 (benchmarks/RESULTS.md).
QUILT_NEIGHBOURHOOD = 1.0 / 16.0
#: Random points tried per radius (1×, 2× and 4× the reach) when a block's place is drawn by
#: rejection (:func:`quilted_detail`); where all miss, a place anywhere.
QUILT_TRIES = 8
#: The fill's noise octaves (:data:`MID_BAND_COARSEST`) finer than this fraction of S (8 texels,
#: ~3 mm at 1K: the skin's grain) get the seen skin's whole covariance, less what the quilted blocks
#: already carry there; the coarser ones :data:`MID_BAND_STRENGTH` of it. With all at 0.35 the
#: filled skin had 0.4 of the seen skin's octave RMS at σ 2–4 and 4–8 texels, now 0.6 (Lee
#: Perry-Smith even 0°; the blocks, zero-mean under a 16-texel window, carry little of σ 2–4).
#: bench_albedo_scans, even and hard side views: gradient ratio 0.65–0.80 → 0.72–0.84 (James,
#: whose unseen scan is beard and hairline), 0.78–1.08 → 0.90–1.14 (Lee Perry-Smith); filled
#: ΔE2000 −0.11 … +0.07 per view.
GRAIN_COARSEST = 1.0 / 128.0
#: Coarsest octave of the fill's synthesised noise (:func:`band_noise`), as a fraction of S (32
#: texels, ~12 mm at 1K): from the quilted band's edge up to this, the fill gets noise in octaves
#: with the seen skin's colour covariance per octave, the grain and mottling that real skin has.
MID_BAND_COARSEST = 1.0 / 32.0
#: The fill's noise has this fraction of the seen skin's covariance in each octave coarser than
#: :data:`GRAIN_COARSEST`: on a photo the seen skin's octaves hold shading residue and features
#: besides its mottling, and at 1.0 the contact sheet's astronaut got soft cm-wide blotches over
#: scalp and chest.
#: bench_albedo_scans (even 0°/−40°, hard side 0°/+40°; the noise then from S/256, all at this
#: share): Lee Perry-Smith's gradient ratio 0.80–1.11 at 0.35 and 0.87–1.15 at 1.0 (0.74–1.09
#: without), filled ΔE2000 +0.1–0.4 and +0.3–0.5.
MID_BAND_STRENGTH = 0.35
#: Lattice of each octave's gradient noise in :func:`band_noise`, in units of the octave's finer σ
#: (a difference of Gaussians σ–2σ peaks at a wavelength of ~6.5σ; gradient noise at ~1.5–2 cells).
NOISE_CELL_PER_SIGMA = 3.5
#: Fine detail beyond this many robust σ of the seen skin's is a mark (a mole, a speck, a lash):
#: it is not mirrored onto the other side of the face (the Lee Perry-Smith scan's cheek mole was).
SPECK_SIGMAS = 4.0
#: Padding outside the UV islands: the edge colour over this fraction of S texels (4 at 1K), then
#: the median of the map (flat).
PAD_FRACTION = 1.0 / 256.0
#: The skin's mean diffuse albedo (linear luminance) assumed to put the specular model in the
#: photo's units (:meth:`DefaultBackend._specular`): measured skin spans ~0.1 (dark) to ~0.5
#: (fair); on darker skin less than the whole sheen is removed, on the fairest ~25 % too much.
SKIN_ALBEDO = 0.4
#: The specular removal keeps at least this fraction of each texel's de-lit value.
SPECULAR_FLOOR = 0.5
#: σ (degrees) of the directional light's sheen over the angle between the normal and the half
#: vector of light and view: skin's GGX lobe (roughness 0.55, α ≈ 0.3 rad, ~17°) widened by the
#: fitted mesh's normal error (median 11–18° against a head scan's, frontal to 40° of yaw) and
#: the light's direction error. Measured at 20 / 30 / 45 on the scans' hard-light views
#: (benchmarks/RESULTS.md): within 0.06 CIEDE2000 of each other.
SUN_SHEEN_LOBE_DEG = 30.0
#: The sheen's white part is smoothed over this surface distance (mm): its estimate from one
#: texel's chroma is noisy, and a sheen varies over millimetres, not pores.
SHEEN_SMOOTH_MM = 2.0
#: Reference texels needed for the skin's diffuse colour away from the lobe.
SHEEN_REFERENCE_TEXELS = 200


def gaussian_blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur (reflected borders) of an (H, W[, C]) float32 image. Above σ = 8 texels it
    runs on a copy downsampled by a power of two (area averaging) and is upsampled bilinearly:
    the result is smooth at that scale anyway, and a direct 6σ kernel at σ = S/5 costs seconds."""
    image = np.asarray(image, np.float32)
    factor = 1
    while sigma / (factor * 2) >= 4.0 and min(image.shape[:2]) // (factor * 2) >= 8:
        factor *= 2
    if factor == 1:  # (OpenCV drops a single channel's axis: the shape is restored)
        return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REFLECT).reshape(image.shape)
    h, w = image.shape[:2]
    small = cv2.resize(image, (max(1, w // factor), max(1, h // factor)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma / factor, borderType=cv2.BORDER_REFLECT)
    out = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)
    return out.reshape(image.shape)


def masked_blur(image: np.ndarray, weight: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of ``image`` (S, S[, C]) that only averages texels with ``weight`` (S, S) >
    0: blur(w·x) / blur(w). Texels with no weighted neighbour within ~3σ get 0."""
    w = weight.astype(np.float32)
    num = gaussian_blur(image * (w[..., None] if image.ndim == 3 else w), sigma)
    den = gaussian_blur(w, sigma)
    den = np.maximum(den, 1e-6)
    return num / (den[..., None] if image.ndim == 3 else den)


#: OpenCV's exact distance transform returns float32 distances; the integer squared distance is
#: recovered from them exactly while it stays below 2^22 (float32 sqrt keeps d² within ±0.5).
_EXACT_SQUARED = float(1 << 22)


def _euclidean_distance(mask: np.ndarray) -> np.ndarray:
    """(H, W) float64 Euclidean distance from each True texel of the (H, W) bool ``mask`` to the
    nearest False one (0 on False texels), bit-identical to ``scipy.ndimage.distance_transform_edt``:
    OpenCV's exact transform (Felzenszwalb's algorithm, ``DIST_MASK_PRECISE``, several times
    faster) gives d in float32, d² is rounded back to its integer and its float64 root taken, as
    SciPy does. SciPy itself where d² could lose that integer or no texel is False."""
    if mask.all():
        return ndimage.distance_transform_edt(mask)
    distance = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
    squared = np.rint(np.square(distance, dtype=np.float64))
    if squared.max() >= _EXACT_SQUARED:
        return ndimage.distance_transform_edt(mask)
    return np.sqrt(squared)


_NEAREST_CACHE: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}


def pad_outside(image: np.ndarray, inside: np.ndarray, width: int | None = None) -> np.ndarray:
    """Pad an (S, S[, C]) map outside ``inside`` (S, S) bool: texels within ``width`` texels of
    the layout (default :data:`PAD_FRACTION` × S, at least 2) take the value of the nearest
    inside texel (bilinear sampling and the first mip levels never see the background), those
    further out one value, flat (no streaks: a neutral padding): the inside texel nearest the
    per-channel median (a real texel value, so a normal map's padding is a unit normal). The
    nearest-texel table is cached per mask (a layout pads all its maps with the same one)."""
    if inside.all() or not inside.any():
        return image
    width = max(2, int(round(inside.shape[0] * PAD_FRACTION))) if width is None else int(width)
    key = hashlib.blake2b(np.packbits(inside).tobytes() + str(inside.shape).encode() + str(width).encode(),
                          digest_size=16).digest()
    if key not in _NEAREST_CACHE:
        if len(_NEAREST_CACHE) >= 4:
            _NEAREST_CACHE.clear()
        distance, (rows, cols) = ndimage.distance_transform_edt(~inside, return_indices=True)
        near = np.flatnonzero(~inside.ravel() & (distance.ravel() <= width))
        source = (rows.ravel()[near] * inside.shape[1] + cols.ravel()[near]).astype(np.int64)
        far = np.flatnonzero(distance.ravel() > width)
        _NEAREST_CACHE[key] = (near, source, far, np.flatnonzero(inside.ravel())[::7])
    near, source, far, sample = _NEAREST_CACHE[key]
    flat_view = image.reshape(inside.size, -1)
    out = flat_view.copy()
    out[near] = flat_view[source]
    values = flat_view[sample]  # a seventh of the inside texels: the median within rounding
    middle = values[np.argmin(np.abs(values - np.median(values, axis=0)).sum(axis=1))]
    out[far] = middle  # the texel nearest the median: a real value (a unit normal stays unit)
    return out.reshape(image.shape)


#: Points per block of the lattice noises (their temporaries stay in the CPU cache).
_NOISE_BLOCK = 16384
#: Perlin's 12 gradient directions (the cube's edge midpoints).
_GRADIENTS = np.array([[1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0], [1, 0, 1], [-1, 0, 1],
                       [1, 0, -1], [-1, 0, -1], [0, 1, 1], [0, -1, 1], [0, 1, -1], [0, -1, -1]], np.float32).T.copy()  # (3, 12)


def value_noise(position_mm: np.ndarray, cell_mm: float, seed: int = 0) -> np.ndarray:
    """3-D value noise (trilinear interpolation of hashed lattice values in [−1, 1], smoothstep
    weights) at (N, 3) points in mm on a lattice of ``cell_mm``: (N,) float32. A function of
    the surface position, so it is continuous across UV seams."""
    return _lattice_noise(position_mm, cell_mm, (seed,), gradient=False)[:, 0]


def gradient_noise(position_mm: np.ndarray, cell_mm: float, seed: int | tuple[int, ...] = 0) -> np.ndarray:
    """3-D gradient (Perlin) noise at (N, 3) points in mm on a lattice of ``cell_mm``: (N,)
    float32, 0 at the lattice points, with most of its power at wavelengths of one to four cells
    (on a plane through it ~86 %, where value noise has ~30 % beyond: octaves of it are
    band-limited without any filtering), isotropic on the surface and continuous across UV seams.
    A tuple of seeds gives (N, len(seed)), one independent noise per seed (each the same as for
    that seed alone; the lattice's coordinates and weights are computed once)."""
    if isinstance(seed, tuple):
        return _lattice_noise(position_mm, cell_mm, seed, gradient=True)
    return _lattice_noise(position_mm, cell_mm, (seed,), gradient=True)[:, 0]


def _lattice_noise(position_mm: np.ndarray, cell_mm: float, seeds: tuple[int, ...], gradient: bool) -> np.ndarray:
    """(N, len(seeds)) float32: :func:`value_noise` or :func:`gradient_noise` for each seed."""
    g = position_mm.astype(np.float32) / np.float32(cell_mm)
    out = np.empty((len(g), len(seeds)), np.float32)
    for start in range(0, len(g), _NOISE_BLOCK):
        out[start:start + _NOISE_BLOCK] = _lattice_noise_block(g[start:start + _NOISE_BLOCK], seeds, gradient)
    return out


def _lattice_noise_block(g: np.ndarray, seeds: tuple[int, ...], gradient: bool) -> np.ndarray:
    """(n, len(seeds)): :func:`value_noise` or :func:`gradient_noise` of (n, 3) float32 lattice coordinates."""
    base = np.floor(g)
    f = g - base
    fade = f * f * f * (f * (6 * f - 15) + 10) if gradient else f * f * (3 - 2 * f)  # Perlin's quintic; smoothstep
    base = base.astype(np.int32)
    # per axis, the lattice point's hash term (int32, wrapping) and trilinear weight at offsets 0 and 1
    terms = [(b * k, (b + 1) * k) for b, k in zip(base.T, (73856093, 19349663, 83492791))]
    weights = [(1 - fade[:, axis], fade[:, axis]) for axis in range(3)]
    offsets = [(f[:, axis], f[:, axis] - 1) for axis in range(3)]  # the offset from the corner at 0 and 1
    out = np.zeros((len(g), len(seeds)), np.float32)
    for corner in range(8):
        o = ((corner >> 2) & 1, (corner >> 1) & 1, corner & 1)
        weight = weights[0][o[0]] * weights[1][o[1]] * weights[2][o[2]]
        lattice = terms[0][o[0]] ^ terms[1][o[1]] ^ terms[2][o[2]]
        for i, seed in enumerate(seeds):
            # integer hash of the lattice point (a xorshift-multiply mix)
            h = lattice ^ (seed * 2654435)
            h = (h ^ (h >> 13)) * 1274126177
            h = h ^ (h >> 16)
            if gradient:  # the corner's gradient · the offset from the corner
                pick = ((h & 0xFFFF) * 12) >> 16
                value = _GRADIENTS[0][pick] * offsets[0][o[0]] + _GRADIENTS[1][pick] * offsets[1][o[1]] + _GRADIENTS[2][pick] * offsets[2][o[2]]
            else:  # the corner's value in [−1, 1]
                value = (h & 0xFFFF).astype(np.float32) * np.float32(2.0 / 65535.0) - 1.0
            out[:, i] += weight * value
    return out


def _subsample(rows: np.ndarray, limit: int = 65536) -> np.ndarray:
    """At most ``limit`` evenly spaced entries of ``rows`` (the light fits' least squares of a
    few coefficients and the fringe's 3 × 3 colour covariance need no more)."""
    return rows if len(rows) <= limit else rows[:: int(np.ceil(len(rows) / limit))]


def _clipped_ceiling() -> np.float32:
    """The linear value of :data:`CLIPPED_LEVEL`: a channel at or above it is clipped."""
    return srgb_to_linear(np.float32(CLIPPED_LEVEL))


def _area_mean(image: np.ndarray, weight: np.ndarray, grid: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``image`` (H, W, C) float32 averaged over ``weight`` (H, W) onto ``grid`` (OpenCV's area
    resampling), and the weight's own average (grid)."""
    w = cv2.resize(weight.astype(np.float32), grid, interpolation=cv2.INTER_AREA)
    x = cv2.resize(image * weight[..., None], grid, interpolation=cv2.INTER_AREA) / np.maximum(w, 1e-6)[..., None]
    return x, w


def _without_specular(delit: np.ndarray, specular: np.ndarray) -> np.ndarray:
    """``delit`` (S, S[, 3]) less ``specular`` (broadcasting; white), keeping at least
    :data:`SPECULAR_FLOOR` of each value."""
    return np.maximum(delit - specular, SPECULAR_FLOOR * delit).astype(np.float32)


def _smoothstep(t: np.ndarray) -> np.ndarray:
    """3t² − 2t³ of t clipped to [0, 1] (float32)."""
    t = np.clip(t, 0.0, 1.0).astype(np.float32)
    return t * t * (3 - 2 * t)


def _mix_keeping_contrast(a: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """(a · x + (1 − a) · y) / √(a² + (1 − a)²) for weights ``a`` in [0, 1] and zero-mean detail
    layers ``x``, ``y`` (broadcast): two independent layers mixed linearly keep only a² + (1 − a)²
    of their variance (half at a = ½), so this keeps their contrast where the mix changes."""
    return (a * x + (1 - a) * y) / np.sqrt(a * a + (1 - a) ** 2)


def _skin(ctx: TextureContext) -> np.ndarray:
    return ctx.coverage if ctx.skin is None else ctx.coverage & (ctx.skin > 0.5)


def _mirror_index(ctx: TextureContext) -> tuple[np.ndarray, np.ndarray]:
    """(S, S) bool: the covered texels that have a mirror texel; (S, S) intp: its flat index into
    an (S·S, …) view (0 where none), so that one gather mirrors a map."""
    has = (ctx.mirror[..., 0] >= 0) & ctx.coverage
    return has, np.where(has, ctx.mirror[..., 0].astype(np.intp) * ctx.size + ctx.mirror[..., 1], 0)


def _push_pull(values: np.ndarray, weight: np.ndarray, size: int, finest: float, mean: np.ndarray) -> np.ndarray:
    """UV-space extrapolation of (S, S, C) ``values`` known with ``weight``: ``mean`` (C,), then
    masked blurs from S/2 texels down to ``finest`` by factors of 4, each finer level kept where
    it has support."""
    out = np.broadcast_to(np.asarray(mean, np.float32), values.shape)
    sigmas = [size / 2.0]
    while sigmas[-1] / 4 >= max(finest, 0.5):
        sigmas.append(sigmas[-1] / 4)
    for sigma in sigmas:
        blurred = masked_blur(values, weight, sigma)
        support = np.clip(gaussian_blur(weight, sigma) * 4.0, 0.0, 1.0)[..., None]
        out = support * blurred + (1 - support) * out
    return out


def restore_clipped(lin: np.ndarray, valid: np.ndarray, size: int) -> np.ndarray:
    """(S, S, 3) linear RGB ``lin`` with each clipped channel (at or above :data:`CLIPPED_LEVEL`)
    raised to what the texel's unclipped channels imply under the local colour ratios of the
    unclipped ``valid`` (S, S) bool texels (their mean colour on a grid 4× coarser, in log RGB
    extended by :func:`_push_pull` down to S/128 texels: a clipped cheek takes the chroma of the
    skin around it), never lowered; texels with every channel clipped, and a map without
    unclipped valid texels, are left as they are. (As a raw converter's highlight reconstruction
    by colour propagation; no library here does it.)"""
    clipped = lin >= _clipped_ceiling()
    count = channel_sum(clipped.view(np.uint8))
    rows, cols = np.nonzero((count > 0) & (count < 3))
    free = valid & (count == 0)
    if len(rows) == 0 or free.sum() < 10:
        return lin
    grid = (max(1, size // 4), max(1, size // 4))
    local, weight = _area_mean(lin, free, grid)
    log_local = np.log(np.maximum(local, 1e-4))
    mean = np.log(np.maximum(lin[free].mean(axis=0), 1e-4))
    ref = cv2.resize(_push_pull(log_local, weight, grid[0], grid[0] / 128.0, mean), (lin.shape[1], lin.shape[0]),
                     interpolation=cv2.INTER_LINEAR)[rows, cols]
    # the reference's level moved onto the texel's unclipped channels (the mean log offset over them)
    value, cut = lin[rows, cols], clipped[rows, cols]
    offset = np.where(cut, 0.0, np.log(np.maximum(value, 1e-4)) - ref).sum(axis=-1, keepdims=True) / (~cut).sum(axis=-1, keepdims=True)
    out = lin.copy()
    out[rows, cols] = np.where(cut, np.maximum(value, np.exp(ref + offset)), value)
    return out


def white_share(texture: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(...) float32 in [0, 1]: the share of each texel's luminance excess over ``reference``
    (..., 3) linear RGB (its neighbourhood's colour) that a white component explains, by the
    dichromatic model: ``texture`` (..., 3) linear RGB = k · reference + s · (1, 1, 1), k and s by
    least squares over the three channels; the share is s over (luminance(texture) −
    luminance(reference)) (0 where the texel is not brighter). A brighter skin colour gives 0, a
    specular reflection of a white light 1."""
    rr, rt = np.einsum("...k,...k->...", reference, reference), np.einsum("...k,...k->...", reference, texture)
    r1, t1 = channel_sum(reference), channel_sum(texture)
    s = (rr * t1 - r1 * rt) / np.maximum(3.0 * rr - r1 * r1, 1e-12)  # Cramer's rule on the 2 × 2 normal equations
    excess = np.maximum(luminance(texture) - luminance(reference), 1e-6)
    return np.clip(s / excess, 0.0, 1.0).astype(np.float32)


def without_sun_sheen(delit: np.ndarray, lobe: np.ndarray, seen: np.ndarray, reference: np.ndarray, smooth: float) -> np.ndarray:
    """(S, S, 3) de-lit, white-balanced linear RGB ``delit`` with a directional light's sheen
    taken out of the ``seen`` (S, S) bool texels, in proportion to ``lobe`` (S, S) in [0, 1]
    (how much of the light's mirror reflection a texel may show).

    The dichromatic model: a texel is k · c + w · (1, 1, 1), c the skin's diffuse colour (the
    median of the ``reference`` (S, S) bool texels outside the lobe, lobe < 0.5, or of all of
    them when fewer than :data:`SHEEN_REFERENCE_TEXELS` are outside), w ≥ 0 the white of the
    sheen (least squares per texel; a texel more saturated than c has none). w is smoothed over
    ``smooth`` texels (masked Gaussian σ) and kept under 0.9 of the texel's smallest channel
    (what remains is never negative and keeps some of its own colour); lobe · w is subtracted.
    Returns ``delit`` itself when there are too few reference texels, or when their colour is
    grey (within 1 % of white's direction: no chroma to tell the sheen by)."""
    rows = reference & (lobe < 0.5)
    if rows.sum() < SHEEN_REFERENCE_TEXELS:
        rows = reference
    if rows.sum() < SHEEN_REFERENCE_TEXELS:
        return delit
    diffuse = np.median(delit.reshape(-1, 3)[_subsample(np.flatnonzero(rows.ravel()))], axis=0).astype(np.float64)
    if diffuse.sum() / max(np.sqrt(3.0) * float(np.linalg.norm(diffuse)), 1e-12) > 0.9999:  # cos(diffuse, white)
        return delit
    basis = np.stack([diffuse, np.ones(3)], axis=1)  # (3, 2): the diffuse colour and white
    white_of = (basis @ np.linalg.inv(basis.T @ basis))[:, 1].astype(np.float32)  # least squares: the white coefficient
    white = np.maximum(delit @ white_of, 0.0)
    white = np.minimum(masked_blur(white, seen, smooth), 0.9 * channel_min(delit))
    return np.where(seen[..., None], delit - (lobe * white)[..., None], delit).astype(np.float32)


def quilted_detail(detail: np.ndarray, source: np.ndarray, need: np.ndarray, seed: int = 0) -> np.ndarray | None:
    """Detail (S, S, C) float32 over ``need`` (S, S) bool, made of blocks of ``detail`` (S, S, C)
    copied from places wholly inside ``source`` (S, S) bool and no busier than
    :data:`QUILT_ENERGY_CAP` × the median place of their neighbourhood: blocks of
    :data:`QUILT_BLOCK` × S texels on a half-overlapping grid, each from a place drawn uniformly
    within :data:`QUILT_NEIGHBOURHOOD` × S / 2 texels of the place nearest to it (so the copy has
    the texture of the source next to it), made zero-mean under its separable Hann window and
    blended with variance-preserving weights Σ w·x / √(Σ w²), so the copy keeps the source's
    contrast at every scale finer than a block and no block edge shows.
    Deterministic for a given ``seed``. 0 outside ``need``; None where ``source`` holds no whole
    block. (By hand: OpenCV's and scikit-image's inpainting diffuse or copy whole regions; none
    synthesises a stationary detail layer by example.)"""
    size = detail.shape[0]
    half = max(4, round(QUILT_BLOCK * size / 2))
    block = 2 * half
    if size < block:
        return None
    inside = cv2.erode(source.astype(np.uint8), np.ones((block, block), np.uint8), anchor=(0, 0),
                       borderType=cv2.BORDER_CONSTANT, borderValue=0)[: size - block + 1, : size - block + 1]
    starts = np.argwhere(inside > 0)
    if len(starts) == 0:
        return None
    energy = cv2.boxFilter(np.einsum("...k,...k->...", detail, detail).astype(np.float32), -1, (block, block), anchor=(0, 0),
                           borderType=cv2.BORDER_CONSTANT)[starts[:, 0], starts[:, 1]]  # mean square over each block
    # too busy by the median of the square of side QUILT_NEIGHBOURHOOD × S that a place starts in
    side = max(block, round(QUILT_NEIGHBOURHOOD * size))
    square = (starts[:, 0] // side) * (size // side + 1) + starts[:, 1] // side
    order = np.argsort(square, kind="stable")
    _, first, counts = np.unique(square[order], return_index=True, return_counts=True)
    median = np.array([np.median(energy[order[a: a + n]]) if n >= block * block else np.nan for a, n in zip(first, counts)])
    limit = np.empty(len(starts))
    limit[order] = np.repeat(np.where(np.isnan(median), np.median(energy), median), counts)
    starts = starts[energy <= QUILT_ENERGY_CAP * limit]
    # each texel's nearest place (its block's centre), in the order of ``starts`` (row-major, as
    # OpenCV numbers the zero pixels)
    centres = np.ones((size, size), np.uint8)
    centres[starts[:, 0] + half, starts[:, 1] + half] = 0
    _, nearest = cv2.distanceTransformWithLabels(centres, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    nearest -= 1
    reach = QUILT_NEIGHBOURHOOD * size / 2
    ramp = np.sin(np.pi * (np.arange(block) + 0.5) / block) ** 2  # Hann: two at half overlap sum to 1
    window = (ramp[:, None] * ramp[None, :]).astype(np.float32)
    channels = detail.shape[2]
    # a canvas (channels first) padded by a block on each side; block (i, j) covers image rows (i − 1)·half … (i + 1)·half
    cells = size // half + 3
    canvas = np.zeros((channels, cells * half + block, cells * half + block), np.float32)
    weight = np.zeros(canvas.shape[1:], np.float32)
    # which half × half cells hold a texel to fill (cell k: image rows k·half …; −1 and past the end: none)
    padded = np.zeros(((cells + 1) * half, (cells + 1) * half), bool)
    padded[:size, :size] = need
    cell_need = padded.reshape(cells + 1, half, cells + 1, half).any(axis=(1, 3))
    cell_need[-1, :] = cell_need[:, -1] = False  # index −1 (the cell before row 0) is empty
    # every block of the detail (channels first, so that the gathered patches are contiguous), a view
    windows = np.lib.stride_tricks.sliding_window_view(np.ascontiguousarray(detail.transpose(2, 0, 1)), (block, block), axis=(1, 2))
    mean_weights = (window / window.sum()).reshape(-1)
    rng = np.random.default_rng(seed)
    offset = block - half  # image row 0 is canvas row `block`, so block i starts at canvas row offset + i·half
    for pr in (0, 1):  # four phases of the half-overlapping grid, each a tiling of disjoint blocks
        for pc in (0, 1):
            rows, cols = np.arange(pr, cells, 2), np.arange(pc, cells, 2)
            ii, jj = np.meshgrid(rows, cols, indexing="ij")
            touch = cell_need[ii - 1, jj - 1] | cell_need[ii - 1, jj] | cell_need[ii, jj - 1] | cell_need[ii, jj]
            if not touch.any():
                continue
            # a place at a random point within ``reach`` of the place nearest to the block's centre:
            # uniform over the places there, by rejection (snapping a point that misses to the
            # nearest place would copy the few places on the region's rim over and over: a brick
            # pattern); where QUILT_TRIES points miss, within twice and four times ``reach``,
            # then anywhere
            bi, bj = np.nonzero(touch)
            near = starts[nearest[np.clip(rows[bi] * half, 0, size - 1), np.clip(cols[bj] * half, 0, size - 1)]] + half
            scale = reach * np.repeat([1.0, 2.0, 4.0], QUILT_TRIES)[:, None]
            angle, radius = rng.uniform(0, 2 * np.pi, scale.shape[0:1] + bi.shape), scale * np.sqrt(rng.random(scale.shape[0:1] + bi.shape))
            point = np.rint(near + radius[..., None] * np.stack([np.sin(angle), np.cos(angle)], -1)).astype(int)
            on_map = np.all((point >= 0) & (point < size), axis=-1)
            point = np.clip(point, 0, size - 1)
            hit = on_map & (centres[point[..., 0], point[..., 1]] == 0)
            chosen = nearest[point[..., 0], point[..., 1]][hit.argmax(0), np.arange(len(bi))]
            pick = starts[np.where(hit.any(0), chosen, rng.integers(len(starts), size=len(bi)))]
            patches = windows[:, pick[:, 0], pick[:, 1]]  # (C, n, block, block), a copy
            patches -= (patches.reshape(channels, len(pick), -1) @ mean_weights)[:, :, None, None]  # zero mean under the window
            patches *= window
            r0, c0 = offset + pr * half, offset + pc * half
            h, w = len(rows) * block, len(cols) * block
            tiling = canvas[:, r0: r0 + h, c0: c0 + w].reshape(channels, len(rows), block, len(cols), block).transpose(0, 1, 3, 2, 4)
            tiling[:, touch] += patches  # (a view of the canvas: C, rows, cols, block, block)
            weight[r0: r0 + h, c0: c0 + w] += np.kron(touch.astype(np.float32), window * window)
    inner = (slice(block, block + size), slice(block, block + size))
    out = (canvas[:, inner[0], inner[1]] / np.sqrt(np.maximum(weight[inner], 1e-6))).transpose(1, 2, 0)
    return np.where(need[..., None], out, 0.0).astype(np.float32)


def nonnegative_least_squares(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ‖a x − b‖ over x ≥ 0 for a small (m, n) ``a`` (n ≤ 8) and (m,) ``b``: (n,) float64.
    The optimum is the unconstrained least-squares solution on its own positive set, so the best
    feasible one over all 2ⁿ − 1 column sets is it. (By hand: scipy.optimize.nnls costs ~0.2 s of
    import in ``facegeo reconstruct``, for systems of three unknowns.)"""
    n = a.shape[1]
    if n > 8:
        raise ValueError(f"nonnegative_least_squares: expected at most 8 unknowns, got {n}")
    best, best_residual = np.zeros(n), float(b @ b)
    for subset in range(1, 1 << n):
        columns = [j for j in range(n) if subset >> j & 1]
        x = np.linalg.lstsq(a[:, columns], b, rcond=None)[0]
        if np.all(x >= 0):
            residual = float(np.sum((a[:, columns] @ x - b) ** 2))
            if residual < best_residual:
                best, best_residual = np.zeros(n), residual
                best[columns] = x
    return best


def band_noise(log_rgb: np.ndarray, source: np.ndarray, need: np.ndarray, position_mm: np.ndarray, cover: np.ndarray,
               outside: np.ndarray, finest: float, coarsest: float, texel_mm: float, strength: float = 1.0,
               whole_below: float = 0.0, present: np.ndarray | None = None, seed: int = 0) -> np.ndarray:
    """Colour noise (S, S, 3) float32 over ``need`` (S, S) bool with ``strength`` × the octave
    statistics of ``log_rgb`` (S, S, 3) on ``source`` (S, S) bool (the whole statistics in the
    octaves whose finer σ is below ``whole_below`` texels): for each octave of Gaussian σ
    from ``finest`` to ``coarsest`` texels (differences of Gaussians), the 3 × 3 covariance over
    the source's places whose local energy in that octave is at most :data:`QUILT_ENERGY_CAP` ×
    the median place's (the skin's mottling, not a fold, a shadow's edge or a hairline). The noise
    is a sum of independent layers, one per octave: 3-D gradient noise of the surface position
    ``position_mm`` (S, S, 3) in mm on ``cover`` (S, S) bool (:func:`gradient_noise`, a lattice
    of :data:`NOISE_CELL_PER_SIGMA` × σ × ``texel_mm``: band-limited by itself, so isotropic on the
    surface and continuous across UV seams, where a UV-space filter would be neither), coloured
    with its octave's covariance at the power that makes the octaves of the sum, measured as the
    source's were, closest to the source's (the layers' spectra overlap: non-negative least
    squares), each faded in over 2σ texels of ``outside`` (S, S), the distance in texels from the
    seen skin, whose octave the fill's base still holds there. Computed on a grid coarser by the
    power of two that leaves ``finest`` ≥ 2 of its texels (each layer on one as coarse as its
    lattice allows), then upsampled bilinearly. ``present`` (S, S, 3), detail already on ``need``
    (the quilted blocks), counts towards each octave: its covariance there is subtracted from the
    wanted one (the nearest covariance where that leaves a negative part), so the noise adds what
    it lacks. 0 outside ``need`` and where ``source`` has fewer than 100 texels; deterministic for
    a given ``seed``. (By hand: no library synthesises noise with a given colour covariance per
    octave on a surface.)"""
    size = log_rgb.shape[0]
    out = np.zeros(log_rgb.shape, np.float32)
    if source.sum() < 100 or not need.any():
        return out
    factor = 1
    while finest / (2 * factor) >= 2.0 and size // (2 * factor) >= 64:
        factor *= 2
    small = (size // factor, size // factor)

    log_small, source_w = _area_mean(log_rgb.astype(np.float32), source, small)
    position, cover_w = _area_mean(position_mm.astype(np.float32), cover, small)
    need_small = cv2.resize(need.astype(np.float32), small, interpolation=cv2.INTER_AREA) > 0.5
    outside_small = cv2.resize(outside.astype(np.float32), small, interpolation=cv2.INTER_AREA) / factor
    solid = source_w > 0.99
    if solid.sum() < 100 or not need_small.any():
        return out
    sigmas = [finest / factor]
    while sigmas[-1] < coarsest / factor * (1 - 1e-6):
        sigmas.append(min(2.0 * sigmas[-1], coarsest / factor))
    count = len(sigmas) - 1

    def octaves(image: np.ndarray, weight: np.ndarray) -> list[np.ndarray]:
        """``image``'s differences of Gaussians (masked by ``weight``) between consecutive ``sigmas``."""
        blurred = [masked_blur(image, weight, s) for s in sigmas]
        return [blurred[k] - blurred[k + 1] for k in range(count)]

    wanted = np.empty((count, 3, 3))  # each octave's covariance over the source's places that are not busy
    for k, band in enumerate(octaves(log_small, source_w)):
        local = masked_blur((band * band).sum(-1), solid, 2.0 * sigmas[k + 1])
        calm = solid & (local <= QUILT_ENERGY_CAP * np.median(local[solid]))
        wanted[k] = np.cov(band[calm].astype(np.float64).T)
    target = np.where(np.array(sigmas[:-1])[:, None, None] * factor < whole_below, 1.0, strength) * wanted
    if present is not None:  # the detail already there counts towards each octave: the noise adds what it lacks
        have, have_w = _area_mean(present.astype(np.float32), need, small)
        inside = have_w > 0.99
        if inside.sum() >= 100:
            for k, band in enumerate(octaves(have, have_w)):
                target[k] -= np.cov(band[inside].astype(np.float64).T)
            values, vectors = np.linalg.eigh(target)  # the nearest covariances (negative parts: more than the source's)
            target = (vectors * np.clip(values, 0.0, None)[:, None, :]) @ vectors.transpose(0, 2, 1)
    # one independent noise layer per octave (3 channels each), unit variance over ``need``
    area = cover_w > 0.5
    layers = []
    for j in range(count):  # gradient noise peaking at the octave's wavelength (~6.5σ), on a grid as coarse as it allows
        cell = NOISE_CELL_PER_SIGMA * sigmas[j]  # in texels of the small grid
        step = 1
        while cell / (2 * step) >= 4.0 and small[0] // (2 * step) >= 32:
            step *= 2
        grid = (small[0] // step, small[1] // step)
        points, covered = (position, cover_w) if step == 1 else _area_mean(position, cover_w, grid)
        flat = np.flatnonzero((covered > 0.25).ravel())
        layer = np.zeros((*grid, 3), np.float32)
        layer.reshape(-1, 3)[flat] = gradient_noise(points.reshape(-1, 3)[flat], cell * factor * texel_mm, seed=(seed + 3 * j, seed + 3 * j + 1, seed + 3 * j + 2))
        if step > 1:
            layer = cv2.resize(layer, small, interpolation=cv2.INTER_LINEAR)
        layer = np.where(area[..., None], layer, 0.0)
        layers.append(layer / np.maximum(layer[need_small].std(0), 1e-12))
    # the spectra overlap, so octave k measured on layer j holds a part V_kj of its variance
    firsts = np.stack([layer[..., 0] for layer in layers], axis=-1)  # one channel of each layer (all three alike)
    measured = octaves(firsts, area)
    leak = np.array([[float(np.var(measured[k][..., j][need_small])) for j in range(count)] for k in range(count)])
    # layer j takes octave j's colour covariance at a power t_j with Σ_j V_kj t_j ≈ octave k's
    # variance (relative least squares, t ≥ 0: a steep spectrum cannot be met exactly)
    variance = np.trace(target, axis1=1, axis2=2)
    if variance.max() <= 1e-12:  # flat seen skin, or all its octaves already there: nothing to give
        return out
    weight = 1.0 / np.maximum(variance, 1e-3 * variance.max())
    scale = nonnegative_least_squares(leak * weight[:, None], variance * weight)
    power = (scale / np.maximum(variance, 1e-12))[:, None, None] * target  # t_j × the octave's covariance of trace 1
    total = np.zeros(log_small.shape, np.float32)
    for j, (layer, p) in enumerate(zip(layers, power)):
        values, vectors = np.linalg.eigh((p + p.T) / 2)
        root = (vectors * np.sqrt(np.clip(values, 0.0, None))).astype(np.float32)  # root @ root.T = p (singular for a greyscale photo)
        ramp = _smoothstep(outside_small / (2.0 * sigmas[j]))[..., None]  # near the seen skin the fill's base still holds the octave
        total += ramp * (layer @ root.T)
    if factor > 1:
        total = cv2.resize(total, (size, size), interpolation=cv2.INTER_LINEAR)
    return np.where(need[..., None], total, 0.0).astype(np.float32)


@dataclass
class _Analysis:
    """Per-texel results of :meth:`DefaultBackend.analyse` (all (S, S) float32)."""

    shading: np.ndarray
    highlight: np.ndarray
    weight: np.ndarray  # visibility × (1 − highlight): how much of each texel is kept as seen
    specular: np.ndarray  # the skin's specular reflection in de-lit units (white after the light's colour is removed)
    greyscale: bool  # the seen texels are grey (:func:`facegeo.colour.is_greyscale`)
    # under the directional light model: how much of a de-lit texel's log is the ambient term's,
    # strength × ambient / shading (the shading is applied as shading^strength); else None
    ambient_dependence: np.ndarray | None
    # under the directional light model: how much of the light's sheen a texel may show, in [0, 1]
    # (:meth:`DefaultBackend._sun_lobe`); else None
    sun_lobe: np.ndarray | None


@dataclass
class DefaultBackend:
    """Weight-free texture backend. Knobs: the detail band (``detail_sigma_fraction`` of S) and
    depth (``detail_depth_mm``), the skin's mean albedo that scales the specular removal
    (``skin_albedo`` in (0, 1]; None for a photo without specular reflection). ``report`` holds
    statistics of the last calls; ``constants`` (:data:`~facegeo.texturing.backend.SKIN_CONSTANTS`)
    the maps not asked for."""

    constants: ClassVar[Mapping[str, float]] = SKIN_CONSTANTS
    name: str = "default"
    detail_sigma_fraction: float = 1.0 / 256.0  # detail = frequencies above ~S/256 texels⁻¹ (~1 mm at 1K: pores, wrinkles, creases)
    detail_depth_mm: float = DETAIL_DEPTH_MM
    skin_albedo: float | None = SKIN_ALBEDO  # None: the photo shows no specular reflection (cross-polarised light)
    report: dict[str, Any] = field(default_factory=dict)
    _analysis: tuple[TextureContext, _Analysis] | None = field(default=None, repr=False)
    _filled: tuple[np.ndarray, np.ndarray] | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.skin_albedo is not None and not 0.0 < self.skin_albedo <= 1.0:
            raise ValueError(f"skin_albedo: expected the skin's mean albedo in (0, 1] or None, got {self.skin_albedo}")

    # ---------------------------------------------------------------------------------- analysis
    def analyse(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> _Analysis:
        """Shading, highlights and kept weight of a photo texture (module docstring); cached for
        ``ctx`` until the next call."""
        return self._analyse(T_inc, srgb_to_linear(T_inc), M_vis, ctx)

    def _analyse(self, T_inc: np.ndarray, lin: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> _Analysis:
        """:meth:`analyse` of the texture ``T_inc`` (S, S, 3) sRGB already linearised: ``lin`` (S, S, 3)
        float32 linear RGB."""
        cover = ctx.coverage
        size = ctx.size
        w = np.clip(M_vis, 0.0, 1.0).astype(np.float32) * cover
        lum = luminance(lin)
        # the fit trusts only reliable skin: facing the camera, away from silhouettes and occluders
        # (at a silhouette the photo mixes in the background: a white wall made grazing skin "lit")
        inner = self._inner_distance(w > 0.5, ctx)
        clipped = (channel_max(lin)[..., 0] >= _clipped_ceiling()) & cover
        fit_mask = _skin(ctx) & (self._reliability(w, inner, ctx) > 0.5) & (lum > 1e-4) & ~clipped
        normals = ctx.normal_camera
        shading = np.ones(cover.shape, np.float32)
        n_fit = int(fit_mask.sum())
        directional = strength = contrast = 0.0
        self.report.pop("light", None)
        light: dict[str, Any] | None = None  # the directional light model's report, where it is used
        ambient_share: np.ndarray | None = None  # under the directional model: ambient / shading, per texel
        sun_lobe: np.ndarray | None = None
        if n_fit >= 100:
            rows = _subsample(np.flatnonzero(fit_mask.ravel()))
            basis = sh_basis(normals.reshape(-1, 3)[rows].astype(np.float32)).astype(np.float64)[:, :SH_TERMS]
            y = lum.ravel()[rows].astype(np.float64)
            keep = np.ones(len(rows), bool)
            for _ in range(4):  # trimmed least squares on the log-ratio
                coeffs, *_ = np.linalg.lstsq(basis[keep], y[keep], rcond=None)
                r = np.log(y / np.maximum(basis @ coeffs, 1e-6))
                med = np.median(r[keep])
                keep = np.abs(r - med) < 2.5 * 1.4826 * np.median(np.abs(r[keep] - med)) + 1e-6
            # how directional the fitted light is: under an even light the fit only finds albedo that
            # happens to correlate with the normals, and dividing by it would put that into the albedo
            directional = float(np.std(basis[keep][:, 1:4] @ coeffs[1:4]) / max(float(np.mean(basis[keep] @ coeffs)), 1e-12))
            # the Deep3D basis: constant term 0.886·c0, linear terms 1.772·(c·n), so κ = 2|c_1..3| / c0
            linear = 2.0 * float(np.linalg.norm(coeffs[1:4]))
            contrast = linear / coeffs[0] if coeffs[0] > linear / CONTRAST_CAP else CONTRAST_CAP
            strength = float(max(_smoothstep(np.float32((directional - DIRECTIONAL_RANGE[0]) / (DIRECTIONAL_RANGE[1] - DIRECTIONAL_RANGE[0]))),
                                 _smoothstep(np.float32((contrast - CONTRAST_RANGE[0]) / (CONTRAST_RANGE[1] - CONTRAST_RANGE[0])))))
            if strength > 0 and ctx.vertices_camera is not None and ctx.position_camera is not None and ctx.triangles is not None:
                e, cast, light = self._directional_shading(lum, fit_mask, ctx)
                ambient_share = np.clip(light["ambient"] / np.maximum(e, 1e-12), 0.0, 1.0)
                sun_lobe = self._sun_lobe(np.asarray(light["direction"]), strength * (1.0 - ambient_share), ctx)
            else:  # the SH fit's own shading over the layout
                flat = np.flatnonzero(cover.ravel())
                e = np.zeros(cover.size)
                e[flat] = sh_basis(normals.reshape(-1, 3)[flat].astype(np.float32))[:, :SH_TERMS] @ coeffs
                e = e.reshape(cover.shape)
            ref = float(np.median(e[fit_mask]))
            shading = np.where(cover, np.maximum(e / max(ref, 1e-6), 1e-3) ** strength, 1.0).astype(np.float32)
            # cast shadows / occlusion: local dips of the de-lit log-luminance below the neighbourhood
            log_a = np.log(np.maximum(lum / shading, 1e-4))
            local = masked_blur(log_a, fit_mask, size / 128.0)
            region = np.maximum(masked_blur(log_a, fit_mask, size / 12.0), masked_blur(log_a, fit_mask, size / 5.0))
            support = np.clip(gaussian_blur(fit_mask, size / 128.0) * 2.0, 0.0, 1.0)
            dip = np.clip(local - region + SHADOW_TOLERANCE, -0.7, 0.0) * support  # no evidence, no shadow
            if light is not None:  # the light model has its cast shadows: a dip far from their edges is albedo (a
                # beard), one near an edge the shadow that the fitted mesh put a few mm off
                steep = 1.0 - self._shading_confidence(cast, ctx)
                dip = dip * np.clip(gaussian_blur(steep, SHADOW_EDGE_MM / ctx.median_texel_mm) * 3.0, 0.0, 1.0)
            elif ctx.surface is not None and ctx.vertices_camera is not None and ctx.triangles is not None:
                # under an even light a dip is occlusion only as deep as the fitted mesh's sky
                # visibility allows within SHADOW_EDGE_MM (the nostrils, the eyes' corners); deeper,
                # or on open skin, it is albedo (a beard)
                dip = np.maximum(dip, self._occlusion_floor(ctx, dip < 0))
            shading = shading * np.exp(np.where(cover, dip, 0.0))
        facing = np.clip(normals[..., 2] / 0.5, 0.0, 1.0)
        grazing, most = (GRAZING_GAIN, MAX_GAIN) if light is None else LIGHT_GAIN
        bound = grazing + (most - grazing) * facing
        shading = np.where(cover, np.clip(shading, 1.0 / bound, bound), 1.0).astype(np.float32)
        delit_lum = lum / shading
        specular = self._specular(delit_lum, fit_mask if n_fit else (w > 0), w > 0, ctx, ambient_share)
        specular_share = float(specular[fit_mask].sum() / max(float(delit_lum[fit_mask].sum()), 1e-12)) if n_fit else 0.0
        delit_lum = _without_specular(delit_lum, specular)
        lo, hi = HIGHLIGHT_RATIO
        ref_weight = fit_mask if n_fit else cover
        # a seen texel with (almost) no reference skin within the neighbourhood's reach (an ear, the
        # neck, the scalp away from the face's reliable skin) is judged against the seen texels
        # around it: there the masked mean was 0 and the whole region passed for a highlight
        reach = gaussian_blur(ref_weight.astype(np.float32), size / 48.0) > HIGHLIGHT_REFERENCE_SUPPORT
        ref_weight = ref_weight | ((w > 0) & cover & ~reach)
        seen = (w > 0.5) & cover
        seen_skin = seen & _skin(ctx)
        greyscale = bool(seen.any()) and is_greyscale(T_inc[seen])
        # by its luminance alone on a patch as wide as HIGHLIGHT_PATCH_MM; on a narrower spot only as
        # far as it is whiter than its neighbourhood (a greyscale photo has no chroma to tell by)
        patch_lum = masked_blur(delit_lum, w > 0, HIGHLIGHT_PATCH_MM / ctx.median_texel_mm)
        white = np.full(cover.shape, np.float32(greyscale))
        if not greyscale:  # (judged where a pass finds the texel bright enough: elsewhere it does not count)
            texture = lin / shading[..., None]
            colour = masked_blur(texture, ref_weight, size / 48.0)
            judged = np.zeros(cover.shape, bool)
            white_lo, white_hi = HIGHLIGHT_WHITE_SHARE
        reach_texels = max(1, round(2.0 * HIGHLIGHT_PATCH_MM / ctx.median_texel_mm))
        around = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach_texels + 1, 2 * reach_texels + 1))
        for _ in range(2):  # the neighbourhood's mean without the highlight candidates of the first pass
            ref_lum = np.maximum(masked_blur(delit_lum, ref_weight, size / 48.0), 1e-6)
            ratio = delit_lum / ref_lum
            if not greyscale:
                todo = (ratio > lo) & ~judged
                white[todo] = np.clip((white_share(texture[todo], colour[todo]) - white_lo) / (white_hi - white_lo), 0.0, 1.0)
                judged |= todo
            # a patch's evidence reaches over its rim (2σ), which the patch's blur makes darker
            patch = cv2.dilate(np.clip((patch_lum / ref_lum - lo) / (hi - lo), 0.0, 1.0).astype(np.float32), around)
            highlight = np.clip((ratio - lo) / (hi - lo), 0.0, 1.0) * np.maximum(patch, white) * (w > 0)
            ref_weight = ref_weight & (highlight == 0)
        highlight = np.clip(gaussian_blur(highlight, max(1.0, size / 512.0)) * 2.0, 0.0, 1.0) * cover
        kept = w * (1.0 - highlight)
        # without chroma a dark sideburn or hairline passes the photo's skin mask anywhere on the face
        fringe = self._occluder_fringe(lin, shading, w, inner, fit_mask, ctx, np.inf if greyscale else FRINGE_MM) if n_fit >= 100 else None
        if fringe is not None:
            kept = kept * (1.0 - fringe)
        analysis = _Analysis(shading, highlight.astype(np.float32), kept.astype(np.float32), specular, greyscale,
                             None if ambient_share is None else (strength * ambient_share).astype(np.float32), sun_lobe)
        self._analysis = (ctx, analysis)
        if light is not None:
            self.report["light"] = light
        self.report["analyse"] = {
            "fit_texels": n_fit,
            "directional": directional,
            "irradiance_contrast": contrast,
            "delighting_strength": strength,
            "gain_p05_p95": [float(x) for x in np.percentile(1.0 / shading[fit_mask], [5, 95])] if n_fit else [1.0, 1.0],
            "highlight_fraction_of_seen_skin": float(highlight[fit_mask].mean()) if n_fit else 0.0,
            "clipped_fraction_of_seen_skin": float(clipped[seen_skin].mean()) if seen_skin.any() else 0.0,
            "specular_fraction_of_seen_skin": specular_share,
            "occluder_fringe_fraction_of_seen_skin": float(fringe[seen_skin].mean()) if fringe is not None else 0.0,
        }
        return analysis

    @staticmethod
    def _occluder_fringe(lin: np.ndarray, shading: np.ndarray, w: np.ndarray, inner: np.ndarray, fit_mask: np.ndarray,
                         ctx: TextureContext, reach: float) -> np.ndarray:
        """(S, S) float32 in [0, 1]: 1 on the seen skin's texels (``w`` (S, S) > 0) within
        ``reach`` mm (``inner``: :meth:`_inner_distance` of ``w > 0.5``, mm) of a texel not
        seen whose de-lit colour (``lin`` (S, S, 3) linear RGB over ``shading`` (S, S)) is not
        skin's: its log RGB beyond the :data:`FRINGE_SIGNIFICANCE` χ² quantile of a robust
        Gaussian of the reliably seen skin (``fit_mask`` (S, S) bool) farther inside, feathered over
        S/512 texels. A mask's edge lets through the fringe of what it masks (a sideburn's last
        strands, a frame's rim), stretched over many texels where the surface turns away; inside
        the seen region the same colours are the face's own (a mole, a beard) and are kept, except
        in a greyscale photo (``reach`` = ∞), whose skin mask had no chroma to keep hair out."""
        def log_delit(rows: np.ndarray) -> np.ndarray:
            return np.log(np.maximum(lin.reshape(-1, 3)[rows] / shading.reshape(-1)[rows, None], 1e-4))

        source = np.flatnonzero((fit_mask & (inner > FRINGE_MM)).ravel())
        if len(source) < 100:
            return np.zeros(w.shape, np.float32)
        mean, cov = robust_gaussian(log_delit(_subsample(source, FRINGE_SAMPLES)))
        near = np.flatnonzero(((w > 0) & _skin(ctx) & (inner < reach)).ravel())
        outlier = np.zeros(w.shape, np.float32)
        outlier.reshape(-1)[near] = mahalanobis_squared(log_delit(near), mean, cov) > chi2_quantile(FRINGE_SIGNIFICANCE, 3)
        return np.clip(gaussian_blur(outlier, max(1.0, ctx.size / 512.0)) * 2.0, 0.0, 1.0).astype(np.float32)

    @staticmethod
    def _directional_shading(lum: np.ndarray, fit_mask: np.ndarray, ctx: TextureContext) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        """The shading (S, S) float32 of one directional light and an ambient term fitted to the
        reliably seen skin's luminance ``lum`` (S, S) linear on ``fit_mask`` (S, S) bool:
        lum ≈ albedo · (ambient + L · max(n·l, 0) · V_l), n the camera-space normal, V_l the
        texel's visibility from the light (a shadow map of the posed mesh, blurred over
        :data:`SHADOW_SOFTNESS_MM`), the albedo taken as constant (robust: soft-L1 loss on the
        log-ratio). l: the best of :data:`LIGHT_CANDIDATES` directions (least squares for ambient
        and L, median |log-ratio|), refined with V_l of that direction, then V_l recomputed.
        Also the cast shadows' own factor (S, S) float32, the shading over that without V_l (1 where
        nothing is in shadow, flat across the terminator), and a JSON-ready report (direction,
        ambient / L, and the ambient term in ``lum``'s units)."""
        from scipy.optimize import least_squares  # here only: 0.3 s of import that an even light never needs

        cover = ctx.coverage
        rows = _subsample(np.flatnonzero(fit_mask.ravel()), LIGHT_FIT_TEXELS)
        n = ctx.normal_camera.reshape(-1, 3)[rows].astype(np.float64)
        log_y = np.log(np.maximum(lum.ravel()[rows].astype(np.float64), 1e-6))
        y = np.exp(log_y)
        # the grid: per candidate direction, ambient and L by least squares, scored by the median |log-ratio|
        candidates = sphere_directions(LIGHT_CANDIDATES)
        candidates = candidates[candidates[:, 2] >= LIGHT_MIN_Z]
        grid_rows = slice(None, None, max(1, len(rows) // 4000))
        cos = np.maximum(n[grid_rows] @ candidates.T, 0.0)  # (n, K)
        yg = y[grid_rows, None]
        c_mean, y_mean = cos.mean(axis=0), yg.mean()
        gain = np.maximum(((cos - c_mean) * (yg - y_mean)).mean(axis=0) / np.maximum(cos.var(axis=0), 1e-12), 0.0)
        ambient = np.maximum(y_mean - gain * c_mean, 1e-3 * y_mean)
        score = np.median(np.abs(np.log(yg / (ambient + gain * cos))), axis=0)
        best = int(np.argmin(score))

        def direction(angles: np.ndarray) -> np.ndarray:
            return np.array([np.sin(angles[0]) * np.cos(angles[1]), np.sin(angles[0]) * np.sin(angles[1]), np.cos(angles[0])])

        def visible(light: np.ndarray) -> np.ndarray:
            flat = np.flatnonzero(cover.ravel())
            lit = np.ones(cover.size, np.float32)
            lit[flat] = light_visibility(ctx.vertices_camera, ctx.triangles, ctx.position_camera.reshape(-1, 3)[flat], light,
                                         SHADOW_MAP_MM)
            lit = lit.reshape(cover.shape)
            return np.where(cover, masked_blur(lit, cover, SHADOW_SOFTNESS_MM / ctx.median_texel_mm), 1.0)

        def residual(x: np.ndarray, v: np.ndarray) -> np.ndarray:
            return log_y - np.log(np.exp(x[2]) + np.exp(x[3]) * np.maximum(n @ direction(x[:2]), 0.0) * v)

        l0 = candidates[best]
        x = np.array([np.arccos(np.clip(l0[2], -1, 1)), np.arctan2(l0[1], l0[0]), np.log(ambient[best]), np.log(max(gain[best], 1e-6))])
        v = visible(l0)
        x = least_squares(residual, x, args=(v.ravel()[rows],), loss="soft_l1", f_scale=0.1, max_nfev=100).x
        light = direction(x[:2])
        v = visible(light)
        direct = np.exp(x[3]) * np.maximum(ctx.normal_camera @ light, 0.0)
        shading = np.exp(x[2]) + direct * v
        cast = shading / (np.exp(x[2]) + direct)
        report = {"direction": [float(c) for c in light], "ambient_over_light": float(np.exp(x[2] - x[3])),
                  "ambient": float(np.exp(x[2])), "lit_fraction_of_fit": float((v[fit_mask] > 0.5).mean())}
        return np.where(cover, shading, 1.0).astype(np.float32), np.where(cover, cast, 1.0).astype(np.float32), report

    @staticmethod
    def _occlusion_floor(ctx: TextureContext, dips: np.ndarray) -> np.ndarray:
        """(S, S) float32 ≤ 0: the log of the posed mesh's sky visibility
        (:func:`facegeo.uv.sky_visibility`, the irradiance an even environment leaves it) at its
        lowest within :data:`SHADOW_EDGE_MM` of each texel (the fitted mesh is a few mm off),
        evaluated at the vertices within that distance of the ``dips`` (S, S) bool texels only (0
        elsewhere: no dip there to bound); 0 outside the layout."""
        cover = ctx.coverage
        radius = max(1, int(round(SHADOW_EDGE_MM / ctx.median_texel_mm)))
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        near = cv2.dilate((dips & cover).astype(np.uint8), disc).astype(bool) & cover
        _, touched = ctx.surface.to_vertices(near.astype(np.float32), near.astype(np.float32))
        at = np.flatnonzero(touched > 0)
        sky = np.ones(len(touched), np.float32)
        sky[at] = sky_visibility(ctx.vertices_camera, ctx.triangles, at=at)
        lowest = cv2.erode(np.where(cover, ctx.surface.to_texels(sky[:, None], ctx.size)[..., 0], 1.0).astype(np.float32), disc)
        return np.where(cover, np.log(np.maximum(lowest, 1e-3)), 0.0).astype(np.float32)

    @staticmethod
    def _sun_lobe(light: np.ndarray, lit: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S) float32 in [0, 1]: where the directional light's sheen may be, for a unit
        camera-space ``light`` direction (3,): a Gaussian of σ = :data:`SUN_SHEEN_LOBE_DEG` over
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
        lobe[rows] = np.where((n * view).sum(axis=-1) > 0, np.exp(-0.5 * (angle / np.radians(SUN_SHEEN_LOBE_DEG)) ** 2), 0.0)
        return (lobe.reshape(lit.shape) * lit).astype(np.float32)

    def _specular(self, delit_lum: np.ndarray, reference: np.ndarray, seen: np.ndarray, ctx: TextureContext,
                  ambient_share: np.ndarray | None) -> np.ndarray:
        """(S, S) float32: the skin's specular reflection of an environment light in the units of
        the de-lit luminance ``delit_lum`` (S, S), on the ``seen`` (S, S) bool texels (0 elsewhere).

        Per texel, photo = (albedo + q) · D: D is the diffuse radiance of a unit albedo, q the
        ratio of the specular radiance to it. For skin (GGX with generic skin's roughness and
        specular level, :data:`~facegeo.texturing.backend.SKIN_CONSTANTS`) under an even
        environment, q = E(n·v), the environment BRDF (:func:`facegeo.texturing.ggx.environment_brdf`:
        ~0.03 facing the camera, ~0.15 at grazing angles); under the directional model only its
        ambient part, q = E(n·v) · ``ambient_share`` (S, S) (ambient / shading). The directional
        light's own lobe is not modelled here: placed by the fitted mesh's normals it took colour
        from the wrong skin (Lee Perry-Smith's hard-light views up to 0.4 CIEDE2000 worse); its
        sheen is told by its colour instead (:func:`without_sun_sheen`). D in de-lit units: the
        ``reference`` (S, S) bool texels' mean de-lit luminance is D · (``skin_albedo`` + their
        mean q) (default :data:`SKIN_ALBEDO`; None: nothing removed). Subtracting D · q takes out
        the sheen that a white environment leaves on skin turned away from the camera, which made
        skin look greyer and bluer than it is (stubble most)."""
        cover = ctx.coverage
        out = np.zeros(cover.shape, np.float32)
        rows = np.flatnonzero((seen & cover).ravel())
        reference = reference & seen & cover
        if len(rows) == 0 or not reference.any() or self.skin_albedo is None:
            return out
        n = ctx.normal_camera.reshape(-1, 3)[rows]
        if ctx.position_camera is not None:
            position = ctx.position_camera.reshape(-1, 3)[rows]
            n_dot_v = -(n * position).sum(axis=1) / np.maximum(np.linalg.norm(position, axis=1), 1e-6)
        else:  # no posed mesh: an orthographic view
            n_dot_v = n[:, 2]
        q = environment_brdf(n_dot_v, self.constants["roughness"], SPECULAR_F0_SCALE * self.constants["specular"])
        if ambient_share is not None:
            q = q * ambient_share.reshape(-1)[rows]
        out.reshape(-1)[rows] = q
        unit = float(delit_lum[reference].mean()) / (self.skin_albedo + float(out[reference].mean()))
        return (unit * out).astype(np.float32)

    # ---------------------------------------------------------------------------------- inpaint
    def inpaint(self, T_inc: np.ndarray, M_vis: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB + (S, S) visibility -> (S, S, 3) sRGB, every texel filled, under the
        photo's lighting (the estimated shading and light colour applied to the filled albedo)."""
        cover = ctx.coverage
        lin = srgb_to_linear(T_inc)
        an = self._analyse(T_inc, lin, M_vis, ctx)
        w = an.weight
        skin = _skin(ctx)
        seen = w > 0.5
        delit = restore_clipped(lin, seen & skin, ctx.size) / an.shading[..., None]
        inner = self._inner_distance(seen, ctx)  # the reliability's edge ramp and the fill's own-detail ramp
        # where the estimated shading is steep (a shadow's edge, a hard light's terminator) a
        # misplacement of the fitted mesh by SHADOW_SOFTNESS_MM changes it by slope × that: such
        # de-lit texels are trusted less and the fill takes over (below: (1 - reliable) · fill)
        confidence = self._shading_confidence(an.shading, ctx)
        reliable = self._reliability(w, inner, ctx) * confidence
        notes: list[str] = []
        greyscale = an.greyscale
        # the light's colour: from the reliably seen skin and the photo's white references
        light = np.zeros(2)
        skin_weight = reliable * skin
        illuminant_report: dict[str, Any] = {"greyscale": greyscale}
        if not greyscale and skin_weight.sum() >= 10:
            free = _without_specular(delit, an.specular[..., None])  # the light's colour is judged without the sheen
            light, illuminant_report = self._light_colour(free, skin_weight, ctx)
            illuminant_report["greyscale"] = False
            if an.ambient_dependence is not None:  # two lights: the ambient term's colour told apart
                light = self._light_colour_map(light, free, an.ambient_dependence, skin_weight, illuminant_report)
            delit = remove_cast(delit, light)
        elif greyscale:
            delit = np.repeat(luminance(delit)[..., None], 3, axis=-1)
            notes.append("the photo is greyscale: the albedo's chroma is invented (a generic skin tone, redder lips)")
        delit = _without_specular(delit, an.specular[..., None])  # white once the light's colour is out
        if an.sun_lobe is not None and not greyscale:  # (a greyscale photo has no chroma to tell the sheen by)
            delit = without_sun_sheen(delit, an.sun_lobe, w > 0, (reliable > 0.5) & skin, SHEEN_SMOOTH_MM / ctx.median_texel_mm)
        if reliable[skin].sum() >= 10:
            mean = (delit * reliable[..., None]).reshape(-1, 3).sum(0) / reliable.sum()
        elif (w > 0).any():
            mean = (delit * w[..., None]).reshape(-1, 3).sum(0) / w.sum()
        else:  # nothing seen at all: the model's texture
            mean = srgb_to_linear(ctx.mean_texture)[cover].mean(0)
        log_seen = np.log(np.maximum(delit, 1e-4))
        own, own_detail, other, via_mirror, amp = self._fill_detail(log_seen, seen & cover, inner, reliable, ctx)
        detail_fill = own * own_detail + (1 - own) * other
        # the gradient-domain blend: the low frequencies of the seen skin minus the fill's detail,
        # solved on the surface with the reliability as data weight (a screened Poisson problem),
        # less where the light model's ambient term lights the texel (AMBIENT_LOG_ERROR), plus the
        # fill's detail; the seen texels kept by their reliability
        data = reliable
        if an.ambient_dependence is not None:
            data = reliable / (1.0 + (an.ambient_dependence * (AMBIENT_LOG_ERROR / FILL_TONE_TOLERANCE)) ** 2)
        values, data, asymmetry, trust = self._with_mirror_tone(log_seen - detail_fill, data, reliable, via_mirror, skin, ctx)
        base = self._base(values, data, np.log(np.maximum(mean, 1e-4)), ctx, FILL_SMOOTHNESS)
        # in the base's place, the seen texel's own mottling where its colour is trusted (kept
        # weight × shading confidence) away from the seen edge, whatever its foreshortening and its
        # distance to the edge: near an edge the base has too little of it, and its noise is not the photo's
        mottling = own * (w * confidence)[..., None] * self._own_mottling(log_seen, own_detail, base, seen & cover, ctx.size)
        # the tone blended by the reliability; the detail by the same weights made to keep its
        # contrast (mixed linearly, a band of smoother skin along the seen edge)
        r = reliable[..., None]
        out_log = r * (log_seen - own_detail) + (1 - r) * (base + mottling) + _mix_keeping_contrast(r + (1 - r) * own, own_detail, other)
        out = np.where(cover[..., None], np.exp(out_log), 0.0)
        if greyscale:
            out = invent_chroma(luminance(out), ctx.regions.get("lips"))
        peak = channel_max(out)
        out = np.where(peak > 1.0, out / np.maximum(peak, 1e-6), out).astype(np.float32)  # keeps chroma
        self.report["inpaint"] = {
            "seen": float(M_vis[cover].mean()) if cover.any() else 0.0,
            "kept_as_seen": float(reliable[cover].mean()) if cover.any() else 0.0,
            "via_mirror": float(((1 - reliable) * via_mirror)[cover].mean()) if cover.any() else 0.0,
            "mirror_asymmetry": asymmetry,
            "mirror_tone": trust,
            "detail_contrast": amp,
        }
        self.report["illuminant"] = illuminant_report
        self.report["notes"] = notes
        relit = linear_to_srgb(np.clip(out * cast_gains(light) * an.shading[..., None], 0.0, None))
        result = pad_outside(relit.astype(np.float32), cover)
        self._filled = (result, out)
        return result

    @staticmethod
    def _light_colour(free: np.ndarray, weight: np.ndarray, ctx: TextureContext) -> tuple[np.ndarray, dict[str, Any]]:
        """The light's chroma (2,) and its report (:func:`~facegeo.texturing.illuminant.estimate_illuminant`)
        from the ``weight`` (S, S)-weighted mean of ``free`` (S, S, 3) linear, the de-lit texture
        without its sheen (white before the light's colour is known: the sheen made skin look less
        saturated, which the skin locus took for a cooler light), and the context's white reference."""
        mean_skin = (free * weight[..., None]).reshape(-1, 3).sum(0) / weight.sum()
        white = None if ctx.white_reference is None else chroma(np.asarray(ctx.white_reference))
        return estimate_illuminant(chroma(mean_skin), white)

    @staticmethod
    def _light_colour_map(light: np.ndarray, free: np.ndarray, ambient: np.ndarray, weight: np.ndarray,
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

    @staticmethod
    def _with_mirror_tone(values: np.ndarray, data: np.ndarray, reliable: np.ndarray, via_mirror: np.ndarray,
                          skin: np.ndarray, ctx: TextureContext) -> tuple[np.ndarray, np.ndarray, float | None, float]:
        """The fill's data (``values`` (S, S, 3) log RGB without the fill's detail, weight ``data``
        (S, S)) with the mirror texel's values added where the texel is not wholly ``reliable``
        (S, S), at weight (1 − reliable) × ``via_mirror`` (S, S, the mirror's reliability) × the
        trust :data:`MIRROR_ASYMMETRY` gives the seen ``skin``'s (S, S) bool symmetry; also that
        asymmetry (None where too little skin is seen on both sides: trust 0) and the trust."""
        size = ctx.size
        _, mirror = _mirror_index(ctx)
        region = (reliable > 0.5) & skin
        both = region & (via_mirror > 0.5)  # (via_mirror is 0 where a texel has no mirror)
        if both.sum() < MIRROR_OVERLAP * size * size:
            return values, data, None, 0.0
        low = masked_blur(values, region, size / 64.0)
        difference = (low - low.reshape(-1, 3)[mirror])[both]
        asymmetry = float(np.sqrt(np.mean(difference ** 2)))
        lo, hi = MIRROR_ASYMMETRY
        trust = float(1.0 - _smoothstep(np.float64((asymmetry - lo) / (hi - lo))))
        if trust <= 0.0:
            return values, data, asymmetry, 0.0
        extra = ((1.0 - reliable) * via_mirror * trust).astype(np.float32)
        total = data + extra
        mixed = (data[..., None] * values + extra[..., None] * values.reshape(-1, 3)[mirror]) / np.maximum(total, 1e-12)[..., None]
        return np.where(total[..., None] > 0, mixed, values).astype(np.float32), total.astype(np.float32), asymmetry, trust

    def reliability(self, weight: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S) float32 in [0, 1]: how far each seen texel is trusted, the kept weight
        (visibility × coverage × facing × (1 − occlusion) × (1 − highlight)) times a
        foreshortening ramp (camera-space normal z from :data:`FORESHORTENING` [0] to [1]) times a
        ramp over :data:`EDGE_MM` mm of surface from the nearest texel not seen (the silhouette,
        an occluder, a highlight), so that the seen skin fades into the fill instead of ending."""
        return self._reliability(weight, self._inner_distance(weight > 0.5, ctx), ctx)

    @staticmethod
    def _reliability(weight: np.ndarray, inner: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """:meth:`reliability` with ``inner`` = :meth:`_inner_distance` of ``weight > 0.5`` (S, S) mm."""
        cover = ctx.coverage
        lo, hi = FORESHORTENING
        fore = _smoothstep((ctx.normal_camera[..., 2] - lo) / (hi - lo))
        edge = inner / EDGE_MM
        return np.where(cover & (weight > 0.5), np.clip(weight, 0.0, 1.0) * fore * _smoothstep(edge), 0.0).astype(np.float32)

    @staticmethod
    def _shading_confidence(shading: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S) float32 in [0, 1]: 1 − a ramp of the de-lit log-albedo's error if the shading
        (S, S) were misplaced on the surface by :data:`SHADOW_SOFTNESS_MM` (its log's slope per mm
        times that), from :data:`SHADING_ERROR` [0] to [1]; 1 where the shading is flat."""
        cover = ctx.coverage
        dy, dx = np.gradient(np.log(np.maximum(shading, 1e-6)))
        inside = cover.copy()  # central differences only between covered texels
        inside[1:-1, 1:-1] &= cover[2:, 1:-1] & cover[:-2, 1:-1] & cover[1:-1, 2:] & cover[1:-1, :-2]
        inside[[0, -1], :] = inside[:, [0, -1]] = False
        error = np.where(inside, np.hypot(dx, dy), 0.0) / ctx.median_texel_mm * SHADOW_SOFTNESS_MM
        lo, hi = SHADING_ERROR
        return (1.0 - _smoothstep((error - lo) / (hi - lo))).astype(np.float32)

    @staticmethod
    def _inner_distance(seen: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S) float32 distance in mm (texel distance × the median texel size) from each seen
        texel to the nearest covered texel that is not seen; texels outside the layout count as
        seen, so island borders are no boundary."""
        cover = ctx.coverage
        if not (seen & cover).any():
            return np.zeros(cover.shape, np.float32)
        return (_euclidean_distance(seen | ~cover) * ctx.median_texel_mm).astype(np.float32)

    def _fill_detail(self, log_seen: np.ndarray, seen: np.ndarray, inner: np.ndarray, reliable: np.ndarray,
                     ctx: TextureContext) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
        """The fill's detail in log RGB (zero mean) as ``own`` (S, S, 1) × the seen texel's own
        detail (S, S, 3; finer than ~S/128 texels, ~2.5 mm at 1K; 0 where not ``seen``) + (1 −
        ``own``) × the other detail (S, S, 3): the mirror texel's where that was reliably seen,
        and where not, blocks of the reliably seen skin's finest detail (above ~S ·
        ``detail_sigma_fraction`` texels⁻¹: pores, stubble; :func:`quilted_detail`) plus, away
        from the seen skin, the octaves above it up to :data:`MID_BAND_COARSEST` × S texels as
        :func:`band_noise` (the skin's grain and mottling, which the fill's smooth base lacks,
        less what the blocks carry), or 3-D value noise of the model-space position with the
        seen skin's contrast where no whole block was seen; the mirror's and the synthesised
        mixed with weights that keep their contrast. ``own`` is 1 inside the seen region and fades
        out over :data:`DETAIL_EDGE_MM` towards its edge (lashes, halos). Also the mirror's weight
        (S, S) and that contrast. ``inner``: :meth:`_inner_distance` of ``seen`` (S, S) mm."""
        cover = ctx.coverage
        size = ctx.size
        detail = np.where(seen[..., None], log_seen - masked_blur(log_seen, seen, max(1.0, size * OWN_DETAIL_COARSEST)), 0.0)
        amp = self._detail_contrast(log_seen, seen & _skin(ctx), size)
        has, mirror = _mirror_index(ctx)
        # a mole or speck is not mirrored (a face's marks are not symmetric): where the source's
        # detail is an outlier (and a little around it), the mirror is not used, quilting is
        source_weight = reliable * (1.0 - self._specks(detail, seen & (reliable > 0.5), size))
        w_m = np.where(has, source_weight.reshape(-1)[mirror], 0.0).astype(np.float32)
        mirrored = detail.reshape(-1, 3)[mirror]
        own = _smoothstep(inner / DETAIL_EDGE_MM)[..., None] * seen[..., None]
        # the fill's detail is needed where the texel's own is not wholly used: unseen, and the seen edge
        need = cover & (own[..., 0] < 1.0 - 1e-3) & (w_m < 1.0 - 1e-3)
        synthesised = None
        if need.any():  # pores and stubble only: quilted wrinkles and blotches made waves on a bald scalp
            fine = np.where(seen[..., None], log_seen - masked_blur(log_seen, seen, max(1.0, size * self.detail_sigma_fraction)), 0.0)
            source = seen & _skin(ctx) & (reliable > 0.99) & (inner > DETAIL_EDGE_MM)
            synthesised = quilted_detail(fine, source, need)
            if synthesised is not None:  # and the noise's octaves: the skin's grain and mottling
                synthesised += band_noise(log_seen, source, need & ~seen, ctx.position, cover, _euclidean_distance(~seen),
                                          max(1.0, size * self.detail_sigma_fraction), size * MID_BAND_COARSEST, ctx.median_texel_mm,
                                          MID_BAND_STRENGTH, whole_below=size * GRAIN_COARSEST, present=synthesised)
        if synthesised is None:  # no whole block of reliable skin was seen: value noise with its contrast
            noise = np.zeros(cover.shape, np.float32)
            if need.any() and amp > 0:
                pos = ctx.position[need]
                n = value_noise(pos, 0.35) + 0.7 * value_noise(pos, 0.7, seed=1) + 0.4 * value_noise(pos, 1.5, seed=2)
                noise[need] = amp * n / max(float(n.std()), 1e-6)
            synthesised = noise[..., None]
        other = _mix_keeping_contrast(w_m[..., None], mirrored, synthesised)
        return (own.astype(np.float32), np.where(cover[..., None], detail, 0.0).astype(np.float32),
                np.where(cover[..., None], other, 0.0).astype(np.float32), w_m, amp)

    @staticmethod
    def _own_mottling(log_seen: np.ndarray, own_detail: np.ndarray, base: np.ndarray, seen: np.ndarray, size: int) -> np.ndarray:
        """(S, S, 3) float32: on the ``seen`` (S, S) bool texels, the band of their log RGB
        ``log_seen`` (S, S, 3) between the fine ``own_detail`` (S, S, 3; :data:`OWN_DETAIL_COARSEST`)
        and :data:`OWN_MID_BAND_COARSEST` × S texels (the skin's mottling) less the same band of
        the fill's ``base`` (S, S, 3) log RGB: added to the base, it replaces the base's band by
        the photo's; 0 elsewhere."""
        coarsest = size * OWN_MID_BAND_COARSEST
        # band(x) = blur_fine(x) − blur_coarse(x), and blur_fine(log_seen) = log_seen − own_detail
        band = log_seen - own_detail - masked_blur(base, seen, max(1.0, size * OWN_DETAIL_COARSEST)) - masked_blur(log_seen - base, seen, coarsest)
        return np.where(seen[..., None], band, 0.0).astype(np.float32)

    @staticmethod
    def _specks(detail: np.ndarray, region: np.ndarray, size: int) -> np.ndarray:
        """(S, S) float32 in [0, 1]: 1 on the marks of the fine detail (S, S, 3) log RGB, texels
        whose channel-mean detail is beyond :data:`SPECK_SIGMAS` robust σ of ``region``'s (S, S)
        bool, grown by a Gaussian of S/512 texels (the mark's rim); 0 elsewhere."""
        d = channel_sum(detail) / 3  # (detail.mean(-1))
        if region.sum() < 100:
            return np.zeros(region.shape, np.float32)
        sigma = 1.4826 * float(np.median(np.abs(d[region]))) + 1e-6
        marks = (np.abs(d) > SPECK_SIGMAS * sigma).astype(np.float32)
        return np.clip(gaussian_blur(marks, max(1.0, size / 512.0)) * 3.0, 0.0, 1.0).astype(np.float32)

    def _base(self, values: np.ndarray, w: np.ndarray, mean: np.ndarray, ctx: TextureContext, smoothness: float) -> np.ndarray:
        """(S, S, C) smooth field: ``values`` (S, S, C) known with weight ``w`` (S, S) extended
        over the surface by a screened Poisson problem on the mesh's vertices (continuous across
        UV seams): minimise Σ_v w_v (x_v − values_v)² + ``smoothness`` Σ_edges (x_a − x_b)² +
        ε Σ_v (x_v − mean)², so that far from anything seen it settles on ``mean`` (C,), and
        near the seen skin it takes that skin's own values. Without surface operators: a UV
        push-pull."""
        size = ctx.size
        if ctx.surface is None:
            return _push_pull(values, w, size, size / 64.0 * np.sqrt(smoothness / FILL_SMOOTHNESS), mean)
        surf = ctx.surface
        vertex_values, vw = surf.to_vertices(values, w)
        eps = 1e-3
        system = (sp.diags(vw + eps) + smoothness * surf.laplacian).tocsc()
        rhs = vw[:, None] * np.nan_to_num(vertex_values) + eps * np.asarray(mean, np.float64)[None, :]
        x = spla.splu(system).solve(rhs)
        return surf.to_texels(x, size)

    def _detail_contrast(self, log_rgb: np.ndarray, seen: np.ndarray, size: int) -> float:
        """Robust σ of the seen skin's fine log-luminance detail (above ~S · ``detail_sigma_fraction``
        texels⁻¹, the band the fill quilts): ``log_rgb`` (S, S, 3) log linear RGB, ``seen`` (S, S) bool."""
        if seen.sum() < 100:
            return 0.0
        log_l = np.log(np.maximum(luminance(np.exp(log_rgb)), 1e-4))
        detail = log_l - masked_blur(log_l, seen, max(1.0, size * self.detail_sigma_fraction))
        d = detail[seen]
        return float(1.4826 * np.median(np.abs(d - np.median(d))))

    # ---------------------------------------------------------------------------------- homogenise
    def homogenise(self, T_full: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """(S, S, 3) sRGB -> (S, S, 3) sRGB albedo: divided by the shading (luminance only)."""
        cover = ctx.coverage
        skin = _skin(ctx)
        if self._filled is not None and self._filled[0] is T_full and self._analysis is not None and self._analysis[0] is ctx:
            shading, albedo = self._analysis[1].shading, self._filled[1]
        else:  # called on its own: analyse the texture as if everything were seen
            an = self.analyse(T_full, cover.astype(np.float32), ctx)
            shading = an.shading
            albedo = srgb_to_linear(T_full) / shading[..., None]
            weight = self.reliability(cover.astype(np.float32), ctx) * skin
            if weight.sum() >= 10 and not is_greyscale(T_full[cover]):
                light, self.report["illuminant"] = self._light_colour(_without_specular(albedo, an.specular[..., None]), weight, ctx)
                albedo = remove_cast(albedo, light)
            albedo = _without_specular(albedo, an.specular[..., None])
            peak = channel_max(albedo)
            albedo = np.where(peak > 1.0, albedo / np.maximum(peak, 1e-6), albedo)
        before = self._shading_variance(T_full, ctx.normal_camera, skin, srgb=True)
        after = self._shading_variance(albedo, ctx.normal_camera, skin)
        self.report["homogenise"] = {
            "shading_variance_before": before,
            "shading_variance_after": after,
            "remaining_fraction": after / max(before, 1e-12),
        }
        return pad_outside(linear_to_srgb(np.where(cover[..., None], albedo, 0.0)), cover)

    @staticmethod
    def _shading_variance(colour: np.ndarray, normals: np.ndarray, skin: np.ndarray, srgb: bool = False) -> float:
        """Variance of the skin's log-luminance explained by the SH basis of the normals
        (``colour`` linear RGB, or sRGB with ``srgb``)."""
        rows = _subsample(np.flatnonzero(skin.ravel()))
        if len(rows) < 10:
            return 0.0
        values = colour.reshape(-1, 3)[rows]
        log_l = np.log(np.maximum(luminance(srgb_to_linear(values) if srgb else values), 1e-4))
        basis = sh_basis(normals.reshape(-1, 3)[rows].astype(np.float32))
        coeffs, *_ = np.linalg.lstsq(basis, log_l - log_l.mean(), rcond=None)
        return float(np.var(basis @ coeffs))

    # ---------------------------------------------------------------------------------- materials
    def materials(self, T_hom: np.ndarray, ctx: TextureContext, maps: frozenset[str] | set[str] = frozenset(MAP_NAMES)) -> dict[str, np.ndarray]:
        """PBR maps (see :mod:`facegeo.asset`) from the homogenised texture; only ``maps``."""
        unknown = set(maps) - set(MAP_NAMES)
        if unknown:
            raise ValueError(f"maps: expected a subset of {MAP_NAMES}, got {sorted(unknown)}")
        cover = ctx.coverage
        out: dict[str, np.ndarray] = {}
        if "albedo" in maps:
            out["albedo"] = T_hom.astype(np.float32)
        if not {"normal", "displacement", "roughness", "specular"} & set(maps):
            return out
        if {"normal", "displacement"} & set(maps):
            log_l = np.log(np.maximum(luminance(srgb_to_linear(T_hom)), 1e-4))
            sigma = max(0.75, ctx.size * self.detail_sigma_fraction)
            detail = np.where(cover, log_l - masked_blur(log_l, cover, sigma), 0.0).astype(np.float32)
            displacement = np.clip(self.detail_depth_mm * detail, -DETAIL_LIMIT_MM, DETAIL_LIMIT_MM)  # dark = deeper
            if "displacement" in maps:
                out["displacement"] = pad_outside(displacement.astype(np.float32), cover)
            if "normal" in maps:
                out["normal"] = pad_outside(self._normal_from_height(displacement, ctx), cover)
        if {"roughness", "specular"} & set(maps):
            rough, spec = self._priors(ctx)
            evidence = np.zeros(cover.shape, np.float32)
            if self._analysis is not None and self._analysis[0] is ctx:
                evidence = np.clip(masked_blur(self._analysis[1].highlight, cover, ctx.size / 96.0) * 2.0, 0.0, 1.0)  # ~3 mm: no blobs
            if "roughness" in maps:  # where highlights were seen the skin is glossier: up to −35 % roughness
                out["roughness"] = pad_outside(np.clip(rough * (1.0 - 0.35 * evidence), 0.05, 1.0).astype(np.float32), cover)
            if "specular" in maps:  # and more specular: up to +50 %
                out["specular"] = pad_outside(np.clip(spec * (1.0 + 0.5 * evidence), 0.0, 1.0).astype(np.float32), cover)
        return out

    @staticmethod
    def _normal_from_height(height_mm: np.ndarray, ctx: TextureContext) -> np.ndarray:
        """Tangent-space normals (S, S, 3) in [−1, 1] of a height field in mm: n ∝ (−∂h/∂u,
        −∂h/∂v, 1) with the derivatives per mm on the surface (+u = columns, +v = rows up)."""
        dh_dcol = np.gradient(height_mm, axis=1)
        dh_drow = np.gradient(height_mm, axis=0)
        du = np.maximum(ctx.texel_size_mm[..., 0], 1e-3)
        dv = np.maximum(ctx.texel_size_mm[..., 1], 1e-3)
        n = np.stack([-dh_dcol / du, dh_drow / dv, np.ones_like(height_mm)], axis=-1)
        length = np.sqrt(n[..., 0] * n[..., 0] + n[..., 1] * n[..., 1] + n[..., 2] * n[..., 2])  # np.linalg.norm's sum, bit for bit,
        return (n / length[..., None]).astype(np.float32)  # without its slow reduction over a length-3 axis

    @staticmethod
    def _priors(ctx: TextureContext) -> tuple[np.ndarray, np.ndarray]:
        """Region-weighted (roughness, specular) priors, (S, S) each, blurred over S/64 texels
        (~8 mm at 1K) so region borders are smooth anatomical gradients, not landmark discs."""
        cover = ctx.coverage
        shape = cover.shape
        total = np.zeros(shape, np.float32)
        rough = np.zeros(shape, np.float32)
        spec = np.zeros(shape, np.float32)
        for name, (r, s) in REGION_PRIORS.items():
            if name in ctx.regions:
                w = ctx.regions[name].astype(np.float32)
                total += w
                rough += w * r
                spec += w * s
        rest = np.clip(1.0 - total, 0.0, 1.0)
        norm = np.maximum(total + rest, 1e-6)
        rough = (rough + rest * DEFAULT_PRIOR[0]) / norm
        spec = (spec + rest * DEFAULT_PRIOR[1]) / norm
        sigma = ctx.size / 64.0
        return masked_blur(rough, cover, sigma), masked_blur(spec, cover, sigma)

    # ---------------------------------------------------------------------------------- upscale
    def upscale(self, map_: np.ndarray, factor: int) -> np.ndarray:
        """Lanczos upscaling by an integer ``factor`` (1 returns the map unchanged)."""
        if factor == 1:
            return map_
        if factor < 1:
            raise ValueError(f"upscale factor: expected an integer ≥ 1, got {factor}")
        h, w = map_.shape[:2]
        return cv2.resize(map_, (w * factor, h * factor), interpolation=cv2.INTER_LANCZOS4)
