"""The morph targets of a written surface: its blendshapes as displacements of the exported mesh.

:func:`surface_targets` turns a surface's :class:`facegeo.blendshapes.Blendshapes` into the named
targets a file carries (:func:`facegeo.arkit.target_naming`: ARKit's names or the model's),
on the vertices that are written:

* **positions**: each target's displacement (mm). With ``--subdiv`` > 0 the coarse displacements
  go through the same Loop subdivision operators as the mesh
  (:func:`facegeo.export.subdivision.subdivide_with_operators`); Loop subdivision is linear, so the
  subdivided neutral plus the subdivided displacement is exactly the subdivided posed mesh. The
  baked displacement map is identity detail: it is baked once into the neutral base mesh (along
  the neutral's normals) and the targets do not change it (a target moves the displaced surface
  by the smooth surface's displacement).
* **normals**: each target's change of the smooth vertex normal (the written mesh's rule,
  :func:`facegeo.normals.vertex_normals`) between the neutral and the target at weight 1, computed
  on the coarse mesh and carried through the same subdivision: a renderer that blends normals
  (three.js, Babylon, engines) shades the moved surface with turned normals. Mixed weights blend
  these changes linearly, the usual morph-target approximation.

Each target keeps only the vertices it moves (its position changes, or its normal turns by more
than :data:`NORMAL_TARGET_MIN`), as sparse arrays; the writers store them sparsely (glTF sparse
accessors, UsdSkel ``pointIndices``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from facegeo.blendshapes import Blendshapes
from facegeo.arkit import TargetNaming
from facegeo.export.subdivision import apply_operators
from facegeo.normals import vertex_normals

__all__ = ["MorphTarget", "SurfaceTargets", "surface_targets", "NORMAL_TARGET_MIN"]

#: A vertex whose position does not move is kept in a target only if its normal turns by more
#: than this (a unit-vector difference, 2°): the ring around a moved region, where shading
#: changes visibly. (A moved vertex keeps its exact normal change, however small.)
NORMAL_TARGET_MIN = 2.0 * np.pi / 180.0
#: Values (float64) subdivided at once: targets go through the subdivision in chunks of at most
#: this many values, which bounds the memory at level 3 (720k vertices × 6 values per target).
_CHUNK_VALUES = 2**24


@dataclass
class MorphTarget:
    """One target on the written mesh's vertices (sparse).

    Attributes:
        name: the target's name.
        indices: (n,) int64, ascending: the vertices the target moves (position or normal).
        positions: (n, 3) float32 mm, their displacement at weight 1.
        normals: (n, 3) float32, the change of their unit normal at weight 1.
    """

    name: str
    indices: np.ndarray
    positions: np.ndarray
    normals: np.ndarray


@dataclass
class SurfaceTargets:
    """The targets of one written surface, in the file's order, and the weights at which the file
    shows the photo's expression.

    Attributes:
        naming: the names' mapping (:class:`facegeo.arkit.TargetNaming`).
        targets: one :class:`MorphTarget` per name of ``naming``.
        weights: (T,) float64, the fitted weights in the targets' terms.
        notes: what the file should say about its targets (a missing ARKit shape, merged halves).
    """

    naming: TargetNaming
    targets: list[MorphTarget]
    weights: np.ndarray
    notes: list[str]

    @property
    def names(self) -> tuple[str, ...]:
        return self.naming.names

    def offset(self, n_vertices: int, weights: np.ndarray | None = None) -> np.ndarray:
        """(n_vertices, 3) float64 mm: Σ_t w_t · positions_t (default: the fitted weights)."""
        w = self.weights if weights is None else np.asarray(weights, dtype=np.float64)
        out = np.zeros((n_vertices, 3))
        for weight, target in zip(w, self.targets):
            out[target.indices] += weight * target.positions
        return out


def surface_targets(shapes: Blendshapes, neutral: np.ndarray, triangles: np.ndarray, naming: TargetNaming,
                    operators: list[sp.csr_matrix] | None = None) -> SurfaceTargets:
    """The targets of one surface.

    Args:
        shapes: the surface's blendshapes (K shapes on V coarse vertices).
        neutral: (V, 3) mm, the coarse neutral mesh (the normals' reference).
        triangles: (F, 3) its triangles.
        naming: the targets' names and how they combine the K shapes.
        operators: the subdivision operators of the written mesh (none at level 0).
    """
    combined = np.stack([shapes.deltas[np.flatnonzero(row)].astype(np.float64).sum(axis=0) for row in naming.combine])
    weights = naming.target_weights(shapes.weights)
    base = np.asarray(neutral, dtype=np.float64)
    normals = vertex_normals(np.concatenate([base[None], base[None] + combined]), triangles)
    changes = normals[1:] - normals[:1]
    targets = []
    n_fine = operators[-1].shape[0] if operators else len(base)
    chunk = len(combined) if not operators else max(1, _CHUNK_VALUES // (6 * n_fine))
    for start in range(0, len(combined), chunk):
        stop = min(start + chunk, len(combined))
        if operators:
            coarse = np.concatenate([combined[start:stop], changes[start:stop]], axis=2).transpose(1, 0, 2)  # (V, n, 6)
            fine = apply_operators(operators, coarse.reshape(len(base), -1)).reshape(n_fine, stop - start, 6)
            positions, normal_changes = (np.ascontiguousarray(fine[..., c].transpose(1, 0, 2)) for c in (slice(0, 3), slice(3, 6)))
        else:
            positions, normal_changes = combined[start:stop], changes[start:stop]
        moves = np.any(positions != 0.0, axis=2) | (np.einsum("tvc,tvc->tv", normal_changes, normal_changes) > NORMAL_TARGET_MIN**2)
        for j, (p, n, m) in enumerate(zip(positions, normal_changes, moves)):
            moved = np.flatnonzero(m)
            targets.append(MorphTarget(naming.names[start + j], moved, p[moved].astype(np.float32), n[moved].astype(np.float32)))
    return SurfaceTargets(naming, targets, weights, _notes(naming, shapes))


def _notes(naming: TargetNaming, shapes: Blendshapes) -> list[str]:
    """The missing ARKit names, and each merged pair whose fitted halves differ."""
    notes = naming.notes()
    for t, name in enumerate(naming.names):
        halves = np.flatnonzero(naming.combine[t])
        if len(halves) > 1 and np.ptp(shapes.weights[halves]) > 0:
            parts = ", ".join(f"{shapes.names[k]} {shapes.weights[k]:.3f}" for k in halves)
            notes.append(f"{name}: the fit's halves ({parts}) share one weight, {float(naming.weights_from_model[t] @ shapes.weights):.3f}")
    return notes
