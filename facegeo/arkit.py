"""Blendshape names: ARKit's 52 (what Live Link Face, Unreal's ARKit curves and three.js examples
use) and how a model's expression names map to them.

ARKit names the subject's own sides (``eyeBlinkLeft`` closes the subject's left eye). ICT-FaceKit's
``_L`` is the subject's left too, shown by geometry rather than names: in the model's axes +X is
the subject's left (iBUG point 36, the outer corner of the subject's right eye, lies at x < 0), and
``eyeBlink_L`` moves the eyelid at x > 0 (``tests/test_arkit.py`` checks it on the exported file).
So ``name_L`` ↦ ``nameLeft`` and ``name_R`` ↦ ``nameRight``; ICT's split ``browInnerUp_L/_R`` and
``cheekPuff_L/_R`` become ARKit's single ``browInnerUp`` and ``cheekPuff``: one target that moves
both halves (their deltas summed) and one weight that drives both. ARKit's ``tongueOut`` has no
ICT-FaceKit shape: it is left out of the targets and named in the files' notes.

A :class:`TargetNaming` turns the model's K shapes into the T targets a file carries:
``target deltas = combine @ model deltas`` and ``target weights = weights_from_model @ δ`` (a
merged pair takes the mean of its halves: the fit's expression with the two halves of
``browInnerUp`` and of ``cheekPuff`` made equal, as ARKit has one weight for each), and an ARKit
weight vector (a Live Link Face frame) becomes the model's δ with ``model_from_arkit``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facegeo.errors import InputError

__all__ = ["ARKIT_NAMES", "BLENDSHAPE_NAMINGS", "TargetNaming", "target_naming", "arkit_name", "ArkitTake"]

#: ARKit's 52 blendshape names, in the order of Live Link Face's CSV columns (camelCase; the CSV
#: capitalises the first letter).
ARKIT_NAMES = (
    "eyeBlinkLeft", "eyeLookDownLeft", "eyeLookInLeft", "eyeLookOutLeft", "eyeLookUpLeft", "eyeSquintLeft", "eyeWideLeft",
    "eyeBlinkRight", "eyeLookDownRight", "eyeLookInRight", "eyeLookOutRight", "eyeLookUpRight", "eyeSquintRight", "eyeWideRight",
    "jawForward", "jawRight", "jawLeft", "jawOpen", "mouthClose", "mouthFunnel", "mouthPucker", "mouthRight", "mouthLeft",
    "mouthSmileLeft", "mouthSmileRight", "mouthFrownLeft", "mouthFrownRight", "mouthDimpleLeft", "mouthDimpleRight",
    "mouthStretchLeft", "mouthStretchRight", "mouthRollLower", "mouthRollUpper", "mouthShrugLower", "mouthShrugUpper",
    "mouthPressLeft", "mouthPressRight", "mouthLowerDownLeft", "mouthLowerDownRight", "mouthUpperUpLeft", "mouthUpperUpRight",
    "browDownLeft", "browDownRight", "browInnerUp", "browOuterUpLeft", "browOuterUpRight", "cheekPuff", "cheekSquintLeft",
    "cheekSquintRight", "noseSneerLeft", "noseSneerRight", "tongueOut",
)

#: ``--blendshape-names`` choices: ARKit's names (default) or the model's own (ICT-FaceKit's).
BLENDSHAPE_NAMINGS = ("arkit", "ict")

_SIDES = {"_L": "Left", "_R": "Right"}


def arkit_name(model_name: str) -> str | None:
    """The ARKit name of one of the model's expression names, or None if ARKit has none:
    ``eyeBlink_L`` -> ``eyeBlinkLeft``, ``browInnerUp_R`` -> ``browInnerUp`` (merged),
    ``jawOpen`` -> ``jawOpen``."""
    base, side = model_name[:-2], _SIDES.get(model_name[-2:])
    if side is None:
        return model_name if model_name in ARKIT_NAMES else None
    if base + side in ARKIT_NAMES:
        return base + side
    return base if base in ARKIT_NAMES else None


@dataclass(frozen=True)
class TargetNaming:
    """How K model shapes become T named targets.

    Attributes:
        naming: ``"arkit"`` or ``"ict"``.
        names: (T,) the targets' names, in the file's order.
        combine: (T, K) float64; a target's delta is ``combine @ deltas`` (1 for each model shape it drives).
        weights_from_model: (T, K) float64; the target weights of model weights δ are ``weights_from_model @ δ``.
        model_from_arkit: (K, 52) float64; the model weights of an ARKit weight vector (in :data:`ARKIT_NAMES` order).
        missing: ARKit names no target carries (``tongueOut`` for ICT-FaceKit).
    """

    naming: str
    names: tuple[str, ...]
    combine: np.ndarray
    weights_from_model: np.ndarray
    model_from_arkit: np.ndarray
    missing: tuple[str, ...]

    def target_weights(self, model_weights: np.ndarray) -> np.ndarray:
        """(..., T) float64 target weights of (..., K) model weights."""
        return np.asarray(model_weights, dtype=np.float64) @ self.weights_from_model.T

    def notes(self) -> list[str]:
        """What a file records about its targets (the ARKit names it cannot carry)."""
        return [f"{name}: no shape in the model; not among the targets" for name in self.missing]


def target_naming(model_names: tuple[str, ...] | list[str], naming: str = "arkit") -> TargetNaming:
    """The :class:`TargetNaming` of a model's expression names under ``naming`` (one of
    :data:`BLENDSHAPE_NAMINGS`).

    Raises:
        InputError: an unknown naming, or (``arkit``) a model name ARKit has no name for.
    """
    names = [str(n) for n in model_names]
    k = len(names)
    if naming not in BLENDSHAPE_NAMINGS:
        raise InputError("<argument>", "blendshape names", f"one of {', '.join(BLENDSHAPE_NAMINGS)}", repr(naming))
    arkit_of = [arkit_name(n) for n in names]
    model_from_arkit = np.zeros((k, len(ARKIT_NAMES)))
    for j, a in enumerate(arkit_of):
        if a is not None:
            model_from_arkit[j, ARKIT_NAMES.index(a)] = 1.0
    if naming == "ict":
        eye = np.eye(k)
        missing = tuple(a for a in ARKIT_NAMES if a not in arkit_of)
        return TargetNaming("ict", tuple(names), eye, eye.copy(), model_from_arkit, missing)
    unmapped = [n for n, a in zip(names, arkit_of) if a is None]
    if unmapped:
        raise InputError("<model>", "expression_names", "names with an ARKit counterpart (or --blendshape-names ict)",
                         ", ".join(unmapped[:5]))
    targets = [a for a in ARKIT_NAMES if a in arkit_of]
    combine = np.zeros((len(targets), k))
    for j, a in enumerate(arkit_of):
        combine[targets.index(a), j] = 1.0
    weights_from_model = combine / combine.sum(axis=1, keepdims=True)
    missing = tuple(a for a in ARKIT_NAMES if a not in targets)
    return TargetNaming("arkit", tuple(targets), combine, weights_from_model, model_from_arkit, missing)


@dataclass
class ArkitTake:
    """A take (N frames) in ARKit's terms: what Live Link Face records
    (:func:`facegeo.export.live_link.read_live_link_csv`) and what ``facegeo track`` makes.

    Attributes:
        source: the file it was read from.
        fps: the time code rate used to read ``Timecode``.
        times: (N,) float64 seconds from the first frame, strictly increasing.
        weights: (N, 52) float32 blendshape weights in [0, 1], in :data:`ARKIT_NAMES` order.
        rotations: group name (``head``, ``left_eye``, ``right_eye``) -> (N, 3) float64 yaw,
            pitch, roll in radians (Live Link Face's signs); only the groups the file has.
        notes: what reading changed (clamped weights).
    """

    source: str
    fps: float
    times: np.ndarray
    weights: np.ndarray
    rotations: dict[str, np.ndarray] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    @property
    def n_frames(self) -> int:
        return int(len(self.times))
