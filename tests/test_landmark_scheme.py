"""The 88-point scheme: mirror table, weights and loss."""

import numpy as np
import pytest
import torch

from facegeo.landmarks.scheme import (
    HYBRID_MIRROR,
    IBUG_MIRROR,
    LANDMARK_WEIGHTS,
    LIP_POINTS,
    landmark_loss,
)


def test_mirror_tables_are_involutions():
    for table, n in ((IBUG_MIRROR, 68), (HYBRID_MIRROR, 88)):
        assert sorted(table) == list(range(n))
        np.testing.assert_array_equal(table[table], np.arange(n))
    # fixed points: chin, nose bridge and tip, lip centres
    assert {int(i) for i in np.flatnonzero(IBUG_MIRROR == np.arange(68))} == {8, 27, 28, 29, 30, 33, 51, 57, 62, 66}


def test_lip_points_weighted_up_and_symmetric():
    assert LANDMARK_WEIGHTS[LIP_POINTS].min() > LANDMARK_WEIGHTS[:68].max()
    np.testing.assert_array_equal(LANDMARK_WEIGHTS, LANDMARK_WEIGHTS[HYBRID_MIRROR])


def test_loss_known_value_and_nan_rows():
    target = torch.zeros(88, 2)
    pred = torch.zeros(88, 2)
    pred[:, 0] = 2.0  # every point 2 px off
    assert float(landmark_loss(pred, target, scale=2.0)) == pytest.approx(1.0)
    target[5] = float("nan")
    pred[5] = 1e6  # ignored with its NaN target
    assert float(landmark_loss(pred, target, scale=2.0)) == pytest.approx(1.0)
    uniform = torch.ones(88)
    pred[10, 1] = 2.0  # one point now off by √8: (87·4 + 8)/87 over the valid points
    value = float(landmark_loss(pred, target, uniform, scale=1.0))
    assert value == pytest.approx((86 * 4 + 8) / 87)
