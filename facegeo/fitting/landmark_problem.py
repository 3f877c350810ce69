"""The landmark term of the fit: residuals and their Jacobian over points on the model surface.

Every observed point (the 88 hybrid landmarks, then any dense points) is a fixed barycentric
combination of three model vertices, Σ_k b_k·S_{v_k} (a vertex landmark is (v, v, v) with
b = (1, 0, 0); a point on an edge has b_2 = 0). The jaw contour points slide (below); every
other point keeps its place on the surface.
"""

from __future__ import annotations

import numpy as np

from facegeo.camera import Camera, cross_matrices, pixels_jacobian, project
from facegeo.fitting.silhouette import Silhouette
from facegeo.landmarks.scheme import BROWS, CHIN, N_LANDMARKS, inter_ocular_distance
from facegeo.morphable_model import MorphableModel

__all__ = ["LandmarkProblem", "SurfacePoints", "silhouette_of", "SubsetBases", "subset_bases", "along_curve_metric"]

_SILHOUETTES: dict[int, tuple[MorphableModel, Silhouette]] = {}


class SubsetBases:
    """The model's mean and bases gathered at a set of vertices (float64, read-only): ``mean``
    (S, 3), ``id_basis`` (n_id, S, 3), ``exp_basis`` (n_exp, S, 3), and ``flat`` {key: (mean
    (K, 3), id (n_id, 3K), exp (n_exp, 3K))} at named sets of rows within them (a landmark
    problem's: the jaw contour, ``"contour"``, and the silhouette, ``"silhouette"``), whose shape
    under α and δ :meth:`shape_at` gives."""

    def __init__(self, model: MorphableModel, subset: np.ndarray, rows: dict[str, np.ndarray]):
        self.mean = model.mean_shape[subset].astype(np.float64)
        self.id_basis = model.id_basis[:, subset].astype(np.float64)
        self.exp_basis = model.exp_basis[:, subset].astype(np.float64)
        # a gather along axis 1 is not C-contiguous, so flattening it copied (n_id + n_exp) × K × 3 per step
        self.flat = {key: (self.mean[r], np.ascontiguousarray(self.id_basis[:, r]).reshape(model.n_id, -1),
                           np.ascontiguousarray(self.exp_basis[:, r]).reshape(model.n_exp, -1)) for key, r in rows.items()}
        for array in (self.mean, self.id_basis, self.exp_basis, *(a for arrays in self.flat.values() for a in arrays)):
            array.setflags(write=False)

    def shape_at(self, key: str, alpha: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(K, 3) model-space positions (mm) of the rows ``key`` under α (n_id,) and δ (n_exp,), float64."""
        mean, id_flat, exp_flat = self.flat[key]
        return mean + (alpha @ id_flat).reshape(-1, 3) + (delta @ exp_flat).reshape(-1, 3)


#: The last few gathers, by model object and vertex set: a video's frames, and photos seen by one
#: detector, observe the same model vertices, and gathering them was half of a tracked frame's solve.
_BASES: dict[tuple[int, bytes], tuple[MorphableModel, SubsetBases]] = {}
_BASES_KEPT = 4


def subset_bases(model: MorphableModel, subset: np.ndarray, rows: dict[str, np.ndarray]) -> SubsetBases:
    """:class:`SubsetBases` of ``model`` at ``subset`` (S,) int vertices and ``rows`` (into
    ``subset``), gathered once per model object and vertex set in a process."""
    key = (id(model), subset.tobytes() + b"|" + b"|".join(rows[k].tobytes() for k in sorted(rows)))
    cached = _BASES.get(key)
    if cached is None or cached[0] is not model:
        cached = (model, SubsetBases(model, subset, rows))
        while len(_BASES) >= _BASES_KEPT:
            del _BASES[next(iter(_BASES))]
        _BASES[key] = cached
    return cached[1]


def silhouette_of(model: MorphableModel) -> Silhouette:
    """The :class:`Silhouette` bins of ``model``, built once per model object in a process."""
    cached = _SILHOUETTES.get(id(model))
    if cached is None or cached[0] is not model:
        cached = (model, Silhouette(model))
        _SILHOUETTES[id(model)] = cached
    return cached[1]


class SurfacePoints:
    """Extra observed points on the model surface (e.g. a dense face mesh's), beside the 88.

    targets (K, 2) px (NaN rows ignored); vertex_ids (K, 3) int model vertices; barycentric
    (K, 3) float weights (rows sum to 1); weights (K,) relative precisions on the scale of the 88
    points' (a point as reliable as a nominal landmark has weight 1; 0 leaves it out); contour
    (K,) bool: points of the face's outline, which slide along the model's occluding contour
    (:mod:`facegeo.fitting.silhouette`) instead of keeping their place on the surface;
    expressive (K,) bool: points whose residuals reach every expression (eyes, brows, lips);
    the others reach only the jaw's (like the jaw contour: a cheek or forehead point that sits
    off the model is explained by the identity, never by puffed cheeks or a frown).
    """

    def __init__(self, targets: np.ndarray, vertex_ids: np.ndarray, barycentric: np.ndarray, weights: np.ndarray,
                 contour: np.ndarray | None = None, expressive: np.ndarray | None = None):
        self.targets = np.asarray(targets, dtype=np.float64).reshape(-1, 2)
        k = len(self.targets)
        self.vertex_ids = np.asarray(vertex_ids, dtype=np.int64).reshape(k, 3)
        self.barycentric = np.asarray(barycentric, dtype=np.float64).reshape(k, 3)
        self.weights = np.asarray(weights, dtype=np.float64).reshape(k)
        self.contour = np.zeros(k, dtype=bool) if contour is None else np.asarray(contour, dtype=bool).reshape(k)
        self.expressive = np.ones(k, dtype=bool) if expressive is None else np.asarray(expressive, dtype=bool).reshape(k)

    def __len__(self) -> int:
        return len(self.targets)


def along_curve_metric(points: np.ndarray, along: float) -> np.ndarray:
    """(K, 2, 2) float64: for each point of a polyline ``points`` (K, 2) px, the matrix that keeps
    a residual's part across the line and scales its part along it by ``along``: n nᵀ + along·t tᵀ,
    t the unit tangent (the central difference of the neighbours, one-sided at the ends), n ⟂ t."""
    tangent = np.gradient(np.asarray(points, np.float64), axis=0)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    return normal[:, :, None] * normal[:, None, :] + along * tangent[:, :, None] * tangent[:, None, :]


class LandmarkProblem:
    """Residuals of the landmark term, with the jaw points sliding along the contour (NumPy
    float64: Gauss–Newton squares the Jacobian, and float32 cannot tell the last sub-pixel
    decreases of the cost apart; NumPy rather than torch because the problem is small (a few
    hundred points × ~160 parameters) and has no autograd in it, so per-call overhead dominates).

    The jaw contour is the model's frontal jaw polyline (landmark vertices 0→8 on the subject's
    right, 16→8 on the left); before each step every jaw point but the chin moves to the point of
    its side's projected polyline nearest to its detected position (eos's sliding contour, made
    continuous so no vertex spacing limits the fit).

    The jaw contour cannot pull expressions: the sliding contour points are moved by the current
    expression (a smile widens the lower cheeks), but that part is frozen at each step like the
    slide itself, so their residuals reach only the pose, the identity and the jaw articulation
    (blendshapes named ``jaw*``; none for PCA expression models). A detected jaw line that is
    wider or narrower than the face is explained by the identity, never by puffed cheeks or a
    stretched mouth. The chin and every other point see all expressions.

    With ``brow_along_noise`` (:attr:`FitPriors.brow_along_noise <facegeo.fitting.priors.FitPriors>`)
    other than 1, a brow point's residual is taken in its detected brow's frame
    (:func:`along_curve_metric`): across the brow as it is, along it divided by that ratio.

    Rows 0..87 are the 88 landmarks (:mod:`facegeo.landmarks.scheme`), rows 88.. the
    :class:`SurfacePoints`, if any. Residuals are in inter-ocular units of the 88 targets.
    """

    def __init__(self, model: MorphableModel, targets: np.ndarray, camera: Camera, weights: np.ndarray,
                 extra: SurfacePoints | None = None, brow_along_noise: float = 1.0):
        self.model, self.camera = model, camera
        extra = extra if extra is not None else SurfacePoints(np.zeros((0, 2)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        n = N_LANDMARKS + len(extra)
        self.n_points = n
        valid = np.isfinite(targets).all(axis=1)
        w = np.where(valid, weights, 0.0).astype(np.float64)
        # relative precisions with mean 1 over the valid of the 88, residuals in inter-ocular units
        norm = np.count_nonzero(w > 0) / max(w.sum(), 1e-12)
        extra_valid = np.isfinite(extra.targets).all(axis=1) & (extra.weights > 0)
        w_all = np.concatenate([w, np.where(extra_valid, extra.weights, 0.0)]) * norm
        self.n_valid = int(np.count_nonzero(w_all > 0))
        # observations for the noise estimate: each valid landmark counts once, a surface point
        # by its weight (a dense detector's points are correlated: K of them at weight λ carry
        # about the evidence of λ·K independent points)
        self.n_observations = float(np.count_nonzero(w > 0) + np.minimum(w_all[N_LANDMARKS:], 1.0).sum())
        self.scale = max(inter_ocular_distance(targets), 1.0)
        self.sqrt_w = np.sqrt(w_all) / self.scale
        all_targets = np.concatenate([targets, extra.targets]).astype(np.float64)
        self.targets = np.where(np.isfinite(all_targets), all_targets, 0.0)  # weight 0 where not finite

        jaw = model.landmark_indices[:17]
        contours = {"right": jaw[: CHIN + 1], "left": jaw[CHIN:][::-1]}
        ids = np.concatenate([np.repeat(np.asarray(model.landmark_indices)[:, None], 3, axis=1), extra.vertex_ids])
        self.silhouette_rows = N_LANDMARKS + np.flatnonzero(extra.contour & (w_all[N_LANDMARKS:] > 0))
        self.silhouette = silhouette_of(model) if len(self.silhouette_rows) else None
        silhouette_vertices = self.silhouette.vertices if self.silhouette is not None else np.zeros(0, np.int64)
        self.subset = np.unique(np.concatenate([ids.ravel(), silhouette_vertices]))
        position = np.full(model.n_vertices, -1, dtype=np.int64)
        position[self.subset] = np.arange(len(self.subset))
        self.rows = position[ids]  # (n, 3) rows into subset
        self.bary = np.concatenate([np.tile([1.0, 0.0, 0.0], (N_LANDMARKS, 1)), extra.barycentric])
        self.sliding_rows = np.array([j for j in range(17) if j != CHIN])
        self.sliding = self.sliding_rows[(w > 0)[self.sliding_rows]]
        names = model.expression_names
        jaw_articulation = np.array([name.startswith("jaw") for name in names] or [False] * model.n_exp)
        self.exp_mask = np.ones((n, model.n_exp))  # which expressions move which point
        self.exp_mask[self.sliding_rows] = jaw_articulation
        self.exp_mask[self.silhouette_rows] = jaw_articulation
        # surface points off the features: expression frozen at the current δ (updated by :meth:`slide`)
        self.frozen_rows = N_LANDMARKS + np.flatnonzero(~extra.expressive & ~np.isin(np.arange(len(extra)), self.silhouette_rows - N_LANDMARKS))
        self.exp_mask[self.frozen_rows] = jaw_articulation
        self.silhouette_subset_rows = position[silhouette_vertices]
        # constraints lost to sliding (a sliding point only constrains its normal)
        self.n_sliding = float(len(self.sliding) + np.minimum(w_all[self.silhouette_rows], 1.0).sum())
        self.contour_rows = {side: position[np.asarray(c)] for side, c in contours.items()}
        self.contour_vertex_rows = np.unique(np.concatenate(list(self.contour_rows.values())))
        # the model at the observed vertices, and the bases of the two vertex sets the slides pose at every step
        self._bases = subset_bases(model, self.subset, {"contour": self.contour_vertex_rows, "silhouette": self.silhouette_subset_rows})
        self.mean, self.id_basis, self.exp_basis = self._bases.mean, self._bases.id_basis, self._bases.exp_basis
        self._update_bases(np.zeros(model.n_exp))
        # each brow point's residual in its brow's frame: across the brow as it is, along it / brow_along_noise
        self.metric_rows = np.zeros(0, np.int64) if brow_along_noise == 1.0 else BROWS
        self.metric = np.concatenate([along_curve_metric(self.targets[row], 1.0 / brow_along_noise) for row in (BROWS[:5], BROWS[5:])]
                                     ) if len(self.metric_rows) else np.zeros((0, 2, 2))

    def _blend(self, values: np.ndarray, rows: np.ndarray | slice) -> np.ndarray:
        """(..., K, 3) per subset vertex -> (..., len(rows), 3) at the observed points."""
        b = self.bary[rows]
        r = self.rows[rows]
        return (b[:, 0, None] * values[..., r[:, 0], :] + b[:, 1, None] * values[..., r[:, 1], :]
                + b[:, 2, None] * values[..., r[:, 2], :])

    def _update_bases(self, delta: np.ndarray, rows: np.ndarray | slice = slice(None)) -> None:
        """The mean and bases at the observed points (only ``rows`` recomputed, after a slide):
        ``mean_lm`` (n, 3) with the frozen expression part of the contour points added,
        ``id_lm`` (n_id, n, 3), ``exp_lm`` (n_exp, n, 3) with the contour's mask applied."""
        if isinstance(rows, slice):
            self.mean_lm = np.zeros((self.n_points, 3))
            self.id_lm = np.zeros((self.model.n_id, self.n_points, 3))
            self.exp_lm = np.zeros((self.model.n_exp, self.n_points, 3))
        mask = self.exp_mask[rows].T[:, :, None]
        exp_full = self._blend(self.exp_basis, rows)
        frozen = (delta @ (exp_full * (1 - mask)).reshape(len(delta), -1)).reshape(-1, 3)
        self.mean_lm[rows] = self._blend(self.mean, rows) + frozen
        self.id_lm[:, rows] = self._blend(self.id_basis, rows)
        self.exp_lm[:, rows] = exp_full * mask
        self.id_flat = self.id_lm.reshape(self.model.n_id, -1)
        self.exp_flat = self.exp_lm.reshape(self.model.n_exp, -1)

    def slide_jaw(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> None:
        """Move each jaw point (but the chin) to the nearest point of its projected contour, and
        freeze the contour's expression part at ``delta``."""
        rows_all = self.contour_vertex_rows  # the contour vertices only
        shape = self._bases.shape_at("contour", alpha, delta)
        uv = np.zeros((len(self.mean), 2))
        uv[rows_all] = project(shape, rotation, translation, self.camera)
        for side, jaw_points in (("right", np.arange(0, CHIN)), ("left", np.arange(CHIN + 1, 17))):
            rows = self.contour_rows[side]
            a, b = uv[rows[:-1]], uv[rows[1:]]  # (S, 2) segment ends
            ab = b - a
            q = self.targets[jaw_points][:, None, :]  # (P, 1, 2)
            t = np.clip(((q - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)  # (P, S)
            s = np.argmin(((a + t[..., None] * ab - q) ** 2).sum(-1), axis=1)
            t_best = t[np.arange(len(jaw_points)), s]
            self.rows[jaw_points] = np.stack([rows[s], rows[s + 1], rows[s + 1]], axis=1)
            self.bary[jaw_points] = np.stack([1.0 - t_best, t_best, np.zeros_like(t_best)], axis=1)
        self._update_bases(delta, self.sliding_rows)

    def slide_silhouette(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> None:
        """Move each outline point to the nearest point of the model's projected occluding
        contour under the current pose and shape (:mod:`facegeo.fitting.silhouette`), and
        freeze its expression part (but the jaw's) at ``delta``."""
        if self.silhouette is None:
            return
        rows_all = self.silhouette_subset_rows
        shape = self._bases.shape_at("silhouette", alpha, delta)
        cam = shape @ rotation.T + translation
        picks = self.silhouette.contour(cam, rotation)
        if len(picks) < 2:
            return
        rows = rows_all[picks]
        uv = project(shape[picks], rotation, translation, self.camera)
        a, b = uv[:-1], uv[1:]
        ab = b - a
        q = self.targets[self.silhouette_rows][:, None, :]
        t = np.clip(((q - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
        s = np.argmin(((a + t[..., None] * ab - q) ** 2).sum(-1), axis=1)
        t_best = t[np.arange(len(s)), s]
        self.rows[self.silhouette_rows] = np.stack([rows[s], rows[s + 1], rows[s + 1]], axis=1)
        self.bary[self.silhouette_rows] = np.stack([1.0 - t_best, t_best, np.zeros_like(t_best)], axis=1)
        self._update_bases(delta, self.silhouette_rows)

    def slide(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> None:
        """Before a step: both slides, the jaw points (:meth:`slide_jaw`) and the outline points
        (:meth:`slide_silhouette`), and the frozen expression part of the surface points that are
        not expressive (:class:`SurfacePoints`) set to ``delta``."""
        self.slide_jaw(rotation, translation, alpha, delta)
        self.slide_silhouette(rotation, translation, alpha, delta)
        if len(self.frozen_rows):
            self._update_bases(delta, self.frozen_rows)

    def landmark_points(self, alpha: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(n, 3) model-space positions of the observed points with the current correspondences."""
        return self.mean_lm + (alpha @ self.id_flat + delta @ self.exp_flat).reshape(self.n_points, 3)

    def projected(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(n, 2) projected observed points with the current correspondences."""
        return project(self.landmark_points(alpha, delta), rotation, translation, self.camera)

    def residuals(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray) -> np.ndarray:
        """(2n,) weighted residuals in inter-ocular units; Σ r² = Σ w_i ‖r_i‖²."""
        diff = self.projected(rotation, translation, alpha, delta) - self.targets
        if len(self.metric_rows):
            diff[self.metric_rows] = (self.metric @ diff[self.metric_rows, :, None])[..., 0]
        return (diff * self.sqrt_w[:, None]).reshape(-1)

    def jacobian(self, rotation: np.ndarray, translation: np.ndarray, alpha: np.ndarray, delta: np.ndarray, n_id: int, n_exp: int,
                 t_unit: float) -> np.ndarray:
        """(2n, 6 + n_id + n_exp) Jacobian of :meth:`residuals` with respect to the update
        x = (ω, Δt / t_unit, Δα[:n_id], Δδ[:n_exp]) of R·exp([ω]×), t + t_unit·Δt, α, δ at x = 0.

        Written out (chain rule through the pinhole projection); a test checks it against
        central finite differences in float64."""
        n = self.n_points
        p_model = self.landmark_points(alpha, delta)  # (n, 3)
        dproj = pixels_jacobian(p_model @ rotation.T + translation, self.camera.focal)  # d(u, v) / d(x_c, y_c, z_c)
        to_model = dproj @ rotation  # (n, 2, 3): d(u, v) / d(model-space point)
        jac = np.empty((n, 2, 6 + n_id + n_exp))
        jac[:, :, :3] = -to_model @ cross_matrices(p_model)  # X_c = R·exp([ω]×)·X: d X_c / d ω = −R·[X]×
        jac[:, :, 3:6] = t_unit * dproj
        # stacked (2, 3) @ (3, K) products: a fifth of einsum's time (the same sums, rounded in another order)
        jac[:, :, 6 : 6 + n_id] = to_model @ self.id_lm[:n_id].transpose(1, 2, 0)
        jac[:, :, 6 + n_id :] = to_model @ self.exp_lm[:n_exp].transpose(1, 2, 0)
        if len(self.metric_rows):
            jac[self.metric_rows] = self.metric @ jac[self.metric_rows]
        jac *= self.sqrt_w[:, None, None]
        return jac.reshape(2 * n, -1)

    def correspondence(self) -> np.ndarray:
        """(88,) int64: the model vertex nearest to each (slid) landmark (the largest barycentric weight)."""
        rows = self.rows[:N_LANDMARKS]
        pick = np.argmax(self.bary[:N_LANDMARKS], axis=1)
        return self.subset[rows[np.arange(N_LANDMARKS), pick]]
