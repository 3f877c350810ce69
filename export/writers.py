"""One entry point for all formats: :func:`export_asset` picks the writer from the format or suffix;
:func:`export_scenes` writes several formats of one asset, computing the shared scene once
(:func:`scene_writers`: the same as one task per format, for several threads)."""

from __future__ import annotations

import importlib
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Sequence

from facegeo.asset import Asset
from facegeo.errors import InputError

if TYPE_CHECKING:
    from facegeo.arkit import ArkitTake
    from facegeo.export.scene import SceneContents, SceneGeometry
    from facegeo.export.textures import TextureFiles

__all__ = ["export_asset", "export_scenes", "scene_writers", "FORMATS", "DEFAULT_FORMATS"]

#: Formats :func:`export_asset` writes (the file suffixes).
FORMATS = ("usdz", "usdc", "usda", "glb")
#: What ``facegeo reconstruct`` writes unless told otherwise (issue 8).
DEFAULT_FORMATS = ("usdz", "glb")


def export_asset(
    asset: Asset,
    path: str | os.PathLike[str],
    *,
    format: str | None = None,
    level: int = 0,
    displacement: str = "bake",
    maps: Iterable[str] | None = None,
    uv_interpolation: str = "surface",
    blendshapes: str | None = "arkit",
    animation: ArkitTake | None = None,
    surfaces: list[tuple[str, SceneContents]] | None = None,
    texture_files: TextureFiles | None = None,
) -> Path:
    """Write ``asset`` to ``path`` as USD (usdz, usdc, usda) or glTF binary (glb).

    ``format``: one of FORMATS; default: the suffix of ``path``. A path without a suffix gets
    ``.<format>`` appended. ``level``: Loop subdivision levels (0-3 are practical); ``displacement``:
    "bake" (into the geometry) or "texture" (USD's displacement input; not possible in glTF);
    ``maps``: the map names to carry (default: all the asset has); ``blendshapes``: the names of
    the asset's blendshapes in the file, "arkit" (default) or "ict" (glTF morph targets, UsdSkel
    blend shapes; an asset without blendshapes is written static), or None to leave them out;
    ``animation``: a Live Link Face take (:func:`facegeo.export.live_link.read_live_link_csv`)
    to animate the face with; ``surfaces``: the asset's
    :func:`facegeo.export.scene.scene_surfaces` with these options, if already computed
    (:func:`export_scenes` shares them between formats); ``texture_files``: the maps' PNG files
    shared with other outputs (:class:`facegeo.export.textures.TextureFiles`; default: made by
    the writer). Returns the path written.

    Raises:
        InputError: unknown format, a suffix that contradicts ``format``, glb with
            ``displacement="texture"``, or any writer's input error.
    """
    target, format = _resolve(Path(path), format, displacement)
    if format == "glb":
        from facegeo.export.gltf import write_glb

        return write_glb(asset, target, level=level, maps=maps, uv_interpolation=uv_interpolation, blendshapes=blendshapes,
                         animation=animation, surfaces=surfaces, texture_files=texture_files)
    from facegeo.export.usd import write_usd

    return write_usd(asset, target, level=level, displacement=displacement, maps=maps, uv_interpolation=uv_interpolation,
                     blendshapes=blendshapes, animation=animation, surfaces=surfaces, texture_files=texture_files)


def export_scenes(
    asset: Asset,
    outputs: Sequence[tuple[str | os.PathLike[str], str | None]],
    *,
    level: int = 0,
    displacement: str = "bake",
    maps: Iterable[str] | None = None,
    uv_interpolation: str = "surface",
    blendshapes: str | None = "arkit",
    animation: ArkitTake | None = None,
    texture_files: TextureFiles | None = None,
) -> list[Path]:
    """:func:`export_asset` for several ``(path, format)`` outputs of one asset (format None: the
    suffix's), with the same options: the scene's geometry, materials and blendshape targets
    (:func:`facegeo.export.scene.scene_surfaces`) are computed once for every output that bakes
    the displacement (glb always, USD with ``displacement="bake"``), and each texture's PNG file
    once for all of them (``texture_files``, default: made here; give one to share the files
    with an asset folder). Every output is checked before anything is written. Returns the paths
    written, in order. (:func:`scene_writers` gives the same work as one task per output.)"""
    return [write() for write in scene_writers(asset, outputs, level=level, displacement=displacement, maps=maps,
                                               uv_interpolation=uv_interpolation, blendshapes=blendshapes,
                                               animation=animation, texture_files=texture_files)]


def scene_writers(
    asset: Asset,
    outputs: Sequence[tuple[str | os.PathLike[str], str | None]],
    *,
    level: int = 0,
    displacement: str = "bake",
    maps: Iterable[str] | None = None,
    uv_interpolation: str = "surface",
    blendshapes: str | None = "arkit",
    animation: ArkitTake | None = None,
    texture_files: TextureFiles | None = None,
    geometries: list[SceneGeometry] | None = None,
) -> list[Callable[[], Path]]:
    """The work of :func:`export_scenes` (same arguments) as one task per output, each writing
    its file and returning its path, to run on several threads
    (:func:`facegeo.concurrency.run_concurrently`): every output is checked here, before any task
    runs; the first task that needs the shared surfaces computes them while any other that needs
    them waits, and the texture files are shared through ``texture_files`` (thread-safe).
    ``geometries``: the asset's :func:`facegeo.export.scene.scene_geometries` with these options,
    if already made (the surfaces then only add the materials)."""
    from facegeo.export.scene import scene_surfaces
    from facegeo.export.textures import TextureFiles

    resolved = [_resolve(Path(path), format, displacement) for path, format in outputs]
    # The writers' modules and libraries are imported here, in the caller's thread: pxr's
    # extension modules run initialisers that let go of the GIL and take it back inside dlopen,
    # so importing them on one thread while another imports any extension module (pygltflib's
    # uuid) deadlocks the process (GIL against the loader's lock); it happened in reconstruct.
    for module in sorted({"facegeo.export.gltf" if fmt == "glb" else "facegeo.export.usd" for _, fmt in resolved}):
        for library in importlib.import_module(module).WRITER_LIBRARIES:
            importlib.import_module(library)
    maps = None if maps is None else list(maps)
    files = TextureFiles() if texture_files is None else texture_files
    lock = threading.Lock()
    computed: list[list[tuple[str, SceneContents]]] = []

    def surfaces() -> list[tuple[str, SceneContents]]:
        with lock:
            if not computed:
                computed.append(scene_surfaces(asset, level=level, maps=maps, uv_interpolation=uv_interpolation, blendshapes=blendshapes,
                                                   geometries=geometries))
            return computed[0]

    def writer(target: Path, fmt: str) -> Callable[[], Path]:
        bakes = fmt == "glb" or displacement == "bake"
        return lambda: export_asset(asset, target, format=fmt, level=level, displacement=displacement, maps=maps,
                                    uv_interpolation=uv_interpolation, blendshapes=blendshapes, animation=animation,
                                    surfaces=surfaces() if bakes else None, texture_files=files)

    return [writer(target, fmt) for target, fmt in resolved]


def _resolve(target: Path, format: str | None, displacement: str) -> tuple[Path, str]:
    """The path and format of one output (the checks of :func:`export_asset`)."""
    suffix = target.suffix.lower().lstrip(".")
    if format is None:
        if suffix not in FORMATS:
            raise InputError(target, "file name", f"a suffix among {', '.join('.' + f for f in FORMATS)} (or an explicit format)", target.suffix or "none")
        format = suffix
    format = format.lower().lstrip(".")
    if format not in FORMATS:
        raise InputError(target, "format", f"one of {', '.join(FORMATS)}", repr(format))
    if not suffix:
        target = target.with_name(target.name + "." + format)
    elif suffix != format:
        raise InputError(target, "file name", f"the .{format} suffix for format {format}", target.suffix)
    if format == "glb" and displacement != "bake":
        raise InputError(target, "displacement", "'bake' for glTF (glTF has no displacement input)", repr(displacement))
    return target, format
