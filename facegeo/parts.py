"""Eyes and mouth interior: the model's extra parts, evaluated with a fit's α and δ, and their materials.

The bundled ICT-FaceKit model keeps only the skin of the head (``ict_face_model.npz``); its
eyeballs, eye sockets, mouth socket, gums + tongue and teeth live in a second file,
``assets/ict_facekit/ict_face_parts.npz`` (made by ``convert_ict_facekit.py --parts-output``,
documented in ``assets/ict_facekit/README.md``). The parts belong to that model only: a parts
file is used with a model when the model has the file's skin vertex count, identity count and
expression names, and the skin vertices the parts share (the lips' and eyelids' inner edges) sit
where the file recorded them (within 1e-3 mm). A model without parts (a Hifi3D++ ``.mat``, any
other ``.npz``) simply has none: :func:`load_parts` returns an empty tuple and every render and
export is skin only.

Each part is a linear model like the skin, S_p(α, δ) = S̄_p + B_id,p·α + B_exp,p·δ (mm, model
space, the skin's axes), evaluated in torch (differentiable, batched), plus the skin vertices
its triangles share, taken from :meth:`MorphableModel.shape` so the seams stay closed. Eyeballs
and teeth store identity as one affine map per connected component (tooth, eyeball) and mode.

Materials (:data:`PART_MATERIALS`, sRGB albedo, perceptual roughness, specular level with
F0 = 0.08·specular as in :mod:`facegeo.asset`): eyeballs get a procedural albedo texture in their
own UVs (:func:`eyeball_texture`: sclera, limbal ring, an iris of the colour found in the photo,
pupil); the other parts are constants.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from facegeo.asset import Asset
from facegeo.blendshapes import Blendshapes, model_blendshapes
from facegeo.errors import ModelFileError
from facegeo.morphable_model import MorphableModel, _dtype_of

if TYPE_CHECKING:  # torch is imported by shape (differentiable); the pipeline uses shape_numpy
    import torch

__all__ = [
    "PartModel",
    "load_parts",
    "part_vertices",
    "part_assets",
    "eyeball_texture",
    "PART_MATERIALS",
    "DEFAULT_IRIS_SRGB",
    "PARTS_ASSET",
    "EYEBALLS_PART",
    "eyeball_centres",
]

#: The bundled parts file, relative to ``facegeo.assets``.
PARTS_ASSET = "ict_facekit/ict_face_parts.npz"
PARTS_FORMAT_VERSION = 1

#: Iris colour used when the photo's irises cannot be found: a mid brown (sRGB), the most common
#: human iris colour.
DEFAULT_IRIS_SRGB = (0.36, 0.24, 0.15)

#: Constant materials (albedo sRGB, roughness, specular level; F0 = 0.08 × specular). Eyeballs:
#: the sclera's albedo is in the texture, the constants are those of a wet cornea (F0 ≈ 0.025 for
#: n = 1.376 → specular 0.3). Linings (eye sockets = conjunctiva, mouth socket) and gums/tongue:
#: moist mucosa, pink to dark red; the mouth socket is darker because nothing here renders the
#: occlusion that darkens it in life. Teeth: ivory enamel.
PART_MATERIALS: dict[str, dict[str, object]] = {
    "eyeballs": {"albedo": (0.92, 0.89, 0.85), "roughness": 0.12, "specular": 0.3},
    "eye_sockets": {"albedo": (0.78, 0.50, 0.47), "roughness": 0.35, "specular": 0.5},
    "mouth_socket": {"albedo": (0.36, 0.13, 0.13), "roughness": 0.45, "specular": 0.5},
    "gums_tongue": {"albedo": (0.70, 0.33, 0.35), "roughness": 0.35, "specular": 0.5},
    "teeth": {"albedo": (0.90, 0.86, 0.76), "roughness": 0.25, "specular": 0.5},
}

#: Eyeball texture radii (mm from the optical axis): pupil, iris outer edge, limbal ring outer edge.
PUPIL_RADIUS_MM = 1.8
IRIS_RADIUS_MM = 5.6
LIMBUS_RADIUS_MM = 6.2


@dataclass(eq=False)
class PartModel:
    """One part's linear model (V own vertices, K shared skin vertices, F triangles).

    Attributes:
        name: e.g. ``"teeth"``.
        mean: (V, 3) float32 mm. skin_index: (K,) int64 skin vertices appended after the own ones.
        triangles: (F, 3) int64 into the V + K vertices, counter-clockwise seen from outside (the
            linings face their cavity). uv: (T, 2) float32 in [0, 1]², origin bottom-left;
            uv_triangles: (F, 3) int64.
        id_basis: (n_id, V, 3) float32 mm per σ, or None for an affine part.
        group: (V,) int64 component of each vertex and id_affine: (n_id, G, 3, 4) float32, the
            affine part's identity: delta_v = Σ_k α_k · id_affine[k, group[v]] @ [p_v, 1].
        exp_basis: (n_exp, V, 3) float32 mm per unit weight (dense; stored sparse in the file).
        radial_mm: (V,) float32 distance from the eyeball's optical axis (eyeballs only, else None).
    """

    name: str
    mean: np.ndarray
    skin_index: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray
    uv_triangles: np.ndarray
    exp_basis: np.ndarray
    id_basis: np.ndarray | None = None
    group: np.ndarray | None = None
    id_affine: np.ndarray | None = None
    radial_mm: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        """V + K, the vertices :meth:`shape` returns."""
        return int(self.mean.shape[0] + self.skin_index.shape[0])

    def shape(self, model: MorphableModel, alpha: torch.Tensor | np.ndarray | None = None,
              delta: torch.Tensor | np.ndarray | None = None) -> torch.Tensor:
        """(..., V + K, 3) mm: the own vertices S̄_p + identity + B_exp,p·δ, then the shared skin
        vertices from ``model.shape``. Batched over the leading axes of α (..., n_id) and
        δ (..., n_exp); differentiable; dtype of the coefficients (float32 default)."""
        import torch

        dtype = _dtype_of(alpha, delta)
        out = torch.as_tensor(self.mean, dtype=dtype)
        if alpha is not None:
            a = torch.as_tensor(alpha, dtype=dtype)
            if self.id_basis is not None:
                out = out + torch.einsum("...k,kvc->...vc", a, torch.as_tensor(self.id_basis, dtype=dtype))
            else:
                maps = torch.einsum("...k,kgij->...gij", a, torch.as_tensor(self.id_affine, dtype=dtype))
                homogeneous = torch.cat([out, torch.ones(out.shape[0], 1, dtype=dtype)], dim=1)
                out = out + torch.einsum("...vij,vj->...vi", maps[..., torch.as_tensor(self.group), :, :], homogeneous)
        if delta is not None:
            d = torch.as_tensor(delta, dtype=dtype)
            out = out + torch.einsum("...k,kvc->...vc", d, torch.as_tensor(self.exp_basis, dtype=dtype))
        skin = model.shape(alpha, delta, vertex_indices=self.skin_index) if self.skin_index.size else None
        if skin is None:
            return out
        skin = skin.to(dtype)
        batch = np.broadcast_shapes(tuple(out.shape[:-2]), tuple(skin.shape[:-2]))  # torch's imports sympy (0.9 s)
        out, skin = out.expand(*batch, *out.shape[-2:]), skin.expand(*batch, *skin.shape[-2:])
        return torch.cat([out, skin], dim=-2)

    def shape_numpy(self, model: MorphableModel, alpha: np.ndarray | None = None,
                    delta: np.ndarray | None = None) -> np.ndarray:
        """The NumPy twin of :meth:`shape` for one α (n_id,) and δ (n_exp,) (None: zeros), used
        where no gradient is needed (:func:`part_vertices`, so the texture stages never import
        torch) -> (V + K, 3) float32 mm, summed in float32."""
        out = self.mean.astype(np.float32, copy=True)
        if alpha is not None:
            a = np.asarray(alpha, dtype=np.float32)
            if self.id_basis is not None:
                out += np.tensordot(a, self.id_basis.astype(np.float32, copy=False), axes=1)
            else:
                maps = np.tensordot(a, self.id_affine.astype(np.float32, copy=False), axes=1)  # (G, 3, 4)
                homogeneous = np.concatenate([out, np.ones((len(out), 1), np.float32)], axis=1)
                out += np.einsum("vij,vj->vi", maps[self.group], homogeneous)
        if delta is not None:
            out += np.tensordot(np.asarray(delta, dtype=np.float32), self.exp_basis.astype(np.float32, copy=False), axes=1)
        if not self.skin_index.size:
            return out
        return np.concatenate([out, model.shape_numpy(alpha, delta, vertex_indices=self.skin_index)])

    def expression_deltas(self, model: MorphableModel) -> np.ndarray:
        """(n_exp, V + K, 3) float32 mm per unit weight: how each expression moves the vertices
        :meth:`shape` returns (the own vertices' B_exp,p, then the shared skin vertices' rows of
        the model's B_exp), so that ``shape(α, δ) = shape(α, 0) + Σ_k δ_k · deltas[k]`` exactly."""
        return np.concatenate([self.exp_basis, model.exp_basis[:, self.skin_index]], axis=1)


def _default_parts_path() -> Path | None:
    from facegeo.assets import asset_path

    try:
        return asset_path(PARTS_ASSET)
    except FileNotFoundError:
        return None


def load_parts(model: MorphableModel, path: str | Path | None = None) -> tuple[PartModel, ...]:
    """The parts of ``model``.

    ``path`` None: the bundled ICT-FaceKit parts if ``model`` is their skin (see the module
    docstring), else none (an empty tuple). An explicit ``path`` must match the model.

    Raises:
        ModelFileError: an explicit parts file that is unreadable, malformed or made for
            another model.
    """
    explicit = path is not None
    path = Path(path) if explicit else _default_parts_path()
    if path is None:
        return ()
    try:
        with np.load(path, allow_pickle=False) as archive:
            data = {k: archive[k] for k in archive.files}
    except Exception as exc:
        raise ModelFileError(path, "file", "a readable parts .npz", f"{type(exc).__name__}: {exc}") from None
    for key in ("format_version", "part_names", "skin_vertex_count", "expression_names", "n_id"):
        if key not in data:
            raise ModelFileError(path, key, "this key in a facegeo parts .npz", "missing")
    if int(data["format_version"]) != PARTS_FORMAT_VERSION:
        raise ModelFileError(path, "format_version", str(PARTS_FORMAT_VERSION), str(data["format_version"]))
    mismatch = _mismatch(model, data)
    if mismatch is not None:
        if explicit:
            raise ModelFileError(path, mismatch[0], mismatch[1], mismatch[2])
        return ()
    parts = []
    n_exp = model.n_exp
    for name in (str(n) for n in data["part_names"]):
        p = f"{name}__"
        try:
            mean = data[p + "mean"].astype(np.float32)
            exp = np.zeros((n_exp, len(mean), 3), dtype=np.float32)
            exp[data[p + "exp_index"].astype(np.int64), data[p + "exp_vertex"].astype(np.int64)] = data[p + "exp_delta"]
            parts.append(PartModel(
                name=name, mean=mean, skin_index=data[p + "skin_index"].astype(np.int64),
                triangles=data[p + "triangles"].astype(np.int64), uv=data[p + "uv"].astype(np.float32),
                uv_triangles=data[p + "uv_triangles"].astype(np.int64), exp_basis=exp,
                id_basis=data[p + "id_basis"].astype(np.float32) if p + "id_basis" in data else None,
                group=data[p + "group"].astype(np.int64) if p + "group" in data else None,
                id_affine=data[p + "id_affine"].astype(np.float32) if p + "id_affine" in data else None,
                radial_mm=data[p + "radial_mm"].astype(np.float32) if p + "radial_mm" in data else None,
            ))
        except (KeyError, IndexError, ValueError) as exc:
            raise ModelFileError(path, f"{name}", "a complete part (mean, triangles, uv, identity, expressions)", str(exc)) from None
        part = parts[-1]
        if (part.id_basis is None) == (part.id_affine is None):
            raise ModelFileError(path, f"{p}id_basis", "either id_basis or group + id_affine", "both or neither")
        if part.triangles.min() < 0 or part.triangles.max() >= part.n_vertices:
            raise ModelFileError(path, f"{p}triangles", f"indices in [0, {part.n_vertices})", "out of range")
    return tuple(parts)


def _mismatch(model: MorphableModel, data: dict[str, np.ndarray]) -> tuple[str, str, str] | None:
    """Why the parts file does not belong to ``model`` (field, expected, found), or None."""
    if int(data["skin_vertex_count"]) != model.n_vertices:
        return "skin_vertex_count", f"the model's {model.n_vertices} vertices", str(int(data["skin_vertex_count"]))
    if int(data["n_id"]) != model.n_id:
        return "n_id", f"the model's {model.n_id} identity components", str(int(data["n_id"]))
    if [str(n) for n in data["expression_names"]] != list(model.expression_names):
        return "expression_names", "the model's expression names, in its order", f"{len(data['expression_names'])} other names"
    for name in (str(n) for n in data["part_names"]):
        index, where = data.get(f"{name}__skin_index"), data.get(f"{name}__skin_mean")
        if index is None or where is None or len(index) != len(where):
            return f"{name}__skin_index", "shared skin vertices and their positions", "missing"
        if len(index) and (index.max() >= model.n_vertices or
                           np.abs(model.mean_shape[index] - where).max() > 1e-3):
            return f"{name}__skin_mean", "the model's neutral skin at the shared vertices (1e-3 mm)", "another shape"
    return None


def part_vertices(parts: tuple[PartModel, ...], model: MorphableModel, alpha: np.ndarray | None,
                  delta: np.ndarray | None) -> dict[str, np.ndarray]:
    """Each part's (V + K, 3) float32 model-space vertices (mm) for one α, δ (e.g. a Fit's)."""
    return {p.name: p.shape_numpy(model, alpha, delta) for p in parts}


#: The part that holds both eyeballs (ICT-FaceKit's name): the one an animation turns per eye.
EYEBALLS_PART = "eyeballs"


def eyeball_centres(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation centres of the two eyeballs of an eyeballs part, mm (model space).

    ``vertices`` (V, 3): both eyeballs; a vertex at x > 0 belongs to the subject's left eye (+X
    is the subject's left, DESIGN.md "Conventions"). Each eye's centre is the least-squares
    sphere through its vertices, fitted again without the 20 % that sit farthest off that
    sphere (the cornea's bulge), so it is the globe's centre, the point an eye turns about.

    Returns:
        ``(side (V,) bool, True for the left eye; centres (2, 3) float64: left, right)``.
    Raises:
        ValueError: an eye with fewer than 4 vertices.
    """
    p = np.asarray(vertices, dtype=np.float64)
    left = p[:, 0] > 0.0
    centres = []
    for mask in (left, ~left):
        q = p[mask]
        if len(q) < 4:
            raise ValueError(f"eyeball_centres: an eye with {len(q)} vertices (at least 4 needed)")
        keep = np.ones(len(q), bool)
        for _ in range(2):
            a = np.concatenate([2.0 * q[keep], np.ones((int(keep.sum()), 1))], axis=1)
            solution = np.linalg.lstsq(a, np.sum(q[keep] ** 2, axis=1), rcond=None)[0]
            centre = solution[:3]
            radius = np.sqrt(solution[3] + centre @ centre)
            off = np.abs(np.linalg.norm(q - centre, axis=1) - radius)
            keep = off <= np.quantile(off, 0.8)
        centres.append(centre)
    return left, np.stack(centres)


def _smoothstep(edge0: float, edge1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def eyeball_texture(part: PartModel, iris_srgb: tuple[float, float, float], size: int = 256) -> np.ndarray:
    """The eyeball albedo in the part's UVs: (size, size, 3) float32 sRGB in [0, 1].

    Each texel's distance r (mm) from its eyeball's optical axis is interpolated from the
    vertices' ``radial_mm``; then pupil (r < 1.8: near black), iris (to 5.6: the given colour,
    darker towards the pupil and the rim), limbal ring (5.6–6.2: the iris colour at 35 %) and
    sclera (:data:`PART_MATERIALS` eyeballs albedo), blended over 0.15 mm.
    """
    from facegeo.uv.raster import rasterize_uv

    if part.radial_mm is None:
        raise ValueError(f"part {part.name!r} has no radial_mm (only eyeballs do)")
    raster = rasterize_uv(part.uv, part.uv_triangles, size=size, padding=size)
    corner_r = np.concatenate([part.radial_mm, np.full(len(part.skin_index), 99.0, np.float32)])[part.triangles]
    r = raster.scatter(raster.interpolate(corner_r[..., None])[:, 0], fill=99.0)
    iris = np.asarray(iris_srgb, dtype=np.float32)
    sclera = np.asarray(PART_MATERIALS["eyeballs"]["albedo"], dtype=np.float32)
    blur = 0.15
    # iris: 70 % at the pupil's collar rising to 100 % mid-way, 80 % at the rim
    iris_shade = 0.7 + 0.3 * _smoothstep(PUPIL_RADIUS_MM, 3.2, r) - 0.2 * _smoothstep(4.2, IRIS_RADIUS_MM, r)
    colour = iris * iris_shade[..., None]
    pupil = np.full(3, 0.02, np.float32)
    colour = pupil + (colour - pupil) * _smoothstep(PUPIL_RADIUS_MM - blur, PUPIL_RADIUS_MM + blur, r)[..., None]
    limbus = iris * 0.35
    colour = colour + (limbus - colour) * _smoothstep(IRIS_RADIUS_MM - blur, IRIS_RADIUS_MM + blur, r)[..., None]
    colour = colour + (sclera - colour) * _smoothstep(LIMBUS_RADIUS_MM - blur, LIMBUS_RADIUS_MM + 2 * blur, r)[..., None]
    return np.clip(colour, 0.0, 1.0).astype(np.float32)


def part_assets(parts: tuple[PartModel, ...], model: MorphableModel, alpha: np.ndarray | None,
                delta: np.ndarray | None, iris_srgb: tuple[float, float, float] = DEFAULT_IRIS_SRGB,
                texture_size: int = 256) -> list[Asset]:
    """One :class:`Asset` per part (model space, mm) with its material: eyeballs textured
    (:func:`eyeball_texture`), the others constants from :data:`PART_MATERIALS`. A part that the
    expressions move carries :class:`facegeo.blendshapes.Blendshapes` (:meth:`PartModel.expression_deltas`
    at the weights ``delta``) when the skin has them (:func:`facegeo.blendshapes.model_blendshapes`);
    ICT-FaceKit's eyeballs do not move with any expression and carry none."""
    vertices = part_vertices(parts, model, alpha, delta)
    skin_shapes = model_blendshapes(model, delta)
    out = []
    for part in parts:
        material = dict(PART_MATERIALS.get(part.name, PART_MATERIALS["mouth_socket"]))
        maps = {}
        if part.radial_mm is not None:
            maps["albedo"] = eyeball_texture(part, iris_srgb, texture_size)
            del material["albedo"]
        shapes = None
        if skin_shapes is not None:
            shapes = Blendshapes(skin_shapes.names, part.expression_deltas(model), skin_shapes.weights.copy())
            shapes = shapes if shapes.moves else None
        out.append(Asset(vertices[part.name], part.triangles, part.uv, part.uv_triangles, maps=maps,
                         constants=material, name=part.name, blendshapes=shapes))
    return out
