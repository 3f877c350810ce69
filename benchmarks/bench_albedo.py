"""Albedo benchmark with ground truth (issue 14): procedural skin on model heads, rendered with a
directional light, its cast shadows and SH ambient, occluders composited into the photo, through
the real pipeline (fit, skin mask, unwrap, texture backend).

Landmarks: the true 88 points projected from the rendered head (``--detect`` detects them on
the render instead: detectors put the brows on the glasses' upper rims there, 17 px mean error and
a misregistered texture, a fitting matter this benchmark keeps apart). Everything else (the
photometric fit, MediaPipe's mesh for the skin mask, the unwrap, the backends) runs as in
``facegeo reconstruct``.

Scenes (bundled ICT-FaceKit model, 768² photo, 40° fov, 600 mm away):

* ground truth per texel, a function of the model-space position of the rendered head (so it is
  continuous across UV seams) and of the facial regions (:func:`facegeo.skin_mask.vertex_regions`): a skin
  tone, low-frequency mottling, redness on cheeks and nose, freckles, pores, stubble (one head),
  red lips and dark brows; roughness 0.4, specular 0.6, flat normals;
* shading: ``shade_ggx`` (diffuse + GGX specular) of one directional light, times its cast-shadow
  map (the mesh z-buffered from the light, 1.5 mm bias), plus SH ambient (``sh_irradiance``);
  rendered with ``facegeo.uv.render``;
* occluders composited with known alpha: a hair fringe (strands) and the hair mass above it,
  glasses (dark frames, clear lenses), a shirt collar, a hand (skin-coloured) over the jaw.

Metrics over skin texels (``skin_vertex_mask``: face without eyes, brows, lips; seen and unseen),
after one global scalar scale of the albedo's linear luminance onto the truth (de-lighting leaves
the light's intensity unknown; chroma is not fitted), with both maps blurred by a Gaussian of one
photo pixel's footprint in texels (σ = (600 mm / focal) / median texel size; the photo cannot
resolve finer detail such as single stubble hairs; ``--full-resolution`` compares texel by texel):

* ΔE2000 (``skimage.color.deltaE_ciede2000``) median and 90th percentile, PSNR on sRGB;
* occluder leak: of the skin texels the camera sees where an occluder covers them (alpha > 0.5,
  facing > 0.3), the share whose albedo is off by ΔE2000 > 5 and nearer the occluder's colour
  (the photo divided by the true shading) than the truth;
* ΔE2000 median over those occluded texels (a skin-coloured hand rarely counts as a leak above,
  its outline and shading show here);
* chroma cast: |mean Δ(a*, b*)| over skin;
* seam contrast: median ΔE2000 between the albedo's colours at the two UV positions of the same
  vertex along UV seams (the truth has 0 there);
* boundary contrast: mean ΔE2000 between neighbouring texels across the visibility boundary
  (M_vis = 0.5) minus the truth's.

The current backend (``DefaultBackend`` of git commit ``BASELINE_COMMIT``, loaded from git, with
the unwrap's plain M_vis as before the skin mask) runs beside the new one on the same photos.

    python benchmarks/bench_albedo.py --write /tmp/albedo.md     # ~5 min on 2 cores
    python benchmarks/bench_albedo.py --time-stages               # texture-stage times of both backends
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
import types
from pathlib import Path

import cv2
import numpy as np
import torch
from skimage.color import deltaE_ciede2000, rgb2lab

import facegeo
from facegeo.camera import Camera, project, rotation_from_euler, to_pixels
from facegeo.colour import linear_to_srgb, luminance, srgb_to_linear
from facegeo.lighting import sh_irradiance
from facegeo.pipeline import reconstruct_with_fit
from facegeo.skin_mask import SkinMask, skin_vertex_mask, vertex_regions
from facegeo.texturing.context import surface_operators
from facegeo.texturing.default import DefaultBackend
from facegeo.texturing.default.noise import value_noise
from facegeo.texturing.image_filters import masked_blur
from facegeo.texturing.shading import shade_ggx
from facegeo.uv.texels import sample_uv
from facegeo.uv import geometry_maps, rasterize_mesh, rasterize_uv, render, unwrap_details
from facegeo.landmarks.scheme import BROWS, IBUG68, LEFT_EYE, RIGHT_EYE

ROOT = Path(__file__).resolve().parents[1]
BASELINE_COMMIT = "0477a8f"
PHOTO = 768
DISTANCE_MM = 600.0

#: name, identity seed (None: mean head), yaw, pitch, light direction (camera space, towards the
#: light), skin tone (sRGB), stubble, occluders
SCENES = [
    ("frontal", None, 0.0, 5.0, (-0.5, 0.5, 0.7), (0.86, 0.66, 0.56), False, ("fringe", "glasses", "collar")),
    ("turned 30°", 1, 30.0, 3.0, (0.6, 0.3, 0.75), (0.74, 0.53, 0.41), False, ("glasses", "collar", "hand")),
    ("stubble, turned −20°", 2, -20.0, 8.0, (0.1, 0.7, 0.7), (0.80, 0.60, 0.50), True, ("fringe", "collar", "hand")),
]


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


# ------------------------------------------------------------------------------------ ground truth
def truth_albedo(model, shape: np.ndarray, raster, tone, stubble: bool, seed: int) -> np.ndarray:
    """(S, S, 3) sRGB albedo of the head ``shape`` (model space, mm)."""
    S = raster.size
    surf = surface_operators(model, raster)
    pos = geometry_maps(shape, model, raster, tangents=False).position
    inside = np.asarray(raster.mask)
    p = pos[inside]
    regions = {k: surf.to_texels(v, S)[inside] for k, v in vertex_regions(model).items()}
    lin = np.tile(srgb_to_linear(np.asarray(tone, np.float32)), (len(p), 1))
    lin *= (1 + 0.06 * value_noise(p, 6.0, seed))[:, None]  # mottling
    red = np.clip(value_noise(p, 10.0, seed + 1) + 0.3, 0, 1) * np.clip(regions["cheeks"] + regions["nose"], 0, 1)
    lin *= 1 + 0.35 * red[:, None] * np.array([0.5, -0.35, -0.3])  # redness
    lin *= (1 + 0.05 * value_noise(p, 0.3, seed + 2))[:, None]  # pores
    lin *= np.where(value_noise(p, 0.45, seed + 3) > 0.55, 0.82, 1.0)[:, None]  # pore pits
    freckle_area = np.clip(regions["cheeks"] + regions["nose"] + 0.5 * regions["forehead"], 0, 1)
    freckle = (value_noise(p, 1.6, seed + 4) > 0.5) & (freckle_area > 0.3)
    lin = np.where(freckle[:, None], lin * np.array([0.72, 0.62, 0.55]), lin)
    if stubble:
        lm = model.mean_shape[model.landmark_indices[IBUG68]]
        lower = (p[:, 1] < lm[33, 1] - 3.0) & (p[:, 2] > lm[0, 2] - 10.0)  # below the nose, front of the jaw
        lips_zone = regions["lips"] > 0.2
        dots = (value_noise(p, 0.35, seed + 5) > 0.2) & lower & ~lips_zone
        lin = np.where(dots[:, None], lin * 0.45, lin)
    lips = np.clip(regions["lips"], 0, 1)[:, None]
    lin = lin * (1 - lips) + lips * srgb_to_linear(np.array([0.72, 0.36, 0.36], np.float32))
    brows = np.clip(regions["brows"] * 1.5, 0, 1)[:, None]
    lin = lin * (1 - brows) + brows * srgb_to_linear(np.array([0.28, 0.19, 0.13], np.float32))
    out = np.zeros((S, S, 3), np.float32)
    out[inside] = linear_to_srgb(np.clip(lin, 0, 1))
    return out


def shadow_map(vertices_cam: np.ndarray, model, light: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N,) float32 1 where ``points`` (camera space) see the directional ``light``, else 0: the
    mesh is z-buffered from 3 m along the light (near-orthographic, 1024²), bias 1.5 mm."""
    centre = vertices_cam.mean(0)
    z = light / np.linalg.norm(light)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    frame = np.stack([x, y, z])

    def to_light(pts):
        q = (pts - centre) @ frame.T
        q[:, 2] -= 3000.0
        return q

    cam = Camera.for_image(1024, 1024, 8.0)
    _, _, depth = rasterize_mesh(to_light(vertices_cam), model.triangles, cam, barycentric=False)
    q = to_light(points.astype(np.float64))
    d = -q[:, 2]
    px, py = to_pixels(q, cam).T
    ix = np.clip(np.floor(px).astype(np.int64), 0, cam.width - 1)
    iy = np.clip(np.floor(py).astype(np.int64), 0, cam.height - 1)
    zb = np.where(np.isfinite(depth), depth, 1e9)[iy, ix]
    return (d <= zb + 1.5).astype(np.float32)


def shaded_texture(model, vertices_cam, raster, albedo_srgb, light) -> tuple[np.ndarray, np.ndarray]:
    """(S, S, 3) sRGB texture under the scene's lighting and (S, S) the true shading's luminance
    factor (linear, per texel: shaded = albedo × factor in luminance)."""
    maps = geometry_maps(vertices_cam, model, raster)
    S = raster.size
    chw = lambda a: torch.from_numpy(np.ascontiguousarray((a[..., None] if a.ndim == 2 else a).transpose(2, 0, 1), np.float32))[None]  # noqa: E731
    albedo = srgb_to_linear(albedo_srgb)
    l = np.asarray(light, np.float32) / np.linalg.norm(light)
    out = shade_ggx(chw(albedo), chw(np.broadcast_to(np.float32([0, 0, 1]), (S, S, 3))), chw(np.full((S, S), 0.4)),
                    chw(np.full((S, S), 0.6)), chw(np.zeros((S, S))), chw(maps.position), chw(maps.normal),
                    chw(maps.tangent), chw(maps.mask.astype(np.float32)), torch.from_numpy(l)[None, None],
                    torch.full((1, 1, 3), 2.0), torch.zeros(1, 3), 0.0, s_disp=1.0)
    direct = out.shaded[0].numpy().transpose(1, 2, 0)
    lit = np.zeros((S, S), np.float32)
    inside = np.asarray(maps.mask)
    lit[inside] = shadow_map(vertices_cam, model, l, maps.position[inside])
    gamma = np.zeros((3, 9), np.float32)
    gamma[:, 0] = 0.42 * np.array([0.95, 1.0, 1.08])  # slightly blue sky ambient
    gamma[:, 1] = -0.08  # brighter from above
    ambient = sh_irradiance(torch.from_numpy(maps.normal.reshape(-1, 3)), torch.from_numpy(gamma)).numpy().reshape(S, S, 3)
    linear = direct * lit[..., None] + albedo * ambient
    factor = luminance(linear) / np.maximum(luminance(albedo), 1e-6)
    return linear_to_srgb(linear), factor


# ------------------------------------------------------------------------------------ occluders
def occluders(kinds, lm: np.ndarray, shape: tuple[int, int], rng) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) colour and (H, W) alpha of the occluders, from the 68 projected landmarks."""
    H, W = shape
    colour = np.zeros((H, W, 3), np.float32)
    alpha = np.zeros((H, W), np.float32)
    iod = float(np.linalg.norm(lm[RIGHT_EYE].mean(0) - lm[LEFT_EYE].mean(0)))
    brow_y = float(lm[BROWS, 1].min())

    def paint(mask: np.ndarray, rgb):
        m = mask.astype(np.float32)
        colour[:] = colour * (1 - m[..., None]) + m[..., None] * np.asarray(rgb, np.float32)
        alpha[:] = np.maximum(alpha, m)

    if "fringe" in kinds:
        top = brow_y - 0.75 * iod
        mass = np.zeros((H, W), np.uint8)
        cx = float(lm[27, 0])
        cv2.ellipse(mass, (int(cx), int(top)), (int(1.6 * iod), int(0.9 * iod)), 0, 180, 360, 1, -1)
        mass[: max(0, int(top)), :] = 1
        paint(mass, (0.20, 0.12, 0.07))
        for _ in range(160):  # strands hanging over the forehead towards one side
            x0 = rng.uniform(lm[17, 0] - 0.2 * iod, cx + 0.4 * iod)
            length = rng.uniform(0.3, 0.75) * iod
            pts = np.array([[x0, top], [x0 + 0.15 * length, top + 0.5 * length], [x0 + 0.35 * length, top + length]])
            strand = np.zeros((H, W), np.uint8)
            cv2.polylines(strand, [np.round(pts).astype(np.int32)], False, 1, thickness=int(rng.integers(2, 4)), lineType=cv2.LINE_AA)
            paint(strand, np.array([0.22, 0.13, 0.07]) * rng.uniform(0.7, 1.4))
    if "glasses" in kinds:
        frame = np.zeros((H, W), np.uint8)
        t = max(2, int(0.06 * iod))
        centres = [lm[RIGHT_EYE].mean(0), lm[LEFT_EYE].mean(0)]
        for c in centres:
            cv2.ellipse(frame, (int(c[0]), int(c[1] + 0.05 * iod)), (int(0.36 * iod), int(0.25 * iod)), 0, 0, 360, 1, t)
        cv2.line(frame, (int(centres[0][0] + 0.36 * iod), int(centres[0][1])), (int(centres[1][0] - 0.36 * iod), int(centres[1][1])), 1, t)
        cv2.line(frame, (int(centres[0][0] - 0.36 * iod), int(centres[0][1])), (int(lm[0, 0]), int(lm[0, 1] - 0.1 * iod)), 1, t)
        cv2.line(frame, (int(centres[1][0] + 0.36 * iod), int(centres[1][1])), (int(lm[16, 0]), int(lm[16, 1] - 0.1 * iod)), 1, t)
        paint(frame, (0.05, 0.05, 0.06))
    if "collar" in kinds:
        collar = np.zeros((H, W), np.uint8)
        jaw = lm[3:14].copy()
        jaw[:, 1] += 0.55 * iod
        poly = np.concatenate([[[jaw[0, 0] - iod, H]], jaw, [[jaw[-1, 0] + iod, H]]])
        cv2.fillPoly(collar, [np.round(poly).astype(np.int32)], 1)
        paint(collar, (0.55, 0.66, 0.82))
    if "hand" in kinds:
        hand = np.zeros((H, W), np.uint8)
        side = 1 if rng.random() < 0.5 else -1
        j = lm[4] if side < 0 else lm[12]
        palm = (int(j[0] + side * 0.1 * iod), int(j[1] + 0.35 * iod))
        cv2.ellipse(hand, palm, (int(0.45 * iod), int(0.55 * iod)), 0, 0, 360, 1, -1)
        for k in range(4):
            x = palm[0] + int((k - 1.5) * 0.22 * iod)
            cv2.ellipse(hand, (x, int(palm[1] - 0.7 * iod)), (int(0.1 * iod), int(0.4 * iod)), 5 * (k - 1.5), 0, 360, 1, -1)
        shade = np.linspace(0.8, 1.05, W, dtype=np.float32)[None, :, None] * np.ones((H, 1, 1), np.float32)
        tone = np.array([0.80, 0.58, 0.47], np.float32)
        m = hand.astype(np.float32)
        colour[:] = colour * (1 - m[..., None]) + m[..., None] * tone * shade
        alpha[:] = np.maximum(alpha, m)
    alpha = cv2.GaussianBlur(alpha, (0, 0), 0.7)
    return colour, np.clip(alpha, 0, 1)


# ------------------------------------------------------------------------------------ metrics
def scaled(albedo_srgb: np.ndarray, truth_srgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    a, t = srgb_to_linear(albedo_srgb), srgb_to_linear(truth_srgb)
    ya, yt = luminance(a[mask]), luminance(t[mask])
    k = float((ya * yt).sum() / max((ya * ya).sum(), 1e-12))
    return linear_to_srgb(a * k)


def lab(srgb: np.ndarray) -> np.ndarray:
    return rgb2lab(np.clip(srgb, 0, 1).astype(np.float64))


def seam_pairs(model) -> np.ndarray:
    """(P, 2, 2) UV pairs of the same vertex on both sides of a UV seam."""
    tri, uvt = np.asarray(model.triangles).ravel(), np.asarray(model.uv_triangles).ravel()
    pairs = np.unique(np.stack([tri, uvt], 1), axis=0)
    out = []
    starts = np.flatnonzero(np.r_[True, pairs[1:, 0] != pairs[:-1, 0]])
    ends = np.r_[starts[1:], len(pairs)]
    for s, e in zip(starts, ends):
        if e - s >= 2:
            out.append(model.uv[pairs[[s, s + 1], 1]])
    return np.asarray(out, np.float32)


def metrics(albedo, truth, skin, occluded, occ_albedo, m_vis, pairs, blur: float, cover: np.ndarray,
            dump: Path | None = None) -> dict:
    a = scaled(albedo, truth, skin)
    de_full = deltaE_ciede2000(lab(a)[occluded], lab(truth)[occluded])  # leaks are judged texel by texel
    de_occ = deltaE_ciede2000(lab(a)[occluded], lab(occ_albedo)[occluded])
    leak = (de_full > 5) & (de_occ < de_full)
    de_occluded = float(np.median(de_full)) if occluded.any() else 0.0
    if blur > 0:  # both at the photo's resolution: detail finer than a pixel cannot be recovered
        a = masked_blur(a, cover, blur)
        truth = masked_blur(truth, cover, blur)
    la, lt = lab(a), lab(truth)
    de = deltaE_ciede2000(la, lt)
    mse = float(np.mean((a[skin] - truth[skin]) ** 2))
    cast = np.abs((la[skin, 1:] - lt[skin, 1:]).mean(0))
    if dump is not None:  # ΔE map (white = 20) with leaking texels in red
        heat = np.repeat(np.clip(np.where(skin, de, 0) / 20, 0, 1)[..., None], 3, -1)
        rows, cols = np.nonzero(occluded)
        heat[rows[leak], cols[leak]] = (1, 0, 0)
        cv2.imwrite(str(dump), cv2.cvtColor((heat * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
    sa, sb = sample_uv(a, pairs[:, 0]), sample_uv(a, pairs[:, 1])
    seam = deltaE_ciede2000(lab(sa[None])[0], lab(sb[None])[0])
    seen = m_vis >= 0.5
    edge = skin[:, :-1] & skin[:, 1:] & (seen[:, :-1] != seen[:, 1:])
    jump = deltaE_ciede2000(la[:, :-1][edge], la[:, 1:][edge]).mean() - deltaE_ciede2000(lt[:, :-1][edge], lt[:, 1:][edge]).mean()
    return dict(de_median=float(np.median(de[skin])), de_p90=float(np.percentile(de[skin], 90)),
                de_seen=float(np.median(de[skin & seen])), de_unseen=float(np.median(de[skin & ~seen])),
                psnr=10 * np.log10(1 / max(mse, 1e-12)), leak=float(leak.mean()) if occluded.any() else 0.0,
                n_occluded=int(occluded.sum()), de_occluded=de_occluded, cast=float(np.hypot(*cast)), seam=float(np.median(seam)),
                boundary=float(jump))


def baseline_backend():
    """The DefaultBackend class of :data:`BASELINE_COMMIT` (loaded from git)."""
    code = subprocess.run(["git", "show", f"{BASELINE_COMMIT}:texturing/default_backend.py"], cwd=ROOT,
                          capture_output=True, text=True, check=True).stdout
    module = types.ModuleType("baseline_default_backend")
    sys.modules[module.__name__] = module  # dataclasses look their module up
    exec(compile(code, f"{BASELINE_COMMIT}:texturing/default_backend.py", "exec"), module.__dict__)
    return module.DefaultBackend


def time_stages(model, Baseline, rounds: int = 3) -> list[str]:
    """Wall time of unwrap + context + inpaint + homogenise + materials at S = 1024 on the bundled
    photo for both backends (one fit, alternating), and of the skin mask: markdown lines."""
    import statistics

    from facegeo.assets import asset_path
    from facegeo.photo import load_photo
    from facegeo.skin_mask import skin_mask
    from facegeo.texturing.context import build_context
    from facegeo.uv import unwrap

    photo = load_photo(asset_path("photos/astronaut.png"))
    fit = facegeo.fit(photo, model)
    raster = rasterize_uv(model, size=1024)
    maps = geometry_maps(fit.vertices, model, raster, tangents=False)
    times: dict[str, list[float]] = {"skin mask": [], "current": [], "new": []}
    start = load()
    for _ in range(rounds):
        t = time.perf_counter()
        mask = skin_mask(photo.image, fit.landmarks)
        times["skin mask"].append(time.perf_counter() - t)
        for label, backend, occlusion in (("current", Baseline(), None), ("new", DefaultBackend(), mask.occlusion)):
            t = time.perf_counter()
            t_inc, m_vis = unwrap(photo.image, fit, model, maps=maps, occlusion=occlusion)
            ctx = build_context(model, fit, raster, maps)
            full = backend.inpaint(t_inc, m_vis, ctx)
            backend.materials(backend.homogenise(full, ctx), ctx)
            times[label].append(time.perf_counter() - t)
    lines = ["", f"Texture stages on `photos/astronaut.png` (S = 1024, one fit, {rounds} alternating rounds; load average "
             f"{start} at the start, {load()} at the end):", "", "| step | min s | median s |", "|---|---|---|"]
    for label, values in times.items():
        name = label if label == "skin mask" else f"{label} backend: unwrap + context + inpaint + homogenise + materials"
        lines.append(f"| {name} | {min(values):.2f} | {statistics.median(values):.2f} |")
    return lines


# ------------------------------------------------------------------------------------ main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024, help="map size S")
    ap.add_argument("--write", type=Path, default=None, help="also write the markdown report here")
    ap.add_argument("--dump", type=Path, default=None, help="write photos and albedos of each scene here (PNG)")
    ap.add_argument("--scenes", default="", help="comma-separated scene indices (default all)")
    ap.add_argument("--new-only", action="store_true", help="skip the current backend (for tuning)")
    ap.add_argument("--time-stages", action="store_true", help="only time the texture stages of both backends on the bundled photo")
    ap.add_argument("--full-resolution", action="store_true", help="compare texel by texel, without the photo-resolution blur")
    ap.add_argument("--detect", action="store_true", help="detect the landmarks on the render instead of using the true ones")
    args = ap.parse_args(argv)
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    model = facegeo.load_model()
    camera = Camera.for_image(PHOTO, PHOTO, 40.0)
    raster = rasterize_uv(model, size=args.size)
    surf = surface_operators(model, raster)
    cover = np.asarray(raster.inside)
    skin = (surf.to_texels(skin_vertex_mask(model).astype(np.float32), args.size) > 0.5) & cover
    pairs = seam_pairs(model)
    Baseline = baseline_backend()
    if args.time_stages:
        print("\n".join(time_stages(model, Baseline)))
        return 0
    load_start, t_start = load(), time.perf_counter()
    rows = []
    chosen = [int(i) for i in args.scenes.split(",") if i] or range(len(SCENES))
    for index in chosen:
        name, id_seed, yaw, pitch, light, tone, stubble, kinds = SCENES[index]
        rng = np.random.default_rng(index)
        alpha = None if id_seed is None else np.random.default_rng(id_seed).normal(0, 0.8, model.n_id).astype(np.float32)
        shape = model.shape(None if alpha is None else torch.from_numpy(alpha)).numpy()
        R = rotation_from_euler(yaw, pitch, 0.0)
        t = np.array([0.0, 0.0, -DISTANCE_MM])
        vertices_cam = (shape @ R.T + t).astype(np.float32)
        truth = truth_albedo(model, shape, raster, tone, stubble, seed=index)
        # one photo pixel's footprint in texels (σ of the resolution-matched comparison)
        texel_mm = float(np.median(np.linalg.norm(np.gradient(geometry_maps(shape, model, raster, tangents=False).position, axis=1), axis=-1)[cover]))
        blur = 0.0 if args.full_resolution else (DISTANCE_MM / camera.focal) / texel_mm
        texture, factor = shaded_texture(model, vertices_cam, raster, truth, np.asarray(light, np.float32))
        view = render(vertices_cam, model, camera, texture=texture, background=(0.42, 0.45, 0.5))
        lm88 = np.asarray(project(shape[model.landmark_indices].astype(np.float64), R, t, camera), np.float32)
        lm = lm88[IBUG68]
        occ_rgb, occ_a = occluders(kinds, np.asarray(lm), (PHOTO, PHOTO), rng)
        photo_f = view.image * (1 - occ_a[..., None]) + occ_rgb * occ_a[..., None]
        photo = np.clip(np.round(photo_f * 255), 0, 255).astype(np.uint8)
        results = {}
        for label, backend, mask in [("current", Baseline(), "none"), ("new", DefaultBackend(), None)][1 if args.new_only else 0:]:
            none = None
            if mask == "none":
                none = SkinMask(np.zeros((PHOTO, PHOTO), np.float32), np.ones((PHOTO, PHOTO), np.float32),
                                np.zeros((PHOTO, PHOTO), bool), np.zeros(2), np.eye(2), "none")
            t0 = time.perf_counter()
            asset, fit = reconstruct_with_fit(photo, model, backend=backend, size=args.size, maps={"albedo"}, skin=none,
                                              landmarks=None if args.detect else lm88)
            seconds = time.perf_counter() - t0
            un = unwrap_details(photo, fit, model, raster=raster, occlusion=occ_a)
            occluded = skin & (un.occlusion > 0.5) & (un.coverage * un.facing > 0.3)
            # what the occluder would look like as albedo: the photo divided by the true shading
            occ_albedo = linear_to_srgb(srgb_to_linear(un.texture) / np.maximum(factor, 1e-3)[..., None])
            m_vis = unwrap_details(photo, fit, model, raster=raster).visibility
            dump = None if args.dump is None else args.dump / f"scene{index}_{label}_error.png"
            if dump is not None:
                args.dump.mkdir(parents=True, exist_ok=True)
            r = metrics(asset.maps["albedo"], truth, skin, occluded, occ_albedo, m_vis, pairs, blur, cover, dump)
            r["seconds"] = seconds
            results[label] = r
            if args.dump is not None:
                args.dump.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(args.dump / f"scene{index}_{label}_albedo.png"),
                            cv2.cvtColor((scaled(asset.maps["albedo"], truth, skin) * 255).round().astype(np.uint8), cv2.COLOR_RGB2BGR))
        if args.dump is not None:
            cv2.imwrite(str(args.dump / f"scene{index}_photo.png"), cv2.cvtColor(photo, cv2.COLOR_RGB2BGR))
            cv2.imwrite(str(args.dump / f"scene{index}_truth.png"), cv2.cvtColor((truth * 255).round().astype(np.uint8), cv2.COLOR_RGB2BGR))
        rows.append((name, kinds, results))
        print(name, {k: {m: round(v, 3) for m, v in r.items()} for k, r in results.items()}, file=sys.stderr)

    lines = ["| scene (occluders) | backend | ΔE2000 median (p90) | seen / unseen median | PSNR dB | occluder leak % (texels) | ΔE2000 median on occluded texels | chroma cast ΔE | seam ΔE | boundary ΔE | s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, kinds, results in rows:
        for label, r in results.items():
            lines.append(f"| {name} ({', '.join(kinds)}) | {label} | {r['de_median']:.2f} ({r['de_p90']:.2f}) | {r['de_seen']:.2f} / {r['de_unseen']:.2f} | "
                         f"{r['psnr']:.2f} | {100 * r['leak']:.2f} ({r['n_occluded']}) | {r['de_occluded']:.2f} | {r['cast']:.2f} | {r['seam']:.2f} | {r['boundary']:+.2f} | {r['seconds']:.1f} |")
    header = [f"command: `python benchmarks/bench_albedo.py {' '.join(sys.argv[1:] if argv is None else argv)}`",
              f"machine: {platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}; load average at start {load_start}, "
              f"at end {load()}; total {time.perf_counter() - t_start:.0f} s; S = {args.size}, photo {PHOTO}²; "
              f"landmarks {'detected' if args.detect else 'true'}; comparison {'texel by texel' if args.full_resolution else 'at the photo resolution'}", ""]
    text = "\n".join(header + lines) + "\n"
    print(text)
    if args.write is not None:
        args.write.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
