"""The truth of the scan renders (benchmarks/scan_renders.py) without Blender or downloads: the
ray-cast point maps and the scans' frontal rotation on known answers."""

import sys
from pathlib import Path

import numpy as np
import pytest

from facegeo import Camera, project
from facegeo.camera import rotation_from_euler
from facegeo.landmarks.scheme import INNER_FACE

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from head_scans import HeadScan, SCANS  # noqa: E402
from scan_renders import cast_rays, frontal_rotation, view_pose, VIEWS  # noqa: E402


def test_point_maps_hit_a_known_plane_at_each_pixel_centre():
    square = np.array([[-400.0, -400.0, 0.0], [400.0, -400.0, 0.0], [400.0, 400.0, 0.0], [-400.0, 400.0, 0.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    camera = Camera(focal=100.0, cx=30.0, cy=21.0, width=64, height=48)
    rotation, translation = np.eye(3), np.array([5.0, -3.0, -600.0])
    points, triangle = cast_rays(square, triangles, rotation, translation, camera)
    assert points.shape == (48, 64, 3) and triangle.shape == (48, 64)
    u, v = np.meshgrid(np.arange(64) + 0.5, np.arange(48) + 0.5)
    expected_x = (u - camera.cx) / camera.focal * 600.0 - 5.0
    expected_y = -(v - camera.cy) / camera.focal * 600.0 + 3.0
    np.testing.assert_allclose(points[..., 0], expected_x, atol=1e-3)
    np.testing.assert_allclose(points[..., 1], expected_y, atol=1e-3)
    np.testing.assert_allclose(points[..., 2], 0.0, atol=1e-3)
    assert np.all(triangle >= 0)
    # and back: the points project onto the pixel centres they were cast through
    back = project(points.reshape(-1, 3), rotation, translation, camera).reshape(48, 64, 2)
    np.testing.assert_allclose(back, np.stack([u, v], axis=-1), atol=1e-4)


def test_rays_that_miss_give_nan_and_minus_one():
    tiny = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0]])
    camera = Camera(focal=100.0, cx=8.0, cy=8.0, width=16, height=16)
    points, triangle = cast_rays(tiny, np.array([[0, 1, 2]]), np.eye(3), np.array([0.0, 0.0, -600.0]), camera,
                                 pixels=np.array([[8.0, 8.0], [0.5, 0.5]]))
    assert triangle.tolist() == [0, -1]
    assert np.all(np.isfinite(points[0])) and np.all(np.isnan(points[1]))


def test_frontal_rotation_undoes_the_scan_frame_and_views_keep_their_angles(model):
    turn = rotation_from_euler(35.0, -20.0, 10.0)
    landmarks = model.mean_shape[model.landmark_indices[:68]].astype(np.float64)
    scan = HeadScan(name="synthetic", vertices=landmarks, triangles=np.zeros((0, 3), np.int64), uv=np.zeros((0, 2)),
                    uv_triangles=np.zeros((0, 3), np.int64), texture=Path("none"), annotation=landmarks @ turn.T + 7.0,
                    source=SCANS["james"])
    np.testing.assert_allclose(frontal_rotation(scan), turn.T, atol=1e-9)
    spec = next(v for v in VIEWS if v.name == "yaw-20")
    rotation, translation = view_pose(scan, spec)
    np.testing.assert_allclose(rotation @ turn, rotation_from_euler(-20.0, 0.0, 0.0), atol=1e-9)
    # the face centre sits on the optical axis at the view's distance
    centre = scan.annotation[INNER_FACE].mean(0)
    assert rotation @ centre + translation == pytest.approx([0.0, 0.0, -spec.distance_mm], abs=1e-9)


def test_the_committed_scan_loads_with_its_landmarks_in_ibug_order(tmp_path):
    from head_scans import load_scan

    scan = load_scan("lee_perry_smith", cache=tmp_path)
    assert scan.vertices.shape == (8844, 3) and scan.triangles.shape == (17684, 3)
    assert scan.uv_triangles.shape == scan.triangles.shape and scan.texture.exists()
    assert 0.0 <= scan.uv.min() and scan.uv.max() <= 1.0
    a = scan.annotation
    # iBUG order on a frontal face: the subject's right (image left, −x) comes first
    rotation = frontal_rotation(scan)
    front = a @ rotation.T
    assert front[36, 0] < front[45, 0] and front[0, 0] < front[16, 0] and front[48, 0] < front[54, 0]
    assert front[8, 1] < front[33, 1] < front[27, 1]  # chin below the nose below the bridge
    assert front[30, 2] == pytest.approx(front[INNER_FACE, 2].max(), abs=3.0)  # the nose tip is the most forward inner point
    # an average-sized head (the scale is estimated that way): Farkas ex–ex 91 ± 4, ch–ch 54 ± 3 mm
    assert 80.0 < np.linalg.norm(a[36] - a[45]) < 100.0
    assert 40.0 < np.linalg.norm(a[48] - a[54]) < 60.0


def test_a_committed_scan_whose_file_changed_is_refused(tmp_path, monkeypatch):
    import dataclasses

    import head_scans
    from facegeo.errors import InputError

    changed = dataclasses.replace(SCANS["lee_perry_smith"], sha256="0" * 64)
    monkeypatch.setitem(head_scans.SCANS, "lee_perry_smith", changed)
    with pytest.raises(InputError, match="sha256"):
        head_scans.load_scan("lee_perry_smith", cache=tmp_path)


def test_quads_are_split_into_two_triangles_with_their_uvs(tmp_path):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks" / "data" / "lee_perry_smith"))
    from convert_lee_perry_smith import read_quad_obj

    obj = tmp_path / "quad.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\nf 1/4 2/3 3/2\n")
    vertices, triangles, uv, uv_triangles = read_quad_obj(obj)
    assert triangles.tolist() == [[0, 1, 2], [0, 2, 3], [0, 1, 2]]
    assert uv_triangles.tolist() == [[0, 1, 2], [0, 2, 3], [3, 2, 1]]
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n")
    with pytest.raises(ValueError, match="without UVs"):
        read_quad_obj(obj)
