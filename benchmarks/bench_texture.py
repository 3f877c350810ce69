"""Benchmark of the default texture backend (issue 7, section 3): measured quality and run time.

All on the bundled ICT-FaceKit model and real UV contexts (``build_context`` of a landmark fit):

1. homogenise round trip: a known skin albedo (sRGB, mid-frequency blotches, a function of the
   model-space position so it is continuous across UV seams) shaded in UV under known SH lighting
   γ (T_full = albedo_lin × sh_irradiance(ctx.normal_camera, γ), sRGB-encoded, ctx.gamma = γ);
   albedo PSNR / SSIM on skin texels (ctx.skin > 0.5 & coverage) after a least-squares global scale
   per channel in linear RGB, against not de-lighting at all (the shaded texture, same scale fit).
2. inpaint with realistic visibility: the known texture is rendered from a posed fit (z-buffer
   renderer, 1024² photo, 40° fov), unwrapped (M_vis), texels with M_vis < 0.5 hidden; PSNR /
   SSIM on the hidden covered texels against the truth, and the same for the trivial mean-colour
   fill (mean of the visible skin) in the same run.
3. error against run time: map size S.
4. a contact sheet of the maps of the demo photo (``--sheet``).

(The multi-band blending ``levels`` knob of the first backend went with issue 14; the albedo
benchmark with ground truth is ``benchmarks/bench_albedo.py``.)

SSIM: ``kornia.metrics.ssim`` (Gaussian window 11×11, σ = 1.5, data range 1, sRGB values,
per-channel map averaged over the selected texels; texels outside the layout are padded with the
nearest inside texel in both images so the window never sees the background). PSNR is on sRGB
values in [0, 1]. Times: wall-clock (perf_counter), median of ``--repeats`` runs, a fresh backend
per run (so each stage pays its own SH shading).

    python benchmarks/bench_texture.py                              # prints the tables
    python benchmarks/bench_texture.py --write benchmarks/RESULTS_texture.md --sheet
"""

from __future__ import annotations

import argparse
import os
import platform
import shlex
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

import facegeo
from facegeo.camera import Camera, project, rotation_from_euler
from facegeo.colour import linear_to_srgb, srgb_to_linear
from facegeo.lighting import sh_irradiance
from facegeo.texturing.context import build_context
from facegeo.texturing.default import DefaultBackend
from facegeo.texturing.image_filters import pad_outside
from facegeo.uv import rasterize_uv, render, unwrap

ROOT = Path(__file__).resolve().parents[1]
SIZES = (256, 512, 1024, 2048)
YAWS = (0.0, 30.0, 60.0)
HOM_YAW = 20.0
PHOTO = 1024
DISTANCE_MM = 600.0

#: Known SH lightings (Deep3D convention, facegeo.lighting): γ0 ambient, γ1 ∝ −n_y, γ2 ∝ n_z,
#: γ3 ∝ −n_x, γ7 ∝ −n_x·n_z; a slightly warm light (per-channel factor).
TINT = np.array([1.0, 0.95, 0.88], np.float32)


def lighting(name: str) -> np.ndarray:
    g = np.zeros(9, np.float32)
    g[0] = 0.8
    if name == "frontal":
        g[2], g[6] = 0.30, 0.05
    elif name == "side":  # from the viewer's right (+x) and a little from the front
        g[3], g[2], g[7] = -0.30, 0.10, -0.05
    elif name == "top":  # from above (+y) and a little from the front
        g[1], g[2], g[6] = -0.30, 0.10, 0.05
    elif name != "ambient":
        raise ValueError(name)
    return (TINT[:, None] * g[None, :]).astype(np.float32)


def load() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:  # pragma: no cover
        return "n/a"


# ------------------------------------------------------------------------------------ fixtures
def synthetic_fit(model, yaw: float, pitch: float = 5.0):
    """facegeo.fit_landmarks on the projected landmarks of the mean shape at ``yaw``."""
    camera = Camera.for_image(PHOTO, PHOTO, 40.0)
    R = rotation_from_euler(yaw, pitch, 0.0)
    t = np.array([0.0, 0.0, -DISTANCE_MM])
    landmarks = project(model.mean_shape[model.landmark_indices].astype(np.float64), R, t, camera)
    return facegeo.fit_landmarks(model, landmarks, camera)


def skin_texture(position: np.ndarray, cover: np.ndarray, seed: int = 0) -> np.ndarray:
    """(S, S, 3) sRGB skin albedo: a skin tone with mid-frequency (6–30 mm) luminance blotches and
    redness, mostly left/right symmetric (x → −x) plus 30 % asymmetric part; 0 outside."""
    rng = np.random.default_rng(seed)
    p = position[cover].astype(np.float64)

    def waves(n: int, symmetric: bool) -> np.ndarray:
        k = rng.normal(size=(n, 3))
        k *= (2 * np.pi / rng.uniform(6.0, 30.0, n) / np.linalg.norm(k, axis=1))[:, None]
        phase = rng.uniform(0, 2 * np.pi, n)
        out = np.cos(p @ k.T + phase).sum(1)
        if symmetric:
            out += np.cos((p * [-1.0, 1.0, 1.0]) @ k.T + phase).sum(1)
        return (out - out.mean()) / out.std()

    lum = waves(24, True) + 0.3 * waves(24, False)
    red = waves(16, True) + 0.3 * waves(16, False)
    base = np.array([0.80, 0.60, 0.50])
    rgb = base * (1 + 0.10 * lum[:, None]) + 0.03 * red[:, None] * np.array([1.0, -0.5, -0.5])
    tex = np.zeros((*cover.shape, 3), np.float32)
    tex[cover] = np.clip(rgb, 0, 1)
    return tex


class Scene:
    """A fit at one yaw and its UV context / known texture / unwrapped photo at size S."""

    def __init__(self, model, fit, size: int, seed: int = 0, gamma: np.ndarray | None = None):
        self.fit = fit
        self.raster = rasterize_uv(model, size=size)
        self.ctx = build_context(model, fit, self.raster)
        cover = self.ctx.coverage
        self.truth = pad_outside(skin_texture(self.ctx.position, cover, seed), cover)
        self.skin = cover & (self.ctx.skin > 0.5)
        if gamma is not None:  # a shaded photo: truth = the texture under γ, known to the context
            self.ctx = replace(self.ctx, gamma=gamma)
            self.truth = shade(self, gamma)
        self._model = model
        self._unwrapped = None

    def unwrapped(self):
        if self._unwrapped is None:
            photo = render(self.fit.vertices, self._model, self.fit.camera, texture=self.truth).image
            self._unwrapped = unwrap(np.clip(photo, 0, 1), self.fit, self._model, raster=self.raster)
        return self._unwrapped


# ------------------------------------------------------------------------------------ metrics
def psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    mse = float(np.mean((a[mask].astype(np.float64) - b[mask]) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray, cover: np.ndarray) -> float:
    """Mean kornia SSIM map (11×11 Gaussian, σ 1.5) over ``mask``; outside ``cover`` padded."""
    from kornia.metrics import ssim as kssim

    def t(x):
        x = pad_outside(np.ascontiguousarray(x, np.float32), cover)
        return torch.from_numpy(np.ascontiguousarray(x.transpose(2, 0, 1)))[None]

    with torch.no_grad():
        m = kssim(t(a), t(b), window_size=11, max_val=1.0)[0].mean(0).numpy()
    return float(m[mask].mean())


def scaled(out_srgb: np.ndarray, ref_srgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``out`` after the least-squares per-channel scale (linear RGB) onto ``ref`` over mask."""
    lo, lr = srgb_to_linear(out_srgb), srgb_to_linear(ref_srgb)
    s = (lo[mask] * lr[mask]).sum(0) / np.maximum((lo[mask] ** 2).sum(0), 1e-12)
    return linear_to_srgb(lo * s)


def timed(fn, repeats: int):
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return out, statistics.median(times)


# ------------------------------------------------------------------------------------ experiments
def shade(scene: Scene, gamma: np.ndarray) -> np.ndarray:
    ctx = scene.ctx
    e = sh_irradiance(torch.from_numpy(ctx.normal_camera), torch.from_numpy(gamma)).numpy()
    return pad_outside(linear_to_srgb(srgb_to_linear(scene.truth) * e), ctx.coverage)


def homogenise_case(scene: Scene, gamma_true: np.ndarray, gamma_ctx: np.ndarray, repeats: int = 1) -> dict:
    ctx = replace(scene.ctx, gamma=gamma_ctx)
    t_full = shade(scene, gamma_true)
    backend = None

    def run():
        nonlocal backend
        backend = DefaultBackend()
        return backend.homogenise(t_full, ctx)

    t_hom, seconds = timed(run, repeats)
    m, truth = scene.skin, scene.truth
    ours, base = scaled(t_hom, truth, m), scaled(t_full, truth, m)
    return dict(psnr=psnr(ours, truth, m), ssim=ssim(ours, truth, m, ctx.coverage),
                base_psnr=psnr(base, truth, m), base_ssim=ssim(base, truth, m, ctx.coverage),
                remaining=backend.report["homogenise"]["remaining_fraction"], seconds=seconds, t_hom=t_hom)


def inpaint_case(scene: Scene, repeats: int = 1, with_ssim: bool = True) -> dict:
    ctx = scene.ctx
    t_inc, m_vis = scene.unwrapped()
    cover = ctx.coverage
    shown = m_vis >= 0.5
    m_in = np.where(shown, m_vis, 0.0).astype(np.float32)
    t_in = np.where(shown[..., None], t_inc, 0.0).astype(np.float32)
    hidden = cover & ~shown
    hidden_skin = hidden & scene.skin
    has = (ctx.mirror[..., 0] >= 0) & cover
    mirror_shown = has & shown[np.maximum(ctx.mirror[..., 0], 0), np.maximum(ctx.mirror[..., 1], 0)]
    via_mirror, neither = hidden & mirror_shown, hidden & ~mirror_shown
    out, seconds = timed(lambda: DefaultBackend().inpaint(t_in, m_in, ctx), repeats)
    vis_skin = shown & scene.skin
    mean_colour = t_in[vis_skin].mean(0) if vis_skin.any() else np.full(3, 0.5, np.float32)
    trivial = np.where(shown[..., None], t_in, mean_colour).astype(np.float32)
    truth = scene.truth
    row = dict(hidden=int(hidden.sum()), hidden_frac=float(hidden.sum() / cover.sum()),
               psnr=psnr(out, truth, hidden), base_psnr=psnr(trivial, truth, hidden),
               psnr_skin=psnr(out, truth, hidden_skin), base_psnr_skin=psnr(trivial, truth, hidden_skin),
               via_mirror=float(via_mirror.sum() / max(hidden.sum(), 1)),
               psnr_mirror=psnr(out, truth, via_mirror), base_psnr_mirror=psnr(trivial, truth, via_mirror),
               psnr_neither=psnr(out, truth, neither), base_psnr_neither=psnr(trivial, truth, neither),
               vis_psnr=psnr(out, truth, cover & shown), seconds=seconds, out=out)
    if with_ssim:
        row.update(ssim=ssim(out, truth, hidden, cover), base_ssim=ssim(trivial, truth, hidden, cover))
    return row


def sheet(model, size: int, path: Path, jpeg: Path | None) -> str:
    """Contact sheet of the maps of the demo photo; returns a one-line description."""
    import cv2

    from facegeo.assets import asset_path
    from facegeo.photo import load_photo
    from facegeo import pipeline

    photo = load_photo(asset_path("photos/astronaut.png"))
    t = time.perf_counter()
    if hasattr(pipeline, "reconstruct_with_fit"):  # reconstruct returns the asset alone
        asset, fit = pipeline.reconstruct_with_fit(photo, model, size=size)
    else:
        asset, fit = pipeline.reconstruct(photo, model, size=size)
    seconds = time.perf_counter() - t
    from facegeo.skin_mask import skin_mask

    t_inc, m_vis = unwrap(photo.image, fit, model, raster=rasterize_uv(model, size=size),
                          occlusion=skin_mask(photo.image, fit.landmarks).occlusion)  # as the pipeline
    maps = asset.maps
    d = maps["displacement"]
    span = max(float(np.abs(d).max()), 1e-6)
    grey = lambda x: np.repeat(np.clip(x, 0, 1)[..., None], 3, -1)  # noqa: E731
    h, w = photo.image.shape[:2]
    side = max(h, w)
    square = np.zeros((side, side, 3), np.uint8)
    square[(side - h) // 2:(side - h) // 2 + h, (side - w) // 2:(side - w) // 2 + w] = photo.image
    panels = [
        ("photo", cv2.resize(square, (size, size), interpolation=cv2.INTER_AREA).astype(np.float32) / 255),
        ("T_inc", t_inc), ("M_vis", grey(m_vis)), ("albedo", maps["albedo"]),
        ("normal (n*0.5+0.5)", maps["normal"] * 0.5 + 0.5), ("roughness", grey(maps["roughness"])),
        ("specular", grey(maps["specular"])), (f"displacement (+-{span:.2f} mm)", grey(0.5 + 0.5 * d / span)),
    ]
    tiles = []
    for label, img in panels:
        tile = (np.clip(img, 0, 1) * 255).round().astype(np.uint8).copy()
        scale = size / 1024
        cv2.putText(tile, label, (int(16 * scale), int(48 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 1.4 * scale,
                    (0, 0, 0), int(6 * scale) + 1, cv2.LINE_AA)
        cv2.putText(tile, label, (int(16 * scale), int(48 * scale)), cv2.FONT_HERSHEY_SIMPLEX, 1.4 * scale,
                    (255, 255, 255), int(2 * scale) + 1, cv2.LINE_AA)
        tiles.append(tile)
    grid = np.concatenate([np.concatenate(tiles[:4], 1), np.concatenate(tiles[4:], 1)], 0)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), cv2.cvtColor(grid, cv2.COLOR_RGB2BGR))
    if jpeg is not None:
        small = cv2.resize(grid, (1400, round(grid.shape[0] * 1400 / grid.shape[1])), interpolation=cv2.INTER_AREA)
        jpeg.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(jpeg), cv2.cvtColor(small, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    timings = asset.metadata.get("timings_s", {})
    return (f"contact sheet `{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}` "
            f"({grid.shape[1]}×{grid.shape[0]}): photo, T_inc, M_vis, albedo, normal, roughness, specular, "
            f"displacement of `photos/astronaut.png` at S = {size}; reconstruct {seconds:.2f} s ("
            + ", ".join(f"{k} {v:.2f}" for k, v in timings.items()) + ")")


# ------------------------------------------------------------------------------------ main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024, help="map size S of tables 1 and 2")
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="comma-separated sizes of table 3")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per cell (median)")
    ap.add_argument("--sheet", action="store_true", help="also write the contact sheet of the demo photo")
    ap.add_argument("--sheet-path", type=Path, default=ROOT / "benchmarks/out/texture_contact_sheet.png")
    ap.add_argument("--sheet-jpeg", type=Path, default=ROOT / "docs/texture_maps.jpg",
                    help="reduced JPEG copy of the sheet (1400 px wide)")
    ap.add_argument("--write", type=Path, default=None, help="also write the report (markdown) here")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes.split(",") if s]
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    model = facegeo.load_model()
    load_start = load()
    t_start = time.perf_counter()
    lines: list[str] = []

    # 1. homogenise round trip
    fit_h = synthetic_fit(model, HOM_YAW)
    scene = Scene(model, fit_h, args.size)
    lines += [f"### 1. homogenise round trip (S = {args.size}, fit at yaw {HOM_YAW:g}°, "
              f"{int(scene.skin.sum())} skin texels)", "",
              "Albedo after a least-squares per-channel scale; baseline = the shaded texture itself (no de-lighting). "
              "'remaining' = the backend's own report of the SH-explained log-luminance variance left.", "",
              "| lighting γ | ctx.gamma | PSNR dB ours | PSNR dB no de-light | Δ dB | SSIM ours | SSIM no de-light | remaining | s |",
              "|---|---|---|---|---|---|---|---|---|"]
    cases = [(n, n) for n in ("frontal", "side", "top")] + [("side", "ambient")]
    hom_side = None
    for true_name, ctx_name in cases:
        r = homogenise_case(scene, lighting(true_name), lighting(ctx_name), repeats=args.repeats)
        if (true_name, ctx_name) == ("side", "side"):
            hom_side = r
        ctx_label = "= γ" if true_name == ctx_name else f"{ctx_name} (γ unknown)"
        lines.append(f"| {true_name} | {ctx_label} | {r['psnr']:.2f} | {r['base_psnr']:.2f} | {r['psnr'] - r['base_psnr']:+.2f} | "
                     f"{r['ssim']:.4f} | {r['base_ssim']:.4f} | {r['remaining']:.3f} | {r['seconds']:.3f} |")
        print(lines[-1], file=sys.stderr)
    del scene

    # 2. inpaint with realistic visibility
    lines += ["", f"### 2. inpaint, visibility from posed fits (S = {args.size}, {PHOTO}² render, 40° fov, "
              f"{DISTANCE_MM:g} mm, pitch 5°; hidden = covered & M_vis < 0.5)", "",
              "Baseline = visible texels kept, hidden ones filled with the mean colour of the visible skin. "
              "'via mirror' = hidden texels whose mirror texel is shown (filled from it); 'neither' = the rest "
              "(mirror hidden too, or no mirror: filled from the model's texture after the Lab transfer). "
              "Rows without a lighting: unshaded photo, ctx.gamma = ambient (fit_landmarks); lit rows: the photo and "
              "the truth are the texture under that SH lighting.", "",
              "| yaw ° | hidden texels (% of covered) | via mirror % | PSNR dB ours | PSNR dB mean fill | Δ dB | SSIM ours | SSIM mean fill | "
              "PSNR via mirror ours / mean fill | PSNR neither ours / mean fill | PSNR hidden skin ours / mean fill | PSNR on shown texels | s |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    scenes = {}
    for yaw, light in [(y, None) for y in YAWS] + [(30.0, "side"), (30.0, "frontal")]:
        if yaw not in scenes:
            scenes[yaw] = synthetic_fit(model, yaw)
        sc = Scene(model, scenes[yaw], args.size, seed=1, gamma=None if light is None else lighting(light))
        r = inpaint_case(sc, repeats=args.repeats)
        lines.append(f"| {yaw:g}{'' if light is None else f', {light}-lit photo (ctx.gamma = γ)'} | {r['hidden']} ({100 * r['hidden_frac']:.1f}) | {100 * r['via_mirror']:.1f} | {r['psnr']:.2f} | "
                     f"{r['base_psnr']:.2f} | {r['psnr'] - r['base_psnr']:+.2f} | {r['ssim']:.4f} | {r['base_ssim']:.4f} | "
                     f"{r['psnr_mirror']:.2f} / {r['base_psnr_mirror']:.2f} | {r['psnr_neither']:.2f} / {r['base_psnr_neither']:.2f} | "
                     f"{r['psnr_skin']:.2f} / {r['base_psnr_skin']:.2f} | {r['vis_psnr']:.2f} | {r['seconds']:.3f} |")
        print(lines[-1], file=sys.stderr)

    # 3. map size
    lines += ["", "### 3. error against run time: map size S", "",
              f"Inpaint at yaw 30° (PSNR on hidden texels, same {PHOTO}² photo for every S), homogenise under the "
              f"'side' lighting (PSNR on skin, after scale), materials = all five maps from that T_hom. "
              f"Median of {args.repeats}.", "",
              "| S | inpaint s | PSNR hidden dB (mean fill) | homogenise s | PSNR albedo dB (no de-light) | materials s | total s |",
              "|---|---|---|---|---|---|---|"]
    for S in sizes:
        sc = Scene(model, scenes[30.0], S, seed=1)
        ri = inpaint_case(sc, repeats=args.repeats, with_ssim=False)
        sh = Scene(model, fit_h, S)
        rh = homogenise_case(sh, lighting("side"), lighting("side"), repeats=args.repeats)
        _, t_mat = timed(lambda: DefaultBackend().materials(rh["t_hom"], sh.ctx), args.repeats)
        lines.append(f"| {S} | {ri['seconds']:.3f} | {ri['psnr']:.2f} ({ri['base_psnr']:.2f}) | {rh['seconds']:.3f} | "
                     f"{rh['psnr']:.2f} ({rh['base_psnr']:.2f}) | {t_mat:.3f} | {ri['seconds'] + rh['seconds'] + t_mat:.3f} |")
        print(lines[-1], file=sys.stderr)
        del sc, sh, ri, rh

    if args.sheet:
        lines += ["", "### 4. contact sheet", "", sheet(model, 1024, args.sheet_path, args.sheet_jpeg)]

    header = [
        "# Texture backend benchmark (DefaultBackend, issue 7 §3)", "",
        f"command: `{' '.join(['python', *map(shlex.quote, [os.path.relpath(sys.argv[0], ROOT) if sys.argv[0] else 'benchmarks/bench_texture.py', *(sys.argv[1:] if argv is None else argv)])])}`",
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"torch {torch.__version__}; load average at start {load_start}, at end {load()}; total {time.perf_counter() - t_start:.0f} s",
        "SSIM: kornia.metrics.ssim (Gaussian 11×11, σ 1.5), PSNR/SSIM on sRGB in [0, 1].", "",
    ]
    text = "\n".join(header + lines) + "\n"
    print(text)
    if args.write is not None:
        args.write.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
