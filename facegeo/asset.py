"""The Asset: a face mesh with face-varying UVs and its PBR maps in UV space.

This is what the texture stage produces and what the exporters write. Conventions (DESIGN.md, "Conventions"):
millimetres, +Y up, +Z out of the face; UV [0, 1]² with the origin bottom-left; map arrays are
stored image-style, row 0 = top (texel row i covers v = 1 − (i + 0.5)/H).

Maps (all float32, H × W texels, any subset may be present):

=============== =============== =========================================================
name            shape           content
=============== =============== =========================================================
``albedo``      (H, W, 3)       base colour, **sRGB**-encoded values in [0, 1]
``normal``      (H, W, 3)       tangent-space normal, decoded unit vectors in [−1, 1]³,
                                OpenGL convention (+Y green up), MikkTSpace frame
``roughness``   (H, W)          perceptual roughness in [0, 1] (α = roughness²), linear
``specular``    (H, W)          specular level in [0, 1], F0 = 0.08·specular, linear
``displacement`` (H, W)         signed displacement along the normal, **millimetres**
=============== =============== =========================================================

A map that is constant over the UV square is better given as a factor in ``constants`` (the
exporters then write a material factor, not a texture).

Parts: an asset may carry ``parts``, further assets (eyeballs, teeth, ...; see
:mod:`facegeo.parts`) in the same space, each with its own UVs and material; the exporters write
each as its own mesh and material. ``face_triangles`` marks the skin's face region, so that a scene
can be cut down to it (:meth:`Asset.select`, ``--parts face|head|full``).

Blendshapes: an asset (and each part the expressions move) may carry ``blendshapes``
(:class:`facegeo.blendshapes.Blendshapes`): its vertices are then the neutral mesh plus the
shapes at the fitted weights, so the exporters can write morph targets / blend shapes and the
asset can be animated (:meth:`Asset.neutral_vertices`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from facegeo.blendshapes import Blendshapes
from facegeo.errors import InputError

__all__ = ["Asset", "MAP_NAMES", "MAP_CHANNELS", "PART_CHOICES", "SPECULAR_F0_SCALE"]

#: The map names, in the order the exporters and the CLI list them.
MAP_NAMES = ("albedo", "normal", "roughness", "specular", "displacement")
#: Channels of each map (1 means a 2-D (H, W) array).
MAP_CHANNELS = {"albedo": 3, "normal": 3, "roughness": 1, "specular": 1, "displacement": 1}
#: F0 = SPECULAR_F0_SCALE × specular: the Disney/Blender "specular" level of the maps (non-metallic
#: skin; the shader, the USD and the glTF writers all read it from here).
SPECULAR_F0_SCALE = 0.08
#: What a scene holds (:meth:`Asset.select`): the face region of the skin, all the skin, or the
#: skin and every part (eyes, mouth interior).
PART_CHOICES = ("face", "head", "full")


@dataclass(eq=False)
class Asset:
    """A textured face.

    vertices: (V, 3) float32 mm, model space (upright, unposed). triangles: (F, 3) int64,
    counter-clockwise seen from outside. uv: (T, 2) float32; uv_triangles: (F, 3) int64.
    maps: name -> array as in the module table. constants: name -> a float (1-channel maps)
    or an RGB triple, for maps that are uniform. name: a short name used for files and prims.
    metadata: JSON-ready provenance (fit parameters, timings, map encodings).
    parts: further assets (eyeballs, teeth, ...) in the same space, each with its own UVs and
    material; they have no parts themselves and their names are distinct.
    face_triangles: (F,) bool, the triangles of the face region, or None (all of them).
    blendshapes: the expression shapes of these vertices and the fitted weights, or None (a
    static surface); the skin and the parts that have them share names and weights.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    uv_triangles: np.ndarray
    maps: dict[str, np.ndarray] = field(default_factory=dict)
    constants: dict[str, Any] = field(default_factory=dict)
    name: str = "face"
    metadata: dict[str, Any] = field(default_factory=dict)
    parts: list["Asset"] = field(default_factory=list)
    face_triangles: np.ndarray | None = None
    blendshapes: Blendshapes | None = None

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32)
        self.triangles = np.ascontiguousarray(self.triangles, dtype=np.int64)
        self.uv = np.ascontiguousarray(self.uv, dtype=np.float32)
        self.uv_triangles = np.ascontiguousarray(self.uv_triangles, dtype=np.int64)
        self.maps = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in self.maps.items()}
        if self.face_triangles is not None:
            self.face_triangles = np.asarray(self.face_triangles, dtype=bool)
        self.parts = list(self.parts)
        self.validate()

    def validate(self, source: str = "<asset>") -> None:
        """Raise :class:`InputError` naming the field for wrong shapes, indices or values (NaN
        or ±inf anywhere included). Run on construction and again by every writer, since the
        arrays can be changed in place afterwards."""
        v, f = self.vertices, self.triangles
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise InputError(source, "vertices", "shape (V, 3) with V > 0", str(v.shape))
        if not np.all(np.isfinite(v)):
            raise InputError(source, "vertices", "finite values", f"{int((~np.isfinite(v)).sum())} NaN/inf")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or f.min() < 0 or f.max() >= len(v):
            raise InputError(source, "triangles", f"shape (F, 3) with indices in [0, {len(v)})", f"{f.shape}")
        if self.uv.ndim != 2 or self.uv.shape[1] != 2 or not np.all(np.isfinite(self.uv)):
            raise InputError(source, "uv", "finite (T, 2) coordinates", str(self.uv.shape))
        ut = self.uv_triangles
        if ut.shape != f.shape or ut.min() < 0 or ut.max() >= len(self.uv):
            raise InputError(source, "uv_triangles", f"shape {f.shape} with indices in [0, {len(self.uv)})", str(ut.shape))
        for name, array in self.maps.items():
            if name not in MAP_CHANNELS:
                raise InputError(source, f"maps[{name!r}]", f"one of {', '.join(MAP_NAMES)}", name)
            channels = MAP_CHANNELS[name]
            ok = array.ndim == 2 if channels == 1 else (array.ndim == 3 and array.shape[2] == channels)
            if not ok or min(array.shape[:2]) < 1:
                expected = "(H, W)" if channels == 1 else f"(H, W, {channels})"
                raise InputError(source, f"maps[{name!r}]", expected, str(array.shape))
            if not np.all(np.isfinite(array)):
                raise InputError(source, f"maps[{name!r}]", "finite values", "NaN/inf texels")
        for name in self.constants:
            if name not in MAP_CHANNELS:
                raise InputError(source, f"constants[{name!r}]", f"one of {', '.join(MAP_NAMES)}", name)
            if name in self.maps:
                raise InputError(source, f"constants[{name!r}]", "a map or a constant, not both", "both")
            value = self.constants[name]
            try:
                finite = bool(np.all(np.isfinite(np.asarray(value, dtype=np.float64))))
            except (TypeError, ValueError):
                finite = False
            if not finite:
                raise InputError(source, f"constants[{name!r}]", "a finite number or RGB triple", repr(value))
        ft = self.face_triangles
        if ft is not None and (ft.shape != (len(f),) or not ft.any()):
            raise InputError(source, "face_triangles", f"({len(f)},) bool with at least one True", str(ft.shape))
        names = [self.name]
        for part in self.parts:
            if not isinstance(part, Asset) or part.parts:
                raise InputError(source, "parts", "assets without parts of their own", type(part).__name__)
            if part.name in names:
                raise InputError(source, "parts", "distinct names", repr(part.name))
            names.append(part.name)
        if self.blendshapes is not None and not isinstance(self.blendshapes, Blendshapes):
            raise InputError(source, "blendshapes", "a facegeo.blendshapes.Blendshapes", type(self.blendshapes).__name__)
        shaped = [(s, s.blendshapes) for s in (self, *self.parts) if s.blendshapes is not None]
        for surface, shapes in shaped:
            shapes.validate(source if surface is self else f"{source}: parts[{surface.name!r}]", len(surface.vertices))
            first = shaped[0][1]
            if shapes.names != first.names or not np.array_equal(shapes.weights, first.weights):
                raise InputError(source, f"parts[{surface.name!r}].blendshapes", "the same blendshape names and weights as the other surfaces",
                                 "others")

    def neutral_vertices(self) -> np.ndarray:
        """(V, 3) float32 mm: the vertices at blendshape weights 0 (the identity without the
        expression); the vertices themselves for an asset without blendshapes."""
        if self.blendshapes is None:
            return self.vertices
        return (self.vertices.astype(np.float64) - self.blendshapes.offset()).astype(np.float32)

    def select(self, parts: str = "full") -> "Asset":
        """The scene ``parts`` asks for (one of :data:`PART_CHOICES`): ``"full"`` this asset,
        ``"head"`` the skin without parts, ``"face"`` the skin's face-region triangles (vertices
        compacted, UVs and maps unchanged) without parts. Raises :class:`InputError` otherwise."""
        if parts not in PART_CHOICES:
            raise InputError("<argument>", "parts", f"one of {', '.join(PART_CHOICES)}", repr(parts))
        if parts == "full":
            return self
        keep = np.ones(len(self.triangles), bool) if parts == "head" or self.face_triangles is None else self.face_triangles
        used, triangles = np.unique(self.triangles[keep], return_inverse=True)
        return Asset(self.vertices[used], triangles.reshape(-1, 3), self.uv, self.uv_triangles[keep],
                     maps=self.maps, constants=dict(self.constants), name=self.name, metadata=self.metadata,
                     face_triangles=None if parts == "face" or self.face_triangles is None else self.face_triangles,
                     blendshapes=None if self.blendshapes is None else self.blendshapes.subset(used))
