"""One identity from several views (facegeo.fitting.shared_identity): known answers on
synthetic views of the bundled model, the single-view fit as the one-view case, errors that name
the view, and two real photos of one person."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from facegeo import Camera, project
from facegeo.assets import asset_path
from facegeo.camera import euler_from_rotation, rotation_from_euler
from facegeo.errors import InputError
from facegeo.fitting import fit, fit_photos
from facegeo.fitting.landmark_fit import solve_landmarks
from facegeo.fitting.shared_identity import LandmarkView, solve_shared_identity
from facegeo.photo import load_photo

CAMERA = Camera.for_image(512, 512)
YAWS = (-40.0, -20.0, 0.0, 20.0, 40.0)


def _views(model, seed: int, noise_px: float):
    """Five views of one random face (α ~ N(0, I)), each with its own expression and pose, and
    the face's neutral shape (V, 3) mm."""
    rng = np.random.default_rng(seed)
    alpha = rng.normal(0, 1, model.n_id).astype(np.float32)
    views, rotations = [], []
    for k, yaw in enumerate(YAWS):
        delta = np.zeros(model.n_exp, np.float32)
        delta[rng.choice(model.n_exp, 3, replace=False)] = rng.uniform(0, 0.6, 3)
        shape = model.shape(torch.from_numpy(alpha), torch.from_numpy(delta)).numpy().astype(np.float64)
        rotation = rotation_from_euler(yaw, rng.uniform(-8, 8), rng.uniform(-5, 5))
        landmarks = project(shape[model.landmark_indices], rotation, np.array([0.0, 0.0, -600.0]), CAMERA)
        views.append(LandmarkView(landmarks + rng.normal(0, noise_px, landmarks.shape), CAMERA, source=f"view{k}.png"))
        rotations.append(rotation)
    neutral = model.shape(torch.from_numpy(alpha), torch.zeros(model.n_exp)).numpy()
    return views, rotations, neutral


def _identity_error(model, alpha: np.ndarray, neutral: np.ndarray) -> float:
    """RMS distance (mm) of α's neutral shape from the true one, no alignment (same model frame)."""
    shape = model.shape(torch.from_numpy(np.asarray(alpha, np.float32)), torch.zeros(model.n_exp)).numpy()
    return float(np.sqrt(((shape - neutral) ** 2).sum(axis=1).mean()))


def test_one_view_is_the_single_view_fit(model):
    views, _, _ = _views(model, 1, 1.0)
    (joint,) = solve_shared_identity(model, views[2:3])
    single = solve_landmarks(model, views[2].landmarks, CAMERA)
    for name in ("alpha", "delta", "rotation", "translation", "vertices"):
        assert np.array_equal(getattr(joint.fit, name), getattr(single.fit, name)), name


def test_noiseless_views_recover_the_face_and_every_pose(model):
    views, rotations, neutral = _views(model, 2, 0.0)
    solutions = solve_shared_identity(model, views, identity_precision=1.0)
    alphas = [s.fit.alpha for s in solutions]
    assert all(np.array_equal(a, alphas[0]) for a in alphas)  # one identity
    # 88 points a view constrain the face, not the whole head the identity also moves: the error
    # left (2.5 mm over all 11,248 vertices, of a head 7.5 mm from the mean) is below every view's own
    singles = [solve_landmarks(model, v.landmarks, v.camera).fit.alpha for v in views]
    assert _identity_error(model, alphas[0], neutral) < min(_identity_error(model, a, neutral) for a in singles)
    assert _identity_error(model, alphas[0], neutral) < 0.4 * _identity_error(model, np.zeros(model.n_id), neutral)
    for solution, rotation in zip(solutions, rotations):
        # yaw exactly; pitch and roll within the ambiguity of a head's tilt and its shape (≤ 1.8° seen)
        assert np.allclose(euler_from_rotation(solution.fit.rotation), euler_from_rotation(rotation), atol=(0.5, 2.5, 2.5))
        assert solution.fit.landmark_rms_px < 0.2
        assert solution.fit.info["shared_identity"]["views"] == 5


def test_views_with_independent_noise_determine_the_identity_better_than_any_one(model):
    # with independent landmark noise the joint MAP estimate (c = 1) beats each view alone and the
    # average of their identities (seed 3: 4.97 mm against 6.38-9.42 mm and 6.56 mm)
    views, _, neutral = _views(model, 3, 1.5)
    joint = solve_shared_identity(model, views, identity_precision=1.0)[0].fit.alpha
    singles = [solve_landmarks(model, v.landmarks, v.camera).fit.alpha for v in views]
    joint_error = _identity_error(model, joint, neutral)
    assert joint_error < min(_identity_error(model, a, neutral) for a in singles)
    assert joint_error < 0.85 * _identity_error(model, np.mean(singles, axis=0), neutral)


def test_the_default_counts_the_views_evidence_as_one_views(model):
    views, _, neutral = _views(model, 3, 1.5)
    default = solve_shared_identity(model, views)
    assert default[0].fit.info["shared_identity"]["identity_precision"] == 5.0
    independent = solve_shared_identity(model, views, identity_precision=1.0)
    assert np.linalg.norm(default[0].fit.alpha) < np.linalg.norm(independent[0].fit.alpha)  # a stronger prior
    assert np.isfinite(_identity_error(model, default[0].fit.alpha, neutral))


def test_a_refused_view_is_named(model):
    views, _, _ = _views(model, 4, 1.0)
    broken = views[3].landmarks.copy()
    broken[[36, 45]] = np.nan
    views[3] = LandmarkView(broken, CAMERA, source="view3.png")
    with pytest.raises(InputError, match=r"^view3\.png: landmarks: expected finite outer eye corners"):
        solve_shared_identity(model, views)
    with pytest.raises(InputError, match="identity_precision"):
        solve_shared_identity(model, views[:2], identity_precision=0.0)
    with pytest.raises(InputError, match="at least one view"):
        solve_shared_identity(model, [])


def test_two_photos_of_one_person_share_one_identity(model, tmp_path):
    import cv2

    photo = asset_path("photos/astronaut.png")
    mirrored = tmp_path / "mirrored.png"
    cv2.imwrite(str(mirrored), cv2.imread(str(photo))[:, ::-1])
    fits = fit_photos([photo, mirrored], model, photometric=False)
    assert np.array_equal(fits[0].alpha, fits[1].alpha)
    assert [f.info["source"] for f in fits] == [str(photo), str(mirrored)]
    single = fit(photo, model, photometric=False)
    assert fits[0].landmark_rms_px < 1.5 * single.landmark_rms_px  # the shared identity still follows each photo
    yaws = [euler_from_rotation(f.rotation)[0] for f in fits]
    assert abs(yaws[0] + yaws[1]) < 3.0  # the mirrored photo is the same face turned the other way


def _grace_hopper():
    matplotlib = pytest.importorskip("matplotlib")
    from pathlib import Path

    return Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg"


def test_face_descriptors_tell_people_apart():
    from facegeo.landmarks import detect_landmarks
    from facegeo.landmarks.face_identity import SAME_PERSON_DISTANCE, face_descriptor, odd_ones_out

    photos = [load_photo(asset_path("photos/astronaut.png")).image, load_photo(_grace_hopper()).image]
    photos.insert(1, np.ascontiguousarray(photos[0][:, ::-1]))  # the same person, mirrored
    descriptors = [face_descriptor(p, detect_landmarks(p)) for p in photos]
    assert all(d.shape == (128,) and d.dtype == np.float32 for d in descriptors)
    assert np.linalg.norm(descriptors[0] - descriptors[1]) < SAME_PERSON_DISTANCE
    assert np.linalg.norm(descriptors[0] - descriptors[2]) > SAME_PERSON_DISTANCE
    assert [k for k, _ in odd_ones_out(descriptors)] == [2]
    assert odd_ones_out(descriptors[:1]) == []


def test_a_photo_of_someone_else_is_named_and_left_out(model, tmp_path):
    import cv2

    photo = asset_path("photos/astronaut.png")
    mirrored = tmp_path / "mirrored.png"
    cv2.imwrite(str(mirrored), cv2.imread(str(photo))[:, ::-1])
    fits = fit_photos([photo, _grace_hopper(), mirrored], model, photometric=False)
    assert [f.info["source"] for f in fits] == [str(photo), str(mirrored)]
    assert fits[0].info["shared_identity"]["left_out"] == [str(_grace_hopper())]
    assert any(n.startswith(f"{_grace_hopper()}: another person") for n in fits[0].info["notes"])


def test_facegeo_fit_one_person_writes_one_record(tmp_path):
    import json
    import subprocess
    import sys

    import cv2

    photo = asset_path("photos/astronaut.png")
    mirrored = tmp_path / "mirrored.png"
    cv2.imwrite(str(mirrored), cv2.imread(str(photo))[:, ::-1])
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", "fit", "--one-person", str(photo), str(_grace_hopper()),
                           str(mirrored), "-o", str(out), "--no-photometric"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"note: {_grace_hopper()}: another person" in done.stdout
    record = json.loads((out / "fit.json").read_text())
    assert record["one_person"] and len(record["alpha"]) > 0 and record["left_out"] == [str(_grace_hopper())]
    assert [p["photo"] for p in record["photos"]] == [str(photo), str(mirrored)] and "alpha" not in record["photos"][0]
    assert {"fit.json", "mesh.obj", "overlay.png"} <= {p.name for p in out.iterdir()}
    one = subprocess.run([sys.executable, "-m", "facegeo.cli", "fit", "--one-person", str(photo), "-o", str(tmp_path / "o2")],
                         capture_output=True, text=True, timeout=300)
    assert one.returncode == 2 and one.stderr.strip().splitlines() == [
        f"facegeo: error: <command line>: --one-person: expected two or more photo files of the person, found {photo}"]


def test_one_person_refuses_a_photo_given_twice_and_two_people_one_photo_each(tmp_path):
    import shutil

    from facegeo.jobs import FitOptions, fit_one_person_into_folder

    photo = asset_path("photos/astronaut.png")
    copy = tmp_path / "copy.png"
    shutil.copy(photo, copy)  # another file, the same picture: no second view
    with pytest.raises(InputError, match=rf"^{re.escape(str(copy))}: one person: expected each photo of the person once, "
                                         rf"found the same picture as {re.escape(str(photo))}$"):
        fit_one_person_into_folder([photo, copy], tmp_path / "out", FitOptions(photometric=False))
    with pytest.raises(InputError, match=r"one person: expected two or more photos of one person, found one of the person "
                                         rf"\({re.escape(str(photo))}\), the rest of someone else by their face descriptors "
                                         rf"\({re.escape(str(_grace_hopper()))}\)$"):
        fit_one_person_into_folder([photo, _grace_hopper()], tmp_path / "out", FitOptions(photometric=False))
    assert not (tmp_path / "out").exists()


def test_facegeo_reconstruct_one_person_fuses_one_texture_from_the_photos(tmp_path):
    """The command (forked views and export) on the bundled photo and its mirror image: one
    asset whose albedo takes each side from the photo that sees it, the exposure matched (the
    same photo: gains of 1), the record of the joint fit with the fusion's; the job in this
    process writes the same maps."""
    import json
    import subprocess
    import sys

    import cv2

    from facegeo.jobs import ReconstructOptions, reconstruct_one_person_into_folder

    photo = asset_path("photos/astronaut.png")
    mirrored = tmp_path / "mirrored.png"
    cv2.imwrite(str(mirrored), cv2.imread(str(photo))[:, ::-1])
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", "reconstruct", "--one-person", str(photo), str(mirrored),
                           "-o", str(out), "--size", "256"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert {"fit.json", "asset.json", "albedo.png", "face.glb", "face.usdz", "preview.png", "blendshapes.npz"} <= {
        p.name for p in out.iterdir()}
    record = json.loads((out / "fit.json").read_text())
    assert record["one_person"] and [p["photo"] for p in record["photos"]] == [str(photo), str(mirrored)]
    assert record["reference"] in (str(photo), str(mirrored))
    fusion = record["fusion"]
    assert np.allclose(fusion["gains"], 1.0, atol=0.05) and min(fusion["share"]) > 0.2
    assert {"fit", "parts", "views", "fuse", "materials", "export", "preview", "total"} == set(record["timings_s"]["stages"])
    inline = reconstruct_one_person_into_folder([photo, mirrored], tmp_path / "inline", ReconstructOptions(size=256), fork=False)
    assert inline.map_size == 256
    for name in ("albedo.png", "normal.png", "roughness.png"):
        assert (out / name).read_bytes() == (tmp_path / "inline" / name).read_bytes(), name
    one = subprocess.run([sys.executable, "-m", "facegeo.cli", "reconstruct", "--one-person", str(photo), "-o", str(tmp_path / "o2")],
                         capture_output=True, text=True, timeout=300)
    assert one.returncode == 2 and one.stderr.strip().splitlines() == [
        f"facegeo: error: <command line>: --one-person: expected two or more photo files of the person, found {photo}"]


def test_a_greyscale_photo_among_colour_ones_is_left_out_of_the_texture(model, tmp_path):
    import cv2

    from facegeo.pipeline import reconstruct_views

    photo = asset_path("photos/astronaut.png")
    grey = tmp_path / "grey_mirrored.png"
    cv2.imwrite(str(grey), cv2.cvtColor(cv2.imread(str(photo), cv2.IMREAD_GRAYSCALE)[:, ::-1], cv2.COLOR_GRAY2BGR))
    fits = fit_photos([grey, photo], model, photometric=False)
    photos = [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in (grey, photo)]
    asset, reference, report = reconstruct_views(photos, fits, model, size=128, maps={"albedo"}, parts=False)
    assert reference == 1 and report["photos"] == [str(photo)]
    assert report["notes"][0] == f"{grey}: a greyscale photo among colour ones: left out of the texture"
    albedo = asset.maps["albedo"]
    assert albedo.shape == (128, 128, 3) and np.ptp(albedo[..., 0] - albedo[..., 2]) > 0.05  # coloured, not grey


def test_facegeo_reconstruct_one_person_forks_the_fit_beside_the_skin_masks(tmp_path):
    # a fresh process (no torch): the joint fit in a forked child while the photos' skin masks are
    # made; the kept photos' fits, the reference and the files as the command documents them
    import json
    import subprocess
    import sys

    import cv2

    photo = asset_path("photos/astronaut.png")
    mirrored = tmp_path / "mirrored.png"
    cv2.imwrite(str(mirrored), cv2.imread(str(photo))[:, ::-1])
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", "reconstruct", "--one-person", str(photo), str(mirrored), "-o", str(out),
                           "--size", "256", "--no-preview", "--format", "glb"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    record = json.loads((out / "fit.json").read_text())
    assert record["one_person"] and [p["photo"] for p in record["photos"]] == [str(photo), str(mirrored)]
    assert record["reference"] in (str(photo), str(mirrored)) and record["photos"][0]["info"]["shared_identity"]["view_consistency"]["pairs"] == 1
    assert {"fit.json", "face.glb", "albedo.png"} <= {p.name for p in out.iterdir()}
