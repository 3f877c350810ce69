"""REALY's bidirectional error of one region: non-rigid ICP of the scan region, then distances.

Written from the protocol of the official REALY code (``utils/eval.py``, ``utils/NICP.py``):

1. the ground-truth region is cleaned as ``trimesh.Trimesh(process=True)`` does (unused
   vertices dropped, duplicates merged; :func:`~facegeo.eval.realy_geometry.merge_vertices`);
2. each of its vertices gets its closest point on the regionally aligned prediction;
3. the region is deformed towards those points by an optimal-step non-rigid ICP (one affine
   4x3 transform per vertex, stiffness on the mesh edges, nearest neighbours among the closest
   points, a match counts when closer than ``max(2 * mean distance, 1)``): four stiffness stages
   ``alpha = 150`` (keypoints only, stiffness weights ``diag(2, 2, 3, 2)``, one solve), then
   ``50 * exp(-0.5 k)`` for k = 0, 1, 2, each until the solution changes by at most
   ``0.5 ** k`` or after 11 solves; keypoint weight 50 in the first stage and
   ``5 * exp(-0.9 * solves so far)`` afterwards. The cheek has no keypoints: three stages
   ``50 * exp(-0.5 k)``, each until the change is at most ``0.5 ** k``;
4. the deformed vertices get their closest points on the prediction again, and the error is the
   mean distance between those and the *original* region vertices (scan units; the caller
   multiplies by the subject's metrical scale).

Each least-squares step solves the normal equations ``A^T A X = A^T B`` (the official code
factors ``A^T A`` with CHOLMOD at every step); here ``A^T A`` is assembled directly, block by
block, with the vertices in METIS' nested-dissection order, and solved by
:mod:`facegeo.eval.realy_solver` (CHOLMOD at every step when CVXOPT is installed, else SuperLU
with its factor reused within a stiffness stage). A singular system (a part of the region that
nothing holds, where the official CHOLMOD call fails) raises
:class:`~facegeo.errors.FacegeoError` instead of giving a number.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from facegeo.errors import FacegeoError
from facegeo.eval.realy_align import EXACT, Settings
from facegeo.eval.realy_geometry import SurfaceQuery, merge_vertices
from facegeo.eval.realy_solver import make_solver

__all__ = ["region_error", "NonRigidICP", "MAX_STEPS_WITHOUT_KEYPOINTS", "UNCERTAINTY_SCALE"]

#: The official loop for the cheek has no step limit; facegeo stops with an error after this many.
MAX_STEPS_WITHOUT_KEYPOINTS = 1000

#: Round-off of the deformed vertices assumed for ``uncertainty``, relative to the region's size
#: (solvers differ by about 1e-11 here; the CG tolerance is 1e-10).
UNCERTAINTY_SCALE = 1e-9

_EPSILON = 1.0
_ALPHA = 50.0
_ALPHA_KEYPOINTS = 150.0
_KEYPOINT_WEIGHT = 50.0
_STIFFNESS = np.array([1.0, 1.0, 1.0, 1.0])  # diag(G)^2, gamma = 1
_STIFFNESS_KEYPOINTS = np.array([2.0, 2.0, 3.0, 2.0]) ** 2  # diag(G_KP)^2


def _nested_dissection(n: int, edges: np.ndarray) -> np.ndarray:
    """(n,) int64 fill-reducing elimination order of the vertices (METIS nested dissection)."""
    import pymetis

    if len(edges) == 0:
        return np.arange(n)
    both = np.concatenate([edges, edges[:, ::-1]])
    both = both[np.lexsort((both[:, 1], both[:, 0]))]
    xadj = np.searchsorted(both[:, 0], np.arange(n + 1)).astype(np.int32)
    adjncy = np.ascontiguousarray(both[:, 1], dtype=np.int32)
    # CSRAdjacency: the xadj=/adjncy= keywords are deprecated (to be removed in 2027)
    perm, _ = pymetis.nested_dissection(adjacency=pymetis.CSRAdjacency(xadj, adjncy))
    return np.asarray(perm, dtype=np.int64)


@dataclass
class _Pattern:
    """Fixed sparsity pattern of A^T A: kron(L, diag) entries plus a dense 4x4 block per vertex.

    Unknowns are numbered in the vertices' nested-dissection order: vertex ``order[k]`` owns
    rows ``4k .. 4k+3``; ``rank`` is the inverse permutation.
    """

    n: int
    indptr: np.ndarray
    indices: np.ndarray
    lap_slot: np.ndarray  # (k,) data position of each kron(L, I4) entry
    lap_value: np.ndarray  # (k,) L value
    lap_comp: np.ndarray  # (k,) which of the 4 components
    block_slot: np.ndarray  # (n, 16) data position of each vertex's 4x4 block entry (vertex order)
    size: int
    order: np.ndarray  # (n,) vertex eliminated k-th
    rank: np.ndarray  # (n,) position of each vertex in ``order``


def _pattern(n: int, triangles: np.ndarray) -> _Pattern:
    # unique undirected edges, as a set of (min, max) pairs; (v, v) pairs (a face repeating a
    # vertex) give a zero row in the official incidence matrix and are dropped here
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [0, 2]], triangles[:, [1, 2]]])
    e = np.sort(e, axis=1)
    e = e[e[:, 0] != e[:, 1]]
    code = np.sort(e[:, 0] * n + e[:, 1])  # unique rows, sorted, through one int64 key
    code = code[np.concatenate([[True], code[1:] != code[:-1]])]
    e = np.column_stack([code // n, code % n])
    order = _nested_dissection(n, e)
    rank = np.empty(n, dtype=np.int64)
    rank[order] = np.arange(n)
    degree = np.bincount(e.ravel(), minlength=n).astype(np.float64)
    lap_rows = rank[np.concatenate([np.arange(n), e[:, 0], e[:, 1]])]
    lap_cols = rank[np.concatenate([np.arange(n), e[:, 1], e[:, 0]])]
    lap_vals = np.concatenate([degree, -np.ones(len(e)), -np.ones(len(e))])
    comp = np.arange(4)
    k_rows = (lap_rows[:, None] * 4 + comp).ravel()
    k_cols = (lap_cols[:, None] * 4 + comp).ravel()
    b = np.arange(16)
    b_rows = (rank[:, None] * 4 + b // 4).ravel()
    b_cols = (rank[:, None] * 4 + b % 4).ravel()
    rows = np.concatenate([k_rows, b_rows])
    cols = np.concatenate([k_cols, b_cols])
    size = 4 * n
    key = cols.astype(np.int64) * size + rows  # column-major (CSC)
    order_k = np.argsort(key, kind="stable")
    sorted_key = key[order_k]
    first = np.concatenate([[True], sorted_key[1:] != sorted_key[:-1]])
    uniq = sorted_key[first]
    inverse = np.empty(len(key), dtype=np.int64)
    inverse[order_k] = np.cumsum(first) - 1
    indices = (uniq % size).astype(np.int32)
    col_of = uniq // size
    indptr = np.searchsorted(col_of, np.arange(size + 1)).astype(np.int32)
    k = len(k_rows)
    return _Pattern(
        n=n,
        indptr=indptr,
        indices=indices,
        lap_slot=inverse[:k],
        lap_value=np.repeat(lap_vals, 4),
        lap_comp=np.tile(comp, len(lap_vals)),
        block_slot=inverse[k:].reshape(n, 16),
        size=len(uniq),
        order=order,
        rank=rank,
    )


class NonRigidICP:
    """The official optimal-step non-rigid ICP of a region towards points on the prediction.

    ``settings`` can loosen the stopping rule (``nicp_epsilon_scale``, ``nicp_max_steps``) and
    the solver (``solver_rtol``, ``factor_reuse``); the defaults are the official protocol.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, targets: np.ndarray,
                 keypoint_index: np.ndarray | None = None, keypoint_targets: np.ndarray | None = None,
                 settings: Settings = EXACT):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.targets = np.asarray(targets, dtype=np.float64)
        self.n = len(self.vertices)
        self.pattern = _pattern(self.n, np.asarray(triangles, dtype=np.int64))
        self.tree = cKDTree(self.targets)  # SciPy's leaf size 16: queries 1.6x faster than with 100
        self.keypoint_index = None if keypoint_index is None else np.asarray(keypoint_index)
        self.keypoint_targets = keypoint_targets
        self.settings = settings
        self.solver = make_solver(settings.solver, self.pattern.indptr, self.pattern.indices,
                                  settings.factor_reuse, settings.solver_rtol)
        self.nearest_seconds = 0.0  # CPU time in the nearest-neighbour queries
        self._stiffness_key: tuple | None = None
        self._stiffness_data = np.zeros(0)

    @property
    def solves(self) -> int:
        return len(self.solver.iterations)

    def _system(self, cur: np.ndarray, alpha: float, stiffness: np.ndarray,
                weight2: np.ndarray, rhs_parts: list[tuple[np.ndarray, np.ndarray]]):
        p = self.pattern
        d = np.empty((self.n, 4), dtype=np.float64)
        d[:, :3] = cur.astype(np.float32)  # the official D matrix is float32
        d[:, 3] = 1.0
        key = (alpha, stiffness.tobytes())
        if self._stiffness_key != key:  # the stiffness part changes only from one stage to the next
            self._stiffness_data = np.bincount(p.lap_slot, weights=(alpha * alpha) * p.lap_value * stiffness[p.lap_comp],
                                               minlength=p.size)
            self._stiffness_key = key
        data = self._stiffness_data.copy()
        block = (weight2[:, None, None] * d[:, :, None] * d[:, None, :]).reshape(self.n, 16)
        data[p.block_slot] += block  # each vertex's block has slots of its own
        rhs = np.zeros((self.n, 4, 3))
        for w2, target in rhs_parts:
            rhs += (w2[:, None, None] * d[:, :, None]) * target[:, None, :]
        return d, data, rhs[p.order].reshape(4 * self.n, 3)

    def _step(self, cur, alpha, stiffness, stage0, kp_weight, x0):
        start = time.process_time()
        dist, idx = self.tree.query(cur, 1)
        self.nearest_seconds += time.process_time() - start
        dist32 = np.asarray(dist, dtype=np.float32)
        nearest = self.targets[np.asarray(idx, dtype=np.int32)]
        threshold = max(np.mean(dist32) * 2, 1)
        w = (dist32 < threshold).astype(np.float64)
        parts = []
        weight2 = np.zeros(self.n)
        if not stage0:
            weight2 += w * w
            parts.append((w * w, nearest))
        if self.keypoint_index is not None:
            kpw = np.zeros(self.n)
            kpw[self.keypoint_index] = kp_weight
            target = nearest.copy()
            target[self.keypoint_index] = self.keypoint_targets
            weight2 += kpw * kpw
            parts.append((kpw * kpw, target))
        d, data, rhs = self._system(cur, alpha, stiffness, weight2, parts)
        x_perm = self.solver.solve(data, rhs, x0)  # unknowns in nested-dissection order
        x4 = x_perm.reshape(self.n, 4, 3)[self.pattern.rank]  # back to vertex order
        x = x4.reshape(4 * self.n, 3)
        new = ((d[:, 0:1] * x4[:, 0] + d[:, 1:2] * x4[:, 1]) + d[:, 2:3] * x4[:, 2]) + x4[:, 3]
        return x, x_perm, new

    def run(self) -> np.ndarray:
        """The deformed vertices (N, 3) float64."""
        cur = self.vertices
        x_prev = np.zeros((4 * self.n, 3))
        x = np.ones((4 * self.n, 3))
        x_perm = None
        with_kp = self.keypoint_index is not None
        cap = self.settings.nicp_max_steps
        if cap is None:
            cap = 11 if with_kp else MAX_STEPS_WITHOUT_KEYPOINTS
        count = 0
        for stage in range(4 if with_kp else 3):
            if with_kp:
                alpha = _ALPHA_KEYPOINTS if stage == 0 else _ALPHA * np.exp(-0.5 * (stage - 1))
                epsilon = _EPSILON * pow(0.5, stage - 1)
            else:
                alpha = _ALPHA * np.exp(-0.5 * stage)
                epsilon = _EPSILON * pow(0.5, stage)
            epsilon *= self.settings.nicp_epsilon_scale
            stage0 = with_kp and stage == 0
            stiffness = _STIFFNESS_KEYPOINTS if stage0 else _STIFFNESS
            self.solver.start_stage()
            step = 0
            while True:
                diff = x - x_prev
                delta = math.sqrt(float(np.einsum("ij,ij->", diff, diff)))  # Frobenius norm
                if delta <= epsilon or step >= cap:
                    break
                x_prev = x
                kp_weight = _KEYPOINT_WEIGHT if stage0 else _KEYPOINT_WEIGHT * np.exp(-0.9 * count) / 10.0
                x, x_perm, cur = self._step(cur, alpha, stiffness, stage0, kp_weight, x_perm)
                step += 1
                count += 1
                if stage0:
                    break
            if not with_kp and self.settings.nicp_max_steps is None and step >= cap:
                raise FacegeoError(f"the non-rigid ICP did not converge in {step} steps")
        return cur

    def details(self) -> dict:
        """The solver's name, solves, analyses, factorisations, PCG iterations per solve (0: direct) and seconds."""
        return self.solver.details()


def region_error(
    pred_vertices: np.ndarray,
    surface: SurfaceQuery,
    scan_vertices: np.ndarray,
    scan_triangles: np.ndarray,
    keypoints: np.ndarray | None,
    scan_keypoints: np.ndarray | None,
    settings: Settings = EXACT,
) -> tuple[float, dict]:
    """REALY's error of one region in scan units, and details (see below).

    ``pred_vertices``: the regionally aligned prediction, ``surface`` the closest-point query of
    its (error-step) triangles; ``scan_vertices`` / ``scan_triangles``:
    the region as read (float32, unmerged); ``keypoints`` / ``scan_keypoints``: the region's
    error-step keypoints on the prediction (float64) and the scan (float32), or None (cheek).

    Details: the solver's counts and seconds (:meth:`NonRigidICP.details`), ``vertices`` (merged
    count), ``nearest_seconds`` (its nearest-neighbour queries) and ``uncertainty``: how much
    the error (relative) can move when the final deformed vertices move by round-off,
    ``UNCERTAINTY_SCALE`` times the region's size: the closest points of the vertices that are
    that near one of trimesh's tie decisions may jump to the other candidate, and the sum of
    those jumps' effects on the mean distance is the bound reported (the official code's own
    rounding moves its numbers that way; a smooth move of the points changes the error by
    about ``UNCERTAINTY_SCALE``, far less).
    """
    gt_vertices, gt_triangles = merge_vertices(scan_vertices, scan_triangles)
    on_prediction = surface(pred_vertices, gt_vertices)
    if keypoints is not None:
        _, kp_index = cKDTree(gt_vertices).query(np.asarray(scan_keypoints, dtype=np.float64))
        nicp = NonRigidICP(gt_vertices, gt_triangles, on_prediction, kp_index, keypoints, settings)
    else:
        nicp = NonRigidICP(gt_vertices, gt_triangles, on_prediction, settings=settings)
    deformed = nicp.run()

    size = float(np.ptp(deformed, axis=0).max())
    updated = surface(pred_vertices, deformed, jitter=UNCERTAINTY_SCALE * size)
    distances = np.sqrt(np.sum((updated - gt_vertices) ** 2, axis=-1))
    error = float(distances.mean())
    if not math.isfinite(error):
        raise FacegeoError("the error step produced a non-finite value")
    # near-ties: the other of the two nearest candidates could be picked under round-off
    near = surface.near_ties
    other = np.sqrt(np.sum((surface.alternatives[near] - gt_vertices[near, None]) ** 2, axis=-1))
    jump = np.nan_to_num(np.abs(other - distances[near, None]), nan=0.0).max(axis=1, initial=0.0)
    uncertainty = float(jump.sum()) / len(distances) / max(error, 1e-300)
    info = nicp.details()
    info.update(vertices=len(gt_vertices), nearest_seconds=nicp.nearest_seconds, uncertainty=uncertainty)
    return error, info
