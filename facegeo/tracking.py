"""A face through a video: one identity from keyframes, then the pose and expression of every frame.

:func:`track_frames` takes the frames of one clip (:func:`facegeo.video.open_video`) and

1. observes every frame as a photo fit does (:func:`facegeo.fitting.photo_fit.observe_photo`:
   the hybrid detector's 88 landmarks and MediaPipe's 468 dense points); a frame where no face is
   found is recorded as such (never invented);
2. sets one camera for the clip: the given focal, or, for an unknown lens, the median over the
   frames of the focal that puts each frame's face 1 m away (one lens, one distance);
3. chooses keyframes that span the head's turn (the frames' yaw from solvePnP on the mean shape,
   at evenly spaced quantiles, each the best-followed frame of its share) and fits one identity α
   to them jointly (:func:`facegeo.fitting.shared_identity.solve_shared_identity`), each observed
   again by the photos' detector where the frames can be decoded again;
4. tracks every frame with α fixed: pose and expression δ by the single-view MAP fit
   (:func:`facegeo.fitting.landmark_fit.solve_landmarks`, identity columns left out), warm-started
   from the previous frame (or, after a frame without a face, from solvePnP), at the keyframes'
   median landmark noise. The blinks are not fitted but read from the lids
   (:mod:`facegeo.landmarks.eyelids`: the iris model's lid gap of each eye, observed in step 1,
   against the gap the eye shows open in the previous frame's pose, calibrated on the keyframes)
   and held in the solve, where the lid points then weigh nothing.

After a frame with a face the face is followed into the next without the face detector (the
face mesh on the previous frame's mesh, as MediaPipe's video mode does: the same person, not
another face that comes into the frame; the region around it, then the whole frame, are searched
where it is lost). A clip long enough is observed and solved in two halves at once, the second
in a forked process (:data:`MIN_PART_FRAMES`). What was observed waits for the identity in an
unnamed temporary file (:class:`~facegeo.observed_frames.ObservedFrames`), not in memory. :func:`smooth_track`
takes the frame-to-frame jitter out afterwards; a cut to another person is told by the face
descriptor (:func:`observe_frames`). Every frame's points are measured from the person's own at
rest (:func:`neutral_offsets`), at a given time, or, where none is given, at the clip's most
typical still stretch (:func:`rest_stretch`) when it is typical enough to be the face at rest (the
frames are then solved again); where the frames can be decoded again, the brows' region of the
face at rest is then carried into each frame by optical flow (:class:`BrowFlow`) and the puff is
read from the cheeks' shading against the face at rest (:mod:`facegeo.cheek_shading`) in place of
the points' own. What is not done yet (issue 48): gaze (eye rotations).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from facegeo.arkit import arkit_name
from facegeo.camera import Camera, euler_from_rotation, to_pixels
from facegeo.cheek_shading import CheekShading, cheek_shading
from facegeo.errors import InputError, NoFaceError
from facegeo.fitting.dense_term import DEFAULT_DENSE
from facegeo.fitting.landmark_fit import LandmarkSolution, initial_pose, solve_landmarks
from facegeo.fitting.landmark_problem import SurfacePoints, subset_bases
from facegeo.fitting.photo_fit import PhotoObservation, observe_photo
from facegeo.fitting.priors import DEFAULT_PRIORS, LandmarkStage
from facegeo.fitting.shared_identity import LandmarkView, solve_shared_identity
from facegeo.landmarks.detectors import get_detector
from facegeo.landmarks import eyelids
from facegeo.landmarks.scheme import BROWS, EYES, JAW, LANDMARK_WEIGHTS, N_LANDMARKS, inter_ocular_distance
from facegeo.morphable_model import MorphableModel
from facegeo.normals import vertex_normals
from facegeo.observed_frames import ObservedFrame, ObservedFrames

__all__ = ["TrackedFrame", "Track", "ClipIdentity", "track_frames", "observe_frames", "clip_identity",
           "follow_region", "spanning_frames", "lid_weights", "track_observed", "solve_frame", "smooth_track", "SolveStart",
           "turned_brow_weights", "TURNED_BROW_RAMP", "NeutralOffsets", "neutral_offsets", "NEUTRAL_POSE_STAGE", "NEUTRAL_WINDOW_S",
           "NEUTRAL_FADE_DEG", "RestStretch", "rest_stretch", "REST_DISTANCE", "REST_STRONGEST", "REST_TURN_DEG", "BrowFlow", "face_at_rest",
           "BROW_FLOW_WEIGHT", "BROW_FLOW_RETURN_PX", "BROW_FLOW_WINDOW", "BROW_FLOW_LEVELS",
           "TRACK_STAGE", "KEYFRAMES", "FOLLOW_MARGIN", "POSE_WINDOW", "WEIGHT_WINDOW", "SLOW_WEIGHT_WINDOW",
           "IDENTITY_CHECK_EVERY", "HELD_FRAMES", "HELD_BYTES", "BROW_ALONG_NOISE", "IDENTITY_DETECTOR", "face_region_only"]

#: The per-frame solve: pose and expression, identity fixed (no identity columns), warm-started;
#: the contours slid before its first 2 iterations (from the previous frame's pose they barely
#: move after). Knobs against the ground-truth take (benchmarks/RESULTS.md, "the track's speed"):
#: 8, 6, 4, 2 iterations give a head median of 0.49, 0.50, 0.51, 0.54° and a mean curve r of 0.744,
#: 0.740, 0.735, 0.719 in 1.0, 0.86, 0.69, 0.52 of 8's time; sliding before 2 of 6 iterations
#: instead of all 6 gives 0.50° and 0.741 in 0.71 of the time (before 1: 0.54°, 0.736).
TRACK_STAGE = LandmarkStage("track", 6, 0, True, slides=2)
#: Keyframes for the identity (fewer when the clip has fewer frames with a face).
KEYFRAMES = 5
#: The eyes' 12 points weigh this many times their weight in a single photo's fit in the
#: per-frame solve: a shut lid moves them by about the landmark noise alone.
EYE_WEIGHT = 4.0
#: Frames of the pose's running median (:func:`smooth_track`; a live use lags by half of it, rounded down).
POSE_WINDOW = 5
#: Frames of the lids' weights' Savitzky–Golay filter, order 2 (:func:`smooth_track`).
WEIGHT_WINDOW = 5
#: Frames of the other weights' Savitzky–Golay filter, order 2, after a running median of
#: :data:`WEIGHT_WINDOW` frames (:func:`smooth_track`).
SLOW_WEIGHT_WINDOW = 9


@dataclass(frozen=True)
class TrackedFrame:
    """One frame of a :class:`Track`. ``index``: its number in the source; ``time_s``: seconds
    from the source's start; ``found``: whether a face was found and fitted; then (None when not
    found) ``rotation`` (3, 3) and ``translation`` (3,) mm (X_c = R·X + t), ``delta`` (n_exp,)
    float32 expression weights, ``landmark_rms_px`` and ``landmark_rms_percent_iod``;
    ``keyframe``: used for the identity; ``note``: why no face (the detector's or the fit's words);
    ``followed_back``: the face was lost going forward and found by following the next frame's
    face back (:attr:`~facegeo.observed_frames.ObservedFrame.followed_back`); ``brow_flow``, how
    many brow points the optical flow from the face at rest carried into this frame
    (:meth:`BrowFlow.carried`; None where it was not tried); ``puff_gain``, the share of the
    cheeks' shading error that the puff read from it explained
    (:meth:`~facegeo.cheek_shading.CheekShading.puff_reading`; None where it was not read)."""

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
    followed_back: bool = False
    brow_flow: int | None = None
    puff_gain: float | None = None

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
        if self.followed_back:
            out["followed_back"] = True
        if self.brow_flow is not None:
            out["brow_flow_points"] = self.brow_flow
        if self.puff_gain is not None:
            out["puff_shading_gain"] = self.puff_gain
        return out


@dataclass
class Track:
    """A tracked clip: the identity ``alpha`` (n_id,) float32 shared by every frame, the clip's
    ``camera`` and landmark ``noise`` (inter-ocular units, :class:`ClipIdentity`), the ``frames``
    in order, ``timings`` (s by stage), ``notes`` and ``open_lids`` (2,), the lid reader's open
    gap over the model's per eye (:class:`ClipIdentity`; None where the blinks were fitted);
    ``neutral``, the person's points at rest every frame was measured from (:func:`neutral_offsets`;
    None: as observed); ``rest``, the clip's most typical still stretch where it was looked for
    (:func:`rest_stretch`; also when it was not typical enough to be taken as the face at rest);
    ``brow_flow``, the number of brow points carried by optical flow from the face at rest
    (:class:`BrowFlow`; 0 without)."""

    alpha: np.ndarray
    camera: Camera
    noise: float
    frames: list[TrackedFrame]
    timings: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    open_lids: np.ndarray | None = None
    neutral: NeutralOffsets | None = None
    rest: RestStretch | None = None
    brow_flow: int = 0

    @property
    def keyframes(self) -> list[int]:
        """The source indices of the keyframes."""
        return [f.index for f in self.frames if f.keyframe]


@dataclass(frozen=True)
class ClipIdentity:
    """What a clip's frames share (:func:`clip_identity`): the ``camera``, the identity ``alpha``
    (n_id,) float64, the landmark ``noise`` (inter-ocular units, the keyframes' median), the
    ``keyframes`` (positions in the observed list) and ``notes``; ``open_lids`` (2,), the ratio of
    the iris model's lid gap to the model's neutral one on the keyframes, per eye
    (:func:`facegeo.landmarks.eyelids.open_ratio`; None where the lids are not read)."""

    camera: Camera
    alpha: np.ndarray
    noise: float
    keyframes: list[int]
    notes: list[str]
    open_lids: np.ndarray | None = None


def track_frames(frames: Iterable[Any], model: MorphableModel, detector: str = "lids", focal: float | None = None,
                 keyframes: int = KEYFRAMES, progress: Callable[[int], None] | None = None, source: str = "<video>",
                 rest: Callable[[], Iterable[Any]] | None = None, neutral_s: float | None = None,
                 frame_image: Callable[[ObservedFrame], np.ndarray | None] | None = None, find_rest: bool = True,
                 frames_again: Callable[[float], Iterable[Any]] | None = None) -> Track:
    """Track the face through ``frames`` (module docstring): :func:`observe_frames`, then
    :func:`clip_identity`, then :func:`track_observed`.

    Args:
        frames: :class:`facegeo.video.Frame`-like objects (``index``, ``time_s``, ``image`` (H, W,
            3) uint8 RGB), all of one size, in order.
        model: the morphable model.
        detector: the landmark detector's name.
        focal: the lens's focal length in pixels of the frames; None: unknown (module docstring).
        keyframes: how many frames the identity is fitted to.
        progress: called with the number of frames observed so far, after each.
        source: the video's name, for errors.
        rest: opens the frames after ``frames``, observed beside them (:func:`observe_frames`).
        neutral_s: seconds (the frames' clock) at which the face is at rest: every frame's points
            are measured from the person's own there (:func:`neutral_offsets`); None: see
            ``find_rest``.
        frame_image: a keyframe's pixels decoded again, for its identity view (:func:`clip_identity`).
        find_rest: without ``neutral_s``, look for the face at rest (:func:`rest_stretch`): where
            the clip's most typical still stretch is within :data:`REST_DISTANCE` of its median
            expression and holds no expression (:data:`REST_STRONGEST`), every frame is solved
            again measured from the person's points there; otherwise (and with False) as
            observed, with a note.
        frames_again: opens the frames again from a time (s, the frames' clock; they may begin
            before it): with the person's points at rest, the brows' region of the frame at rest is
            carried into each frame by optical flow (:class:`BrowFlow`); None: not.
    Returns:
        The :class:`Track`.
    Raises:
        InputError: no frames, frames of different sizes, no frame with a face, or none near
            ``neutral_s``.
    """
    timings: dict[str, float] = {}
    start = time.perf_counter()
    observed, size = observe_frames(frames, model, detector, progress, source, rest)
    timings["observe"] = time.perf_counter() - start
    start = time.perf_counter()
    shared = clip_identity(model, observed, size, focal, keyframes, source, frame_image)
    offsets = None if neutral_s is None else neutral_offsets(model, observed, shared, neutral_s, source)
    flow, shading = (None, None) if offsets is None or frames_again is None else face_at_rest(model, observed, shared, offsets,
                                                                                             frames_again)
    timings["identity"] = time.perf_counter() - start
    start = time.perf_counter()
    tracked = track_observed(model, observed, shared, offsets=offsets, flow=flow, shading=shading)
    timings["track"] = time.perf_counter() - start
    notes, found_rest = list(shared.notes), None
    if neutral_s is None and find_rest:
        start = time.perf_counter()
        found_rest = rest_stretch(model, tracked)
        if found_rest is not None and found_rest.at_rest:
            offsets = neutral_offsets(model, observed, shared, found_rest.time_s, source)
            flow, shading = (None, None) if frames_again is None else face_at_rest(model, observed, shared, offsets, frames_again)
            tracked = track_observed(model, observed, shared, offsets=offsets, flow=flow, shading=shading)
            notes.append(f"expressions measured from the face at rest at {found_rest.time_s:.2f} s (the clip's most typical still "
                         f"stretch; --neutral S to choose the time, --neutral none for the points as observed)")
        elif found_rest is not None and found_rest.distance <= REST_DISTANCE:
            notes.append(f"expressions measured from the points as observed: the clip's most typical still stretch (at "
                         f"{found_rest.time_s:.2f} s) holds an expression ({found_rest.strongest_name} {found_rest.strongest[1]:.2f}), "
                         "not the face at rest; --neutral S gives a time at which the face is at rest")
        else:
            notes.append("expressions measured from the points as observed: no stretch of the clip holds its typical face "
                         f"still{'' if found_rest is None else f' (the closest: {found_rest.distance:.2f} at {found_rest.time_s:.2f} s)'}; "
                         "--neutral S gives a time at which the face is at rest")
        timings["rest"] = time.perf_counter() - start
    return Track(shared.alpha.astype(np.float32), shared.camera, shared.noise, tracked, timings, notes, shared.open_lids,
                 offsets, found_rest, 0 if flow is None else len(flow.rows))


def observe_frames(frames: Iterable[Any], model: MorphableModel, detector: str = "lids",
                   progress: Callable[[int], None] | None = None, source: str = "<video>",
                   rest: Callable[[], Iterable[Any]] | None = None) -> tuple[ObservedFrames, tuple[int, int]]:
    """Every frame observed as a photo fit observes a photo (module docstring, step 1), the
    pixels dropped: ``(frames, (width, height))``, the frames in an
    :class:`~facegeo.observed_frames.ObservedFrames` (an unnamed temporary file: memory stays the
    same however long the clip). The person stays the same from frame to frame:

    * after a frame with a face, the face is followed into the next frame without the face
      detector where the detector can (its ``follow``: the face mesh on the previous frame's
      mesh ROI, as MediaPipe's video mode does), so that another face in the frame is not taken
      for it; where it is lost, the region around the last face (:data:`FOLLOW_MARGIN` × the
      landmarks' extent on each side) is searched, then the whole frame;
    * the clip's person is the first face found; a face found by searching the whole frame, and
      a face that jumped from the previous frame's (:func:`_jumped`: a cut), and every
      :data:`IDENTITY_CHECK_EVERY`-th followed one, is compared
      with it by its face descriptor (:mod:`facegeo.landmarks.face_identity`); another person's
      face is not observed (the frame is flagged as showing another person, and the next frame
      searched whole again);
    * frames where no face was found, or another person's, wait (up to :data:`HELD_FRAMES`) for
      the next face found, which is then followed back into them
      (:meth:`_FrameObserver.observe`): a face the detector misses but the face mesh follows, or
      whose descriptor a hand or motion blur moved past the limit, is kept.

    ``rest``: opens the clip's frames that follow ``frames`` (its second part), which a forked
    child (:mod:`facegeo.forked_call`, where :func:`~facegeo.forked_call.can_fork`) observes on
    the other core once the clip's person is found here, from a detection of its own; their
    observations follow these. None: ``frames`` is the whole clip. ``progress`` is called with
    the number of frames this process observed, doubled while the child works.

    Raises :class:`InputError` (naming ``source``) for no frames or frames of different sizes."""
    from facegeo.forked_call import beside_child, can_fork, fork_call

    observer = _FrameObserver(model, detector, source)
    observed = observer.store()
    theirs: ObservedFrames | None = None  # the child's part, filled by the child
    forking = False
    frames = iter(frames)
    for frame in frames:  # until the clip's person is found (the child's part needs it)
        observed.extend(observer.observe(frame))
        if progress is not None:
            progress(len(observed))
        if rest is not None and observer.person is not None and can_fork():
            forking = True
            break

    def start() -> Any:  # the child, forked by beside_child inside the guard that stops it
        nonlocal theirs
        if not forking:
            return None
        theirs = observer.store()
        return fork_call(_observe_rest, observer, rest, theirs)

    def here() -> ObservedFrames:
        for frame in frames:
            observed.extend(observer.observe(frame))
            if progress is not None:
                progress(len(observed) * (2 if forking else 1))
        return observed.extend(observer.flush())

    def instead() -> ObservedFrames:  # the rest here: no face to hand over, the child met another person first, or it was lost
        part = observer.store() if theirs is None else theirs.clear()
        if rest is not None:
            for frame in rest():
                part.extend(observer.observe(frame))
        return part.extend(observer.flush())

    mine, child_part = beside_child(start, here, lambda lost: instead(),
                                    lambda count: None if count is None or theirs is None else theirs.sync())
    observed = mine.extend(child_part)
    if observer.size is None:
        raise InputError(source, "frames", "at least one frame", "none in the range")
    return observed, observer.size


def _observe_rest(observer: _FrameObserver, rest: Callable[[], Iterable[Any]], store: ObservedFrames) -> int | None:
    """A forked child's part of :func:`observe_frames`: the frames ``rest`` opens, observed by a
    copy of ``observer`` that knows the clip's person and frame size but starts with no face,
    appended to ``store`` (made by the caller before the fork; it takes them with
    :meth:`~facegeo.observed_frames.ObservedFrames.sync`); returns their number. None where the
    first face it finds is another person's (a clip with several people: the largest face is not
    always the clip's person, whom the caller then follows into this part)."""
    observer.forget_face()
    observer.held = []  # the other part's frames
    faces = 0
    for frame in rest():
        decided = observer.observe(frame)
        if observer.stranger and not faces:
            return None
        faces += sum(seen.observation is not None for seen in decided)
        store.extend(decided)
    store.extend(observer.flush())
    return len(store)


class _FrameObserver:
    """The state :func:`observe_frames` carries from frame to frame (its docstring): the detector,
    the iris model, the clip's ``person`` descriptor and frame ``size``, and the last face."""

    def __init__(self, model: MorphableModel, detector: str, source: str):
        from facegeo.landmarks.iris import IrisDetector

        self.model, self.source = model, source
        self.det = get_detector(detector)
        self.follow = getattr(self.det, "follow", None)  # a detector that follows a face from frame to frame
        self.iris = IrisDetector() if all(name in model.expression_names for name in eyelids.BLINK_NAMES) else None
        self.size: tuple[int, int] | None = None
        self.person: np.ndarray | None = None  # the clip's person's face descriptor
        self.same_person: list[float] = []  # descriptor distances of the faces accepted as the person
        self.held: list[_HeldFrame] = []  # the latest frames without a face, oldest first, not yet handed out
        self.forget_face()

    def same_person_limit(self) -> float:
        """The largest descriptor distance from the clip's person at which a face is still the
        person: :data:`~facegeo.landmarks.face_identity.SAME_PERSON_DISTANCE` (dlib's, for photos)
        until :data:`SAME_PERSON_CHECKS` faces have been accepted, then what this clip shows of the
        person (the accepted distances' median + 3 robust σ), within [:data:`SAME_PERSON_FLOOR`,
        SAME_PERSON_DISTANCE]: a video's frames are blurred and small, and two people in one
        clip can be nearer than 0.6 to each other while the person stays near 0.35 to herself."""
        from facegeo.landmarks.face_identity import SAME_PERSON_DISTANCE

        if len(self.same_person) < SAME_PERSON_CHECKS:
            return SAME_PERSON_DISTANCE
        seen = np.asarray(self.same_person)
        median = float(np.median(seen))
        spread = 1.4826 * float(np.median(np.abs(seen - median)))
        return float(np.clip(median + 3.0 * spread, SAME_PERSON_FLOOR, SAME_PERSON_DISTANCE))

    def forget_face(self) -> None:
        """Start as after a frame without a face."""
        self.region = None  # (x0, y0, x1, y1) px around the previous frame's face
        self.previous = None  # the previous frame's landmarks
        self.previous_detection = None  # the previous frame's detection, frame pixels
        self.followed = 0  # frames followed since the last identity check
        self.spread_age = SPREAD_EVERY  # frames since the mesh model's spread was found (the frame it was found counts 1)
        self.stranger = False  # whether another person's face was found since

    def observe(self, frame: Any) -> list[ObservedFrame]:
        """One frame (``index``, ``time_s``, ``image`` (H, W, 3) uint8 RGB) observed: the frames
        it decides, in order. A frame without a face (or with a face rejected as another
        person's) is held, its pixels kept, up to :data:`HELD_FRAMES` frames (and
        :data:`HELD_BYTES`); the next face found is followed back into the held frames
        (:meth:`_followed_back`) before they are handed out. :meth:`flush` hands out the rest."""
        held = self._observe(frame)
        if held.seen.observation is not None:
            return self._followed_back(held) + [held.seen]
        self.held.append(held)
        out = []
        while len(self.held) > HELD_FRAMES or sum(h.frame.image.nbytes for h in self.held) > HELD_BYTES:
            out.append(self.held.pop(0).seen)
        return out

    def flush(self) -> list[ObservedFrame]:
        """The held frames (:meth:`observe`), handed out without a face: no face came after them."""
        out = [held.seen for held in self.held]
        self.held = []
        return out

    def _followed_back(self, after: _HeldFrame) -> list[ObservedFrame]:
        """The held frames, in order, the latest first followed back into from ``after`` (the
        frame that follows them, with a face) as a face is followed forward. Where the face is
        lost going back, that frame and those before it stay without a face. A face followed back
        that jumped (:func:`_jumped`) is compared with the clip's person, as forward. In a frame
        whose face was rejected as another person's, the face followed back is the person's
        where it is that face in that place (not :func:`_jumped` from it) and its descriptor is
        within the limit of the next frame's face's: the same person in two frames a moment
        apart, alike in pose, blur and what covers the face (a hand, the motion blur of a fast
        turn), which set the face apart from the clip's person."""
        held, self.held = self.held, []
        back: list[ObservedFrame] = []
        image, face, descriptor = after.frame.image, after.seen.observation, None
        while held and self.follow is not None and face is not None:
            last = held[-1]
            found = self.follow(last.frame.image, face.detection, self.source)
            if found is None:
                break
            observation = _observe_region(last.frame.image, self.model, found)
            if last.rejected is not None:
                if _jumped(last.rejected.landmarks, observation.landmarks):
                    break
                descriptor = _face_descriptor(image, face) if descriptor is None else descriptor
                mine = _face_descriptor(last.frame.image, observation)
                if float(np.linalg.norm(mine - descriptor)) > self.same_person_limit():
                    break
                descriptor = mine
            elif _jumped(face.landmarks, observation.landmarks):
                mine = _face_descriptor(last.frame.image, observation)
                if float(np.linalg.norm(mine - self.person)) > self.same_person_limit():
                    break
                descriptor = mine
            else:
                descriptor = None
            held.pop()
            back.append(ObservedFrame(last.frame.index, last.frame.time_s, observation, None,
                                      self._lid_gaps(last.frame.image, observation), followed_back=True))
            image, face = last.frame.image, observation
        return [h.seen for h in held] + back[::-1]

    def _lid_gaps(self, image: np.ndarray, observation: PhotoObservation | None) -> np.ndarray | None:
        return None if observation is None or self.iris is None else eyelids.lid_gaps(image, observation.landmarks, self.iris)

    def _observe(self, frame: Any) -> _HeldFrame:
        """One frame observed on its own, going forward (:class:`_HeldFrame`)."""
        height, width = frame.image.shape[:2]
        if self.size is None:
            self.size = (width, height)
        elif self.size != (width, height):
            raise InputError(self.source, f"frame {frame.index}: frame size", f"{self.size[0]}x{self.size[1]} px as the first frame",
                             f"{width}x{height} px")
        observation, why, searched_whole, rejected = None, None, False, None
        if self.follow is not None and self.previous_detection is not None:
            keep = self.spread_age < SPREAD_EVERY
            found = self.follow(frame.image, self.previous_detection, self.source, keep_spread=keep)
            if found is not None:
                self.spread_age = self.spread_age + 1 if keep else 1
                observation = _observe_region(frame.image, self.model, found)
        regions = [] if observation is not None else ([self.region] if self.region is not None else []) + [(0, 0, width, height)]
        for x0, y0, x1, y1 in regions:
            try:
                observation = _observe_region(frame.image, self.model, self.det, (x0, y0, x1, y1))
                searched_whole = (x0, y0, x1, y1) == (0, 0, width, height)
                self.spread_age = 1
                break
            except NoFaceError as error:
                why = f"{error.field}: {error.found or error.expected}"
        if observation is not None and (self.person is None or searched_whole or self.followed >= IDENTITY_CHECK_EVERY
                                        or _jumped(self.previous, observation.landmarks)):
            descriptor = _face_descriptor(frame.image, observation)
            self.followed = 0
            if self.person is None:
                self.person = descriptor
            elif (distance := float(np.linalg.norm(descriptor - self.person))) > (limit := self.same_person_limit()):
                self.stranger = True
                rejected = observation
                observation, why = None, (f"another person (face descriptor {distance:.2f} from the clip's person's, more than "
                                          f"{limit:.2f})")
            else:
                self.same_person.append(distance)
        self.followed += 1
        self.previous = None if observation is None else observation.landmarks
        self.previous_detection = None if observation is None else observation.detection
        self.region = None if observation is None else follow_region(observation.landmarks, width, height)
        return _HeldFrame(frame, ObservedFrame(frame.index, frame.time_s, observation, None if observation is not None else why,
                                               self._lid_gaps(frame.image, observation)), rejected)

    def store(self) -> ObservedFrames:
        """An empty :class:`~facegeo.observed_frames.ObservedFrames` for this clip's frames."""
        from facegeo.landmarks.dense import load_dense_correspondence

        correspondence = load_dense_correspondence(self.model)
        return ObservedFrames(self.model, self.source, None if correspondence is None else (correspondence.vertex_ids,
                                                                                           correspondence.barycentric))


@dataclass(frozen=True)
class _HeldFrame:
    """A frame as :meth:`_FrameObserver._observe` observed it: the ``frame`` (its pixels), what
    was observed of it (``seen``) and, where its descriptor was rejected as another person's,
    the face (``rejected``; else None)."""

    frame: Any
    seen: ObservedFrame
    rejected: PhotoObservation | None = None


#: The photos' detector, which observes the keyframes again for the clip's identity: on the scans'
#: head-turn clips it gives 0.729 / 0.944 of the mean shape's error against the ``lids``
#: detector's 0.855 / 0.965 (benchmarks/RESULTS.md, "the keyframes observed again"); the frames
#: are tracked with ``lids`` (its eyes and symmetric points read the lids and the expressions).
IDENTITY_DETECTOR = "hybrid"


def face_region_only(image: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: ``image`` with everything outside the region around the face of
    ``landmarks`` (88, 2) px (:func:`follow_region`) grey, so that a photo's detector finds that
    face, not the largest one in the frame."""
    region = follow_region(landmarks, image.shape[1], image.shape[0])
    if region is None:
        return image
    x0, y0, x1, y1 = region
    out = np.full_like(image, 128)
    out[y0:y1, x0:x1] = image[y0:y1, x0:x1]
    return out


#: Frames without a face held for the next face to be followed back into (a face the detector
#: misses on its own but the face mesh follows, the blurred frame whose descriptor passed the
#: limit), at most this many (0.5 s at 30 frames/s) and this many bytes of pixels: the oldest is
#: handed out without a face beyond either.
HELD_FRAMES = 15
HELD_BYTES = 256 * 2**20
#: A followed face is compared with the clip's person every this many frames (a cut to another
#: person in the same place); a face found by searching the whole frame always is.
IDENTITY_CHECK_EVERY = 15
#: Faces accepted as the clip's person before the clip's own descriptor distances set the limit
#: (:meth:`_FrameObserver.same_person_limit`), and the lowest that limit goes.
SAME_PERSON_CHECKS = 3
SAME_PERSON_FLOOR = 0.45
#: A followed face's dense points keep the spread of the mesh model (its mirror pass,
#: :meth:`~facegeo.landmarks.mediapipe_mesh.MediaPipeFaceMesh.spread`) found this many frames
#: before at most: it follows the head's pose, which moves little in a few frames, and the pass
#: was a sixth of a frame's observation. A symmetric detector (``lids``, the default) makes that
#: pass on every frame anyway and always gives this frame's spread.
SPREAD_EVERY = 5


def _face_descriptor(image: np.ndarray, observation: PhotoObservation) -> np.ndarray:
    """The face descriptor (:func:`facegeo.landmarks.face_identity.face_descriptor`) of the face
    ``observation`` found in ``image`` (H, W, 3) uint8 RGB."""
    from facegeo.landmarks.face_identity import face_descriptor

    return face_descriptor(image, observation.landmarks)


def _jumped(previous: np.ndarray | None, landmarks: np.ndarray) -> bool:
    """Whether the face moved between two frames more than a face moves in 1/30 s: its landmarks'
    centre by over a quarter of the inter-ocular distance, or that distance by over a fifth (a
    cut). False without a previous face."""
    if previous is None:
        return False
    before, now = inter_ocular_distance(previous), inter_ocular_distance(landmarks)
    shift = float(np.linalg.norm(np.nanmean(landmarks, axis=0) - np.nanmean(previous, axis=0)))
    return not (before > 0 and 0.8 < now / before < 1.25 and shift < 0.25 * before)


#: The region a face is looked for in the next frame: the landmarks' bounding box grown by this
#: many times its width and height on each side.
FOLLOW_MARGIN = 1.0


def follow_region(landmarks: np.ndarray, width: int, height: int) -> tuple[int, int, int, int] | None:
    """(x0, y0, x1, y1) px of the region around ``landmarks`` (88, 2) px where the next frame's
    face is looked for, inside the frame; None where it would be the whole frame anyway or too
    small for a photo (:data:`facegeo.photo.MIN_SIDE`)."""
    from facegeo.photo import MIN_SIDE

    points = landmarks[np.isfinite(landmarks).all(axis=1)]
    lo, hi = points.min(axis=0), points.max(axis=0)
    grow = FOLLOW_MARGIN * (hi - lo)
    x0, y0 = (int(max(0.0, np.floor(v))) for v in lo - grow)
    x1, y1 = int(min(width, np.ceil(hi[0] + grow[0]))), int(min(height, np.ceil(hi[1] + grow[1])))
    if min(x1 - x0, y1 - y0) < MIN_SIDE or (x0, y0, x1, y1) == (0, 0, width, height):
        return None
    return x0, y0, x1, y1


def _observe_region(image: np.ndarray, model: MorphableModel, detector: Any,
                    region: tuple[int, int, int, int] | None = None) -> PhotoObservation:
    """:func:`~facegeo.fitting.photo_fit.observe_photo` of a frame ``image`` (H, W, 3) uint8 RGB,
    or of its ``region`` (x0, y0, x1, y1) px, with the dense points, by ``detector`` (a detector,
    or a detection already made: a followed face), in the frame's pixels with its pixels dropped
    (:func:`_shifted`). Raises :class:`NoFaceError` where the detector finds none."""
    x0, y0, x1, y1 = (0, 0, image.shape[1], image.shape[0]) if region is None else region
    return _shifted(observe_photo(np.ascontiguousarray(image[y0:y1, x0:x1]), model, None, detector, None, DEFAULT_DENSE), x0, y0)


def _shifted(observation: PhotoObservation, x0: int, y0: int) -> PhotoObservation:
    """An observation made in a region whose top-left corner is (x0, y0) px of the frame, in the
    frame's pixels (its landmarks, surface points and detection), its pixels dropped (a clip's
    frames are not kept in memory)."""
    offset = np.array([x0, y0], dtype=np.float64)
    surface = observation.surface_points
    if surface is not None:
        surface = SurfacePoints(surface.targets + offset, surface.vertex_ids, surface.barycentric, surface.weights,
                                surface.contour, surface.expressive)
    detection = observation.detection
    if detection is not None:
        shift = offset.astype(np.float32)
        detection = dataclasses.replace(detection, points=detection.points + shift, box=detection.box + np.tile(shift, 2),
                                        dense=None if detection.dense is None else detection.dense + shift)
    empty = np.zeros((0, 0, 3), np.uint8)
    return dataclasses.replace(observation, image=empty, pixels=empty, landmarks=observation.landmarks + offset,
                               surface_points=surface, detection=detection)


def clip_identity(model: MorphableModel, observed: Sequence[ObservedFrame], size: tuple[int, int], focal: float | None = None,
                  keyframes: int = KEYFRAMES, source: str = "<video>",
                  frame_image: Callable[[ObservedFrame], np.ndarray | None] | None = None) -> ClipIdentity:
    """The clip's camera and identity (module docstring, steps 2 and 3). ``size``: (width,
    height) px of the frames. The keyframes are chosen among the frames whose face was not
    followed back into them (:attr:`ObservedFrame.followed_back`), where there are any.
    ``frame_image``: a keyframe's pixels (H, W, 3) uint8 RGB, decoded again (None where they are
    not at hand); each keyframe is then observed again by the photos' detector
    (:data:`IDENTITY_DETECTOR`) on its face's region (:func:`face_region_only`) for the identity,
    its tracked observation where that finds no face, and the keyframes' colours refine the
    identity (:mod:`facegeo.fitting.view_consistency`). Raises :class:`NoFaceError` when no frame
    has a face."""
    found, focals, back = [], [], []  # one pass over the frames, none of them kept (a long clip's are on disk)
    for k, frame in enumerate(observed):
        if frame.observation is not None:
            found.append(k)
            focals.append(frame.observation.camera.focal)
            back.append(frame.followed_back)
    if not found:
        raise NoFaceError(source, "face", "a face in at least one frame", f"none in {len(observed)} frames")
    # a face followed back into a frame was lost there going forward (a hand, motion blur): not a keyframe
    candidates = [k for k, followed_back in zip(found, back) if not followed_back] or found
    width, height = size
    notes = []
    if focal is None:
        camera = Camera(float(np.median(focals)), width / 2.0, height / 2.0, width, height)
        notes.append(f"focal length unknown: set to {camera.focal:.0f} px, the median over the frames of the focal that puts "
                     "the face 1.0 m from the camera (give --focal for a known lens)")
    else:
        camera = Camera(float(focal), width / 2.0, height / 2.0, width, height)
    chosen = [candidates[j] for j in _keyframes(model, (observed[k].observation for k in candidates), len(candidates), camera, keyframes)]

    def view(k: int) -> LandmarkView:
        seen, name = observed[k].observation, f"{source}, frame {observed[k].index}"
        image = None if frame_image is None else frame_image(observed[k])
        if image is not None:
            try:
                seen = observe_photo(face_region_only(image, seen.landmarks), model, None, IDENTITY_DETECTOR, camera, DEFAULT_DENSE)
            except NoFaceError:
                pass
        # the decoded frame for the views' colours (view_consistency), whichever detector observed it
        return dataclasses.replace(LandmarkView.of(seen, name), camera=camera, pixels=image)

    views = [view(k) for k in chosen]
    solutions = solve_shared_identity(model, views)
    alpha = solutions[0].fit.alpha.astype(np.float64)
    open_lids = None
    if all(observed[k].lid_gaps is not None for k in chosen):
        model_gaps = [eyelids.model_lid_gaps(model, alpha, _without_lids(model, s.fit.delta), s.fit.rotation, s.fit.translation, camera)
                      for s in solutions]
        ratio = eyelids.open_ratio(np.stack([observed[k].lid_gaps for k in chosen]), np.stack(model_gaps))
        open_lids = ratio if np.isfinite(ratio).any() else None
    return ClipIdentity(camera, alpha, float(np.median([s.noise for s in solutions])), chosen, notes, open_lids)


def _without_lids(model: MorphableModel, delta: np.ndarray) -> np.ndarray:
    """``delta`` (n_exp,) with the expressions that move the lids themselves (ICT-FaceKit's
    ``eye*``: blink, squint, wide, gaze) at 0: the expression a lid's open gap is measured in (a
    smile's raised cheeks and a lowered brow narrow the eye; they stay)."""
    return np.where(lid_weights(model.expression_names), 0.0, np.asarray(delta, np.float64))


def track_observed(model: MorphableModel, observed: Sequence[ObservedFrame], shared: ClipIdentity,
                   stage: LandmarkStage = TRACK_STAGE, parts: int = 2, offsets: NeutralOffsets | None = None,
                   flow: BrowFlow | None = None, shading: CheekShading | None = None) -> list[TrackedFrame]:
    """Every observed frame's pose and expression with the clip's identity fixed (module
    docstring, step 4), ``stage`` the per-frame solve (its ``n_id`` must be 0: the identity stays),
    the points measured from the person's at rest where ``offsets`` are given (:func:`solve_frame`),
    and with ``flow`` (which needs them) the brows' region of the face at rest carried into each
    frame the offsets reach (:meth:`BrowFlow.carried`), and with ``shading`` too (which needs the
    flow's frames) the puff read from the cheeks' shading in every frame at its solved pose
    (:meth:`~facegeo.cheek_shading.CheekShading.puff_reading`), in place of the solve's own (the
    next frame's solve starts from the solve's own).

    ``parts`` 2: a clip of at least 2 × :data:`MIN_PART_FRAMES` frames is solved in two halves at
    once, the second by a forked child (:mod:`facegeo.forked_call`, where it
    :func:`~facegeo.forked_call.can_fork`), which starts its first frame from solvePnP as after a
    frame without a face (the halves' solves are otherwise the same); 1: in this process alone."""
    from facegeo.forked_call import beside_child, can_fork, fork_call

    if stage.n_id != 0:
        raise InputError("<argument>", "stage", "a stage that leaves the identity out (n_id 0)", repr(stage.n_id))
    split = len(observed) // 2 if parts >= 2 and len(observed) >= 2 * MIN_PART_FRAMES and can_fork() else len(observed)
    first, second = beside_child(
        lambda: fork_call(_track_part, model, observed, shared, stage, split, len(observed), offsets, flow, shading)
        if split < len(observed) else None,
        lambda: _track_part(model, observed, shared, stage, 0, split, offsets, flow, shading),
        lambda lost: _track_part(model, observed, shared, stage, split, len(observed), offsets, flow, shading))
    return first + second


#: A clip is tracked in two parts at once (:func:`observe_frames`' ``rest``, :func:`track_observed`)
#: when each has at least this many frames: below, a forked process's start (about 0.1 s) and its
#: first frame's detection weigh more than they save.
MIN_PART_FRAMES = 30


def _track_part(model: MorphableModel, observed: Sequence[ObservedFrame], shared: ClipIdentity, stage: LandmarkStage, first: int,
                end: int, offsets: NeutralOffsets | None = None, flow: BrowFlow | None = None,
                shading: CheekShading | None = None) -> list[TrackedFrame]:
    """:func:`track_observed` on ``observed[first:end]``, the first from solvePnP."""
    out: list[TrackedFrame] = []
    previous = None
    images = None if flow is None or offsets is None or first >= end else _FramesInOrder(lambda: flow.frames_again(observed[first].time_s))
    for k in range(first, end):
        frame = observed[k]
        obs = frame.observation
        if obs is None:
            out.append(TrackedFrame(frame.index, frame.time_s, False, note=frame.note))
            previous = None
            continue
        # where the solve starts: the previous frame's fit (1/30 s ago), or solvePnP's pose with no expression
        if previous is None:
            rotation, translation = initial_pose(model, obs.landmarks, shared.camera)
            start = SolveStart(rotation, translation, np.asarray(shared.alpha, np.float64), np.zeros(model.n_exp))
        else:
            start = previous
        measured, carried = None, None
        if shared.open_lids is not None and frame.lid_gaps is not None:  # the eye's open gap in that pose
            open_gaps = shared.open_lids * eyelids.model_lid_gaps(model, shared.alpha, _without_lids(model, start.delta), start.rotation,
                                                          start.translation, shared.camera)
            measured = eyelids.blinks(frame.lid_gaps, open_gaps, start.rotation)
        near_rest = images is not None and offsets.share(start.rotation) > 0.0  # where the brows' flow is tried
        image = images.at(frame.index) if images is not None and (shading is not None or near_rest) else None
        if image is not None and near_rest and obs.surface_points is not None:
            obs, carried = flow.carried(obs, image)
        fit = solve_frame(model, obs, shared.camera, shared.alpha, shared.noise, start, stage, measured, offsets).fit
        previous = SolveStart(fit.rotation, fit.translation, shared.alpha, fit.delta)
        delta, gain = fit.delta, None
        reading = None if shading is None or image is None else shading.puff_reading(image, fit.rotation, fit.translation, fit.delta)
        if reading is not None:  # the puff in this frame's cheeks, in place of the points' own
            delta, gain = shading.with_puff(fit.delta, reading[0]).astype(fit.delta.dtype), reading[1]
        out.append(TrackedFrame(frame.index, frame.time_s, True, fit.rotation, fit.translation, delta,
                                float(fit.landmark_rms_px), float(fit.landmark_rms_percent_iod), k in shared.keyframes,
                                followed_back=frame.followed_back, brow_flow=carried, puff_gain=gain))
    return out


def solve_frame(model: MorphableModel, seen: PhotoObservation, camera: Camera, alpha: np.ndarray, noise: float,
                start: SolveStart | None = None, stage: LandmarkStage = TRACK_STAGE,
                blinks: np.ndarray | None = None, offsets: NeutralOffsets | None = None) -> LandmarkSolution:
    """One frame's pose and expression with the clip's identity ``alpha`` (n_id,) fixed, in the
    clip's ``camera``, at its landmark ``noise`` (inter-ocular units, no re-estimation), from
    ``start`` (None: solvePnP on the mean shape, δ = 0): the per-frame solve of
    :func:`track_observed`, and of a keyframe fitted again for the clip's asset.

    ``blinks`` (2,): the right and left eye's blink read from the lids
    (:func:`facegeo.landmarks.eyelids.blinks`), held in the solve; the lid points
    (:data:`~facegeo.landmarks.eyelids.LID_POINTS`) then weigh nothing (they would pull the eyes
    open or shut again through the other lid shapes) and the eye corners their single-photo
    weight. None (or NaN): the lids are fitted, the eyes' 12 points weighed ×:data:`EYE_WEIGHT`.
    The brows weigh less as the head turns them away (:func:`turned_brow_weights`), and so do
    the dense points of the brows' region (:data:`BROW_REGION_MM`), by the brows' mean factor: the
    Face Landmarker also puts a brow that turns away on the outline (the ground-truth take's PNG
    frames with ``--neutral``: browDown's r 0.41 / 0.48 → 0.85 / 0.82, benchmarks/RESULTS.md). ``offsets``:
    the person's points at rest (:func:`neutral_offsets`), taken off the observed points in the
    start's pose; None: the points as observed."""
    if start is None:
        rotation, translation = initial_pose(model, seen.landmarks, camera)
        start = SolveStart(rotation, translation, np.asarray(alpha, np.float64), np.zeros(model.n_exp))
    if offsets is not None:
        seen = offsets.taken_off(seen, start.rotation, start.translation, camera)
    # the gaze blendshapes move the lids: without the irises they only mimic a blink's opposite
    gaze = tuple(n for n in model.expression_names if n.startswith("eyeLook"))
    weights = np.array(LANDMARK_WEIGHTS if seen.weights is None else seen.weights, np.float64)
    measured: tuple[tuple[str, float], ...] = ()
    if blinks is not None and np.isfinite(blinks).all():
        measured = tuple(zip(eyelids.BLINK_NAMES, (float(b) for b in blinks)))
        weights[np.ravel(eyelids.LID_POINTS)] = 0.0
    else:
        weights[EYES] *= EYE_WEIGHT
    brows = turned_brow_weights(model, start)
    weights[BROWS] *= brows
    surface = seen.surface_points
    if surface is not None:  # the dense points of the brows' region weigh as dlib's brows do, on average
        region = _brow_ring(model).in_region(surface)
        surface = SurfacePoints(surface.targets, surface.vertex_ids, surface.barycentric,
                                np.where(region, surface.weights * float(brows.mean()), surface.weights),
                                surface.contour, surface.expressive)
    priors = dataclasses.replace(DEFAULT_PRIORS, noise=noise, noise_rounds=0, held_expressions=gaze, measured_expressions=measured,
                                 brow_along_noise=BROW_ALONG_NOISE)
    return solve_landmarks(model, seen.landmarks, camera, weights, (stage,), priors, start, surface)


#: A brow point's noise along its brow over its noise across it in the per-frame solve
#: (:attr:`~facegeo.fitting.priors.FitPriors.brow_along_noise`). On the ground-truth take
#: (benchmarks/RESULTS.md, "the brows' points along the brow"), 1, 2, 3 and 5 pass 6, 8, 9 and 9
#: of 14 curves on the mp4 frames (8, 9, 9, 9 on the PNG frames): the compressed frames' brow
#: points slide along the brow and read as brows raised less than they are; the head's median
#: error grows 0.85, 0.97, 1.00, 1.03° (a constant pitch offset, 0.26 → 0.45°).
BROW_ALONG_NOISE = 3.0
#: The brows' weights in the per-frame solve fall from 1 to 0 as a brow point's facing ratio
#: (:func:`turned_brow_weights`) goes from the second to the first of these, squared.
TURNED_BROW_RAMP = (0.4, 0.9)
#: A model vertex is in the brows' region where one of the model's brow blendshapes (those whose
#: ARKit name starts with ``brow``) moves it by more than this many mm at weight 1 (ICT-FaceKit:
#: the brows, the forehead above them and the upper lids' skin; 130 of the 468 dense points).
BROW_REGION_MM = 1.0


def turned_brow_weights(model: MorphableModel, start: SolveStart) -> np.ndarray:
    """(10,) factors for the 88 points' brows (:data:`~facegeo.landmarks.scheme.BROWS`, dlib's)
    in a frame whose head is posed as ``start``: a 2-D detector puts a brow that turns away from
    the camera on the head's outline, not on the brow (on the ground-truth take, dlib's far brow
    read as browDown 0.75 while the head held 36° of yaw, the truth 0). A point's facing ratio
    is the cosine between its surface normal and the ray from the camera in that pose over the
    normal's cosine to a frontal camera's axis; its factor ((ratio − 0.4) / 0.5, clipped to
    [0, 1])² (:data:`TURNED_BROW_RAMP`), and a point and its mirror partner take the smaller of
    theirs, so that a clip and its mirror image weigh their brows alike (the far brow's alone:
    the head's yaw then agreed less with the mirrored clip's). Measured in
    benchmarks/RESULTS.md ("the brows that drop when the head turns")."""
    ring = _brow_ring(model)
    bases = subset_bases(model, ring.vertices, {"ring": np.arange(len(ring.vertices))})  # gathered once a process
    vertices = bases.shape_at("ring", np.asarray(start.alpha, np.float64), np.asarray(start.delta, np.float64))
    normals = vertex_normals(vertices, ring.triangles)[ring.rows]
    rotation = np.asarray(start.rotation, np.float64)
    points = vertices[ring.rows] @ rotation.T + np.asarray(start.translation, np.float64)
    facing = -np.einsum("kc,kc->k", normals @ rotation.T, points / np.linalg.norm(points, axis=1, keepdims=True))
    ratio = facing / np.maximum(normals[:, 2], 0.1)
    low, high = TURNED_BROW_RAMP
    factor = np.clip((ratio - low) / (high - low), 0.0, 1.0) ** 2
    return np.minimum(factor, factor[::-1])  # BROWS runs from one brow's outer end to the other's


@dataclass(frozen=True)
class _BrowRing:
    """The model's triangles around the brows' landmark vertices: the U ``vertices`` (U,) they
    use, the ``triangles`` (T, 3) indexing into them and the brow vertices' ``rows`` (10,) among
    them (each brow vertex's normal over its whole ring is its normal on the whole mesh); and
    the brows' ``region`` (V,) bool over all the model's vertices (:data:`BROW_REGION_MM`; none
    for a model without brow blendshapes)."""

    vertices: np.ndarray
    triangles: np.ndarray
    rows: np.ndarray
    region: np.ndarray

    def in_region(self, points: SurfacePoints) -> np.ndarray:
        """(K,) bool: the dense ``points`` on a triangle with a vertex in the brows' :attr:`region`."""
        return self.region[points.vertex_ids].any(axis=1)


_BROW_RINGS: dict[int, tuple[MorphableModel, _BrowRing]] = {}


def _brow_ring(model: MorphableModel) -> _BrowRing:
    """The :class:`_BrowRing` of ``model``, made once per model object in a process."""
    kept = _BROW_RINGS.get(id(model))
    if kept is None or kept[0] is not model:
        brows = np.asarray(model.landmark_indices)[BROWS]
        triangles = np.asarray(model.triangles, np.int64)
        around = triangles[np.isin(triangles, brows).any(axis=1)]
        vertices, local = np.unique(around, return_inverse=True)
        shapes = [k for k, name in enumerate(model.expression_names) if (arkit_name(name) or "").startswith("brow")]
        region = np.zeros(model.n_vertices, bool)
        if shapes and model.expression_kind == "blendshape":
            region = (np.linalg.norm(model.exp_basis[shapes], axis=2) > BROW_REGION_MM).any(axis=0)
        kept = (model, _BrowRing(vertices, local.reshape(-1, 3), np.searchsorted(vertices, brows), region))
        _BROW_RINGS[id(model)] = kept
    return kept[1]


@dataclass(frozen=True)
class SolveStart:
    """Where a frame's solve starts (what :func:`solve_landmarks` reads of its ``init``):
    rotation (3, 3), translation (3,) mm, alpha (n_id,) and delta (n_exp,)."""

    rotation: np.ndarray
    translation: np.ndarray
    alpha: np.ndarray
    delta: np.ndarray


def _keyframes(model: MorphableModel, observations: Iterable[PhotoObservation], n: int, camera: Camera, count: int) -> list[int]:
    """Indices into the ``n`` ``observations`` (read once, in order) of up to ``count`` keyframes
    spanning the head's yaw (the frames' solvePnP yaws on the mean shape, :func:`spanning_frames`)."""
    if n <= count:
        return list(range(n))
    yaws, points = np.empty(n), np.empty(n, np.int64)
    for k, o in enumerate(observations):
        yaws[k] = euler_from_rotation(initial_pose(model, o.landmarks, camera)[0])[0]
        points[k] = int(np.isfinite(o.landmarks).all(axis=1).sum())
    return spanning_frames(yaws, points, count)


def spanning_frames(yaws: np.ndarray, points: np.ndarray, count: int) -> list[int]:
    """Sorted indices of ``count`` frames (fewer if there are fewer) spanning the range of the
    frames' ``yaws`` (N,) (its 2nd to 98th percentile: a stray frame's yaw does not set it): for
    each of ``count`` yaws evenly spaced over the range, ends included, the frame within half a
    spacing of it with the most ``points`` (N,) (then the nearest, then the earliest) that is not
    yet chosen, else the nearest frame not yet chosen. (Equal shares of the frames sorted by yaw
    chose five frontal frames of a clip that turns to ±35° but is frontal most of the time:
    benchmarks/bench_track_truth.py.)"""
    n = len(yaws)
    if n <= count:
        return list(range(n))
    lo, hi = np.percentile(yaws, [2, 98])
    targets = np.linspace(lo, hi, count)
    half = 0.5 * (hi - lo) / max(count - 1, 1)
    chosen: list[int] = []
    for target in targets:
        distance = np.abs(yaws - target)
        free = np.ones(n, bool)
        free[chosen] = False
        near = np.flatnonzero(free & (distance <= half))
        if len(near):
            chosen.append(int(min(near, key=lambda j: (-points[j], distance[j], j))))
        else:
            chosen.append(int(np.flatnonzero(free)[np.argmin(distance[free])]))
    return sorted(chosen)


#: The frames with a face within this many seconds of the neutral time show the person at rest
#: (:func:`neutral_offsets`).
NEUTRAL_WINDOW_S = 0.25


#: The person's points at rest (:class:`NeutralOffsets`) hold in full within the first of these
#: angles (degrees) of the head's rotation at rest, not at all beyond the second, linearly between:
#: measured on the ground-truth take with ``--neutral 0.5`` (benchmarks/RESULTS.md, "the person's
#: points at rest"), curves passing of 14: no fade 6, (2, 8) 10, (3, 12) 11, (5, 15) 10,
#: (5, 20) 10, (10, 30) 8; the weights' calibration it replaced 8. Beyond, the take's turned head
#: read false frowns from the frontal offsets.
NEUTRAL_FADE_DEG = (3.0, 12.0)
#: The solve of a neutral frame (:func:`neutral_offsets`): the pose alone, from solvePnP, the jaw
#: and the outline slid before every iteration.
NEUTRAL_POSE_STAGE = LandmarkStage("neutral pose", 12, 0, False)


@dataclass(frozen=True)
class NeutralOffsets:
    """Where a clip's detector puts the person's points at rest, against where the clip's
    identity with no expression puts them (:func:`neutral_offsets`): ``points`` (88 + K, 3) mm,
    the 88 landmarks' and the K dense points' places on that neutral face in model space;
    ``offsets`` (88 + K, 3) mm, model space, what the detector adds to them; ``frames``, the
    source indices of the neutral frames they were measured on; ``rest_rotation`` (3, 3), the
    head's rotation there (their mean); ``time_s``, the time they were measured at. A detector's
    bias depends on the view: measured in one, the offsets hold near it and fade as the head turns
    away from it (:meth:`share`)."""

    points: np.ndarray
    offsets: np.ndarray
    frames: list[int]
    rest_rotation: np.ndarray
    time_s: float

    def shift(self, rotation: np.ndarray, translation: np.ndarray, camera: Camera) -> np.ndarray:
        """(88 + K, 2) px: how far the offsets move the points' images with the head posed by
        ``rotation`` (3, 3) and ``translation`` (3,) mm (the offsets turn with the head)."""
        rotation = np.asarray(rotation, np.float64)
        at = self.points @ rotation.T + np.asarray(translation, np.float64)
        return self.share(rotation) * (to_pixels(at + self.offsets @ rotation.T, camera) - to_pixels(at, camera))

    def share(self, rotation: np.ndarray) -> float:
        """The share of the offsets that holds with the head turned by ``rotation`` (3, 3): 1
        within the first of :data:`NEUTRAL_FADE_DEG` of :attr:`rest_rotation`, 0 beyond the
        second, linear between."""
        angle = float(_angles_deg(np.asarray(rotation, np.float64)[None], self.rest_rotation)[0])
        full, none = NEUTRAL_FADE_DEG
        return float(np.clip((none - angle) / (none - full), 0.0, 1.0))

    def taken_off(self, seen: PhotoObservation, rotation: np.ndarray, translation: np.ndarray, camera: Camera) -> PhotoObservation:
        """``seen`` with :meth:`shift` in that pose taken off its 88 landmarks and, where it has
        the K dense points measured, off those."""
        shift = self.shift(rotation, translation, camera)
        surface = seen.surface_points
        if surface is not None and len(surface) == len(shift) - N_LANDMARKS:
            surface = SurfacePoints(surface.targets - shift[N_LANDMARKS:], surface.vertex_ids, surface.barycentric, surface.weights,
                                    surface.contour, surface.expressive)
        return dataclasses.replace(seen, landmarks=seen.landmarks - shift[:N_LANDMARKS], surface_points=surface)


def neutral_offsets(model: MorphableModel, observed: Sequence[ObservedFrame], shared: ClipIdentity, time_s: float,
                    source: str = "<video>") -> NeutralOffsets:
    """The person's points at rest (:class:`NeutralOffsets`), measured on the frames with a face
    within :data:`NEUTRAL_WINDOW_S` of ``time_s`` (seconds, the frames' own clock): each posed
    alone (:data:`NEUTRAL_POSE_STAGE`, no expression: the face is at rest there), each point's
    residual (observed − model, px) lifted to the point's depth parallel to the image plane and
    turned into model space, the median over those frames. Points that slide along the outline
    (the 88's jaw, the dense contour) keep their place and get no offset, nor do dense points not
    seen there.

    This is Live Link Face's neutral calibration done where the bias is, in the landmarks: a 2-D
    detector puts a real face's brows, lip corners and cheeks a few pixels off the model's
    (dlib's brows 3-9 px below the take's at rest), and a bounded weight cannot show a bias
    below its rest (a brow raised first fills that gap: the take's browInnerUp peaked at 0.09
    for 0.85). The idea of per-point displacements beside a blendshape model is Cao et al.'s
    displaced dynamic expression regression (SIGGRAPH 2014). Raises :class:`InputError` naming
    ``--neutral`` where no frame near ``time_s`` has a face."""
    camera, alpha = shared.camera, np.asarray(shared.alpha, np.float64)
    near = [frame for frame in observed if frame.observation is not None and abs(frame.time_s - time_s) <= NEUTRAL_WINDOW_S]
    if not near:
        raise InputError(source, "--neutral", f"a time at which the face is found (within {NEUTRAL_WINDOW_S:g} s)",
                         f"{time_s:g} s: no tracked face there")
    dense = near[0].observation.surface_points
    landmark_ids = np.asarray(model.landmark_indices, np.int64)
    dense_ids = np.zeros((0, 3), np.int64) if dense is None else dense.vertex_ids
    ids, inverse = np.unique(np.concatenate([landmark_ids, dense_ids.ravel()]), return_inverse=True)
    bases = subset_bases(model, ids, {"all": np.arange(len(ids))})
    at_rest = bases.shape_at("all", alpha, np.zeros(model.n_exp))
    points = at_rest[inverse[:N_LANDMARKS]]
    if dense is not None:
        points = np.concatenate([points, np.einsum("kj,kjc->kc", dense.barycentric, at_rest[inverse[N_LANDMARKS:]].reshape(-1, 3, 3))])
    sliding = np.zeros(len(points), bool)
    sliding[JAW] = True
    if dense is not None:
        sliding[N_LANDMARKS:] = dense.contour
    priors = dataclasses.replace(DEFAULT_PRIORS, noise=shared.noise, noise_rounds=0)
    lifted, rotations = [], []
    for frame in near:
        seen = frame.observation
        rotation, translation = initial_pose(model, seen.landmarks, camera)
        start = SolveStart(rotation, translation, alpha, np.zeros(model.n_exp))
        fit = solve_landmarks(model, seen.landmarks, camera, None, (NEUTRAL_POSE_STAGE,), priors, start, seen.surface_points).fit
        if dense is None:
            observed_px = seen.landmarks
        else:  # a frame without the dense points measures none of them
            targets = seen.surface_points.targets if seen.surface_points is not None else np.full((len(dense), 2), np.nan)
            observed_px = np.concatenate([seen.landmarks, targets])
        posed = points @ fit.rotation.T + fit.translation
        residual = observed_px - to_pixels(posed, camera)
        depth = -posed[:, 2:3] / camera.focal  # mm per px at each point
        moved = np.concatenate([residual[:, :1] * depth, -residual[:, 1:] * depth, np.zeros_like(depth)], axis=1)
        lifted.append(moved @ fit.rotation)  # camera space -> model space: R^T
        rotations.append(fit.rotation)
    with warnings.catch_warnings():  # a point unseen in every neutral frame: all-NaN, no offset
        warnings.simplefilter("ignore", RuntimeWarning)
        offsets = np.nanmedian(np.stack(lifted), axis=0)
    offsets[sliding | ~np.isfinite(offsets).all(axis=1)] = 0.0
    u, _, vt = np.linalg.svd(np.sum(rotations, axis=0))  # the rotations' chordal mean
    mean = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    return NeutralOffsets(points, offsets, [frame.index for frame in near], mean, float(time_s))


#: A stretch of the clip is the face at rest (:func:`rest_stretch`, :func:`track_frames`) when
#: its mean distance from the clip's median expression is at most this (the L1 distance of the
#: ICT weights other than the eyes'). Measured (benchmarks/RESULTS.md, "the face at rest found in
#: the clip"): the ground-truth take, at rest half of its 23.7 s, 0.17; three real clips of people
#: talking and smiling throughout 0.61, 0.89 and 0.93 (no rest found, the points as observed).
REST_DISTANCE = 0.3
#: ... and when none of its mean weights (the same weights) is above this: the clip's most typical
#: face is the face at rest only where the person does not hold an expression throughout (a clip
#: of a held smile would be measured from the smile, which then reads 0). The ground-truth take
#: at rest, as observed: at most 0.29 (mouthStretch_R, the detector's bias); its held smile of 0.9
#: tracked as a clip of its own: 0.52-0.54 (mouthSmile_L/R) (benchmarks/RESULTS.md, "a held
#: expression is not the face at rest"). A lighter expression held throughout is still taken.
REST_STRONGEST = 0.45
#: :func:`rest_stretch` looks for the face at rest within this many degrees of the clip's typical
#: head rotation (the points at rest hold in full only near the view they were measured in,
#: :data:`NEUTRAL_FADE_DEG`).
REST_TURN_DEG = 10.0


@dataclass(frozen=True)
class RestStretch:
    """The clip's most typical still stretch (:func:`rest_stretch`): ``time_s``, its middle
    (seconds, the frames' clock); ``distance``, its frames' mean L1 distance from the clip's
    median expression (the ICT weights other than the eyes'); ``strongest``, the largest of its
    frames' mean weights (the same weights) and the model's name for it."""

    time_s: float
    distance: float
    strongest: tuple[str, float]

    @property
    def strongest_name(self) -> str:
        """The strongest weight's ARKit name (the model's own where ARKit has none), as notes and
        ``track.json`` give it."""
        return arkit_name(self.strongest[0]) or self.strongest[0]

    @property
    def at_rest(self) -> bool:
        """Whether the stretch is taken as the face at rest: near the clip's median expression
        (:data:`REST_DISTANCE`) and holding no expression (:data:`REST_STRONGEST`)."""
        return self.distance <= REST_DISTANCE and self.strongest[1] <= REST_STRONGEST


#: A brow point carried by the optical flow from the face at rest (:class:`BrowFlow`) weighs this
#: many times the dense point it replaces. On the ground-truth take (benchmarks/RESULTS.md, "the
#: brows carried from the face at rest"), curves passing of 14, mp4 / PNG: 3: 12 / 13, 5: 13 / 13,
#: 8: 13 / 13, 16: 13 / 13; the head's median error 1.24, 1.32, 1.41, 1.55°.
BROW_FLOW_WEIGHT = 5.0
#: A carried point is kept where the flow back from the frame lands within this many pixels of
#: where it started (the forward-backward check: an occluded or changed patch does not return).
BROW_FLOW_RETURN_PX = 0.3
#: Pyramidal Lucas–Kanade's window (px, square) and pyramid levels for the brows' flow.
BROW_FLOW_WINDOW = 21
BROW_FLOW_LEVELS = 3


@dataclass(frozen=True)
class BrowFlow:
    """The brows' region of the face at rest, carried into other frames by optical flow
    (:meth:`carried`): a 2-D detector spaces its brow points along the brow by its own shape
    prior and misses the brow's motion along itself (the model's browDown moves the brow 2-5 mm
    inwards and 1-4 mm down), where the skin's and the hairs' pixels show it.

    ``image`` (H, W) uint8, the frame at rest in grey; ``points``, its observed dense points;
    ``rows`` (K,) int, the brows' region's among them (:data:`BROW_REGION_MM`; measured there, not
    on the outline); ``frames_again`` opens the clip's frames again from a time (s). The carried
    points keep the detector's place at rest, which the person's offsets at rest
    (:class:`NeutralOffsets`, measured on the same frames) take off. (By hand over OpenCV's
    pyramidal Lucas–Kanade: no library tracks a face mesh's points from a reference frame.)"""

    image: np.ndarray
    points: SurfacePoints
    rows: np.ndarray
    frames_again: Callable[[float], Iterable[Any]]

    def carried(self, seen: PhotoObservation, image: np.ndarray) -> tuple[PhotoObservation, int]:
        """``seen`` with its dense points of :attr:`rows` moved to where the flow from the face at
        rest puts them in ``image`` (H, W, 3) uint8 RGB, the frame's own (its detected places the
        flow's first guess), weighted ×:data:`BROW_FLOW_WEIGHT`; a point whose flow does not
        return (:data:`BROW_FLOW_RETURN_PX`) keeps its detected place and weight. Also how many
        were carried. ``seen`` unchanged (0 carried) where its dense points are not the face at
        rest's (another count) or the image is another size."""
        surface = seen.surface_points
        if surface is None or len(surface) != len(self.points) or not len(self.rows):
            return seen, 0
        grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
        if grey.shape != self.image.shape:
            return seen, 0
        start = self.points.targets[self.rows].astype(np.float32).reshape(-1, 1, 2)
        detected = surface.targets[self.rows].astype(np.float32).reshape(-1, 1, 2)
        guess = np.where(np.isfinite(detected), detected, start)
        lk = {"winSize": (BROW_FLOW_WINDOW, BROW_FLOW_WINDOW), "maxLevel": BROW_FLOW_LEVELS, "flags": cv2.OPTFLOW_USE_INITIAL_FLOW}
        moved, found, _ = cv2.calcOpticalFlowPyrLK(self.image, grey, start, guess.copy(), **lk)
        back, returned, _ = cv2.calcOpticalFlowPyrLK(grey, self.image, moved, start.copy(), **lk)
        good = (found[:, 0] == 1) & (returned[:, 0] == 1) & (np.linalg.norm((back - start).reshape(-1, 2), axis=1) < BROW_FLOW_RETURN_PX)
        rows = self.rows[good]
        targets, weights = surface.targets.copy(), surface.weights.copy()
        targets[rows] = moved.reshape(-1, 2)[good]
        weights[rows] *= BROW_FLOW_WEIGHT
        return dataclasses.replace(seen, surface_points=SurfacePoints(targets, surface.vertex_ids, surface.barycentric, weights,
                                                                      surface.contour, surface.expressive)), int(good.sum())


def face_at_rest(model: MorphableModel, observed: Sequence[ObservedFrame], shared: ClipIdentity, offsets: NeutralOffsets,
                 frames_again: Callable[[float], Iterable[Any]]) -> tuple[BrowFlow | None, CheekShading | None]:
    """What every frame reads against the face at rest, the middle one of the frames ``offsets``
    were measured on, decoded again by ``frames_again``: the :class:`BrowFlow` (None where that
    frame has no dense points or is not found again) and, with it, the cheeks' shading
    (:func:`facegeo.cheek_shading.cheek_shading` at the frame's own solve; None where it cannot
    be read)."""
    at_rest = {frame.index: frame for frame in observed if frame.observation is not None}
    frame = at_rest.get(offsets.frames[len(offsets.frames) // 2])
    if frame is None or frame.observation.surface_points is None:
        return None, None
    image = _FramesInOrder(lambda: frames_again(frame.time_s)).at(frame.index)
    if image is None:
        return None, None
    points = frame.observation.surface_points
    region = _brow_ring(model).in_region(points) & ~points.contour & np.isfinite(points.targets).all(axis=1)
    flow = BrowFlow(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), points, np.flatnonzero(region), frames_again)
    fit = solve_frame(model, frame.observation, shared.camera, shared.alpha, shared.noise, offsets=offsets).fit
    return flow, cheek_shading(model, shared.alpha, shared.camera, image, fit.rotation, fit.translation, fit.delta)


class _FramesInOrder:
    """The images of frames (``index``, ``image``) read in order from what ``opened`` opens, asked
    for by increasing index (:meth:`at`). A video that cannot be opened or read again here (it was
    read once) gives no more images, not an error: the brows' flow is a refinement."""

    def __init__(self, opened: Callable[[], Iterable[Any]]):
        try:
            self._frames: Iterator[Any] = iter(opened())
        except InputError:
            self._frames = iter(())
        self._next: Any = None

    def at(self, index: int) -> np.ndarray | None:
        """The image (H, W, 3) uint8 RGB of the frame numbered ``index``; None where the frames
        pass it (or end, or fail) without it."""
        while True:
            if self._next is None:
                try:
                    self._next = next(self._frames, None)
                except InputError:
                    self._next, self._frames = None, iter(())
                if self._next is None:
                    return None
            if self._next.index == index:
                return self._next.image
            if self._next.index > index:
                return None
            self._next = None


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angles (degrees) between rotations ``a`` (N, 3, 3) and ``b`` (3, 3) or (N, 3, 3)."""
    trace = np.einsum("kij,kij->k", a, np.broadcast_to(b, a.shape))
    return np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))


def rest_stretch(model: MorphableModel, frames: Sequence[TrackedFrame]) -> RestStretch | None:
    """The stretch of :data:`NEUTRAL_WINDOW_S` either side of a frame (at least 3 frames with a
    face, each within :data:`REST_TURN_DEG` of the clip's typical head rotation, the frame whose
    rotation is nearest the others' by the median chordal distance, and within the first of
    :data:`NEUTRAL_FADE_DEG` of the middle frame's: the head still, where the offsets measured
    there hold in full) whose frames' expressions
    (the weights other than the eyes': the lids blink at rest) are nearest the clip's median
    expression, per weight: the face the clip shows most, which in a take that holds the face
    still at rest for a good part of it is the face at rest (a detector's bias for this person's
    face at rest, explained by the model as an expression, is in every frame and so in the median;
    a smile explains the same points with less weight, so the smallest weights would not find the
    rest). None where no stretch qualifies. Pass 1 of :func:`track_frames`'s tracked ``frames``.

    A person who talks or smiles throughout has no such stretch near the median: its distance
    tells (:data:`REST_DISTANCE`)."""
    found = [f for f in frames if f.found]
    if len(found) < 3:
        return None
    expressive = ~lid_weights(model.expression_names)
    weights = np.stack([np.asarray(f.delta, np.float64)[expressive] for f in found])
    distance = np.abs(weights - np.median(weights, axis=0)).sum(axis=1)
    rotations = np.stack([np.asarray(f.rotation, np.float64) for f in found])
    sample = rotations[:: max(1, len(found) // 200)]  # the typical rotation among at most ~200 frames
    typical = sample[np.argmin(np.median(np.linalg.norm(sample[:, None] - sample[None], axis=(2, 3)), axis=1))]
    turn = _angles_deg(rotations, typical)
    times = np.array([f.time_s for f in found])
    first = np.searchsorted(times, times - NEUTRAL_WINDOW_S, "left")
    last = np.searchsorted(times, times + NEUTRAL_WINDOW_S, "right")
    summed = np.concatenate([[0.0], np.cumsum(distance)])
    turned = np.concatenate([[0], np.cumsum(turn > REST_TURN_DEG)])
    count = last - first
    usable = (count >= 3) & (turned[last] == turned[first])
    middle = np.arange(len(found))
    for shift in range(1, int(max((middle - first).max(), (last - 1 - middle).max())) + 1):  # the head still in the stretch
        for other in (middle - shift, middle + shift):
            inside = (other >= first) & (other < last)
            moved = _angles_deg(rotations[np.clip(other, 0, len(found) - 1)], rotations) > NEUTRAL_FADE_DEG[0]
            usable &= ~(inside & moved)
    if not usable.any():
        return None
    mean = np.where(usable, (summed[last] - summed[first]) / np.maximum(count, 1), np.inf)
    best = int(np.argmin(mean))
    held = weights[first[best]:last[best]].mean(axis=0)
    names = np.asarray(model.expression_names)[expressive]
    return RestStretch(float(times[best]), float(mean[best]), (str(names[np.argmax(held)]), float(held.max())))


def lid_weights(names: list[str] | tuple[str, ...]) -> np.ndarray:
    """(n_exp,) bool: the expressions whose weights :func:`smooth_track` keeps fast, the lids'
    (ICT-FaceKit's ``eye*``: blink, squint, wide, and the gaze that moves them), of the model's
    expression ``names``."""
    return np.array([name.startswith("eye") for name in names], bool)


def smooth_track(frames: list[TrackedFrame], lower: np.ndarray, upper: np.ndarray,
                 fast: np.ndarray | None = None) -> list[TrackedFrame]:
    """The frames with their frame-to-frame jitter taken out, each run of consecutive frames with a
    face on its own (nothing is carried across a frame without one; a run shorter than a window
    keeps its values). Offline and centred: no lag in a file; used live, a window of n frames lags
    by (n − 1) / 2 frames.

    * The pose: the running median of :data:`POSE_WINDOW` frames of the rotation (as rotation
      vectors about the run's middle frame's rotation, component by component) and of the
      translation. A median keeps a head turn's ramp and its stops where they are and takes out
      single-frame jumps.
    * The ``fast`` (n_exp,) bool weights (the lids', :func:`lid_weights`; None: every weight): a Savitzky–Golay filter
      of :data:`WEIGHT_WINDOW` frames, order 2: it keeps the peak of a blink of 3 frames at 0.97 of
      its height (a median would halve it) and halves the jitter.
    * The other weights: a running median of :data:`WEIGHT_WINDOW` frames, then a Savitzky–Golay
      filter of :data:`SLOW_WEIGHT_WINDOW` frames, order 2 (a smile or a frown lasts longer than a
      blink: on the ground-truth take of ``benchmarks/bench_track_truth.py`` their still
      stretches' frame-to-frame change went from 0.04–0.05 to 0.02–0.03, and 8 curves pass its
      bars instead of 6). Used live they would lag by 6 frames.
    * The weights are clipped to the model's range ``lower``/``upper`` (n_exp,).

    Measured on real clips (benchmarks/RESULTS.md, "facegeo track on real clips"): the head's
    frame-to-frame change from 0.4–0.8° to about 0.1°, the most jittery weight's from 0.08 to 0.04
    (the Savitzky–Golay filter of 5 frames alone).
    """
    from facegeo.running_filters import running_median, savitzky_golay

    out = list(frames)
    k = 0
    while k < len(frames):
        if not frames[k].found:
            k += 1
            continue
        end = k
        while end < len(frames) and frames[end].found:
            end += 1
        run = frames[k:end]
        if len(run) >= POSE_WINDOW:
            reference = np.asarray(run[len(run) // 2].rotation, np.float64)
            vectors = running_median(np.stack([cv2.Rodrigues(reference.T @ np.asarray(f.rotation, np.float64))[0][:, 0] for f in run]),
                                     POSE_WINDOW)
            rotations = np.stack([reference @ cv2.Rodrigues(v)[0] for v in vectors]).astype(np.float32)
            translations = running_median(np.stack([np.asarray(f.translation, np.float64) for f in run]), POSE_WINDOW).astype(np.float32)
            for j in range(len(run)):
                out[k + j] = dataclasses.replace(out[k + j], rotation=rotations[j], translation=translations[j])
        if len(run) >= WEIGHT_WINDOW:
            raw = np.stack([np.asarray(f.delta, np.float64) for f in run])
            weights = savitzky_golay(raw, WEIGHT_WINDOW, 2)
            slow = np.zeros(raw.shape[1], bool) if fast is None else ~np.asarray(fast, bool)
            if slow.any() and len(run) >= SLOW_WEIGHT_WINDOW:
                weights[:, slow] = savitzky_golay(running_median(raw[:, slow], WEIGHT_WINDOW), SLOW_WEIGHT_WINDOW, 2)
            weights = np.clip(weights, lower, upper).astype(np.float32)
            for j in range(len(run)):
                out[k + j] = dataclasses.replace(out[k + j], delta=weights[j])
        k = end
    return out
