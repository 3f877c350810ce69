"""The bundled REALY keypoint file of the ICT-FaceKit topology: format, provenance, semantics."""

from __future__ import annotations

import json

import numpy as np
import pytest

from facegeo.assets import asset_path
from make_ict_keypoints import (
    EXTRA_POINTS,
    averaged_table,
    extra_point_positions,
    eye_frame,
    first_hits,
    ict_keypoints,
    measure,
)
from facegeo.eval.realy_io import barycentric_points, read_keypoint_file
from facegeo.landmarks.scheme import EYES, IBUG68, JAW_ENDS, NOSTRILS


@pytest.fixture(scope="module")
def points(model):
    tri, w = read_keypoint_file(asset_path("realy/ICT-FaceKit.txt"), len(model.triangles))
    return barycentric_points(model.mean_shape.astype(np.float64), model.triangles, tri, w)


def test_file_is_what_the_script_makes(model):
    rows = json.loads(asset_path("realy/ICT-FaceKit.txt").read_text())
    assert rows == json.loads(json.dumps(ict_keypoints(model.mean_shape, model.triangles, model.landmark_indices[IBUG68])))
    assert len(rows) == 85
    table = np.array(rows, dtype=float)
    w = np.column_stack([table[:, 1], table[:, 2], 1 - table[:, 1] - table[:, 2]])
    assert np.all(w >= -1e-12) and np.allclose(w.sum(axis=1), 1.0)


def test_first_68_are_icts_multipie_vertices(model, points):
    assert np.allclose(points[IBUG68], model.mean_shape[model.landmark_indices[IBUG68]], atol=1e-9)


def test_extra_points_are_frontal_surface_points_at_their_documented_places(model, points):
    v = model.mean_shape.astype(np.float64)
    origin, unit, axes = eye_frame(points[IBUG68])
    local = (points - origin) @ axes.T / unit
    for index, _, x, y in EXTRA_POINTS:
        assert local[index, :2] == pytest.approx([x, y], abs=1e-9), index
    # each is the first surface point seen from the front along the ray through it
    extra = [e[0] for e in EXTRA_POINTS]
    starts = points[extra] + axes[2] * 2.0 * unit
    tri, u, w = first_hits(v, model.triangles, starts, -axes[2])
    a, b, c = (v[model.triangles[tri][:, k]] for k in range(3))
    hits = (1 - u - w)[:, None] * a + u[:, None] * b + w[:, None] * c
    assert np.allclose(hits, points[extra], atol=1e-6)


def test_extra_points_are_at_the_right_semantic_places(points):
    p = points
    origin, unit, axes = eye_frame(p[IBUG68])
    q = (p - origin) @ axes.T / unit  # eye frame: x to the subject's left, y up, z to the viewer
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    pairs = [(68, 69), (70, 71), (72, 73), (74, 75), (76, 77), (78, 80), (81, 82), (83, 84)]
    for r, l in pairs:  # mirror pairs: right side (-x) first, symmetric within 2 mm
        assert x[r] < 0 < x[l]
        assert np.linalg.norm(q[r] * [-1, 1, 1] - q[l]) * unit < 2.0, (r, l)
    eye_y = y[EYES].mean()
    nose_bottom = y[NOSTRILS].mean()
    assert all(nose_bottom < y[k] < eye_y for k in (68, 69))  # below the eyes, above the nose
    assert all(abs(x[k]) > abs(x[31]) and y[33] - 0.1 < y[k] < y[29] for k in (70, 71))  # beside the nose wing
    assert all(abs(x[k]) > abs(x[48]) and abs(y[k] - y[48]) < 0.15 for k in (72, 73))  # beside the mouth corners
    assert all(y[8] < y[k] < y[57] for k in (78, 79, 80))  # chin: below the lower lip, above the menton
    assert abs(x[79]) < 1e-6 and z[79] > z[8]
    assert all(abs(x[k]) > abs(x[68]) for k in (74, 75, 76, 77, 81, 82, 83, 84))  # lateral cheek points
    assert np.all(z[68:85] > z[JAW_ENDS].max() - 0.1)  # on the front of the face, not behind the jaw ends


def test_measuring_the_table_on_a_topology_gives_its_extra_points(model, tmp_path):
    # the measuring code of --measure, run on the ICT-FaceKit template and its keypoint file (whose
    # extra points are frontal surface points at EXTRA_POINTS): it reads the table back
    rows = json.loads(asset_path("realy/ICT-FaceKit.txt").read_text())
    xy = extra_point_positions(model.mean_shape, model.triangles, rows)
    assert np.abs(xy - np.array([[x, y] for _, _, x, y in EXTRA_POINTS])).max() < 1e-9
    from facegeo.mesh_io import obj_text

    for name in ("A", "B"):
        (tmp_path / f"{name}.obj").write_text(obj_text(model.mean_shape, model.triangles, digits=6, comment=False))
        (tmp_path / f"{name}.txt").write_text(json.dumps(rows))
    assert measure(tmp_path, ("A", "B")) == {i: (x, y) for i, _, x, y in EXTRA_POINTS}
    # averaging and symmetrising: a right point measured 0.02 farther out moves both of its pair by 0.01
    shifted = xy.copy()
    shifted[0, 0] -= 0.02
    table = averaged_table([shifted])
    assert table[68] == (-0.47, -0.17) and table[69] == (0.47, -0.17) and table[79] == (0.0, -0.97)
