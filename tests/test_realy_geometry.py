"""REALY geometry kernels and readers: exact closest points, vertex merging, OBJ semantics."""

from __future__ import annotations

import numpy as np
import pytest

from facegeo.errors import InputError
from facegeo.eval.realy_align import fit_transform
from facegeo.eval.realy_geometry import SurfaceQuery, closest_points, merge_vertices, point_triangle_closest
from facegeo.eval.realy_io import read_keypoint_file, read_obj
from facegeo.model_files import load_model


def _brute(vertices, triangles, queries):
    out = []
    for q in queries:
        p = point_triangle_closest(np.repeat(q[None], len(triangles), 0), *(vertices[triangles[:, k]] for k in range(3)))
        out.append(p[np.argmin(((p - q) ** 2).sum(axis=1))])
    return np.array(out)


@pytest.fixture(scope="module")
def head():
    m = load_model()
    return m.mean_shape.astype(np.float64) / 9.0, m.triangles


def test_closest_points_are_exact_in_float64(head):
    v, f = head
    rng = np.random.default_rng(1)
    q = v[rng.choice(len(v), 200)] + rng.normal(scale=0.5, size=(200, 3))
    exact = _brute(v, f, q)
    assert np.abs(closest_points(v, f, q) - exact).max() < 1e-12
    # trimesh's rule moves a point only where another face is within 1e-8 in squared distance
    picked = SurfaceQuery(f)(v, q)
    d_exact = ((exact - q) ** 2).sum(axis=1)
    d_picked = ((picked - q) ** 2).sum(axis=1)
    assert np.all(d_picked - d_exact < 1e-8 + 1e-15)


def test_degenerate_triangles_act_as_their_segment_or_point(head):
    v, f = head
    v = v.copy()
    f = f.copy()
    # a zero-area face (a repeated vertex) and a collapsed face (three equal corners)
    f[100] = [f[100, 0], f[100, 0], f[100, 1]]
    v = np.vstack([v, v[f[200, 0]][None].repeat(3, 0)])
    f[200] = [len(v) - 3, len(v) - 2, len(v) - 1]
    rng = np.random.default_rng(2)
    centres = v[f[[100, 200, 300]]].mean(axis=1)
    q = np.repeat(centres, 20, axis=0) + rng.normal(scale=0.3, size=(60, 3))
    exact = _brute(v, f, q)
    assert np.abs(closest_points(v, f, q) - exact).max() < 1e-12
    picked = SurfaceQuery(f)(v, q)
    assert np.all(np.isfinite(picked))
    assert np.all(((picked - q) ** 2).sum(axis=1) - ((exact - q) ** 2).sum(axis=1) < 1e-8 + 1e-15)


def test_one_tree_serves_rigid_motions_of_the_mesh(head):
    v, f = head
    rng = np.random.default_rng(3)
    q = v[rng.choice(len(v), 300)] + rng.normal(scale=0.5, size=(300, 3))
    query = SurfaceQuery(f)
    first = query(v, q)
    angle = 0.3
    rotation = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    moved = (v @ rotation.T + [3.0, -1.0, 2.0]).astype(np.float32)  # as the regional ICP moves it
    q_moved = q @ rotation.T + [3.0, -1.0, 2.0]
    got = query(moved, q_moved)
    assert query.trees_built == 1
    fresh = SurfaceQuery(f)(moved, q_moved)  # a tree of its own
    assert np.array_equal(got, fresh)
    assert np.abs(got - (first @ rotation.T + [3.0, -1.0, 2.0])).max() < 1e-5
    # a non-rigid change of the vertices is not mistaken for a motion: a new tree
    bent = v.copy()
    bent[:, 2] += 0.05 * np.sin(bent[:, 0])
    assert np.array_equal(query(bent, q), SurfaceQuery(f)(bent, q))
    assert query.trees_built == 2


def test_merge_vertices_follows_trimesh_process():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [1, 0, 0], [0, 1, 1e-9]], dtype=np.float32)
    f = np.array([[0, 1, 2], [0, 4, 5]])
    mv, mf = merge_vertices(v, f)
    # vertex 3 unused: dropped; 4 duplicates 1; 5 equals 2 after rounding to 1e-8? no: 1e-9 rounds to 0
    assert mv.tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    assert mf.tolist() == [[0, 1, 2], [0, 1, 2]]
    v2 = v.copy()
    v2[5, 2] = 1e-6
    mv2, mf2 = merge_vertices(v2, f)
    assert len(mv2) == 4 and mf2.tolist() == [[0, 1, 2], [0, 1, 3]]


def test_obj_reader_splits_quads_like_the_official_reader(tmp_path):
    path = tmp_path / "q.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1 4/1\nf 1 2 3\n")
    mesh = read_obj(path)
    assert mesh.vertices.dtype == np.float32
    assert mesh.triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 2]]
    path.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 2 2\nf 1 2 3 4 5\n")
    with pytest.raises(InputError, match="5 corners"):
        read_obj(path)
    path.write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="1..2"):
        read_obj(path)


def test_obj_reader_fast_and_line_by_line_paths_agree(tmp_path):
    # well-formed files take a vectorised path; one odd line sends the file line by line
    rng = np.random.default_rng(4)
    v = rng.normal(size=(40, 3))
    faces = [rng.choice(40, size=rng.choice([3, 4]), replace=False) + 1 for _ in range(60)]
    v_lines = [f"v {x!r} {y!r} {z!r} 0.5 0.5 0.5" for x, y, z in v.tolist()]  # with vertex colours
    f_lines = ["f " + " ".join(f"{i}/{i}/{i}" if k % 2 else str(i) for i in f) for k, f in enumerate(faces)]
    expected = []
    for f in faces:
        expected += [[f[0], f[1], f[2]]] + ([[f[0], f[2], f[3]]] if len(f) == 4 else [])
    path = tmp_path / "m.obj"
    path.write_text("\n".join(v_lines + ["vt 0 0"] + f_lines) + "\n")
    mesh = read_obj(path)
    assert np.array_equal(mesh.vertices, v.astype(np.float32))
    assert mesh.triangles.tolist() == (np.array(expected) - 1).tolist()
    # a negative (relative) index sends the file line by line, and is an error there
    path.write_text("\n".join(v_lines + ["vt 0 0"] + f_lines + ["f 1 2 -40"]) + "\n")
    with pytest.raises(InputError, match="index -40"):
        read_obj(path)
    path.write_text("v 0 0 0\nv 1 0 zero\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="numbers"):
        read_obj(path)
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 x\n")
    with pytest.raises(InputError, match="line 4"):
        read_obj(path)


def test_keypoint_file_checks(tmp_path):
    path = tmp_path / "k.txt"
    path.write_text("[[0, 1, 0]]")
    with pytest.raises(InputError, match="85 rows"):
        read_keypoint_file(path)
    path.write_text(str([[5, 0.2, 0.3]] * 85))
    tri, w = read_keypoint_file(path, n_triangles=10)
    assert tri.tolist() == [5] * 85 and w[0].tolist() == pytest.approx([0.2, 0.3, 0.5])
    with pytest.raises(InputError, match="below 3"):
        read_keypoint_file(path, n_triangles=3)


def test_fit_transform_uses_realys_scale_rule():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(7, 3))
    angle = 0.4
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    tgt = 2.5 * src @ rot.T + [1.0, 2.0, 3.0]
    scale, r, t = fit_transform(src, tgt.astype(np.float32), with_scale=True)
    assert scale == pytest.approx(2.5, rel=1e-6) and np.allclose(r, rot, atol=1e-6)
    # with noise the scale is sum|t - mean| / sum|R (s - mean)|, not Umeyama's
    noisy = (tgt + rng.normal(scale=0.1, size=tgt.shape)).astype(np.float32)
    scale, r, _ = fit_transform(src, noisy, with_scale=True)
    t1 = noisy - noisy.mean(axis=0)
    s1 = src - src.mean(axis=0)
    assert scale == pytest.approx(np.abs(t1).sum() / np.abs(s1 @ r.T).sum(), rel=1e-6)


def test_pruned_ring_search_equals_the_full_one(head):
    # queries near the surface, on edges and vertices (ties), and farther out: the faces skipped by
    # the lower bound never change trimesh's pick, bit for bit
    v, f = head
    rng = np.random.default_rng(5)
    corners = v[f[rng.choice(len(f), 400)]]
    w = rng.dirichlet([1.0, 1.0, 1.0], 400)
    w[:100, 0] = 0.0  # on an edge
    w[:100] /= w[:100].sum(axis=1, keepdims=True)
    w[100:150] = [1.0, 0.0, 0.0]  # on a vertex
    on_surface = np.einsum("nk,nkj->nj", w, corners)
    q = np.vstack([on_surface + rng.normal(scale=s, size=on_surface.shape) for s in (1e-7, 1e-3, 0.3, 3.0)])
    pruned = SurfaceQuery(f)
    full = SurfaceQuery(f)
    full.prune = False
    assert np.array_equal(pruned(v, q), full(v, q))
    moved = (v * 1.01 + [0.5, 0.0, -0.2]).astype(np.float32)  # another frame: a new tree, the same rule
    assert np.array_equal(pruned(moved, q), full(moved, q))


def test_near_ties_are_the_queries_round_off_could_flip():
    # a unit square in z = 0 split along its diagonal; queries one unit above it
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    off = 1e-4 / np.sqrt(2)  # 1e-4 from the diagonal: squared distances 1 and 1 + 1e-8
    q = np.array([[0.9, 0.1, 1.0], [0.5, 0.5, 1.0], [0.5 + off, 0.5 - off, 1.0]])
    query = SurfaceQuery(f)
    points = query(v, q, jitter=1e-9)
    assert np.allclose(points[0], [0.9, 0.1, 0.0]) and np.allclose(points[1], [0.5, 0.5, 0.0])
    assert query.near_ties.tolist() == [False, True, True]
    # the two nearest candidates of the last query: its foot in the first triangle, the diagonal point
    assert np.allclose(np.sort(query.alternatives[2, :, 0]), [0.5, 0.5 + off], atol=1e-12)
    query(v, q)  # without jitter nothing is looked for
    assert not query.near_ties.any()


def test_queries_on_the_same_vertices_share_one_tree(head):
    v, f = head
    q = v[::7] + 0.25
    first, second = SurfaceQuery(f), SurfaceQuery(f)
    a, b = first(v, q), second(v.copy(), q)
    assert second._tree is first._tree and np.array_equal(a, b)  # the regions of one prediction
    other = SurfaceQuery(f)
    other(v + 1.0, q)  # other vertices: a tree of their own
    assert other._tree is not first._tree
