"""Eyes and mouth interior: loading, evaluation against ICT-FaceKit's OBJ data, materials, iris colour."""

import numpy as np
import pytest
import torch

from facegeo import Camera
from facegeo.errors import ModelFileError
from facegeo.landmarks.iris import Iris, iris_colour, sample_iris_ring
from facegeo.morphable_model import MorphableModel
from facegeo.parts import DEFAULT_IRIS_SRGB, PART_MATERIALS, eyeball_texture, load_parts, part_assets, part_vertices
from facegeo.uv.renderer import rasterize_mesh
from facegeo.landmarks.scheme import LEFT_EYE, RIGHT_EYE

#: Vertices of ICT-FaceKit's OBJs (commit da5f95a, centimetres, as written in the files):
#: global index -> (part, neutral, identity003.obj, jawOpen.obj).
ICT_VERTICES = {
    17039: ("teeth", (2.32055, -2.23823, 5.83703), (2.33321, -2.23986, 5.87274), (2.32055, -2.23823, 5.83703)),
    19257: ("teeth", (2.47311, -3.11956, 6.12351), (2.48807, -3.12658, 6.15852), (2.47295, -4.726, 4.61573)),
    21551: ("eyeballs", (3.27208, 4.50193, 9.17924), (3.31206, 4.44596, 9.19711), (3.27208, 4.50193, 9.17924)),
    11748: ("mouth_socket", (-2.22916, -3.62197, 9.62241), (-2.26248, -3.62864, 9.68728), (-2.08908, -5.03992, 8.3396)),
}
#: Own-vertex offsets of the parts in ICT's numbering (the converter keeps ICT's order).
FIRST_VERTEX = {"teeth": 17039, "eyeballs": 21451, "mouth_socket": 11248}
#: Stored error bound per part (README: max over 1000 random instances; one mode is far below).
TOLERANCE_MM = {"teeth": 0.1, "eyeballs": 0.03, "mouth_socket": 0.03}


@pytest.fixture(scope="module")
def parts(model):
    return {p.name: p for p in load_parts(model)}


def test_the_bundled_model_has_its_parts(parts):
    assert list(parts) == ["eyeballs", "eye_sockets", "mouth_socket", "gums_tongue", "teeth"]
    assert parts["eyeballs"].id_affine is not None and parts["teeth"].id_affine.shape[1] == 32  # one map per tooth
    assert parts["mouth_socket"].skin_index.size > 0 and parts["teeth"].skin_index.size == 0


@pytest.mark.parametrize("vertex", sorted(ICT_VERTICES))
def test_ict_vertices_are_reproduced(model, parts, vertex):
    name, neutral, identity3, jaw_open = ICT_VERTICES[vertex]
    part = parts[name]
    local = vertex - FIRST_VERTEX[name]
    alpha = np.zeros(model.n_id, np.float64)
    alpha[3] = 1.0
    delta = np.zeros(model.n_exp, np.float64)
    delta[model.expression_names.index("jawOpen")] = 1.0
    tol = TOLERANCE_MM[name]
    np.testing.assert_allclose(part.shape(model)[local].numpy(), np.array(neutral) * 10, atol=1e-4)
    np.testing.assert_allclose(part.shape(model, alpha)[local].numpy(), np.array(identity3) * 10, atol=tol)
    np.testing.assert_allclose(part.shape(model, None, delta)[local].numpy(), np.array(jaw_open) * 10, atol=tol)


def test_jaw_open_moves_the_lower_teeth_with_the_chin(model, parts):
    delta = np.zeros(model.n_exp, np.float32)
    delta[model.expression_names.index("jawOpen")] = 1.0
    teeth = parts["teeth"]
    moved = (teeth.shape(model, None, delta) - teeth.shape(model)).numpy()
    chin = model.landmark_indices[8]
    chin_move = (model.shape(None, delta) - model.shape())[chin].numpy()
    lower = np.linalg.norm(moved, axis=1) > 1.0
    assert 0.4 < lower.mean() < 0.6  # half the teeth move, the upper half stays
    assert np.abs(moved[~lower]).max() < 0.05
    # the lower incisors' tips (the lower teeth's front-most points) go down and back like the chin
    front = np.flatnonzero(lower)[np.argsort(teeth.mean[lower, 2])[-20:]]
    direction = moved[front].mean(axis=0)
    assert direction[1] < -10.0 and direction[2] < 0.0
    cosine = direction @ chin_move / np.linalg.norm(direction) / np.linalg.norm(chin_move)
    assert cosine > 0.9 and 0.5 < np.linalg.norm(direction) / np.linalg.norm(chin_move) < 1.5


def test_shared_vertices_follow_the_skin_and_shapes_are_differentiable(model, parts):
    rng = np.random.default_rng(0)
    alpha = torch.tensor(rng.standard_normal((2, model.n_id)), dtype=torch.float64, requires_grad=True)
    delta = torch.tensor(rng.uniform(0, 1, (2, model.n_exp)), dtype=torch.float64)
    socket = parts["mouth_socket"]
    out = socket.shape(model, alpha, delta)
    assert out.shape == (2, socket.n_vertices, 3) and out.dtype == torch.float64
    skin = model.shape(alpha, delta)[:, socket.skin_index]
    torch.testing.assert_close(out[:, len(socket.mean):], skin)
    single = socket.shape(model, alpha[1].detach().float(), delta[1].float())
    torch.testing.assert_close(single, out[1].detach().float(), atol=1e-3, rtol=0)  # float32 against float64
    out[..., 1].sum().backward()
    assert torch.isfinite(alpha.grad).all() and alpha.grad.abs().sum() > 0
    teeth = parts["teeth"]  # the affine identity is differentiable too
    a = torch.zeros(model.n_id, requires_grad=True)
    teeth.shape(model, a)[:, 0].sum().backward()
    assert a.grad.abs().sum() > 0


def test_a_model_without_parts_has_none_and_a_mismatch_is_named(tmp_path, model):
    tiny = MorphableModel(
        mean_shape=np.random.default_rng(0).normal(size=(100, 3)), id_basis=np.zeros((2, 100, 3)),
        exp_basis=np.zeros((1, 100, 3)), mean_albedo=np.full((100, 3), 0.5), tex_basis=np.zeros((0, 100, 3)),
        triangles=[[0, 1, 2]], uv=np.zeros((3, 2)), uv_triangles=[[0, 1, 2]],
        landmark_indices=np.arange(88), face_mask=np.ones(100, bool), expression_names=["jawOpen"])
    assert load_parts(tiny) == ()
    from facegeo.assets import asset_path

    with pytest.raises(ModelFileError, match="skin_vertex_count"):
        load_parts(tiny, asset_path("ict_facekit/ict_face_parts.npz"))
    bad = tmp_path / "parts.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(ModelFileError, match="parts.npz"):
        load_parts(model, bad)


def test_eyeball_texture_has_pupil_iris_and_sclera(parts):
    eye = parts["eyeballs"]
    iris = (0.2, 0.5, 0.3)
    texture = eyeball_texture(eye, iris, size=128)
    assert texture.shape == (128, 128, 3) and texture.dtype == np.float32
    from facegeo.uv.raster import rasterize_uv

    raster = rasterize_uv(eye.uv, eye.uv_triangles, size=128, padding=0)
    r = raster.scatter(raster.interpolate(eye.radial_mm[eye.triangles][..., None])[:, 0], fill=-1.0)
    colours = {name: texture[(r >= lo) & (r < hi)] for name, lo, hi in
               [("pupil", 0.0, 1.4), ("iris", 3.4, 4.0), ("sclera", 8.0, 20.0)]}
    assert all(len(c) > 3 for c in colours.values())
    assert colours["pupil"].max() < 0.1
    np.testing.assert_allclose(np.median(colours["iris"], axis=0), iris, atol=0.02)  # full strength mid-iris
    np.testing.assert_allclose(np.median(colours["sclera"], axis=0), PART_MATERIALS["eyeballs"]["albedo"], atol=1e-3)


def test_parts_fill_the_eye_and_mouth_holes(model, parts):
    """From the front, the eye centres and the open mouth show parts, not the inside of the skin."""
    delta = np.zeros(model.n_exp, np.float32)
    delta[model.expression_names.index("jawOpen")] = 0.6
    assets = part_assets(tuple(parts.values()), model, None, delta, texture_size=32)
    skin = model.shape(None, delta).numpy()
    vertices = np.concatenate([skin] + [a.vertices for a in assets])
    offsets = np.cumsum([0, len(skin)] + [len(a.vertices) for a in assets])
    triangles = np.concatenate([model.triangles] + [a.triangles + o for a, o in zip(assets, offsets[1:])])
    owner = np.repeat(np.arange(len(assets) + 1), [len(model.triangles)] + [len(a.triangles) for a in assets])
    camera = Camera(2000.0, 128.0, 128.0, 256, 256)
    cam = vertices - [0.0, 0.0, 1000.0]
    tri, _, _ = rasterize_mesh(cam, triangles, camera, barycentric=False)

    def pixel(point):
        u = camera.cx + camera.focal * point[0] / (-point[2])
        v = camera.cy - camera.focal * point[1] / (-point[2])
        return int(v), int(u)

    lm = skin[model.landmark_indices] - [0.0, 0.0, 1000.0]
    names = ["skin"] + [a.name for a in assets]
    for eye in ((36, 39), (42, 45)):
        assert names[owner[tri[pixel(lm[list(eye)].mean(axis=0))]]] == "eyeballs"
    mouth = pixel((lm[62] + lm[66]) / 2)  # between the inner lips
    assert names[owner[tri[mouth]]] in ("teeth", "gums_tongue", "mouth_socket")


def test_iris_ring_sampling_finds_a_known_colour():
    rng = np.random.default_rng(1)
    image = np.full((80, 120, 3), (200, 150, 130), np.uint8)  # skin
    yy, xx = np.mgrid[:80, :120] + 0.5
    eye = ((xx - 60) / 30) ** 2 + ((yy - 40) / 12) ** 2 <= 1
    image[eye] = (235, 232, 228)  # sclera
    d = np.hypot(xx - 60, yy - 40)
    iris_rgb = np.array([70, 110, 160])
    image[(d <= 10) & eye] = np.clip(iris_rgb + rng.normal(0, 6, (int(((d <= 10) & eye).sum()), 3)), 0, 255)
    image[d <= 3.5] = (10, 10, 10)  # pupil
    image[(np.hypot(xx - 57, yy - 37) <= 1.5)] = (255, 255, 255)  # highlight
    image[(yy < 31) & (np.abs(xx - 60) < 30)] = (200, 150, 130)  # upper eyelid over the iris top
    polygon = np.array([[30, 40], [45, 30], [75, 30], [90, 40], [75, 50], [45, 50]], np.float64)
    landmarks = np.full((68, 2), np.nan)
    landmarks[RIGHT_EYE] = polygon
    landmarks[LEFT_EYE] = polygon
    pixels = sample_iris_ring(image, np.array([60.0, 40.0]), 10.0, polygon)
    assert len(pixels) > 50

    class Found:
        def __call__(self, image, landmarks):
            return [Iris("right", np.array([60.0, 40.0]), 10.0, np.zeros((4, 2)))]

    colour, report = iris_colour(image, landmarks, detector=Found())
    np.testing.assert_allclose(np.array(colour) * 255, iris_rgb, atol=4.0)
    assert report["irises"][0]["pixels"] == len(pixels)

    class NotFound:
        def __call__(self, image, landmarks):
            return []

    colour, report = iris_colour(image, landmarks, detector=NotFound())
    assert colour is None and "default colour" in report["note"]
    assert len(DEFAULT_IRIS_SRGB) == 3


def test_iris_model_finds_the_irises_of_the_bundled_photo():
    from facegeo import detect_landmarks, load_photo
    from facegeo.assets import asset_path
    from facegeo.landmarks.iris import IrisDetector

    photo = load_photo(asset_path("photos/astronaut.png"))
    landmarks = np.asarray(detect_landmarks(photo.image, detector="mediapipe"))
    irises = IrisDetector()(photo.image, landmarks)
    assert [i.eye for i in irises] == ["right", "left"]
    for iris, (a, b) in zip(irises, ((36, 39), (42, 45))):
        width = np.linalg.norm(landmarks[b] - landmarks[a])
        along = (iris.centre - landmarks[a]) @ (landmarks[b] - landmarks[a]) / width**2
        assert 0.2 < along < 0.8  # between the eye corners
        assert 0.12 < iris.radius / width < 0.35  # an iris is about 40 % of the eye's width across


def test_expression_deltas_pose_the_part_exactly(model, parts):
    """shape(α, δ) = shape(α, 0) + Σ δ_k · expression_deltas[k] (the blendshapes the exporters
    write), shared skin vertices included."""
    rng = np.random.default_rng(1)
    alpha = rng.normal(0, 0.8, model.n_id)
    delta = rng.uniform(0, 1, model.n_exp) * (rng.random(model.n_exp) < 0.3)
    for part in parts.values():
        deltas = part.expression_deltas(model)
        assert deltas.shape == (model.n_exp, part.n_vertices, 3)
        with torch.no_grad():
            posed = part.shape(model, alpha, delta).numpy()
            neutral = part.shape(model, alpha).numpy()
        np.testing.assert_allclose(posed, neutral + np.tensordot(delta, deltas.astype(np.float64), axes=1), atol=1e-9)
    assert not parts["eyeballs"].expression_deltas(model).any()  # ICT's eyeballs move with no shape


def test_eyeball_centres_are_the_globes_centres(model, parts):
    from facegeo.parts import eyeball_centres

    with torch.no_grad():
        vertices = parts["eyeballs"].shape(model).numpy()
    left, centres = eyeball_centres(vertices)
    assert np.all(vertices[left, 0] > 0) and np.all(vertices[~left, 0] < 0)
    np.testing.assert_allclose(centres[0] * [-1, 1, 1], centres[1], atol=0.05)  # ICT's eyes are mirror images
    eye_corners = model.mean_shape[model.landmark_indices[42:48]].mean(axis=0)  # the subject's left eye
    assert 8.0 < eye_corners[2] - centres[0][2] < 16.0  # the globe's centre sits behind the lids
    pupil = vertices[left][np.argmin(parts["eyeballs"].radial_mm[left])]  # on the optical axis
    axis = (pupil - centres[0]) / np.linalg.norm(pupil - centres[0])
    assert axis[2] > 0.98  # the centre is on the axis, behind the pupil
    # a known sphere: the centre comes back
    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    sphere = 12.0 * d / np.linalg.norm(d, axis=1, keepdims=True)
    both = np.concatenate([sphere + [30, 35, 80], sphere + [-30, 35, 80]])
    np.testing.assert_allclose(eyeball_centres(both)[1], [[30, 35, 80], [-30, 35, 80]], atol=1e-9)


def test_the_numpy_shape_equals_the_torch_shape_for_every_part(model):
    # part_vertices (the pipeline's, without torch) against the differentiable shape
    parts = load_parts(model)
    rng = np.random.default_rng(3)
    alpha = rng.normal(size=model.n_id).astype(np.float32)
    delta = rng.uniform(0, 1, size=model.n_exp).astype(np.float32)
    for part in parts:
        for a, d in ((None, None), (alpha, None), (alpha, delta)):
            np.testing.assert_allclose(part.shape_numpy(model, a, d), part.shape(model, a, d).numpy(), atol=2e-4, rtol=0)
    vertices = part_vertices(parts, model, alpha, delta)
    assert all(vertices[p.name].dtype == np.float32 and vertices[p.name].shape == (p.n_vertices, 3) for p in parts)
