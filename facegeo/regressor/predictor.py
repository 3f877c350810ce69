"""Checkpoints and inference: ``facegeo.regressor.load(ckpt)`` -> a :class:`Predictor` whose
output is a :class:`facegeo.Fit`.

A checkpoint is one ``torch.save`` file (read back with ``weights_only=True``: tensors, numbers,
strings, lists and dicts only) holding the config, both backbones' transformers configs (so no
weights folder is needed to load it), the morphable model's :class:`ModelSignature`, the network
state and, for training runs, the optimiser state, step counters and RNG states.
"""

from __future__ import annotations

import dataclasses
import io
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from facegeo.camera import Camera, project
from facegeo.errors import InputError
from facegeo.torch_checkpoint import read_torch_file
from facegeo.fitting import Fit
from facegeo.fitting.photo_fit import observe_photo
from facegeo.landmarks.detectors import LandmarkDetector
from facegeo.model_files import load_model
from facegeo.morphable_model import MorphableModel
from facegeo.photo import Photo
from facegeo.regressor.config import RegressorConfig
from facegeo.regressor.data import crop_box, crop_face
from facegeo.regressor.losses import slide_jaw
from facegeo.regressor.network import ModelSignature, MSSFRegressor
from facegeo.staged_output import atomic_write_bytes

__all__ = ["CHECKPOINT_FORMAT", "save_checkpoint", "read_checkpoint", "network_from_checkpoint", "Predictor", "load"]

CHECKPOINT_FORMAT = "facegeo-regressor/2"  # 2: δ projected, not a sigmoid (a /1 head decodes differently)


def save_checkpoint(path: str | Path, network: MSSFRegressor, config: RegressorConfig, **extra: Any) -> Path:
    """Write ``network`` (+ ``extra`` entries: optimizer, step, ...) to ``path`` atomically."""
    convnext, dino = network.backbone_configs()
    payload = {"format": CHECKPOINT_FORMAT, "config": config.to_dict(), "convnext_config": convnext,
               "dino_config": dino, "signature": network.signature.to_dict(), "state_dict": network.state_dict(), **extra}
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return atomic_write_bytes(path, buffer.getvalue())


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint's dict; :class:`InputError` naming the file when it is missing, truncated
    or not a facegeo regressor checkpoint."""
    payload = read_torch_file(path, "regressor checkpoint")
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        found = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise InputError(Path(path), "format", CHECKPOINT_FORMAT, repr(found))
    return payload


def network_from_checkpoint(payload: dict[str, Any], source: str | Path,
                            model: MorphableModel | None = None) -> tuple[MSSFRegressor, RegressorConfig]:
    """Rebuild the network of a :func:`read_checkpoint` payload; with ``model`` given, its
    coefficient counts must match the checkpoint's (else :class:`InputError`)."""
    config = RegressorConfig.from_dict(payload["config"], str(source))
    sig = ModelSignature(**{k: tuple(v) if isinstance(v, list) else v for k, v in payload["signature"].items()})
    if model is not None:
        mine = ModelSignature.of(model)
        for field in ("n_id", "n_exp", "n_tex", "n_vertices"):
            if getattr(mine, field) != getattr(sig, field):
                raise InputError(source, f"signature.{field}", f"{getattr(mine, field)} (the model {model.name!r})",
                                 f"{getattr(sig, field)} (trained for {sig.name!r})")
    network = MSSFRegressor(config.network, sig, payload["convnext_config"], payload["dino_config"] or False)
    try:
        network.load_state_dict(payload["state_dict"])
    except RuntimeError as exc:
        raise InputError(source, "state_dict", "weights matching the stored configs", str(exc).splitlines()[0]) from None
    network.eval()
    return network, config


class Predictor:
    """A trained regressor for one morphable model. Call it like :func:`facegeo.fit`.

    Args:
        network: the trained :class:`MSSFRegressor`. model: the morphable model it was trained
        for. config: its :class:`RegressorConfig`. detector: landmark detector for the crop
        (and the reported landmark errors) when no landmarks are given. source: the checkpoint.
        refine: also run the analysis-by-synthesis fit (:func:`facegeo.fit`) started from the
        prediction, on the same landmarks and in the same camera.
    """

    def __init__(self, network: MSSFRegressor, model: MorphableModel, config: RegressorConfig,
                 detector: str | LandmarkDetector = "hybrid", source: str = "<memory>", refine: bool = False):
        self.network, self.model, self.config, self.detector, self.source = network.eval(), model, config, detector, source
        self.refine = refine

    def __call__(self, image: np.ndarray | str | Path | Photo, model: MorphableModel | None = None,
                 landmarks: np.ndarray | None = None, detector: str | LandmarkDetector | None = None,
                 camera: Camera | None = None, photometric: bool = True) -> Fit:
        """Predict χ for one photo and return it as a :class:`Fit`.

        Args:
            image: (H, W, 3) uint8 RGB, a path or a :class:`Photo`.
            model: must be the predictor's model (or None); another gives :class:`InputError`.
            landmarks: (88, 2) px to crop around and report errors against (else detected).
            detector: overrides the predictor's detector.
            camera: the photo's intrinsics (default: an unknown focal, :meth:`Camera.unknown_focal`,
                as :func:`facegeo.fit` takes it). A camera whose focal is not known (``focal_known``
                False) gets the focal :func:`facegeo.fit` would estimate from the same landmarks
                (:func:`~facegeo.fitting.camera_estimate.camera_for_face`), once, before the
                prediction: the photo, landmarks and camera come from the fit's own front door,
                :func:`facegeo.fitting.photo_fit.observe_photo`.
            photometric: with ``refine``, run the fit's photometric stage (the prediction itself
                always includes β and γ).
        Returns:
            A :class:`Fit` in the camera it was predicted with (``Fit.camera``: for an unknown
            focal the estimated one, ``focal_known`` still False, and the estimate's note in
            ``info["notes"]``, as :func:`facegeo.fit` reports it); ``info["fitter"]`` is
            ``"regressor"`` or ``"regressor+refine"`` (refined in the same camera); timings
            ``detect``, ``regress`` (and the fit's with ``refine``).
        """
        if model is not None and model is not self.model and ModelSignature.of(model) != self.network.signature:
            raise InputError(self.source, "model", f"the model the regressor was trained for ({self.network.signature.name})", model.name)
        # the fit's front door: given landmarks checked, the photo loaded, the landmarks detected, the one camera default
        seen = observe_photo(image, self.model, landmarks, detector or self.detector, camera, dense=None)
        timings = {name: seen.timings[name] for name in ("detect",) if name in seen.timings}
        notes, source, pixels, camera, targets = list(seen.notes), seen.source, seen.pixels, seen.camera, seen.landmarks
        detector_name = seen.detection.detector if seen.detection is not None else "given"
        t0 = time.perf_counter()
        size = self.config.network.image_size
        x0, y0, side = crop_box(targets, self.config.network.crop_scale)
        crop = crop_face(pixels, (x0, y0, side), size)
        s = size / side
        intrinsics = torch.tensor([[camera.focal * s, (camera.cx - x0) * s, (camera.cy - y0) * s]], dtype=torch.float32)
        with torch.no_grad():
            batch = torch.from_numpy(crop.astype(np.float32).transpose(2, 0, 1) / 255.0)[None]
            p = {k: v[0] for k, v in self.network.predict(batch, intrinsics).items()}
            shape = self.model.shape(p["alpha"], p["delta"])
            posed = shape @ p["rotation"].T + p["translation"]
            uv = project(posed, torch.eye(3), torch.zeros(3), camera)
            fitted = slide_jaw(posed[None], self.model.landmark_indices, torch.from_numpy(targets).float()[None], camera)[0].double().numpy()
        timings["regress"] = time.perf_counter() - t0
        errors = np.linalg.norm(fitted - targets, axis=1)
        valid = np.isfinite(errors)
        nearest = self.model.landmark_indices.copy()  # the jaw points' slid correspondences: nearest contour vertex
        jaw = nearest[:17]
        nearest[:17] = jaw[np.argmin(((uv.numpy()[jaw][None] - fitted[:17, None]) ** 2).sum(-1), axis=1)]
        f32 = lambda t: t.numpy().astype(np.float32)  # noqa: E731
        prediction = Fit(
            alpha=f32(p["alpha"]), delta=f32(p["delta"]), beta=f32(p["beta"]), gamma=f32(p["gamma"]),
            rotation=f32(p["rotation"]), translation=f32(p["translation"]), camera=camera,
            vertices=f32(posed), shape_vertices=f32(shape), landmarks=targets.astype(np.float32),
            landmarks_fitted=fitted.astype(np.float32), landmark_vertices=nearest.astype(np.int64),
            landmark_errors_px=errors.astype(np.float32),
            landmark_rms_px=float(np.sqrt(np.mean(errors[valid] ** 2))) if valid.any() else 0.0,
            timings=timings,
            info={"fitter": "regressor", "checkpoint": self.source, "source": source, "model": self.model.name,
                  "detector": detector_name, "notes": notes, "valid_landmarks": int(valid.sum())},
        )
        return self._refined(prediction, seen.image, photometric) if self.refine else prediction

    def _refined(self, prediction: Fit, image: np.ndarray | Photo, photometric: bool) -> Fit:
        """The analysis-by-synthesis fit on the prediction's landmarks, started from the prediction
        and in its camera: the fit is handed that camera as known, so it estimates no focal of its
        own, and the refined fit reports ``prediction.camera`` (``focal_known`` as predicted)."""
        from facegeo import fitting

        notes = list(prediction.info["notes"])
        result = fitting.fit(image, model=self.model, landmarks=prediction.landmarks,
                             camera=dataclasses.replace(prediction.camera, focal_known=True),
                             photometric=photometric, init=prediction)
        result = dataclasses.replace(result, camera=prediction.camera, timings={**prediction.timings, **result.timings})
        result.info.update(fitter="regressor+refine", checkpoint=self.source, detector=prediction.info["detector"],
                           notes=notes + [n for n in result.info.get("notes", []) if n not in notes],
                           regressor_landmark_rms_px=prediction.landmark_rms_px)
        return result


def load(checkpoint: str | Path, model: MorphableModel | str | Path | None = None,
         detector: str | LandmarkDetector = "hybrid", refine: bool = False) -> Predictor:
    """Load a trained regressor. ``model``: the morphable model (or its file; default: the
    bundled one); its counts must match the checkpoint's. Errors name the checkpoint file and
    come before any image is read. ``refine``: see :class:`Predictor`."""
    payload = read_checkpoint(checkpoint)
    if not isinstance(model, MorphableModel):
        model = load_model(model)
    network, config = network_from_checkpoint(payload, checkpoint, model)
    return Predictor(network, model, config, detector, str(checkpoint), refine)
