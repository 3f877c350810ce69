"""facegeo.uv tangents: MikkTSpace, compared with the reference C implementation (the pymikktspace
binding, where installed) and with values recorded from it; invariants of the tangent frame."""

import numpy as np
import pytest

from facegeo.errors import InputError
from facegeo.uv import mesh_tangents, mikktspace_tangents, vertex_normals
from facegeo.camera import rotation_from_euler


def small_mesh():
    """A bumpy 5x4 grid (24 triangles) whose right half has its own, mirrored UV island, one
    triangle with a zero-area UV triangle, one degenerate (two corners at one position) triangle and
    a flap on an interior edge (a non-manifold edge): 26 triangles."""
    xs, ys = np.meshgrid(np.arange(5.0), np.arange(4.0))
    z = 0.3 * np.sin(xs * 1.3) * np.cos(ys * 0.9)
    V = np.stack([xs.ravel(), ys.ravel(), z.ravel()], 1)
    tris = []
    for j in range(3):
        for i in range(4):
            a = j * 5 + i
            tris += [[a, a + 1, a + 6], [a, a + 6, a + 5]]
    T = np.array(tris)
    uv = np.stack([xs.ravel() / 4 * 0.45, ys.ravel() / 3 * 0.9], 1)
    uvt = T.copy()
    uv2 = uv.copy()
    uv2[:, 0] = 1.0 - uv2[:, 0]
    right = V[T][:, :, 0].min(1) >= 2
    uvt[right] = T[right] + len(uv)
    uv = np.concatenate([uv, uv2, [[0.2, 0.95]]])
    uvt[5] = [len(uv) - 1] * 3
    V = np.concatenate([V, [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.5, 1.2, 0.1], [1.5, 1.5, 1.0]]])
    T = np.concatenate([T, [[20, 21, 22], [6, 7, 23]]])
    uvt = np.concatenate([uvt, [[0, 1, 2], [6, 7, 3]]])
    return V.astype(np.float32), T, uv.astype(np.float32), uvt


#: pymikktspace 0.3.0 (Mikkelsen's reference C code, genTangSpaceDefault) on small_mesh() with
#: vertex_normals(): per corner tangent x, y, z and sign, 7 decimals.
REFERENCE = np.array([
    ( 0.9736164,  0.0000516,  0.2281907, +1),
    ( 0.9996890, -0.0058878,  0.0242353, +1),
    ( 0.9973950,  0.0000073,  0.0721338, +1),
    ( 0.9736164,  0.0000516,  0.2281907, +1),
    ( 0.9973950,  0.0000073,  0.0721338, +1),
    ( 0.9952279, -0.0016130,  0.0975640, +1),
    ( 0.9996890, -0.0058878,  0.0242353, +1),
    ( 0.9724060, -0.0012907, -0.2332914, +1),
    ( 0.9940953,  0.0010674, -0.1085060, +1),
    ( 0.9996890, -0.0058878,  0.0242353, +1),
    ( 0.9940953,  0.0010674, -0.1085060, +1),
    ( 0.9973950,  0.0000073,  0.0721338, +1),
    (-0.9723979, -0.0014067,  0.2333245, -1),
    (-0.9885797,  0.0038286,  0.1506505, -1),
    (-0.9896919, -0.0018379,  0.1432011, -1),
    ( 1.0000000,  0.0000000,  0.0000000, -1),
    ( 1.0000000,  0.0000000,  0.0000000, -1),
    ( 1.0000000,  0.0000000,  0.0000000, -1),
    (-0.9885797,  0.0038286,  0.1506505, -1),
    (-0.9982812,  0.0000000,  0.0586056, -1),
    (-0.9990393, -0.0002414,  0.0438226, -1),
    (-0.9885797,  0.0038286,  0.1506505, -1),
    (-0.9990393, -0.0002414,  0.0438226, -1),
    (-0.9896919, -0.0018379,  0.1432011, -1),
    ( 0.9952279, -0.0016130,  0.0975640, +1),
    ( 0.9973950,  0.0000073,  0.0721338, +1),
    ( 0.9992718,  0.0022466,  0.0380919, +1),
    ( 0.9952279, -0.0016130,  0.0975640, +1),
    ( 0.9992718,  0.0022466,  0.0380919, +1),
    ( 0.9915498, -0.0010558, -0.1297221, +1),
    ( 0.9973950,  0.0000073,  0.0721338, +1),
    ( 0.9940953,  0.0010674, -0.1085060, +1),
    ( 0.9970006,  0.0071999,  0.0770576, +1),
    ( 0.9973950,  0.0000073,  0.0721338, +1),
    ( 0.9970006,  0.0071999,  0.0770576, +1),
    ( 0.9992718,  0.0022466,  0.0380919, +1),
    (-0.9941097, -0.0031444,  0.1083324, -1),
    (-0.9896919, -0.0018379,  0.1432011, -1),
    (-0.9999937, -0.0012015, -0.0033679, -1),
    (-0.9941097, -0.0031444,  0.1083324, -1),
    (-0.9999937, -0.0012015, -0.0033679, -1),
    (-0.9969071,  0.0062222, -0.0783424, -1),
    (-0.9896919, -0.0018379,  0.1432011, -1),
    (-0.9990393, -0.0002414,  0.0438226, -1),
    (-0.9999949, -0.0007991,  0.0031176, -1),
    (-0.9896919, -0.0018379,  0.1432011, -1),
    (-0.9999949, -0.0007991,  0.0031176, -1),
    (-0.9999937, -0.0012015, -0.0033679, -1),
    ( 0.9915498, -0.0010558, -0.1297221, +1),
    ( 0.9992718,  0.0022466,  0.0380919, +1),
    ( 0.9976987, -0.0064833, -0.0674940, +1),
    ( 0.9915498, -0.0010558, -0.1297221, +1),
    ( 0.9976987, -0.0064833, -0.0674940, +1),
    ( 0.9675065,  0.0000000, -0.2528461, +1),
    ( 0.9992718,  0.0022466,  0.0380919, +1),
    ( 0.9970006,  0.0071999,  0.0770576, +1),
    ( 0.9876895,  0.0107482,  0.1560574, +1),
    ( 0.9992718,  0.0022466,  0.0380919, +1),
    ( 0.9876895,  0.0107482,  0.1560574, +1),
    ( 0.9976987, -0.0064833, -0.0674940, +1),
    (-0.9969071,  0.0062222, -0.0783424, -1),
    (-0.9999937, -0.0012015, -0.0033679, -1),
    (-0.9883893,  0.0016053, -0.1519348, -1),
    (-0.9969071,  0.0062222, -0.0783424, -1),
    (-0.9883893,  0.0016053, -0.1519348, -1),
    (-0.9868688,  0.0207742, -0.1601821, -1),
    (-0.9999937, -0.0012015, -0.0033679, -1),
    (-0.9999949, -0.0007991,  0.0031176, -1),
    (-0.9994490, -0.0000167, -0.0331910, -1),
    (-0.9999937, -0.0012015, -0.0033679, -1),
    (-0.9994490, -0.0000167, -0.0331910, -1),
    (-0.9883893,  0.0016053, -0.1519348, -1),
    ( 1.0000000,  0.0000000,  0.0000000, -1),
    ( 1.0000000,  0.0000000,  0.0000000, -1),
    ( 1.0000000,  0.0000000,  0.0000000, -1),
    ( 0.9973949, -0.0005133,  0.0721321, -1),
    ( 0.9941031,  0.0021194, -0.1084181, -1),
    ( 0.9965275,  0.0000000, -0.0832648, -1),
], dtype=np.float64)


def test_small_mesh_matches_the_reference_implementation():
    V, T, uv, uvt = small_mesh()
    got = mesh_tangents(V, T, uv, uvt).reshape(-1, 4)
    np.testing.assert_allclose(got[:, :3], REFERENCE[:, :3], atol=2e-6)
    np.testing.assert_array_equal(got[:, 3], REFERENCE[:, 3])


def _reference(P, N, UV):
    mikktspace = pytest.importorskip("mikktspace")
    out = mikktspace.gen_default(np.arange(P.shape[0] * 3), np.ascontiguousarray(P, np.float32).ravel(),
                                 np.ascontiguousarray(N, np.float32).ravel(), np.ascontiguousarray(UV, np.float32).ravel())
    return np.array(out, dtype=np.float32).reshape(-1, 3, 4)


@pytest.mark.parametrize("case", ["mean", "degenerate_uv", *(pytest.param(c, marks=pytest.mark.slow)
                                                              for c in ("identity", "mirrored", "degenerate_mesh"))])
def test_ict_matches_pymikktspace(model, case):
    """Bit-equal to the reference except where its neighbour search skips an edge: the 2011 C code
    leaves the last run of its sorted edge list unsorted and can miss a pairing there (Blender's
    C++ port pairs every edge, as we do). At most one welded vertex may differ."""
    rng = np.random.default_rng(3)
    V = model.mean_shape.copy()
    uv, uvt, tri = model.uv.copy(), model.uv_triangles.copy(), model.triangles
    if case == "identity":
        V = V + np.einsum("k,kvc->vc", rng.standard_normal(model.n_id).astype(np.float32), model.id_basis)
    elif case == "degenerate_uv":
        sel = rng.choice(len(tri), 300, replace=False)
        uvt[sel, 1] = uvt[sel, 0]
    elif case == "mirrored":
        left = np.unique(uvt[(V[tri][:, :, 0] < 0).all(1)])
        uv[left, 0] = 1.0 - uv[left, 0]
    elif case == "degenerate_mesh":
        sel = rng.choice(len(tri), 100, replace=False)
        V[tri[sel, 1]] = V[tri[sel, 0]]
    n = vertex_normals(V, tri)
    ref = _reference(V[tri], n[tri], uv[uvt])
    got = mesh_tangents(V, tri, uv, uvt)
    assert np.isfinite(got).all()
    diff = np.abs(got - ref).max(axis=2)
    bad = np.argwhere(diff > 1e-6)
    assert len(bad) <= 8
    assert len({int(tri[f, c]) for f, c in bad}) <= 1
    np.testing.assert_array_equal(got[..., 3], ref[..., 3])


def test_frame_invariants_on_ict(model):
    V = model.mean_shape
    n = vertex_normals(V, model.triangles)
    t = mesh_tangents(V, model.triangles, model.uv, model.uv_triangles)
    tang, sign = t[..., :3], t[..., 3]
    np.testing.assert_allclose(np.linalg.norm(tang, axis=-1), 1.0, atol=1e-5)
    # orthogonal to the vertex normal, all UV triangles of ICT preserve orientation
    cos = np.abs((tang * n[model.triangles]).sum(-1))
    assert cos.max() < 1e-5
    assert (sign == 1).all()
    # the tangent follows +u: it agrees with each triangle's dP/du
    P = V[model.triangles].astype(np.float64)
    T = model.uv[model.uv_triangles].astype(np.float64)
    d1, d2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    t1, t2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    det = t1[:, 0] * t2[:, 1] - t1[:, 1] * t2[:, 0]
    dpdu = (d1 * t2[:, 1:2] - d2 * t1[:, 1:2]) / det[:, None]
    assert ((tang.mean(1) * dpdu).sum(-1) > 0).mean() > 0.999


def test_flat_plane_gives_exact_axes_and_mirroring_flips_sign():
    V = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0]], np.float32)
    T = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    t = mesh_tangents(V, T, uv, T)
    np.testing.assert_allclose(t[..., :3].reshape(-1, 3), [[1, 0, 0]] * 6, atol=1e-7)
    assert (t[..., 3] == 1).all()
    mirrored = uv.copy()
    mirrored[:, 0] = 1 - mirrored[:, 0]
    t = mesh_tangents(V, T, mirrored, T)
    np.testing.assert_allclose(t[..., :3].reshape(-1, 3), [[-1, 0, 0]] * 6, atol=1e-7)
    assert (t[..., 3] == -1).all()
    # bitangent = sign * cross(N, T) points along +v in both cases
    n = np.array([0, 0, 1.0])
    assert np.allclose(t[0, 0, 3] * np.cross(n, t[0, 0, :3]), [0, 1, 0])


def test_rotation_equivariance(model):
    R = rotation_from_euler(30, -20, 10).astype(np.float32)
    V = model.mean_shape
    a = mesh_tangents(V, model.triangles, model.uv, model.uv_triangles)
    b = mesh_tangents(V @ R.T, model.triangles, model.uv, model.uv_triangles)
    np.testing.assert_allclose(a[..., :3] @ R.T, b[..., :3], atol=2e-4)
    np.testing.assert_array_equal(a[..., 3], b[..., 3])


def test_mesh_and_soup_forms_agree(model):
    V = model.mean_shape
    n = vertex_normals(V, model.triangles)
    a = mesh_tangents(V, model.triangles, model.uv, model.uv_triangles)
    b = mikktspace_tangents(V[model.triangles], n[model.triangles], model.uv[model.uv_triangles])
    np.testing.assert_array_equal(a, b)


def test_all_degenerate_and_bad_input():
    P = np.zeros((2, 3, 3), np.float32)
    out = mikktspace_tangents(P, P, np.zeros((2, 3, 2), np.float32))
    np.testing.assert_array_equal(out[..., :3].reshape(-1, 3), [[1, 0, 0]] * 6)
    assert (out[..., 3] == -1).all()
    with pytest.raises(InputError):
        mikktspace_tangents(np.zeros((2, 3)), P, P)
    bad = P.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError):
        mikktspace_tangents(bad, P, np.zeros((2, 3, 2)))


def test_angular_threshold_split_path(model, monkeypatch):
    """The reference's sub-groups (only exactly opposite directions split at the default 180°):
    with a 2° threshold forced, groups split and every corner still gets a unit tangent in the
    normal's plane, within 90° of its own triangle's ∂P/∂u."""
    import facegeo.uv.tangents as tangents

    V = model.mean_shape
    default = mesh_tangents(V, model.triangles, model.uv, model.uv_triangles)
    monkeypatch.setattr(tangents, "_THRESHOLD_COS", np.float32(np.cos(np.radians(2.0))))
    n = vertex_normals(V, model.triangles)[model.triangles]
    t = mikktspace_tangents(V[model.triangles], n, model.uv[model.uv_triangles])
    tang = t[..., :3]
    np.testing.assert_allclose(np.linalg.norm(tang, axis=-1), 1.0, atol=1e-5)
    assert np.abs((tang * n).sum(-1)).max() < 1e-5
    P = V[model.triangles].astype(np.float64)
    T = model.uv[model.uv_triangles].astype(np.float64)
    d1, d2 = P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]
    t1, t2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    dpdu = d1 * t2[:, 1:2] - d2 * t1[:, 1:2]
    assert ((tang * dpdu[:, None, :]).sum(-1) > 0).all()
    assert np.abs(default[..., :3] - tang).max() > 1e-3  # the split changed something
