"""The learned regressor of Sec. 3.2: the MSSF encoder (trainable ConvNeXt V2 + frozen DINOv3),
its self-supervised objective, training, synthetic training faces and inference.

Needs the optional extra ``pip install facegeo[regressor]`` (transformers); nothing else in
facegeo imports this package. Names are imported lazily.

    predictor = facegeo.regressor.load("run/best.pt")   # -> Predictor
    fit = predictor("photo.jpg")                          # -> facegeo.Fit
    asset, fit = facegeo.pipeline.reconstruct_with_fit("photo.jpg", fitter=predictor)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from facegeo.lazy_exports import lazy_exports

_EXPORTS = {
    "RegressorConfig": "facegeo.regressor.config",
    "NetworkConfig": "facegeo.regressor.config",
    "LossConfig": "facegeo.regressor.config",
    "TrainConfig": "facegeo.regressor.config",
    "load_config": "facegeo.regressor.config",
    "MSSFRegressor": "facegeo.regressor.network",
    "ModelSignature": "facegeo.regressor.network",
    "Objective": "facegeo.regressor.losses",
    "train": "facegeo.regressor.training",
    "evaluate": "facegeo.regressor.training",
    "make_synthetic_faces": "facegeo.regressor.synthetic",
    "Predictor": "facegeo.regressor.predictor",
    "load": "facegeo.regressor.predictor",
    "save_checkpoint": "facegeo.regressor.predictor",
}

__all__ = list(_EXPORTS)

if TYPE_CHECKING:
    from facegeo.regressor.config import LossConfig, NetworkConfig, RegressorConfig, TrainConfig, load_config
    from facegeo.regressor.losses import Objective
    from facegeo.regressor.network import ModelSignature, MSSFRegressor
    from facegeo.regressor.predictor import Predictor, load, save_checkpoint
    from facegeo.regressor.synthetic import make_synthetic_faces
    from facegeo.regressor.training import evaluate, train


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
