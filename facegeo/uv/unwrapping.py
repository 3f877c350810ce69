"""Unwrapping a photo into UV space with the fitted camera: the incomplete texture T_inc and the
visibility M_vis.

For every texel with a triangle (inside or seam padding, :mod:`facegeo.uv.raster`) the surface
point P (camera space, from the fitted mesh) is projected into the photo at (x, y) (continuous
pixel coordinates, pixel centres at +0.5, :mod:`facegeo.camera`), and

* ``T_inc`` = the photo sampled bilinearly at (x, y) (edge pixels repeated). Colour space: by
  default the photo's own sRGB values as float32 in [0, 1] (a colour map, stored in sRGB as
  DESIGN.md, "Conventions", asks; linearise with ``facegeo.colour.srgb_to_linear`` before shading);
  ``colour_space="linear"`` linearises the photo first and returns linear RGB.
* ``M_vis`` = visible · coverage · facing · (1 − occlusion), in [0, 1], where
  - **visible** (self-occlusion, image bounds, orientation) is the geometric visibility of P:
    P is in front of the camera, projects inside the image, its triangle's own (flat) normal
    faces the camera, and the ray from the camera to P is not blocked by the mesh. The depth test
    uses the z-buffer of the mesh rendered at the photo's resolution
    (:func:`facegeo.uv.rasterize_mesh`): when one of the four pixel centres around (x, y) sees a
    surface nearer than P by more than ``tol`` = ``depth_tolerance_mm`` + 1.5 pixel footprints
    (1.5·depth/f mm), a walk across the mesh from that surface's triangle towards P's ray looks
    for a triangle the ray passes through in front of P (exact wherever the occluder is
    connected to what the pixels see); when all four see a surface more than max(3·tol, 10 mm)
    nearer, P counts as hidden too. This agrees with ray casting (Open3D's ``RaycastingScene``,
    compared in the tests) on more than 99.8 % of the texels at every pose tried;
  - **coverage** is the share of the bilinear footprint of (x, y) that sees P's own surface: each
    of the four pixel centres counts, with its bilinear weight, when its nearest surface is P's
    triangle or a point within ``tol`` of that triangle's plane and of P's depth (±``tol`` + 3
    pixel footprints). It falls off over a pixel along occluding contours and silhouettes, where
    the photo's colours mix with the occluder or the background;
  - **facing** = smoothstep((cos θ − c0)/(c1 − c0)) with cos θ = N·v, N the interpolated vertex
    normal and v the unit vector from P to the camera, (c0, c1) = ``facing_ramp`` = (0, 0.3) by
    default: 0 at and beyond grazing (θ ≥ 90°), 1 from θ ≤ 72.5°, smooth between, so strongly
    foreshortened (blurred, resampled) texels fade out;
  - **occlusion** is the optional image-space mask (1 = something covers the face: hair,
    glasses, hands) sampled bilinearly at (x, y).

Texels with M_vis = 0 (and texels without a triangle) have T_inc = 0. :func:`unwrap_details`
also returns every factor (``visible``, ``coverage``, ``facing``, ``cos_view``, ``in_image``,
``front``, ``occlusion``) and the projected pixel positions.
"""

from __future__ import annotations

import hashlib

import numpy as np

from facegeo.camera import Camera, to_pixels
from facegeo.colour import srgb8_to_linear, srgb_to_linear
from facegeo.errors import InputError
from facegeo.uv.maps import GeometryMaps, texel_geometry
from facegeo.uv.raster import UVRaster, rasterize_uv
from facegeo.uv.renderer import NEAR_MM, _as_float_image, rasterize_mesh
from facegeo.uv.texels import sample_bilinear
from facegeo.normals import vertex_normals

__all__ = ["unwrap", "unwrap_details", "Unwrapped", "FACING_RAMP", "DEPTH_TOLERANCE_MM"]

#: (c0, c1): the facing weight rises smoothly from 0 at cos θ = c0 to 1 at cos θ = c1.
FACING_RAMP = (0.0, 0.3)
#: Fixed part of the depth-test tolerance in mm (1.5 pixel footprints are added).
DEPTH_TOLERANCE_MM = 1.0
#: Pixel footprints added to the depth-test tolerance.
TOLERANCE_PIXELS = 1.5


class Unwrapped:
    """The unwrap and its parts. Dense maps are (S, S) float32 unless stated, zeros outside the
    layout; they are built on first access from per-texel arrays (``raster.texels`` order).

    Attributes / properties:
        texture: (S, S, 3) float32 T_inc (colour space per ``colour_space``).
        visibility: M_vis in [0, 1].
        visible: bool, geometric visibility (unblocked ray, front-facing, inside the image).
        coverage, facing: the factors of M_vis described in the module docstring.
        cos_view: N·v, the cosine between the interpolated normal and the direction to the camera.
        in_image: bool. front: bool.
        occlusion: the external mask sampled at the texels (zeros when none was given).
        pixel: (S, S, 2) float32 projected pixel coordinates (x, y) (−1 outside the layout or
            behind the camera).
        colour_space: "srgb" or "linear".
        raster: the :class:`UVRaster` used.
        texel: dict of the per-texel (N, ...) arrays behind the maps.
    """

    _FILL = {"pixel": -1.0}

    def __init__(self, raster: UVRaster, colour_space: str, **texel: np.ndarray):
        self.raster = raster
        self.colour_space = colour_space
        self.texel = texel
        self._dense: dict[str, np.ndarray] = {}

    def _map(self, name: str) -> np.ndarray:
        if name not in self._dense:
            self._dense[name] = self.raster.scatter(self.texel[name], fill=self._FILL.get(name, 0))
        return self._dense[name]

    texture = property(lambda self: self._map("texture"))
    visibility = property(lambda self: self._map("visibility"))
    visible = property(lambda self: self._map("visible"))
    coverage = property(lambda self: self._map("coverage"))
    facing = property(lambda self: self._map("facing"))
    cos_view = property(lambda self: self._map("cos_view"))
    in_image = property(lambda self: self._map("in_image"))
    front = property(lambda self: self._map("front"))
    occlusion = property(lambda self: self._map("occlusion"))
    pixel = property(lambda self: self._map("pixel"))


def unwrap(image, fit, model, size: int = 1024, **kwargs) -> tuple[np.ndarray, np.ndarray]:
    """Unwrap a photo into UV space: ``(T_inc (S, S, 3) float32, M_vis (S, S) float32)``.

    See :func:`unwrap_details` for the arguments; this returns only the texture and visibility.
    """
    result = unwrap_details(image, fit, model, size, **kwargs)
    return result.texture, result.visibility


def unwrap_details(image, fit, model, size: int = 1024, *, occlusion: np.ndarray | None = None,
                   raster: UVRaster | None = None, maps: GeometryMaps | None = None,
                   colour_space: str = "srgb", facing_ramp: tuple[float, float] = FACING_RAMP,
                   depth_tolerance_mm: float = DEPTH_TOLERANCE_MM, near: float = NEAR_MM) -> Unwrapped:
    """Unwrap a photo into UV space with the fitted camera (see the module docstring).

    Args:
        image: the photo the fit was made on: (H, W, 3) uint8 RGB (or float in [0, 1]), or a
            :class:`facegeo.Photo`; its size must be the fit camera's.
        fit: a :class:`facegeo.Fit`, or any object with ``vertices`` ((V, 3) camera space, mm)
            and ``camera`` (:class:`facegeo.Camera`).
        model: the model the fit used (``triangles``, ``uv``, ``uv_triangles``).
        size: S (ignored when ``raster`` or ``maps`` is given).
        occlusion: optional (H, W) image-space mask in [0, 1] or bool, 1 where something in front
            of the face hides it.
        raster: a :class:`UVRaster` of the model's layout (default: the cached one for ``size``).
        maps: camera-space :class:`GeometryMaps` of ``fit.vertices`` already computed (saves
            the interpolation).
        colour_space: "srgb" (default: the photo's values) or "linear".
        facing_ramp: (c0, c1) of the facing weight.
        depth_tolerance_mm: fixed part of the depth-test tolerance.
        near: mm; texels and triangles closer to the camera plane count as not visible.
    Returns:
        :class:`Unwrapped`.
    Raises:
        InputError: an image or mask of the wrong size or type, bad vertices, or an unknown
            colour space.
    """
    if colour_space not in ("srgb", "linear"):
        raise InputError("<argument>", "colour_space", '"srgb" or "linear"', repr(colour_space))
    camera: Camera = fit.camera
    img = _photo(image, camera, colour_space)
    occ_img = _occlusion(occlusion, camera)
    triangles = np.asarray(model.triangles, dtype=np.int64)
    vertices = _vertices(fit.vertices, triangles)

    if maps is not None:
        raster = maps.raster
        if "position" in maps.texel and "normal" in maps.texel:
            P, n_s = maps.texel["position"], maps.texel["normal"]
        else:
            P, n_s = raster.gather(maps.position), raster.gather(maps.normal)
    else:
        if raster is None:
            raster = rasterize_uv(model, size=size)
        geo = texel_geometry(vertices, vertex_normals(vertices, triangles).astype(np.float32), model, raster, tangents=False)
        P, n_s = geo["position"], geo["normal"]
    tri = raster.texel_triangle
    planes = _Planes(vertices, triangles)
    H, W = camera.height, camera.width
    N = tri.size

    # projection (float32 keeps 1e-3 px at 16k pixels)
    depth = -P[:, 2]
    ahead = depth > near
    x, y = to_pixels(P, camera).T
    in_image = ahead & (x >= 0) & (x <= W) & (y >= 0) & (y <= H)
    # the texel lies on its triangle's plane n·X = c, so the plane faces the camera iff c < 0
    front = planes.faces_camera[tri]
    cos_view = -np.einsum("ij,ij->i", n_s, P) / np.maximum(np.sqrt(np.einsum("ij,ij->i", P, P)), np.float32(1e-12))

    # self-occlusion and the rest, only where something can be seen
    todo = np.flatnonzero(in_image & front)
    visible = np.zeros(N, dtype=bool)
    coverage = np.zeros(N, dtype=np.float32)
    visibility = np.zeros(N, dtype=np.float32)
    colours = np.zeros((N, 3), dtype=np.float32)
    occ = np.zeros(N, dtype=np.float32)
    c0, c1 = float(facing_ramp[0]), float(facing_ramp[1])
    t = np.clip((cos_view - np.float32(c0)) / np.float32(max(c1 - c0, 1e-9)), 0.0, 1.0)
    facing = t * t * (np.float32(3.0) - np.float32(2.0) * t)
    if todo.size:
        tri_buf, _, depth_buf = rasterize_mesh(vertices, triangles, camera, near, barycentric=False)
        tol = depth_tolerance_mm + TOLERANCE_PIXELS * depth[todo] / camera.focal
        cov, hidden = _coverage(P[todo], depth[todo], x[todo], y[todo], tri[todo], tol, tri_buf, depth_buf,
                                planes, triangles, camera)
        coverage[todo] = cov
        seen = todo[~hidden]
        visible[seen] = True
        # bilinear lookups of the photo (and the mask) at the projections of the seen texels
        at = np.stack([x[seen], y[seen]], axis=1)
        if occ_img is not None:
            occ[seen] = sample_bilinear(occ_img, at)
        visibility[seen] = np.clip(coverage[seen] * facing[seen] * (1.0 - occ[seen]), 0.0, 1.0)
        colours[seen] = sample_bilinear(img, at)
        colours[visibility <= 0] = 0.0
    return Unwrapped(
        raster, colour_space,
        texture=colours,
        visibility=visibility,
        visible=visible,
        coverage=coverage,
        facing=facing.astype(np.float32),
        cos_view=cos_view.astype(np.float32),
        in_image=in_image,
        front=front,
        occlusion=occ,
        pixel=np.where(ahead[:, None], np.stack([x, y], axis=1), np.float32(-1.0)),
    )


class _Planes:
    """Per triangle (camera space, float64): unit normal, plane offset n·A, corner A and the dual
    edge vectors u1, u2 giving barycentrics λ_B = u1·(X − A), λ_C = u2·(X − A) of a point X on
    the plane; ``ok`` is False for zero-area triangles."""

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray):
        c = vertices[triangles].astype(np.float64)
        a = c[:, 0]
        e1, e2 = c[:, 1] - a, c[:, 2] - a
        cross = np.cross(e1, e2)
        area2 = np.linalg.norm(cross, axis=1)
        self.ok = area2 > 1e-12
        safe = np.where(self.ok, area2, 1.0)
        self.normal = np.where(self.ok[:, None], cross / safe[:, None], 0.0)
        self.offset = _dot(self.normal, a)
        #: the plane (and every point on it) faces the camera at the origin
        self.faces_camera = self.ok & (self.offset < 0)
        g00, g01, g11 = _dot(e1, e1), _dot(e1, e2), _dot(e2, e2)
        det = np.where(self.ok, g00 * g11 - g01 * g01, 1.0)
        self.u1 = ((g11 / det)[:, None] * e1 - (g01 / det)[:, None] * e2)
        self.u2 = ((g00 / det)[:, None] * e2 - (g01 / det)[:, None] * e1)
        self.a = a
        #: (F, 14) float64 rows: normal, offset, a, u1, u2, ok (one gather per walk step)
        self.packed = np.concatenate([self.normal, self.offset[:, None], a, self.u1, self.u2,
                                      self.ok[:, None].astype(np.float64)], axis=1)


#: A ray meets a triangle when its barycentrics are all ≥ −_HIT_EPS; it is blocked when that
#: point is nearer than the texel by more than _HIT_DEPTH_EPS of the texel's depth.
_HIT_EPS = 1e-6
_HIT_DEPTH_EPS = 1e-5
#: Steps of the walk across the mesh from a tap's triangle towards the texel's ray.
_WALK_STEPS = 16
#: Taps whose surface is nearer than the texel by more than max(_FAR_TOLERANCES·tol, _FAR_MM):
#: when all four are, the texel counts as hidden.
_FAR_TOLERANCES = 3.0
_FAR_MM = 10.0
#: A tap's surface point counts as the texel's surface only within this many pixel footprints
#: (plus the tolerance) of the texel's depth.
_NEAR_PIXELS = 3.0


def _coverage(P, depth, x, y, tri, tol, tri_buf, depth_buf, planes: _Planes, triangles, camera
              ) -> tuple[np.ndarray, np.ndarray]:
    """Self-occlusion of projected texels against the z-buffer.

    Returns ``(coverage, hidden)``:

    * coverage: the bilinear share of the texel's footprint (the four pixel centres around its
      projection) whose nearest surface is the texel's own triangle, or a point within ``tol``
      of that triangle's plane whose depth is within ``tol`` + 3 pixel footprints of the texel's;
    * hidden: the ray from the camera to the texel is blocked. When a tap's nearest surface is
      more than ``tol`` nearer than the texel, a walk across the mesh starts from the nearest such
      surface's triangle towards the texel's ray (:func:`_walk_to_ray`); the texel is hidden when
      the walk ends on a triangle the ray passes through in front of the texel. This is exact
      wherever the blocking surface is connected, within a few triangles, to what the taps see.
    """
    H, W = tri_buf.shape
    f32 = np.float32
    # buffers padded by one pixel of background, so taps need no bounds checks
    tri_pad = np.full((H + 2, W + 2), -1, dtype=np.int32)
    tri_pad[1:-1, 1:-1] = tri_buf
    depth_pad = np.zeros((H + 2, W + 2), dtype=f32)
    depth_pad[1:-1, 1:-1] = np.where(tri_buf >= 0, depth_buf, 0.0)
    tri_flat, depth_flat = tri_pad.ravel(), depth_pad.ravel()
    depth32, tol32 = depth.astype(f32), tol.astype(f32)
    near = (tol + _NEAR_PIXELS * depth / camera.focal).astype(f32)
    nrm = planes.normal[tri]
    c_own = planes.offset[tri].astype(f32)
    tri32 = tri.astype(np.int32)
    valid_own = planes.ok[tri]
    fx0 = np.clip(np.floor(x - 0.5), -1, W)  # texels project inside the image: taps in [-1, W]
    fy0 = np.clip(np.floor(y - 0.5), -1, H)
    ax, ay = (x - 0.5 - fx0).astype(f32), (y - 0.5 - fy0).astype(f32)
    base = ((fy0 + 1) * (W + 2) + (fx0 + 1)).astype(np.int64)
    inv_f = 1.0 / camera.focal
    # the tap's surface point X = d·(rx, ry, −1); its distance to the texel's plane is |d·k − c|
    rx0 = (fx0 + 0.5 - camera.cx) * inv_f
    ry0 = (camera.cy - fy0 - 0.5) * inv_f
    k00 = (nrm[:, 0] * rx0 + nrm[:, 1] * ry0 - nrm[:, 2]).astype(f32)
    kx, ky = (nrm[:, 0] * inv_f).astype(f32), (nrm[:, 1] * inv_f).astype(f32)
    cov = np.zeros(P.shape[0], dtype=f32)
    # per texel, the nearest tap surface that is more than tol in front of it: where a walk starts
    start_depth = depth32 - tol32
    start_tri = np.full(P.shape[0], -1, dtype=np.int32)
    others: list[tuple[np.ndarray, np.ndarray]] = []
    far = np.zeros(P.shape[0], dtype=np.int8)
    far_depth = depth32 - np.maximum(_FAR_TOLERANCES * tol32, f32(_FAR_MM))
    for dx, dy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        w = (ax if dx else 1.0 - ax) * (ay if dy else 1.0 - ay)
        q = base + (dy * (W + 2) + dx)
        f = tri_flat[q]
        d_q = depth_flat[q]
        k = k00 + (kx if dx else 0) - (ky if dy else 0)
        agree = (np.abs(d_q * k - c_own) <= tol32) & (np.abs(d_q - depth32) <= near)
        same = (f == tri32) | ((f >= 0) & valid_own & agree)
        cov += np.where(same, w, f32(0.0))
        candidate = (f >= 0) & (f != tri32) & (d_q < depth32 - tol32)
        others.append((candidate, f))
        nearer = candidate & (d_q < start_depth)
        start_depth = np.where(nearer, d_q, start_depth)
        start_tri = np.where(nearer, f, start_tri)
        far += (f >= 0) & (d_q < far_depth)
    hidden = np.zeros(P.shape[0], dtype=bool)
    adjacency = _edge_adjacency(triangles)
    a = np.flatnonzero(start_tri >= 0)
    if a.size:  # first from the nearest tap surface ...
        hidden[a[_walk_to_ray(P[a], depth[a], start_tri[a].astype(np.int64), planes, adjacency)]] = True
    for candidate, f in others:  # ... then from the other nearer ones
        b = np.flatnonzero(candidate & ~hidden & (f != start_tri))
        if b.size:
            hidden[b[_walk_to_ray(P[b], depth[b], f[b].astype(np.int64), planes, adjacency)]] = True
    # the whole footprint sees a surface far in front: hidden even if no walk reached the ray
    hidden |= far == 4
    return cov, hidden


def _walk_to_ray(P: np.ndarray, depth: np.ndarray, f: np.ndarray, planes: _Planes, adjacency: np.ndarray) -> np.ndarray:
    """From triangle f, walk across edges towards the point where the ray through P meets the
    surface (always leaving through the edge the meeting point with the current plane lies
    furthest beyond), for at most :data:`_WALK_STEPS` steps. True where the walk ends on a
    triangle that the ray passes through nearer to the camera than P (P is hidden)."""
    hidden = np.zeros(P.shape[0], dtype=bool)
    active = np.arange(P.shape[0])
    table = planes.packed
    for _ in range(_WALK_STEPS + 1):
        if active.size == 0:
            break
        fa, pa = f[active], P[active]
        t = table[fa]  # normal, offset, a, u1, u2, ok
        with np.errstate(divide="ignore", invalid="ignore"):
            s = t[:, 3] / (t[:, 0] * pa[:, 0] + t[:, 1] * pa[:, 1] + t[:, 2] * pa[:, 2])
            rx, ry, rz = s * pa[:, 0] - t[:, 4], s * pa[:, 1] - t[:, 5], s * pa[:, 2] - t[:, 6]
        lb = t[:, 7] * rx + t[:, 8] * ry + t[:, 9] * rz
        lc = t[:, 10] * rx + t[:, 11] * ry + t[:, 12] * rz
        la = 1.0 - lb - lc
        valid = (t[:, 13] > 0) & np.isfinite(s) & (s > 0)
        hit = valid & (la >= -_HIT_EPS) & (lb >= -_HIT_EPS) & (lc >= -_HIT_EPS)
        blocked = hit & (s < 1.0 - _HIT_DEPTH_EPS)
        hidden[active[blocked]] = True
        worst = np.where(la <= lb, np.where(la <= lc, 0, 2), np.where(lb <= lc, 1, 2))
        nxt = adjacency[fa, worst]
        go = valid & ~hit & (nxt >= 0)
        active = active[go]
        f[active] = nxt[go]
    return hidden


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of (n, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


_ADJ_CACHE: dict[bytes, np.ndarray] = {}


def _edge_adjacency(triangles: np.ndarray) -> np.ndarray:
    """(F, 3) int64: the triangle across the edge opposite each corner (−1 on boundaries; on a
    non-manifold edge, one of the others). Cached per triangle list."""
    key = hashlib.blake2b(np.ascontiguousarray(triangles).tobytes(), digest_size=16).digest()
    hit = _ADJ_CACHE.get(key)
    if hit is not None:
        return hit
    F = triangles.shape[0]
    a = triangles[:, [1, 2, 0]].reshape(-1)  # edge opposite corner k: corners k+1, k+2
    b = triangles[:, [2, 0, 1]].reshape(-1)
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi, lo))
    lo_s, hi_s = lo[order], hi[order]
    same_next = (lo_s[1:] == lo_s[:-1]) & (hi_s[1:] == hi_s[:-1])
    adj = np.full(3 * F, -1, dtype=np.int64)
    e1, e2 = order[:-1][same_next], order[1:][same_next]
    adj[e1] = e2 // 3
    adj[e2] = e1 // 3
    adj = adj.reshape(F, 3)
    if len(_ADJ_CACHE) > 8:
        _ADJ_CACHE.clear()
    _ADJ_CACHE[key] = adj
    return adj


def _photo(image, camera: Camera, colour_space: str) -> np.ndarray:
    pixels = getattr(image, "image", image)
    by_table = colour_space == "linear" and isinstance(pixels, np.ndarray) and pixels.dtype == np.uint8
    img = srgb8_to_linear(pixels) if by_table else _as_float_image(pixels, "image")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    if img.shape[:2] != (camera.height, camera.width) or img.shape[2] not in (3, 4):
        raise InputError("<array>", "image", f"a {camera.width}x{camera.height} RGB image (the fit camera's size)",
                         f"shape {img.shape}")
    img = np.ascontiguousarray(img[..., :3])
    if colour_space == "linear" and not by_table:
        img = srgb_to_linear(img)
    return img


def _occlusion(occlusion, camera: Camera) -> np.ndarray | None:
    if occlusion is None:
        return None
    occ = np.asarray(occlusion)
    if occ.ndim not in (2, 3) or occ.shape[:2] != (camera.height, camera.width):
        raise InputError("<array>", "occlusion", f"a {camera.width}x{camera.height} mask", f"shape {occ.shape}")
    occ = _as_float_image(occ.astype(np.float32) if occ.dtype == bool else occ, "occlusion")
    if occ.ndim == 3:
        occ = occ.mean(axis=2)
    return np.ascontiguousarray(np.clip(occ, 0.0, 1.0), dtype=np.float32)


def _vertices(vertices, triangles: np.ndarray) -> np.ndarray:
    v = np.asarray(vertices)
    if v.ndim != 2 or v.shape[1] != 3 or v.shape[0] <= int(triangles.max()) or v.dtype.kind not in "fiu":
        raise InputError("<array>", "fit.vertices", f"a (V, 3) array with V = {int(triangles.max()) + 1}", f"shape {v.shape}")
    v = v.astype(np.float32)
    if not np.all(np.isfinite(v)):
        raise InputError("<array>", "fit.vertices", "finite values", "NaN/inf values")
    return v
