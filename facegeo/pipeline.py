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

__all__ = ["reconstruct", "reconstruct_with_fit", "reconstruct_views", "BACKENDS", "STAGES", "VIEW_STAGES"]

#: The stages, in order, as reported to a progress callback and in ``metadata["timings_s"]``
#: (the parts need only the fit: with them the asset's geometry is complete before the texture
#: stages, :func:`reconstruct_with_fit`'s ``geometry_ready``).
STAGES = ("fit", "parts", "unwrap", "inpaint", "homogenise", "materials", "upscale")

#: The stages of :func:`reconstruct_views`, in order.
VIEW_STAGES = ("parts", "views", "fuse", "materials")


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
    geometry_ready: Callable[[Asset], int | None] | None = None,
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
            its maps, constants and metadata (its geometry, parts and blendshapes: as in the asset
            returned), e.g. to start writing the files that need no maps; returns how many cores
            the work it starts keeps busy meanwhile (None: none), which the unwrap leaves to it.
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

    t = _starting(progress, "fit")
    if fitted is None:
        result = fitter(photo, model=model, landmarks=landmarks, detector=detector, camera=camera)
        timings["fit"] = time.perf_counter() - t
    else:
        result, timings["fit"] = fitted

    t = _starting(progress, "parts")
    geometry, parts_report = _geometry(pixels, result, model, parts)
    timings["parts"] = time.perf_counter() - t
    busy = (geometry_ready(geometry) or 0) if geometry_ready is not None else 0

    t = _starting(progress, "unwrap")
    if skin is None:
        skin = skin_mask(pixels, result.landmarks)
    raster = rasterize_uv(model, size=size)
    camera_maps = geometry_maps(result.vertices, model, raster, tangents=False)  # shared by both
    # independent of each other: on two threads where the process may use two (one in a Dask
    # worker: concurrency.usable_threads) and geometry_ready's work does not keep the second busy
    # (the export's forked child begins now: beside it, the two threads took 0.51 s against 0.44 s
    # on one, benchmarks/RESULTS.md); their loops release the GIL
    ctx, (t_inc, m_vis) = run_concurrently([
        lambda: build_context(model, result, raster, camera_maps, white_reference=skin.white_reference),
        lambda: unwrap(pixels, result, model, maps=camera_maps, occlusion=skin.occlusion),
    ], workers=max(1, usable_threads() - busy))
    timings["unwrap"] = time.perf_counter() - t

    t = _starting(progress, "inpaint")
    t_full = backend.inpaint(t_inc, m_vis, ctx)
    timings["inpaint"] = time.perf_counter() - t

    t = _starting(progress, "homogenise")
    t_hom = backend.homogenise(t_full, ctx)
    timings["homogenise"] = time.perf_counter() - t
    result.info.setdefault("notes", []).extend(backend.report.get("notes", []))  # e.g. chroma invented

    t = _starting(progress, "materials")
    out = backend.materials(t_hom, ctx, maps=wanted)
    timings["materials"] = time.perf_counter() - t

    t = _starting(progress, "upscale")
    if upscale > 1:
        out = {name: backend.upscale(m, upscale) for name, m in out.items()}
        if "normal" in out:  # interpolated unit vectors are shorter than 1
            n = out["normal"]
            out["normal"] = (n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)).astype(np.float32)
        for name in ("albedo", "roughness", "specular"):
            if name in out:  # Lanczos overshoots at edges
                out[name] = np.clip(out[name], 0.0, 1.0)
    timings["upscale"] = time.perf_counter() - t

    asset = _textured(geometry, out, backend, model, result, skin, parts_report, size, upscale, timings)
    return asset, result


def _starting(progress: Callable[[str], None] | None, name: str) -> float:
    """Tell ``progress`` (when given) that the stage ``name`` starts; the clock's time (s)."""
    if progress is not None:
        progress(name)
    return time.perf_counter()


def _textured(geometry: Asset, maps: dict[str, np.ndarray], backend: TextureBackend, model: MorphableModel, fit_result: Fit,
              skin: SkinMask, parts_report: dict, size: int, upscale: int, timings: dict[str, float], **extra: object) -> Asset:
    """``geometry`` (:func:`_geometry`) with its ``maps``, the backend's constants for the maps
    not made, and the metadata: the parts' report, the model, backend, size, upscale, stage
    timings, texture report, skin mask summary, landmark RMS and fit record, then ``extra``."""
    return replace(
        geometry,
        maps=maps,
        constants={name: value for name, value in backend.constants.items() if name not in maps},
        metadata={
            "parts": parts_report,
            "model": model.name,
            "backend": backend.name,
            "size": size,
            "upscale": upscale,
            "timings_s": timings,
            **extra,
            "texture_report": backend.report,
            "skin_mask": skin.summary(),
            "landmark_rms_px": fit_result.landmark_rms_px,
            "fit": {k: v for k, v in fit_result.to_dict().items() if k not in ("landmarks_px", "landmarks_fitted_px")},
        },
    )


def _geometry(pixels: np.ndarray, fit_result: Fit, model: MorphableModel, parts: bool) -> tuple[Asset, dict]:
    """The asset of ``fit_result`` without maps, constants or metadata: its neutral-posed shape
    with the fitted expression, face region and blendshapes, and the model's eyes and mouth
    interior (the iris colour read in ``pixels``; a default one and a note in the fit's ``info``
    when none is found); and the parts' report."""
    part_list, report = [], {}
    model_parts = load_parts(model) if parts else ()
    if model_parts:
        iris, report = iris_colour(pixels, fit_result.landmarks)
        if iris is None:
            fit_result.info.setdefault("notes", []).append(report["note"])
        report["iris_srgb_used"] = list(iris or DEFAULT_IRIS_SRGB)
        part_list = part_assets(model_parts, model, fit_result.alpha, fit_result.delta, iris or DEFAULT_IRIS_SRGB)
        report["names"] = [p.name for p in part_list]
    geometry = Asset(
        vertices=fit_result.shape_vertices,
        triangles=model.triangles,
        uv=model.uv,
        uv_triangles=model.uv_triangles,
        name="face",
        parts=part_list,
        face_triangles=np.all(model.face_mask[model.triangles], axis=1),
        blendshapes=model_blendshapes(model, fit_result.delta),
    )
    return geometry, report


def _view_albedo(pixels: np.ndarray, fit_result: Fit, model: MorphableModel, skin: SkinMask | None, size: int,
                 backend: TextureBackend, reference: bool) -> tuple[np.ndarray, np.ndarray, object, SkinMask]:
    """What one photo of several gives: its de-lit albedo in UV ((S, S, 3) float32 linear RGB;
    the reference's complete, by the backend's inpaint and homogenise, the others' only where
    they saw the skin, by its ``delight``), how far each texel is to be taken from it ((S, S)
    float32: the backend's reliability of the seen texel, for the others only on the face's skin
    (the context's skin prior), × :func:`facegeo.texturing.fusion.view_weight`'s pixels per mm²), its :class:`TextureContext` (``backend`` keeps its analysis for
    ``materials``) and its skin mask (``skin``, or made here from MediaPipe's mesh or the fit's
    landmarks)."""
    from facegeo.colour import srgb_to_linear
    from facegeo.texturing.fusion import view_weight
    from facegeo.uv import unwrap_details

    skin = skin_mask(pixels, fit_result.landmarks) if skin is None else skin
    raster = rasterize_uv(model, size=size)
    camera_maps = geometry_maps(fit_result.vertices, model, raster, tangents=False)
    ctx = build_context(model, fit_result, raster, camera_maps, white_reference=skin.white_reference)
    seen = unwrap_details(pixels, fit_result, model, maps=camera_maps, occlusion=skin.occlusion)
    if reference:
        albedo = srgb_to_linear(backend.homogenise(backend.inpaint(seen.texture, seen.visibility, ctx), ctx)).astype(np.float32)
        reliable = backend.seen_reliability(ctx)
    else:  # only the face's skin (the context's skin prior): the lips, eyes and brows (which another expression or
        # a blink changes), the scalp, ears and neck (hair, the background at a silhouette) stay the reference's
        albedo, reliable = backend.delight(seen.texture, seen.visibility, ctx)
        if ctx.skin is not None:
            reliable = reliable * np.clip(ctx.skin, 0.0, 1.0)
    distance = np.linalg.norm(camera_maps.position, axis=-1)
    weight = view_weight(reliable, seen.cos_view, distance, fit_result.camera.focal)
    return albedo, weight, ctx, skin


def _other_views(pixels: list[np.ndarray], fits: list[Fit], model: MorphableModel, skins: list[SkinMask | None], size: int,
                 backend: str, views: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`_view_albedo` of the photos ``views`` (indices into the lists; not the reference),
    one after another, each with a fresh ``backend`` (by name): ``[(albedo, weight), ...]`` in
    that order (what a forked child sends back)."""
    answers = []
    for k in views:
        albedo, weight, _, _ = _view_albedo(pixels[k], fits[k], model, skins[k], size, BACKENDS[backend](), reference=False)
        answers.append((albedo, weight))
    return answers


#: What the reference's view costs over another's (it is completed by the backend's inpaint and
#: homogenise; the others are only de-lit): 2.0 s against 1.1 s on James's renders at 1K, 2 cores.
REFERENCE_VIEW_COST = 1.8


def _view_shares(count: int, reference: int, workers: int) -> list[list[int]]:
    """Which of ``count`` views each of ``workers`` processes textures: ``[this process's, each
    child's, ...]``, the reference in this process's share, first; each other view in turn to the
    least loaded (ties to a child), the reference weighing :data:`REFERENCE_VIEW_COST` others.
    On 2 cores five photos split as the reference and one other here, three in a child. A child
    a view, all at once, kept both cores as busy, with five processes each slowed by the others:
    the views of five renders took 5.9 s so, 4.4-4.8 s now (``reconstruct --one-person``)."""
    loads = [REFERENCE_VIEW_COST] + [0.0] * (workers - 1)
    shares: list[list[int]] = [[reference]] + [[] for _ in range(workers - 1)]
    for k in range(count):
        if k != reference:
            least = min(range(workers), key=lambda w: (loads[w], w == 0, w))
            shares[least].append(k)
            loads[least] += 1.0
    return shares


def _view_albedos(pixels: list[np.ndarray], fits: list[Fit], model: MorphableModel, skins: list[SkinMask | None], size: int,
                  backend: str, reference: int, main_backend: TextureBackend,
                  fork: bool) -> tuple[list[np.ndarray], list[np.ndarray], object, SkinMask]:
    """Every photo's albedo and weight (:func:`_view_albedo`), in order, and the reference's
    :class:`TextureContext` and skin mask: the reference's made here with ``main_backend``, the
    others shared between this process and, where ``fork`` and forking help, forked children,
    one fewer than :func:`usable_threads` (:func:`_view_shares`), all started before the
    reference's view begins."""
    from facegeo.forked_call import beside_children, can_fork, fork_call

    workers = usable_threads() if fork and can_fork() else 1
    shares = _view_shares(len(pixels), reference, workers)
    starts = [lambda share=share: fork_call(_other_views, pixels, fits, model, skins, size, backend, share) if share else None
              for share in shares[1:]]

    def mine() -> tuple[dict[int, tuple[np.ndarray, np.ndarray]], object, SkinMask]:
        albedo, weight, ctx, skin = _view_albedo(pixels[reference], fits[reference], model, skins[reference], size, main_backend,
                                                 reference=True)
        others = _other_views(pixels, fits, model, skins, size, backend, shares[0][1:])
        return {reference: (albedo, weight), **dict(zip(shares[0][1:], others))}, ctx, skin

    (results, ctx, skin), theirs = beside_children(
        starts, mine, lambda w, lost: _other_views(pixels, fits, model, skins, size, backend, shares[1 + w]))
    for share, answers in zip(shares[1:], theirs):
        results.update(zip(share, answers))
    return [results[k][0] for k in range(len(pixels))], [results[k][1] for k in range(len(pixels))], ctx, skin


def reconstruct_views(
    photos: list[Photo | np.ndarray],
    fits: list[Fit],
    model: MorphableModel | None = None,
    *,
    backend: str = "default",
    size: int = 1024,
    maps: Iterable[str] = MAP_NAMES,
    skins: list[SkinMask | None] | None = None,
    parts: bool = True,
    progress: Callable[[str], None] | None = None,
    fork: bool = False,
    geometry_ready: Callable[[Asset], None] | None = None,
) -> tuple[Asset, int, dict]:
    """One textured face from several photos of one person, fitted jointly (one identity,
    :func:`facegeo.fitting.fit_photos`): each photo unwrapped, completed and de-lit on its own
    by a fresh ``backend`` (its own camera, light and exposure), the albedos fused texel by
    texel from the photos that see each best, exposure and white balance matched to the
    reference photo (:func:`facegeo.texturing.fusion.fuse_albedos`), then the other maps made
    from the fused albedo in the reference's context. The reference is the colour photo whose
    head faces the camera most (the smallest rotation) among those without a hand over the face
    (their skin masks', all of them where every one has a hand); the asset carries its
    expression and parts. A greyscale photo among colour ones is left out of the texture (it has no skin colour
    to give), with a note.

    Args:
        photos: the K photos (:class:`Photo` or (H, W, 3) uint8 RGB), in the order of ``fits``.
        fits: their fits (sharing ``alpha``).
        model: the model the fits are of (default: the bundled one).
        backend: a name in :data:`BACKENDS` that needs no weights (the default backend).
        size: UV map size S. maps: as :func:`reconstruct_with_fit`.
        skins: each photo's :class:`facegeo.skin_mask.SkinMask` if already computed (None
            entries: computed here).
        parts, progress: as :func:`reconstruct_with_fit` (stages :data:`VIEW_STAGES`).
        fork: texture the other photos in forked children beside the reference's, one fewer
            than the threads the process may keep busy (:func:`_view_shares`,
            :func:`facegeo.forked_call.can_fork`, :func:`facegeo.concurrency.usable_threads`);
            the results are the same either way.
        geometry_ready: as :func:`reconstruct_with_fit`'s, called before the photos are textured;
            what it returns is not used here (the views' children are shared by
            :func:`_view_shares` alone).
    Returns:
        ``(asset, reference, report)``: the asset in model space (upright, mm; ``metadata``
        records the photos, the reference, the fusion report and the stage timings), the
        reference photo's index, and the fusion report.
    Raises:
        InputError: no photos, counts that do not match, bad maps or size. (One photo, e.g. the
            only one of the person left: its own albedo, as :func:`reconstruct_with_fit` makes it.)
    """
    from facegeo.colour import is_greyscale, linear_to_srgb
    from facegeo.texturing.fusion import fuse_albedos
    from facegeo.texturing.image_filters import pad_outside

    wanted = frozenset(maps)
    if not wanted or wanted - set(MAP_NAMES):
        raise InputError("<argument>", "maps", f"a non-empty subset of {', '.join(MAP_NAMES)}", ", ".join(sorted(wanted)) or "none")
    if not photos or len(photos) != len(fits) or (skins is not None and len(skins) != len(photos)):
        raise InputError("<argument>", "photos", "one or more photos, one fit (and skin mask) each",
                         f"{len(photos)} photos, {len(fits)} fits")
    if not 64 <= size <= 8192:
        raise InputError("<argument>", "size", "a map size between 64 and 8192 texels", str(size))
    if backend not in BACKENDS or backend == "diffusion":
        raise InputError("<argument>", "backend", "the default backend (several photos)", repr(backend))
    model = load_model() if model is None else model
    timings: dict[str, float] = {}

    pixels = [photo.image if isinstance(photo, Photo) else as_rgb_uint8(photo) for photo in photos]
    names = [str(f.info.get("source", k)) for k, f in enumerate(fits)]
    # a greyscale photo tells nothing of the skin's colour: the colour ones texture the face where there are any
    grey = [is_greyscale(p[::4, ::4]) for p in pixels]
    used = [k for k in range(len(pixels)) if not grey[k]] or list(range(len(pixels)))
    turn = [np.arccos(np.clip((np.trace(np.asarray(f.rotation, np.float64)) - 1) / 2, -1, 1)) for f in fits]
    skins = list(skins) if skins is not None else [None] * len(photos)
    frontal_first = sorted(used, key=lambda k: turn[k])
    for reference in frontal_first:  # the most frontal whose mask finds no hand over the face
        if skins[reference] is None:  # (the reference's mask is made here anyway; another's only if one before it has a hand)
            skins[reference] = skin_mask(pixels[reference], fits[reference].landmarks)
        if skins[reference].hands == 0:
            break
    else:  # a hand in every photo
        reference = frontal_first[0]
    main = fits[reference]
    t = _starting(progress, "parts")
    geometry, parts_report = _geometry(pixels[reference], main, model, parts)
    timings["parts"] = time.perf_counter() - t
    if geometry_ready is not None:
        geometry_ready(geometry)

    t = _starting(progress, "views")
    main_backend = BACKENDS[backend]()
    albedos, weights, ctx, skin_used = _view_albedos([pixels[k] for k in used], [fits[k] for k in used], model,
                                                     [skins[k] for k in used], size, backend, used.index(reference), main_backend, fork)
    timings["views"] = time.perf_counter() - t

    t = _starting(progress, "fuse")
    skin = ctx.coverage if ctx.skin is None else ctx.coverage & (ctx.skin > 0.5)
    fused, report = fuse_albedos(albedos, weights, skin, ctx.coverage, used.index(reference), names=[names[k] for k in used])
    report["notes"] = [f"{names[k]}: a greyscale photo among colour ones: left out of the texture" for k in range(len(pixels))
                       if k not in used] + report["notes"]
    report["photos"] = [names[k] for k in used]  # what the report's indices (its reference's too) count
    timings["fuse"] = time.perf_counter() - t

    t = _starting(progress, "materials")
    out = main_backend.materials(pad_outside(linear_to_srgb(fused).astype(np.float32), ctx.coverage), ctx, maps=wanted)
    timings["materials"] = time.perf_counter() - t

    asset = _textured(geometry, out, main_backend, model, main, skin_used, parts_report, size, 1, timings,
                      photos=names, reference=reference, fusion=report)
    return asset, reference, report
