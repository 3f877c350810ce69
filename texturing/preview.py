"""The relit preview (``preview.png`` of ``facegeo reconstruct``): the photo beside the asset seen
from the front, three-quarter and profile, shaded with the project's GGX shader (in NumPy,
:func:`facegeo.texturing.ggx.ggx_shaded`: the command never imports torch) and as grey clay, so
the 3-D shape shows at a glance.

It lives beside the shader it uses; :func:`facegeo.jobs.reconstruct_into_folder` writes it.
"""

from __future__ import annotations

import cv2
import numpy as np

from facegeo.asset import Asset
from facegeo.camera import Camera, rotation_from_euler
from facegeo.colour import linear_to_srgb, srgb_to_linear
from facegeo.fitting import Fit
from facegeo.landmarks.scheme import IBUG68
from facegeo.normals import vertex_normals
from facegeo.photo import as_rgb_uint8
from facegeo.texturing.backend import SKIN_CONSTANTS
from facegeo.texturing.ggx import ggx_shaded
from facegeo.uv.renderer import rasterize_mesh
from facegeo.uv.tangents import mesh_tangents
from facegeo.uv.texels import sample_uv

__all__ = ["relit_preview", "PreviewViews", "clip_preview", "posed_asset", "PREVIEW_VIEWS", "PREVIEW_LIGHTS", "PREVIEW_AMBIENT", "CLAY", "PREVIEW_BACKGROUND"]


#: The preview's views: yaw in degrees (rotation_from_euler's convention: positive turns the nose
#: to the viewer's right and shows the subject's right side).
PREVIEW_VIEWS = (("front", 0.0), ("three-quarter", 40.0), ("profile", 90.0))
#: Lights of the preview in camera space (towards the light; linear radiance) and the ambient
#: term: a key light from the upper left, a weaker fill from the right.
PREVIEW_LIGHTS = (((-0.5, 0.55, 0.65), 2.0), ((0.75, 0.1, 0.45), 0.6))
PREVIEW_AMBIENT = 0.15
#: Clay: linear grey albedo, roughness and specular level.
CLAY = (0.45, 0.6, 0.25)
#: Background of the rendered panels (sRGB).
PREVIEW_BACKGROUND = 0.12


def relit_preview(photo: np.ndarray, asset: Asset, fit_result: Fit, *, panel: int = 256) -> np.ndarray:
    """The photo beside the asset from the front, three-quarter and profile: textured and relit
    (top row) and as clay (bottom row), parts (eyes, mouth interior) included.

    The photo panel is the (2·panel)² square around the detected landmarks. Each view is a
    virtual camera (perspective, 800 mm away, framing the skin's face region) around the
    model-space asset; the meshes are rasterised with :func:`facegeo.uv.rasterize_mesh` and each
    pixel is shaded with the project's GGX shader (:func:`ggx_shaded`, deferred: the per-pixel
    position, normal, MikkTSpace tangent, albedo, normal map, roughness and specular) under
    :data:`PREVIEW_LIGHTS`; clay uses :data:`CLAY` and no normal map. Returns
    (2·panel, 5·panel, 3) uint8 sRGB. (:class:`PreviewViews` and its :meth:`~PreviewViews.render`:
    the same in two halves, the first before the maps exist.)
    """
    return PreviewViews(asset, photo, fit_result.landmarks[IBUG68], panel=panel).render(asset)


class PreviewViews:
    """:func:`relit_preview` in two halves: what needs no maps, made here from the asset's geometry
    (the photo panel, the scene's corners and each view's rasterisation and interpolated position,
    normal and UV: ``facegeo reconstruct`` makes it while the texture stages run), then
    :meth:`render` with the maps.

    Args:
        geometry: the asset (its maps, constants and metadata are not read here, but for the
            parts' maps, which it has).
        photo: (H, W, 3) uint8 RGB photo.
        landmarks: (68, 2) px iBUG points of the fit (non-finite rows ignored).
        panel: the side of one view, px.
        skin_maps: the map names the skin will have (its normal map decides its tangents);
            default: those ``geometry`` has. A different set at :meth:`render` is handled there.
    """

    def __init__(self, geometry: Asset, photo: np.ndarray, landmarks: np.ndarray, *, panel: int = 256,
                 skin_maps: frozenset[str] | None = None):
        self.panel = p = int(panel)
        self.scene = scene = _PreviewScene(geometry, skin_maps)
        self.shots = []
        for _, yaw in PREVIEW_VIEWS:
            rotation = rotation_from_euler(yaw, 0.0, 0.0)
            distance = 800.0
            focal = 0.5 * p * (distance - scene.radius) / (1.05 * scene.radius)
            self.shots.append(scene.shot((scene.vertices - scene.centre) @ rotation.T + [0.0, 0.0, -distance], rotation,
                                         Camera(focal, p / 2.0, p / 2.0, p, p)))
        points = np.asarray(landmarks, np.float64)
        points = points[np.all(np.isfinite(points), axis=1)]
        lo, hi = points.min(axis=0), points.max(axis=0)
        centre, half = (lo + hi) / 2.0, 0.75 * float(np.max(hi - lo))
        side = 2 * p
        scale = side / (2.0 * half)
        warp = np.array([[scale, 0.0, side / 2.0 - scale * centre[0]], [0.0, scale, side / 2.0 - scale * centre[1]]])
        self.photo_panel = cv2.warpAffine(as_rgb_uint8(photo), warp, (side, side), flags=cv2.INTER_AREA, borderMode=cv2.BORDER_REPLICATE)

    def render(self, asset: Asset) -> np.ndarray:
        """(2·panel, 5·panel, 3) uint8 sRGB: the preview of ``asset``, the geometry's asset with its
        maps and constants (same vertices, triangles and parts)."""
        p = self.panel
        self.scene.dress(asset)
        columns = [np.where(covered[None, ..., None], shaded, np.float32(PREVIEW_BACKGROUND)).reshape(2 * p, p, 3)
                   for covered, shaded in _shaded_views(self.shots)]
        views = (np.concatenate(columns, axis=1) * 255.0).round().clip(0, 255).astype(np.uint8)
        return np.concatenate([self.photo_panel, views], axis=1)


def _shaded_views(shots: list["_Shot"]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each shot (:meth:`_PreviewScene.shot`, its scene dressed) shaded textured and as clay under
    :data:`PREVIEW_LIGHTS`, all views' covered pixels in one call of :func:`ggx_shaded`. Returns
    per view (covered (H, W) bool, (2, H, W, 3) float32 sRGB: textured, clay; 0 where not covered)."""
    lights = np.array([d for d, _ in PREVIEW_LIGHTS], np.float32)
    radiance = np.array([[r, r, r] for _, r in PREVIEW_LIGHTS], np.float32)
    buffers = [shot.buffers() for shot in shots]
    # (2, N, C) materials over (1, N, C) geometry
    inputs = [np.concatenate(column, axis=-2) for column in zip(*buffers)]
    shaded = ggx_shaded(*inputs, lights, radiance, np.zeros(3, np.float32), PREVIEW_AMBIENT)
    pixels = linear_to_srgb(shaded.clip(0.0, None))  # (2, N, 3)
    out, start = [], 0
    for shot in shots:
        covered = shot.covered
        idx = np.flatnonzero(covered.ravel())
        image = np.zeros((2, covered.size, 3), np.float32)
        image[:, idx] = pixels[:, start:start + len(idx)]
        start += len(idx)
        out.append((covered, image.reshape(2, *covered.shape, 3)))
    return out


def posed_asset(asset: Asset, weights: dict[str, float]) -> Asset:
    """``asset`` with its skin and parts at the expression ``weights`` (blendshape name -> weight;
    shapes not named are at 0) instead of the fitted ones: neutral + Σ w·deltas
    (:class:`facegeo.blendshapes.Blendshapes`). Surfaces without blendshapes stay as they are."""
    import dataclasses

    def pose(surface: Asset) -> Asset:
        shapes = surface.blendshapes
        if shapes is None:
            return surface
        w = np.array([weights.get(name, 0.0) for name in shapes.names], np.float64)
        return dataclasses.replace(surface, vertices=(surface.neutral_vertices() + shapes.offset(w)).astype(np.float32))

    return dataclasses.replace(pose(asset), parts=[pose(part) for part in asset.parts])


def clip_preview(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, float], np.ndarray]], asset: Asset,
                 camera: Camera, *, panel: int = 212) -> np.ndarray:
    """A tracked clip's frames beside the asset posed as tracked on each (``facegeo track``'s
    ``preview.png``): one column a frame, (image (H, W, 3) uint8 RGB, rotation (3, 3) and
    translation (3,) mm of the head (model to camera), expression weights by blendshape name, the
    face's landmarks (K, 2) px that frame it), seen by the clip's ``camera``: the frame around the
    face on top, then the asset drawn over it textured and relit (:data:`PREVIEW_LIGHTS`), then as
    clay. Each panel is the square around the landmarks, 1.5 × their extent (as
    :func:`relit_preview` frames the photo). Returns (3·panel, len(frames)·panel, 3) uint8 sRGB."""
    p = int(panel)
    shots, backgrounds = [], []
    for image, rotation, translation, weights, landmarks in frames:
        posed = posed_asset(asset, weights)
        scene = _PreviewScene(posed).dress(posed)
        rotation, translation = np.asarray(rotation, np.float64), np.asarray(translation, np.float64)
        cam_vertices = scene.vertices @ rotation.T + translation
        points = np.asarray(landmarks, np.float64)
        points = points[np.all(np.isfinite(points), axis=1)]
        centre, side = (points.min(axis=0) + points.max(axis=0)) / 2.0, 1.5 * float(np.max(points.max(axis=0) - points.min(axis=0)))
        scale = p / side
        x0, y0 = centre - side / 2.0
        shots.append(scene.shot(cam_vertices, rotation, Camera(camera.focal * scale, (camera.cx - x0) * scale, (camera.cy - y0) * scale, p, p)))
        warp = np.array([[scale, 0.0, -x0 * scale], [0.0, scale, -y0 * scale]])
        backgrounds.append(cv2.warpAffine(as_rgb_uint8(image), warp, (p, p), flags=cv2.INTER_AREA,
                                          borderMode=cv2.BORDER_CONSTANT).astype(np.float32) / 255.0)
    columns = []
    for (covered, shaded), frame in zip(_shaded_views(shots), backgrounds):
        drawn = np.where(covered[None, ..., None], shaded, frame[None])
        columns.append(np.concatenate([frame, drawn[0], drawn[1]], axis=0))
    return (np.concatenate(columns, axis=1) * 255.0).round().clip(0, 255).astype(np.uint8)


class _PreviewScene:
    """The skin and its parts as one triangle soup for the preview, with per-corner UVs, normals
    and tangents (made from the geometry), and per-surface materials (linear albedo, normal map,
    roughness, specular: :meth:`dress`, from the asset with its maps). ``skin_maps``: the map
    names the skin will have, where its asset has none yet (its normal map decides its tangents);
    default: the asset's own."""

    def __init__(self, asset: Asset, skin_maps: frozenset[str] | None = None):
        surfaces = [asset, *asset.parts]
        # framing: the skin's face region
        face = asset.triangles if asset.face_triangles is None else asset.triangles[asset.face_triangles]
        head = asset.vertices[np.unique(face)]
        self.centre = (head.min(axis=0) + head.max(axis=0)) / 2.0
        #: the largest half-extent of the head seen from any preview view (x and y after the yaw)
        self.radius = max(float(np.abs(((head - self.centre) @ rotation_from_euler(yaw, 0.0, 0.0).T)[:, :2]).max())
                          for _, yaw in PREVIEW_VIEWS)
        verts, tris, corner_uv, corner_n, surface = [], [], [], [], []
        self._surfaces = surfaces
        self._normals: list[np.ndarray] = []
        self._tangents: dict[tuple[int, bool], np.ndarray] = {}  # (surface, normal-mapped) -> corner tangents (T, 3, 3)
        offset = 0
        for k, s in enumerate(surfaces):
            normals = vertex_normals(s.vertices, s.triangles)
            self._normals.append(normals)
            self._surface_tangents(k, "normal" in (s.maps if k or skin_maps is None else skin_maps))
            verts.append(s.vertices)
            tris.append(s.triangles + offset)
            corner_uv.append(s.uv[s.uv_triangles])
            corner_n.append(normals[s.triangles])
            surface.append(np.full(len(s.triangles), k))
            offset += len(s.vertices)
        self.vertices = np.concatenate(verts).astype(np.float64)
        self.triangles = np.concatenate(tris)
        self.corner_uv = np.concatenate(corner_uv).astype(np.float32)
        self.corner_normal = np.concatenate(corner_n).astype(np.float32)
        self.surface = np.concatenate(surface)
        self.corner_tangent: np.ndarray | None = None
        self.materials: list[dict[str, np.ndarray]] | None = None

    def _surface_tangents(self, k: int, normal_mapped: bool) -> np.ndarray:
        """Corner tangents (T_k, 3, 3) of surface ``k``: MikkTSpace's where it has a normal map,
        else any tangent perpendicular to the normal (it shades the same); made once each."""
        key = (k, normal_mapped)
        if key not in self._tangents:
            s, normals = self._surfaces[k], self._normals[k]
            if normal_mapped:
                tangents = mesh_tangents(s.vertices, s.triangles, s.uv, s.uv_triangles, normals.astype(np.float32))[..., :3]
            else:
                helper = np.where(np.abs(normals[:, 1:2]) < 0.9, [[0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0]])
                tangents = np.cross(helper, normals)[s.triangles]
            self._tangents[key] = tangents
        return self._tangents[key]

    def dress(self, asset: Asset) -> "_PreviewScene":
        """The materials of ``asset`` (this scene's geometry with its maps and constants) and the
        tangents its normal maps call for; returns this scene."""
        surfaces = [asset, *asset.parts]
        self.corner_tangent = np.concatenate([self._surface_tangents(k, "normal" in s.maps)
                                              for k, s in enumerate(surfaces)]).astype(np.float32)
        self.materials = [self._material(s) for s in surfaces]
        return self

    def shot(self, cam_vertices: np.ndarray, rotation: np.ndarray, camera: Camera) -> "_Shot":
        """One view: camera-space vertices (V, 3) mm, the rotation (3, 3) that took the model's
        normals there, the view's camera; rasterised here."""
        tri, bary, _ = rasterize_mesh(cam_vertices, self.triangles, camera)
        return _Shot(self, tri, bary, cam_vertices, rotation)

    @staticmethod
    def _material(s: Asset) -> dict[str, np.ndarray]:
        def value(name: str, default: float | tuple[float, ...]) -> np.ndarray:
            if name in s.maps:
                return s.maps[name]
            return np.asarray(s.constants.get(name, default), np.float32)

        return {"albedo": srgb_to_linear(value("albedo", 0.5)), "normal": value("normal", (0.0, 0.0, 1.0)),
                "roughness": value("roughness", SKIN_CONSTANTS["roughness"]),
                "specular": value("specular", SKIN_CONSTANTS["specular"])}


class _Shot:
    """One rasterised view of a :class:`_PreviewScene`: its covered pixels (row-major) and their
    camera-space position, normal and UV, interpolated once; :meth:`buffers` adds the tangent and
    the materials of the scene as dressed."""

    def __init__(self, scene: _PreviewScene, tri: np.ndarray, bary: np.ndarray, cam_vertices: np.ndarray, rotation: np.ndarray):
        self.scene, self.rotation = scene, rotation
        self.covered = tri >= 0
        idx = np.flatnonzero(tri.ravel() >= 0)
        self._t = tri.ravel()[idx]
        self._b = bary.reshape(-1, 3)[idx]
        self.position = self._interpolate(cam_vertices[scene.triangles].astype(np.float32))
        self.normal = self._interpolate(scene.corner_normal) @ rotation.T.astype(np.float32)
        self.uv = self._interpolate(scene.corner_uv)

    def _interpolate(self, corner: np.ndarray) -> np.ndarray:
        return np.einsum("nk,nkc->nc", self._b, corner[self._t])

    def buffers(self) -> list[np.ndarray]:
        """:func:`ggx_shaded`'s per-pixel inputs for the covered pixels: albedo, normal map,
        roughness, specular as (2, N, C) float32 (textured, clay), then position, normal, tangent
        as (1, N, 3) float32 (the geometry both share)."""
        scene, n = self.scene, len(self._t)
        if scene.materials is None or scene.corner_tangent is None:
            raise ValueError("_Shot.buffers: dress the scene with the asset's maps first")
        tangent = self._interpolate(scene.corner_tangent) @ self.rotation.T.astype(np.float32)
        uv = self.uv
        values = {"albedo": np.zeros((n, 3), np.float32), "normal": np.zeros((n, 3), np.float32),
                  "roughness": np.zeros((n, 1), np.float32), "specular": np.zeros((n, 1), np.float32)}
        surface = scene.surface[self._t]
        for k, material in enumerate(scene.materials):
            sel = surface == k
            if not sel.any():
                continue
            for name, array in material.items():
                if array.ndim >= 2:
                    values[name][sel] = sample_uv(array, uv[sel]).reshape(int(sel.sum()), -1)
                else:
                    values[name][sel] = array.reshape(1, -1)

        def pair(textured: np.ndarray, clay: np.ndarray | float) -> np.ndarray:
            out = np.empty((2, n, textured.shape[1]), np.float32)
            out[0], out[1] = textured, clay
            return out

        clay_albedo, clay_roughness, clay_specular = CLAY
        return [pair(values["albedo"], clay_albedo), pair(values["normal"], np.array([0.0, 0.0, 1.0], np.float32)),
                pair(values["roughness"], clay_roughness), pair(values["specular"], clay_specular),
                *(np.asarray(a, np.float32)[None] for a in (self.position, self.normal, tangent))]
