"""The whole pipeline: photo → fit → unwrap → texture backend → :class:`Asset`.

It composes the layers (DESIGN.md, "Layers"): the geometry (``facegeo``), the UV space
(``facegeo.uv``) and a texture backend (``facegeo.texturing``), through the two seams of
DESIGN.md, "Seams": any :class:`facegeo.fitting.Fitter` (``fitter=``) and any
:class:`facegeo.texturing.backend.TextureBackend` (``backend=``). Writing files (the asset folder,
the scenes, the relit preview) is :func:`facegeo.jobs.reconstruct_into_folder`'s.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import replace
from pathlib import Path

import numpy as np

from facegeo.asset import MAP_NAMES, Asset
from facegeo.blendshapes import model_blendshapes
from facegeo.camera import Camera
from facegeo.concurrency import run_concurrently, usable_threads
from facegeo.errors import InputError
from facegeo.fitting import Fit, Fitter, fit
from facegeo.landmarks.iris import iris_colour
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.parts import DEFAULT_IRIS_SRGB, load_parts, part_assets
from facegeo.photo import Photo, as_rgb_uint8, load_photo
from facegeo.skin_mask import SkinMask, skin_mask
from facegeo.texturing.backend import TextureBackend
from facegeo.texturing.context import build_context
from facegeo.texturing.registry import BACKENDS
from facegeo.uv import geometry_maps, rasterize_uv, unwrap

__all__ = ["reconstruct", "reconstruct_with_fit", "BACKENDS", "STAGES"]

#: The stages, in order, as reported to a progress callback and in ``metadata["timings_s"]``
#: (the parts need only the fit: with them the asset's geometry is complete before the texture
#: stages, :func:`reconstruct_with_fit`'s ``geometry_ready``).
STAGES = ("fit", "parts", "unwrap", "inpaint", "homogenise", "materials", "upscale")

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
    fitter: Fitter = fit,
    fitted: tuple[Fit, float] | None = None,
    geometry_ready: Callable[[Asset], None] | None = None,
) -> tuple[Asset, Fit]:
    """Reconstruct a textured face from one photo.

    Args:
        image: (H, W, 3) uint8 RGB, a path, or a :class:`Photo`.
        model: the morphable model (default: the bundled one).
        backend: a name in :data:`BACKENDS` (``"default"``; ``"diffusion"`` needs its weights, so
            pass an instance) or any :class:`TextureBackend` instance.
        size: UV map size S in texels (the maps come out at ``size · upscale``).
        upscale: 1, 2 or 4: Lanczos (or the backend's) upscaling of the maps.
        maps: which of albedo, normal, roughness, specular, displacement to compute; maps not
            asked for are not computed (roughness and specular fall back to the backend's
            ``constants``, written as factors).
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
        fitter: any :class:`facegeo.fitting.Fitter`, called once as
            ``fitter(photo, model=, landmarks=, detector=, camera=)``; default the
            analysis-by-synthesis :func:`facegeo.fit`, or e.g. a ``facegeo.regressor.Predictor``.
        fitted: ``(fit, seconds)``: a fit of this photo already made (e.g. in a forked child,
            :func:`facegeo.jobs.reconstruct_into_folder`) and the seconds it took, reported as the
            ``fit`` stage's time; ``fitter`` is then not called.
        geometry_ready: called before the unwrap and the texture stages, with the asset without
            its maps,
            constants and metadata (its geometry, parts and blendshapes: as in the asset
            returned), e.g. to start writing the files that need no maps.
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
    if fitted is None:
        result = fitter(photo, model=model, landmarks=landmarks, detector=detector, camera=camera)
        timings["fit"] = time.perf_counter() - t
    else:
        result, timings["fit"] = fitted

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
    geometry = Asset(
        vertices=result.shape_vertices,
        triangles=model.triangles,
        uv=model.uv,
        uv_triangles=model.uv_triangles,
        name="face",
        parts=part_list,
        face_triangles=np.all(model.face_mask[model.triangles], axis=1),
        blendshapes=model_blendshapes(model, result.delta),
    )
    if geometry_ready is not None:
        geometry_ready(geometry)

    t = stage("unwrap")
    if skin is None:
        skin = skin_mask(pixels, result.landmarks)
    raster = rasterize_uv(model, size=size)
    camera_maps = geometry_maps(result.vertices, model, raster, tangents=False)  # shared by both
    # independent of each other: on two threads where the process may use two (one in a Dask
    # worker: concurrency.usable_threads); their loops release the GIL
    ctx, (t_inc, m_vis) = run_concurrently([
        lambda: build_context(model, result, raster, camera_maps, white_reference=skin.white_reference),
        lambda: unwrap(pixels, result, model, maps=camera_maps, occlusion=skin.occlusion),
    ], workers=usable_threads())
    timings["unwrap"] = time.perf_counter() - t

    t = stage("inpaint")
    t_full = backend.inpaint(t_inc, m_vis, ctx)
    timings["inpaint"] = time.perf_counter() - t

    t = stage("homogenise")
    t_hom = backend.homogenise(t_full, ctx)
    timings["homogenise"] = time.perf_counter() - t
    result.info.setdefault("notes", []).extend(backend.report.get("notes", []))  # e.g. chroma invented

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

    constants = {name: value for name, value in backend.constants.items() if name not in out}
    asset = replace(
        geometry,
        maps=out,
        constants=constants,
        metadata={
            "parts": parts_report,
            "model": model.name,
            "backend": backend.name,
            "size": size,
            "upscale": upscale,
            "timings_s": timings,
            "texture_report": backend.report,
            "skin_mask": skin.summary(),
            "landmark_rms_px": result.landmark_rms_px,
            "fit": {k: v for k, v in result.to_dict().items() if k not in ("landmarks_px", "landmarks_fitted_px")},
        },
    )
    return asset, result
