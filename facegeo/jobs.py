"""One photo in, one output folder out: the two jobs the ``fit`` and ``reconstruct`` commands run,
as library functions (the CLI parses options into :class:`FitOptions` / :class:`ReconstructOptions`
and calls :func:`fit_into_folder` / :func:`reconstruct_into_folder`; batch processing calls the
same functions once per photo).

The folder is written through :class:`facegeo.staged_output.StagedOutput`: it appears complete
or not at all; a re-run into an earlier facegeo output replaces that run's files and keeps every
other file. Each job holds the folder's lock (:func:`facegeo.staged_output.locked_output`) from
its start, so a second run into the same folder is refused before it fits. The morphable model and a
regressor checkpoint are loaded once per process and reused (:func:`loaded_resources`), so a
worker that runs many jobs reads them once.
"""

from __future__ import annotations

import functools
import json
import math
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from facegeo.errors import InputError

__all__ = ["FitOptions", "ReconstructOptions", "TrackOptions", "JobRecord", "fit_into_folder", "fit_one_person_into_folder",
           "reconstruct_into_folder", "track_into_folder", "loaded_resources", "photo_camera", "FIT_FILES", "DISPLACEMENT_BAKE_RULE"]

#: The files ``fit_into_folder`` writes.
FIT_FILES = ("fit.json", "mesh.obj", "overlay.png")

#: When displacement is baked into the exported geometry (see :func:`reconstruct_into_folder`).
DISPLACEMENT_BAKE_RULE = (
    "An 11k-vertex mesh cannot carry texel-scale displacement: at subdiv 0 the detail travels in the "
    "normal map only and the displacement map stays in the asset folder; at subdiv ≥ 1 the subdivided "
    "mesh is displaced and the scenes carry the displacement map as well."
)

_SOURCE = "<options>"


@dataclass(frozen=True)
class FitOptions:
    """What a fit needs besides the photo.

    Attributes:
        model: model file (.npz, HIFI3D++ .mat, AI-NExT .mat); None = $FACEGEO_MODEL or the bundled one.
        landmarks: landmark detector name (``facegeo.landmarks.DETECTORS``).
        focal: focal length in pixels of the (possibly downscaled) photo; None = unknown (the
            fitter estimates it from the face: :mod:`facegeo.fitting.camera_estimate`).
        principal_point: (cx, cy) pixels of the (possibly downscaled) photo, e.g. of a crop;
            None = the centre.
        max_side: photos whose longer side exceeds this many pixels are downscaled.
        photometric: run the albedo and SH lighting stage (``fit`` only; ``reconstruct`` always does).
        regressor: a trained regressor checkpoint to use instead of the analysis-by-synthesis fit.
        refine: with ``regressor``: run the analysis-by-synthesis fit started from its prediction.
    """

    model: Path | None = None
    landmarks: str = "hybrid"
    focal: float | None = None
    principal_point: tuple[float, float] | None = None
    max_side: int = 2048
    photometric: bool = True
    regressor: Path | None = None
    refine: bool = False

    def __post_init__(self) -> None:
        from facegeo.landmarks import DETECTORS

        if self.landmarks not in DETECTORS:
            raise InputError(_SOURCE, "landmarks", f"one of {', '.join(DETECTORS)}", repr(self.landmarks))
        if self.refine and self.regressor is None:
            raise InputError(_SOURCE, "refine", "a regressor checkpoint with it", "no regressor")


@dataclass(frozen=True)
class ReconstructOptions(FitOptions):
    """:class:`FitOptions` plus what the texture, export and preview stages need.

    Attributes:
        backend: texture backend name (``facegeo.texturing.registry.BACKENDS``).
        weights: the diffusion backend's weights folder (only with ``backend="diffusion"``).
        size: UV map size in texels; upscale: 1, 2 or 4; subdiv: Loop levels of the exported mesh.
        maps: which maps to compute and export (names from ``facegeo.asset.MAP_NAMES``).
        formats: scene formats to write (names from ``facegeo.export.writers.FORMATS``).
        parts: what the scenes hold: face, head or full (``facegeo.asset.PART_CHOICES``).
        preview: render preview.png.
        blendshapes: write the expression blendshapes into the scenes (glTF morph targets,
            UsdSkel blend shapes) so that they can be animated; False: a static asset.
        blendshape_names: their names, ``arkit`` or ``ict`` (``facegeo.arkit.BLENDSHAPE_NAMINGS``).
    """

    backend: str = "default"
    weights: Path | None = None
    size: int = 1024
    upscale: int = 1
    subdiv: int = 0
    maps: tuple[str, ...] = ("albedo", "normal", "roughness", "specular", "displacement")
    formats: tuple[str, ...] = ("usdz", "glb")
    parts: str = "full"
    preview: bool = True
    blendshapes: bool = True
    blendshape_names: str = "arkit"

    def __post_init__(self) -> None:
        super().__post_init__()
        from facegeo.asset import MAP_NAMES, PART_CHOICES
        from facegeo.export.writers import FORMATS
        from facegeo.texturing.registry import BACKENDS

        for name, values, allowed in (("maps", self.maps, MAP_NAMES), ("formats", self.formats, FORMATS)):
            if not values or any(v not in allowed for v in values):
                raise InputError(_SOURCE, name, f"one or more of {', '.join(allowed)}", ", ".join(values) or "none")
        if self.backend not in BACKENDS:
            raise InputError(_SOURCE, "backend", f"one of {', '.join(BACKENDS)}", repr(self.backend))
        if self.weights is not None and self.backend != "diffusion":
            raise InputError(_SOURCE, "weights", "backend diffusion", f"backend {self.backend}")
        if self.upscale not in (1, 2, 4):
            raise InputError(_SOURCE, "upscale", "1, 2 or 4", str(self.upscale))
        if self.subdiv not in (0, 1, 2, 3):
            raise InputError(_SOURCE, "subdiv", "0, 1, 2 or 3", str(self.subdiv))
        if self.parts not in PART_CHOICES:
            raise InputError(_SOURCE, "parts", f"one of {', '.join(PART_CHOICES)}", repr(self.parts))
        from facegeo.arkit import BLENDSHAPE_NAMINGS

        if self.blendshape_names not in BLENDSHAPE_NAMINGS:
            raise InputError(_SOURCE, "blendshape_names", f"one of {', '.join(BLENDSHAPE_NAMINGS)}", repr(self.blendshape_names))


@dataclass
class JobRecord:
    """What one job did. ``timings`` in seconds by stage (``export`` and ``preview`` overlap:
    :func:`reconstruct_into_folder`); ``landmark_rms_percent_iod`` in % of the inter-ocular
    distance; ``files``: the names written into ``output``."""

    photo: str
    output: str
    landmark_rms_px: float
    landmark_rms_percent_iod: float
    timings: dict[str, float]
    files: list[str]
    notes: list[str] = field(default_factory=list)
    maps: list[str] = field(default_factory=list)
    map_size: int = 0

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict."""
        return asdict(self)


@functools.lru_cache(maxsize=4)
def loaded_resources(model: Path | None, regressor: Path | None, refine: bool, landmarks: str) -> tuple[Any, Callable[..., Any] | None]:
    """``(model, predictor)`` for these options, loaded once per process: the
    :class:`facegeo.MorphableModel` and the :class:`facegeo.regressor.Predictor` (None without a
    checkpoint). Errors name the file and come before any photo is read."""
    from facegeo.model_files import load_model

    loaded = load_model(model)
    if regressor is None:
        return loaded, None
    from facegeo.regressor.predictor import load

    return loaded, load(regressor, model=loaded, detector=landmarks, refine=refine)


def photo_camera(photo: Any, focal: float | None, principal_point: tuple[float, float] | None = None) -> Any:
    """The :class:`facegeo.Camera` of a loaded :class:`facegeo.Photo` (the ``--focal`` and
    ``--principal-point`` options of every command that fits): ``focal`` and ``principal_point``
    in pixels of the (possibly downscaled) photo; the principal point defaults to the centre; no
    focal gives :meth:`Camera.unknown_focal` (the fitter estimates it from the face)."""
    from facegeo.camera import Camera

    height, width = photo.image.shape[:2]
    if focal is None:
        return Camera.unknown_focal(width, height, principal_point)
    cx, cy = (width / 2.0, height / 2.0) if principal_point is None else principal_point
    return Camera(focal, cx, cy, width, height)


def fit_into_folder(photo_path: str | Path, output: str | Path, options: FitOptions | None = None) -> JobRecord:
    """Fit the model to one photo and write ``fit.json`` (parameters, camera, per-point landmark
    errors, timings), ``mesh.obj`` (posed mesh in camera space, mm, with UVs) and ``overlay.png``
    into ``output`` (an earlier facegeo output there: its files are replaced, other files kept).
    ``options``: default ``FitOptions()``.

    Raises:
        facegeo.errors.FacegeoError: bad photo, no face, failed fit checks, an unwritable output,
            or another run writing into ``output``.
    """
    from facegeo.image_files import png_bytes
    from facegeo.fitting import fit
    from facegeo.mesh_io import obj_text
    from facegeo.overlay import draw_overlay
    from facegeo.photo import load_photo
    from facegeo.staged_output import StagedOutput, locked_output

    options = FitOptions() if options is None else options
    with locked_output(output):  # a second run into the same folder is refused now, not after the fit
        start = time.perf_counter()
        model, predictor = loaded_resources(options.model, options.regressor, options.refine, options.landmarks)
        model_seconds = time.perf_counter() - start
        photo = load_photo(photo_path, max_side=options.max_side)
        fitter = predictor or fit
        result = fitter(photo, model=model, detector=options.landmarks, camera=photo_camera(photo, options.focal, options.principal_point),
                        photometric=options.photometric)
        result.timings["load_model"] = model_seconds
        result.timings["total"] = time.perf_counter() - start
        result.info["landmark_rms_percent_iod"] = result.landmark_rms_percent_iod
        with StagedOutput(output, replace=True) as stage:
            stage.path("fit.json").write_text(json.dumps(result.to_dict(), indent=1))
            stage.path("mesh.obj").write_text(obj_text(result.vertices, model.triangles, model.uv, model.uv_triangles))
            stage.path("overlay.png").write_bytes(png_bytes(draw_overlay(photo.image, result, model)))
        return JobRecord(photo=str(photo_path), output=str(output), landmark_rms_px=float(result.landmark_rms_px),
                         landmark_rms_percent_iod=float(result.landmark_rms_percent_iod),
                         timings=dict(result.timings), files=list(FIT_FILES), notes=list(result.info.get("notes", [])))


def fit_one_person_into_folder(photo_paths: list[str | Path], output: str | Path, options: FitOptions | None = None) -> JobRecord:
    """Fit several photos of one person jointly (:func:`facegeo.fitting.fit_photos`: one
    identity α, pose, expression and camera per photo; a photo of someone else is left out with a
    note) and write into ``output``: ``fit.json`` (the shared ``alpha``, ``photos``: per photo
    its fit as ``fit_into_folder`` records it, without α; ``left_out``; timings; notes),
    ``mesh.obj`` (posed in the first kept photo's camera) and ``overlay.png`` (each kept photo's
    overlay, side by side at one height).

    Raises:
        facegeo.errors.FacegeoError: fewer than two photos, a regressor (not supported here), a bad
            photo, no face, failed fit checks, an unwritable output, or another run into ``output``.
    """
    import cv2

    from facegeo.image_files import png_bytes
    from facegeo.mesh_io import obj_text
    from facegeo.overlay import draw_overlay
    from facegeo.staged_output import StagedOutput, locked_output

    options = FitOptions() if options is None else options
    with locked_output(output):
        start = time.perf_counter()
        model, photos, fits, _ = _one_person_fits(photo_paths, options)
        seconds = time.perf_counter() - start
        document = _one_person_document(fits, model, {"total": seconds})
        notes = document["notes"]
        overlays = [draw_overlay(photo.image, fit, model) for photo, fit in zip(photos, fits)]
        height = min(o.shape[0] for o in overlays)
        strip = np.concatenate([cv2.resize(o, (round(o.shape[1] * height / o.shape[0]), height), interpolation=cv2.INTER_AREA)
                                for o in overlays], axis=1)
        with StagedOutput(output, replace=True) as stage:
            stage.path("fit.json").write_text(json.dumps(document, indent=1))
            stage.path("mesh.obj").write_text(obj_text(fits[0].vertices, model.triangles, model.uv, model.uv_triangles))
            stage.path("overlay.png").write_bytes(png_bytes(strip))
        rms = [float(f.landmark_rms_px) for f in fits]
        return JobRecord(photo=", ".join(str(p) for p in photo_paths), output=str(output), landmark_rms_px=float(np.sqrt(np.mean(np.square(rms)))),
                         landmark_rms_percent_iod=float(np.sqrt(np.mean([f.landmark_rms_percent_iod ** 2 for f in fits]))),
                         timings={"total": seconds}, files=list(FIT_FILES), notes=notes)


def _one_person_fits(photo_paths: list[str | Path], options: FitOptions,
                     beside: Callable[[list[Any]], Any] | None = None) -> tuple[Any, list[Any], list[Any], Any]:
    """``(model, photos, fits, beside's answer)`` of the joint fit of several photos of one person
    (:func:`facegeo.fitting.fit_photos`), each photo with its own camera; the photos are those
    of the kept fits, in order. ``beside(observations)`` (None: nothing) runs on the photos'
    observations while they are fitted, the fit in a forked child where that helps. Refuses
    fewer than two photos and a regressor."""
    from facegeo.fitting.photo_fit import observe_photo
    from facegeo.fitting.shared_identity import fit_observed
    from facegeo.forked_call import beside_child, can_fork, fork_call
    from facegeo.photo import load_photo

    if len(photo_paths) < 2:
        raise InputError(_SOURCE, "one person", "two or more photos of the person", str(len(photo_paths)))
    if options.regressor is not None:
        raise InputError(_SOURCE, "regressor", "no regressor with several photos of one person (the joint fit)", str(options.regressor))
    model, _ = loaded_resources(options.model, None, False, options.landmarks)
    photos = [load_photo(p, max_side=options.max_side) for p in photo_paths]
    _refuse_repeated_photos(photos)
    seen = [observe_photo(photo, model, None, options.landmarks, photo_camera(photo, options.focal, options.principal_point))
            for photo in photos]
    forking = beside is not None and can_fork()
    aside, fits = beside_child(lambda: fork_call(fit_observed, seen, model, options.photometric) if forking else None,
                               lambda: beside(seen) if beside is not None else None,
                               lambda lost: fit_observed(seen, model, options.photometric))
    if len(fits) < 2:  # the others were someone else: no second view of this person
        others = ", ".join(fits[0].info["shared_identity"]["left_out"])
        raise InputError(_SOURCE, "one person", "two or more photos of one person",
                         f"one of the person ({fits[0].info['source']}), the rest of someone else by their face descriptors ({others})")
    by_source = {photo.path: photo for photo in photos}
    return model, [by_source[fit.info["source"]] for fit in fits], fits, aside


def _refuse_repeated_photos(photos: list[Any]) -> None:
    """Raise :class:`InputError` for a photo given twice (the same file by two names, or a file
    with the same pixels): a second view that is the first one again adds nothing to the joint
    fit but its weight."""
    import hashlib

    first: dict[tuple[str, ...], Any] = {}
    for photo in photos:
        key = (str(photo.image.shape), hashlib.blake2b(photo.image.tobytes(), digest_size=16).hexdigest())
        if key in first:
            raise InputError(photo.path, "one person", "each photo of the person once",
                             f"the same picture as {first[key].path}")
        first[key] = photo


def _skin_masks(seen: list[Any]) -> dict[str, Any]:
    """Each observed photo's skin mask (:func:`facegeo.skin_mask.skin_mask`) by its source, on the
    landmarks as its fit records them (float32), so the mask is the one the pipeline would make."""
    from facegeo.skin_mask import skin_mask

    return {str(s.source): skin_mask(s.pixels, np.asarray(s.landmarks, np.float64).astype(np.float32)) for s in seen}


def _one_person_document(fits: list[Any], model: Any, timings: dict[str, float]) -> dict[str, Any]:
    """The ``fit.json`` of a joint fit: the shared ``alpha``, ``photos`` (per photo its fit as
    :func:`fit_into_folder` records it, without α), ``left_out``, ``timings_s``, ``notes``."""
    records = []
    for fit in fits:
        record = fit.to_dict()
        record.pop("alpha")
        record["photo"] = fit.info["source"]
        record["landmark_rms_percent_iod"] = fit.landmark_rms_percent_iod
        records.append(record)
    return {"one_person": True, "model": model.name, "alpha": fits[0].alpha.tolist(), "photos": records,
            "left_out": fits[0].info["shared_identity"].get("left_out", []), "timings_s": timings,
            "notes": list(dict.fromkeys(n for f in fits for n in f.info.get("notes", [])))}


def reconstruct_one_person_into_folder(photo_paths: list[str | Path], output: str | Path, options: ReconstructOptions | None = None,
                                       progress: Callable[[str], None] | None = None, fork: bool = False) -> JobRecord:
    """Several photos of one person into one textured face in ``output``: the joint fit (one
    identity, a pose, expression and camera per photo; a photo of someone else left out with a
    note), each photo textured on its own and the albedos fused, each texel from the photos that
    see it best (:func:`facegeo.pipeline.reconstruct_views`; the reference is the most frontal
    photo, whose expression, parts and light analysis the asset takes), then the files of
    :func:`reconstruct_into_folder`: ``fit.json`` (the joint fit's record as
    :func:`fit_one_person_into_folder` writes it, with the stage timings, the reference, the
    fusion and texture reports and the parts), the asset folder, the scenes and ``preview.png``
    (the reference photo beside the asset).

    Args:
        fork: texture the photos in forked children beside each other where that helps
            (:func:`facegeo.pipeline.reconstruct_views`); the results are the same either way.
    Raises:
        facegeo.errors.FacegeoError: fewer than two photos, a regressor or the diffusion backend
            (not supported here), a bad photo, no face, failed fit checks, an unwritable output,
            or another run writing into ``output``.
    """
    from facegeo.export_job import PREVIEW_FILE, ExportJob
    from facegeo.forked_call import can_fork
    from facegeo.image_files import png_bytes
    from facegeo.pipeline import reconstruct_views
    from facegeo.staged_output import StagedOutput, locked_output
    from facegeo.texturing.preview import relit_preview

    options = ReconstructOptions() if options is None else options
    if options.backend != "default":
        raise InputError(_SOURCE, "backend", "the default backend with several photos of one person", options.backend)
    if options.upscale != 1:
        raise InputError(_SOURCE, "upscale", "1 with several photos of one person", str(options.upscale))
    with locked_output(output):
        start = time.perf_counter()
        if progress is not None:
            progress("fit")
        # the photos' skin masks (they need the observed landmarks only) while the joint fit runs in a child
        model, photos, fits, masks = _one_person_fits(photo_paths, options, beside=_skin_masks if fork else None)
        skins = None if masks is None else [masks[str(fit.info["source"])] for fit in fits]
        timings = {"fit": time.perf_counter() - start}
        with StagedOutput(output, replace=True) as stage:
            jobs: list[ExportJob] = []
            plan = _export_plan(options, stage.staging_dir)
            try:  # the export begins on the reference's geometry, in a child where forking helps, while the photos are textured
                asset, reference, _ = reconstruct_views(
                    photos, fits, model, skins=skins, size=options.size, maps=options.maps, progress=progress, fork=fork,
                    geometry_ready=lambda geometry: jobs.append(ExportJob(geometry, plan, fork=fork and can_fork())))
                timings.update(asset.metadata["timings_s"])
                if progress is not None:
                    progress("export")
                beside = []
                if options.preview:
                    preview = stage.path(PREVIEW_FILE)
                    beside.append(("preview", lambda: preview.write_bytes(png_bytes(relit_preview(photos[reference].image, asset,
                                                                                                  fits[reference])))))
                timings.update(_completed_export(jobs[0], asset, beside))
            except BaseException:
                for job in jobs:
                    job.abandon()
                raise
            timings["total"] = time.perf_counter() - start
            document = _one_person_document(fits, model, {"stages": timings})
            document["notes"] = list(dict.fromkeys([*document["notes"], *asset.metadata["fusion"]["notes"], *jobs[0].notes]))
            document.update({"reference": fits[reference].info["source"], "fusion": asset.metadata["fusion"],
                             "texture_report": asset.metadata["texture_report"], "parts": asset.metadata["parts"]})
            stage.path("fit.json").write_text(json.dumps(document, indent=1))
            files = sorted(p.name for p in stage.staging_dir.iterdir())
        rms = [float(f.landmark_rms_px) for f in fits]
        return JobRecord(photo=", ".join(str(f.info["source"]) for f in fits), output=str(output),  # the photos kept
                         landmark_rms_px=float(np.sqrt(np.mean(np.square(rms)))),
                         landmark_rms_percent_iod=float(np.sqrt(np.mean([f.landmark_rms_percent_iod ** 2 for f in fits]))),
                         timings=timings, files=files, notes=document["notes"],
                         maps=list(asset.maps), map_size=int(next(iter(asset.maps.values())).shape[0]))


def reconstruct_into_folder(photo_path: str | Path, output: str | Path, options: ReconstructOptions | None = None,
                            progress: Callable[[str], None] | None = None, fork: bool = False) -> JobRecord:
    """The whole pipeline on one photo, into ``output``: ``fit.json`` (the fit, stage timings, the
    texture report, the parts), the asset files (``asset.json`` + map PNGs, re-exportable with
    ``facegeo export``), ``skin_mask.png`` when MediaPipe's mesh found the face, one scene per
    format (``face.usdz``, ``face.glb``, ...) holding ``options.parts``, and ``preview.png`` (the
    photo beside the asset from the front, three-quarter and profile, textured and as clay).
    Displacement: :data:`DISPLACEMENT_BAKE_RULE`.

    The export (:class:`facegeo.export_job.ExportJob`) begins on the fit's geometry and ends on
    the maps, each map's PNG made once for the scenes and the asset folder; the preview and the
    skin mask are made beside its end. The record's ``export`` time runs from the maps' hand-over
    to the last export file written, ``preview`` is the preview's own time, and the two overlap.

    Args:
        options: default ``ReconstructOptions()``.
        progress: called with each stage's name as it starts (the pipeline's ``STAGES``, then
            ``export`` and ``preview``, which start together).
        fork: where that helps (:func:`facegeo.forked_call.can_fork`, the default backend, no
            regressor; the single-photo command's choice), fit and make the skin mask in a
            forked child while this process imports the texture stages and loads the model's UV
            raster and layout priors, and write the export in another, begun on the fit's
            geometry while the texture stages run (:mod:`facegeo.forked_call`); the results are
            the same either way.
    Raises:
        facegeo.errors.FacegeoError: bad photo or options, no face, failed fit checks, missing
            weights, an unwritable output, or another run writing into ``output``.
    """
    from facegeo.forked_call import ChildLost, beside_child, can_fork, fork_call
    from facegeo.photo import load_photo
    from facegeo.staged_output import StagedOutput, locked_output
    from facegeo.texturing.registry import BACKENDS

    options = ReconstructOptions() if options is None else options
    with locked_output(output):  # a second run into the same folder is refused now, not after the fit
        start = time.perf_counter()
        backend = BACKENDS[options.backend](options.weights) if options.backend == "diffusion" else options.backend  # weights checked first
        model, predictor = loaded_resources(options.model, options.regressor, options.refine, options.landmarks)
        photo = load_photo(photo_path, max_side=options.max_side)
        forking = fork and backend == "default" and predictor is None and can_fork()

        def meanwhile() -> None:  # while the child fits: the texture stages' imports, the UV raster and the layout priors
            import facegeo.export_job  # noqa: F401  (the modules below loaded now, from sys.modules then)
            import facegeo.image_files  # noqa: F401
            import facegeo.pipeline  # noqa: F401
            from facegeo.texturing.context import layout_priors
            from facegeo.uv import rasterize_uv
            if options.preview:
                import facegeo.texturing.preview  # noqa: F401

            if forking:  # both depend on the model alone and are cached: the pipeline finds them
                layout_priors(model, rasterize_uv(model, size=options.size))

        def fitted_here(lost: ChildLost | None) -> tuple[Any, float, Any]:
            fitted, seconds, skin = _fitted_and_skin(photo, str(photo_path), options)
            if lost is not None:  # the child was killed (e.g. out of memory): the same fit, here
                fitted.info.setdefault("notes", []).append(f"the forked fit ended {lost.how} without an answer; fitted again in the main process")
            return fitted, seconds, skin

        _, (fitted, fit_seconds, skin) = beside_child(
            lambda: fork_call(_fitted_and_skin, photo, str(photo_path), options) if forking else None, meanwhile, fitted_here)
        from facegeo.export_job import ExportJob, PreviewPlan
        from facegeo.image_files import png_bytes
        from facegeo.landmarks.scheme import IBUG68
        from facegeo.pipeline import reconstruct_with_fit
        from facegeo.skin_mask import skin_mask_image

        with StagedOutput(output, replace=True) as stage:
            jobs: list[ExportJob] = []
            plan = _export_plan(options, stage.staging_dir)
            if options.preview:  # its views are rasterised on the geometry, with the rest of the export's first half
                plan = replace(plan, preview=PreviewPlan(photo.image, fitted.landmarks[IBUG68]))

            def export_begun(geometry: Any) -> int:  # the cores it keeps busy meanwhile: the child's, whose first half runs now
                jobs.append(ExportJob(geometry, plan, fork=forking))
                return 1 if forking else 0

            try:  # the export begins on the fit's geometry, in a child where forking helps, while the texture stages run here
                asset, result = reconstruct_with_fit(
                    photo, model, backend=backend, size=options.size, upscale=options.upscale, maps=options.maps,
                    detector=options.landmarks, skin=skin, progress=progress, fitted=(fitted, fit_seconds),
                    geometry_ready=export_begun)
                timings = dict(asset.metadata["timings_s"])  # asset.json's stage timings, and fit.json's after export
                if progress is not None:
                    progress("export")
                    if options.preview:
                        progress("preview")
                beside: list[tuple[str, Callable[[], Any]]] = []
                if skin is not None:
                    mask = stage.path("skin_mask.png")
                    beside.append(("skin mask", lambda: mask.write_bytes(png_bytes(skin_mask_image(skin)))))
                timings.update(_completed_export(jobs[0], asset, beside))
            except BaseException:
                for job in jobs:
                    job.abandon()
                raise
            result.info.setdefault("notes", []).extend(jobs[0].notes)
            timings["total"] = time.perf_counter() - start
            record = result.to_dict()
            record["timings_s"] = {**record["timings_s"], "stages": timings}
            record["texture_report"] = asset.metadata.get("texture_report", {})
            record["parts"] = asset.metadata.get("parts", {})
            stage.path("fit.json").write_text(json.dumps(record, indent=1))
            files = sorted(p.name for p in stage.staging_dir.iterdir())
        return JobRecord(photo=str(photo_path), output=str(output), landmark_rms_px=float(result.landmark_rms_px),
                         landmark_rms_percent_iod=float(result.landmark_rms_percent_iod),
                         timings=timings, files=files, notes=list(result.info.get("notes", [])),
                         maps=list(asset.maps), map_size=int(next(iter(asset.maps.values())).shape[0]))


def _export_plan(options: ReconstructOptions, folder: Path) -> Any:
    """The :class:`facegeo.export_job.ExportPlan` of ``options`` into ``folder`` (the displacement
    carried by the scenes as :data:`DISPLACEMENT_BAKE_RULE` says)."""
    from facegeo.export_job import ExportPlan

    return ExportPlan(folder=folder, formats=tuple(options.formats), parts=options.parts, level=options.subdiv,
                      bake_displacement=options.subdiv > 0 and "displacement" in options.maps,
                      blendshapes=options.blendshape_names if options.blendshapes else None, maps=frozenset(options.maps))


def _completed_export(job: Any, asset: Any, beside: list[tuple[str, Callable[[], Any]]]) -> dict[str, float]:
    """Complete the :class:`facegeo.export_job.ExportJob` ``job`` with ``asset``, the ``beside``
    tasks (the skin mask; the preview where the job's plan has none) made meanwhile here; returns
    the ``export`` time (from the maps' hand-over to the last export file written, the preview
    aside) and the ``preview``'s own, when made (by the job, its views in the first half
    included, or beside it)."""
    start = time.perf_counter()
    spans = job.complete(asset, beside)
    own = {name for name, _ in beside} | {"preview"}
    timings = {"export": max(end for name, (_, end) in spans.items() if name not in own) - start}
    if "preview" in spans:  # with its views, where the job made them on the geometry
        timings["preview"] = sum(spans[name][1] - spans[name][0] for name in ("preview views", "preview") if name in spans)
    return timings


def _fitted(photo: Any, source: str, options: FitOptions) -> tuple[Any, float]:
    """The fit of a reconstruction and its seconds (in a forked child where
    :func:`reconstruct_into_folder` can overlap it with the skin mask and the texture stages'
    model-only work)."""
    from facegeo.fitting import fit

    model, predictor = loaded_resources(options.model, options.regressor, options.refine, options.landmarks)
    start = time.perf_counter()
    result = (predictor or fit)(photo, model=model, detector=options.landmarks,
                                camera=photo_camera(photo, options.focal, options.principal_point))
    return result, time.perf_counter() - start


def _fitted_and_skin(photo: Any, source: str, options: FitOptions) -> tuple[Any, float, Any]:
    """:func:`_fitted` and then :func:`_photo_skin`: ``(fit, seconds, skin mask or None)``. One
    call, so that a forked child makes the mask on the MediaPipe models its fit has just loaded
    while the caller imports the texture stages (the caller's imports took longer than the
    child's fit: with the mask made there too, the caller waited for neither)."""
    fitted, seconds = _fitted(photo, source, options)
    return fitted, seconds, _photo_skin(photo, source)


def _photo_skin(photo: Any, source: str) -> Any:
    """The photo's :class:`facegeo.skin_mask.SkinMask`, or None when MediaPipe finds no face
    (the pipeline then builds one from the fit's landmarks)."""
    from facegeo.errors import NoFaceError
    from facegeo.skin_mask import skin_mask

    try:
        return skin_mask(photo.image, source=source)
    except NoFaceError:
        return None


@dataclass(frozen=True)
class TrackOptions:
    """What tracking a video needs besides the video.

    Attributes:
        model, landmarks: as :class:`FitOptions`.
        focal: the lens's focal length in pixels of the frames; None: unknown (one focal for the
            clip, :mod:`facegeo.tracking`).
        start_s, end_s: only the frames from ``start_s`` to before ``end_s`` (seconds; None: the
            whole clip); every: every N-th of those frames.
        keyframes: how many frames the identity is fitted to.
        asset: also write the person's textured asset animated by the take
            (:func:`track_into_folder`).
        smooth: take the frame-to-frame jitter out of the pose and the weights
            (:func:`facegeo.tracking.smooth_track`).
        neutral_s: seconds into the video at which the face is at rest: every frame's points are
            then measured from the person's own there (:func:`facegeo.tracking.neutral_offsets`,
            what Live Link Face's calibration is for); None: see ``find_rest``.
        find_rest: without ``neutral_s``, measure them from the clip's most typical still
            stretch where it is typical enough to be the face at rest
            (:func:`facegeo.tracking.rest_stretch`); False: as observed.
        fps: the frames' rate (frames per second) where the source records none (a folder of
            frames) or records it wrong; None: the source's, else 30 with a note.
    """

    model: Path | None = None
    landmarks: str = "hybrid"
    focal: float | None = None
    start_s: float | None = None
    end_s: float | None = None
    every: int = 1
    keyframes: int = 5
    asset: bool = True
    smooth: bool = True
    neutral_s: float | None = None
    fps: float | None = None
    find_rest: bool = True

    def __post_init__(self) -> None:
        from facegeo.landmarks import DETECTORS

        if self.landmarks not in DETECTORS:
            raise InputError(_SOURCE, "landmarks", f"one of {', '.join(DETECTORS)}", repr(self.landmarks))
        if not (isinstance(self.keyframes, int) and self.keyframes >= 1):
            raise InputError(_SOURCE, "keyframes", "an integer >= 1", repr(self.keyframes))
        if self.neutral_s is not None and not (math.isfinite(self.neutral_s) and self.neutral_s >= 0):
            raise InputError(_SOURCE, "neutral", "a time in seconds >= 0", repr(self.neutral_s))
        if self.neutral_s is not None and not ((self.start_s is None or self.neutral_s >= self.start_s)
                                               and (self.end_s is None or self.neutral_s < self.end_s)):
            raise InputError(_SOURCE, "neutral", "a time within the tracked range (--start to --end)", f"{self.neutral_s:g} s")


def track_into_folder(video: str | Path, output: str | Path, options: TrackOptions | None = None,
                      progress: Callable[[int, float], None] | None = None) -> dict[str, Any]:
    """Track the face through a video (:mod:`facegeo.tracking`) and write into ``output``:

    * ``take.csv``: a Live Link Face take (:func:`facegeo.export.live_link.live_link_csv_lines`),
      one row per tracked frame at the video's frame rate: the 52 ARKit weights of the frame's
      expression (``tongueOut`` 0: the model has no such shape) and the head's yaw, pitch and roll;
      a frame without a face repeats the nearest tracked frame's values (``track.json`` flags it);
    * ``track.json``: the source, frame rate, camera, identity α, per frame whether a face was
      found, its landmark RMS (px, % of the inter-ocular distance; of the frame's own fit), pose,
      ICT weights (smoothed with ``options.smooth``, as in the take), whether it was a keyframe
      and, where the brows' flow was tried, how many brow points it carried
      (:class:`facegeo.tracking.BrowFlow`), where the puff was read from the cheeks' shading, the
      share of their shading error it explained (:mod:`facegeo.cheek_shading`); the smoothing,
      the neutral calibration (given by ``options.neutral_s`` or found, ``options.find_rest``;
      None without one), keyframes, timings and notes;
    * with ``options.asset``: the person's textured asset (``asset/``), ``face.glb`` and
      ``face.usdz`` animated by the take, and ``preview.png`` (:func:`_animated_asset`).

    ``progress``: called with (frames observed, frames per second so far). Returns the
    ``track.json`` record without its ``frames`` (written a frame at a time: read them from the
    file).

    Raises:
        facegeo.errors.FacegeoError: an unreadable video, bad options, no face in any frame, an
            unwritable output, or another run writing into ``output``.
    """
    from facegeo.export.animation import head_angles
    from facegeo.arkit import ARKIT_NAMES, ArkitTake, target_naming
    from facegeo.export.live_link import live_link_csv_lines
    from facegeo.staged_output import StagedOutput, locked_output
    from facegeo.cheek_shading import PUFF_GAIN_RAMP
    from facegeo.landmarks.eyelids import SHUT_FRACTION
    from facegeo.landmarks.scheme import N_LANDMARKS
    from facegeo.tracking import (BROW_FLOW_RETURN_PX, BROW_FLOW_WEIGHT, NEUTRAL_FADE_DEG, POSE_WINDOW, SLOW_WEIGHT_WINDOW,
                                  WEIGHT_WINDOW, lid_weights, smooth_track, track_frames)
    from facegeo.video import open_video

    options = TrackOptions() if options is None else options
    with locked_output(output):
        start = time.perf_counter()
        model, _ = loaded_resources(options.model, None, False, options.landmarks)
        info, frames = open_video(video, options.start_s, options.end_s, options.every, options.fps)
        frames, rest = _clip_parts(video, info, frames, options)
        report = None if progress is None else (lambda n: progress(n, n / max(time.perf_counter() - start, 1e-9)))
        track = track_frames(frames, model, options.landmarks, options.focal, options.keyframes, report, str(video), rest,
                             options.neutral_s, lambda seen: _frame_again(video, seen, options.fps).image, options.find_rest,
                             lambda time_s: open_video(video, time_s, options.end_s, 1, options.fps)[1])
        if options.smooth:
            track.frames = smooth_track(track.frames, *model.expression_range, fast=lid_weights(model.expression_names))
        calibration = None
        flowed = [f.brow_flow for f in track.frames if f.brow_flow is not None]
        gains = [f.puff_gain for f in track.frames if f.puff_gain is not None]
        if track.neutral is not None:
            size = np.linalg.norm(track.neutral.offsets, axis=1)
            calibration = {"time_s": track.neutral.time_s, "frames": track.neutral.frames,
                           "chosen": "given" if options.neutral_s is not None else "the clip's most typical still stretch",
                           "distance_from_median_expression": None if track.rest is None else track.rest.distance,
                           "strongest_weight_there": None if track.rest is None else
                           {"name": track.rest.strongest_name, "weight": track.rest.strongest[1]},
                           "rule": "each frame's landmarks and dense points measured from where the detector put the person's at rest in "
                                   "these frames (their offsets from the clip's identity with no expression, turning with the head), in "
                                   f"full within {NEUTRAL_FADE_DEG[0]:g} deg of the head's rotation there, none beyond "
                                   f"{NEUTRAL_FADE_DEG[1]:g} deg",
                           "brow_flow": ({"points": track.brow_flow, "weight": BROW_FLOW_WEIGHT,
                                          "frames": len(flowed),
                                          "carried_median": float(np.median(flowed)) if flowed else None,
                                          "rule": "the brows' region points of the middle frame at rest carried into each frame the "
                                                  "offsets reach by pyramidal Lucas-Kanade optical flow (kept where the flow back returns "
                                                  f"within {BROW_FLOW_RETURN_PX:g} px)"} if track.brow_flow else None),
                           "puff_shading": ({"frames": len(gains), "frames_with_puff": sum(g > PUFF_GAIN_RAMP[0] for g in gains),
                                             "gain_ramp": list(PUFF_GAIN_RAMP),
                                             "rule": "cheekPuff read from the cheeks' shading against the frame at rest (SH light and "
                                                     "albedo fitted there, the exposure from skin a puff does not move), kept by the "
                                                     "share of the shading error it explains, none below the ramp's first value, all "
                                                     "from its second; in place of the landmark solve's"} if gains else None),
                           "offsets_mm": {"landmarks_median": float(np.median(size[:N_LANDMARKS])),
                                          "landmarks_max": float(size[:N_LANDMARKS].max()),
                                          "dense_median": float(np.median(size[N_LANDMARKS:])) if len(size) > N_LANDMARKS else None}}
        found = np.flatnonzero([f.found for f in track.frames])
        # each frame's nearest frame with a face (itself where it has one; the earlier on a tie)
        after = np.minimum(np.searchsorted(found, np.arange(len(track.frames))), len(found) - 1)
        before = np.maximum(after - 1, 0)
        nearest = np.where(np.arange(len(track.frames)) - found[before] <= found[after] - np.arange(len(track.frames)),
                           found[before], found[after])
        naming = target_naming(model.expression_names, "arkit")
        model_weights = np.stack([track.frames[j].delta for j in nearest]).astype(np.float64)
        targets = np.clip(naming.target_weights(model_weights), 0.0, 1.0)
        weights = np.zeros((len(track.frames), len(ARKIT_NAMES)), np.float32)
        for t, name in enumerate(naming.names):
            weights[:, ARKIT_NAMES.index(name)] = targets[:, t]
        angles = head_angles(np.stack([track.frames[j].rotation for j in nearest]))
        times = np.array([f.time_s for f in track.frames], np.float64)
        take = ArkitTake(str(video), float(info.fps), times - times[0], weights, {"head": angles})
        seconds = time.perf_counter() - start
        record = {"source": str(video), "fps": info.fps, "frames_tracked": len(track.frames), "frames_with_face": len(found),
                  "keyframes": track.keyframes, "camera": track.camera.as_dict(), "alpha": track.alpha.tolist(),
                  "expression_names": list(model.expression_names),
                  "timings_s": {**track.timings, "total": seconds},
                  "frames_per_second": len(track.frames) / seconds,
                  "smoothing": ({"pose": f"running median of {POSE_WINDOW} frames",
                                 "eye weights": f"Savitzky-Golay filter of {WEIGHT_WINDOW} frames, order 2",
                                 "other weights": f"running median of {WEIGHT_WINDOW} frames, then a Savitzky-Golay filter of "
                                                  f"{SLOW_WEIGHT_WINDOW} frames, order 2",
                                 "lag_frames_if_live": {"pose": (POSE_WINDOW - 1) // 2, "eye weights": (WEIGHT_WINDOW - 1) // 2,
                                                        "other weights": (WEIGHT_WINDOW - 1) // 2 + (SLOW_WEIGHT_WINDOW - 1) // 2}}
                                if options.smooth else None),
                  "blinks": ({"read_from": "the lids' gap in MediaPipe's iris model, held in each frame's solve "
                                           "(facegeo.landmarks.eyelids)",
                              "open_gap_over_model": {eye: float(v) if np.isfinite(v) else None
                                                      for eye, v in zip(("right", "left"), track.open_lids)},
                              "shut_fraction": SHUT_FRACTION}
                             if track.open_lids is not None else {"read_from": "the fit (no lid reading)"}),
                  "neutral_calibration": calibration,
                  "notes": list(info.notes) + track.notes + [f"{n}: no shape in the model, written as 0" for n in naming.missing],
                  "frames": _FRAMES_HERE}
        with StagedOutput(output, replace=True) as stage:
            with open(stage.path("take.csv"), "w", encoding="utf-8", newline="") as handle:
                handle.writelines(live_link_csv_lines(take, timecode_start_s=float(times[0])))
            if options.asset:
                begin = time.perf_counter()
                record["asset"] = _animated_asset(video, options, model, track, take, stage)
                record["timings_s"]["asset"] = time.perf_counter() - begin
                record["timings_s"]["total"] = time.perf_counter() - start
            _write_track_json(stage.path("track.json"), record, track.frames)
        del record["frames"]
        return record


#: Where :func:`_write_track_json` puts the frames in ``track.json``'s record.
_FRAMES_HERE = "\0frames\0"


def _write_track_json(path: Path, record: dict[str, Any], frames: Sequence[Any]) -> None:
    """``track.json``: ``record`` as ``json.dumps(record, indent=1)`` writes it, with the list of
    ``frames``' :meth:`~facegeo.tracking.TrackedFrame.to_dict` where ``record["frames"]`` is
    :data:`_FRAMES_HERE`, written one frame at a time (a long clip's file without its whole text,
    or a dict a frame, in memory)."""
    head, tail = json.dumps(record, indent=1).split(json.dumps(_FRAMES_HERE), 1)
    with open(path, "w", encoding="utf-8") as handle:
        handle.write(head)
        if not frames:
            handle.write("[]")
        else:
            handle.write("[")
            for k, frame in enumerate(frames):  # each at the list's depth (1) in the record: two spaces more a line
                handle.write(("\n  " if k == 0 else ",\n  ") + json.dumps(frame.to_dict(), indent=1).replace("\n", "\n  "))
            handle.write("\n ]")
        handle.write(tail)


def _clip_parts(video: str | Path, info: Any, frames: Iterator[Any], options: TrackOptions) -> tuple[Iterable[Any], Any]:
    """The clip ``frames`` (of ``open_video(video, ...)`` with ``options``' range) as its first half
    and a callable that opens its second half, observed beside each other
    (:func:`facegeo.tracking.observe_frames`); ``(frames, None)`` where the source's frame count is
    unknown, the halves would be shorter than :data:`facegeo.tracking.MIN_PART_FRAMES`, or no
    second process can be forked. The halves meet at a frame of the ``--every`` grid."""
    import itertools

    from facegeo.forked_call import can_fork
    from facegeo.tracking import MIN_PART_FRAMES
    from facegeo.video import open_video

    first = next(frames)
    frames = itertools.chain([first], frames)
    if info.frame_count is None or not can_fork():
        return frames, None
    last = info.frame_count - 1
    if options.end_s is not None and math.isfinite(options.end_s * info.fps):
        last = min(last, math.ceil(options.end_s * info.fps) - 1)
    kept = len(range(first.index, last + 1, options.every))
    if kept < 2 * MIN_PART_FRAMES:
        return frames, None
    middle = first.index + options.every * (kept // 2)  # the second half's first frame

    def rest() -> Iterator[Any]:
        try:
            second = open_video(video, (middle - 0.5) / info.fps, options.end_s, options.every, options.fps)[1]
        except InputError:  # the container's frame count overstated the clip: no second half
            return
        yield from second

    return itertools.takewhile(lambda frame: frame.index < middle, frames), rest


#: Frames of the clip shown in ``facegeo track``'s ``preview.png`` (spread evenly over the frames with a face).
PREVIEW_FRAMES = 6


def _frame_again(video: str | Path, frame: Any, fps: float | None = None) -> Any:
    """The video's frame (:class:`facegeo.video.Frame`) of ``frame`` (its ``index`` and
    ``time_s``: a tracked or observed frame; ``fps`` as the track opened the video with), decoded again."""
    from facegeo.video import open_video

    _, frames = open_video(video, frame.time_s, None, 1, fps)
    return next(f for f in frames if f.index == frame.index)


def _animated_asset(video: str | Path, options: TrackOptions, model: Any, track: Any, take: Any, stage: Any) -> dict[str, Any]:
    """The person's textured asset, animated by the take (:func:`track_into_folder`): the
    texture frames (the keyframes, each replaced by the frame nearest to it in yaw that shows the
    face whole where its own face is cut by the frame's border) fitted again with the clip's
    identity and camera (their albedo and light, the single-photo checks), their textures fused
    (:func:`facegeo.pipeline.reconstruct_views`: the most frontal without a hand over the face
    the reference, the others' de-lit skin where they see it best; one frame: its own texture),
    its asset folder in ``asset/``, ``face.glb`` and ``face.usdz`` with the take's keys (one a
    frame) and ``preview.png`` (the reference frame beside the asset from the front, three-quarter and
    profile; below it :data:`PREVIEW_FRAMES` frames spread over the clip, each with the asset
    posed as tracked there drawn over it, textured and as clay). Returns what ``track.json``
    records of it."""
    from facegeo.camera import euler_from_rotation, project
    from facegeo.concurrency import EXPORT_WORKERS, run_concurrently
    from facegeo.errors import FacegeoError, NoFaceError
    from facegeo.export.asset_io import write_asset_files
    from facegeo.export.textures import TextureFiles
    from facegeo.export.writers import export_asset
    from facegeo.fitting.photo_fit import finish_photo_fit, observe_photo
    from facegeo.image_files import png_bytes
    from facegeo.photo import Photo
    from facegeo.pipeline import reconstruct_views
    from facegeo.skin_mask import skin_mask
    from facegeo.texturing.preview import clip_preview, relit_preview
    from facegeo.tracking import SolveStart, face_region_only, solve_frame

    keys = [f for f in track.frames if f.keyframe]

    def landmarks_of(tracked: Any) -> np.ndarray:  # (88, 2) px: the tracked face's landmarks as fitted
        shape = model.shape_numpy(track.alpha, tracked.delta, vertex_indices=model.landmark_indices)
        return project(shape.astype(np.float64), np.asarray(tracked.rotation, np.float64), np.asarray(tracked.translation, np.float64),
                       track.camera)

    def inside(f: Any) -> bool:  # the face's 68 points within the frame (a face cut by the border loses texture)
        uv = landmarks_of(f)[:68]
        return bool(np.all((uv >= 0) & (uv <= [track.camera.width, track.camera.height])))

    def texture_frames() -> list[Any]:
        """Each keyframe where its face lies wholly inside the frame, else the frame nearest to it
        in yaw that shows the face whole (the sides the keyframes span, seen whole; each frame
        once); the keyframes themselves where no frame shows the face whole."""
        whole = [f for f in track.frames if f.found and inside(f)]
        if not whole:
            return keys
        yaw = {f.index: euler_from_rotation(f.rotation)[0] for f in whole + keys}
        whole_indices = {f.index for f in whole}
        chosen: dict[int, Any] = {}
        for key in keys:
            if key.index in whole_indices:
                chosen.setdefault(key.index, key)
                continue
            spare = [f for f in whole if f.index not in chosen]
            if spare:
                near = min(spare, key=lambda f: abs(yaw[f.index] - yaw[key.index]))
                chosen[near.index] = near
        return sorted(chosen.values(), key=lambda f: f.index)

    alpha = track.alpha.astype(np.float64)
    photos, fits, skins, indices, notes = [], [], [], [], []
    for key in texture_frames():
        frame = _frame_again(video, key, options.fps)
        # the tracked face's region only: a detector finds the tracked person, not the largest face in the frame
        photo = Photo(face_region_only(frame.image, landmarks_of(key)), f"{video} (frame {frame.index})", 1.0,
                      (frame.image.shape[1], frame.image.shape[0]))
        try:
            seen = observe_photo(photo, model, None, options.landmarks, track.camera)
            solution = solve_frame(model, seen, track.camera, alpha, track.noise, SolveStart(key.rotation, key.translation, alpha, key.delta))
            fits.append(finish_photo_fit(seen, solution, photometric=True))
        except FacegeoError as error:  # the frame's face refused on its own (its checks): the others texture the face
            notes.append(f"frame {key.index} left out of the texture: {error}")
            continue
        photos.append(photo)
        # the skin mask from the whole frame: a hand over the face reaches beyond the face's region
        skins.append(skin_mask(frame.image, fits[-1].landmarks))
        indices.append(int(key.index))
    if not fits:
        raise NoFaceError(str(video), "keyframes", "a texture frame whose fit passes its checks", "none")
    asset, reference, fusion = reconstruct_views(photos, fits, model, skins=skins, fork=True)
    result = fits[reference]
    folder = stage.path("asset")
    folder.mkdir()
    texture_files = TextureFiles()  # each map's PNG made once, shared by the folder and the scenes

    def preview() -> None:
        turntable = relit_preview(photos[reference].image, asset, result)
        found = [f for f in track.frames if f.found]
        shown = [found[k] for k in np.unique(np.linspace(0, len(found) - 1, PREVIEW_FRAMES).round().astype(int))]
        names = list(model.expression_names)
        clip = clip_preview([(_frame_again(video, f, options.fps).image, f.rotation, f.translation, dict(zip(names, np.asarray(f.delta, float))),
                              landmarks_of(f)[:68]) for f in shown], asset, track.camera, panel=turntable.shape[1] // PREVIEW_FRAMES)
        strip = np.zeros((clip.shape[0], turntable.shape[1], 3), np.uint8)
        strip[:, : clip.shape[1]] = clip
        stage.path("preview.png").write_bytes(png_bytes(np.concatenate([turntable, strip], axis=0)))

    # the preview first: the longest; the folder and the two scenes share the map files as they come
    run_concurrently([preview, lambda: write_asset_files(asset, folder, texture_files=texture_files)]
                     + [functools.partial(export_asset, asset, stage.path(f"face.{fmt}"), format=fmt, blendshapes="arkit", animation=take,
                                          texture_files=texture_files) for fmt in ("glb", "usdz")], EXPORT_WORKERS)
    return {"reference_frame": indices[reference], "texture_frames": indices,
            "fusion": fusion, "landmark_rms_px": float(result.landmark_rms_px),
            "notes": notes + list(dict.fromkeys(n for f in fits for n in f.info.get("notes", []))) + fusion["notes"],
            "files": ["asset/", "face.glb", "face.usdz", "preview.png"]}
