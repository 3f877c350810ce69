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
from facegeo.landmarks.iris import iris_colour
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.parts import DEFAULT_IRIS_SRGB, load_parts, part_assets
from facegeo.photo import Photo, as_rgb_uint8, load_photo
from facegeo.skin_mask import SkinMask, skin_mask
from facegeo.texturing.backend import TextureBackend
from facegeo.texturing.context import build_context
from facegeo.texturing.default_backend import DefaultBackend
from facegeo.uv import geometry_maps, rasterize_uv, unwrap
from facegeo.uv.texels import sample_uv
from facegeo.landmarks.scheme import IBUG68

__all__ = ["reconstruct", "reconstruct_with_fit", "relit_preview", "BACKENDS", "STAGES"]


def _diffusion_backend(weights: str | Path | None = None) -> TextureBackend:
    """The diffusion backend from a weights folder (the optional [diffusion] extra, imported only here)."""
    from facegeo.texturing.diffusion import require_extra

    require_extra()
    from facegeo.texturing.diffusion.backend import DiffusionBackend

    return DiffusionBackend.from_weights(weights)


#: Texture backends by name; ``diffusion`` takes its weights folder as its argument.
BACKENDS: dict[str, Callable[..., TextureBackend]] = {"default": DefaultBackend, "diffusion": _diffusion_backend}
#: The stages, in order, as reported to a progress callback and in ``metadata["timings_s"]``.
STAGES = ("fit", "unwrap", "inpaint", "homogenise", "materials", "upscale", "parts")

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
    parts: bool = True,
    fitter: Callable[..., Fit] = fit,
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
        parts: add the model's eyes and mouth interior (:mod:`facegeo.parts`; none for a model
            without parts) as ``asset.parts``, the eyeballs with the iris colour found in the
            photo (:func:`facegeo.landmarks.iris.iris_colour`; a default colour and a note in
            ``fit.info["notes"]`` when none is found).
        fitter: called as ``fitter(photo, model=, detector=, camera=)`` -> :class:`Fit`; default
            the analysis-by-synthesis :func:`facegeo.fit` (e.g. a ``facegeo.regressor.Predictor``).
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
    result = fitter(photo, model=model, landmarks=landmarks, detector=detector, camera=camera)
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

    t = stage("parts")
    part_list, parts_report = [], {}
    model_parts = load_parts(model) if parts else ()
    if model_parts:
        iris, parts_report = iris_colour(pixels, result.landmarks)
        if iris is None:
            result.info.setdefault("notes", []).append(parts_report["note"])
        parts_report["iris_srgb_used"] = list(iris or DEFAULT_IRIS_SRGB)
        part_list = part_assets(model_parts, model, result.alpha, result.delta, iris or DEFAULT_IRIS_SRGB)
        parts_report["names"] = [p.name for p in part_list]
    timings["parts"] = time.perf_counter() - t

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
        parts=part_list,
        face_triangles=np.all(model.face_mask[model.triangles], axis=1),
        metadata={
            "parts": parts_report,
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


#: The preview's views: yaw in degrees (rotation_from_euler's convention: positive turns the nose
#: to the viewer's right and shows the subject's right side).
PREVIEW_VIEWS = (("front", 0.0), ("three-quarter", 40.0), ("profile", 90.0))
#: Lights of the preview in camera space (towards the light; linear radiance) and the ambient
#: term: a key light from the upper left, a weaker fill from the right.
PREVIEW_LIGHTS = (((-0.5, 0.55, 0.65), 2.0), ((0.75, 0.1, 0.45), 0.6))
PREVIEW_AMBIENT = 0.15
#: Clay: linear grey albedo, roughness and specular level.
CLAY = (0.45, 0.6, 0.25)
#: Background of the rendered panels (sRGB).
PREVIEW_BACKGROUND = 0.12


def relit_preview(photo: np.ndarray, asset: Asset, fit_result: Fit, *, panel: int = 256) -> np.ndarray:
    """The photo beside the asset from the front, three-quarter and profile: textured and relit
    (top row) and as clay (bottom row), parts (eyes, mouth interior) included.

    The photo panel is the (2·panel)² square around the detected landmarks. Each view is a
    virtual camera (perspective, 800 mm away, framing the skin's face region) around the
    model-space asset; the meshes are rasterised with :func:`facegeo.uv.rasterize_mesh` and each
    pixel is shaded with the project's GGX shader (:func:`shade_ggx`, deferred: the per-pixel
    position, normal, MikkTSpace tangent, albedo, normal map, roughness and specular) under
    :data:`PREVIEW_LIGHTS`; clay uses :data:`CLAY` and no normal map. Returns
    (2·panel, 5·panel, 3) uint8 sRGB.
    """
    from facegeo.camera import rotation_from_euler
    from facegeo.texturing.shading import shade_ggx
    from facegeo.uv.renderer import rasterize_mesh

    scene = _PreviewScene(asset)
    p = int(panel)
    lights = torch.tensor([[d for d, _ in PREVIEW_LIGHTS]], dtype=torch.float32)
    lights = torch.nn.functional.normalize(lights, dim=-1)
    radiance = torch.tensor([[[r, r, r] for _, r in PREVIEW_LIGHTS]], dtype=torch.float32)
    coverage, buffers = [], []
    for _, yaw in PREVIEW_VIEWS:
        rotation = rotation_from_euler(yaw, 0.0, 0.0)
        distance = 800.0
        focal = 0.5 * p * (distance - scene.radius) / (1.05 * scene.radius)
        camera = Camera(focal, p / 2.0, p / 2.0, p, p)
        cam_vertices = (scene.vertices - scene.centre) @ rotation.T + [0.0, 0.0, -distance]
        tri, bary, _ = rasterize_mesh(cam_vertices, scene.triangles, camera)
        coverage.append(np.flatnonzero(tri.ravel() >= 0))
        buffers.append(scene.buffers(tri, bary, cam_vertices, rotation))
    # the covered pixels of all views shaded in one call, as a (2, C, 1, N) "image"
    inputs = [torch.cat(column, dim=-1) for column in zip(*buffers)]
    with torch.inference_mode():  # no autograd bookkeeping (15 % faster here)
        shaded = shade_ggx(*inputs, lights, radiance, torch.zeros(1, 3), PREVIEW_AMBIENT, s_disp=1.0).shaded
    pixels = linear_to_srgb(shaded[:, :, 0].numpy().transpose(0, 2, 1).clip(0.0, None))  # (2, N, 3)
    columns, start = [], 0
    for idx in coverage:
        panel_rgb = np.full((2, p * p, 3), PREVIEW_BACKGROUND, np.float32)
        panel_rgb[:, idx] = pixels[:, start:start + len(idx)]
        start += len(idx)
        columns.append(panel_rgb.reshape(2 * p, p, 3))
    landmarks = np.asarray(fit_result.landmarks[IBUG68], np.float64)
    landmarks = landmarks[np.all(np.isfinite(landmarks), axis=1)]
    lo, hi = landmarks.min(axis=0), landmarks.max(axis=0)
    centre, half = (lo + hi) / 2.0, 0.75 * float(np.max(hi - lo))
    side = 2 * p
    scale = side / (2.0 * half)
    warp = np.array([[scale, 0.0, side / 2.0 - scale * centre[0]], [0.0, scale, side / 2.0 - scale * centre[1]]])
    photo_panel = cv2.warpAffine(as_rgb_uint8(photo), warp, (side, side), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REPLICATE)
    views = (np.concatenate(columns, axis=1) * 255.0).round().clip(0, 255).astype(np.uint8)
    return np.concatenate([photo_panel, views], axis=1)


class _PreviewScene:
    """The skin and its parts as one triangle soup for the preview, with per-corner UVs, normals
    and tangents, and per-surface materials (linear albedo, normal map, roughness, specular)."""

    def __init__(self, asset: Asset):
        from facegeo.camera import rotation_from_euler
        from facegeo.normals import vertex_normals
        from facegeo.uv.tangents import mesh_tangents

        surfaces = [asset, *asset.parts]
        # framing: the skin's face region
        face = asset.triangles if asset.face_triangles is None else asset.triangles[asset.face_triangles]
        head = asset.vertices[np.unique(face)]
        self.centre = (head.min(axis=0) + head.max(axis=0)) / 2.0
        #: the largest half-extent of the head seen from any preview view (x and y after the yaw)
        self.radius = max(float(np.abs(((head - self.centre) @ rotation_from_euler(yaw, 0.0, 0.0).T)[:, :2]).max())
                          for _, yaw in PREVIEW_VIEWS)
        verts, tris, corner_uv, corner_n, corner_t, surface = [], [], [], [], [], []
        offset = 0
        for k, s in enumerate(surfaces):
            normals = vertex_normals(s.vertices, s.triangles)
            if "normal" in s.maps:
                tangents = mesh_tangents(s.vertices, s.triangles, s.uv, s.uv_triangles, normals.astype(np.float32))[..., :3]
            else:  # no normal map: any tangent perpendicular to the normal shades the same
                helper = np.where(np.abs(normals[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
                tangents = np.cross(helper, normals)[s.triangles]
            verts.append(s.vertices)
            tris.append(s.triangles + offset)
            corner_uv.append(s.uv[s.uv_triangles])
            corner_n.append(normals[s.triangles])
            corner_t.append(tangents)
            surface.append(np.full(len(s.triangles), k))
            offset += len(s.vertices)
        self.vertices = np.concatenate(verts).astype(np.float64)
        self.triangles = np.concatenate(tris)
        self.corner_uv = np.concatenate(corner_uv).astype(np.float32)
        self.corner_normal = np.concatenate(corner_n).astype(np.float32)
        self.corner_tangent = np.concatenate(corner_t).astype(np.float32)
        self.surface = np.concatenate(surface)
        self.materials = [self._material(s) for s in surfaces]

    @staticmethod
    def _material(s: Asset) -> dict[str, np.ndarray]:
        def value(name: str, default: float | tuple[float, ...]) -> np.ndarray:
            if name in s.maps:
                return s.maps[name]
            return np.asarray(s.constants.get(name, default), np.float32)

        return {"albedo": srgb_to_linear(value("albedo", 0.5)), "normal": value("normal", (0.0, 0.0, 1.0)),
                "roughness": value("roughness", DEFAULT_CONSTANTS["roughness"]),
                "specular": value("specular", DEFAULT_CONSTANTS["specular"])}

    def buffers(self, tri: np.ndarray, bary: np.ndarray, cam_vertices: np.ndarray, rotation: np.ndarray) -> list[torch.Tensor]:
        """shade_ggx's inputs for the covered pixels (row-major) of one view as (B, C, 1, N)
        float32 (batch 2: textured, clay; geometry shared, batch 1)."""
        idx = np.flatnonzero(tri.ravel() >= 0)
        t = tri.ravel()[idx]
        b = bary.reshape(-1, 3)[idx]

        def interpolate(corner: np.ndarray) -> np.ndarray:
            return np.einsum("nk,nkc->nc", b, corner[t])

        position = interpolate(cam_vertices[self.triangles].astype(np.float32))
        normal = interpolate(self.corner_normal) @ rotation.T.astype(np.float32)
        tangent = interpolate(self.corner_tangent) @ rotation.T.astype(np.float32)
        uv = interpolate(self.corner_uv)
        values = {"albedo": np.zeros((len(idx), 3), np.float32), "normal": np.zeros((len(idx), 3), np.float32),
                  "roughness": np.zeros((len(idx), 1), np.float32), "specular": np.zeros((len(idx), 1), np.float32)}
        surface = self.surface[t]
        for k, material in enumerate(self.materials):
            sel = surface == k
            if not sel.any():
                continue
            for name, array in material.items():
                if array.ndim >= 2:
                    values[name][sel] = sample_uv(array, uv[sel]).reshape(int(sel.sum()), -1)
                else:
                    values[name][sel] = array.reshape(1, -1)

        def image(textured: np.ndarray, clay: np.ndarray | float) -> torch.Tensor:
            out = np.empty((2, len(idx), textured.shape[1]), np.float32)
            out[0], out[1] = textured, clay
            return torch.from_numpy(out.transpose(0, 2, 1)[:, :, None].copy())

        def shared(array: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32).T[None, :, None].copy())

        clay_albedo, clay_roughness, clay_specular = CLAY
        return [image(values["albedo"], clay_albedo), image(values["normal"], np.array([0.0, 0.0, 1.0], np.float32)),
                image(values["roughness"], clay_roughness), image(values["specular"], clay_specular),
                torch.zeros(1, 1, 1, len(idx)), shared(position), shared(normal), shared(tangent),
                torch.ones(1, 1, 1, len(idx))]
