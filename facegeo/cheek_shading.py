"""cheekPuff read from the cheeks' shading, against the face at rest.

A puff moves the cheeks outwards by up to 8 mm, but the points a landmark detector places on a
cheek follow its outline and texture poorly (RESULTS.md, issue 48: the tracker read 0.06 at a
held 0.9), and the lips' motion it does see, other expressions explain as well. What a puff
changes most is how the cheeks turn: their normals, so their shading under the room's light.

:func:`cheek_shading` takes the frame at rest (the clip's own, where its person's points at rest
were measured) and its solved pose and expression, and fits there

* the light: second-order SH irradiance γ (3, 9) in camera space (:mod:`facegeo.lighting`), by
  least squares over the visible cheeks and reference skin with its colour taken as one constant
  (which γ absorbs); a camera that does not move has the room's light fixed in camera space, so
  this light holds for the whole clip (a hand-held camera that turns moves it: the gain below
  then drops and no puff is read);
* each cheek vertex's albedo (luminance): its colour at rest over the shading there, so that the
  frame at rest reads no puff whatever the face's own colours; the same for the exposure's
  reference skin (below).

:meth:`CheekShading.puff_reading` then reads a frame: with its solved pose and expression and the puff
p on a grid over [0, :data:`PUFF_MAX`], the cheek vertices (those a full puff moves by more than
:data:`PUFF_REGION_MM`, skin, not lips or eyes) are moved and shaded, and the photo's log
luminance there is compared with the albedo × shading, less the frame's exposure against the
frame at rest (the median log ratio over skin that a puff does not move, :data:`REFERENCE_MM`:
a camera's automatic exposure; white balance is left in): the error is the facing-weighted mean of
the squared log ratios, each clipped at :data:`RESIDUAL_CLIP` (misplaced skin texture, hair, a
highlight, a cast shadow that moved). The best p (refined by a parabola through its neighbours)
is kept by how much of the error at p = 0 it explains, the gain: an error of the solved pose or
identity, or of the light fitted at rest, makes a shading change that a puff explains a little of,
a puff much more; the reading is p × a ramp of the gain over :data:`PUFF_GAIN_RAMP`. On the
ground-truth takes (benchmarks/RESULTS.md), frames whose true puff is above 0.5 against those
with none: under key + fill light, gains 0.43-0.44 (10th percentile, median) against 0.05 (99th
percentile); under a window light on a darker, more textured skin, 0.08-0.16 against 0.04 (90th)
and 0.13 (99th).

Why by hand: no library reads a blendshape's weight from shading; this is a one-parameter
analysis by synthesis at the model's vertices, which needs no renderer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from facegeo.camera import Camera, to_pixels
from facegeo.colour import luminance, srgb_to_linear
from facegeo.landmarks.scheme import OUTER_EYE_CORNERS
from facegeo.lighting import sh_basis
from facegeo.morphable_model import MorphableModel
from facegeo.normals import vertex_normals
from facegeo.skin_mask import skin_vertex_mask, vertex_regions
from facegeo.uv.texels import sample_bilinear
from facegeo.visibility import facing_cosine, vertex_visibility

__all__ = ["CheekShading", "cheek_shading", "PUFF_NAMES", "PUFF_REGION_MM", "PUFF_MAX", "PUFF_STEPS", "RESIDUAL_CLIP", "REFERENCE_MM",
           "MIN_FACING", "MIN_VERTICES", "MIN_EYE_SPAN_PX", "PUFF_GAIN_RAMP"]

#: The model's puff targets (ICT-FaceKit's), moved together: ARKit has one ``cheekPuff``.
PUFF_NAMES = ("cheekPuff_L", "cheekPuff_R")
#: The cheek vertices: skin that a full puff (both targets at 1) moves by more than this (mm).
PUFF_REGION_MM = 2.0
#: The puff read is looked for on [0, PUFF_MAX] in PUFF_STEPS steps.
PUFF_MAX, PUFF_STEPS = 1.2, 6
#: A vertex's squared log-luminance ratio counts at most this ratio's square (a factor of 1.35):
#: 0.05 left 40-90 % of a textured skin's vertices clipped and most of the puff's gain with them
#: (0.05 / 0.15 / 0.3 / 0.4 on the two takes tuned on: benchmarks/RESULTS.md).
RESIDUAL_CLIP = 0.3
#: The exposure's reference: skin that a full puff moves by less than this (mm), not the lips or eyes.
REFERENCE_MM = 0.5
#: Vertices facing the camera less than this (cosine) are not read: grazing shading, the outline.
MIN_FACING = 0.3
#: No puff is read where fewer cheek (or reference) vertices than this face the camera.
MIN_VERTICES = 50
#: ... nor where the outer eye corners are less than this far apart in the frame (px): the cheeks
#: then span a few pixels, compression and blur; a real clip of a face at 19 px read 0.5-0.9
#: (benchmarks/RESULTS.md). The ground-truth takes' faces are at 105-113 px.
MIN_EYE_SPAN_PX = 50.0
#: The share of the error at no puff that the best puff must explain: none below the first, all
#: of it read at or above the second (a linear ramp between); chosen on the two takes tuned on.
PUFF_GAIN_RAMP = (0.04, 0.08)


@dataclass(frozen=True)
class CheekShading:
    """The cheeks at rest, for :meth:`puff_reading`. ``local`` (K,) int, the cheek vertices' rows
    in ``patch`` (P,) int, the vertices of every triangle that touches them, and ``triangles``
    (T, 3) int, those triangles in patch rows; ``identity`` (P, 3) float64, the patch of the clip's
    identity (mm); ``exp_basis`` (n_exp, P × 3) float64, its expressions; ``puff`` (n_exp,)
    float64, the expression vector of a full puff (1 at :data:`PUFF_NAMES`), and ``motion``
    (P, 3) float64, the patch's motion by it (mm); ``gamma`` (3, 9) float64, the light (linear
    RGB); ``albedo`` (K,) float64, each cheek vertex's luminance over its shading at rest;
    ``camera`` the clip's. The exposure's reference, skin that a puff does not move
    (:data:`REFERENCE_MM`): ``reference_shape`` (R, 3) float64, the identity there (mm);
    ``reference_basis`` (n_exp, R × 3) float64, its expressions; ``reference_normals`` (R, 3)
    float64, its normals at rest in model space; ``reference_albedo`` (R,) float64, as
    ``albedo``. ``eye_centre`` (3,) float64, the midpoint of the outer eye corners (iBUG 36, 45)
    of the identity (mm), and ``eye_span_mm`` their distance: the face's size in the frame."""

    local: np.ndarray
    patch: np.ndarray
    triangles: np.ndarray
    identity: np.ndarray
    exp_basis: np.ndarray
    puff: np.ndarray
    motion: np.ndarray
    gamma: np.ndarray
    albedo: np.ndarray
    camera: Camera
    reference_shape: np.ndarray
    reference_basis: np.ndarray
    reference_normals: np.ndarray
    reference_albedo: np.ndarray
    eye_centre: np.ndarray
    eye_span_mm: float

    def with_puff(self, delta: np.ndarray, puff: float) -> np.ndarray:
        """``delta`` (n_exp,) with its puff targets set to ``puff`` (a copy, float64)."""
        return np.where(self.puff > 0, float(puff), np.asarray(delta, np.float64))

    def puff_reading(self, image: np.ndarray, rotation: np.ndarray, translation: np.ndarray,
                     delta: np.ndarray) -> tuple[float, float] | None:
        """The puff this frame's cheeks show and the gain it was kept by (module docstring).

        Args:
            image: (H, W, 3) uint8 sRGB, the frame.
            rotation: (3, 3), translation (3,) mm: its solved pose.
            delta: (n_exp,) its solved expression (its own puff is replaced).
        Returns:
            (puff in [0, 1], gain in [0, 1]); None where the face is too small to read
            (:data:`MIN_EYE_SPAN_PX`) or too few cheek or reference vertices face the camera.
        """
        r, t = np.asarray(rotation, np.float64), np.asarray(translation, np.float64)
        depth = -float((self.eye_centre @ r.T + t)[2])
        if depth <= 0 or self.camera.focal * self.eye_span_mm / depth < MIN_EYE_SPAN_PX:
            return None
        exposure = self._exposure(image, r, t, np.asarray(delta, np.float64))
        if exposure is None:
            return None
        base = np.asarray(delta, np.float64) * (self.puff == 0)
        shape = self.identity + (base @ self.exp_basis).reshape(-1, 3)
        steps = np.linspace(0.0, PUFF_MAX, PUFF_STEPS + 1)
        cams = (shape[None] + steps[:, None, None] * self.motion[None]) @ r.T + t  # (S, P, 3)
        normals = vertex_normals(cams, self.triangles)[:, self.local]  # (S, K, 3)
        points = cams[:, self.local]
        facing = facing_cosine(points.reshape(-1, 3), normals.reshape(-1, 3)).reshape(len(steps), -1)
        ok = facing[0] > MIN_FACING  # the vertices read: those facing the camera at no puff
        if ok.sum() < MIN_VERTICES:
            return None
        colour = sample_bilinear(image, to_pixels(points[:, ok], self.camera)).astype(np.float64)  # (S, N, 3)
        observed = luminance(srgb_to_linear(colour / 255.0), np.float64)
        shading = luminance(sh_basis(normals[:, ok]) @ self.gamma.T, np.float64)
        ratio = np.log(np.maximum(observed, 1e-4)) - np.log(np.maximum(self.albedo[ok] * shading, 1e-4)) - exposure
        weight = np.maximum(facing[:, ok], 0.0)
        e = np.sum(weight * np.minimum(ratio * ratio, RESIDUAL_CLIP ** 2), axis=1) / np.sum(weight, axis=1)
        best = int(np.argmin(e))
        p = steps[best]
        if 0 < best < len(e) - 1:  # the parabola through the best step and its neighbours
            curve = e[best - 1] - 2 * e[best] + e[best + 1]
            if curve > 0:
                p += 0.5 * (e[best - 1] - e[best + 1]) / curve * (steps[1] - steps[0])
        gain = (e[0] - e[best]) / e[0] if e[0] > 0 else 0.0
        low, high = PUFF_GAIN_RAMP
        return float(np.clip(p, 0.0, 1.0) * np.clip((gain - low) / (high - low), 0.0, 1.0)), float(gain)

    def _exposure(self, image: np.ndarray, r: np.ndarray, t: np.ndarray, delta: np.ndarray) -> float | None:
        """The frame's exposure against the frame at rest: the median log ratio of the
        reference's luminance to its albedo × shading (its normals at rest turned with the head;
        the expressions barely turn skin that a puff does not move); None where fewer than
        :data:`MIN_VERTICES` of it face the camera."""
        points = (self.reference_shape + (delta @ self.reference_basis).reshape(-1, 3)) @ r.T + t
        normals = self.reference_normals @ r.T
        ok = facing_cosine(points, normals) > MIN_FACING
        if ok.sum() < MIN_VERTICES:
            return None
        observed = luminance(srgb_to_linear(sample_bilinear(image, to_pixels(points[ok], self.camera)) / 255.0), np.float64)
        shading = luminance(sh_basis(normals[ok]) @ self.gamma.T, np.float64)
        return float(np.median(np.log(np.maximum(observed, 1e-4)) - np.log(np.maximum(self.reference_albedo[ok] * shading, 1e-4))))


def cheek_shading(model: MorphableModel, alpha: np.ndarray, camera: Camera, image: np.ndarray, rotation: np.ndarray,
                  translation: np.ndarray, delta: np.ndarray) -> CheekShading | None:
    """The cheeks at rest (module docstring) from the frame at rest.

    Args:
        model: the morphable model; alpha (n_id,) the clip's identity.
        camera: the clip's camera.
        image: (H, W, 3) uint8 sRGB, the frame at rest.
        rotation: (3, 3), translation (3,) mm, delta (n_exp,): its solved pose and expression.
    Returns:
        The :class:`CheekShading`; None where the model has no puff targets
        (:data:`PUFF_NAMES`) or too few cheek or skin vertices face the camera at rest.
    """
    names = list(model.expression_names)
    if not all(name in names for name in PUFF_NAMES):
        return None
    puff = np.zeros(model.n_exp)
    puff[[names.index(name) for name in PUFF_NAMES]] = 1.0
    regions = vertex_regions(model)
    skin = skin_vertex_mask(model) & (regions["lips"] <= 0.5) & (regions["eyes"] <= 0.5)
    moved = np.linalg.norm(np.einsum("k,kvc->vc", puff, model.exp_basis), axis=1)
    identity = model.mean_shape.astype(np.float64) + np.einsum("k,kvc->vc", np.asarray(alpha, np.float64), model.id_basis)
    r, t = np.asarray(rotation, np.float64), np.asarray(translation, np.float64)
    cam = (identity + np.einsum("k,kvc->vc", np.asarray(delta, np.float64) * (puff == 0), model.exp_basis)) @ r.T + t
    normals = vertex_normals(cam, model.triangles)
    seen = skin & vertex_visibility(cam, model.triangles, normals, camera) & (facing_cosine(cam, normals) > MIN_FACING)
    cheeks = np.flatnonzero(seen & (moved > PUFF_REGION_MM))
    reference = np.flatnonzero(seen & (moved < REFERENCE_MM))
    if len(cheeks) < MIN_VERTICES or len(reference) < MIN_VERTICES:
        return None
    lit = np.concatenate([cheeks, reference])
    colour = srgb_to_linear(sample_bilinear(image, to_pixels(cam[lit], camera)) / 255.0).astype(np.float64)
    basis = sh_basis(normals[lit])
    gamma = np.stack([np.linalg.lstsq(basis, colour[:, c], rcond=None)[0] for c in range(3)])
    albedo = luminance(colour, np.float64) / np.maximum(luminance(basis @ gamma.T, np.float64), 1e-4)
    touching = np.isin(model.triangles, cheeks).any(axis=1)
    patch, inverse = np.unique(model.triangles[touching], return_inverse=True)
    exp_basis = model.exp_basis[:, patch].astype(np.float64).reshape(model.n_exp, -1)
    n = len(cheeks)
    corners = identity[np.asarray(model.landmark_indices)[OUTER_EYE_CORNERS]]
    return CheekShading(np.searchsorted(patch, cheeks), patch, inverse.reshape(-1, 3), identity[patch], exp_basis, puff,
                        (puff @ exp_basis).reshape(-1, 3), gamma, albedo[:n], camera, identity[reference],
                        model.exp_basis[:, reference].astype(np.float64).reshape(model.n_exp, -1), normals[reference] @ r,
                        albedo[n:], 0.5 * (corners[0] + corners[1]), float(np.linalg.norm(corners[0] - corners[1])))
