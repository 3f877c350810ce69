"""The default backend's settings: every knob of its stages in one frozen dataclass.

:data:`DEFAULT_SETTINGS` holds today's values; a caller or a test passes others as
``DefaultBackend(settings=dataclasses.replace(DEFAULT_SETTINGS, fringe_mm=0.0))``, and every
function of :mod:`facegeo.texturing.default` that reads a knob takes it from the settings passed
down. Each field's comment says what it does and, where it was measured, what the benchmarks
(``benchmarks/bench_albedo_scans.py``, ``benchmarks/RESULTS.md``) found. Fractions "of S" are of
the map's size in texels (S = 1024: 1K); mm are of the fitted mesh's surface.
"""

from __future__ import annotations

from dataclasses import dataclass

from facegeo.texturing.backend import SKIN_CONSTANTS
from facegeo.texturing.image_filters import PAD_FRACTION

__all__ = ["DEFAULT_SETTINGS", "DefaultSettings"]


@dataclass(frozen=True)
class DefaultSettings:
    """The knobs of :class:`~facegeo.texturing.default.backend.DefaultBackend` (frozen and
    hashable: derive others with :func:`dataclasses.replace`). Grouped by the module that reads
    them."""

    # ---- the shading fit: delighting.py
    #: SH terms of the shading fit: order 1 (constant + the three linear terms). Order 2 over the
    #: half-sphere of normals a photo shows is ill-conditioned: on renders of a real head scan under
    #: an even light it fitted a dark centre and bright sides (the albedo's beard zone and cheeks),
    #: anti-correlated with the true shading (benchmarks/bench_albedo_scans.py, RESULTS.md).
    sh_terms: int = 4
    #: (none, full): the shading is applied as shading^strength, the strength rising from 0 to 1 as the
    #: fit's directional part (the standard deviation of its linear terms over the fitted skin over
    #: its mean) goes from the first value to the second: an even light's fit finds 0.15–0.21 there
    #: (albedo that correlates with the normals), a hard side light 0.29–0.33.
    directional_range: tuple[float, float] = (0.2, 0.3)
    #: (none, full): the strength also rises from 0 to 1 as the fit's irradiance contrast over the
    #: sphere of normals, |linear part| / constant (E(n) = c·(1 + κ·n·d): κ ≥ 1 puts part of the head
    #: in the dark), goes from the first value to the second; the strength is the larger of the two.
    #: A hard light whose shadowed side is too dark for the skin mask leaves only lit skin to fit,
    #: whose normals span too little for :attr:`directional_range` (0.17 on bench_albedo_scans'
    #: Lee Perry-Smith scan, hard side 0°) while κ is large (the constant term near or below 0). An
    #: even light: κ 0.3–0.5 on both scans' frontal renders, 0.4–0.9 on the contact sheet's photos
    #: (benchmarks/sheet_albedo.py); the James scan's colour map, whose capture light is baked in,
    #: reads as a hard light at ±40° (4.4, and a constant term below 0).
    contrast_range: tuple[float, float] = (1.0, 2.0)
    #: κ reported (and used) where the constant term is ≤ 0 or smaller than the linear part over this.
    contrast_cap: float = 100.0
    #: Largest de-lighting gain (and 1/smallest) where the surface faces the camera.
    max_gain: float = 2.0
    #: Largest gain at grazing angles (camera-space normal z → 0).
    grazing_gain: float = 1.25
    # ---- the directional light model: directional_light.py
    #: Candidate light directions of the directional fit (a Fibonacci sphere; those below
    #: :attr:`light_min_z` are left out: a light from behind the head shows the camera no skin; and
    #: those below :attr:`light_min_y`).
    light_candidates: int = 400
    #: Smallest camera-space z of a candidate light direction.
    light_min_z: float = -0.3
    #: Smallest camera-space y (up) of the light's direction: no light from more than 30° below the
    #: horizon. Photographers do not light faces from below; on the sample photos and the scans'
    #: renders (38 faces) the fit found y ≥ −0.30, but on a face 21 px between the eyes (a real
    #: clip's), where the skin's shading is a few pixels, it found (−0.05, −0.98, 0.17) and drew
    #: that light's shadows into the albedo.
    light_min_y: float = -0.5
    #: Texels the directional fit uses at most (evenly spaced over the reliably seen skin).
    light_fit_texels: int = 20000
    #: Shadow-map pixel size at the mesh, mm (:func:`facegeo.uv.light_visibility`).
    shadow_map_mm: float = 1.0
    #: The shadow map's visibility is blurred over this many mm of surface (σ): the fitted mesh is
    #: only near the true one, and a hard shadow edge of the wrong shape would be drawn into the albedo.
    shadow_softness_mm: float = 3.0
    #: (trusted, not trusted): a seen texel's de-lit log-albedo error if the estimated shading were
    #: misplaced by :attr:`shadow_softness_mm` on the surface; between the two its reliability falls
    #: to 0 (:func:`~facegeo.texturing.default.reliability.shading_confidence`: shadow edges, a hard light's terminator).
    #: bench_albedo_scans, hard side views of both scans: seen ΔE2000 on Lee Perry-Smith +40°
    #: 3.13 -> 2.90, off-skin 3.26 -> 2.68 %; filled, Lee Perry-Smith 0° 4.47 -> 4.26, James −40°
    #: 12.55 -> 12.10; the other hard views within 0.13.
    shading_error: tuple[float, float] = (0.1, 0.4)
    #: (grazing, facing) largest de-lighting gains (as :attr:`grazing_gain`, :attr:`max_gain`) where
    #: the directional light model is used: it is a physical model, and the shadowed side of a face
    #: under a hard light is 5–15× darker than the lit side (bench_albedo_scans, hard side 0°: seen
    #: ΔE2000 7.45 with (8, 16), 7.84 with (8, 8), 9.33 with (4, 4)). At a de-lighting strength s
    #: below 1, the bounds are these^s × the SH fit's^(1 − s).
    light_gain: tuple[float, float] = (8.0, 16.0)
    # ---- cast shadows and occlusion: delighting.py
    #: Log-luminance dips (local vs neighbourhood) shallower than this are albedo, deeper ones shadow.
    shadow_tolerance: float = 0.15
    #: Under the directional light model, dips of the de-lit luminance count as shadow only within
    #: about this many mm of a cast shadow's edge (where the fitted mesh misplaces it); elsewhere they
    #: are albedo (a beard). bench_albedo_scans: James hard side 0° seen ΔE2000 7.49 → 7.12, Lee
    #: Perry-Smith hard +40° filled 5.34 → 5.07 and off-skin 2.46 → 2.07 %. The terminator too (within 6
    #: mm of any steep shading) did more there (2.87 → 2.75 seen, 1.26 % off-skin) but took James's
    #: stubble at the face's sides for shadow where his scan's baked light reads as a frontal one.
    #: Under an even light, a dip is bounded by the posed mesh's lowest sky visibility within this
    #: distance (:func:`~facegeo.texturing.default.delighting.occlusion_floor`): James even 0° seen ΔE2000 2.00 → 1.80,
    #: filled 10.21 → 9.69, gradient ratio 0.789 → 0.812 (his beard had been taken for shadow); Lee
    #: Perry-Smith's even views within 0.02.
    shadow_edge_mm: float = 6.0
    # ---- the skin's sheen: sheen.py
    #: The skin's mean diffuse albedo (linear luminance) assumed to put the specular model in the
    #: photo's units (:func:`~facegeo.texturing.default.sheen.environment_specular`): measured skin spans ~0.1 (dark) to ~0.5
    #: (fair); on darker skin less than the whole sheen is removed, on the fairest ~25 % too much.
    #: None: the photo shows no specular reflection (cross-polarised light); nothing is removed.
    skin_albedo: float | None = 0.4
    #: The specular removal keeps at least this fraction of each texel's de-lit value.
    specular_floor: float = 0.5
    #: σ (degrees) of the directional light's sheen over the angle between the normal and the half
    #: vector of light and view: skin's GGX lobe (roughness 0.55, α ≈ 0.3 rad, ~17°) widened by the
    #: fitted mesh's normal error (median 11–18° against a head scan's, frontal to 40° of yaw) and
    #: the light's direction error. Measured at 20 / 30 / 45 on the scans' hard-light views
    #: (benchmarks/RESULTS.md): within 0.06 CIEDE2000 of each other.
    sun_sheen_lobe_deg: float = 30.0
    #: The sheen's white part is smoothed over this surface distance (mm): its estimate from one
    #: texel's chroma is noisy, and a sheen varies over millimetres, not pores.
    sheen_smooth_mm: float = 2.0
    #: Reference texels needed for the skin's diffuse colour away from the lobe.
    sheen_reference_texels: int = 200
    # ---- highlights: highlights.py
    #: (start, full): a texel is a highlight where its de-lit luminance exceeds its neighbourhood's by these ratios.
    highlight_ratio: tuple[float, float] = (1.3, 1.6)
    #: A highlight's neighbourhood is the reliable skin's where that skin has at least this share of
    #: the neighbourhood's Gaussian weight, else the seen texels' around it. (Without it, seen texels
    #: beyond the Gaussian's reach of the reliable skin, ~3σ = 24 mm at 1K, had a neighbourhood mean
    #: of 0 and were all highlights: filled, and glossier in the specular map.)
    highlight_reference_support: float = 0.01
    #: A highlight at the photo's scale is a patch: a texel is one by its luminance alone where its
    #: neighbourhood within this σ (mm of surface) is as bright (that patch's evidence reaching 2σ
    #: over its rim, which the blur darkens); a brighter texel on a narrower spot is one only as far
    #: as it is whiter than its neighbourhood (:attr:`highlight_white_share`). The skin between a
    #: beard's or stubble's hairs is 1.8–2 × a neighbourhood mean that the hairs drag down and no
    #: whiter than it: it was filled, smooth holes in the stubble. bench_albedo_scans, James's nine
    #: even, warm and hard side views: gradient ratio +0.004–0.017 (even −40° 0.768 → 0.776), seen
    #: ΔE2000 −0.14 … +0.07 (even 0° 1.76 → 1.62); Lee Perry-Smith (no beard) unchanged. At 2.5 mm
    #: James even −40° 0.783, at 1.0 mm 0.775; without the rim's reach the highlights' rims stayed
    #: (pale-pink smears by Breaking Bad's mouth), and at 4 mm without it a lower lip's wet shine
    #: under warm light (``obama2.jpg``: the specular is the light's colour, not white).
    highlight_patch_mm: float = 1.5
    #: (start, full): the share of a texel's luminance excess over its neighbourhood that a white
    #: component explains (the dichromatic model: a specular reflection adds the light's colour, white
    #: under a neutral light) at which a bright spot narrower than :attr:`highlight_patch_mm` starts to
    #: be, and is wholly, a highlight. James's flagged beard texels explain none (their saturation
    #: −0.006 … −0.016 against the neighbourhood; a white specular of that strength takes ~0.2).
    highlight_white_share: tuple[float, float] = (0.2, 0.5)
    # ---- clipped texels: clipping.py
    #: A photo texel with a channel at or above this sRGB level is clipped (the sensor's or the grade's
    #: ceiling): its brightness and chroma are lower bounds, not measurements. Its clipped channels
    #: are restored from the others (below) before the analysis; where every channel is clipped it
    #: is left out of the light fits (and of the sheen's and the fringe's reference skin). (Before
    #: the restoration came first, every clipped texel was left out.) bench_albedo_scans' hard
    #: side light clips 37 % and 13 % of Lee Perry-Smith's seen skin at 0° and +40°: seen ΔE2000 2.44 →
    #: 2.18 and 3.02 → 2.69 (0.98 → 0.87 of the flat colour's), filled +0.1. Its de-lit value is kept
    #: as the albedo there: filled instead, 0° went to 3.51 (the fill is further off than a value a
    #: little under the truth). 240 / 255: 2.28 and 2.90. With the clipped channel (red) restored
    #: from the others (:func:`~facegeo.texturing.default.clipping.restore_clipped`): 0° 2.18 → 1.89, off-skin 0.30 → 0.00 %, filled +0.09.
    clipped_level: float = 250.0 / 255.0
    # ---- an occluder's fringe: occluders.py
    #: Seen skin this close (mm of surface) to a texel not seen whose de-lit colour is beyond the
    #: :attr:`fringe_significance` χ² quantile of the reliably seen skin's is an occluder's fringe
    #: (hair strands, a frame's rim, background at the silhouette that the photo's mask let through)
    #: and is treated as unseen. bench_albedo_scans: off-skin texels of James even −40° (a
    #: sideburn's edge) 5.35 → 1.17 %, Lee Perry-Smith hard side +40°'s seam 1.44 → 0.86.
    fringe_mm: float = 4.0
    #: The probability of the χ² quantile (3 degrees of freedom) beyond which a colour is not skin's.
    fringe_significance: float = 0.999
    #: σ (mm of surface) of the local level of the reliably seen skin that a greyscale photo's seen
    #: texels near the unseen are judged against (:func:`~facegeo.texturing.default.occluders.grey_fringe`:
    #: without chroma a hair fringe, a collar or a dark padding is told by its step in luminance from
    #: the skin beside it, not from the whole face's spread).
    fringe_local_mm: float = 8.0
    #: Robust σ of that skin's own departures from its local level from which such a texel starts to
    #: be the fringe's; wholly from the :attr:`fringe_significance` quantile (1 degree of freedom, 3.3 σ).
    fringe_soft_sigmas: float = 2.0
    #: Texels of reliably seen skin the fringe's colour Gaussian is fitted to, at most (evenly spaced;
    #: a 3 × 3 covariance needs far fewer, and 65536 cost 36 ms).
    fringe_samples: int = 16384
    # ---- the seen texels' reliability: reliability.py
    #: (start, full): the reliability of a seen texel rises from 0 to 1 as its camera-space normal's z
    #: goes from the first value to the second (foreshortened, resampled texels are trusted less).
    foreshortening: tuple[float, float] = (0.1, 0.4)
    #: The reliability rises over this many mm of surface from the nearest unseen texel.
    edge_mm: float = 4.0
    # ---- the fill's tone: fill.py
    #: Weight of the edge Laplacian in the screened Poisson fill (vertex data terms have weight ≤ 1).
    fill_smoothness: float = 2.0
    #: How far (log) the directional light model's ambient term may be off: it is the fit's least
    #: constrained part (a hard light's shadowed side is mostly left out by the skin mask, and what is
    #: left of it is grazing or occluded); on bench_albedo_scans' hard side light it came out 2–10× the
    #: render's. A seen texel's de-lit log-albedo is off by its ambient share of the shading times that.
    ambient_log_error: float = 0.7
    #: The de-lit error (log) at which a seen texel's weight as the fill's data is halved: under the
    #: directional model the fill's base weights each texel by 1 / (1 + (strength · ambient share ·
    #: :attr:`ambient_log_error` / this)²), so that the filled skin takes its tone from the lit skin, not
    #: from the shadowed fringe the skin mask left in. bench_albedo_scans, filled ΔE2000 of the hard side
    #: views 0° / −40° / +40°: Lee Perry-Smith 4.58 / 4.54 / 4.21 -> 4.15 / 3.72 / 4.04; James (whose
    #: colour map has the scanner's light baked in: his shadowed fringe is darker in the truth too)
    #: 10.74 / 11.98 / 7.92 -> 11.36 / 11.48 / 7.92; seen skin within 0.1. A ratio of 4 or 8 in place
    #: of 7: Lee Perry-Smith 4.26 / 3.54 / 4.18 and 4.14 / 3.79 / 3.99.
    fill_tone_tolerance: float = 0.1
    #: (trusted, not trusted): the RMS left–right difference of the seen skin's de-lit log colour
    #: (Gaussian σ = S/64 texels, ~6 mm at 1K; over the skin seen reliably on both sides) up to which
    #: the hidden side takes the mirror's tone as the fill's data, and from which it does not
    #: (smoothstep between). A face's own asymmetry is below the first; a side still lit or shadowed
    #: after de-lighting, or a colour map with the scanner's light baked in, above the second.
    #: bench_albedo_scans (even and hard side views): Lee Perry-Smith 0.05–0.10, James 0.19–0.42.
    mirror_asymmetry: tuple[float, float] = (0.06, 0.15)
    #: The share of the S × S texels that must be seen reliably on both sides to judge the symmetry.
    mirror_overlap: float = 1.0 / 1024.0
    # ---- the fill's detail: fill.py
    #: The seen texels' own fine detail is used from this many mm inside the seen region (nearer its
    #: edge, the mirror's or noise: the edge's texels carry lashes, frame shadows, highlight halos).
    detail_edge_mm: float = 2.0
    #: A seen texel's own fine detail (the fill's D_own, mirrored to the other side) is its band finer
    #: than this fraction of S (8 texels, ~3 mm at 1K: pores, stubble, fine wrinkles).
    own_detail_coarsest: float = 1.0 / 128.0
    #: A seen texel's own band from its fine detail (:attr:`own_detail_coarsest`) up to this fraction
    #: of S (16 texels, ~6 mm at 1K: mottling, small wrinkles) replaces the fill base's wherever its
    #: colour is trusted (kept weight × shading confidence, from :attr:`detail_edge_mm` inside the seen
    #: region), instead of fading into that smooth base with the reliability's foreshortening and edge ramps: the seen
    #: skin with reliability ≤ 0.95 (a third of it on James even −40°: highlight holes, the far
    #: cheek) had 0.70 of the scan's gradient there, its de-lit photo 1.02. bench_albedo_scans (12 even
    #: and hard side views): James's gradient ratio 0.76–0.88 → 0.77–0.89 (hard side 0° 0.797 → 0.805),
    #: seen ΔE2000 −0.04 … +0.01, filled within ±0.02; Lee Perry-Smith's gradient +0.01, seam ratio
    #: at most 1.10. Seen skin at 50 % reliability from foreshortening alone keeps 0.94 of its
    #: mottling instead of 0.73 (the test's hemisphere). At S/32 (an earlier form, without the base's
    #: band taken out): Lee Perry-Smith's seam ratio up to 1.27.
    own_mid_band_coarsest: float = 1.0 / 64.0
    #: Fine detail beyond this many robust σ of the seen skin's is a mark (a mole, a speck, a lash):
    #: it is not mirrored onto the other side of the face (the Lee Perry-Smith scan's cheek mole was).
    speck_sigmas: float = 4.0
    #: The lips' own chroma for what the fill gives them (:func:`~facegeo.texturing.default.fill.region_chroma`)
    #: needs their trusted seen texels to weigh at least this share of the S × S map (210 texels at
    #: 1K; the bundled photo's lips weigh ~1,100).
    region_chroma_min_share: float = 2e-4
    # ---- quilting: quilting.py
    #: Side of the blocks of seen skin detail that the fill's detail is quilted from, as a fraction of
    #: S (16 texels, ~6 mm at 1K: a few pores). bench_albedo_scans, the filled skin's gradient ratio
    #: over the even and hard views: 0.29–0.43 with value noise, 0.41–0.53 with these blocks of the
    #: finest band; blocks of S/32 with the fill's whole detail band (~3 mm) reached 0.56–0.66 but
    #: drew waves of copied wrinkles over Grace Hopper's scalp.
    quilt_block: float = 1.0 / 64.0
    #: A block of seen skin is quilted from only where its detail's mean square is at most this × the
    #: median block's of its neighbourhood (:attr:`quilt_neighbourhood`): a mole, a lash, a speck or a
    #: wrinkle copied over the scalp shows as a repeated mark (the contact sheet's astronaut and Grace
    #: Hopper); bench_albedo_scans' gradient ratio loses 0.03 to it.
    quilt_energy_cap: float = 2.5
    #: The fill's blocks come from the seen skin near the block's nearest seen place: a place drawn
    #: uniformly within half this fraction of S (32 texels, ~10 mm at 1K) of it, and a block is too
    #: busy by the median of its square of this side (64 texels; one with fewer places than a block
    #: has texels: by the whole source's). A stubbled jaw goes on under the chin and a smooth forehead
    #: onto the scalp; with blocks from anywhere on the face, James's fill (a full beard) was as calm
    #: as his cheeks. bench_albedo_scans, even and hard views: James's gradient ratio 0.75–0.86 →
    #: 0.76–0.88, Lee Perry-Smith's within ±0.03, filled median 5.91 → 5.97 (benchmarks/RESULTS.md).
    quilt_neighbourhood: float = 1.0 / 16.0
    #: Random points tried per radius (1×, 2× and 4× the reach) when a block's place is drawn by
    #: rejection (:func:`~facegeo.texturing.default.quilting.quilted_detail`); where all miss, a place anywhere.
    quilt_tries: int = 8
    # ---- noise: noise.py
    #: The fill's noise octaves (:attr:`mid_band_coarsest`) finer than this fraction of S (8 texels,
    #: ~3 mm at 1K: the skin's grain) get the seen skin's whole covariance, less what the quilted blocks
    #: already carry there; the coarser ones :attr:`mid_band_strength` of it. With all at 0.35 the
    #: filled skin had 0.4 of the seen skin's octave RMS at σ 2–4 and 4–8 texels, now 0.6 (Lee
    #: Perry-Smith even 0°; the blocks, zero-mean under a 16-texel window, carry little of σ 2–4).
    #: bench_albedo_scans, even and hard side views: gradient ratio 0.65–0.80 → 0.72–0.84 (James,
    #: whose unseen scan is beard and hairline), 0.78–1.08 → 0.90–1.14 (Lee Perry-Smith); filled
    #: ΔE2000 −0.11 … +0.07 per view.
    grain_coarsest: float = 1.0 / 128.0
    #: Coarsest octave of the fill's synthesised noise (:func:`~facegeo.texturing.default.noise.band_noise`), as a fraction of S (32
    #: texels, ~12 mm at 1K): from the quilted band's edge up to this, the fill gets noise in octaves
    #: with the seen skin's colour covariance per octave, the grain and mottling that real skin has.
    mid_band_coarsest: float = 1.0 / 32.0
    #: The fill's noise has this fraction of the seen skin's covariance in each octave coarser than
    #: :attr:`grain_coarsest`: on a photo the seen skin's octaves hold shading residue and features
    #: besides its mottling, and at 1.0 the contact sheet's astronaut got soft cm-wide blotches over
    #: scalp and chest.
    #: bench_albedo_scans (even 0°/−40°, hard side 0°/+40°; the noise then from S/256, all at this
    #: share): Lee Perry-Smith's gradient ratio 0.80–1.11 at 0.35 and 0.87–1.15 at 1.0 (0.74–1.09
    #: without), filled ΔE2000 +0.1–0.4 and +0.3–0.5.
    mid_band_strength: float = 0.35
    #: Lattice of each octave's gradient noise in :func:`~facegeo.texturing.default.noise.band_noise`, in units of the octave's finer σ
    #: (a difference of Gaussians σ–2σ peaks at a wavelength of ~6.5σ; gradient noise at ~1.5–2 cells).
    noise_cell_per_sigma: float = 3.5
    # ---- the albedo's level: albedo_level.py
    #: (lowest, highest) linear luminance the skin-reflectance prior gives skin (Fitzpatrick VI to I
    #: lie within; the locus's log-linear line through the ColorChecker's two skin patches is bounded
    #: by it).
    level_skin_range: tuple[float, float] = (0.05, 0.45)
    #: The share of the ColorChecker skin patches' luminance-against-chroma slope that the skin prior
    #: keeps: without a sclera in view a warm light reads partly as darker skin (a warmly lit light-
    #: skinned face of the sample photos, biden.jpg, was placed beyond the dark patch: 0.06 at the
    #: full slope, 0.11 at half).
    level_tone_share: float = 0.5
    #: σ in log of the skin prior's luminance (people of one skin chroma differ by about ±50 %).
    level_skin_sigma: float = 0.5
    #: Linear luminance of the white references as photos show them (the brighter, less saturated
    #: half of the sclera that :func:`facegeo.skin_mask.white_reference` keeps: lit, but under the
    #: lids' and lashes' shade; teeth alike).
    level_white_reflectance: float = 0.55
    #: σ in log of that (the lids' shade, a wet sclera's sheen, teeth's colour).
    level_white_sigma: float = 0.35
    #: A white reference whose level and the skin prior's differ by more than this many σ (their σ
    #: combined) is not used: bench_albedo_scans' James scan, whose scanned eyes are grey, read
    #: 4.8 σ off (its "white" 5× darker than the skin).
    level_gate: float = 2.5
    # ---- materials: materials.py
    #: Displacement in mm per unit of high-frequency log-luminance detail (dark = deeper), clipped to
    #: ±DETAIL_LIMIT_MM: skin detail of 3 % contrast (the typical σ of a photo's fine skin detail) is
    #: 0.03 mm of relief, a crease that darkens the skin by a quarter 0.29 mm (pores are 0.05–0.1 mm
    #: deep, fine wrinkles 0.1–0.3 mm). The issue's old gain (0.5 mm, ±0.5 mm) changed a Blender
    #: render by 0.6/255 on average.
    detail_depth_mm: float = 1.0
    #: The detail band of the fill and of the relief maps: frequencies above ~S × this texels⁻¹ (S/256:
    #: ~1 mm at 1K; pores, wrinkles, creases).
    detail_sigma_fraction: float = 1.0 / 256.0
    #: Largest displacement either way (mm).
    detail_limit_mm: float = 0.3
    #: (roughness, specular) priors per facial region; oily T-zone glossier, brows matte, lips smooth
    #: and less specular (values in the range of measured facial BRDF fits, e.g. Weyrich et al. 2006).
    #: (A tuple of (region, (roughness, specular)) pairs, in the order they are summed, so that the
    #: settings stay hashable.)
    region_priors: tuple[tuple[str, tuple[float, float]], ...] = (
        ("forehead", (0.45, 0.60)),
        ("nose", (0.40, 0.65)),
        ("cheeks", (0.55, 0.45)),
        ("chin", (0.50, 0.50)),
        ("lips", (0.35, 0.40)),
        ("brows", (0.75, 0.25)),
        ("eyes", (0.30, 0.70)),
    )
    #: Roughness and specular where no region mask says otherwise (skin on the head and neck).
    default_prior: tuple[float, float] = (SKIN_CONSTANTS["roughness"], SKIN_CONSTANTS["specular"])
    # ---- padding: facegeo.texturing.image_filters.pad_outside
    #: Padding outside the UV islands: the edge colour over this fraction of S texels (4 at 1K), then
    #: the median of the map (flat). (Its default is the shared padding's, which the diffusion backend uses.)
    pad_fraction: float = PAD_FRACTION

    def __post_init__(self) -> None:
        if self.skin_albedo is not None and not 0.0 < self.skin_albedo <= 1.0:
            raise ValueError(f"skin_albedo: expected the skin's mean albedo in (0, 1] or None, got {self.skin_albedo}")


#: The default backend's settings as tuned (the values the benchmarks report).
DEFAULT_SETTINGS = DefaultSettings()
