"""Expression blendshapes that travel with an :class:`~facegeo.asset.Asset`, so that the exporters
can write an animatable face (glTF morph targets, UsdSkel blend shapes; issue 28).

A surface with blendshapes is linear in the expression weights: the mesh at weights w is
``neutral + Σ_k w_k · deltas[k]``, and the asset's own vertices are the mesh at the fitted weights
(the photo's expression). Identity is not a blendshape: it stays in the neutral mesh. For the
bundled ICT-FaceKit model this is exact for the skin (S = S̄ + B_id·α + B_exp·δ) and for every
part (:meth:`facegeo.parts.PartModel.shape` adds B_exp,p·δ to the identity-posed part; the skin
vertices a part shares move with the skin's deltas).

Only blendshape models have them (``MorphableModel.expression_kind == "blendshape"`` with
names): PCA expression components (Hifi3D++, AI-NExT) are not shapes an animator can drive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeo.errors import InputError

__all__ = ["Blendshapes", "model_blendshapes"]


@dataclass(eq=False)
class Blendshapes:
    """The blendshapes of one surface (K shapes, V vertices).

    Attributes:
        names: (K,) the model's expression names (ICT-FaceKit's ``eyeBlink_L``, ``jawOpen``, ...).
        deltas: (K, V, 3) float32 mm per unit weight, the displacement of each vertex by each shape.
        weights: (K,) float32, the fitted weights (δ) at which the surface's vertices are posed.
    """

    names: tuple[str, ...]
    deltas: np.ndarray
    weights: np.ndarray

    def __post_init__(self) -> None:
        self.names = tuple(str(n) for n in self.names)
        self.deltas = np.ascontiguousarray(self.deltas, dtype=np.float32)
        self.weights = np.ascontiguousarray(self.weights, dtype=np.float32).reshape(-1)

    def validate(self, source: str, n_vertices: int) -> None:
        """Raise :class:`InputError` for shapes that disagree (K names, (K, n_vertices, 3) deltas,
        (K,) weights), repeated names or non-finite values."""
        k = len(self.names)
        if k == 0 or len(set(self.names)) != k:
            raise InputError(source, "blendshapes.names", "one or more distinct names", f"{k} names, {len(set(self.names))} distinct")
        if self.deltas.shape != (k, n_vertices, 3):
            raise InputError(source, "blendshapes.deltas", f"shape ({k}, {n_vertices}, 3)", str(self.deltas.shape))
        if self.weights.shape != (k,):
            raise InputError(source, "blendshapes.weights", f"shape ({k},)", str(self.weights.shape))
        for name, array in (("deltas", self.deltas), ("weights", self.weights)):
            if not np.all(np.isfinite(array)):
                raise InputError(source, f"blendshapes.{name}", "finite values", "NaN/inf")

    def offset(self, weights: np.ndarray | None = None) -> np.ndarray:
        """(V, 3) float64 mm: Σ_k w_k · deltas[k] for ``weights`` (K,) (default: the fitted ones)."""
        w = self.weights if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape != (len(self.names),):
            raise InputError("<blendshapes>", "weights", f"shape ({len(self.names)},)", str(w.shape))
        return np.tensordot(w.astype(np.float64), self.deltas.astype(np.float64), axes=1)

    def subset(self, vertex_indices: np.ndarray) -> "Blendshapes":
        """The same shapes on the vertices ``vertex_indices`` (e.g. a compacted face region)."""
        return Blendshapes(self.names, self.deltas[:, np.asarray(vertex_indices)], self.weights.copy())

    @property
    def moves(self) -> bool:
        """Whether any shape moves any vertex (the eyeballs of ICT-FaceKit do not)."""
        return bool(np.any(self.deltas))


def model_blendshapes(model: object, delta: np.ndarray | None) -> Blendshapes | None:
    """The skin's :class:`Blendshapes` of a :class:`facegeo.MorphableModel` at the fitted
    ``delta`` (n_exp,), or None when the model's expressions are not named blendshapes."""
    names = list(getattr(model, "expression_names", []) or [])
    if getattr(model, "expression_kind", "pca") != "blendshape" or not names:
        return None
    weights = np.zeros(len(names), np.float32) if delta is None else np.asarray(delta, dtype=np.float32)
    return Blendshapes(tuple(names), model.exp_basis, weights)  # type: ignore[attr-defined]
