"""Driving an exported face with a Live Link Face take: the rig (head and eyes) and the per-frame
values the writers key.

The rig (:func:`face_rig`):

* **head**: every mesh turns with the head about the model's origin (ICT-FaceKit's origin lies
  inside the head between the ears, at about the height of the nose tip: a natural centre for
  nodding and turning; the neck and shoulders of the skin turn with it, there is no neck joint);
* **eyes**: the eyeballs part is split into the subject's left and right eye, each turning about
  its globe's centre (:func:`facegeo.parts.eyeball_centres`). ICT-FaceKit's ``eyeLook*``
  shapes move the eyelids only (its eyeballs move with no shape), so gaze comes from the eye
  rotations, as in ARKit's own face rig, and is not applied twice.

The values (:func:`target_weights`, :func:`rotations`): the take's 52 ARKit weights become the
model's weights (:attr:`facegeo.arkit.TargetNaming.model_from_arkit`: ARKit's
``browInnerUp`` drives both of ICT's halves; ``tongueOut`` drives nothing) and then the file's
target weights; Live Link Face's yaw, pitch and roll (radians, its signs: a positive yaw turns
towards the subject's right, a positive pitch looks down, :mod:`facegeo.export.live_link`) become
rotations in the model's axes (+X the subject's left, +Y up, +Z out of the face):
``R = R_y(−yaw) · R_x(pitch) · R_z(−roll)``, yaw outermost.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from facegeo.arkit import ArkitTake, TargetNaming
from facegeo.asset import Asset
from facegeo.parts import EYEBALLS_PART, eyeball_centres

__all__ = ["FaceRig", "face_rig", "target_weights", "rotations", "head_angles", "EYE_NAMES", "HEAD_NAME"]

#: The head joint / node.
HEAD_NAME = "head"
#: The eye joints / nodes (the subject's left, then right) and the take's rotation group of each.
EYE_NAMES = {"eye_left": "left_eye", "eye_right": "right_eye"}


@dataclass
class FaceRig:
    """How an asset is turned by an animation.

    Attributes:
        eyeballs: the name of the part split into the eyes, or None (an asset without eyeballs:
            the eye rotations are not written).
        eyes: the eye surfaces (named as :data:`EYE_NAMES`), vertices relative to their centres.
        centres: (2, 3) float64 mm, the left and right eye's centre (model space).
    """

    eyeballs: str | None
    eyes: list[Asset] = field(default_factory=list)
    centres: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    def material_of(self, surface: str) -> str:
        """The material a surface uses (both eyes share the eyeballs')."""
        return self.eyeballs if surface in EYE_NAMES and self.eyeballs is not None else surface


def face_rig(asset: Asset) -> FaceRig:
    """The :class:`FaceRig` of an asset (its eyeballs part, if any, split per eye)."""
    eyeballs = next((p for p in asset.parts if p.name == EYEBALLS_PART), None)
    if eyeballs is None:
        return FaceRig(None)
    side, centres = eyeball_centres(eyeballs.vertices)
    eyes = []
    for name, mask, centre in zip(EYE_NAMES, (side, ~side), centres):
        keep = np.all(mask[eyeballs.triangles], axis=1)
        used, triangles = np.unique(eyeballs.triangles[keep], return_inverse=True)
        shapes = eyeballs.blendshapes.subset(used) if eyeballs.blendshapes is not None else None
        eyes.append(Asset(eyeballs.vertices[used] - centre.astype(np.float32), triangles.reshape(-1, 3), eyeballs.uv,
                          eyeballs.uv_triangles[keep], maps=eyeballs.maps, constants=dict(eyeballs.constants),
                          name=name, blendshapes=shapes))
    return FaceRig(eyeballs.name, eyes, centres)


def target_weights(take: ArkitTake, naming: TargetNaming) -> np.ndarray:
    """(N, T) float64: the file's target weights at each frame of the take."""
    model = take.weights.astype(np.float64) @ naming.model_from_arkit.T
    return naming.target_weights(model)


def head_angles(rotation: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations in the model's axes (a fit's head rotation, model to camera) -> (N, 3)
    float64 Live Link Face yaw, pitch, roll in radians: the inverse of :func:`rotations`."""
    # R = R_y(a) · R_x(b) · R_z(c) read off its entries (SciPy's as_euler("YXZ"), whose import,
    # scipy.spatial's, costs 0.3 s of facegeo track's serial tail); at b = ±90° (the head looking
    # straight up or down) only a − c or a + c is defined: c is taken as 0, as SciPy does
    r = np.asarray(rotation, dtype=np.float64).reshape(-1, 3, 3)
    b = np.arcsin(np.clip(-r[:, 1, 2], -1.0, 1.0))
    locked = np.hypot(r[:, 1, 0], r[:, 1, 1]) < 1e-9
    a = np.where(locked, np.arctan2(-r[:, 2, 0], r[:, 0, 0]), np.arctan2(r[:, 0, 2], r[:, 2, 2]))
    c = np.where(locked, 0.0, np.arctan2(r[:, 1, 0], r[:, 1, 1]))
    return np.stack([-a, b, -c], axis=1)


def rotations(angles: np.ndarray) -> np.ndarray:
    """(N, 3) Live Link Face yaw, pitch, roll (radians) -> (N, 4) float64 unit quaternions
    (x, y, z, w) in the model's axes (module docstring)."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(angles, dtype=np.float64).reshape(-1, 3)
    return Rotation.from_euler("YXZ", np.stack([-a[:, 0], a[:, 1], -a[:, 2]], axis=1)).as_quat()
