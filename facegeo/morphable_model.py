"""The linear 3D morphable model: S = S̄ + B_id·α + B_exp·δ and T = T̄ + B_tex·β (paper Eq. 1).

Units and axes follow DESIGN.md, "Conventions": millimetres, right-handed, +Y up, +Z out of the face (towards a
frontal camera). Coefficients are in standard-deviation units: each basis column is already scaled
by its component's standard deviation, so α ~ N(0, I) samples the model's prior. For blendshape
expression bases (ICT-FaceKit) δ is the blendshape weight, 1 = the full expression.

Files are read by :mod:`facegeo.model_files`; this module only holds and evaluates the model.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from facegeo.errors import ModelFileError
from facegeo.landmarks.scheme import N_LANDMARKS

if TYPE_CHECKING:  # torch is imported by the methods that answer in tensors: NumPy users (the fit) never load it
    import torch

__all__ = ["MorphableModel", "EXPRESSION_KINDS"]

#: What the expression coefficients δ are (see :class:`MorphableModel`).
EXPRESSION_KINDS = ("blendshape", "pca")


@dataclass(eq=False)
class MorphableModel:
    """A linear face model with face-varying UVs and an 88-point landmark correspondence.

    Attributes (V vertices, F triangles, T UV coordinates):
        mean_shape: (V, 3) float32, mm.
        id_basis: (n_id, V, 3) float32, mm per standard deviation.
        exp_basis: (n_exp, V, 3) float32, mm per unit coefficient.
        mean_albedo: (V, 3) float32, linear RGB in [0, 1].
        tex_basis: (n_tex, V, 3) float32, linear RGB per standard deviation (n_tex may be 0).
        triangles: (F, 3) int64, counter-clockwise seen from outside (normals point outwards).
        uv: (T, 2) float32 in [0, 1]², origin bottom-left.
        uv_triangles: (F, 3) int64 indices into ``uv`` (face-varying: seams allowed).
        landmark_indices: (88,) int64 vertex indices: the frontal correspondence of the
            68 iBUG points followed by the 20 lip points. Points 0..16 (the jaw, subject's right
            to left through the chin at 8) also define the contour polyline along which the
            jaw landmarks slide in fitting.
        face_mask: (V,) bool, the facial region (used for the skin mask and for errors).
        expression_names: names of the expression components (may be empty).
        expression_kind: ``"blendshape"`` (δ are blendshape weights, each valid on
            ``expression_range``, [0, 1] for ICT-FaceKit's ARKit-style shapes; the fit puts a
            magnitude and sparsity prior on them) or ``"pca"`` (δ in σ units with the Gaussian
            prior N(0, I), unbounded: Hifi3D++ and AI-NExT files).
        name: a short human-readable name; ``source``: the file it came from.
    """

    mean_shape: np.ndarray
    id_basis: np.ndarray
    exp_basis: np.ndarray
    mean_albedo: np.ndarray
    tex_basis: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    uv_triangles: np.ndarray
    landmark_indices: np.ndarray
    face_mask: np.ndarray
    expression_names: list[str] = field(default_factory=list)
    expression_kind: str = "pca"
    name: str = "model"
    source: str = "<memory>"

    def __post_init__(self) -> None:
        self.mean_shape = np.asarray(self.mean_shape, dtype=np.float32)
        self.id_basis = np.asarray(self.id_basis, dtype=np.float32)
        self.exp_basis = np.asarray(self.exp_basis, dtype=np.float32)
        self.mean_albedo = np.asarray(self.mean_albedo, dtype=np.float32)
        self.tex_basis = np.asarray(self.tex_basis, dtype=np.float32)
        self.triangles = np.asarray(self.triangles, dtype=np.int64)
        self.uv = np.asarray(self.uv, dtype=np.float32)
        self.uv_triangles = np.asarray(self.uv_triangles, dtype=np.int64)
        self.landmark_indices = np.asarray(self.landmark_indices, dtype=np.int64)
        self.face_mask = np.asarray(self.face_mask, dtype=bool)
        self._validate()
        self._torch: dict[tuple[str, object], torch.Tensor] = {}

    # ------------------------------------------------------------------ checks
    def _fail(self, field_name: str, expected: str, found: str) -> None:
        raise ModelFileError(self.source, field_name, expected, found)

    def _validate(self) -> None:
        V = self.mean_shape.shape[0] if self.mean_shape.ndim == 2 else -1
        checks = [
            ("mean_shape", self.mean_shape, (V, 3)),
            ("id_basis", self.id_basis, (None, V, 3)),
            ("exp_basis", self.exp_basis, (None, V, 3)),
            ("mean_albedo", self.mean_albedo, (V, 3)),
            ("tex_basis", self.tex_basis, (None, V, 3)),
            ("triangles", self.triangles, (None, 3)),
            ("uv", self.uv, (None, 2)),
            ("uv_triangles", self.uv_triangles, (self.triangles.shape[0], 3)),
            ("landmark_indices", self.landmark_indices, (N_LANDMARKS,)),
            ("face_mask", self.face_mask, (V,)),
        ]
        if V <= 0:
            self._fail("mean_shape", "an array of shape (V, 3) with V > 0", str(self.mean_shape.shape))
        for name, array, shape in checks:
            ok = array.ndim == len(shape) and all(s is None or s == a for s, a in zip(shape, array.shape))
            if not ok:
                wanted = "(" + ", ".join("*" if s is None else str(s) for s in shape) + ")"
                self._fail(name, f"shape {wanted}", str(tuple(array.shape)))
            if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
                self._fail(name, "finite values", f"{int(np.sum(~np.isfinite(array)))} NaN/inf entries")
        for name, array, bound in [
            ("triangles", self.triangles, V),
            ("uv_triangles", self.uv_triangles, self.uv.shape[0]),
            ("landmark_indices", self.landmark_indices, V),
        ]:
            if array.size and (array.min() < 0 or array.max() >= bound):
                self._fail(name, f"indices in [0, {bound})", f"range [{array.min()}, {array.max()}]")
        if self.triangles.shape[0] == 0:
            self._fail("triangles", "at least one triangle", "none")
        if self.expression_names and len(self.expression_names) != self.n_exp:
            self._fail("expression_names", f"{self.n_exp} names", str(len(self.expression_names)))
        if self.expression_kind not in EXPRESSION_KINDS:
            self._fail("expression_kind", f"one of {', '.join(EXPRESSION_KINDS)}", repr(self.expression_kind))

    # ------------------------------------------------------------------ sizes
    @property
    def n_vertices(self) -> int:
        """V, the number of vertices."""
        return int(self.mean_shape.shape[0])

    @property
    def n_id(self) -> int:
        """Number of identity components (read from the file)."""
        return int(self.id_basis.shape[0])

    @property
    def n_exp(self) -> int:
        """Number of expression components (read from the file)."""
        return int(self.exp_basis.shape[0])

    @property
    def expression_range(self) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper): (n_exp,) float32 bounds of each expression coefficient: [0, 1] for
        blendshape weights, (−inf, inf) for PCA coefficients in σ units."""
        if self.expression_kind == "blendshape":
            return np.zeros(self.n_exp, np.float32), np.ones(self.n_exp, np.float32)
        return np.full(self.n_exp, -np.inf, np.float32), np.full(self.n_exp, np.inf, np.float32)

    @property
    def n_tex(self) -> int:
        """Number of texture components (0 when the model has a mean albedo only)."""
        return int(self.tex_basis.shape[0])

    # ------------------------------------------------------------------ evaluation
    def tensor(self, name: str, dtype: torch.dtype | None = None) -> torch.Tensor:
        """The array attribute ``name`` as a cached CPU torch tensor of ``dtype`` (default float32)."""
        import torch

        dtype = torch.float32 if dtype is None else dtype
        key = (name, dtype)
        if key not in self._torch:
            array = np.ascontiguousarray(getattr(self, name))
            if not array.flags.writeable:  # the default model's arrays are memory-mapped read-only (layout cache): torch wants its own
                array = array.copy()
            self._torch[key] = torch.from_numpy(array).to(dtype)
        return self._torch[key]

    def shape(
        self,
        alpha: torch.Tensor | np.ndarray | None = None,
        delta: torch.Tensor | np.ndarray | None = None,
        vertex_indices: torch.Tensor | np.ndarray | None = None,
    ) -> torch.Tensor:
        """S(α, δ) = S̄ + B_id·α + B_exp·δ, batched and differentiable.

        Args:
            alpha: (..., n_id) identity coefficients (σ units), or None for zeros.
            delta: (..., n_exp) expression coefficients, or None for zeros.
            vertex_indices: optional (K,) int64 subset of vertices to evaluate (cheap for
                landmark fitting).
        Returns:
            (..., V, 3) or (..., K, 3) tensor in mm, dtype of the coefficients (float32 default).
        """
        import torch

        dtype = _dtype_of(alpha, delta)
        mean = self.tensor("mean_shape", dtype)
        id_basis = self.tensor("id_basis", dtype)
        exp_basis = self.tensor("exp_basis", dtype)
        if vertex_indices is not None:
            idx = torch.as_tensor(vertex_indices, dtype=torch.long)
            mean, id_basis, exp_basis = mean[idx], id_basis[:, idx], exp_basis[:, idx]
        out = mean
        if alpha is not None:
            alpha = _coefficients(alpha, self.n_id, "alpha", dtype)
            out = out + torch.einsum("...k,kvc->...vc", alpha, id_basis)
        if delta is not None:
            delta = _coefficients(delta, self.n_exp, "delta", dtype)
            out = out + torch.einsum("...k,kvc->...vc", delta, exp_basis)
        return out

    def shape_numpy(self, alpha: np.ndarray | None = None, delta: np.ndarray | None = None,
                    vertex_indices: np.ndarray | None = None) -> np.ndarray:
        """The NumPy twin of :meth:`shape` for callers that need no gradient (the landmark fit,
        the texture stages and the parts, which then never import torch): (n_id,) α and
        (n_exp,) δ (None: zeros), optional (K,) int ``vertex_indices`` -> (V, 3) or (K, 3)
        float32 mm, summed in float32 like :meth:`shape`."""
        rows = slice(None) if vertex_indices is None else np.asarray(vertex_indices, dtype=np.int64)
        out = self.mean_shape[rows].copy()
        for name, value, basis, n in (("alpha", alpha, self.id_basis, self.n_id), ("delta", delta, self.exp_basis, self.n_exp)):
            if value is None:
                continue
            value = np.asarray(value, dtype=np.float32)
            if value.shape != (n,):
                raise ValueError(f"{name}: expected shape ({n},), got {value.shape}")
            out += np.tensordot(value, basis[:, rows], axes=1)
        return out

    def albedo(self, beta: torch.Tensor | np.ndarray | None = None) -> torch.Tensor:
        """T(β) = T̄ + B_tex·β: (..., V, 3) linear RGB, not clamped; β is (..., n_tex)."""
        import torch

        dtype = _dtype_of(beta)
        out = self.tensor("mean_albedo", dtype)
        if beta is not None and self.n_tex > 0:
            beta = _coefficients(beta, self.n_tex, "beta", dtype)
            out = out + torch.einsum("...k,kvc->...vc", beta, self.tensor("tex_basis", dtype))
        elif beta is not None:
            beta = torch.as_tensor(beta, dtype=dtype)
            out = out.expand(*beta.shape[:-1], *out.shape)
        return out

    def albedo_numpy(self, beta: np.ndarray | None = None) -> np.ndarray:
        """The NumPy twin of :meth:`albedo` (the texture stages use it without importing torch):
        (n_tex,) β (None: zeros) -> (V, 3) float32 linear RGB, not clamped."""
        out = self.mean_albedo.astype(np.float32, copy=True)
        if beta is not None and self.n_tex > 0:
            beta = np.asarray(beta, dtype=np.float32)
            if beta.shape != (self.n_tex,):
                raise ValueError(f"beta: expected shape ({self.n_tex},), got {beta.shape}")
            out += np.tensordot(beta, self.tex_basis, axes=1)
        return out

    def vertex_normals(self, vertices: torch.Tensor) -> torch.Tensor:
        """Unit vertex normals of (..., V, 3) vertices on the model's triangles -> (..., V, 3),
        differentiable (:func:`facegeo.normals.vertex_normals_torch`)."""
        import torch

        from facegeo.normals import vertex_normals_torch

        return vertex_normals_torch(vertices, self.tensor("triangles", torch.long))


def _dtype_of(*tensors: object) -> torch.dtype:
    import torch

    for t in tensors:
        if isinstance(t, torch.Tensor) and t.is_floating_point():
            return t.dtype
        if isinstance(t, np.ndarray) and t.dtype == np.float64:
            return torch.float64
    return torch.float32


def _coefficients(value: torch.Tensor | np.ndarray, n: int, name: str, dtype: torch.dtype) -> torch.Tensor:
    import torch

    value = torch.as_tensor(value, dtype=dtype)
    if value.shape[-1:] != (n,):
        raise ValueError(f"{name}: expected shape (..., {n}), got {tuple(value.shape)}")
    return value
