"""Geometry kernels of the REALY protocol: closest points as the official code gets them, and
trimesh-style vertex merging.

:class:`SurfaceQuery` answers, for every query point, the closest point on a triangle mesh the way
the official code's ``trimesh.Trimesh.nearest.on_surface`` (trimesh 3.x) does, vectorised:

* the nearest face comes from libigl's AABB tree (``igl.AABB``, exact in float64: it agrees
  with a brute-force point-to-triangle search to rounding, tests/test_realy_geometry.py), built
  once per prediction and reused for its rigid motions (:class:`SurfaceQuery`). open3d's
  RaycastingScene is not used: it computes in float32 (errors up to 2e-5 mm on a head measured
  in mm);
* trimesh does not always return the nearest of its candidates: when the two nearest candidate
  triangles are within 1e-8 in *squared* distance (and both farther than 1e-8), it takes the one
  whose normal points more towards the query. That happens when the closest point lies within
  1e-4 of a triangle edge, or when a nearly coplanar neighbour is almost as close (about one
  query in a thousand), and it moves the point by up to a few 1e-3. So every query is re-solved
  among the triangles sharing a vertex with the nearest one, with trimesh's rule and its
  point-to-triangle formula (:func:`point_triangle_closest`).

:func:`merge_vertices` reproduces what ``trimesh.Trimesh(..., process=True)`` (trimesh 3.x, the
official code's version) does to a ground-truth region before the error step: vertices that no
face uses are dropped, vertices whose coordinates agree after rounding to 1e-8 are merged into
the first of them (first-occurrence order), and faces are re-indexed (faces that become
degenerate are kept).
"""

from __future__ import annotations

import hashlib
import time

import numpy as np

__all__ = ["SurfaceQuery", "closest_points", "merge_vertices", "point_triangle_closest"]

#: trimesh's tolerances (trimesh.constants.tol): squared distances closer than MERGE tie.
_MERGE = 1e-8
_ZERO = 1e-13
_ONES = np.ones(3)
#: ring tables by triangulation digest (a few topologies at most)
_RING_TABLES: dict[bytes, np.ndarray] = {}
#: AABB trees by digest of (vertices, triangles): the regions of one prediction start from the
#: same aligned vertices, so in one process they share its tree (the same tree as one built anew)
_TREES: dict[bytes, tuple[object, np.ndarray, float]] = {}
_CACHED = 4


def _remember(cache: dict, key: bytes, value):
    """Put ``value`` in a small first-in-first-out cache (at most _CACHED entries)."""
    if len(cache) >= _CACHED:
        cache.pop(next(iter(cache)))
    cache[key] = value
    return value


def closest_points(vertices: np.ndarray, triangles: np.ndarray, queries: np.ndarray) -> np.ndarray:
    """(Q, 3) float64: the exact closest point on the mesh for each query point."""
    return _igl_closest(vertices, triangles, queries)[2]


def _igl_closest(vertices, triangles, queries):
    import igl

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(triangles, dtype=np.int64)
    q = np.ascontiguousarray(queries, dtype=np.float64)
    d2, face, points = igl.point_mesh_squared_distance(q, v, f)
    return np.asarray(d2), np.asarray(face, dtype=np.int64).reshape(-1), np.asarray(points, dtype=np.float64)


class SurfaceQuery:
    """Closest points on meshes of one triangulation, as trimesh's ``nearest.on_surface`` gives them.

    The protocol queries one prediction in many poses (the regional ICPs move it rigidly, with a
    float32 cast after every step). The AABB tree is built once, for the first vertices given;
    a later call whose vertices are a rigid motion of those (Kabsch fit, largest deviation at
    most ``FRAME_TOLERANCE`` times the mesh size: float32 rounding) maps its queries into the
    tree's frame to find each query's nearest face there, and the exact closest point is then
    computed on the *given* vertices among the faces around that face, with trimesh's rule.
    That is the exact answer unless a non-adjacent face is within twice the deviation (about
    1e-6 of the mesh size) of the nearest one; other vertices get a new tree.
    """

    #: largest deviation from a rigid motion of the tree's vertices, relative to the mesh size
    FRAME_TOLERANCE = 1e-6

    def __init__(self, triangles: np.ndarray):
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self._ring_table: np.ndarray | None = None
        self._tree = None
        self._tree_vertices: np.ndarray | None = None
        self._tree_size = 0.0  # largest extent of the tree's vertices
        self.trees_built = 0  # trees this query needed (built here or shared from an earlier query)
        self.seconds = 0.0  # CPU time spent answering queries (trees included)
        self.prune = True  # False: the exact point on every ring face (the reference in the tests)
        self._jitter = 0.0
        self.near_ties = np.zeros(0, dtype=bool)  # of the last call (see __call__)
        self.alternatives = np.zeros((0, 2, 3))

    def rings(self) -> np.ndarray:
        """(F, K) table: each face and the faces sharing a vertex with it, padded with -1.

        Shared by the queries of one triangulation (the predictions of a topology) in a process.
        """
        if self._ring_table is None:
            key = hashlib.blake2b(self.triangles.tobytes(), digest_size=16).digest()
            self._ring_table = _RING_TABLES.get(key)
        if self._ring_table is None:
            f = self.triangles
            corner_vertex = f.reshape(-1)
            order = np.argsort(corner_vertex, kind="stable")
            by_vertex = order // 3
            start = np.searchsorted(corner_vertex[order], np.arange(int(corner_vertex.max()) + 2))
            valence = np.diff(start)
            owner = np.repeat(np.arange(len(f)), 3)
            counts = valence[corner_vertex]
            first = np.repeat(start[corner_vertex], counts)
            offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
            pairs = np.sort(np.repeat(owner, counts) * len(f) + by_vertex[first + offset])
            pairs = pairs[np.concatenate([[True], pairs[1:] != pairs[:-1]])]  # sorted unique (faster than np.unique's hash)
            face, other = pairs // len(f), pairs % len(f)
            sizes = np.bincount(face, minlength=len(f))
            table = np.full((len(f), int(sizes.max())), -1, dtype=np.int64)
            slot = np.arange(len(pairs)) - np.repeat(np.cumsum(sizes) - sizes, sizes)
            table[face, slot] = other
            self._ring_table = _remember(_RING_TABLES, key, table)
        return self._ring_table

    def _queries_in_tree_frame(self, vertices: np.ndarray, queries: np.ndarray) -> np.ndarray:
        """``queries`` mapped into the frame of the tree (built here when none fits)."""
        ref = self._tree_vertices
        if ref is not None and ref.shape == vertices.shape:
            if np.array_equal(ref, vertices):
                return queries
            # the motion from at most 1024 spread vertices (the check below covers all of them)
            every = max(1, len(ref) // 1024)
            rotation, translation = _rigid_fit(ref[::every], vertices[::every])
            deviation = float(np.abs(ref @ rotation.T + translation - vertices).max())
            if deviation <= self.FRAME_TOLERANCE * self._tree_size:
                return (queries - translation) @ rotation
        digest = hashlib.blake2b(digest_size=16)
        digest.update(np.ascontiguousarray(vertices).tobytes())
        digest.update(self.triangles.tobytes())
        key = digest.digest()
        found = _TREES.get(key)
        if found is None:
            import igl

            tree_vertices = np.ascontiguousarray(vertices).copy()  # the caller may change its array
            tree = igl.AABB()
            tree.init(tree_vertices, self.triangles)
            found = _remember(_TREES, key, (tree, tree_vertices, float(np.ptp(tree_vertices, axis=0).max())))
        self._tree, self._tree_vertices, self._tree_size = found
        self.trees_built += 1
        return queries

    def __call__(self, vertices: np.ndarray, queries: np.ndarray, jitter: float = 0.0) -> np.ndarray:
        """(Q, 3) float64 closest points of ``queries`` on the mesh with these ``vertices``.

        With ``jitter`` > 0 (a length), the call also finds the queries whose answer could change
        if they moved by up to ``jitter``: those near one of trimesh's decisions (two squared
        distances 1e-8 apart, or two normals equally aligned). :attr:`near_ties` (Q,) bool marks
        them and :attr:`alternatives` (Q, 2, 3) holds the two nearest candidate points of each
        query (NaN where there is no second candidate).
        """
        start = time.process_time()
        self.near_ties = np.zeros(len(queries), dtype=bool)
        self.alternatives = np.full((len(queries), 2, 3), np.nan)
        self._jitter = float(jitter)
        vertices = np.asarray(vertices, dtype=np.float64)
        queries = np.asarray(queries, dtype=np.float64)
        mapped = np.ascontiguousarray(self._queries_in_tree_frame(vertices, queries))
        _, face, _ = self._tree.squared_distance(self._tree_vertices, self.triangles, mapped)
        # the exact point among the faces around the nearest one, where trimesh may also prefer
        # a rival within 1e-8 in squared distance (across a nearby edge or nearly coplanar)
        result = self._trimesh_pick(vertices, queries, np.asarray(face, dtype=np.int64).reshape(-1))
        self.seconds += time.process_time() - start
        return result

    def _trimesh_pick(self, vertices: np.ndarray, queries: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """trimesh's choice among the faces around ``faces`` for each query (see the module doc)."""
        ring = self.rings()[faces]  # (S, K)
        n_queries = len(faces)
        tri0 = vertices[self.triangles[faces]]
        close0 = _closest_tolerant(queries, tri0[:, 0], tri0[:, 1], tri0[:, 2])
        vec0 = queries - close0
        d0 = np.dot(vec0 * vec0, _ONES)
        own = ring == faces[:, None]  # the tree's face in its own ring
        s_idx, k_idx = np.nonzero((ring >= 0) & ~own)  # the other faces of each ring
        face = ring[s_idx, k_idx]
        if self.prune:
            # Only the ring faces that can be within trimesh's tie window of the tree's face need
            # the exact point: a face is skipped when a lower bound of its squared distance (its
            # plane and its three edge lines) exceeds the tree face's squared distance plus the
            # window, with a margin for rounding. That leaves 0.6 of the 12 other ring faces per
            # query on average (large subject 1).
            slot = np.zeros(len(self.triangles), dtype=np.int64)
            slot[face] = 1
            used = np.nonzero(slot)[0]
            slot[used] = np.arange(len(used))
            slot = slot[face]
            planes, offsets = _face_planes(vertices, self.triangles[used])
            q = queries[s_idx]
            signed = np.einsum("mij,mj->mi", planes[slot], q) - offsets[slot]  # (M, 4)
            outside = np.maximum(np.maximum(np.maximum(signed[:, 1], signed[:, 2]), signed[:, 3]), 0.0)
            scale2 = float(np.max(np.abs(vertices))) ** 2 + float(np.max(np.abs(queries))) ** 2
            window = 2 * _MERGE
            if self._jitter > 0:  # a rival up to M + 2 slack away can become a tie under the jitter
                j = self._jitter
                window = window + 8 * np.sqrt(d0[s_idx] + 4 * _MERGE) * j + 4 * j * j
            limit = (d0[s_idx] + window) * (1 + 1e-9) + 1e-12 * scale2
            keep = ~(signed[:, 0] ** 2 + outside**2 > limit)  # NaN bounds are kept
            s_idx, k_idx, face = s_idx[keep], k_idx[keep], face[keep]
        # the candidates: the tree's face of each query first, then the kept ring faces
        q = queries[s_idx]
        tri = vertices[self.triangles[face]]
        close = np.concatenate([close0, point_triangle_closest(q, tri[:, 0], tri[:, 1], tri[:, 2], tolerant=True)])
        # the same expressions as trimesh, so that near-equal values round the same way
        vec = np.concatenate([vec0, q - close[n_queries:]])
        dist = np.concatenate([d0, np.dot(vec[n_queries:] * vec[n_queries:], _ONES)])
        owner = np.concatenate([np.arange(n_queries), s_idx])
        place = np.concatenate([np.argmax(own, axis=1), k_idx])  # place in the ring
        face = np.concatenate([faces, face])
        # each query's two nearest candidates (ties in ring order, as a stable sort; NaN last)
        order = np.lexsort((place, dist, owner))
        start = np.searchsorted(owner[order], np.arange(n_queries))
        count = np.diff(np.append(start, len(order)))
        two = np.column_stack([order[start], order[np.minimum(start + 1, len(order) - 1)]])
        result = close[two[:, 0]]
        if ring.shape[1] < 2:
            return result
        pair = np.column_stack([dist[two[:, 0]], np.where(count > 1, dist[two[:, 1]], np.inf)])
        tie = (np.ptp(pair, axis=1) < _MERGE) & np.all(np.abs(pair) > _MERGE, axis=1)
        jitter = self._jitter
        if jitter > 0:
            # a move by jitter changes a squared distance d^2 by at most 2 d jitter + jitter^2
            with np.errstate(invalid="ignore"):
                slack = 2 * np.sqrt(np.max(np.where(np.isfinite(pair), pair, 0.0), axis=1)) * jitter + jitter**2
                near = np.abs(np.ptp(pair, axis=1) - _MERGE) <= 2 * slack
                near |= np.any(np.abs(pair - _MERGE) <= slack[:, None], axis=1)
            self.near_ties = near
            self.alternatives = np.where(np.isfinite(pair)[:, :, None], close[two], np.nan)
        if np.any(tie):
            r = np.nonzero(tie)[0]
            both = two[r]  # (T, 2) candidates
            tri2 = vertices[self.triangles[face[both]]]  # (T, 2, 3, 3)
            normals = _unit_normals(tri2.reshape(-1, 3, 3)).reshape(-1, 2, 3)
            vectors = vec[both] / pair[tie].reshape(-1, 2, 1) ** 0.5
            aligned = (normals * vectors).sum(axis=2)
            pick = aligned.argmax(axis=1)
            result[r] = close[both[np.arange(len(r)), pick]]
            if jitter > 0:  # the directions turn by up to about 2 jitter / distance
                turn = 4 * jitter / np.sqrt(pair[tie].min(axis=1))
                self.near_ties[r] |= np.abs(aligned[:, 0] - aligned[:, 1]) <= turn
        return result


def _rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation and translation with ``source @ R.T + t ~ target`` (Kabsch).

    By hand: trimesh.registration.procrustes would add trimesh's 0.7 s import to every run, and
    realy_align.fit_transform reproduces the official code's quirks (no reflection guard).
    """
    cs, ct = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((target - ct).T @ (source - cs))
    fix = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ fix @ vt
    return rotation, ct - cs @ rotation.T


def _face_planes(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per face, its unit normal and its three outward in-plane edge normals: (F, 4, 3), and
    their offsets (F, 4), so that ``planes @ q - offsets`` gives the signed distances of ``q`` to
    the face's plane and past each edge. Zero rows for degenerate faces (no bound)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    normal = _unit_normals(np.stack([a, b, c], axis=1))
    planes = np.empty((len(triangles), 4, 3))
    planes[:, 0] = normal
    for k, (start, end) in enumerate(((a, b), (b, c), (c, a)), 1):
        edge = _cross(end - start, normal)
        length = np.sqrt(np.einsum("ij,ij->i", edge, edge))
        planes[:, k] = np.divide(edge, length[:, None], out=np.zeros_like(edge), where=length[:, None] > 0)
    offsets = np.einsum("fij,fij->fi", planes, np.stack([a, a, b, c], axis=1))
    return planes, offsets


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n, 3) row-wise cross products: np.cross's products and differences in its order, without
    its per-call reshaping (a third of the time on these small arrays)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _unit_normals(tri: np.ndarray) -> np.ndarray:
    """Unit face normals (zero for degenerate faces), as trimesh's ``face_normals``."""
    edges = np.diff(tri, axis=1)
    cross = _cross(edges[:, 0], edges[:, 1])
    norm = np.sqrt(np.dot(cross * cross, _ONES))
    ok = norm > 1e-12
    norm[ok] **= -1
    return np.where(ok[:, None], cross * norm.reshape(-1, 1), 0.0)


def point_triangle_closest(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray,
                           tolerant: bool = False) -> np.ndarray:
    """Closest points of points ``p`` on triangles ``(a, b, c)`` (all (n, 3)), by Voronoi regions.

    The method of Ericson, *Real-Time Collision Detection* (5.1.5), in float64. With
    ``tolerant=True`` the region tests use trimesh's small tolerance (1e-13) in the order trimesh
    applies them, which is what the official code computes; otherwise they are exact and
    fully degenerate triangles fall back to their edges (a reference for the tests).
    """
    if tolerant:
        return _closest_tolerant(p, a, b, c)
    p, a, b, c = (np.asarray(x, dtype=np.float64) for x in (p, a, b, c))
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v_in = vb / denom
        w_in = vc / denom
        out = a + ab * v_in[:, None] + ac * w_in[:, None]
        # edges
        v_ab = d1 / (d1 - d3)
        w_ac = d2 / (d2 - d6)
        w_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    cases = [
        (vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * v_ab[:, None],
        (vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * w_ac[:, None],
        (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0), b + (c - b) * w_bc[:, None],
        (d6 >= 0) & (d5 <= d6), c,
        (d3 >= 0) & (d4 <= d3), b,
        (d1 <= 0) & (d2 <= 0), a,
    ]
    # apply from the lowest priority up, so that vertex regions win over edges, edges over face
    for mask, value in reversed(list(zip(cases[0::2], cases[1::2]))):
        out = np.where(mask[:, None], value, out)
    bad = ~np.isfinite(out).all(axis=1)
    if np.any(bad):  # fully degenerate (all corners equal, or collinear): brute force on edges
        out[bad] = _closest_on_edges(p[bad], a[bad], b[bad], c[bad])
    return out


def _closest_tolerant(p, a, b, c):
    """Ericson's closest point with trimesh 3.x's tolerances and branch order.

    Fully degenerate triangles can give NaN here, as in trimesh; NaN distances sort last.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return _closest_tolerant_raw(p, a, b, c)


def _closest_tolerant_raw(p, a, b, c):
    z = _ZERO
    result = np.zeros_like(p)
    remain = np.ones(len(p), dtype=bool)
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.dot(ab * ap, _ONES)
    d2 = np.dot(ac * ap, _ONES)
    is_a = (d1 < z) & (d2 < z)
    result[is_a] = a[is_a]
    remain &= ~is_a
    bp = p - b
    d3 = np.dot(ab * bp, _ONES)
    d4 = np.dot(ac * bp, _ONES)
    is_b = (d3 > -z) & (d4 <= d3) & remain
    result[is_b] = b[is_b]
    remain &= ~is_b
    vc = d1 * d4 - d3 * d2
    is_ab = (vc < z) & (d1 > -z) & (d3 < z) & remain
    if is_ab.any():
        v = d1[is_ab] / (d1[is_ab] - d3[is_ab])
        result[is_ab] = a[is_ab] + v[:, None] * ab[is_ab]
    remain &= ~is_ab
    cp = p - c
    d5 = np.dot(ab * cp, _ONES)
    d6 = np.dot(ac * cp, _ONES)
    is_c = (d6 > -z) & (d5 <= d6) & remain
    result[is_c] = c[is_c]
    remain &= ~is_c
    vb = d5 * d2 - d1 * d6
    is_ac = (vb < z) & (d2 > -z) & (d6 < z) & remain
    if is_ac.any():
        w = d2[is_ac] / (d2[is_ac] - d6[is_ac])
        result[is_ac] = a[is_ac] + w[:, None] * ac[is_ac]
    remain &= ~is_ac
    va = d3 * d6 - d5 * d4
    is_bc = (va < z) & ((d4 - d3) > -z) & ((d5 - d6) > -z) & remain
    if is_bc.any():
        d43 = d4[is_bc] - d3[is_bc]
        w = d43 / (d43 + (d5[is_bc] - d6[is_bc]))
        result[is_bc] = b[is_bc] + w[:, None] * (c[is_bc] - b[is_bc])
    remain &= ~is_bc
    if remain.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            denom = 1.0 / (va[remain] + vb[remain] + vc[remain])
        v = vb[remain] * denom
        w = vc[remain] * denom
        result[remain] = a[remain] + ab[remain] * v[:, None] + ac[remain] * w[:, None]
    return result


def _closest_on_edges(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    best = None
    best_d = None
    for s, e in ((a, b), (b, c), (c, a)):
        d = e - s
        length2 = np.einsum("ij,ij->i", d, d)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.clip(np.einsum("ij,ij->i", p - s, d) / length2, 0.0, 1.0)
        t = np.where(length2 > 0, t, 0.0)
        q = s + d * t[:, None]
        dist = np.einsum("ij,ij->i", p - q, p - q)
        if best is None:
            best, best_d = q, dist
        else:
            closer = dist < best_d
            best = np.where(closer[:, None], q, best)
            best_d = np.where(closer, dist, best_d)
    return best


def merge_vertices(vertices: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(float64 vertices, int64 triangles) as ``trimesh.Trimesh(v, f, process=True)`` leaves them."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64)
    referenced = np.zeros(len(v), dtype=bool)
    referenced[f] = True
    keys = np.round(v * 1e8).astype(np.int64)
    ref_index = np.nonzero(referenced)[0]
    _, first, inverse = np.unique(keys[ref_index], axis=0, return_index=True, return_inverse=True)
    # unique rows in order of first occurrence
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    new_index = np.zeros(len(v), dtype=np.int64)
    new_index[ref_index] = rank[inverse.reshape(-1)]
    kept = ref_index[first[order]]
    return v[kept], new_index[f]
