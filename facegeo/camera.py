"""Perspective pinhole camera, rigid pose and projection (OpenGL axes, pixel rows downwards).

Camera space follows DESIGN.md, "Conventions": X_c = R·X + t, +X right, +Y up, and the camera looks down −Z, so
a visible point has z_c < 0. A pixel (u, v) has u growing to the right and v growing downwards:

    u = cx + f · x_c / (−z_c),    v = cy − f · y_c / (−z_c).

Pixel coordinates are continuous with the origin at the top-left corner of the image: pixel (i, j)
(column i, row j) covers [i, i+1) × [j, j+1) and its centre is (i + 0.5, j + 0.5). Landmarks,
projections and the principal point all use this convention (subtract 0.5 for OpenCV's
integer-centred pixel grid).

OpenCV's camera (looking down +Z, y down) differs by D = diag(1, −1, −1): R_cv = D·R, t_cv = D·t.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from facegeo.array_namespace import array_namespace, is_tensor
from facegeo.errors import InputError

if TYPE_CHECKING:  # torch is imported by whoever passes a tensor; NumPy callers (the fit) never load it
    import torch

__all__ = [
    "Camera",
    "project",
    "to_pixels",
    "pixels_jacobian",
    "cross_matrices",
    "rotation_from_axis_angle",
    "rotation_from_euler",
    "euler_from_rotation",
    "OPENCV_FROM_OPENGL",
]

#: D = diag(1, −1, −1): maps OpenGL camera coordinates to OpenCV's (and back; D = D⁻¹).
OPENCV_FROM_OPENGL = np.diag([1.0, -1.0, -1.0])

#: Horizontal-or-vertical field of view (degrees) assumed for the longer image side when the
#: focal length of a photo is unknown: a 50 mm lens on a full-frame camera sees about 40° along
#: its long side; portrait photos are usually taken with 35–85 mm equivalents.
DEFAULT_FOV_DEG = 40.0


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics in pixels: focal length ``focal``, principal point (``cx``, ``cy``),
    image size ``width`` × ``height``. Square pixels, no skew, no distortion.

    ``focal_known`` False marks a focal length that is a placeholder (a photo of unknown lens,
    :meth:`unknown_focal`): the fitter replaces it with its own estimate
    (:func:`facegeo.fitting.camera_estimate.camera_for_face`)."""

    focal: float
    cx: float
    cy: float
    width: int
    height: int
    focal_known: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.focal) and self.focal > 0):
            raise InputError("<camera>", "focal", "a finite focal length > 0 in pixels", repr(self.focal))
        if not (math.isfinite(self.cx) and math.isfinite(self.cy)):
            raise InputError("<camera>", "principal point", "finite pixel coordinates", f"({self.cx!r}, {self.cy!r})")
        if self.width <= 0 or self.height <= 0:
            raise InputError("<camera>", "image size", "a positive width and height in pixels", f"{self.width}x{self.height}")

    @classmethod
    def for_image(cls, width: int, height: int, fov_deg: float = DEFAULT_FOV_DEG) -> "Camera":
        """A camera for a ``width`` × ``height`` photo with principal point at the centre and the
        given field of view (degrees) along the longer side."""
        focal = 0.5 * max(width, height) / math.tan(math.radians(fov_deg) / 2.0)
        return cls(focal=focal, cx=width / 2.0, cy=height / 2.0, width=int(width), height=int(height))

    @classmethod
    def unknown_focal(cls, width: int, height: int, principal_point: tuple[float, float] | None = None) -> "Camera":
        """A camera for a photo whose focal length is unknown: principal point at the centre (or
        ``principal_point``, px, e.g. of a cropped photo), the focal a placeholder (40° field of
        view) with ``focal_known`` False, for the fitter to estimate."""
        base = cls.for_image(width, height)
        cx, cy = (base.cx, base.cy) if principal_point is None else (float(principal_point[0]), float(principal_point[1]))
        return cls(focal=base.focal, cx=cx, cy=cy, width=base.width, height=base.height, focal_known=False)

    def scaled(self, factor: float) -> "Camera":
        """The same camera for the image resized by ``factor`` (continuous pixel coordinates with
        the origin at the top-left image corner scale linearly)."""
        return Camera(
            focal=self.focal * factor,
            cx=self.cx * factor,
            cy=self.cy * factor,
            width=max(1, round(self.width * factor)),
            height=max(1, round(self.height * factor)),
            focal_known=self.focal_known,
        )

    def matrix(self) -> np.ndarray:
        """(3, 3) float64 OpenCV intrinsic matrix K (for cv2.solvePnP and friends)."""
        return np.array([[self.focal, 0.0, self.cx], [0.0, self.focal, self.cy], [0.0, 0.0, 1.0]])

    def as_dict(self) -> dict[str, float | int]:
        """JSON-ready fields."""
        return {"focal": self.focal, "cx": self.cx, "cy": self.cy, "width": self.width, "height": self.height,
                "focal_known": self.focal_known}


def project(
    points: torch.Tensor | np.ndarray,
    rotation: torch.Tensor | np.ndarray,
    translation: torch.Tensor | np.ndarray,
    camera: Camera,
) -> torch.Tensor | np.ndarray:
    """Project model-space points to pixels.

    Args:
        points: (..., N, 3) mm, model space.
        rotation: (..., 3, 3) rotation matrix R.
        translation: (..., 3) mm, t.
        camera: the intrinsics.
    Returns:
        (..., N, 2) pixel coordinates (u right, v down). A torch tensor (differentiable) when
        ``points`` is a tensor, else a float64 NumPy array. Points at or behind the camera
        plane (z_c ≥ −1e-6 mm) are projected with their depth clamped to 1e-6 mm, so results
        stay finite.
    """
    if is_tensor(points):
        xp = array_namespace(points)
        p, r, t = points, xp.as_tensor(rotation, dtype=points.dtype), xp.as_tensor(translation, dtype=points.dtype)
    else:  # NumPy in, NumPy out, computed in float64 without a round trip through torch
        xp = np
        p, r, t = (np.asarray(a, dtype=np.float64) for a in (points, rotation, translation))
    return to_pixels(p @ xp.swapaxes(r, -1, -2) + t[..., None, :], camera)


def to_pixels(points_cam: torch.Tensor | np.ndarray, camera: Camera) -> torch.Tensor | np.ndarray:
    """The pinhole of the module docstring, the one implementation of the projection (:func:`project`
    poses points, then calls it): (..., N, 3) camera-space points (mm) -> (..., N, 2) pixels (u right,
    v down), in the input's type and float dtype (differentiable for tensors).

    Reads only ``camera.focal``, ``cx`` and ``cy`` (floats, or tensors that broadcast). Depths are
    clamped to ≥ 1e-6 mm, so points at or behind the camera plane stay finite; callers that must
    skip them test the depth themselves.
    """
    xp = array_namespace(points_cam)
    scale = camera.focal / xp.clip(-points_cam[..., 2], 1e-6, None)  # pixels per mm at that depth
    return xp.stack([camera.cx + points_cam[..., 0] * scale, camera.cy - points_cam[..., 1] * scale], axis=-1)


def pixels_jacobian(points_cam: np.ndarray, focal: float) -> np.ndarray:
    """d(u, v) / d(x, y, z) of :func:`to_pixels` at (N, 3) camera-space points (mm): (N, 2, 3)
    float64 px/mm, with the same depth clamp (for the fits' hand-written Jacobians)."""
    depth = np.maximum(-points_cam[:, 2], 1e-6)
    out = np.zeros((len(points_cam), 2, 3))
    out[:, 0, 0] = focal / depth
    out[:, 0, 2] = focal * points_cam[:, 0] / depth**2
    out[:, 1, 1] = -focal / depth
    out[:, 1, 2] = -focal * points_cam[:, 1] / depth**2
    return out


def cross_matrices(points: np.ndarray) -> np.ndarray:
    """(N, 3, 3) [p]×, the matrices with [p]× v = p × v, of (N, 3) points, in their dtype: for a
    pose R·exp([ω]×), d(R·exp([ω]×)·p) / dω = −R·[p]× at ω = 0."""
    out = np.zeros((len(points), 3, 3), points.dtype)
    px, py, pz = points.T
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -pz, py, -px
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = pz, -py, px
    return out


def rotation_from_axis_angle(axis_angle: torch.Tensor) -> torch.Tensor:
    """Rodrigues' formula: (..., 3) axis·angle in radians -> (..., 3, 3) rotation matrices.

    Written out rather than taken from kornia because callers differentiate it with
    ``torch.func`` transforms, which kornia's data-dependent branches do not support. Smooth and
    exact at the zero rotation: θ² gets a 1e-12 guard that changes no result above 1e-6 rad.
    """
    import torch

    theta2 = (axis_angle * axis_angle).sum(-1, keepdim=True)[..., None] + 1e-12
    theta = theta2.sqrt()
    x, y, z = axis_angle.unbind(-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*axis_angle.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=axis_angle.dtype).expand_as(k)
    return eye + torch.sin(theta) / theta * k + (1 - torch.cos(theta)) / theta2 * (k @ k)


def rotation_from_euler(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """(3, 3) float64 R = R_z(roll) · R_x(pitch) · R_y(yaw), angles in degrees.

    Yaw turns the face about +Y (positive: the nose turns towards +X, the viewer's right, and the
    subject's right ear comes into view), pitch about +X (positive: chin goes down), roll about +Z.
    """
    y, p, r = (math.radians(a) for a in (yaw, pitch, roll))
    ry = np.array([[math.cos(y), 0, math.sin(y)], [0, 1, 0], [-math.sin(y), 0, math.cos(y)]])
    rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    return rz @ rx @ ry


def euler_from_rotation(rotation: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`rotation_from_euler`: (yaw, pitch, roll) in degrees."""
    r = np.asarray(rotation, dtype=np.float64)
    pitch = math.asin(max(-1.0, min(1.0, r[2, 1])))
    yaw = math.atan2(-r[2, 0], r[2, 2])
    roll = math.atan2(-r[0, 1], r[1, 1])
    return math.degrees(yaw), math.degrees(pitch), math.degrees(roll)
