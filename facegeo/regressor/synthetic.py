"""Synthetic training faces with known parameters (``facegeo make-synthetic-faces``).

Each image is a random instance of the morphable model rendered with ``facegeo.uv.render``:
α ~ N(0, σ_id²) (σ_id = 0.8 by default); δ sparse as in a real face, drawn among the expressions
that landmarks can see (:func:`landmark_visible_expressions`; each active with probability 0.1 by
default, uniform in 0–80 % of its range, a corrective such as ICT's
``mouthClose`` at most its driver as ``fit_landmarks`` keeps it; or N(0, (2p)²) when unbounded); a skin albedo = the model's albedo(β) times a random skin-tone
gain and a smooth random variation; random SH lighting about ambient white; yaw, pitch and roll
uniform in ±``max_yaw``, ±20°, ±12°; the face filling 35–60 % of the frame; a random background
(a colour gradient with noise). Camera: :meth:`Camera.for_image` (40° field of view).

Written into the output folder: ``000000.png`` ... and ``faces.npz`` with ``names`` (N,),
``landmarks`` (N, 88, 2) px (the projected frontal landmark vertices), ``alpha``, ``delta``,
``beta``, ``gamma`` (N, 3, 9), ``rotation`` (N, 3, 3), ``translation`` (N, 3) mm and ``camera``
(N, 3) = focal, cx, cy px.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch

from facegeo.camera import Camera, project, rotation_from_euler
from facegeo.colour import linear_to_srgb
from facegeo.fitting import CORRECTIVES
from facegeo.image_files import png_bytes
from facegeo.landmarks.scheme import OUTER_EYE_CORNERS
from facegeo.lighting import AMBIENT_WHITE, sh_irradiance
from facegeo.morphable_model import MorphableModel
from facegeo.regressor.data import TRUTH_FILE
from facegeo.regressor.network import ModelSignature
from facegeo.staged_output import StagedOutput
from facegeo.uv import render

__all__ = ["landmark_visible_expressions", "random_face", "render_face", "make_synthetic_faces"]


def landmark_visible_expressions(model: MorphableModel, min_shift: float = 0.01) -> np.ndarray:
    """(n_exp,) bool: the expressions whose full weight (1 for blendshapes, 1 σ for PCA) moves
    the 88 landmark vertices of the mean face by an RMS of at least ``min_shift`` inter-ocular
    distances in the image plane (frontal view). ICT-FaceKit at 0.01: 38 of 53; out: eye gaze but
    eyeLookDown, eyeSquint, eyeWide, cheekSquint, browInnerUp and jawForward (< 0.01: landmarks
    barely constrain them)."""
    points = model.mean_shape[model.landmark_indices].astype(np.float64)
    iod = float(np.linalg.norm(np.subtract(*points[OUTER_EYE_CORNERS, :2])))
    shift = model.exp_basis.reshape(model.n_exp, model.n_vertices, 3)[:, model.landmark_indices, :2].astype(np.float64)
    return np.sqrt((shift**2).sum(-1).mean(-1)) >= min_shift * iod


def random_face(model: MorphableModel, rng: np.random.Generator, size: int, max_yaw: float = 75.0,
                sigma_id: float = 0.8, expressions: float = 0.1, min_shift: float = 0.01) -> dict[str, np.ndarray]:
    """Random parameters of one face: alpha, delta, beta, gamma (3, 9), rotation (3, 3),
    translation (3,) mm for a ``size``² image; float32, plus ``albedo`` (V, 3) linear RGB.
    ``sigma_id``: the identity's standard deviation (σ units); ``expressions``: the probability
    of each bounded expression being active (unbounded ones: N(0, (2·expressions)²)); only the
    expressions of :func:`landmark_visible_expressions` at ``min_shift`` (0: all) are drawn."""
    lower, upper = model.expression_range
    bounded = np.isfinite(lower) & np.isfinite(upper)
    active = (rng.random(model.n_exp) < expressions) & landmark_visible_expressions(model, min_shift)
    span = np.where(bounded, upper - lower, 1.0)
    delta = np.where(bounded, np.where(active, lower + rng.uniform(0, 0.8, model.n_exp) * span, np.clip(0.0, lower, upper)),
                     np.where(landmark_visible_expressions(model, min_shift), rng.normal(0, 2.0 * expressions, model.n_exp), 0.0))
    names = list(model.expression_names)
    for corrective, driver in CORRECTIVES.items():
        if corrective in names and driver in names:
            delta[names.index(corrective)] = min(delta[names.index(corrective)], delta[names.index(driver)])
    alpha = rng.normal(0, sigma_id, model.n_id)
    beta = rng.normal(0, 1.0, model.n_tex)
    gamma = AMBIENT_WHITE.astype(np.float64)
    gamma[:, 0] *= rng.uniform(0.8, 1.25)
    gamma[:, 1:4] = rng.normal(0, 0.25, 3)[None] * rng.uniform(0.9, 1.1, (3, 1))
    gamma[:, 4:] = rng.normal(0, 0.08, 5)[None] * rng.uniform(0.9, 1.1, (3, 1))
    rotation = rotation_from_euler(rng.uniform(-max_yaw, max_yaw), rng.uniform(-20, 20), rng.uniform(-12, 12))
    camera = Camera.for_image(size, size)
    sig = ModelSignature.of(model)
    depth = camera.focal * sig.extent / (size * rng.uniform(0.35, 0.6))
    offset = rng.uniform(-0.08, 0.08, 2) * size * depth / camera.focal
    anchor = np.asarray(sig.anchor)
    translation = np.array([offset[0], offset[1], -depth]) - rotation @ anchor
    albedo = model.albedo(torch.from_numpy(beta).float()).numpy().astype(np.float64)
    tone = rng.uniform(0.55, 1.25) * np.array([1.0, rng.uniform(0.8, 0.95), rng.uniform(0.65, 0.9)])
    k = rng.normal(0, 1 / 60.0, (3, 3))  # smooth variation: a few waves over the mm positions
    phase = rng.uniform(0, 2 * np.pi, 3)
    waves = np.sin(model.mean_shape.astype(np.float64) @ k + phase).mean(1, keepdims=True)
    albedo = np.clip(albedo * tone * (1 + 0.12 * waves), 0.01, 1.0)
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    return {"alpha": f32(alpha), "delta": f32(delta), "beta": f32(beta), "gamma": f32(gamma), "rotation": f32(rotation),
            "translation": f32(translation), "albedo": f32(albedo)}


def render_face(model: MorphableModel, face: dict[str, np.ndarray], size: int,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, Camera]:
    """(image (size, size, 3) uint8 sRGB, landmarks (88, 2) px, camera) of one random face."""
    camera = Camera.for_image(size, size)
    shape = model.shape(torch.from_numpy(face["alpha"]), torch.from_numpy(face["delta"]))
    posed = shape @ torch.from_numpy(face["rotation"]).T + torch.from_numpy(face["translation"])
    normals = model.vertex_normals(posed)
    colours = (torch.from_numpy(face["albedo"]) * sh_irradiance(normals, torch.from_numpy(face["gamma"]))).numpy()
    view = render(posed.numpy(), model, camera, colours=np.clip(colours, 0, 1))
    ys, xs = np.mgrid[0:size, 0:size] / size
    c0, c1 = rng.uniform(0, 1, 3), rng.uniform(0, 1, 3)
    t = np.cos(rng.uniform(0, np.pi)) * xs + np.sin(rng.uniform(0, np.pi)) * ys
    background = c0 + (c1 - c0) * ((t - t.min()) / max(np.ptp(t), 1e-6))[..., None]
    background = np.clip(background + rng.normal(0, 0.03, background.shape), 0, 1)
    image = np.where(view.mask[..., None], linear_to_srgb(view.image), background)
    image = cv2.GaussianBlur(image.astype(np.float32), (0, 0), 0.6)  # a lens, not aliased edges
    landmarks = project(posed[model.tensor("landmark_indices", torch.int64)], torch.eye(3), torch.zeros(3), camera)
    return (np.clip(image, 0, 1) * 255).round().astype(np.uint8), landmarks.numpy().astype(np.float32), camera


def make_synthetic_faces(out_dir: str | Path, count: int, model: MorphableModel, size: int = 256, seed: int = 0,
                         max_yaw: float = 75.0, progress: bool = False, sigma_id: float = 0.8,
                         expressions: float = 0.1) -> Path:
    """Render ``count`` random faces into ``out_dir`` (written atomically) with their ground
    truth in ``faces.npz``; returns ``out_dir``. See the module docstring for the contents and
    :func:`random_face` for ``sigma_id`` and ``expressions``."""
    from tqdm import tqdm

    rng = np.random.default_rng(seed)
    keys = ("alpha", "delta", "beta", "gamma", "rotation", "translation")
    truth: dict[str, list] = {k: [] for k in (*keys, "names", "landmarks", "camera")}
    with StagedOutput(out_dir) as stage:
        for i in tqdm(range(count), desc="synthetic faces", unit="img", disable=not progress, leave=False):
            face = random_face(model, rng, size, max_yaw, sigma_id, expressions)
            image, landmarks, camera = render_face(model, face, size, rng)
            name = f"{i:06d}.png"
            stage.path(name).write_bytes(png_bytes(image))
            for k in keys:
                truth[k].append(face[k])
            truth["names"].append(name)
            truth["landmarks"].append(landmarks)
            truth["camera"].append(np.array([camera.focal, camera.cx, camera.cy], np.float32))
        np.savez(stage.path(TRUTH_FILE), **{k: np.array(v) for k, v in truth.items()})
    return Path(out_dir)
