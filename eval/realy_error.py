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

Numerical uncertainty (:func:`region_error`): the official D matrix holds the deformed vertices
in float32, so round-off differences of the solutions (1e-11 between CHOLMOD builds or solvers)
grow into float32 roundings of the vertices (about 6e-8 of their coordinates) within a few
steps, in the official code as in any other implementation. Such a move can turn the loop's
discrete decisions (a vertex's nearest target, whether it counts as matched, whether a stage
stops) and the final closest points' tie decisions when they are that close to their
thresholds; :class:`NonRigidICP` records those decisions and follows each the other way.
Following one costs the solves from its step to the end, as many as the run's own; each re-run
takes the run's nearest targets where they provably still hold instead of asking the tree
again (:meth:`NonRigidICP._nearest`: the same numbers, bit for bit).

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
from facegeo.eval.realy_settings import EXACT, Settings
from facegeo.eval.realy_geometry import SurfaceQuery, merge_vertices
from facegeo.eval.realy_solver import make_solver

__all__ = ["region_error", "NonRigidICP", "Decision", "MAX_STEPS_WITHOUT_KEYPOINTS", "UNCERTAINTY_SCALE", "PATHS_ENOUGH"]

#: The official loop for the cheek has no step limit; facegeo stops with an error after this many.
MAX_STEPS_WITHOUT_KEYPOINTS = 1000

#: Round-off of the deformed vertices assumed for ``uncertainty`` (a distance, relative to their
#: largest coordinate, scan units). Every step multiplies the vertices, cast to float32 as in the
#: official D matrix, by the solution, so solutions that differ by round-off (1e-11 between
#: solvers) give vertices that differ by up to a float32 rounding (2**-24 = 6e-8) a few steps
#: later: up to 7e-8 measured, between facegeo and the official code and between solvers
#: (benchmarks/RESULTS.md). 2**-23 = 1.2e-7.
UNCERTAINTY_SCALE = 2.0 ** -23
#: The same for the solutions (Frobenius norm, relative), in the stopping tests (measured up to 5e-8).
_SOLUTION_ROUNDING = 2.0 ** -23
#: Relative uncertainty from turned decisions past which no more of them are followed.
PATHS_ENOUGH = 1e-4

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


def _distances(points: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """(K,) float64 distances between (K, 3) ``points`` and (K, 3) ``targets``, bit for bit as
    cKDTree computes them: ``sqrt((dx * dx + dy * dy) + dz * dz)`` (scipy/spatial/ckdtree,
    ``sqeuclidean_distance_double``; a test checks it against its queries)."""
    diff = points - targets
    square = diff[:, 0] * diff[:, 0] + diff[:, 1] * diff[:, 1]
    square += diff[:, 2] * diff[:, 2]
    return np.sqrt(square)


def _unmoved(cur: np.ndarray, at: np.ndarray, nearest: np.ndarray, second: np.ndarray) -> np.ndarray:
    """(N,) bool: the (N, 3) points ``cur`` that have moved from ``at`` by less than half the gap
    between their nearest and second-nearest target's distances (N,) at ``at``: the nearest
    target there is then still strictly the nearest, with a margin (1e-9 relative) far above the
    distances' rounding (1e-16)."""
    moved = cur - at
    shift = np.sqrt(np.einsum("ij,ij->i", moved, moved))
    return (second - nearest) > 2.0 * shift * (1.0 + 1e-9) + 1e-9 * second


@dataclass(frozen=True)
class _State:
    """Where the non-rigid ICP's loop stands before a stopping test: stiffness stage, solves in
    this stage and in all, the deformed vertices, the last two solutions (vertex order) and the
    last solution in the solver's order (its start for SuperLU's conjugate gradients)."""

    stage: int
    step: int
    count: int
    cur: np.ndarray
    x_prev: np.ndarray
    x: np.ndarray
    x_perm: np.ndarray | None


@dataclass(frozen=True)
class Decision:
    """A decision of the non-rigid ICP that round-off could turn (see :meth:`NonRigidICP.run`).

    ``kind``: ``"stop"`` (the stage's stopping test: the change of the solution against its
    threshold), ``"match"`` (the nearest target of ``vertices``: ``alternative`` holds the other
    target of each) or ``"weight"`` (whether ``vertices`` count as matched: their distance
    against the threshold ``max(2 * mean distance, 1)``). ``state``: the loop just before it.
    """

    kind: str
    state: _State
    vertices: np.ndarray | None = None
    alternative: np.ndarray | None = None


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
        self.near_decisions: list[Decision] = []  # of the last run with a deviation
        self._deviation = 0.0
        self._trace: dict[tuple[int, int], _State] = {}  # the last run's states, by (stage, step)
        # the last run's two nearest targets, by (stage, step): (cur, nearest, its distance, the second's)
        self._neighbours: dict[tuple[int, int], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
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

    def _nearest(self, cur: np.ndarray, key: tuple[int, int], deviation: float, stage0: bool,
                 ) -> tuple[np.ndarray, np.ndarray, list[tuple[str, np.ndarray, np.ndarray | None]]]:
        """Each vertex's nearest target: (N,) float64 distances and (N,) int64 indices, bit for bit
        what cKDTree's 1-nearest query gives, and the ``"match"`` decisions a move of ``cur`` by up
        to ``deviation`` could turn ([(kind, vertices, alternative targets)], with ``deviation`` > 0).

        ``key``: the loop's (stage, step). A run with ``deviation`` > 0 asks the tree for the two
        nearest targets and keeps them by ``key``; a re-run at the same ``key`` then
        takes, for each vertex that has moved by less than half the gap between the run's two
        distances, the run's nearest target without a query (no other target can have come nearer;
        the distance computed as cKDTree does, :func:`_distances`); only the others are queried.
        """
        if deviation > 0 and not stage0:  # the first stage matches nothing but keypoints
            two_d, two_i = self.tree.query(cur, 2)
            # the nearest target is the first of the two, with the distance a 1-nearest query
            # gives (the same computation), except where both are equally far: which of them a
            # 1-nearest query returns is its own choice, so those points ask it
            dist, idx = two_d[:, 0].copy(), two_i[:, 0].copy()
            tie = two_d[:, 0] == two_d[:, 1]
            if tie.any():
                dist[tie], idx[tie] = self.tree.query(cur[tie], 1)
            self._neighbours[key] = (cur, idx, dist, two_d[:, 1])
            other = np.where(two_i[:, 0] == idx, two_i[:, 1], two_i[:, 0])
            rival = ((two_d[:, 1] - two_d[:, 0]) <= 2 * deviation) & np.any(self.targets[other] != self.targets[idx], axis=1)
            return dist, idx, [("match", np.nonzero(rival)[0], other[rival])] if rival.any() else []
        reference = self._neighbours.get(key) if deviation == 0 else None
        if reference is None:
            dist, idx = self.tree.query(cur, 1)
            return dist, idx, []
        cur0, idx0, first, second = reference
        kept = _unmoved(cur, cur0, first, second)
        idx = idx0.copy()
        dist = np.empty(self.n)
        dist[kept] = _distances(cur[kept], self.targets[idx0[kept]])
        if not kept.all():
            asked = ~kept
            dist[asked], idx[asked] = self.tree.query(cur[asked], 1)
        return dist, idx, []

    def _step(self, cur, alpha, stiffness, stage0, kp_weight, x0, key: tuple[int, int], deviation: float = 0.0,
              flip: Decision | None = None):
        """One solve at the loop's (stage, step) ``key``. With ``deviation`` > 0 also the decisions
        a move of ``cur`` by up to ``deviation`` could turn: [(kind, vertices, alternative
        targets)]; ``flip`` turns one."""
        start = time.process_time()
        dist, idx, near = self._nearest(cur, key, deviation, stage0)
        if flip is not None and flip.kind == "match":
            idx = np.array(idx)
            idx[flip.vertices] = flip.alternative
            dist = np.array(dist)
            dist[flip.vertices] = np.sqrt(np.sum((cur[flip.vertices] - self.targets[flip.alternative]) ** 2, axis=1))
        self.nearest_seconds += time.process_time() - start
        dist32 = np.asarray(dist, dtype=np.float32)
        nearest = self.targets[np.asarray(idx, dtype=np.int32)]
        threshold = max(np.mean(dist32) * 2, 1)
        w = (dist32 < threshold).astype(np.float64)
        if deviation > 0 and not stage0:  # the distances and their mean move by up to ``deviation``
            close = np.abs(dist32.astype(np.float64) - float(threshold)) <= 4 * deviation
            if close.any():
                near.append(("weight", np.nonzero(close)[0], None))
        if flip is not None and flip.kind == "weight":
            w[flip.vertices] = 1.0 - w[flip.vertices]
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
        return x, x_perm, new, near

    def _stage_parameters(self, stage: int) -> tuple[float, float, np.ndarray, bool]:
        """(alpha, epsilon, stiffness weights, keypoints-only stage) of a stiffness stage."""
        if self.keypoint_index is not None:
            alpha = _ALPHA_KEYPOINTS if stage == 0 else _ALPHA * np.exp(-0.5 * (stage - 1))
            epsilon = _EPSILON * pow(0.5, stage - 1)
        else:
            alpha = _ALPHA * np.exp(-0.5 * stage)
            epsilon = _EPSILON * pow(0.5, stage)
        stage0 = self.keypoint_index is not None and stage == 0
        return alpha, epsilon * self.settings.nicp_epsilon_scale, _STIFFNESS_KEYPOINTS if stage0 else _STIFFNESS, stage0

    def run(self, deviation: float = 0.0) -> np.ndarray:
        """The deformed vertices (N, 3) float64.

        With ``deviation`` > 0 (a length: how far round-off can move the deformed vertices, see
        :data:`UNCERTAINTY_SCALE`), the decisions that such a move could turn are collected in
        :attr:`near_decisions`: a stopping test whose change of the solution is within its
        round-off of the threshold, vertices whose two nearest targets are within
        ``2 * deviation`` of each other, or whose distance is within ``4 * deviation`` of the
        match threshold (one :class:`Decision` per kind and step). :meth:`rerun` follows one of
        them the other way. The numbers of the run itself do not depend on ``deviation``.
        """
        self.near_decisions = []
        self._deviation = deviation
        self._trace = {}
        self._neighbours = {}
        start = _State(0, 0, 0, self.vertices, np.zeros((4 * self.n, 3)), np.ones((4 * self.n, 3)), None)
        return self._loop(start, deviation, None)

    def rerun(self, decision: Decision) -> np.ndarray | None:
        """The deformed vertices (N, 3) had ``decision`` gone the other way (the rest of the run
        as the protocol goes; its decisions are not collected), or None when that run comes back
        to within round-off (``deviation``) of this one at the same step: from there on it is
        this run again, whose later decisions are collected on their own."""
        self.solver.start_stage()
        return self._loop(decision.state, 0.0, decision)

    def _rejoined(self, state: _State) -> bool:
        """Whether a re-run's ``state`` is within round-off of the run's own at the same step."""
        own = self._trace.get((state.stage, state.step))
        if own is None or own.count != state.count:
            return False
        if float(np.abs(state.cur - own.cur).max()) > self._deviation:
            return False
        for mine, theirs in ((state.x, own.x), (state.x_prev, own.x_prev)):
            gap = float(np.sqrt(np.einsum("ij,ij->", mine - theirs, mine - theirs)))
            if gap > _SOLUTION_ROUNDING * float(np.sqrt(np.einsum("ij,ij->", theirs, theirs))):
                return False
        return True

    def _loop(self, state: _State, deviation: float, flip: Decision | None) -> np.ndarray | None:
        stage, step, count = state.stage, state.step, state.count
        cur, x_prev, x, x_perm = state.cur, state.x_prev, state.x, state.x_perm
        with_kp = self.keypoint_index is not None
        cap = self.settings.nicp_max_steps
        if cap is None:
            cap = 11 if with_kp else MAX_STEPS_WITHOUT_KEYPOINTS
        branch = flip is not None
        while stage < (4 if with_kp else 3):
            alpha, epsilon, stiffness, stage0 = self._stage_parameters(stage)
            if step == 0:
                self.solver.start_stage()
            while True:
                here = _State(stage, step, count, cur, x_prev, x, x_perm)
                if deviation > 0:
                    self._trace[stage, step] = here
                elif branch and flip is None and self._rejoined(here):
                    return None
                diff = x - x_prev
                delta = math.sqrt(float(np.einsum("ij,ij->", diff, diff)))  # Frobenius norm
                stop = delta <= epsilon or step >= cap
                if flip is not None and flip.kind == "stop":
                    stop, flip = not stop, None
                elif deviation > 0 and step < cap and not (stage0 and step > 0):
                    # the solutions move by round-off too: about 2**-24 of their size per step
                    slack = _SOLUTION_ROUNDING * (math.sqrt(float(np.einsum("ij,ij->", x, x)))
                                                  + math.sqrt(float(np.einsum("ij,ij->", x_prev, x_prev))))
                    if abs(delta - epsilon) <= slack:
                        self.near_decisions.append(Decision("stop", here))
                if stop:
                    break
                x_prev = x
                kp_weight = _KEYPOINT_WEIGHT if stage0 else _KEYPOINT_WEIGHT * np.exp(-0.9 * count) / 10.0
                x, x_perm, cur, near = self._step(cur, alpha, stiffness, stage0, kp_weight, x_perm, (stage, step),
                                                  deviation, flip)
                flip = None
                self.near_decisions.extend(Decision(kind, here, v, alt) for kind, v, alt in near)
                step += 1
                count += 1
                if stage0:
                    break
            if not with_kp and self.settings.nicp_max_steps is None and step >= cap:
                raise FacegeoError(f"the non-rigid ICP did not converge in {step} steps")
            stage += 1
            step = 0
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

    Details: the solver's counts and seconds (:meth:`NonRigidICP.details`, of the run itself),
    ``vertices`` (merged count), ``nearest_seconds`` (its nearest-neighbour queries) and
    ``uncertainty``: how far (relative) round-off can move the error, the sum of two parts:

    * ``uncertainty_paths``: the non-rigid ICP's decisions that a move of the deformed vertices
      by round-off (``deviation`` = :data:`UNCERTAINTY_SCALE` times their largest coordinate)
      could turn (:meth:`NonRigidICP.run`) are each followed the other way to the end
      (:meth:`NonRigidICP.rerun`), and the changes of the error they give are summed. One turned
      decision can move a value by up to 1e-2 (benchmarks/RESULTS.md);
    * ``uncertainty_ties``: the final closest points of the vertices within ``deviation`` of one of
      trimesh's tie decisions may jump to the other candidate; the sum of those jumps' effects.

    A smooth move of the points by round-off changes the error by a few 1e-8 (measured), and is
    not counted. ``reruns`` counts the decisions followed by kind (and those whose other way came
    back to this run: ``rejoined``), ``rerun_solves`` / ``rerun_seconds`` their cost. Once the
    followed decisions add up to :data:`PATHS_ENOUGH` the rest are not followed: the
    uncertainty is then at least that (the value is flagged either way).
    """
    gt_vertices, gt_triangles = merge_vertices(scan_vertices, scan_triangles)
    on_prediction = surface(pred_vertices, gt_vertices)
    if keypoints is not None:
        _, kp_index = cKDTree(gt_vertices).query(np.asarray(scan_keypoints, dtype=np.float64))
        nicp = NonRigidICP(gt_vertices, gt_triangles, on_prediction, kp_index, keypoints, settings)
    else:
        nicp = NonRigidICP(gt_vertices, gt_triangles, on_prediction, settings=settings)
    deviation = UNCERTAINTY_SCALE * float(np.abs(gt_vertices).max())
    deformed = nicp.run(deviation if settings.follow_decisions else 0.0)
    info = nicp.details()  # of the run itself (the re-runs below are counted apart)

    updated = surface(pred_vertices, deformed, jitter=deviation)
    distances = np.sqrt(np.sum((updated - gt_vertices) ** 2, axis=-1))
    error = float(distances.mean())
    if not math.isfinite(error):
        raise FacegeoError("the error step produced a non-finite value")
    # near-ties: the other of the two nearest candidates could be picked under round-off
    near = surface.near_ties
    other = np.sqrt(np.sum((surface.alternatives[near] - gt_vertices[near, None]) ** 2, axis=-1))
    jump = np.nan_to_num(np.abs(other - distances[near, None]), nan=0.0).max(axis=1, initial=0.0)
    ties = float(jump.sum()) / len(distances)
    # decisions of the non-rigid ICP that round-off could turn: each followed the other way
    start = time.process_time()
    solves = nicp.solves
    paths = 0.0
    kinds: dict[str, int] = {}
    for decision in nicp.near_decisions:
        if paths >= PATHS_ENOUGH * error:
            break
        kinds[decision.kind] = kinds.get(decision.kind, 0) + 1
        alternative = nicp.rerun(decision)
        if alternative is None:
            kinds["rejoined"] = kinds.get("rejoined", 0) + 1
            continue
        other_way = surface(pred_vertices, alternative)
        paths += abs(float(np.sqrt(np.sum((other_way - gt_vertices) ** 2, axis=-1)).mean()) - error)
    scale = max(error, 1e-300)
    info.update(vertices=len(gt_vertices), nearest_seconds=nicp.nearest_seconds, uncertainty=(ties + paths) / scale,
                uncertainty_ties=ties / scale, uncertainty_paths=paths / scale if settings.follow_decisions else None,
                reruns=kinds,
                rerun_solves=nicp.solves - solves, rerun_seconds=time.process_time() - start)
    return error, info
