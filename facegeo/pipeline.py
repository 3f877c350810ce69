"""The whole pipeline: photo → fit → unwrap → texture backend → :class:`Asset` (+ preview).

This is the one geometry-side module that composes ``facegeo.texturing`` (DESIGN.md: only the
CLI/pipeline module does); exporting is left to :func:`facegeo.export.export_asset`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path

import cv2
import numpy as np
import torch

from facegeo.asset import MAP_NAMES, Asset
from facegeo.camera import Camera
from facegeo.colour import linear_to_srgb, srgb_to_linear
from facegeo.errors import InputError
from facegeo.fitting import Fit, fit
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.photo import Photo, as_rgb_uint8, load_photo
from facegeo.skin_mask import SkinMask, skin_mask
from facegeo.texturing.backend import TextureBackend
from facegeo.texturing.context import build_context
from facegeo.texturing.default_backend import DefaultBackend
from facegeo.uv import geometry_maps, rasterize_uv, render, unwrap

__all__ = ["reconstruct", "reconstruct_with_fit", "relit_preview", "BACKENDS", "STAGES"]

#: Texture backends by name. The diffusion backend (an adapter over a DiT) is not built yet.
BACKENDS: dict[str, Callable[[], TextureBackend]] = {"default": DefaultBackend}
#: The stages, in order, as reported to a progress callback and in ``metadata["timings_s"]``.
STAGES = ("fit", "unwrap", "inpaint", "homogenise", "materials", "upscale")

#: Constant-map factors used when a map is not asked for (the exporters write a factor).
DEFAULT_CONSTANTS = {"roughness": 0.55, "specular": 0.45}


def reconstruct(image: np.ndarray | str | Path | Photo, model: MorphableModel | None = None, **options) -> Asset:
    """Reconstruct a textured face from one photo: :func:`reconstruct_with_fit` without the fit
    (its parameters are in ``asset.metadata["fit"]``)."""
    asset, _ = reconstruct_with_fit(image, model, **options)
    return asset


def reconstruct_with_fit(
    image: np.ndarray | str | Path | Photo,
    model: MorphableModel | None = None,
    *,
    backend: str | TextureBackend = "default",
    size: int = 1024,
    upscale: int = 1,
    maps: Iterable[str] = MAP_NAMES,
    detector: str = "hybrid",
    camera: Camera | None = None,
    skin: SkinMask | None = None,
    landmarks: np.ndarray | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[Asset, Fit]:
    """Reconstruct a textured face from one photo.

    Args:
        image: (H, W, 3) uint8 RGB, a path, or a :class:`Photo`.
        model: the morphable model (default: the bundled one).
        backend: ``"default"`` or a :class:`TextureBackend` instance.
        size: UV map size S in texels (the maps come out at ``size · upscale``).
        upscale: 1, 2 or 4: Lanczos (or the backend's) upscaling of the maps.
        maps: which of albedo, normal, roughness, specular, displacement to compute; maps not
            asked for are not computed (roughness and specular fall back to constant factors).
        detector: landmark detector name. camera: intrinsics (default: 40° field of view).
        skin: the photo's :class:`facegeo.skin_mask.SkinMask` if already computed (default: computed
            here, from the 468-point mesh or, failing that, the fit's landmarks); its occlusion is
            folded into M_vis. ``asset.metadata["skin_mask"]`` summarises it.
        landmarks: optional (88, 2) pixel landmarks (skips detection, as :func:`facegeo.fit`).
        progress: called with each stage's name as it starts.
    Returns:
        ``(asset, fit)``: the asset in model space (upright, mm) with its maps, and the fit.
    """
    wanted = frozenset(maps)
    unknown = wanted - set(MAP_NAMES)
    if unknown or not wanted:
        raise InputError("<argument>", "maps", f"a non-empty subset of {', '.join(MAP_NAMES)}", ", ".join(sorted(unknown)) or "none")
    if upscale not in (1, 2, 4):
        raise InputError("<argument>", "upscale", "1, 2 or 4", str(upscale))
    if not 64 <= size <= 8192:
        raise InputError("<argument>", "size", "a map size between 64 and 8192 texels", str(size))
    if isinstance(backend, str):
        if backend not in BACKENDS:
            raise InputError("<argument>", "backend", f"one of {', '.join(BACKENDS)}", repr(backend))
        backend = BACKENDS[backend]()
    photo = load_photo(image) if isinstance(image, (str, Path)) else image
    pixels = photo.image if isinstance(photo, Photo) else as_rgb_uint8(photo)
    model = load_model() if model is None else model
    timings: dict[str, float] = {}

    def stage(name: str) -> float:
        if progress is not None:
            progress(name)
        return time.perf_counter()

    t = stage("fit")
    result = fit(photo, model=model, landmarks=landmarks, detector=detector, camera=camera)
    timings["fit"] = time.perf_counter() - t

    t = stage("unwrap")
    if skin is None:
        skin = skin_mask(pixels, result.landmarks)
    raster = rasterize_uv(model, size=size)
    camera_maps = geometry_maps(result.vertices, model, raster, tangents=False)  # shared by both
    t_inc, m_vis = unwrap(pixels, result, model, maps=camera_maps, occlusion=skin.occlusion)
    ctx = build_context(model, result, raster, camera_maps)
    timings["unwrap"] = time.perf_counter() - t

    t = stage("inpaint")
    t_full = backend.inpaint(t_inc, m_vis, ctx)
    timings["inpaint"] = time.perf_counter() - t

    t = stage("homogenise")
    t_hom = backend.homogenise(t_full, ctx)
    timings["homogenise"] = time.perf_counter() - t

    t = stage("materials")
    out = backend.materials(t_hom, ctx, maps=wanted)
    timings["materials"] = time.perf_counter() - t

    t = stage("upscale")
    if upscale > 1:
        out = {name: backend.upscale(m, upscale) for name, m in out.items()}
        if "normal" in out:  # interpolated unit vectors are shorter than 1
            n = out["normal"]
            out["normal"] = (n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)).astype(np.float32)
        for name in ("albedo", "roughness", "specular"):
            if name in out:  # Lanczos overshoots at edges
                out[name] = np.clip(out[name], 0.0, 1.0)
    timings["upscale"] = time.perf_counter() - t

    constants = {name: value for name, value in DEFAULT_CONSTANTS.items() if name not in out}
    report = getattr(backend, "report", {})
    asset = Asset(
        vertices=result.shape_vertices,
        triangles=model.triangles,
        uv=model.uv,
        uv_triangles=model.uv_triangles,
        maps=out,
        constants=constants,
        name="face",
        metadata={
            "model": model.name,
            "backend": getattr(backend, "name", type(backend).__name__),
            "size": size,
            "upscale": upscale,
            "timings_s": timings,
            "texture_report": report,
            "skin_mask": skin.summary(),
            "landmark_rms_px": result.landmark_rms_px,
            "fit": {k: v for k, v in result.to_dict().items() if k not in ("landmarks_px", "landmarks_fitted_px")},
        },
    )
    return asset, result


def relit_preview(photo: np.ndarray, asset: Asset, fit_result: Fit, model: MorphableModel, *, height: int = 384,
                  shading_size: int = 512) -> np.ndarray:
    """The photo next to the asset relit from three directions with ``shade_ggx``.

    The maps (resampled to ``shading_size``) are shaded in UV space on the fitted, posed geometry
    (camera at the origin); the mesh is rasterised once into the photo's view and each shaded
    texture is looked up through the per-pixel UVs. The panels are cropped around the face.
    Returns (height, 4·width', 3) uint8 sRGB.
    """
    from facegeo.texturing.shading import shade_ggx

    size = shading_size
    raster = rasterize_uv(model, size=size)
    geo = geometry_maps(fit_result.vertices, model, raster)

    def resampled(name: str, default: float | tuple[float, ...]) -> np.ndarray:
        if name in asset.maps:
            return cv2.resize(asset.maps[name], (size, size), interpolation=cv2.INTER_AREA)
        value = asset.constants.get(name, default)
        return np.broadcast_to(np.asarray(value, np.float32), (size, size, 3) if name in ("albedo", "normal") else (size, size)).copy()

    def chw(a: np.ndarray) -> torch.Tensor:
        a = a[..., None] if a.ndim == 2 else a
        return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1), dtype=np.float32))[None]

    albedo = srgb_to_linear(resampled("albedo", 0.5))
    normal = resampled("normal", (0.0, 0.0, 1.0))
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-6)
    maps = [chw(albedo), chw(normal), chw(resampled("roughness", 0.55)), chw(resampled("specular", 0.45)),
            chw(resampled("displacement", 0.0)), chw(geo.position), chw(geo.normal), chw(geo.tangent),
            chw(geo.mask.astype(np.float32))]
    view = render(fit_result.vertices, model, fit_result.camera)
    map_x = (view.uv[..., 0] * size - 0.5).astype(np.float32)
    map_y = ((1.0 - view.uv[..., 1]) * size - 0.5).astype(np.float32)
    dimmed = (photo * 0.25).astype(np.uint8)
    directions = np.array([[-0.7, 0.3, 0.65], [0.0, 0.45, 0.9], [0.7, 0.3, 0.65]], np.float32)  # left, front, right
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    panels = [photo]
    for d in directions:
        shaded = shade_ggx(*maps, torch.from_numpy(d)[None, None], torch.full((1, 1, 3), 2.2), torch.zeros(1, 3), 0.15,
                           s_disp=1.0)  # positions and displacement are both in mm
        texture = np.ascontiguousarray(shaded.shaded[0].numpy().transpose(1, 2, 0))
        image = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        rgb = (linear_to_srgb(image) * 255).round().astype(np.uint8)
        panels.append(np.where(view.mask[..., None], rgb, dimmed))
    ys, xs = np.nonzero(view.mask)
    if len(ys):
        pad = int(0.1 * max(np.ptp(ys), np.ptp(xs)))
        y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad, photo.shape[0])
        x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad, photo.shape[1])
        panels = [p[y0:y1, x0:x1] for p in panels]
    scale = height / panels[0].shape[0]
    width = max(1, round(panels[0].shape[1] * scale))
    return np.concatenate([cv2.resize(p, (width, height), interpolation=cv2.INTER_AREA) for p in panels], axis=1)
