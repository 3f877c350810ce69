"""facegeo.cheek_shading: the puff read from the cheeks' shading, on faces rendered under a known
light (the model's own shapes, a textured albedo, a key light from the side and above)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from facegeo.camera import Camera, rotation_from_euler
from facegeo.cheek_shading import PUFF_NAMES, cheek_shading
from facegeo.colour import linear_to_srgb
from facegeo.lighting import sh_irradiance
from facegeo.normals import vertex_normals
from facegeo.uv.renderer import render

CAMERA = Camera(700.0, 320.0, 240.0, 640, 480)
TRANSLATION = np.array([0.0, 0.0, -550.0])
#: SH irradiance of a white light from the upper right and in front, with some ambient (linear RGB).
GAMMA = np.tile(np.array([0.55, -0.25, 0.30, -0.20, 0.05, -0.06, 0.0, -0.04, 0.02]), (3, 1)) * np.array([[1.0], [0.85], [0.75]])


@pytest.fixture(scope="module")
def albedo(model) -> np.ndarray:
    """(V, 3) the model's mean albedo with a blotchy per-vertex variation, as skin has."""
    rng = np.random.default_rng(3)
    return np.clip(model.mean_albedo * rng.uniform(0.85, 1.15, (model.n_vertices, 1)), 0.0, 1.0)


def _frame(model, albedo, delta, yaw: float = 0.0, exposure: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(image (480, 640, 3) uint8, rotation) of the mean identity with ``delta``, turned by ``yaw`` degrees."""
    rotation = rotation_from_euler(yaw, 0.0, 0.0)
    cam = (model.mean_shape.astype(np.float64) + np.einsum("k,kvc->vc", delta, model.exp_basis)) @ rotation.T + TRANSLATION
    colours = albedo * sh_irradiance(vertex_normals(cam, model.triangles), GAMMA) * exposure
    view = render(cam, model, CAMERA, colours=np.clip(colours, 0.0, 1.0), background=0.2)
    return (np.clip(linear_to_srgb(view.image), 0.0, 1.0) * 255).round().astype(np.uint8), rotation


def _delta(model, **weights: float) -> np.ndarray:
    delta = np.zeros(model.n_exp)
    for name, value in weights.items():
        delta[list(model.expression_names).index(name)] = value
    return delta


@pytest.fixture(scope="module")
def at_rest(model, albedo):
    image, rotation = _frame(model, albedo, np.zeros(model.n_exp))
    shading = cheek_shading(model, np.zeros(model.n_id), CAMERA, image, rotation, TRANSLATION, np.zeros(model.n_exp))
    assert shading is not None
    return shading


def _read(shading, model, albedo, delta, **frame) -> tuple[float, float]:
    image, rotation = _frame(model, albedo, delta, **frame)
    solved = delta.copy()
    solved[[list(model.expression_names).index(n) for n in PUFF_NAMES]] = 0.0  # the puff the landmarks missed
    return shading.puff_reading(image, rotation, TRANSLATION, solved)


def test_the_frame_at_rest_reads_no_puff(at_rest, model, albedo):
    puff, gain = _read(at_rest, model, albedo, np.zeros(model.n_exp))
    assert puff == 0.0 and gain < 0.01


@pytest.mark.parametrize("true_puff", [0.5, 0.9])
def test_a_puff_is_read_from_the_shading(at_rest, model, albedo, true_puff):
    puff, gain = _read(at_rest, model, albedo, _delta(model, cheekPuff_L=true_puff, cheekPuff_R=true_puff))
    assert abs(puff - true_puff) < 0.05
    assert gain > 0.3


@pytest.mark.parametrize("yaw, exposure", [(20.0, 0.7), (-35.0, 1.0)])
def test_a_puff_is_read_under_another_exposure_and_pose(at_rest, model, albedo, yaw, exposure):
    """The head turned and the camera's exposure changed (0.7: −0.5 EV): the reference skin
    takes the exposure out, the light stays in camera space."""
    puff, _ = _read(at_rest, model, albedo, _delta(model, cheekPuff_L=0.8, cheekPuff_R=0.8), yaw=yaw, exposure=exposure)
    assert abs(puff - 0.8) < 0.05
    puff, _ = _read(at_rest, model, albedo, np.zeros(model.n_exp), yaw=yaw, exposure=exposure)
    assert puff == 0.0


def test_other_expressions_read_no_puff(at_rest, model, albedo):
    for weights in ({"mouthSmile_L": 0.9, "mouthSmile_R": 0.9}, {"jawOpen": 0.6}, {"mouthPucker": 0.9}):
        puff, _ = _read(at_rest, model, albedo, _delta(model, **weights))
        assert puff < 0.05, weights


def test_with_puff_sets_both_targets(at_rest, model):
    delta = at_rest.with_puff(np.full(model.n_exp, 0.3), 0.7)
    names = list(model.expression_names)
    assert [delta[names.index(n)] for n in PUFF_NAMES] == [0.7, 0.7]
    assert np.count_nonzero(delta == 0.3) == model.n_exp - 2


def test_no_reading_without_puff_targets_or_a_face(model, albedo):
    renamed = dataclasses.replace(model, expression_names=[n.replace("cheekPuff", "cheekBlow") for n in model.expression_names])
    image, rotation = _frame(model, albedo, np.zeros(model.n_exp))
    assert cheek_shading(renamed, np.zeros(model.n_id), CAMERA, image, rotation, TRANSLATION, np.zeros(model.n_exp)) is None
    away = rotation_from_euler(180.0, 0.0, 0.0)  # the back of the head
    assert cheek_shading(model, np.zeros(model.n_id), CAMERA, image, away, TRANSLATION, np.zeros(model.n_exp)) is None


def test_no_reading_of_a_face_too_small(at_rest, model, albedo):
    """At 5 m the outer eye corners are ~13 px apart (below MIN_EYE_SPAN_PX): the frame is not read."""
    image, rotation = _frame(model, albedo, np.zeros(model.n_exp))
    assert at_rest.puff_reading(image, rotation, np.array([0.0, 0.0, -5000.0]), np.zeros(model.n_exp)) is None
    assert at_rest.puff_reading(image, rotation, TRANSLATION, np.zeros(model.n_exp)) is not None


def test_the_tracker_reads_the_puff_from_the_shading(model, albedo):
    """facegeo.tracking.track_frames on a rendered clip (the face at rest, then a puff up to 0.8 and
    back): with the face at rest given and the frames decoded again, every frame's puff is the
    shading's; without the frames again it is the landmarks' own (not read)."""
    from types import SimpleNamespace

    from facegeo.tracking import track_frames

    puffs = [0.0] * 8 + [0.4, 0.8, 0.8, 0.4] + [0.0] * 4
    frames = [SimpleNamespace(index=k, time_s=k / 10.0, image=_frame(model, albedo, _delta(model, cheekPuff_L=p, cheekPuff_R=p))[0])
              for k, p in enumerate(puffs)]
    again = lambda time_s: [f for f in frames if f.time_s >= time_s - 1e-9]  # noqa: E731
    track = track_frames(frames, model, keyframes=3, focal=CAMERA.focal, neutral_s=0.3, frames_again=again)
    names = list(model.expression_names)
    read = np.array([[f.delta[names.index(n)] for n in PUFF_NAMES] for f in track.frames])
    assert all(f.found and f.puff_gain is not None for f in track.frames)
    assert np.abs(read - np.asarray(puffs)[:, None]).max() < 0.1
    unread = track_frames(frames, model, keyframes=3, focal=CAMERA.focal, neutral_s=0.3)
    assert all(f.puff_gain is None for f in unread.frames)


@pytest.mark.parametrize("value", [0, 255])
def test_a_black_or_clipped_white_frame_reads_no_puff(at_rest, model, value):
    image = np.full((CAMERA.height, CAMERA.width, 3), value, np.uint8)
    puff, gain = at_rest.puff_reading(image, np.eye(3), TRANSLATION, np.zeros(model.n_exp))
    assert puff == 0.0 and np.isfinite(gain)
