"""A reconstruction's files, begun on the fit's geometry and finished when the maps exist.

``facegeo reconstruct`` writes one scene per format (usdz, glb, ...) and the asset folder. Much
of that needs the fit alone: the writers' libraries (pxr and pygltflib take ~0.6 s to import),
the scenes' geometry (the neutral mesh, its normals and the 51 morph targets,
:func:`facegeo.export.scene.scene_geometries`) and the asset folder's meshes, parts and
blendshapes (:func:`facegeo.export.asset_io.write_asset_geometry`). The maps come last, after
the texture stages, which keep one core busy for seconds. So :class:`ExportJob` starts on the
geometry (:func:`facegeo.pipeline.reconstruct_with_fit`'s ``geometry_ready``) in a forked child
(:func:`facegeo.forked_call.fork_call` with an inbox: the second core, without the GIL or pxr's
import lock shared with the texture stages), which then waits for the maps, constants and
metadata (:meth:`ExportJob.complete` sends them) and writes the rest: each map's PNG once for
all outputs (:class:`facegeo.export.textures.TextureFiles`), the scenes, ``asset.json`` and, where
the plan asks for it, ``preview.png`` (its views rasterised in the first half:
:class:`facegeo.texturing.preview.PreviewViews`), on :data:`facegeo.concurrency.EXPORT_WORKERS`
threads, while the caller makes what it runs beside (the skin mask). Where a
fork does not help or work (:func:`facegeo.forked_call.can_fork`, a batch worker) the same work
runs in the caller, beside the skin mask, as one set of tasks on as many threads as the process may
keep busy (:func:`facegeo.concurrency.usable_threads`: one in a batch worker, whose neighbours
use the other cores). The files are the same either way.

The child writes only into the caller's staging folder (:class:`facegeo.staged_output.StagedOutput`),
which the caller commits or removes; a caller that fails first stops the child
(:meth:`ExportJob.abandon`); a child that ends without an answer is redone in the caller.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from facegeo.asset import Asset

__all__ = ["ExportPlan", "PreviewPlan", "ExportJob", "PREVIEW_FILE"]

#: The preview's file name in the plan's folder.
PREVIEW_FILE = "preview.png"

#: (name, (start, end)) of each piece of work, in :func:`time.perf_counter` seconds (one clock
#: for the caller and the forked child: CLOCK_MONOTONIC).
Spans = dict[str, tuple[float, float]]


@dataclass(frozen=True)
class ExportPlan:
    """What to write and where.

    Attributes:
        folder: the (staging) folder the files go into; it exists.
        formats: scene formats (``facegeo.export.writers.FORMATS``), written as ``face.<format>``.
        parts: what the scenes hold (``facegeo.asset.PART_CHOICES``); the asset folder holds all.
        level: Loop subdivision levels of the scenes' skin.
        bake_displacement: the scenes carry the displacement map (baked into the subdivided
            skin: then the skin's scene geometry waits for the maps).
        blendshapes: the scenes' blendshape naming (``arkit``, ``ict``) or None for static scenes.
        maps: the maps the texture stages will make: what the first half expects the skin to
            carry (a scene whose skin carries others makes what it needs then); None: not known
            (the glb's arrays then wait for the maps).
        preview: also write ``preview.png`` of this photo (:class:`PreviewPlan`), its views
            rasterised in the first half; None: no preview.
    """

    folder: Path
    formats: tuple[str, ...]
    parts: str
    level: int
    bake_displacement: bool
    blendshapes: str | None
    maps: frozenset[str] | None = None
    preview: PreviewPlan | None = None


@dataclass(frozen=True)
class PreviewPlan:
    """What ``preview.png`` shows beside the asset (:class:`facegeo.texturing.preview.PreviewViews`):
    ``photo`` (H, W, 3) uint8 RGB and the fit's ``landmarks`` (68, 2) px that frame it."""

    photo: np.ndarray
    landmarks: np.ndarray


class _Prepared:
    """What the first half made: the asset folder's geometry records and the scenes' geometry."""

    def __init__(self, geometry: Asset, plan: ExportPlan):
        from facegeo.export.asset_io import write_asset_geometry
        from facegeo.export.scene import scene_geometries
        from facegeo.export.textures import TextureFiles

        _import_writers(plan.formats)
        self.spans: Spans = {}
        begin = time.perf_counter()
        self.texture_files = TextureFiles()  # each map's PNG made once for the asset folder and the scenes
        self.record = write_asset_geometry(geometry, plan.folder, texture_files=self.texture_files)
        selected = geometry.select(plan.parts)
        self.geometries = None if plan.bake_displacement else scene_geometries(selected, level=plan.level, blendshapes=plan.blendshapes)
        if self.geometries is not None and plan.maps is not None and "glb" in plan.formats:  # its wedges, tangents, morph targets
            from facegeo.export.gltf import prepare_surface_arrays

            prepare_surface_arrays(self.geometries, selected.parts, plan.maps)
        self.spans["geometry"] = (begin, time.perf_counter())
        self.preview = None
        if plan.preview is not None:
            from facegeo.texturing.preview import PreviewViews

            begin = time.perf_counter()
            self.preview = PreviewViews(geometry, plan.preview.photo, plan.preview.landmarks, skin_maps=plan.maps)
            self.spans["preview views"] = (begin, time.perf_counter())


def _import_writers(formats: tuple[str, ...]) -> None:
    """Import the writers of ``formats`` and their libraries in this thread (pxr's extension
    modules must not be imported while another thread imports one: see
    :func:`facegeo.export.writers.scene_writers`)."""
    for module in sorted({"facegeo.export.gltf" if fmt == "glb" else "facegeo.export.usd" for fmt in formats}):
        for library in importlib.import_module(module).WRITER_LIBRARIES:
            importlib.import_module(library)


def _finish_tasks(asset: Asset, plan: ExportPlan, prepared: _Prepared, spans: Spans) -> list[Callable[[], None]]:
    """The second half's tasks, in the order measured best (RESULTS.md, "Issue 29: export"): the
    first scene beside the asset folder, then the other scenes; each records its span."""
    from facegeo.export.asset_io import write_asset_files
    from facegeo.export.writers import scene_writers

    carried = [m for m in asset.maps if m != "displacement" or plan.bake_displacement]
    scenes = scene_writers(asset.select(plan.parts), [(plan.folder / f"face.{fmt}", fmt) for fmt in plan.formats],
                           level=plan.level, maps=carried, blendshapes=plan.blendshapes,
                           texture_files=prepared.texture_files, geometries=prepared.geometries)
    tasks = [_timed(f"scene {k}", write, spans) for k, write in enumerate(scenes)]
    tasks.insert(1, _timed("asset", lambda: write_asset_files(asset, plan.folder, texture_files=prepared.texture_files,
                                                              geometry_record=prepared.record), spans))
    if prepared.preview is not None:  # last: its shading is the shortest task (RESULTS.md, "the preview in the export's child")
        from facegeo.image_files import png_bytes

        views = prepared.preview
        tasks.append(_timed("preview", lambda: (plan.folder / PREVIEW_FILE).write_bytes(png_bytes(views.render(asset))), spans))
    return tasks


def _timed(name: str, work: Callable[[], Any], spans: Spans) -> Callable[[], None]:
    def task() -> None:
        begin = time.perf_counter()
        work()
        spans[name] = (begin, time.perf_counter())
    return task


def _completed(geometry: Asset, maps: dict[str, Any], constants: dict[str, Any], metadata: dict[str, Any]) -> Asset:
    """The asset :func:`facegeo.pipeline.reconstruct_with_fit` returned, from its geometry."""
    return replace(geometry, maps=maps, constants=constants, metadata=metadata)


def _write_in_child(geometry: Asset, plan: ExportPlan, receive: Callable[[], Any]) -> Spans:
    """The forked child's whole export: the first half, then the second on what the caller sends."""
    from facegeo.concurrency import EXPORT_WORKERS, run_concurrently

    prepared = _Prepared(geometry, plan)
    maps, constants, metadata = receive()
    spans = dict(prepared.spans)
    run_concurrently(_finish_tasks(_completed(geometry, maps, constants, metadata), plan, prepared, spans), EXPORT_WORKERS)
    return spans


class ExportJob:
    """A reconstruction's export (module docstring): made on the geometry, completed with the
    maps by :meth:`complete`; :meth:`abandon` when the caller fails first.

    Args:
        geometry: the asset without maps (``reconstruct_with_fit``'s ``geometry_ready``).
        plan: what to write where.
        fork: begin in a forked child now (check :func:`facegeo.forked_call.can_fork`); False:
            all the work happens in :meth:`complete`.
    """

    def __init__(self, geometry: Asset, plan: ExportPlan, *, fork: bool):
        from facegeo.forked_call import fork_call

        self.geometry, self.plan = geometry, plan
        self._pending = fork_call(_write_in_child, geometry, plan, inbox=True) if fork else None
        #: What happened that the user should know (a child lost and the work redone here).
        self.notes: list[str] = []

    def complete(self, asset: Asset, beside: list[tuple[str, Callable[[], Any]]]) -> Spans:
        """Write the rest for ``asset`` (the geometry's asset with its maps, constants and
        metadata), running the ``beside`` tasks (name, work) in this process meanwhile (the
        preview); returns the spans of every piece of work, the ``beside`` ones included.
        Raises what the export raised (a :class:`facegeo.errors.FacegeoError` as itself)."""
        from facegeo.concurrency import EXPORT_WORKERS, run_concurrently, usable_threads
        from facegeo.forked_call import ChildLost

        spans: Spans = {}
        own = [_timed(name, work, spans) for name, work in beside]
        pending = self._pending
        if pending is not None:
            pending.send((asset.maps, asset.constants, asset.metadata))
            try:
                run_concurrently(own, 1)
            except BaseException:
                self.abandon()
                raise
            self._pending = None
            try:
                spans.update(pending.result())
                return spans
            except ChildLost as lost:  # killed (e.g. out of memory): the same files, here
                self.notes.append(f"the forked export ended {lost.how} without an answer; written again in the main process")
            own = []  # done above
        prepared = _Prepared(self.geometry, self.plan)
        spans.update(prepared.spans)
        run_concurrently(_finish_tasks(asset, self.plan, prepared, spans) + own, min(EXPORT_WORKERS, usable_threads()))
        return spans

    def abandon(self) -> None:
        """Stop a forked child (the caller failed or was interrupted first)."""
        if self._pending is not None:
            self._pending.abandon()
            self._pending = None
