"""The model's occluding contour around the lower face under a pose: where a detector's face-oval
points really are on a turned or pitched face.

A face-oval point of a detector marks the edge of the face in the photo: on a frontal face the
jaw line, on a turned face the far cheek's silhouette and the near jaw's edge. No fixed vertex
is that point in every pose (a fixed frontal jaw polyline put the chin 4–7 mm behind the real
one on turned and pitched views, issue 25). Here the lower face is cut into angular bins around a
centre between the eyes and the mouth (in the mean shape's front view, from the subject's right
temple down around the chin to the left temple); in each bin the vertices are ordered outwards,
and the contour vertex under a pose is the outermost one that still faces the camera before the
surface first turns away from it (walking outwards). The contour points of the fit then slide
along the polyline of these vertices (:meth:`facegeo.fitting.landmark_problem.LandmarkProblem.slide_silhouette`).

Normals are the mean shape's, rotated with the head (identity and expression change them little
at the contour's resolution); positions are the current shape's.
"""

from __future__ import annotations

import numpy as np

from facegeo.landmarks.scheme import EYES, JAW, MOUTH
from facegeo.morphable_model import MorphableModel
from facegeo.normals import vertex_normals

__all__ = ["Silhouette", "BIN_DEGREES", "MIN_RADIUS_FRACTION", "CHIN_MARGIN_MM"]

#: Angular width of a bin (degrees); the bins span 180° (temple to temple through the chin).
BIN_DEGREES = 5.0
#: Bins start this fraction of the jaw's radius from the centre (inside it, the nose's and the
#: eye sockets' own turning surfaces are not the face's outline).
MIN_RADIUS_FRACTION = 0.6
#: Bins end this far (mm) below the mean shape's chin: the jaw's underside runs smoothly into
#: the neck, so on a turned face the walk outwards would otherwise end on the neck, where no
#: detector puts the face's outline.
CHIN_MARGIN_MM = 8.0


class Silhouette:
    """The lower-face bins of one model (see the module docstring).

    Attributes:
        vertices: (M,) int64 model vertices of all bins.
        bins: list of (m_k,) int64 arrays, per bin its members as indices into ``vertices``,
            ordered outwards (by distance from the centre in the mean shape's front view).
        normals: (M, 3) float64 unit mean-shape normals of ``vertices`` (model space).
    """

    def __init__(self, model: MorphableModel):
        mean = model.mean_shape.astype(np.float64)
        lm = mean[model.landmark_indices]
        eye_y = float(lm[EYES, 1].mean())
        centre = np.array([0.0, 0.5 * (eye_y + float(lm[MOUTH, 1].mean()))])
        jaw = lm[JAW]
        jaw_radius = float(np.median(np.linalg.norm(jaw[:, :2] - centre, axis=1)))
        half_width = float(np.abs(jaw[:, 0]).max()) * 1.08
        rel = mean[:, :2] - centre
        radius = np.linalg.norm(rel, axis=1)
        angle = np.degrees(np.arctan2(rel[:, 1], rel[:, 0])) % 360.0
        normals = vertex_normals(model.mean_shape, np.asarray(model.triangles)).astype(np.float64)
        chin_y = float(lm[JAW, 1].min())
        candidate = ((np.abs(mean[:, 0]) <= half_width) & (mean[:, 2] >= float(jaw[:, 2].min()) - 10.0)
                     & (mean[:, 1] <= eye_y) & (mean[:, 1] >= chin_y - CHIN_MARGIN_MM)
                     & (radius >= MIN_RADIUS_FRACTION * jaw_radius)
                     & (radius <= 1.5 * jaw_radius) & model.face_mask)
        self.vertices = np.flatnonzero(candidate).astype(np.int64)
        self.normals = normals[self.vertices]
        r, a = radius[self.vertices], angle[self.vertices]
        centres = np.arange(180.0 + BIN_DEGREES / 2, 360.0, BIN_DEGREES)
        self.bins = []
        for c in centres:
            members = np.flatnonzero(np.abs(a - c) < BIN_DEGREES / 2)
            if len(members):
                self.bins.append(members[np.argsort(r[members], kind="stable")])
        # the bins as rows of one array, padded with -1, so that a pose's contour is a few array operations
        self._rows = np.full((len(self.bins), max((len(b) for b in self.bins), default=0)), -1, np.int64)
        for k, members in enumerate(self.bins):
            self._rows[k, : len(members)] = members

    def contour(self, positions_cam: np.ndarray, rotation: np.ndarray) -> np.ndarray:
        """The contour vertex of every non-empty bin under a pose.

        Args:
            positions_cam: (M, 3) camera-space positions (mm) of :attr:`vertices`.
            rotation: (3, 3) the head's rotation (model to camera), for the normals.
        Returns:
            (B,) int64 indices into :attr:`vertices`, one per bin, in bin order (subject's right
            temple, chin, left temple); bins whose vertices all face away are left out.
        """
        facing = ((self.normals @ rotation.T) * -positions_cam).sum(axis=1) > 0.0
        rows = self._rows
        f = (rows >= 0) & facing[rows]  # (B, L); the padding faces away
        start = np.argmax(f, axis=1)  # each bin's first facing vertex
        away = ~f & (np.arange(rows.shape[1]) >= start[:, None])
        end = np.where(away.any(axis=1), np.argmax(away, axis=1), rows.shape[1])  # facing to the bin's end: its last vertex
        kept = f.any(axis=1)
        return rows[kept, end[kept] - 1].astype(np.int64)
