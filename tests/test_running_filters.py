"""The running filters against SciPy's (``median_filter`` mode nearest, ``savgol_filter`` mode
interp) and on known answers."""

import numpy as np
import pytest
from scipy.ndimage import median_filter
from scipy.signal import savgol_filter

from facegeo.running_filters import running_median, savitzky_golay


@pytest.mark.parametrize("rows, window, order", [(rows, window, order) for rows in (5, 9, 10, 300)
                                                  for window, order in ((5, 2), (9, 2), (5, 0), (3, 1), (1, 0)) if rows >= window])
def test_savitzky_golay_equals_scipy(rows, window, order):
    values = np.random.default_rng(rows + window).normal(size=(rows, 7))
    expected = savgol_filter(values, window, order, axis=0, mode="interp")
    np.testing.assert_allclose(savitzky_golay(values, window, order), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("rows", [1, 4, 5, 300])
@pytest.mark.parametrize("window", [1, 3, 5, 9])
def test_running_median_equals_scipy(rows, window):
    values = np.random.default_rng(rows * window).normal(size=(rows, 3)).astype(np.float32)
    np.testing.assert_array_equal(running_median(values, window), median_filter(values.astype(np.float64), size=(window, 1),
                                                                                 mode="nearest"))


def test_savitzky_golay_keeps_a_polynomial_of_its_order_everywhere():
    t = np.arange(12, dtype=np.float64)[:, None]
    quadratic = 0.3 * t**2 - 2.0 * t + 1.0
    np.testing.assert_allclose(savitzky_golay(quadratic, 5, 2), quadratic, atol=1e-10)
    # a constant filter (order 0) is the window's mean inside
    ramp = np.arange(9, dtype=np.float64)[:, None]
    assert savitzky_golay(ramp, 3, 0)[4, 0] == pytest.approx(4.0)


def test_running_median_removes_a_single_frame_spike():
    values = np.zeros((9, 1))
    values[4] = 10.0
    assert not running_median(values, 3).any()


@pytest.mark.parametrize("window, order", [(4, 2), (0, 0), (5, 5)])
def test_bad_windows_are_refused(window, order):
    with pytest.raises(ValueError, match="odd window"):
        savitzky_golay(np.zeros((10, 1)), window, order)


def test_too_few_rows_are_refused():
    with pytest.raises(ValueError, match="at least 5 rows"):
        savitzky_golay(np.zeros((4, 1)), 5, 2)
