"""A face through a video: one identity from keyframes, then the pose and expression of every frame.

:func:`track_frames` takes the frames of one clip (:func:`facegeo.video.open_video`) and

1. observes every frame as a photo fit does (:func:`facegeo.fitting.photo_fit.observe_photo`:
   the hybrid detector's 88 landmarks and MediaPipe's 468 dense points); a frame where no face is
   found is recorded as such (never invented);
2. sets one camera for the clip: the given focal, or, for an unknown lens, the median over the
   frames of the focal that puts each frame's face 1 m away (one lens, one distance);
3. chooses keyframes that span the head's turn (the frames' yaw from solvePnP on the mean shape,
   at evenly spaced quantiles, each the best-followed frame of its share) and fits one identity α
   to them jointly (:func:`facegeo.fitting.shared_identity.solve_shared_identity`);
4. tracks every frame with α fixed: pose and expression δ by the single-view MAP fit
   (:func:`facegeo.fitting.landmark_fit.solve_landmarks`, identity columns left out), warm-started
   from the previous frame (or, after a frame without a face, from solvePnP), at the keyframes'
   median landmark noise.

What is not done yet (issue 48): detection runs on every frame (no box from the previous
frame's landmarks), no temporal smoothing, no gaze (eye rotations), no cut detection.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from facegeo.camera import Camera, euler_from_rotation
from facegeo.errors import InputError, NoFaceError
from facegeo.fitting.dense_term import DEFAULT_DENSE
from facegeo.fitting.landmark_fit import initial_pose, solve_landmarks
from facegeo.fitting.photo_fit import PhotoObservation, observe_photo
from facegeo.fitting.priors import DEFAULT_PRIORS, LandmarkStage
from facegeo.fitting.shared_identity import LandmarkView, solve_shared_identity
from facegeo.landmarks.detectors import get_detector
from facegeo.morphable_model import MorphableModel

__all__ = ["TrackedFrame", "Track", "track_frames", "TRACK_STAGE", "KEYFRAMES"]

#: The per-frame solve: pose and expression, identity fixed (no identity columns), warm-started.
TRACK_STAGE = LandmarkStage("track", 8, 0, True)
#: Keyframes for the identity (fewer when the clip has fewer frames with a face).
KEYFRAMES = 5


@dataclass(frozen=True)
class TrackedFrame:
    """One frame of a :class:`Track`. ``index``: its number in the source; ``time_s``: seconds
    from the source's start; ``found``: whether a face was found and fitted; then (None when not
    found) ``rotation`` (3, 3) and ``translation`` (3,) mm (X_c = R·X + t), ``delta`` (n_exp,)
    float32 expression weights, ``landmark_rms_px`` and ``landmark_rms_percent_iod``;
    ``keyframe``: used for the identity; ``note``: why no face (the detector's or the fit's words)."""

    index: int
    time_s: float
    found: bool
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    delta: np.ndarray | None = None
    landmark_rms_px: float | None = None
    landmark_rms_percent_iod: float | None = None
    keyframe: bool = False
    note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: pose as rotation, Euler angles (degrees) and translation (mm)."""
        out: dict[str, Any] = {"index": self.index, "time_s": self.time_s, "found": self.found, "keyframe": self.keyframe}
        if self.found:
            yaw, pitch, roll = euler_from_rotation(self.rotation)
            out.update(landmark_rms_px=self.landmark_rms_px, landmark_rms_percent_iod=self.landmark_rms_percent_iod,
                       rotation=np.asarray(self.rotation).tolist(), euler_deg={"yaw": yaw, "pitch": pitch, "roll": roll},
                       translation_mm=np.asarray(self.translation).tolist(), delta=np.asarray(self.delta).tolist())
        if self.note:
            out["note"] = self.note
        return out


@dataclass
class Track:
    """A tracked clip: the identity ``alpha`` (n_id,) float32 shared by every frame, the clip's
    ``camera``, the ``frames`` in order, ``timings`` (s by stage) and ``notes``."""

    alpha: np.ndarray
    camera: Camera
    frames: list[TrackedFrame]
    timings: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def keyframes(self) -> list[int]:
        """The source indices of the keyframes."""
        return [f.index for f in self.frames if f.keyframe]


def track_frames(frames: Iterable[Any], model: MorphableModel, detector: str = "hybrid", focal: float | None = None,
                 keyframes: int = KEYFRAMES, progress: Callable[[int], None] | None = None, source: str = "<video>") -> Track:
    """Track the face through ``frames`` (module docstring).

    Args:
        frames: :class:`facegeo.video.Frame`-like objects (``index``, ``time_s``, ``image`` (H, W,
            3) uint8 RGB), all of one size, in order.
        model: the morphable model.
        detector: the landmark detector's name.
        focal: the lens's focal length in pixels of the frames; None: unknown (module docstring).
        keyframes: how many frames the identity is fitted to.
        progress: called with the number of frames observed so far, after each.
        source: the video's name, for errors.
    Returns:
        The :class:`Track`.
    Raises:
        InputError: no frames, frames of different sizes, or no frame with a face.
    """
    timings: dict[str, float] = {}
    det = get_detector(detector)
    start = time.perf_counter()
    seen: list[tuple[Any, PhotoObservation | None, str | None]] = []
    size = None
    for frame in frames:
        height, width = frame.image.shape[:2]
        if size is None:
            size = (width, height)
        elif size != (width, height):
            raise InputError(source, f"frame {frame.index}: frame size", f"{size[0]}x{size[1]} px as the first frame", f"{width}x{height} px")
        try:
            observation = observe_photo(frame.image, model, None, det, None, DEFAULT_DENSE)
            seen.append((frame, _light(observation), None))
        except NoFaceError as error:
            seen.append((frame, None, f"{error.field}: {error.found or error.expected}"))
        if progress is not None:
            progress(len(seen))
    timings["observe"] = time.perf_counter() - start
    if not seen:
        raise InputError(source, "frames", "at least one frame", "none in the range")
    found = [k for k, (_, obs, _) in enumerate(seen) if obs is not None]
    if not found:
        raise NoFaceError(source, "face", "a face in at least one frame", f"none in {len(seen)} frames")
    width, height = size
    camera = (Camera.unknown_focal(width, height) if focal is None else
              Camera(float(focal), width / 2.0, height / 2.0, width, height))
    notes = []
    if focal is None:
        camera = dataclasses.replace(camera, focal=float(np.median([seen[k][1].camera.focal for k in found])), focal_known=True)
        notes.append(f"focal length unknown: set to {camera.focal:.0f} px, the median over the frames of the focal that puts "
                     "the face 1.0 m from the camera (give --focal for a known lens)")

    start = time.perf_counter()
    chosen = _keyframes(model, [seen[k][1] for k in found], camera, keyframes)
    key_ids = [found[j] for j in chosen]
    views = [LandmarkView(seen[k][1].landmarks, camera, seen[k][1].weights, seen[k][1].surface_points, f"{source}, frame {seen[k][0].index}")
             for k in key_ids]
    solutions = solve_shared_identity(model, views)
    alpha = solutions[0].fit.alpha.astype(np.float64)
    noise = float(np.median([s.noise for s in solutions]))
    timings["identity"] = time.perf_counter() - start

    start = time.perf_counter()
    priors = dataclasses.replace(DEFAULT_PRIORS, noise=noise, noise_rounds=0)
    out: list[TrackedFrame] = []
    previous = None
    for k, (frame, obs, why) in enumerate(seen):
        if obs is None:
            out.append(TrackedFrame(frame.index, frame.time_s, False, note=why))
            previous = None
            continue
        if previous is None:
            rotation, translation = initial_pose(model, obs.landmarks, camera)
            previous = _Start(rotation, translation, alpha, np.zeros(model.n_exp))
        fit = solve_landmarks(model, obs.landmarks, camera, obs.weights, (TRACK_STAGE,), priors, previous, obs.surface_points).fit
        previous = _Start(fit.rotation, fit.translation, alpha, fit.delta)
        out.append(TrackedFrame(frame.index, frame.time_s, True, fit.rotation, fit.translation, fit.delta,
                                float(fit.landmark_rms_px), float(fit.landmark_rms_percent_iod), k in key_ids))
    timings["track"] = time.perf_counter() - start
    return Track(alpha.astype(np.float32), camera, out, timings, notes)


@dataclass(frozen=True)
class _Start:
    """Where a frame's solve starts (what :func:`solve_landmarks` reads of its ``init``)."""

    rotation: np.ndarray
    translation: np.ndarray
    alpha: np.ndarray
    delta: np.ndarray


def _light(observation: PhotoObservation) -> PhotoObservation:
    """The observation without its pixels (a clip's frames are not kept in memory)."""
    return dataclasses.replace(observation, image=np.zeros((0, 0, 3), np.uint8), pixels=np.zeros((0, 0, 3), np.uint8))


def _keyframes(model: MorphableModel, observations: list[PhotoObservation], camera: Camera, count: int) -> list[int]:
    """Indices into ``observations`` of up to ``count`` keyframes spanning the head's yaw: the
    frames sorted by their solvePnP yaw on the mean shape are cut into ``count`` equal shares and
    each share gives its frame of most points (then earliest)."""
    if len(observations) <= count:
        return list(range(len(observations)))
    yaws = np.array([euler_from_rotation(initial_pose(model, o.landmarks, camera)[0])[0] for o in observations])
    order = np.argsort(yaws, kind="stable")
    chosen = []
    for share in np.array_split(order, count):
        chosen.append(int(min(share, key=lambda j: (-int(np.isfinite(observations[j].landmarks).all(axis=1).sum()), j))))
    return sorted(chosen)
