"""The hybrid detector's box for dlib's predictor: from MediaPipe's face, HOG only as a fallback."""

from __future__ import annotations

import numpy as np
import pytest

from facegeo.landmarks.detectors import DlibDetector, HybridDetector, MediaPipeDetector, dlib_box_from_mediapipe
from facegeo.landmarks.dlib_detector import DlibLandmarker
from facegeo.landmarks.mediapipe_mesh import MediaPipeFaceMesh, ibug68_from_mesh
from facegeo.photo import load_photo

pytest.importorskip("dlib")


@pytest.fixture(scope="module")
def photo() -> np.ndarray:
    from facegeo.assets import asset_path

    return load_photo(asset_path("photos/astronaut.png")).image


class _NoHog(DlibLandmarker):
    def boxes(self, image: np.ndarray) -> list:
        raise AssertionError("HOG ran although MediaPipe found the face")


class _NoFaceMesh(MediaPipeFaceMesh):
    def __call__(self, image: np.ndarray) -> list:
        return []


def test_hybrid_runs_dlib_in_the_box_from_mediapipe_without_hog(photo):
    mediapipe = MediaPipeDetector()
    found = HybridDetector(DlibDetector(_NoHog()), mediapipe).detect(photo)
    face = mediapipe.mesh(photo)[0]
    box = dlib_box_from_mediapipe(ibug68_from_mesh(face.mesh))
    np.testing.assert_array_equal(found.points[:68], DlibLandmarker().landmarks(photo, box))
    assert found.detector == "hybrid" and found.notes == () and found.dense is not None


def test_box_from_mediapipe_is_near_hogs(photo):
    """On the bundled photo HOG's box is (175, 76, 265, 166); the calibrated one is within 10 %
    of its side at every corner."""
    face = MediaPipeFaceMesh()(photo)[0]
    box = dlib_box_from_mediapipe(ibug68_from_mesh(face.mesh))
    hog = np.array([175, 76, 265, 166], dtype=np.float32)
    assert box.dtype == np.float32 and box.shape == (4,)
    assert np.abs(box - hog).max() < 0.1 * (hog[2] - hog[0])


class _NoFaceAnywhere(_NoFaceMesh):
    def mesh_in_roi(self, image: np.ndarray, center: np.ndarray, side: float, angle: float) -> tuple[np.ndarray, float]:
        return super().mesh_in_roi(image, center, side, angle)[0], 0.0


def test_the_mesh_is_placed_on_hogs_face_where_mediapipes_detector_finds_none(photo):
    """The short-range detector misses faces under ~60 px that HOG finds (a video of a room):
    the mesh then runs on the ROI of dlib's 68 points, refined on its own, and the face has its
    dense points, as where MediaPipe's detector found it (the same mesh within a pixel)."""
    found = HybridDetector(DlibDetector(), MediaPipeDetector(_NoFaceMesh())).detect(photo)
    usual = HybridDetector().detect(photo)
    assert found.detector == "hybrid" and found.dense is not None and found.dense.shape == usual.dense.shape
    assert any("the face mesh was placed on dlib's" in note for note in found.notes)
    assert np.median(np.linalg.norm(found.dense - usual.dense, axis=1)) < 1.0  # px; inter-ocular distance 60 px
    assert np.abs(found.points - usual.points).max() < 3.0
    assert not np.array_equal(found.points[68:], found.points[48:68])  # the mesh's lips, not dlib's mouth again


def test_hybrid_falls_back_to_hog_alone_where_the_mesh_finds_no_face_either(photo):
    found = HybridDetector(DlibDetector(), MediaPipeDetector(_NoFaceAnywhere())).detect(photo)
    assert found.detector == "hybrid" and found.dense is None
    assert any("MediaPipe found no face" in note for note in found.notes)
    np.testing.assert_array_equal(found.points[68:], found.points[48:68])  # dlib's own mouth points


def test_the_lids_detector_takes_the_eyes_from_the_face_landmarkers_mesh(photo):
    """``lids`` (facegeo track's default): the symmetric hybrid detector on the Face Landmarker's
    mesh (v2) with the eyes' 12 points (iBUG 36-47) the mesh's: those of the mean of the mesh and
    its mirror pass; the other 76 as the symmetric hybrid detector gives them on that mesh."""
    from facegeo.landmarks.dense import face_mesh_mirror
    from facegeo.landmarks.detectors import get_detector
    from facegeo.landmarks.scheme import EYES

    lids = get_detector("lids")
    found = lids.detect(photo)
    v2 = MediaPipeDetector(MediaPipeFaceMesh(mesh_model="v2", num_threads=1))
    plain = HybridDetector(mediapipe=v2, symmetric=True).detect(photo)
    face = v2.mesh(photo)[0]
    mean = (face.mesh + v2.mesh.mirrored_mesh(photo, face, face_mesh_mirror())[0]) / 2
    assert found.detector == "lids" and found.points.shape == (88, 2)
    np.testing.assert_allclose(found.points[EYES], ibug68_from_mesh(mean)[EYES] + 0.5, atol=1e-4)
    others = np.setdiff1d(np.arange(88), EYES)
    np.testing.assert_array_equal(found.points[others], plain.points[others])
    with pytest.raises(ValueError, match="eyes"):
        HybridDetector(eyes="iris")


def test_the_symmetric_detector_finds_the_mirror_image_of_a_face_mirrored(photo):
    """``symmetric``: on the photo mirrored left-right the 88 points and the 468 dense points come
    out as the photo's mirrored (renumbered left for right), up to the crops' own sampling: median
    0.16 px, dense at most 0.27 px on the bundled photo (eyes from the mesh, as ``lids``;
    inter-ocular 60 px), where the plain
    detector's differ by 0.41 px and up to 1.6 px. dlib's points are whole pixels, so its
    mirror-image mean is at most half a pixel off a mirrored one's each, 1 px in all."""
    from facegeo.landmarks.dense import face_mesh_mirror
    from facegeo.landmarks.scheme import HYBRID_MIRROR

    def mirror_gap(detector: HybridDetector) -> tuple[float, float]:
        found, mirrored = detector.detect(photo), detector.detect(np.ascontiguousarray(photo[:, ::-1]))
        points, dense = mirrored.points[HYBRID_MIRROR].copy(), mirrored.dense[face_mesh_mirror()].copy()
        points[:, 0], dense[:, 0] = photo.shape[1] - points[:, 0], photo.shape[1] - dense[:, 0]
        return float(np.median(np.linalg.norm(points - found.points, axis=1))), float(np.abs(dense - found.dense).max())

    v2 = MediaPipeDetector(MediaPipeFaceMesh(mesh_model="v2", num_threads=1))
    symmetric = mirror_gap(HybridDetector(mediapipe=v2, eyes="mesh", symmetric=True))
    plain = mirror_gap(HybridDetector(mediapipe=v2, eyes="mesh"))
    assert symmetric[0] < 0.25 and symmetric[1] < 0.4, symmetric
    assert plain[0] > 0.3 and plain[1] > 1.0, plain


def test_a_face_is_followed_into_the_next_frame_without_the_detector(photo):
    """``follow`` (a video's frames): the mesh on the previous frame's mesh ROI, no BlazeFace and
    no rotation search; it finds the face where it moved and says when it is lost."""
    import cv2

    from facegeo.landmarks.detectors import get_detector

    lids = get_detector("lids")
    found = lids.detect(photo)
    shift = np.float32([[1, 0, 6], [0, 1, -4]])  # the next frame: the face 6 px right, 4 px up
    moved = cv2.warpAffine(photo, shift, photo.shape[1::-1], borderMode=cv2.BORDER_REPLICATE)
    calls = []
    detect = lids.mediapipe.mesh.detect
    lids.mediapipe.mesh.detect = lambda image: calls.append(1) or detect(image)
    try:
        followed = lids.follow(moved, found)
    finally:
        lids.mediapipe.mesh.detect = detect
    assert calls == [] and followed is not None and followed.detector == "lids" and followed.dense is not None
    fresh = lids.detect(moved)
    iod = np.linalg.norm(fresh.points[36] - fresh.points[45])
    assert np.median(np.linalg.norm(followed.points - fresh.points, axis=1)) < 0.02 * iod  # as good as detecting it
    assert np.median(np.linalg.norm(followed.points - (found.points + [6, -4]), axis=1)) < 0.03 * iod
    noise = np.random.default_rng(0).integers(0, 256, photo.shape, dtype=np.uint8)
    assert lids.follow(noise, found) is None  # lost
    assert lids.follow(moved, HybridDetector(DlibDetector(), MediaPipeDetector(_NoFaceAnywhere())).detect(photo)) is None  # no mesh


def test_the_symmetric_detector_keeps_a_followed_face_by_both_passes_presence(photo):
    """A symmetric detector loses a followed face only where the mean of the crop's and the
    mirror image's presence is under the limit (0.5): 0.3 and 0.9 keep it, 0.3 and 0.5 do not."""
    from facegeo.landmarks.detectors import get_detector

    lids = get_detector("lids")
    found = lids.detect(photo)
    mesh = lids.mediapipe.mesh
    in_roi, mirrored = mesh.mesh_in_roi, mesh.mirrored_mesh
    try:
        for crop, mirror, kept in ((0.3, 0.9, True), (0.3, 0.5, False)):
            mesh.mesh_in_roi = lambda *a, p=crop: (in_roi(*a)[0], p)
            mesh.mirrored_mesh = lambda *a, p=mirror: (mirrored(*a)[0], p)
            assert (lids.follow(photo, found) is not None) == kept, (crop, mirror)
    finally:
        mesh.mesh_in_roi, mesh.mirrored_mesh = in_roi, mirrored
