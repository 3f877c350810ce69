"""Albedo against a real skin colour map (issues 26, 49): Blender renders of a real head scan whose
texture is known, reconstructed by facegeo, the asset's albedo compared with the scan's colour at
corresponding surface points.

Scans and renders: ``benchmarks/scan_renders.py`` (per view the render, the scan texture's colour
at every pixel (Cycles' Diffuse Color pass) and the scan point at every pixel) of two scans
(:mod:`head_scans`), whose colour maps differ in kind:

* ``james``: the 3dMD scan of the menpo3d sdist. Its colour map is two of the scanner's photos,
  lighting and all: under the renders' even light the subject's right half of the face is 1.5×
  brighter than the left (median skin luminance of the Diffuse Color pass, yaw 0°), and its log
  luminance varies with a MAD of 0.33 over the seen skin; a beard. A light estimate that takes
  the albedo's low frequencies as constant is biased by that baked light (RESULTS.md);
* ``lee_perry_smith``: Infinite-Realities' scan from the three.js examples (CC BY 3.0): an
  evenly lit colour map, as an albedo is; eyes closed (no sclera to see), head shaved.

Views here, per scan: yaw 0° and ±40° under the lights of :data:`LIGHTS` (recipes in
``blender_render_scan.py``); the issue's bars (issue 49) are on a photographer's lights
(:data:`BAR_LIGHTS`):

* **key + fill**: the studio portrait light, a large soft key from the subject's left and above,
  a fill of a third of its irradiance from the other side, a dim environment;
* **window**: one large soft source from the side and a brighter environment (room bounce);
* **hard side** light (a small sun from the subject's left and a dim environment): the
  ``hard-side`` view of the scans helper at yaw 0°;
* **sun + sky**: the same sun, warm (~4500 K), under a blue sky (~10000 K): the skin in the
  sun's shadow is lit by a light of another colour than the lit skin;

and, not in the bars:

* **ring**: a soft source around the lens (along the camera axis) and a dim environment;
* **even** light (the renders' uniform white environment: no photographer lights a face so);
* **warm** light: the even render's linear RGB times the von Kries gains :data:`WARM` of a
  ~3200 K tungsten light (exact for a scene lit by one light colour: the render is linear
  before its sRGB encoding, the "Standard" view transform), re-encoded to 8-bit sRGB.

The even views and ``hard-side`` are the scans helper's; the others are rendered here
(:data:`EXTRA_VIEWS`, into ``~/.cache/facegeo/scans_albedo``, ~10 s each with Debian's
``blender`` on 2 cores) where missing.

Per view: ``facegeo``'s fit (default detector), skin mask, unwrap and texture backend at
S = 1024; the new default backend, the one it replaced (``DefaultBackend`` and ``skin_mask`` of
git commit :data:`BASELINE_COMMIT`) on the same fit, and two baselines: a **flat** albedo of the
seen skin's median photo colour, and the **raw** photo colour (seen texels only).

Correspondence. Seen texels (M_vis > 0.5 with the new mask): the truth is the scan colour image
at the texel's projection into the photo (bilinear, where all four pixels are on the scan). All
texels: the fitted mesh (camera space) is similarity-aligned to the scan (Umeyama, trimmed: the
seen texels' positions against the scan points at their pixels), and the truth is the inverse-
distance mean of the scan colour at the 4 nearest scan points of the five even views (yaw 0,
±20, ±40), where the nearest is within 3 mm. Skin texels: the model's skin region
(:func:`facegeo.skin_mask.skin_vertex_mask`: face without eyes, brows, lips).

Metrics over skin texels, after one exposure scale per view (the albedo's linear luminance
least-squares scaled onto the truth's over the seen skin; chroma is not fitted):

* ΔE2000 median on **seen** skin (photo-pixel truth) and on **filled** skin (M_vis < 0.5,
  3-D truth); the **chroma** error alone: median |Δ(a*, b*)|;
* **gradient ratio**: mean |∇Lab| of the albedo over skin texels divided by the truth's, both
  maps (3-D truth) blurred by one photo pixel's footprint (σ in texels, the finest scale the
  photo resolves); below 1 detail is lost, above it blotches or noise were added;
* **seam ratio**: mean |∇Lab| within 3 texels of the seen/filled boundary divided by the mean
  elsewhere, for the albedo and for the truth;
* **truth extended** (a ceiling, not a method): the filled skin's ΔE2000 when the truth's own
  colours on the seen texels are extended by the new backend's gradient-domain fill (with the
  mirror's tone as far as the truth's own seen sides agree); no fill from the seen skin can be
  expected to do better (the scan's unseen skin differs: beard, neck);
* **truth through the fill**: the gradient ratios (all / seen / filled skin) of the new backend's
  albedo when its input is the truth's own colours on the seen texels (the photo-pixel truth
  where the texel is on the scan, else the 3-D truth) with the same visibility: how much of the
  scan's detail the fill can carry when the seen skin is perfect;
* **level**: the albedo's linear luminance over the truth's on the seen skin (1 / the exposure
  scale above): 1 where the albedo's level is the scan's colour map's. Those maps are not
  calibrated reflectance (James's is his scanner's photos, exposure and all), so it tells a bias
  of the level (issue 49: the albedo's level anchored by the skin and the whites), not an error;
* **off-skin**: share of skin texels whose albedo colour the real skin map never takes: Lab
  Mahalanobis distance > :data:`OFF_SKIN_SIGMAS` from a robust Gaussian (median, MAD-scaled
  covariance) of the truth's colours over the skin texels (glasses, background, hair, dark cast
  shadows or blotches left in);
* **the light's colour**: the rendered light's chroma as the seen skin shows it (the photo's
  (log R/G, log B/G) less the albedo pass's, median over the seen skin texels) against the new
  backend's estimate of it, and whether it used a white reference (the JSON also gives the white's
  miss and tint, :func:`facegeo.texturing.illuminant.estimate_illuminant`'s gates). The scans' eyes are not white
  (James's scanned scleras are yellow, Lee Perry-Smith has skin for eyes: RESULTS.md), so this
  separates an error of the light's estimate from one of the skin's own colour.
* **the map's shading-like lightness** (:func:`map_field`, a diagnostic: it uses the truth): the
  part of the 3-D truth's log-luminance over the skin that a light on the fitted mesh explains (9
  spherical-harmonic terms of the normals, least squares; its share of the variance and its span
  over the seen skin, p5–p95), and how the new backend's seen log-luminance error (the view's
  exposure scale, median removed) follows it: correlation and regression slope β (−1: the albedo
  lost all of it, taken for light; 0: kept it as the map has it). A de-lighting that takes the
  albedo's low frequencies as constant cannot tell that lightness from the light's; the seen
  ΔE2000 with β of it put back (the albedo × exp(−β · field)) says how much of the view's error
  it is.

Per region (:data:`REGIONS`: mouth (the lips), eyes, nose, cheeks, forehead; the layout's
:func:`facegeo.skin_mask.vertex_regions` > 0.5): the seen texels' ΔE2000 median (photo-pixel
truth, the view's exposure scale), of the new and the previous backend and of the raw photo (where
the photo itself is far from the truth, the region lies in shadow or under a moustache).

Exposure series (:func:`exposure_series`): the key + fill render at yaw 0° at −1, 0 and +1 EV
(its linear RGB × 0.5, 1, 2, clipped and re-encoded to 8-bit sRGB), each reconstructed on its own
(its own fit and skin mask, the new backend), the albedos compared with each other with no
exposure scale: the ΔE2000 median of −1 and +1 EV against 0 EV over the skin texels all three see
(M_vis > 0.5), and the ratio of their median luminance. An albedo independent of the exposure
gives ΔE 0 and ratio 1; one that follows it, 0.5 and 2.

    python benchmarks/bench_albedo_scans.py --write /tmp/albedo_scans.md    # ~15 min on 2 cores, both scans
    python benchmarks/bench_albedo_scans.py --time-stages 5                  # texture-stage times
    python benchmarks/bench_albedo_scans.py --time-stages 5 --photo obama.jpg  # ... under an even light
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
import types
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree
from skimage.color import deltaE_ciede2000, rgb2lab

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scan_evaluation import similarity_transform  # noqa: E402
from scan_renders import ViewSpec, load_view, render_views  # noqa: E402

import facegeo  # noqa: E402
from facegeo.colour import linear_to_srgb, luminance, srgb_to_linear  # noqa: E402
from facegeo.errors import NoFaceError  # noqa: E402
from facegeo.lighting import sh_basis  # noqa: E402
from facegeo.pipeline import reconstruct_with_fit  # noqa: E402
from facegeo.skin_mask import SkinMask, skin_mask, skin_vertex_mask  # noqa: E402
from facegeo.texturing.context import build_context, surface_operators  # noqa: E402
from facegeo.texturing.default import DEFAULT_SETTINGS, DefaultBackend  # noqa: E402
from facegeo.texturing.default.fill import fill_base, with_mirror_tone  # noqa: E402
from facegeo.texturing.default.texels import mirror_index  # noqa: E402
from facegeo.texturing.illuminant import PLANCKIAN, chroma  # noqa: E402
from facegeo.texturing.image_filters import masked_blur  # noqa: E402
from facegeo.uv import Unwrapped, geometry_maps, rasterize_uv, unwrap_details  # noqa: E402
from facegeo.uv.texels import sample_bilinear  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
BASELINE_COMMIT = "b62b557"
#: The scans compared (:data:`head_scans.SCANS`), and their labels in the tables.
SCAN_LABELS = {"james": "James (3dMD)", "lee_perry_smith": "Lee Perry-Smith (IR)"}
#: von Kries gains (linear sRGB, G = 1) of a ~3200 K light against the renders' white one.
WARM = np.array([1.0, 0.76, 0.52], np.float32)
#: The yaws (degrees) of every light's views, in :data:`VIEWS`' order, and their labels.
YAWS = (0.0, -40.0, 40.0)
YAW_LABELS = ("0°", "−40°", "+40°")


def extra_views(light: str, yaws: tuple[float, ...]) -> tuple[ViewSpec, ...]:
    """Views of ``light`` (a recipe of ``blender_render_scan.py``) at ``yaws``, named after the
    light and the yaw (``sun-sky``, ``sun-sky+40``, ``sun-sky-40``)."""
    return tuple(ViewSpec(light + (f"{yaw:+.0f}" if yaw else ""), yaw=yaw, light=light) for yaw in yaws)


#: The views rendered here (not by the scans helper) with its recipe: the hard side light at
#: ±40° (its yaw-0° view is the helper's ``hard-side``) and the other lights at every yaw.
EXTRA_VIEWS = extra_views("hard-side", YAWS[1:]) + tuple(v for light in ("sun-sky", "key-fill", "window", "ring")
                                                         for v in extra_views(light, YAWS))
EXTRA_CACHE = Path.home() / ".cache" / "facegeo" / "scans_albedo"
#: The scans helper's even renders at :data:`YAWS`.
EVEN = ("yaw+00", "yaw-40", "yaw+40")
#: light -> (label, its renders at :data:`YAWS`): "even" and "warm" share the helper's even
#: renders (warm: re-coloured by :data:`WARM`), the others are rendered under the light.
LIGHTS = {"even": ("even", EVEN), "warm": ("warm", EVEN),
          "hard": ("hard side", ("hard-side", "hard-side-40", "hard-side+40")),
          **{light: (label, tuple(v.name for v in extra_views(light, YAWS)))
             for light, label in (("sun-sky", "sun + sky"), ("key-fill", "key + fill"), ("window", "window"), ("ring", "ring"))}}
#: (label, render, light) of the compared views.
VIEWS = [(f"{label} {yaw}", render, light) for light, (label, renders) in LIGHTS.items() for yaw, render in zip(YAW_LABELS, renders)]
#: The lights of the issue's bars (issue 49: a photographer's lights); the others' views are extra.
BAR_LIGHTS = ("key-fill", "window", "hard", "sun-sky")
#: The regions of the per-region seen ΔE2000 (:func:`facegeo.skin_mask.vertex_regions`), and their labels.
REGIONS = {"lips": "mouth (lips)", "eyes": "eyes", "nose": "nose", "cheeks": "cheeks", "forehead": "forehead"}
#: The exposure series: this render, its linear RGB times 2^EV for each EV, each reconstructed on its own.
EV_RENDER = "key-fill"
EVS = (-1, 0, 1)


def ev_label(ev: int) -> str:
    """"−1", "0", "+1": an EV as the tables write it."""
    return f"{ev:+d}".replace("-", "−") if ev else "0"


#: The even views whose scan points and colours make the 3-D truth.
TRUTH_VIEWS = ("yaw+00", "yaw-20", "yaw+20", "yaw-40", "yaw+40")
#: Truth only where the nearest scan point is this close (mm).
TRUTH_RADIUS_MM = 3.0
#: Off-skin: Lab Mahalanobis distance above this from the truth skin's colours.
OFF_SKIN_SIGMAS = 5.0
METHODS = ("new", "previous", "flat", "raw")
DUMP: Path | None = None  # --dump: the UV maps compared, per view


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def from_git(path: str, name: str) -> types.ModuleType:
    """A module of the project as it was at :data:`BASELINE_COMMIT`."""
    code = subprocess.run(["git", "show", f"{BASELINE_COMMIT}:{path}"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    module = types.ModuleType(name)
    sys.modules[name] = module  # dataclasses look their module up
    exec(compile(code, f"{BASELINE_COMMIT}:{path}", "exec"), module.__dict__)
    return module


def view_for(scan: str, render: str):
    """The scans helper's view ``render`` of ``scan``, rendered first where missing (extra views here)."""
    if render in {v.name for v in EXTRA_VIEWS}:
        try:
            return load_view(scan, render, cache=EXTRA_CACHE)
        except facegeo.errors.InputError:
            render_views(scan, cache=EXTRA_CACHE, views=EXTRA_VIEWS)
            return load_view(scan, render, cache=EXTRA_CACHE)
    try:
        return load_view(scan, render)
    except facegeo.errors.InputError:
        render_views(scan)
        return load_view(scan, render)


def regraded(image: np.ndarray, gains: np.ndarray | float) -> np.ndarray:
    """The 8-bit sRGB ``image`` with its linear RGB times ``gains`` (per channel, or one
    exposure factor), clipped and re-encoded to 8-bit sRGB: exact for a render, linear before its
    sRGB encoding, as long as nothing was clipped."""
    linear = srgb_to_linear(image.astype(np.float32) / 255.0) * np.asarray(gains, np.float32)
    return np.clip(np.round(linear_to_srgb(np.clip(linear, 0.0, 1.0)) * 255.0), 0, 255).astype(np.uint8)


def photo_of(view, light: str) -> np.ndarray:
    """The photo of ``view`` under ``light``: the render itself, or for "warm" re-coloured by :data:`WARM`."""
    return regraded(view.image, WARM) if light == "warm" else view.image


@dataclass
class Truth3D:
    """Scan points (N, 3) mm of the even views and their scan colour (N, 3) linear RGB."""

    tree: cKDTree
    colour: np.ndarray

    @classmethod
    def build(cls, scan: str) -> "Truth3D":
        points, colours = [], []
        for name in TRUTH_VIEWS:
            view = view_for(scan, name)
            mask = view.mask
            points.append(view.points[mask])
            colours.append(srgb_to_linear(view.albedo[mask].astype(np.float32) / 255.0))
        return cls(cKDTree(np.concatenate(points)), np.concatenate(colours))

    def lookup(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse-distance mean colour (N, 3) linear of the 4 nearest scan points, and (N,) bool
        where the nearest is within TRUTH_RADIUS_MM."""
        d, i = self.tree.query(points, k=4)
        w = 1.0 / np.maximum(d, 0.05)
        colour = (self.colour[i] * w[..., None]).sum(1) / w.sum(1, keepdims=True)
        return colour.astype(np.float32), d[:, 0] <= TRUTH_RADIUS_MM


class CachedFit:
    """A fitter that returns the fit already made (the methods share one fit per view)."""

    def __init__(self, fit):
        self.fit = fit

    def __call__(self, photo, **_):
        return self.fit


@dataclass
class Observed:
    """One photo as facegeo sees it: its own fit, skin mask and unwrap (``unwrap.visibility``: M_vis)."""

    photo: np.ndarray
    fit: facegeo.Fit
    mask: SkinMask
    unwrap: Unwrapped

    @classmethod
    def of(cls, photo: np.ndarray, model, raster) -> "Observed":
        fit = facegeo.fit(photo, model)
        mask = skin_mask(photo, fit.landmarks)
        return cls(photo, fit, mask, unwrap_details(photo, fit, model, raster=raster, occlusion=mask.occlusion))

    def albedo(self, model, backend, skin: SkinMask, size: int) -> np.ndarray:
        """(S, S, 3) linear: the albedo map ``backend`` makes of the photo on this fit with the skin mask ``skin``."""
        asset, _ = reconstruct_with_fit(self.photo, model, fitter=CachedFit(self.fit), backend=backend, size=size,
                                        maps={"albedo"}, skin=skin, parts=False)
        return srgb_to_linear(asset.maps["albedo"])


def lab(linear: np.ndarray) -> np.ndarray:
    return rgb2lab(np.clip(linear_to_srgb(np.clip(linear, 0.0, 1.0)), 0, 1).astype(np.float64))


def exposure(albedo_lin: np.ndarray, truth_lin: np.ndarray) -> float:
    ya, yt = luminance(albedo_lin), luminance(truth_lin)
    return float((ya * yt).sum() / max((ya * ya).sum(), 1e-12))


def median_de(lab_a: np.ndarray, lab_b: np.ndarray, where: np.ndarray) -> float:
    """The median ΔE2000 between two (S, S, 3) Lab maps over the texels ``where`` (NaN if none)."""
    return float(np.median(deltaE_ciede2000(lab_a[where], lab_b[where]))) if where.any() else float("nan")


def gradient(lab_map: np.ndarray, region: np.ndarray) -> np.ndarray:
    """(S, S) |∇Lab| by forward differences where the texel and its right/lower neighbours are
    in ``region``; NaN elsewhere."""
    gx = np.zeros(region.shape, np.float64)
    gy = np.zeros(region.shape, np.float64)
    gx[:, :-1] = ((lab_map[:, 1:] - lab_map[:, :-1]) ** 2).sum(-1)
    gy[:-1] = ((lab_map[1:] - lab_map[:-1]) ** 2).sum(-1)
    ok = region.copy()
    ok[:, :-1] &= region[:, 1:]
    ok[:-1] &= region[1:]
    ok[:, -1] = ok[-1] = False
    return np.where(ok, np.sqrt(gx + gy), np.nan)


def map_field(truth: np.ndarray, normal: np.ndarray, skin: np.ndarray) -> tuple[np.ndarray, float]:
    """The 3-D truth's (S, S, 3) linear log-luminance over ``skin`` (S, S) bool as far as 9
    spherical-harmonic terms of the fitted mesh's unit ``normal`` (S, S, 3) explain it (least
    squares): (S, S) float64, zero mean over the skin, 0 elsewhere; and its share of the variance."""
    log_y = np.log(np.maximum(luminance(truth[skin]), 1e-4)).astype(np.float64)
    basis = np.asarray(sh_basis(normal[skin].astype(np.float32)), np.float64)[:, :9]
    coefficients, *_ = np.linalg.lstsq(basis, log_y, rcond=None)
    explained = basis @ coefficients
    field = np.zeros(skin.shape)
    field[skin] = explained - explained.mean()
    return field, float(1.0 - np.var(log_y - explained) / max(float(np.var(log_y)), 1e-12))


def evaluate(scan: str, name: str, render: str, light: str, model, raster, skin_texels, truth3d: Truth3D, previous) -> dict:
    view = view_for(scan, render)
    photo = photo_of(view, light)
    S = raster.size
    observed = Observed.of(photo, model, raster)
    fit, mask, un = observed.fit, observed.mask, observed.unwrap
    m_vis = un.visibility
    cover = np.asarray(raster.inside)
    # truth at the seen texels: the scan colour image where the texel projects
    on_scan = view.mask.astype(np.float32)
    pixel = un.pixel
    seen = cover & (m_vis > 0.5)
    xy = pixel[seen]
    ok = sample_bilinear(on_scan, xy) > 0.999
    truth_seen = np.zeros((S, S, 3), np.float32)
    truth_seen_ok = np.zeros((S, S), bool)
    idx = np.flatnonzero(seen.ravel())
    truth_seen.reshape(-1, 3)[idx[ok]] = srgb_to_linear(sample_bilinear(view.albedo.astype(np.float32) / 255.0, xy[ok]))
    truth_seen_ok.ravel()[idx[ok]] = True
    # 3-D truth everywhere: the fitted mesh aligned to the scan on the seen texels
    geometry = geometry_maps(fit.vertices, model, raster, tangents=False)
    position = geometry.position
    px = np.clip(np.floor(xy[ok]).astype(int), 0, [view.camera.width - 1, view.camera.height - 1])
    target = view.points[px[:, 1], px[:, 0]]
    source = position.reshape(-1, 3)[idx[ok]]
    good = np.all(np.isfinite(target), axis=1)
    source, target = source[good], target[good]
    keep = np.ones(len(source), bool)
    for _ in range(4):  # trimmed: the worst 20 % (geometry errors, the mask's edges) left out
        s, R, t = similarity_transform(source[keep], target[keep])
        residual = np.linalg.norm(source @ R.T * s + t - target, axis=1)
        keep = residual <= np.quantile(residual, 0.8)
    aligned = position[cover] @ R.T * s + t
    colour, near = truth3d.lookup(aligned)
    truth = np.zeros((S, S, 3), np.float32)
    truth[cover] = colour
    truth_ok = np.zeros((S, S), bool)
    truth_ok[cover] = near
    skin = skin_texels & truth_ok
    seen_skin = skin & seen & truth_seen_ok
    filled_skin = skin & (m_vis < 0.5)
    # the methods' albedos (linear)
    new_backend = DefaultBackend()
    albedos = {"new": observed.albedo(model, new_backend, mask, S),
               "previous": observed.albedo(model, previous.backend(), previous.mask(photo, fit.landmarks), S)}
    t_inc = srgb_to_linear(un.texture)
    albedos["flat"] = np.broadcast_to(np.median(t_inc[seen & skin_texels], axis=0), (S, S, 3)).astype(np.float32)
    albedos["raw"] = t_inc
    texel_mm = float(np.median(np.linalg.norm(np.gradient(position, axis=1), axis=-1)[cover]))
    blur = max(0.5, float(np.median(-position[seen][:, 2])) / fit.camera.focal / texel_mm)
    lab_truth = lab(masked_blur(truth, skin, blur))
    g_truth = gradient(lab_truth, skin)
    boundary = np.zeros((S, S), bool)
    from scipy import ndimage

    seen_mask = seen | ~cover
    boundary = (ndimage.binary_dilation(seen_mask, iterations=3) & ndimage.binary_dilation(~seen_mask, iterations=3)) & skin
    rest = skin & ~ndimage.binary_dilation(boundary, iterations=6)

    def seam(g):
        a, b = np.nanmean(g[boundary]), np.nanmean(g[rest])
        return float(a / b) if np.isfinite(a) and np.isfinite(b) and b > 0 else float("nan")

    ctx = build_context(model, fit, raster)
    if DUMP is not None:
        DUMP.mkdir(parents=True, exist_ok=True)
        import cv2

        tiles = [truth_seen, truth] + [albedos[m] * exposure(albedos[m][seen_skin], truth_seen[seen_skin]) for m in METHODS]
        shown = skin | np.any([ctx.regions[region] > 0.5 for region in REGIONS], axis=0)  # the lips and eyes too
        tiles = [np.where(shown[..., None], linear_to_srgb(np.clip(t, 0, 1)), 0.3) for t in tiles]
        cv2.imwrite(str(DUMP / f"{render}_{light}.png"), cv2.cvtColor((np.concatenate(tiles, 1)[::2, ::2] * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
    # what any fill from the seen skin can reach: the truth's own colours on the seen texels,
    # extended over the rest by the new backend's gradient-domain fill (its private solver and its
    # use of the mirror's tone, trusted by the truth's own symmetry, so that the ceiling is the
    # same method's)
    reliable = DefaultBackend().reliability((seen & truth_ok).astype(np.float32), ctx)
    log_truth = np.log(np.maximum(truth, 1e-4))
    mean = (log_truth * reliable[..., None]).reshape(-1, 3).sum(0) / max(float(reliable.sum()), 1e-6)
    has, mirror = mirror_index(ctx)
    via_mirror = np.where(has, reliable.reshape(-1)[mirror], 0.0).astype(np.float32)
    values, weight, _, _ = with_mirror_tone(log_truth, reliable, reliable, via_mirror, skin_texels, ctx, DEFAULT_SETTINGS)
    extended = np.exp(fill_base(values, weight, mean, ctx, DEFAULT_SETTINGS.fill_smoothness, DEFAULT_SETTINGS))
    # the same backend on the truth's own colours where the photo saw the skin
    through = DefaultBackend()
    seen_truth = np.where(truth_seen_ok[..., None], truth_seen, truth)
    t_truth = np.where(seen[..., None], linear_to_srgb(np.clip(seen_truth, 0.0, 1.0)), 0.0).astype(np.float32)
    via_fill = srgb_to_linear(through.homogenise(through.inpaint(t_truth, m_vis, ctx), ctx))
    g_via = gradient(lab(masked_blur(via_fill * exposure(via_fill[seen_skin], truth_seen[seen_skin]), skin, blur)), skin)
    through_fill = [float(np.nanmean(g_via[m]) / np.nanmean(g_truth[m])) if m.any() else float("nan") for m in (skin, seen_skin, filled_skin)]
    # the light as rendered, as the skin shows it: the photo's chroma less the albedo pass's, median
    # over the seen skin texels neither clipped nor black; against the new backend's estimate (its
    # mean light, after the shrinkage towards neutral), which the albedo's colour depends on
    lit = seen_skin & np.all((t_inc > 0.01) & (t_inc < 0.98), axis=-1) & np.all(truth_seen > 0.01, axis=-1)
    rendered = np.median(chroma(t_inc[lit]) - chroma(truth_seen[lit]), axis=0) if lit.any() else np.full(2, np.nan)
    illuminant = new_backend.report["illuminant"]
    light_chroma = {"rendered": rendered.tolist(), "estimated": list(illuminant.get("light_chroma", [np.nan, np.nan])),
                    "white_used": bool(illuminant.get("white_used", False)), "white_chroma": illuminant.get("white_chroma"),
                    "white_miss": illuminant.get("white_miss"), "white_tint": illuminant.get("white_tint"),
                    "skin_chroma": illuminant.get("skin_chroma")}
    lab_truth_seen, lab_truth_3d = lab(truth_seen), lab(truth)
    # the map's shading-like lightness, and how much of it the new backend's albedo lost
    field, field_share = map_field(truth, geometry.normal, skin)
    k_new = exposure(albedos["new"][seen_skin], truth_seen[seen_skin])
    error = np.log(np.maximum(luminance(albedos["new"][seen_skin] * k_new), 1e-4)) - np.log(np.maximum(luminance(truth_seen[seen_skin]), 1e-4))
    error, along = error - np.median(error), field[seen_skin]
    beta = float((error * along).sum() / max(float((along * along).sum()), 1e-12))
    put_back = albedos["new"] * np.exp(-beta * field)[..., None].astype(np.float32)
    k_back = exposure(put_back[seen_skin], truth_seen[seen_skin])
    map_lightness = {"share": field_share, "span": [float(np.percentile(along, 5)), float(np.percentile(along, 95))],
                     "corr": float(np.corrcoef(error, along)[0, 1]), "beta": beta,
                     "de_seen_put_back": median_de(lab(put_back * k_back), lab_truth_seen, seen_skin)}
    out = {"scan": scan, "view": name, "light": light, "light_chroma": light_chroma, "map_lightness": map_lightness, "truth_through_fill_gradient": through_fill, "seen_texels": int(seen_skin.sum()), "filled_texels": int(filled_skin.sum()),
           "truth_seam": seam(g_truth), "blur_texels": blur, "fit_rms_px": fit.landmark_rms_px, "methods": {},
           "mirror_asymmetry": new_backend.report["inpaint"].get("mirror_asymmetry"),
           "mirror_tone": new_backend.report["inpaint"].get("mirror_tone"),
           "truth_extended_de_filled": median_de(lab(extended), lab_truth_3d, filled_skin)}
    skin_lab = lab_truth_3d[skin]
    centre = np.median(skin_lab, axis=0)
    deviation = skin_lab - centre
    robust = np.abs(deviation) < 3 * 1.4826 * np.median(np.abs(deviation), axis=0)
    inliers = deviation[robust.all(axis=1)]
    precision = np.linalg.inv(np.cov(inliers.T) + 1e-6 * np.eye(3))
    for method, albedo in albedos.items():
        k = exposure(albedo[seen_skin], truth_seen[seen_skin])
        scaled = albedo * k
        la = lab(scaled)
        de_seen = deltaE_ciede2000(la[seen_skin], lab_truth_seen[seen_skin])
        chroma_seen = np.linalg.norm(la[seen_skin][:, 1:] - lab_truth_seen[seen_skin][:, 1:], axis=1)
        r = {"de_seen": float(np.median(de_seen)), "chroma_seen": float(np.median(chroma_seen)), "level": 1.0 / k}
        if method != "raw":
            de_filled = deltaE_ciede2000(la[filled_skin], lab_truth_3d[filled_skin])
            r["de_filled"] = float(np.median(de_filled)) if filled_skin.any() else float("nan")
            r["chroma_filled"] = float(np.median(np.linalg.norm(la[filled_skin][:, 1:] - lab_truth_3d[filled_skin][:, 1:], axis=1))) if filled_skin.any() else float("nan")
            d = la[skin] - centre
            r["off_skin"] = float(np.mean(np.einsum("ni,ij,nj->n", d, precision, d) > OFF_SKIN_SIGMAS ** 2))
            g = gradient(lab(masked_blur(scaled, skin, blur)), skin)
            r["gradient"] = float(np.nanmean(g[skin]) / np.nanmean(g_truth[skin]))
            r["gradient_seen"] = float(np.nanmean(g[seen_skin]) / np.nanmean(g_truth[seen_skin]))
            r["gradient_filled"] = float(np.nanmean(g[filled_skin]) / np.nanmean(g_truth[filled_skin])) if filled_skin.any() else float("nan")
            r["seam"] = seam(g)
        if method in ("new", "previous", "raw"):  # per region: its seen texels against the photo-pixel truth
            r["regions_de_seen"] = {region: median_de(la, lab_truth_seen, (ctx.regions[region] > 0.5) & seen & truth_seen_ok)
                                    for region in REGIONS}
        out["methods"][method] = r
    return out


def exposure_series(scan: str, model, raster, skin_texels: np.ndarray) -> dict:
    """The :data:`EV_RENDER` view at each EV of :data:`EVS` (its linear RGB × 2^EV, clipped,
    8-bit sRGB), each reconstructed on its own (its own fit and skin mask, the new backend),
    compared with the 0 EV albedo with no exposure scale over the skin texels every photo sees
    (M_vis > 0.5): the median ΔE2000, the ratio of the albedos' median linear luminance, and the
    share of those texels clipped (a channel ≥ 254.5/255) in each photo."""
    image = view_for(scan, EV_RENDER).image
    albedos, photo_colour = {}, {}
    seen = skin_texels.copy()
    for ev in EVS:
        observed = Observed.of(regraded(image, 2.0 ** ev), model, raster)
        albedos[ev] = observed.albedo(model, DefaultBackend(), observed.mask, raster.size)
        photo_colour[ev] = observed.unwrap.texture
        seen &= observed.unwrap.visibility > 0.5
    reference_lab, reference_y = lab(albedos[0]), float(np.median(luminance(albedos[0][seen])))
    return {"scan": scan, "render": EV_RENDER, "texels": int(seen.sum()),
            "de": {str(ev): median_de(lab(albedos[ev]), reference_lab, seen) for ev in EVS if ev},
            "luminance_ratio": {str(ev): float(np.median(luminance(albedos[ev][seen]))) / reference_y for ev in EVS if ev},
            "clipped": {str(ev): float(np.mean(photo_colour[ev][seen].max(-1) >= 254.5 / 255.0)) for ev in EVS}}


class Previous:
    """The backend and skin mask of :data:`BASELINE_COMMIT`."""

    def __init__(self):
        self._backend = from_git("texturing/default_backend.py", "baseline_default_backend").DefaultBackend
        self._mask = from_git("facegeo/skin_mask.py", "baseline_skin_mask").skin_mask

    def backend(self):
        return self._backend()

    def mask(self, photo, landmarks) -> SkinMask:
        """The old mask as today's :class:`SkinMask` (it measured no white reference)."""
        old = self._mask(photo, landmarks)
        return SkinMask(old.occlusion, old.skin_probability, old.sample, old.mean, old.covariance, old.source, old.hands)


def fmt(x: float, digits: int = 2) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def in_bars(row: dict) -> bool:
    """Whether the view's light is one of the issue's bars (:data:`BAR_LIGHTS`)."""
    return row["light"] in BAR_LIGHTS


def mark(light: str) -> str:
    """" †" after a view or light that is not in the bars, else nothing."""
    return "" if light in BAR_LIGHTS else " †"


def mouth_over_cheeks(method: dict) -> float:
    """The mouth's (lips') seen ΔE2000 minus the cheeks'."""
    return method["regions_de_seen"]["lips"] - method["regions_de_seen"]["cheeks"]


def view_tables(rows: list[dict]) -> list[str]:
    """Every view's numbers per method, and the filled skin's against the truth extended."""
    lines = ["Views marked † are not in the bars (their lights are not the issue's).", "",
             "| scan | view | method | ΔE2000 seen | ΔE2000 filled | chroma seen / filled | gradient ratio (seen / filled) | seam ratio (truth) | off-skin % |",
             "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        where = f"{SCAN_LABELS[row['scan']]} | {row['view']}{mark(row['light'])}"
        for method in METHODS:
            r = row["methods"][method]
            if method == "raw":
                lines.append(f"| {where} | raw photo | {fmt(r['de_seen'])} | — | {fmt(r['chroma_seen'])} / — | — | — | — |")
                continue
            lines.append(f"| {where} | {method} | {fmt(r['de_seen'])} | {fmt(r['de_filled'])} | {fmt(r['chroma_seen'])} / {fmt(r['chroma_filled'])} | "
                         f"{fmt(r['gradient'])} ({fmt(r['gradient_seen'])} / {fmt(r['gradient_filled'])}) | {fmt(r['seam'])} ({fmt(row['truth_seam'])}) | "
                         f"{100 * r['off_skin']:.2f} |")
    lines += ["", "Filled skin, ΔE2000 median: the new backend, the flat colour, and the truth's own colours on the seen texels "
              "extended by the new backend's fill (what any fill from the seen skin reaches on that scan); the gradient ratio "
              "(all / seen / filled skin) of the new backend on the photo and on the truth's own colours on the seen texels "
              "(truth through the fill):", "",
              "| scan | view | new | flat | truth extended | gradient: new | gradient: truth through the fill |", "|---|---|---|---|---|---|---|"]
    for row in rows:
        new = row["methods"]["new"]
        via = row.get("truth_through_fill_gradient", [float("nan")] * 3)
        lines.append(f"| {SCAN_LABELS[row['scan']]} | {row['view']} | {fmt(new['de_filled'])} | {fmt(row['methods']['flat']['de_filled'])} | "
                     f"{fmt(row.get('truth_extended_de_filled', float('nan')))} | {fmt(new['gradient'])} ({fmt(new['gradient_seen'])} / "
                     f"{fmt(new['gradient_filled'])}) | {fmt(via[0])} ({fmt(via[1])} / {fmt(via[2])}) |")
    return lines


def light_colour_table(rows: list[dict]) -> list[str]:
    """Per view: the rendered light's chroma (log R/G, log B/G) as the seen skin shows it (the photo
    over the albedo pass), the new backend's estimate, the difference's length and its part along
    the Planckian direction (> 0: the estimate warmer than the light), and whether a white
    reference (sclera, teeth) was used."""
    lines = ["", "The light's colour per view: rendered (the photo's chroma less the albedo pass's, median over the "
             "seen skin) against the new backend's estimate (its mean light), chroma (log R/G, log B/G); the error's "
             "length and its part along the Planckian direction (> 0: estimated warmer than rendered):", "",
             "| scan | view | rendered | estimated | error | warmer by | white reference |", "|---|---|---|---|---|---|---|"]
    for row in rows:
        lc = row["light_chroma"]
        rendered, estimated = np.asarray(lc["rendered"]), np.asarray(lc["estimated"])
        error = estimated - rendered
        pair = lambda c: f"({c[0]:+.2f}, {c[1]:+.2f})"  # noqa: E731
        lines.append(f"| {SCAN_LABELS[row['scan']]} | {row['view']}{mark(row['light'])} | {pair(rendered)} | {pair(estimated)} | "
                     f"{np.linalg.norm(error):.2f} | {float(error @ PLANCKIAN):+.2f} | {'used' if lc['white_used'] else 'not used'} |")
    return lines


def map_lightness_table(rows: list[dict]) -> list[str]:
    """Per view: the map's shading-like lightness (:func:`map_field`) and what the new backend made of it."""
    lines = ["", "The maps' shading-like lightness per view (a diagnostic on the truth): the share of the 3-D truth's skin "
             "log-luminance variance that 9 spherical-harmonic terms of the fitted normals explain, its span over the seen skin "
             "(p5, p95); the new backend's seen log-luminance error against it (correlation, slope β: −1 all of it taken for "
             "light); the seen ΔE2000, and with β of it put back:", "",
             "| scan | view | share | span | correlation | β | ΔE2000 seen | put back |", "|---|---|---|---|---|---|---|---|"]
    for row in rows:
        m = row.get("map_lightness")
        if m is None:
            continue
        lines.append(f"| {SCAN_LABELS[row['scan']]} | {row['view']}{mark(row['light'])} | {fmt(m['share'])} | {m['span'][0]:+.2f}, "
                     f"{m['span'][1]:+.2f} | {m['corr']:+.2f} | {m['beta']:+.2f} | {fmt(row['methods']['new']['de_seen'])} | "
                     f"{fmt(m['de_seen_put_back'])} |")
    return lines


def light_tables(rows: list[dict]) -> list[str]:
    """Per scan and light (its views' median): the seen skin's ΔE2000 of the methods and the new
    backend's worst ratio to the flat colour's; then the new backend's seen ΔE2000 per region."""
    lines = ["", "Seen skin per light, ΔE2000 median over its views (0°, ±40°); new / flat: the worst view's ratio; new's "
             "level: its seen skin's luminance over the scan's (median over the views; no exposure scale):", "",
             "| scan | light | new | previous | flat | raw photo | new / flat, worst view | new's level |", "|---|---|---|---|---|---|---|---|"]
    groups = {}
    for row in rows:
        groups.setdefault((row["scan"], row["light"]), []).append(row)
    for (scan, light), subset in groups.items():
        cells = [fmt(statistics.median(r["methods"][m]["de_seen"] for r in subset)) for m in METHODS]
        worst = max(r["methods"]["new"]["de_seen"] / r["methods"]["flat"]["de_seen"] for r in subset)
        level = fmt(statistics.median(r["methods"]["new"]["level"] for r in subset))
        lines.append(f"| {SCAN_LABELS[scan]} | {LIGHTS[light][0]}{mark(light)} | {' | '.join(cells)} | {fmt(worst)} | {level} |")
    lines += ["", "Seen texels per region (`facegeo.skin_mask.vertex_regions` > 0.5; M_vis > 0.5), the new backend's ΔE2000 "
              "median against the photo-pixel truth (the view's exposure scale), median over the light's views; mouth − "
              "cheeks: the worst view:", "",
              "| scan | light | " + " | ".join(REGIONS.values()) + " | mouth − cheeks, worst view |", "|---|---|" + "---|" * (len(REGIONS) + 1)]
    for (scan, light), subset in groups.items():
        cells = [fmt(statistics.median(r["methods"]["new"]["regions_de_seen"][region] for r in subset)) for region in REGIONS]
        worst = max(mouth_over_cheeks(r["methods"]["new"]) for r in subset)
        lines.append(f"| {SCAN_LABELS[scan]} | {LIGHTS[light][0]}{mark(light)} | {' | '.join(cells)} | {fmt(worst)} |")
    return lines


def bar_table(rows: list[dict]) -> list[str]:
    """The issue's bars on the views of :data:`BAR_LIGHTS`, per scan and both, and on all views."""
    lines = ["", "The bars on the views of the issue's lights (" + ", ".join(LIGHTS[light][0] for light in BAR_LIGHTS)
             + "), per scan and both scans, and on all views:", "", "| bar | new | previous |", "|---|---|---|"]
    scans = list(dict.fromkeys(r["scan"] for r in rows))
    groups = [(f"{SCAN_LABELS[scan]}, bar lights", [r for r in rows if r["scan"] == scan and in_bars(r)]) for scan in scans]
    if len(scans) > 1:
        groups.append(("both scans, bar lights", [r for r in rows if in_bars(r)]))
    groups.append(("all views (even, warm, ring too)", rows))
    for label, subset in groups:
        if not subset:
            continue
        vals = {m: statistics.median(r["methods"][m]["de_seen"] for r in subset) for m in ("new", "previous")}
        lines.append(f"| {label}: seen ΔE2000 median over views ≤ 3.5 | {vals['new']:.2f} | {vals['previous']:.2f} |")
        ratios = {m: [r["methods"][m]["de_seen"] / r["methods"]["flat"]["de_seen"] for r in subset] for m in ("new", "previous")}
        lines.append(f"| {label}: seen ΔE / flat's, worst view ≤ 0.7 | {max(ratios['new']):.2f} | {max(ratios['previous']):.2f} |")
        lines.append(f"| {label}: seen ΔE / flat's, median over views | {statistics.median(ratios['new']):.2f} | {statistics.median(ratios['previous']):.2f} |")
        mouth = {m: max(mouth_over_cheeks(r["methods"][m]) for r in subset) for m in ("new", "previous")}
        lines.append(f"| {label}: mouth − cheeks seen ΔE2000, worst view ≤ 1 | {mouth['new']:.2f} | {mouth['previous']:.2f} |")
        for text, key, agg in (("filled ΔE2000 median over views ≤ 6 (issue 26)", "de_filled", statistics.median),
                               ("gradient ratio, range over views in 0.8–1.5", "gradient", None),
                               ("seam ratio, worst view ≤ 1.2", "seam", max),
                               ("off-skin %, worst view ≤ 1", "off_skin", max)):
            cells = []
            for m in ("new", "previous"):
                vals = [r["methods"][m][key] for r in subset if np.isfinite(r["methods"][m][key])]
                if agg is None:
                    cells.append(f"{min(vals):.2f}–{max(vals):.2f}")
                elif key == "off_skin":
                    cells.append(f"{100 * agg(vals):.2f}")
                else:
                    cells.append(f"{agg(vals):.2f}")
            lines.append(f"| {label}: {text} | {cells[0]} | {cells[1]} |")
    return lines


def exposure_table(series: list[dict]) -> list[str]:
    """The exposure series (:func:`exposure_series`) per scan (none: no table); the bar: within ΔE2000 2 of each other."""
    if not series:
        return []
    evs = [ev for ev in EVS if ev]
    lines = ["", f"Exposure series: the `{EV_RENDER}` render (yaw 0°) at " + ", ".join(map(ev_label, EVS)) + " EV, each "
             "reconstructed on its own (own fit, new backend), the albedos compared with the 0 EV one with no exposure scale "
             "over the skin texels all of them see (bar: ΔE2000 ≤ 2); luminance: the ratio of the albedos' median linear "
             "luminance; clipped: the share of those texels at 255 in a channel in each photo:", "",
             "| scan | texels | " + " | ".join(f"ΔE2000 {ev_label(ev)} EV vs 0" for ev in evs) + " | "
             + " | ".join(f"luminance {ev_label(ev)} / 0" for ev in evs) + " | clipped % (" + ", ".join(map(ev_label, EVS)) + " EV) |",
             "|---|---|" + "---|" * (2 * len(evs) + 1)]
    for row in series:
        clipped = ", ".join(f"{100 * row['clipped'][str(ev)]:.1f}" for ev in EVS)
        lines.append(f"| {SCAN_LABELS[row['scan']]} | {row['texels']} | " + " | ".join(fmt(row["de"][str(ev)]) for ev in evs) + " | "
                     + " | ".join(fmt(row["luminance_ratio"][str(ev)], 3) for ev in evs) + f" | {clipped} |")
    return lines


def report(rows: list[dict], series: list[dict]) -> list[str]:
    """The markdown tables: the views, the lights and regions, the bars and the exposure series."""
    return view_tables(rows) + light_colour_table(rows) + map_lightness_table(rows) + light_tables(rows) + bar_table(rows) + exposure_table(series)


def time_stages(rounds: int, photo_name: str | None = None) -> list[str]:
    """Wall time of the texture stages (inpaint + homogenise + materials, all maps) at S = 1024 on
    the bundled photo (a directional light) or the sample photo ``photo_name``
    (:mod:`sample_photos`), the previous backend and the new one alternating on one fit, unwrap
    and context (the new skin mask for both): markdown lines with min and median."""
    from facegeo.assets import asset_path
    from facegeo.photo import load_photo
    from facegeo.texturing.context import build_context
    from facegeo.uv import unwrap

    model = facegeo.load_model()
    if photo_name is None:
        path = asset_path("photos/astronaut.png")
    else:
        from sample_photos import sample_photos, white_house_photos

        found = [p for p in sample_photos() + white_house_photos() if p.name == photo_name]
        if not found:
            raise SystemExit(f"--photo: no sample photo named {photo_name!r}")
        path = found[0]
    photo = load_photo(path)
    fit = facegeo.fit(photo, model)
    raster = rasterize_uv(model, size=1024)
    maps = geometry_maps(fit.vertices, model, raster, tangents=False)
    mask = skin_mask(photo.image, fit.landmarks)
    t_inc, m_vis = unwrap(photo.image, fit, model, maps=maps, occlusion=mask.occlusion)
    ctx = build_context(model, fit, raster, maps, white_reference=mask.white_reference)
    previous = Previous()
    times: dict[str, list[float]] = {"previous": [], "new": []}
    start = load()
    for _ in range(rounds):
        for label, backend in (("previous", previous.backend()), ("new", DefaultBackend())):
            t = time.perf_counter()
            backend.materials(backend.homogenise(backend.inpaint(t_inc, m_vis, ctx), ctx), ctx)
            times[label].append(time.perf_counter() - t)
    lines = [f"Texture stages (inpaint + homogenise + materials, all maps) on `{path.name}`, S = 1024, "
             f"torch threads {torch.get_num_threads()}, {rounds} alternating rounds; load average {start} at the start, "
             f"{load()} at the end:", "", "| backend | min s | median s |", "|---|---|---|"]
    for label, values in times.items():
        lines.append(f"| {label} | {min(values):.2f} | {statistics.median(values):.2f} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024, help="map size S")
    ap.add_argument("--views", default="", help="comma-separated indices into VIEWS (default all)")
    ap.add_argument("--scans", nargs="+", default=list(SCAN_LABELS), choices=list(SCAN_LABELS), help="the scans (default both)")
    ap.add_argument("--write", type=Path, default=None, help="also write the markdown report here")
    ap.add_argument("--json", type=Path, default=None, help="also write the raw numbers here")
    ap.add_argument("--time-stages", type=int, default=0, metavar="ROUNDS", help="only time the texture stages, this many rounds")
    ap.add_argument("--photo", default=None, help="with --time-stages: a sample photo by file name (default the bundled astronaut)")
    ap.add_argument("--no-series", action="store_true", help="leave out the exposure series (EV_RENDER at EVS)")
    ap.add_argument("--dump", type=Path, default=None, help="write the compared UV maps (truth seen, truth 3-D, methods) here")
    args = ap.parse_args(argv)
    global DUMP
    DUMP = args.dump
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    if args.time_stages:
        print("\n".join(time_stages(args.time_stages, args.photo)))
        return 0
    load_start, t_start = load(), time.perf_counter()
    model = facegeo.load_model()
    raster = rasterize_uv(model, size=args.size)
    surf = surface_operators(model, raster)
    skin_texels = (surf.to_texels(skin_vertex_mask(model).astype(np.float32), args.size) > 0.5) & np.asarray(raster.inside)
    previous = Previous()
    chosen = [VIEWS[int(i)] for i in args.views.split(",") if i] or VIEWS
    rows, series, refused = [], [], []
    for scan in args.scans:
        truth3d = Truth3D.build(scan)
        for name, render, light in chosen:
            try:
                row = evaluate(scan, name, render, light, model, raster, skin_texels, truth3d, previous)
            except NoFaceError as error:  # the fit's own check refused the view
                refused.append(f"{SCAN_LABELS[scan]} {name} ({error})")
                continue
            rows.append(row)
            print(json.dumps(row), file=sys.stderr)
        if not args.no_series:
            try:
                series.append(exposure_series(scan, model, raster, skin_texels))
            except NoFaceError as error:
                refused.append(f"{SCAN_LABELS[scan]} exposure series ({error})")
                continue
            print(json.dumps(series[-1]), file=sys.stderr)
    header = [f"command: `python benchmarks/bench_albedo_scans.py {' '.join(sys.argv[1:] if argv is None else argv)}`",
              f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}; load average at start {load_start}, "
              f"at end {load()}; total {time.perf_counter() - t_start:.0f} s; S = {args.size}; scans {', '.join(f'`{s}`' for s in args.scans)}, renders 512×768; "
              f"previous = `DefaultBackend` + `skin_mask` of {BASELINE_COMMIT}", ""]
    if refused:
        header[-1:-1] = ["views whose fit `facegeo.fit` refused (left out): " + "; ".join(refused)]
    text = "\n".join(header + report(rows, series)) + "\n"
    print(text)
    if args.write is not None:
        args.write.write_text(text)
    if args.json is not None:
        args.json.write_text(json.dumps({"views": rows, "exposure_series": series}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
