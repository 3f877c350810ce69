"""Filters that run along a clip's frames (axis 0 of an (N, C) array): a running median and a
Savitzky–Golay filter, with SciPy's edge rules (``scipy.ndimage.median_filter(mode="nearest")``,
``scipy.signal.savgol_filter(mode="interp")``).

Written with NumPy because importing ``scipy.signal`` costs about 0.45 s (its package loads
scipy.stats, scipy.interpolate and the window functions) and ``scipy.ndimage`` 0.15 s, in the
serial tail of ``facegeo track`` (a 10 s command for 300 frames, benchmarks/RESULTS.md); both
filters are a few lines, and tests/test_running_filters.py checks them against SciPy's.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

__all__ = ["running_median", "savitzky_golay"]


def running_median(values: np.ndarray, window: int) -> np.ndarray:
    """(N, C) float64: each row the median of the ``window`` (odd, ≥ 1) rows centred on it, of
    ``values`` (N, C) (any real dtype), the first and last rows repeated beyond the ends (SciPy's
    ``median_filter(values, size=(window, 1), mode="nearest")``, the same values)."""
    values = np.asarray(values, np.float64)
    _check_window(window, 0)
    half = window // 2
    padded = np.pad(values, ((half, half), (0, 0)), mode="edge")
    return np.median(sliding_window_view(padded, window, axis=0), axis=-1)


def savitzky_golay(values: np.ndarray, window: int, order: int) -> np.ndarray:
    """(N, C) float64: ``values`` (N, C, N ≥ ``window``) smoothed by a Savitzky–Golay filter of
    ``window`` (odd) rows and polynomial ``order`` (< ``window``): each row the value at its
    centre of the polynomial fitted by least squares to the window around it; the first and last
    ``window // 2`` rows the values of the polynomial fitted to the first (last) window (SciPy's
    ``savgol_filter(values, window, order, axis=0, mode="interp")``, equal to rounding)."""
    values = np.asarray(values, np.float64)
    _check_window(window, order)
    if len(values) < window:
        raise ValueError(f"savitzky_golay: expected at least {window} rows, got {len(values)}")
    half = window // 2
    design = np.vander(np.arange(-half, half + 1, dtype=np.float64), order + 1, increasing=True)  # (window, order + 1)
    fit = np.linalg.pinv(design)  # (order + 1, window): a window's least-squares polynomial coefficients
    out = np.empty_like(values)
    out[half:len(values) - half] = sliding_window_view(values, window, axis=0) @ fit[0]
    if half:
        out[:half] = design[:half] @ (fit @ values[:window])
        out[len(values) - half:] = design[half + 1:] @ (fit @ values[len(values) - window:])
    return out


def _check_window(window: int, order: int) -> None:
    if window < 1 or window % 2 == 0 or not 0 <= order < window:
        raise ValueError(f"expected an odd window ≥ 1 above the order, got window {window}, order {order}")
