"""A face through a clip (facegeo.tracking, facegeo.jobs.track_into_folder, ``facegeo track``):
frames made from the bundled photo turned in the image plane by known angles, one without a face."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from facegeo.assets import asset_path
from facegeo.export.animation import head_angles, rotations
from facegeo.photo import load_photo

PHOTO = asset_path("photos/astronaut.png")
#: in-plane turns of the frames, degrees (counter-clockwise in the image)
ROLLS = (-8.0, -4.0, 0.0, 4.0, 8.0, 4.0, 0.0)
NO_FACE = 5  # this frame is noise


def _frames() -> list[np.ndarray]:
    image = load_photo(PHOTO).image
    height, width = image.shape[:2]
    out = []
    for k, roll in enumerate(ROLLS):
        turn = cv2.getRotationMatrix2D((width / 2.0, height / 3.0), roll, 1.0)
        frame = cv2.warpAffine(image, turn, (width, height), borderMode=cv2.BORDER_REPLICATE)
        if k == NO_FACE:
            frame = np.random.default_rng(0).integers(0, 256, frame.shape, dtype=np.uint8)
        out.append(frame)
    return out


def test_head_angles_invert_the_take_rotations():
    angles = np.random.default_rng(1).uniform(-1.2, 1.2, (50, 3))
    from scipy.spatial.transform import Rotation

    assert np.abs(head_angles(Rotation.from_quat(rotations(angles)).as_matrix()) - angles).max() < 1e-12


def test_head_angles_equal_scipys_euler_angles_even_at_the_gimbal_lock():
    from scipy.spatial.transform import Rotation

    matrices = Rotation.random(500, random_state=2).as_matrix()
    a, b, c = Rotation.from_matrix(matrices).as_euler("YXZ").T
    assert np.abs(head_angles(matrices) - np.stack([-a, b, -c], axis=1)).max() < 1e-12
    for pitch in (np.pi / 2, -np.pi / 2):  # straight up or down: one angle is free, the rotation is kept
        locked = Rotation.from_euler("YXZ", [[0.3, pitch, 0.2]]).as_matrix()
        angles = head_angles(locked)
        assert angles[0, 2] == 0.0 and abs(angles[0, 1] - pitch) < 1e-7
        assert np.abs(Rotation.from_quat(rotations(angles)).as_matrix() - locked).max() < 1e-7


@pytest.fixture(scope="module")
def tracked(model):
    from facegeo.tracking import track_frames

    frames = [SimpleNamespace(index=k, time_s=k / 10.0, image=f) for k, f in enumerate(_frames())]
    return track_frames(frames, model, keyframes=3)


def test_every_frame_is_tracked_and_the_one_without_a_face_is_flagged(tracked, model):
    assert [f.index for f in tracked.frames] == list(range(len(ROLLS)))
    assert [f.found for f in tracked.frames] == [k != NO_FACE for k in range(len(ROLLS))]
    assert tracked.frames[NO_FACE].rotation is None and "no face" in tracked.frames[NO_FACE].note
    assert len(tracked.keyframes) == 3 and NO_FACE not in tracked.keyframes
    assert tracked.alpha.shape == (model.n_id,) and np.all(np.isfinite(tracked.alpha))
    for frame in tracked.frames:
        if frame.found:
            assert np.all(np.isfinite(frame.delta)) and frame.landmark_rms_percent_iod < 6.0


def test_the_head_roll_follows_the_turn_of_the_frame(tracked):
    # a frame turned counter-clockwise by θ (as displayed) tilts the top of the head towards the
    # image's left, the subject's right: Live Link Face's roll (a positive roll tilts the top
    # towards the subject's left, facegeo.export.live_link) falls by θ; the yaw and pitch stay
    found = [f for f in tracked.frames if f.found]
    angles = np.degrees(head_angles(np.stack([f.rotation for f in found])))
    turns = np.array([ROLLS[f.index] for f in found])
    roll = angles[:, 2] - angles[list(turns).index(0.0), 2]
    assert np.abs(roll + turns).max() < 1.5, (roll, turns)
    # yaw and pitch move only as much as the face's shift across the image turns the line of
    # sight (the turn is about a point above the face: up to ~40 px at f ≈ 740 px, about 3°)
    assert np.ptp(angles[:, 0]) < 5.0 and np.ptp(angles[:, 1]) < 5.0


def test_facegeo_track_writes_a_take_the_live_link_reader_reads(tmp_path):
    from facegeo.export.live_link import read_live_link_csv

    clip = tmp_path / "clip.avi"
    frames = _frames()
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (width, height))
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", "track", str(clip), "-o", str(out), "--keyframes", "3",
                           "--neutral", "0.2"],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"tracked {clip}: {len(ROLLS)} frames (1 without a face)" in done.stdout
    take = read_live_link_csv(out / "take.csv", fps=10.0)
    assert take.n_frames == len(ROLLS) and np.allclose(take.times, np.arange(len(ROLLS)) / 10.0, atol=1e-6)
    assert set(take.rotations) == {"head"}
    text = (out / "track.json").read_text()
    record = json.loads(text)
    assert json.dumps(record, indent=1) == text  # written a frame at a time, as json.dumps writes the whole
    assert [f["found"] for f in record["frames"]] == [k != NO_FACE for k in range(len(ROLLS))]
    assert record["frames_with_face"] == len(ROLLS) - 1 and record["fps"] == pytest.approx(10.0)
    assert record["blinks"]["shut_fraction"] > 0 and 0.5 < record["blinks"]["open_gap_over_model"]["left"] < 2.0
    calibration = record["neutral_calibration"]  # the frames within 0.25 s of 0.2 s
    assert calibration["time_s"] == 0.2 and calibration["frames"] == [0, 1, 2, 3, 4] and calibration["chosen"] == "given"
    assert 0.0 < calibration["offsets_mm"]["landmarks_median"] <= calibration["offsets_mm"]["landmarks_max"] < 20.0
    # the frame without a face repeats its nearest tracked neighbour's values (flagged in track.json)
    np.testing.assert_array_equal(take.weights[NO_FACE], take.weights[NO_FACE - 1])
    assert {p.name for p in out.iterdir()} >= {"take.csv", "track.json", "asset", "face.glb", "face.usdz", "preview.png"}
    # the asset is the person's, animated by the take: one key a tracked frame
    import pygltflib

    gltf = pygltflib.GLTF2().load(str(out / "face.glb"))
    keys = gltf.accessors[gltf.animations[0].samplers[0].input]
    assert keys.count == len(ROLLS) and keys.max[0] == pytest.approx((len(ROLLS) - 1) / 10.0, abs=1e-4)
    assert record["asset"]["reference_frame"] in record["asset"]["texture_frames"]
    found = {f["index"] for f in record["frames"] if f["found"]}
    assert set(record["asset"]["texture_frames"]) <= found and len(record["asset"]["fusion"]["gains"]) == len(
        record["asset"]["texture_frames"])


def test_a_track_without_its_asset_imports_no_scipy(tmp_path):
    """The smoothing's filters and the take's head angles are NumPy's and OpenCV's: importing
    scipy.signal, scipy.ndimage and scipy.spatial cost 0.6-0.9 s of a 10 s track (RESULTS.md)."""
    folder = tmp_path / "frames"
    folder.mkdir()
    for k, frame in enumerate(_frames()):
        cv2.imwrite(str(folder / f"{k:03d}.png"), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    code = ("import sys; from facegeo.jobs import TrackOptions, track_into_folder; "
            f"track_into_folder({str(folder)!r}, {str(tmp_path / 'out')!r}, TrackOptions(asset=False, keyframes=3)); "
            "print(sorted(m for m in sys.modules if m == 'scipy' or m.startswith('scipy.')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "[]"
    assert json.loads((tmp_path / "out" / "track.json").read_text())["smoothing"]


def test_a_video_without_any_face_is_one_line(tmp_path):
    clip = tmp_path / "noise.avi"
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (160, 120))
    rng = np.random.default_rng(2)
    for _ in range(3):
        writer.write(rng.integers(0, 256, (120, 160, 3), dtype=np.uint8))
    writer.release()
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", "track", str(clip), "-o", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"facegeo: error: {clip}: face: expected a face in at least one frame, found none in 3 frames"]
    assert not (tmp_path / "out").exists()


def test_a_neutral_that_is_no_time_is_one_line(tmp_path):
    done = subprocess.run([sys.executable, "-m", "facegeo.cli", "track", str(tmp_path / "clip.mp4"), "-o", str(tmp_path / "out"),
                           "--neutral", "soon"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == ["facegeo: error: <command line>: --neutral: expected a time in seconds >= 0, auto or none, "
                                                "found soon"]


def test_the_same_person_is_followed_when_a_larger_face_comes_into_the_frame(model):
    # the detector takes a frame's most prominent face; after the first frame the tracker looks
    # for the face around the previous one first, so the larger face on the right is not taken
    from facegeo.tracking import track_frames

    face = load_photo(PHOTO).image
    larger = cv2.resize(face[:, ::-1], None, fx=1.3, fy=1.3)
    frames = []
    for k in range(4):
        canvas = np.full((larger.shape[0], face.shape[1] + larger.shape[1], 3), 90, np.uint8)
        canvas[: face.shape[0], : face.shape[1]] = face
        if k >= 1:
            canvas[:, face.shape[1]:] = larger
        frames.append(SimpleNamespace(index=k, time_s=k / 10.0, image=canvas))
    tracked = track_frames(frames, model, keyframes=2)
    assert all(f.found for f in tracked.frames)
    # the face on the left stays left of the image's centre (camera x < 0) in every frame
    assert all(f.translation[0] < 0 for f in tracked.frames), [f.translation for f in tracked.frames]


def test_smoothing_takes_the_jitter_out_and_keeps_a_blink_and_a_turn():
    from scipy.spatial.transform import Rotation

    from facegeo.tracking import TrackedFrame, smooth_track

    rng = np.random.default_rng(3)
    n = 40
    yaw = np.concatenate([np.zeros(15), np.linspace(0.0, 0.3, 10), np.full(15, 0.3)])  # still, a turn (rad), still
    blink = np.zeros(n)
    blink[30:33] = [0.7, 1.0, 0.7]  # a blink of three frames
    frames = []
    for k in range(n):
        rotation = Rotation.from_euler("YXZ", [yaw[k] + rng.normal(0, 0.01), rng.normal(0, 0.01), 0.0]).as_matrix()
        delta = np.clip(np.array([blink[k], 0.3 + rng.normal(0, 0.03)]), 0, 1).astype(np.float32)
        frames.append(TrackedFrame(k, k / 30.0, k != 20, rotation.astype(np.float32) if k != 20 else None,
                                   np.array([0.0, 0.0, -600.0 + rng.normal(0, 1.0)], np.float32) if k != 20 else None,
                                   delta if k != 20 else None))
    smoothed = smooth_track(frames, np.zeros(2), np.ones(2), fast=np.array([True, False]))  # the blink is a lid's
    assert [f.found for f in smoothed] == [f.found for f in frames] and smoothed[20].rotation is None

    def yaws(fs):
        return np.array([Rotation.from_matrix(f.rotation).as_euler("YXZ")[0] for f in fs if f.found])

    still = slice(0, 14)  # the first run's still stretch
    assert np.abs(np.diff(yaws(smoothed)[still])).mean() < 0.5 * np.abs(np.diff(yaws(frames)[still])).mean()
    weights = np.array([f.delta for f in smoothed if f.found])
    raw = np.array([f.delta for f in frames if f.found])
    # the other weight: a median of 5 and a Savitzky-Golay filter of 9 frames
    assert np.abs(np.diff(weights[:14, 1])).mean() < 0.4 * np.abs(np.diff(raw[:14, 1])).mean()
    assert weights[:, 0].max() > 0.9  # the blink keeps its peak (the lids' filter: 5 frames)
    every = np.array([f.delta for f in smooth_track(frames, np.zeros(2), np.ones(2), fast=np.array([False, False])) if f.found])
    assert every[:, 0].max() < 0.8  # the slow filter would have flattened it
    assert abs(yaws(smoothed)[-1] - 0.3) < 0.03 and abs(yaws(smoothed)[0]) < 0.03  # the turn ends where it ended (noise σ 0.01)


def test_a_cut_to_another_person_is_flagged(model):
    # a clip of the astronaut that cuts to Grace Hopper (same frame size) and back: the other
    # person's frames are flagged, not fitted with the clip's identity
    matplotlib = pytest.importorskip("matplotlib")
    from pathlib import Path

    from facegeo.tracking import track_frames

    face = load_photo(PHOTO).image
    other = cv2.resize(load_photo(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg").image,
                       (face.shape[1], face.shape[0]))
    images = [face, face, other, other, face]
    frames = [SimpleNamespace(index=k, time_s=k / 10.0, image=im) for k, im in enumerate(images)]
    tracked = track_frames(frames, model, keyframes=2)
    assert [f.found for f in tracked.frames] == [True, True, False, False, True]
    assert tracked.frames[2].note.startswith("another person (face descriptor")


def test_keyframes_span_the_head_turn_of_a_mostly_frontal_clip():
    """A clip that faces the camera most of the time and turns to ±35° briefly: one keyframe
    per yaw interval, the turns included (equal shares of the frames sorted by yaw picked only
    frontal ones) and their ends; a stray yaw does not stretch the range; a yaw without a frame
    near it takes the nearest unchosen one; more points win among the frames near a yaw."""
    from facegeo.tracking import spanning_frames

    yaws = np.concatenate([np.zeros(80), np.linspace(0, 35, 10), np.full(10, 35.0), np.linspace(0, -35, 10), np.full(10, -35.0)])
    yaws = np.radians(yaws + np.random.default_rng(0).normal(0, 0.3, len(yaws)))
    points = np.full(len(yaws), 88)
    chosen = spanning_frames(yaws, points, 5)
    assert len(chosen) == 5 and len(set(chosen)) == 5
    picked = np.degrees(yaws[chosen])
    assert picked.min() < -30 and picked.max() > 30 and np.abs(picked).min() < 10
    with_stray = np.append(yaws, np.radians(170.0))  # one mis-fitted frame
    assert len(yaws) not in spanning_frames(with_stray, np.append(points, 88), 5)
    gap = np.radians([0.0, 0.1, 0.2, 40.0, 40.1, 40.2])  # nothing between 0.2° and 40°: the nearest unchosen frames
    assert spanning_frames(gap, np.full(6, 88), 4) == [0, 2, 3, 5]  # targets 0°, 13.4°, 26.8°, 40.2°
    fewer_points = np.full(len(yaws), 88)
    fewer_points[np.argmin(np.abs(yaws))] = 70  # the most frontal frame lost points to a hand: another frontal one
    assert np.argmin(np.abs(yaws)) not in spanning_frames(yaws, fewer_points, 5)


def test_a_wink_is_tracked_as_one_eye_shut(model):
    from test_eyelids import shut_left_eye

    from facegeo.landmarks.detectors import detect_landmarks
    from facegeo.tracking import track_frames

    image = load_photo(PHOTO).image
    winked = shut_left_eye(image, detect_landmarks(image, "lids"))
    frames = [SimpleNamespace(index=k, time_s=k / 30.0, image=winked if k == 3 else image) for k in range(6)]
    track = track_frames(frames, model, keyframes=3)
    names = list(model.expression_names)
    left, right = (np.array([f.delta[names.index(n)] for f in track.frames]) for n in ("eyeBlink_L", "eyeBlink_R"))
    assert left[3] >= 0.6 and right[3] <= 0.3  # the wink: the subject's left eye alone
    assert np.all(np.delete(left, 3) <= 0.3) and np.all(right <= 0.3)


PARTS_SCRIPT = r"""
import json, sys
import numpy as np
import facegeo.forked_call as forked
from facegeo.jobs import TrackOptions, track_into_folder

clip, out = sys.argv[1], sys.argv[2]
forks, fork_call = [], forked.fork_call
forked.fork_call = lambda function, *args, **kwargs: forks.append(function.__name__) or fork_call(function, *args, **kwargs)
options = TrackOptions(asset=False, smooth=False, keyframes=3, every=int(sys.argv[3]), find_rest=False)  # one pass of the solve
two = track_into_folder(clip, out + "/two", options)
forked.can_fork = lambda: False
one = track_into_folder(clip, out + "/one", options)
assert "torch" not in sys.modules
frames = {name: json.load(open(out + "/" + name + "/track.json"))["frames"] for name in ("two", "one")}
assert "frames" not in two and "frames" not in one  # the record returned: the file has them
print(json.dumps({"forks": forks, **frames}))
"""


@pytest.mark.parametrize("every", [1, 2])
def test_a_clip_tracked_in_two_processes_is_the_clip_tracked_in_one(tmp_path, every):
    """Halves of a clip observed and solved at once, the second in a forked child: the same
    frames, in order, the same faces, poses and weights up to the child's own first detection
    and solve (the second half starts from a detection, not from the first half's last face)."""
    from facegeo.tracking import MIN_PART_FRAMES

    image = load_photo(PHOTO).image
    height, width = image.shape[:2]
    clip = tmp_path / "pan.avi"
    count = 2 * MIN_PART_FRAMES * every + 3
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (width, height))
    for k in range(count):  # a slow pan and turn in the image plane
        turn = cv2.getRotationMatrix2D((width / 2.0, height / 3.0), 6.0 * np.sin(k / 15.0), 1.0)
        turn[0, 2] += 8.0 * np.sin(k / 20.0)
        writer.write(cv2.cvtColor(cv2.warpAffine(image, turn, (width, height), borderMode=cv2.BORDER_REPLICATE), cv2.COLOR_RGB2BGR))
    writer.release()
    done = subprocess.run([sys.executable, "-c", PARTS_SCRIPT, str(clip), str(tmp_path), str(every)], capture_output=True, text=True,
                          timeout=900)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["forks"] == ["_observe_rest", "_track_part"]
    two, one = result["two"], result["one"]
    assert [f["index"] for f in two] == [f["index"] for f in one] == list(range(0, count, every))
    assert all(f["found"] for f in two + one)
    yaw_roll = np.array([[f["euler_deg"]["yaw"], f["euler_deg"]["roll"]] for f in two])
    assert np.abs(yaw_roll - [[f["euler_deg"]["yaw"], f["euler_deg"]["roll"]] for f in one]).max() < 1.0  # degrees
    assert np.abs(np.array([f["delta"] for f in two]) - [f["delta"] for f in one]).max() < 0.15


def test_a_second_part_that_starts_on_another_person_is_left_to_the_caller(model):
    """The forked child's part (:func:`facegeo.tracking._observe_rest`) starts from a detection of
    its own: where that finds another person first (the largest face of a crowd), it hands its
    part back rather than flag it all, and the caller follows the clip's person into it."""
    matplotlib = pytest.importorskip("matplotlib")
    from pathlib import Path

    from facegeo.tracking import _FrameObserver, _observe_rest

    face = load_photo(PHOTO).image
    other = cv2.resize(load_photo(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg").image,
                       (face.shape[1], face.shape[0]))
    observer = _FrameObserver(model, "lids", "<clip>")
    assert observer.observe(SimpleNamespace(index=0, time_s=0.0, image=face))[-1].observation is not None
    person = observer.person.copy()
    assert _observe_rest(observer, lambda: iter([SimpleNamespace(index=1, time_s=0.1, image=other)]), observer.store()) is None
    observer.person = person
    part = observer.store()
    assert _observe_rest(observer, lambda: iter([SimpleNamespace(index=k, time_s=k / 10, image=face) for k in (1, 2)]), part) == 2
    assert [f.index for f in part] == [1, 2] and all(f.observation is not None for f in part)


class _MissesSome:
    """A detector that finds no face in the frames whose pixels' sum is in ``missed`` (a face too
    small or too blurred for the face detector) and otherwise is ``detector``."""

    def __init__(self, detector, missed: set[int]):
        self.detector, self.missed = detector, missed

    def detect(self, image, source="<array>"):
        from facegeo.errors import NoFaceError

        if int(image.sum(dtype=np.int64)) in self.missed:
            raise NoFaceError(source, "face (test detector)", "a face", "no face")
        return self.detector.detect(image, source)


def _panned(image: np.ndarray, dx: float) -> np.ndarray:
    shift = np.float32([[1, 0, dx], [0, 1, 0]])
    return cv2.warpAffine(image, shift, image.shape[1::-1], borderMode=cv2.BORDER_REPLICATE)


def test_frames_the_detector_misses_are_followed_back_from_the_next_face(model):
    """A face the detector misses but the face mesh follows (the event clip's 50 px face in frame
    45, where the child's part started) is found by following the next frame's face back into
    the held frames; a frame without a face stays without one, and the frames come out in order."""
    from facegeo.tracking import _FrameObserver

    face = load_photo(PHOTO).image
    noise = np.random.default_rng(0).integers(0, 256, face.shape, dtype=np.uint8)
    images = [noise, _panned(face, 2.0), _panned(face, 4.0), _panned(face, 6.0)]
    observer = _FrameObserver(model, "lids", "<clip>")
    observer.det = _MissesSome(observer.det, {int(images[k].sum(dtype=np.int64)) for k in (1, 2)})
    decided = [observer.observe(SimpleNamespace(index=k, time_s=k / 30, image=im)) for k, im in enumerate(images)]
    assert [[f.index for f in out] for out in decided] == [[], [], [], [0, 1, 2, 3]]  # held until the face at 3
    frames = decided[-1]
    assert [f.observation is not None for f in frames] == [False, True, True, True]
    assert frames[0].note.endswith("no face")
    centre = [float(np.mean(f.observation.landmarks[:, 0])) for f in frames[1:]]
    assert np.diff(centre) == pytest.approx([2.0, 2.0], abs=0.5)  # px: each frame's own face, not a copy of the next one's
    assert all(f.lid_gaps is not None for f in frames[1:])
    assert [f.followed_back for f in frames] == [False, True, True, False]
    assert observer.flush() == []
    from facegeo.tracking import TrackedFrame

    assert TrackedFrame(1, 0.0, True, np.eye(3), np.zeros(3), np.zeros(2), 1.0, 1.0, followed_back=True).to_dict()["followed_back"]
    assert "followed_back" not in TrackedFrame(1, 0.0, True, np.eye(3), np.zeros(3), np.zeros(2), 1.0, 1.0).to_dict()


def test_the_keyframes_are_observed_again_by_the_photos_detector_for_the_identity(model):
    """With the frames' pixels at hand (``frame_image``), each keyframe is observed again by the
    photos' detector (its face only: the rest of the frame grey) for the clip's identity; where
    the pixels are not at hand (None), the tracked observation serves, as without the callback."""
    import facegeo.tracking as tracking
    from facegeo.tracking import clip_identity, observe_frames

    face = load_photo(PHOTO).image
    frames = [SimpleNamespace(index=k, time_s=k / 30, image=_panned(face, 3.0 * k)) for k in range(3)]
    observed, size = observe_frames(frames, model)
    asked = []
    plain = clip_identity(model, observed, size, keyframes=2)
    unavailable = clip_identity(model, observed, size, keyframes=2, frame_image=lambda seen: asked.append(seen.index))
    assert sorted(asked) == plain.keyframes and np.array_equal(unavailable.alpha, plain.alpha)
    images = {f.index: f.image for f in frames}
    seen_by = []
    detect = tracking.observe_photo

    def observing(image, model_, landmarks, detector, *args):
        seen_by.append((detector, float((image == 128).all(axis=-1).mean())))
        return detect(image, model_, landmarks, detector, *args)

    tracking.observe_photo = observing
    try:
        again = clip_identity(model, observed, size, keyframes=2, frame_image=lambda seen: images[seen.index])
    finally:
        tracking.observe_photo = detect
    assert [d for d, _ in seen_by] == [tracking.IDENTITY_DETECTOR] * 2
    assert all(grey > 0.3 for _, grey in seen_by)  # the frame outside the face's region is grey
    assert again.keyframes == plain.keyframes and not np.array_equal(again.alpha, plain.alpha)


def test_a_frame_the_face_was_followed_back_into_is_not_a_keyframe(model):
    """The keyframes of the clip's identity come from frames whose face was found going forward
    (a face followed back was lost there: a hand over it, motion blur); a clip of such frames only
    still gets its identity from them."""
    from facegeo.tracking import clip_identity, observe_frames

    face = load_photo(PHOTO).image
    frames = [SimpleNamespace(index=k, time_s=k / 30, image=_panned(face, 2.0 * k)) for k in range(4)]
    observed, size = observe_frames(frames, model)
    marked = [dataclasses.replace(f, followed_back=k in (1, 2)) for k, f in enumerate(observed)]
    assert clip_identity(model, marked, size, keyframes=2).keyframes == [0, 3]
    only = [dataclasses.replace(f, followed_back=True) for f in observed]
    assert len(clip_identity(model, only, size, keyframes=2).keyframes) == 2


def test_held_frames_are_handed_out_in_order_beyond_the_limit(model, monkeypatch):
    import facegeo.tracking as tracking

    monkeypatch.setattr(tracking, "HELD_FRAMES", 2)
    noise = np.random.default_rng(1).integers(0, 256, (200, 200, 3), dtype=np.uint8)
    observer = tracking._FrameObserver(model, "lids", "<clip>")
    out = [[f.index for f in observer.observe(SimpleNamespace(index=k, time_s=k / 30, image=noise))] for k in range(4)]
    assert out == [[], [], [0], [1]] and [f.index for f in observer.flush()] == [2, 3]
    assert observer.flush() == []


def test_a_face_rejected_in_one_frame_is_the_persons_when_the_next_frame_shows_it_again(model, monkeypatch):
    """A followed face whose descriptor passes the clip's limit in one frame (the event clip's
    fast-moving man, motion-blurred: 0.63 against 0.60) is the person's where the next frame's
    face, the person's, followed back finds the same face there and the two frames' descriptors
    agree; another person's face in between is not (a cut to Grace Hopper and back)."""
    matplotlib = pytest.importorskip("matplotlib")
    from pathlib import Path

    import facegeo.landmarks.face_identity as face_identity
    from facegeo.tracking import IDENTITY_CHECK_EVERY, _FrameObserver

    face = load_photo(PHOTO).image
    other = cv2.resize(load_photo(Path(matplotlib.get_data_path()) / "sample_data" / "grace_hopper.jpg").image,
                       (face.shape[1], face.shape[0]))
    blurred, after = _panned(face, 3.0), _panned(face, 6.0)
    descriptor = face_identity.face_descriptor
    # the blurred frame's descriptor 0.65 from the person's, the next frame's (blurred less) half-way
    moved = {int(blurred.sum(dtype=np.int64)): 0.65, int(after.sum(dtype=np.int64)): 0.325}
    monkeypatch.setattr(face_identity, "face_descriptor", lambda image, points: descriptor(image, points)
                        + moved.get(int(image.sum(dtype=np.int64)), 0.0) * np.eye(128, 1).ravel())
    for middle, kept in ((blurred, True), (other, False)):
        observer = _FrameObserver(model, "lids", "<clip>")
        frames = observer.observe(SimpleNamespace(index=0, time_s=0.0, image=face))
        observer.followed = IDENTITY_CHECK_EVERY  # the middle frame's face is compared with the person
        assert observer.observe(SimpleNamespace(index=1, time_s=1 / 30, image=middle)) == []
        assert observer.held[0].seen.note.startswith("another person (face descriptor")
        frames += observer.observe(SimpleNamespace(index=2, time_s=2 / 30, image=after))
        assert [f.index for f in frames] == [0, 1, 2]
        assert [f.observation is not None for f in frames] == [True, kept, True], middle is other


def test_the_same_person_limit_follows_what_the_clip_shows_of_the_person(model):
    from facegeo.landmarks.face_identity import SAME_PERSON_DISTANCE
    from facegeo.tracking import SAME_PERSON_CHECKS, SAME_PERSON_FLOOR, _FrameObserver

    observer = _FrameObserver(model, "lids", "<clip>")
    assert observer.same_person_limit() == SAME_PERSON_DISTANCE  # no evidence yet: dlib's
    observer.same_person = [0.34, 0.36, 0.35, 0.37][:SAME_PERSON_CHECKS - 1]
    assert observer.same_person_limit() == SAME_PERSON_DISTANCE
    observer.same_person = [0.34, 0.36, 0.35, 0.37, 0.33]  # a clip whose person stays near 0.35 to herself
    assert observer.same_person_limit() == pytest.approx(SAME_PERSON_FLOOR)  # 0.35 + 3 robust σ is under the floor
    observer.same_person = [0.30, 0.50, 0.40, 0.45, 0.35]
    assert SAME_PERSON_FLOOR < observer.same_person_limit() <= SAME_PERSON_DISTANCE
    observer.same_person = [0.2, 0.55, 0.58, 0.3, 0.59]
    assert observer.same_person_limit() == SAME_PERSON_DISTANCE  # never above dlib's


def test_brows_weigh_less_as_the_head_turns_them_away_and_alike_on_both_sides(model):
    """turned_brow_weights: 1 on a frontal face's inner brow, falling as the head turns (never
    rising), a point and its mirror partner alike, the same at +yaw and -yaw (ICT is nearly
    symmetric), and the brow ring's normals those of the whole mesh."""
    from facegeo.camera import rotation_from_euler
    from facegeo.landmarks.scheme import BROWS
    from facegeo.normals import vertex_normals
    from facegeo.tracking import SolveStart, _brow_ring, turned_brow_weights

    def at(yaw: float) -> np.ndarray:
        return turned_brow_weights(model, SolveStart(rotation_from_euler(yaw, 0.0, 0.0), np.array([0.0, 0.0, -1000.0]),
                                                     np.zeros(model.n_id), np.zeros(model.n_exp)))

    frontal = at(0.0)
    assert frontal.shape == (10,) and np.all(frontal[2:8] == 1.0) and np.all(frontal > 0.3)
    previous = frontal
    for yaw in (10.0, 20.0, 36.0, 60.0):
        now = at(yaw)
        np.testing.assert_array_equal(now, now[::-1])
        np.testing.assert_allclose(now, at(-yaw), atol=0.05)
        assert np.all(now <= previous + 1e-12) and now.sum() < previous.sum()
        previous = now
    assert at(60.0).max() == 0.0  # both brows left to the dense points
    ring = _brow_ring(model)
    everywhere = vertex_normals(model.shape_numpy().astype(np.float64), model.triangles)[np.asarray(model.landmark_indices)[BROWS]]
    np.testing.assert_allclose(vertex_normals(model.mean_shape[ring.vertices].astype(np.float64), ring.triangles)[ring.rows], everywhere,
                               atol=1e-9)


def test_the_dense_points_of_a_turned_away_brow_weigh_as_the_brows_do(model):
    """At 36 degrees of yaw a detector puts the far brow on the head's outline: the model face's
    own 88 points and dense points, with the far brow's landmarks and brow-region dense points 6 px
    low, read a frown under 0.2 (the region's points weigh as the mostly turned-away brows: 0.49
    when they weighed as the rest of the face), while frontal, where a brow faces the camera,
    both brows 6 px low read one above 0.1. The region holds the
    ten brow landmarks' vertices and none of the lips'."""
    from facegeo.camera import Camera, project, rotation_from_euler
    from facegeo.fitting.landmark_problem import SurfacePoints
    from facegeo.fitting.photo_fit import PhotoObservation
    from facegeo.landmarks.dense import load_dense_correspondence, points_on_mesh
    from facegeo.landmarks.scheme import BROWS
    from facegeo.tracking import SolveStart, _brow_ring, solve_frame

    region = _brow_ring(model).region
    indices = np.asarray(model.landmark_indices)
    assert region[indices[BROWS]].all() and not region[indices[48:68]].any()
    corr = load_dense_correspondence(model)
    camera = Camera(1000.0, 320.0, 240.0, 640, 480)
    alpha, delta = np.zeros(model.n_id), np.zeros(model.n_exp)
    shape = model.shape_numpy(alpha, delta).astype(np.float64)
    names = list(model.expression_names)
    frown = [names.index("browDown_L"), names.index("browDown_R")]
    on_region = region[corr.vertex_ids].any(axis=1)
    LOW_PX = 6.0
    readings = {}
    for yaw in (36.0, 0.0):
        rotation = rotation_from_euler(yaw, 0.0, 0.0)
        translation = np.array([0.0, 0.0, -1000.0])
        on_mesh = points_on_mesh(shape, corr).astype(np.float64)
        dense = project(on_mesh, rotation, translation, camera)
        depth = (on_mesh @ rotation.T)[:, 2]  # the far brow is the one further from the camera
        far = on_region & (depth < np.median(depth[on_region]) if yaw else True)
        dense[far, 1] += LOW_PX
        surface = SurfacePoints(dense, corr.vertex_ids, corr.barycentric, np.full(len(dense), 0.25))
        landmarks = project(shape[indices], rotation, translation, camera)
        brow_depth = (shape[indices[BROWS]] @ rotation.T)[:, 2]
        landmarks[np.asarray(BROWS)[brow_depth < np.median(brow_depth) if yaw else slice(None)], 1] += LOW_PX
        blank = np.zeros((camera.height, camera.width, 3), np.uint8)
        seen = PhotoObservation(blank, "<test>", blank, model, landmarks, camera, None, None, surface, {}, [])
        start = SolveStart(rotation, translation, alpha, delta)
        readings[yaw] = solve_frame(model, seen, camera, alpha, 0.02, start, blinks=np.zeros(2)).fit.delta[frown]
    assert readings[36.0].max() < 0.2 and readings[0.0].min() > 0.1, readings


def _posed_observation(model, alpha, delta, rotation, bias, camera):
    """The 88 landmarks of the model face (α, δ) posed by ``rotation`` 1 m from ``camera``, each
    moved by ``bias`` (88, 3) mm in model space: a detector's bias that turns with the head."""
    from facegeo.camera import project
    from facegeo.fitting.photo_fit import PhotoObservation

    points = model.shape_numpy(alpha, delta, np.asarray(model.landmark_indices)).astype(np.float64) + bias
    pixels = project(points, rotation, np.array([0.0, 0.0, -1000.0]), camera)
    blank = np.zeros((camera.height, camera.width, 3), np.uint8)
    return PhotoObservation(blank, "<test>", blank, model, pixels, camera, None, None, None, {}, [])


def _clip_frames(model, deltas: np.ndarray, yaws: np.ndarray, fps: float = 30.0) -> list:
    """Tracked frames (no images) with these expression weights (N, n_exp) and head yaws (N,) degrees."""
    from facegeo.camera import rotation_from_euler
    from facegeo.tracking import TrackedFrame

    return [TrackedFrame(k, k / fps, True, rotation_from_euler(float(yaw), 0.0, 0.0), np.array([0.0, 0.0, -600.0]),
                         d.astype(np.float32)) for k, (d, yaw) in enumerate(zip(deltas, yaws))]


def test_the_face_at_rest_is_the_clips_most_typical_still_stretch_not_its_smallest_weights(model):
    """A take at rest for most of its 3 s, whose detector bias reads as a stretch, a press and
    the jaw forward at rest (0.7 in all), with a smile that explains its frames with less weight
    (0.6): the rest is found, not the smile, and not in the first half second, where the face at
    rest is turned 25 degrees from the clip's typical view; its frames are at the clip's median
    (distance 0 <= REST_DISTANCE). A clip of a held smile (0.6) has its smile there, which is not
    taken for the face at rest (REST_STRONGEST). A person who talks throughout has no such
    stretch, and a head that never holds still (4 degrees between frames) none at all."""
    from facegeo.tracking import NEUTRAL_WINDOW_S, REST_DISTANCE, REST_STRONGEST, REST_TURN_DEG, rest_stretch

    names = list(model.expression_names)
    at_rest = np.zeros(model.n_exp)
    at_rest[[names.index(n) for n in ("mouthStretch_L", "mouthStretch_R")]] = 0.2
    at_rest[[names.index(n) for n in ("mouthPress_L", "jawForward")]] = 0.15
    smile = np.zeros(model.n_exp)
    smile[[names.index(n) for n in ("mouthSmile_L", "mouthSmile_R")]] = 0.3
    deltas = np.array([at_rest] * 60 + [smile] * 30)
    deltas[:, names.index("eyeBlink_L")] = np.where(np.arange(90) % 20 < 2, 1.0, 0.0)  # blinks at rest count for nothing
    yaws = np.where(np.arange(90) < 15, REST_TURN_DEG + 15.0, 0.0)
    found = rest_stretch(model, _clip_frames(model, deltas, yaws))
    assert found is not None and abs(found.distance) < 1e-6 and found.at_rest
    assert 14 / 30 < found.time_s - NEUTRAL_WINDOW_S and found.time_s + NEUTRAL_WINDOW_S < 60 / 30, found  # its frames: 15-59
    assert found.strongest[0] in ("mouthStretch_L", "mouthStretch_R") and abs(found.strongest[1] - 0.2) < 1e-6

    # a clip of a held smile: its most typical stretch is the smile, which is not the face at rest
    held = np.array([at_rest + 2 * smile] * 90)
    found = rest_stretch(model, _clip_frames(model, held, np.zeros(90)))
    assert found is not None and found.distance < REST_DISTANCE and not found.at_rest
    assert found.strongest[0] in ("mouthSmile_L", "mouthSmile_R") and abs(found.strongest[1] - 0.6) < 1e-6 and 0.6 > REST_STRONGEST

    rng = np.random.default_rng(3)
    talking = np.zeros((90, model.n_exp))
    for name in ("jawOpen", "mouthSmile_L", "mouthSmile_R", "mouthFunnel", "mouthRollLower"):
        talking[:, names.index(name)] = np.clip(0.3 + 0.25 * np.sin(np.arange(90) * rng.uniform(0.5, 1.5) + rng.uniform(0, 6)), 0, 1)
    found = rest_stretch(model, _clip_frames(model, talking, np.zeros(90)))
    assert found is not None and found.distance > REST_DISTANCE
    assert rest_stretch(model, _clip_frames(model, deltas, np.full(90, 40.0))[:2]) is None  # too few frames
    assert rest_stretch(model, _clip_frames(model, deltas, np.where(np.arange(90) % 2, 4.0, 0.0))) is None  # the head never still


def test_the_points_at_rest_are_measured_and_taken_off(model):
    """neutral_offsets on frames of the face at rest whose detector puts the brows 3 mm low (and
    every other inner point up to 1 mm off): a frame with the brows raised 0.6, 2 degrees from the
    rest pose, then reads as an unbiased detector's frame does (within 0.02), where as observed the
    bias takes more than 0.1 off; the offsets turn with the head and fade from 3 to 12 degrees of
    turn; no face near the time is a clear error."""
    from facegeo.camera import Camera, rotation_from_euler
    from facegeo.errors import InputError
    from facegeo.observed_frames import ObservedFrame
    from facegeo.tracking import NEUTRAL_FADE_DEG, ClipIdentity, neutral_offsets, solve_frame

    rng = np.random.default_rng(5)
    alpha = rng.normal(0.0, 0.5, model.n_id)
    camera = Camera(1000.0, 320.0, 240.0, 640, 480)
    bias = rng.uniform(-1.0, 1.0, (88, 3))
    bias[17:27, 1] -= 3.0  # the brows
    bias[:17] = 0.0  # the jaw slides along the outline: no bias it keeps
    rest = rotation_from_euler(0.0, 0.0, 0.0)
    frames = [ObservedFrame(k, k / 30, _posed_observation(model, alpha, np.zeros(model.n_exp), rest, bias, camera)) for k in range(6)]
    frames.append(ObservedFrame(40, 40 / 30, None, "no face"))
    shared = ClipIdentity(camera, alpha, 0.02, [0], [])
    offsets = neutral_offsets(model, frames, shared, 0.1)
    assert offsets.frames == [0, 1, 2, 3, 4, 5] and offsets.points.shape == offsets.offsets.shape == (88, 3)
    np.testing.assert_allclose(offsets.offsets[:17], 0.0)
    assert np.degrees(np.arccos(np.clip((np.trace(offsets.rest_rotation) - 1) / 2, -1, 1))) < 1.0  # the bias tilts the pose a little

    names = list(model.expression_names)
    raised = np.zeros(model.n_exp)
    raised[[names.index(n) for n in ("browInnerUp_L", "browInnerUp_R", "browOuterUp_L", "browOuterUp_R")]] = 0.6
    brows = [names.index(n) for n in ("browInnerUp_L", "browInnerUp_R")]
    turned = rotation_from_euler(2.0, 1.0, 0.0)
    seen = _posed_observation(model, alpha, raised, turned, bias, camera)
    measured = solve_frame(model, seen, camera, alpha, 0.02, offsets=offsets).fit.delta[brows]
    as_observed = solve_frame(model, seen, camera, alpha, 0.02).fit.delta[brows]
    unbiased = solve_frame(model, _posed_observation(model, alpha, raised, turned, np.zeros((88, 3)), camera), camera, alpha, 0.02)
    unbiased = unbiased.fit.delta[brows]  # the prior's shrinkage at this noise: about 0.24
    assert np.abs(measured - unbiased).max() < 0.02 and (unbiased - as_observed).min() > 0.1, (measured, as_observed, unbiased)

    full, none = NEUTRAL_FADE_DEG
    assert offsets.share(rotation_from_euler(full * 0.9, 0.0, 0.0) @ offsets.rest_rotation) == 1.0
    assert offsets.share(rotation_from_euler(0.0, (full + none) / 2, 0.0) @ offsets.rest_rotation) == pytest.approx(0.5, abs=1e-6)
    far = rotation_from_euler(none + 1, 0.0, 0.0) @ offsets.rest_rotation
    assert offsets.share(far) == 0.0 and np.abs(offsets.shift(far, np.array([0.0, 0.0, -1000.0]), camera)).max() == 0.0
    with pytest.raises(InputError, match="--neutral.*no tracked face"):
        neutral_offsets(model, frames, shared, 40 / 30)
    with pytest.raises(InputError, match="within the tracked range"):
        from facegeo.jobs import TrackOptions

        TrackOptions(start_s=1.0, end_s=2.0, neutral_s=2.5)


def test_the_brows_of_the_face_at_rest_are_carried_by_the_flow_where_it_returns():
    """BrowFlow.carried on a textured frame moved by (2.6, -1.4) px, whose detector left its points
    where they were at rest: the carried points land on the moved texture within 0.05 px and weigh
    BROW_FLOW_WEIGHT times more; where the frame's patch is another texture (an occluder), the flow
    does not return and the points keep their detected place and weight; points outside ``rows``
    are not touched. Frames read again are found by index, in order; a video that fails to open
    or to read again gives no more images, not an error."""
    from facegeo.camera import Camera
    from facegeo.fitting.landmark_problem import SurfacePoints
    from facegeo.fitting.photo_fit import PhotoObservation
    from facegeo.errors import InputError
    from facegeo.tracking import BROW_FLOW_WEIGHT, BrowFlow, _FramesInOrder

    rng = np.random.default_rng(7)
    texture = cv2.GaussianBlur(rng.uniform(0, 255, (240, 320)).astype(np.float32), (0, 0), 2.0)
    texture = cv2.normalize(texture, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
    shift = np.array([2.6, -1.4])
    moved = cv2.warpAffine(texture, np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]), (320, 240), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REFLECT)
    occluder = rng.uniform(0, 255, (60, 60)).astype(np.uint8)
    moved[150:210, 220:280] = cv2.GaussianBlur(occluder, (0, 0), 2.0)
    points = np.array([[x, y] for y in (60.0, 100.0, 180.0) for x in (60.0, 110.0, 160.0, 250.0)])  # 12; (250, 180) occluded
    k = len(points)
    rest = SurfacePoints(points, np.zeros((k, 3)), np.tile([1.0, 0.0, 0.0], (k, 1)), np.ones(k))
    rows = np.array([0, 1, 2, 4, 5, 6, 11])  # 3, 7, 8, 9, 10 are not the brows'
    flow = BrowFlow(texture, rest, rows, lambda time_s: [])
    detected = points.copy()
    detected[1] = np.nan  # a point the detector did not place: the flow starts from where it was at rest
    camera = Camera(300.0, 160.0, 120.0, 320, 240)
    seen = PhotoObservation(np.zeros((240, 320, 3), np.uint8), "<test>", np.zeros((240, 320, 3), np.uint8), None,
                            np.zeros((88, 2)), camera, None, None, SurfacePoints(detected, rest.vertex_ids, rest.barycentric, np.ones(k)),
                            {}, [])
    carried, count = flow.carried(seen, cv2.cvtColor(moved, cv2.COLOR_GRAY2RGB))
    carried = carried.surface_points
    assert count == 6
    kept = np.array([0, 1, 2, 4, 5, 6])
    assert np.abs(carried.targets[kept] - (points[kept] + shift)).max() < 0.05
    np.testing.assert_array_equal(carried.weights[kept], BROW_FLOW_WEIGHT)
    np.testing.assert_array_equal(carried.targets[11], points[11])  # under the occluder: no return
    assert carried.weights[11] == 1.0
    others = np.setdiff1d(np.arange(k), rows)
    np.testing.assert_array_equal(carried.targets[others], detected[others])
    np.testing.assert_array_equal(carried.weights[others], 1.0)

    frames = [SimpleNamespace(index=i, image=np.full((2, 2, 3), i, np.uint8)) for i in (3, 5, 6, 9)]
    reader = _FramesInOrder(lambda: frames)
    assert reader.at(5)[0, 0, 0] == 5 and reader.at(7) is None and reader.at(9)[0, 0, 0] == 9 and reader.at(12) is None

    def unreadable():
        yield frames[0]
        raise InputError("clip.mp4", "frames", "a readable frame", "a broken packet")

    def unopenable():
        raise InputError("clip.mp4", "video", "a video", "nothing")

    reader = _FramesInOrder(unreadable)
    assert reader.at(3) is not None and reader.at(5) is None and reader.at(6) is None  # read again, it fails: no more images
    assert _FramesInOrder(unopenable).at(0) is None
