"""A z-buffer rasteriser of a textured (or vertex-coloured) mesh into the image: the inverse of
:func:`facegeo.uv.unwrap`, used by its depth test, for round-trip tests and for overlays.

Camera and pixels as in :mod:`facegeo.camera`: camera space, mm, looking down −Z; the image
samples the scene at pixel centres (i + 0.5, j + 0.5), one sample per pixel (no anti-aliasing).
Both faces of every triangle are drawn (the nearest surface wins, whatever its orientation);
triangles with a corner closer than ``near`` mm to the camera plane, or behind it, are skipped
(there is no clipping). Barycentric coordinates are perspective-correct; ``depth`` is the
distance along −Z in mm.

Textures are sampled bilinearly at the interpolated UV (texel centres at ((j + 0.5)/S,
1 − (i + 0.5)/S), row 0 = top, DESIGN.md, "Conventions"), with edge texels repeated beyond the border; the
values are used as given (pass sRGB to get sRGB pixels, linear to get linear ones).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeo.camera import Camera, to_pixels
from facegeo.errors import InputError
from facegeo.uv._triangles import triangle_fragments
from facegeo.uv.texels import sample_uv

__all__ = ["Rendering", "light_visibility", "rasterize_mesh", "render", "sky_visibility", "sphere_directions"]

#: Default near distance in mm: triangles with a corner closer to the camera plane are skipped.
NEAR_MM = 1.0
#: :func:`light_visibility`'s light camera stands this far (mm) beyond the mesh along the light:
#: a pinhole so far away is a directional light (its rays diverge by < 0.2° over a head).
LIGHT_DISTANCE_MM = 1e5
#: :func:`sky_visibility`'s rays start this far (mm) off the surface along its normal, so that a
#: ray does not hit the triangles around its own vertex.
SKY_OFFSET_MM = 0.5


@dataclass(frozen=True, eq=False)
class Rendering:
    """A rendered view.

    Attributes:
        image: (H, W, C) float32 colours (``background`` where ``mask`` is False), or None when
            neither a texture nor colours were given.
        depth: (H, W) float32 distance along −Z in mm (inf on the background).
        triangle: (H, W) int32 index of the visible triangle (−1 on the background).
        barycentric: (H, W, 3) float32 perspective-correct barycentric coordinates.
        uv: (H, W, 2) float32 interpolated UV coordinates (0 on the background), or None for a
            mesh rendered without UVs.
        mask: (H, W) bool, pixels covered by the mesh.
    """

    image: np.ndarray | None
    depth: np.ndarray
    triangle: np.ndarray
    barycentric: np.ndarray
    uv: np.ndarray | None
    mask: np.ndarray


def rasterize_mesh(vertices_cam: np.ndarray, triangles: np.ndarray, camera: Camera, near: float = NEAR_MM,
                   barycentric: bool = True) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """The z-buffer: per pixel the nearest triangle, its perspective-correct barycentrics and depth.

    Args:
        vertices_cam: (V, 3) camera-space positions, mm. triangles: (F, 3) int.
        camera: intrinsics and image size.
        near: triangles with a corner at depth < ``near`` mm are skipped.
        barycentric: also return the barycentric buffer (else None; a little faster).
    Returns:
        ``(triangle (H, W) int32, barycentric (H, W, 3) float32, depth (H, W) float32)``; −1,
        zeros and inf on the background. Ties in depth go to the triangle drawn last.
    """
    v = np.asarray(vertices_cam, dtype=np.float64)
    tri = np.asarray(triangles, dtype=np.int64)
    W, H = camera.width, camera.height
    depth_v = -v[:, 2]
    ok = np.flatnonzero((depth_v[tri] >= near).all(axis=1) & np.isfinite(depth_v[tri]).all(axis=1))
    pts = to_pixels(v, camera)[tri[ok]]  # (F', 3, 2)
    inv_d = 1.0 / depth_v[tri[ok]]  # (F', 3)
    zbuf = np.full(H * W, np.inf)
    tbuf = np.full(H * W, -1, dtype=np.int32)
    bbuf = np.zeros((H * W, 3), dtype=np.float32) if barycentric else None
    for pix, t, lam in triangle_fragments(pts, W, H):
        w = lam * inv_d[t]  # perspective-correct weights
        s = w[:, 0] + w[:, 1] + w[:, 2]
        d = 1.0 / s
        np.minimum.at(zbuf, pix, d)
        win = d <= zbuf[pix]
        pix, t = pix[win], t[win]
        tbuf[pix] = ok[t]
        if bbuf is not None:
            bbuf[pix] = w[win] / s[win, None]
    return (tbuf.reshape(H, W), None if bbuf is None else bbuf.reshape(H, W, 3),
            zbuf.astype(np.float32).reshape(H, W))


def render(vertices_cam: np.ndarray, model, camera: Camera, texture: np.ndarray | None = None,
           colours: np.ndarray | None = None, *, background: float | tuple[float, ...] = 0.0,
           near: float = NEAR_MM) -> Rendering:
    """Render a mesh into the camera's image with a z-buffer.

    Args:
        vertices_cam: (V, 3) camera-space vertex positions, mm (e.g. ``fit.vertices``).
        model: the :class:`facegeo.MorphableModel` (``triangles``, ``uv``, ``uv_triangles``).
        camera: intrinsics and image size.
        texture: (S, S, C) UV-space map (uint8 is scaled to [0, 1]), sampled bilinearly.
        colours: (V, C) per-vertex colours, interpolated (used when no texture is given).
        background: colour of uncovered pixels.
        near: see :func:`rasterize_mesh`.
    Returns:
        :class:`Rendering` (image float32; None without texture and colours).
    Raises:
        InputError: arrays of the wrong shape.
    """
    v = np.asarray(vertices_cam)
    triangles = np.asarray(model.triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] <= int(triangles.max()):
        raise InputError("<array>", "vertices_cam", f"a (V, 3) array with V = {int(triangles.max()) + 1}", f"shape {v.shape}")
    tri_buf, bary, depth = rasterize_mesh(v, triangles, camera, near)
    mask = tri_buf >= 0
    H, W = mask.shape
    idx = np.flatnonzero(mask.ravel())
    t = tri_buf.ravel()[idx]
    b = bary.reshape(-1, 3)[idx]
    uv_img = None
    uv = getattr(model, "uv", None)
    uv_tris = getattr(model, "uv_triangles", None)
    if uv is not None and uv_tris is not None:
        corner_uv = np.asarray(uv, dtype=np.float64)[np.asarray(uv_tris, dtype=np.int64)]  # (F, 3, 2)
        uvp = np.einsum("nk,nkc->nc", b.astype(np.float64), corner_uv[t])
        uv_img = np.zeros((H * W, 2), dtype=np.float32)
        uv_img[idx] = uvp
        uv_img = uv_img.reshape(H, W, 2)
    image = None
    if texture is not None:
        if uv_img is None:
            raise InputError("<argument>", "texture", "a model with UVs", "none")
        image = sample_uv(_as_float_image(texture, "texture"), uv_img)  # background replaced below
    elif colours is not None:
        c = np.asarray(colours, dtype=np.float32)
        if c.ndim != 2 or c.shape[0] != v.shape[0]:
            raise InputError("<array>", "colours", f"a ({v.shape[0]}, C) array", f"shape {c.shape}")
        vals = np.einsum("nk,nkc->nc", b, c[triangles[t]])
        image = np.zeros((H * W, c.shape[1]), dtype=np.float32)
        image[idx] = vals
        image = image.reshape(H, W, c.shape[1])
    if image is not None:
        bg = np.broadcast_to(np.asarray(background, dtype=np.float32), (image.shape[-1],))
        image = np.where(mask[..., None], image, bg).astype(np.float32)
    return Rendering(image, depth, tri_buf, bary, uv_img, mask)


def _as_float_image(a: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(a)
    if a.ndim not in (2, 3) or a.shape[0] < 1 or a.shape[1] < 1:
        raise InputError("<array>", name, "an (H, W) or (H, W, C) image", f"shape {a.shape}")
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float32) / 65535.0
    out = a.astype(np.float32)
    if not np.all(np.isfinite(out)):
        raise InputError("<array>", name, "finite values", "NaN/inf values")
    return out


def light_visibility(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray, direction: np.ndarray,
                     resolution_mm: float = 1.0, bias_mm: float = 2.0) -> np.ndarray:
    """A shadow map: which ``points`` a distant (directional) light sees past the mesh.

    The mesh is rendered with :func:`rasterize_mesh` by a pinhole :data:`LIGHT_DISTANCE_MM` mm
    beyond it along ``direction``, its pixels ``resolution_mm`` mm wide at the mesh; a point is lit
    where its distance from that camera is at most the z-buffer's at its pixel (nearest) plus
    ``bias_mm`` (points on the surface itself are not shadowed by it). Points whose pixel the mesh
    does not cover are lit.

    Args:
        vertices: (V, 3) mesh vertices, mm, in any frame. triangles: (F, 3) int.
        points: (N, 3) points in the same frame, mm (e.g. texel positions on the mesh).
        direction: (3,) towards the light (normalised here).
        resolution_mm: shadow-map pixel size at the mesh, mm.
        bias_mm: depth tolerance, mm.
    Returns:
        (N,) bool, True where the light reaches the point.
    """
    light = np.asarray(direction, np.float64)
    light = light / max(float(np.linalg.norm(light)), 1e-12)
    helper = np.array([0.0, 1.0, 0.0]) if abs(light[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(helper, light)
    right /= np.linalg.norm(right)
    frame = np.stack([right, np.cross(light, right), light])  # rows: the light camera's x, y, z (z towards the light)
    v = np.asarray(vertices, np.float64) @ frame.T
    p = np.asarray(points, np.float64) @ frame.T
    lo, hi = v.min(axis=0), v.max(axis=0)
    shift = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, hi[2] + LIGHT_DISTANCE_MM])
    width, height = (int(np.ceil((hi[k] - lo[k]) / resolution_mm)) + 4 for k in (0, 1))
    camera = Camera(focal=LIGHT_DISTANCE_MM / resolution_mm, cx=width / 2.0, cy=height / 2.0, width=width, height=height)
    _, _, depth = rasterize_mesh(v - shift, triangles, camera, barycentric=False)
    p = p - shift
    pixel = np.floor(to_pixels(p, camera)).astype(np.int64)
    inside = (pixel[:, 0] >= 0) & (pixel[:, 0] < width) & (pixel[:, 1] >= 0) & (pixel[:, 1] < height)
    nearest = np.full(len(p), np.inf)
    nearest[inside] = depth[pixel[inside, 1], pixel[inside, 0]]
    return -p[:, 2] <= nearest + bias_mm


def sphere_directions(count: int) -> np.ndarray:
    """(count, 3) float64 unit vectors spread evenly over the sphere: a Fibonacci lattice (equal
    steps in z, the golden angle in azimuth), the same on every call."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    return np.stack([np.sqrt(1.0 - z * z) * np.cos(phi), np.sqrt(1.0 - z * z) * np.sin(phi), z], axis=1)


def sky_visibility(vertices: np.ndarray, triangles: np.ndarray, directions: int = 64, at: np.ndarray | None = None) -> np.ndarray:
    """Ambient occlusion: the share of a uniform sky that a vertex of a mesh sees past the mesh
    itself, cosine-weighted (its irradiance under an even environment, relative to an open plane's).

    Rays are cast from the vertex (moved :data:`SKY_OFFSET_MM` along its normal) in ``directions``
    fixed directions spread evenly over the sphere (:func:`sphere_directions`: the same answer on
    every run), those above its tangent plane only; a ray that meets a triangle is blocked. The rays are
    libigl's AABB tree's (``igl.AABB.intersect_ray_first``): 64 directions from the 11k vertices of
    the bundled model take ~0.4 s on one core, after ~0.25 s of importing igl; open3d's Embree
    scene gives the same answer in 0.1 s but its import takes ~0.8 s, and the rasterised shadow maps
    of :func:`light_visibility` were ~4× less accurate at 0.65 s (32 directions at 3 mm).

    Args:
        vertices: (V, 3) positions, mm. triangles: (F, 3) counter-clockwise vertex indices (the
            normals point out of the surface).
        directions: rays per vertex over the whole sphere (half of them above its tangent plane).
        at: (N,) int indices of the vertices to evaluate (default: all).
    Returns:
        (N,) float32 in [0, 1]: 1 where nothing of the mesh hides the sky above the vertex.
    Raises:
        InputError: ``directions`` below 1, or vertices or triangles not (·, 3).
    """
    if int(directions) < 1:
        raise InputError("<argument>", "directions", "at least 1 ray per vertex", str(directions))
    if np.ndim(vertices) != 2 or np.shape(vertices)[1] != 3 or np.ndim(triangles) != 2 or np.shape(triangles)[1] != 3:
        raise InputError("<array>", "vertices, triangles", "(V, 3) positions and (F, 3) vertex indices",
                         f"{np.shape(vertices)} and {np.shape(triangles)}")
    import igl  # here only: ~0.25 s of import that the rest of this module never needs

    from facegeo.normals import vertex_normals

    v = np.ascontiguousarray(vertices, np.float64)
    f = np.ascontiguousarray(np.asarray(triangles, np.int64).reshape(-1, 3))
    rows = np.arange(len(v)) if at is None else np.asarray(at, np.int64).reshape(-1)
    if len(rows) == 0 or len(f) == 0:
        return np.ones(len(rows), np.float32)
    n = vertex_normals(v, f)[rows]
    d = sphere_directions(directions)
    cosine = np.maximum(n @ d.T, 0.0)
    point, ray = np.nonzero(cosine > 0)
    tree = igl.AABB()
    tree.init(v, f)
    origin = np.ascontiguousarray(v[rows[point]] + SKY_OFFSET_MM * n[point])
    face, _, _ = tree.intersect_ray_first(v, f, origin, np.ascontiguousarray(d[ray]))
    blocked = np.zeros(cosine.shape, bool)
    blocked[point, ray] = face >= 0
    total = cosine.sum(axis=1)
    seen = (cosine * ~blocked).sum(axis=1)
    return np.where(total > 0, seen / np.maximum(total, 1e-12), 0.0).astype(np.float32)
