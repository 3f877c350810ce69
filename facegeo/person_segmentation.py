"""Person vs background in a photo: MediaPipe's selfie segmentation, run offline with LiteRT.

One bundled model (``assets/mediapipe``, Apache-2.0, extracted from the ``mediapipe==0.10.14``
wheel by ``assets/mediapipe/extract_mediapipe_models.py``), run through the loader of
:mod:`facegeo.landmarks.mediapipe_mesh`:

``selfie_segmentation.tflite`` -- the general (square) selfie segmentation model
    Input (1, 256, 256, 3) float32 RGB in [0, 1]: the whole photo resized to 256² without
    keeping its aspect ratio (MediaPipe's ``selfie_segmentation_cpu`` graph: ImageToTensor with
    ``keep_aspect_ratio: false`` and the range [0, 1]). Output (1, 256, 256, 1), the probability
    that a pixel shows a person (the model ends in a sigmoid), resized back to the photo
    bilinearly.

Its classes are a person and the rest: hair, glasses, clothing and hands are "person", so the
skin mask (:mod:`facegeo.skin_mask`) uses it only to keep the background (walls, flags, car
interiors, skies) out of the face's texture, where a background of the skin's colour passes the
skin-colour model.
"""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np

from facegeo.landmarks.mediapipe_mesh import MediaPipeFaceMesh, _check_image, _Model

__all__ = ["PersonSegmenter", "default_person_segmenter", "SEGMENTATION_ASSET", "SEGMENTATION_SIZE"]

SEGMENTATION_ASSET = "mediapipe/selfie_segmentation.tflite"
#: The model's square input side in pixels.
SEGMENTATION_SIZE = 256


class PersonSegmenter:
    """The selfie segmentation model on one RGB photo (loaded on first use; ``path`` defaults to
    the bundled model)."""

    def __init__(self, path: str | Path | None = None, *, num_threads: int | None = 1):
        self.path = None if path is None else Path(path)
        self.num_threads = num_threads
        self._model: _Model | None = None

    @property
    def model(self) -> _Model:
        if self._model is None:
            size = SEGMENTATION_SIZE
            self._model = _Model(self.path or MediaPipeFaceMesh._asset(SEGMENTATION_ASSET), (1, size, size, 3),
                                 {"person": (1, size, size, 1)}, self.num_threads)
        return self._model

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """(H, W) float32 probability in [0, 1] that each pixel of the (H, W, 3) uint8 RGB photo
        shows a person (the subject, their hair, clothes, glasses, hands)."""
        _check_image(image)
        H, W = image.shape[:2]
        size = SEGMENTATION_SIZE
        shrink = cv2.INTER_AREA if min(H, W) >= size else cv2.INTER_LINEAR
        tensor = cv2.resize(image, (size, size), interpolation=shrink).astype(np.float32)[None] / np.float32(255.0)
        person = self.model(tensor)["person"][0, ..., 0]
        return np.clip(cv2.resize(person, (W, H), interpolation=cv2.INTER_LINEAR), 0.0, 1.0).astype(np.float32)


@functools.cache
def default_person_segmenter() -> PersonSegmenter:
    """The shared :class:`PersonSegmenter` with the bundled model (loaded once per process)."""
    return PersonSegmenter()
