"""REALY's alignment: a global similarity on 7 keypoints, then a rigid ICP per region.

Written from the protocol of the official REALY code (github czh-98/REALY, ``utils/gICP.py``,
``utils/rICP.py``, ``utils/util.py``). Each step keeps the official arithmetic where it changes a
number: which arrays are float32, the order of the reductions, and NumPy 1's scalar casting
(the official code ran under NumPy < 2, where a float32 array times a float64 scalar stays
float32).

* :func:`fit_transform`: rotation ``U @ Vt`` from the SVD of the cross-covariance (no reflection
  fix); the scale, when asked for, is ``sum|target - mean| / sum|R (source - mean)|`` (REALY's
  rule, not Umeyama's); the translation is the mean of ``target - s R source``.
* :func:`global_alignment`: that similarity on keypoints 36, 39, 42, 45 (eye corners), 33 (nose
  bottom), 48, 54 (mouth corners), applied to the whole prediction (scaled in float32).
* :func:`regional_icp`: per region, ICP between the scan region's vertices (and the region's
  keypoints, repeated ``int(n_scan / n_keypoints)`` times, a quarter of that for the cheek) and
  their closest points on the prediction; it stops when the float32 mean squared residual
  changes by less than 1e-6 or after 100 updates, and the transform of the stopping iteration
  is not applied.
"""

from __future__ import annotations

import numpy as np

from facegeo.eval.realy_geometry import SurfaceQuery
from facegeo.eval.realy_settings import EXACT, Settings

__all__ = [
    "SEVEN_KEYPOINTS",
    "RIGID_KEYPOINTS",
    "ERROR_KEYPOINTS",
    "REGIONS",
    "fit_transform",
    "global_alignment",
    "regional_icp",
]

_FOREHEAD = (36, 37, 38, 39, 40, 41, 42, 43, 44, 45, 46, 47, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26)
_MOUTH = (48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 60, 64)
_NOSE = (27, 28, 29, 30, 31, 32, 33, 34, 35)
_NOSE_RIGID = (27, 28, 29, 30, 31, 35, 32, 33, 34, 70, 71)
_CHEEK = (48, 49, 50, 51, 52, 53, 54, 55, 56, 57, 58, 59, 60, 64, 76, 77, 36, 41, 40, 39, 42, 47, 46, 45, 7, 8, 9)

#: Keypoints of the global similarity alignment.
SEVEN_KEYPOINTS = (36, 39, 42, 45, 33, 48, 54)
#: Keypoints of each region's rigid ICP (the nose uses a wider set than in the error step).
RIGID_KEYPOINTS = {"forehead": _FOREHEAD, "mouth": _MOUTH, "nose": _NOSE_RIGID, "cheek": _CHEEK}
#: Keypoints of each region's non-rigid ICP in the error step (none for the cheek).
ERROR_KEYPOINTS = {"nose": _NOSE, "mouth": _MOUTH, "forehead": _FOREHEAD, "cheek": None}
#: Regions in the order of the output columns.
REGIONS = ("nose", "mouth", "forehead", "cheek")
#: Order in which the official code runs the regional ICPs (it does not change the numbers).
ICP_ORDER = ("forehead", "mouth", "nose", "cheek")


def fit_transform(source: np.ndarray, target: np.ndarray, with_scale: bool) -> tuple[float, np.ndarray, np.ndarray]:
    """(scale, R (3, 3), t (3,)) taking ``source`` (n, 3) onto ``target`` (n, 3), REALY's way.

    The arrays keep their dtypes (the official code mixes float64 sources with float32 targets)
    and are reduced in the official memory layout, so that float32 sums round the same way.
    """
    n = source.shape[0]
    src = source.T  # (3, n) views of (n, 3) rows, as the official code passes them
    tgt = target.T
    mean_s = np.mean(src, 1)
    mean_t = np.mean(tgt, 1)
    s1 = src - np.tile(mean_s, (n, 1)).T
    t1 = tgt - np.tile(mean_t, (n, 1)).T
    u, _, vt = np.linalg.svd(t1.dot(s1.T))
    rotation = u.dot(vt)
    scale = np.sum(np.abs(t1)) / np.sum(np.abs(rotation.dot(s1))) if with_scale else 1.0
    translation = np.mean(tgt - scale * rotation.dot(src), 1)
    return scale, rotation, translation


def global_alignment(vertices: np.ndarray, keypoints: np.ndarray, scan_keypoints: np.ndarray) -> np.ndarray:
    """The prediction (float32 (V, 3)) aligned by REALY's 7-point similarity: float64 (V, 3).

    ``keypoints`` are the prediction's 85 keypoints (float64), ``scan_keypoints`` the scan's
    (float32, from REALY_HIFI3D_keypoints).
    """
    idx = list(SEVEN_KEYPOINTS)
    scale, rotation, translation = fit_transform(keypoints[idx], scan_keypoints[idx], with_scale=True)
    # NumPy 1 (the official environment): float32 array * float64 scalar is computed in float32
    scaled = vertices * np.asarray(scale, dtype=vertices.dtype)
    return np.matmul(scaled, rotation.T) + translation


def regional_icp(
    vertices: np.ndarray,
    surface: SurfaceQuery,
    scan_vertices: np.ndarray,
    keypoints: np.ndarray,
    scan_keypoints: np.ndarray,
    region: str,
    settings: Settings = EXACT,
) -> tuple[np.ndarray, int]:
    """Rigid ICP of the globally aligned prediction onto one scan region.

    ``vertices`` (V, 3) float64 from :func:`global_alignment`; ``surface`` the closest-point
    query of the prediction's triangles; ``scan_vertices`` (N, 3) float32 as
    read from the region file (all of its vertices); ``keypoints`` / ``scan_keypoints`` the
    region's keypoint subsets (prediction float64, scan float32); ``settings`` its stopping
    rule (``rigid_tolerance``, ``rigid_max_updates``). Returns the aligned vertices
    (float32 after at least one update, else the input) and the number of updates applied.
    """
    per = scan_vertices.shape[0] / scan_keypoints.shape[0]
    if region == "cheek":
        per = per / 4
    repeat = int(per)
    if repeat < 1:
        raise ValueError(f"the {region} region has fewer vertices than its {scan_keypoints.shape[0]} keypoints")
    kp_pred = np.vstack([keypoints] * repeat)
    target = np.vstack((scan_vertices, np.vstack([scan_keypoints] * repeat)))
    queries = scan_vertices.astype(np.float64)
    previous = None
    updates = 0
    while True:
        on_prediction = surface(vertices, queries)
        source = np.vstack((on_prediction, kp_pred))
        _, rotation, translation = fit_transform(source, target, with_scale=False)
        moved = (np.matmul(source, rotation.T) + translation).astype(np.float32)
        error = np.sum((moved - target) ** 2, axis=1).mean()  # float32, as in the official code
        # NumPy 1 scalar rules: float32 - 0.0 is float64; float32 - float32 stays float32;
        # the comparison with 1e-6 is made in float64
        change = abs(float(error)) if previous is None else float(abs(error - previous))
        if change < settings.rigid_tolerance or updates >= settings.rigid_max_updates:
            break
        updates += 1
        previous = error
        vertices = (np.matmul(vertices, rotation.T) + translation).astype(np.float32)
        kp_pred = (np.matmul(kp_pred, rotation.T) + translation).astype(np.float32)
    return vertices, updates
