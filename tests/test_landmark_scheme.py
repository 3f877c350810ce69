"""The 88-point scheme: mirror table, weights and loss."""

import numpy as np
import pytest
import torch

from facegeo.landmarks import scheme
from facegeo.landmarks.scheme import (
    IBUG68,
    HYBRID_MIRROR,
    IBUG_MIRROR,
    LANDMARK_WEIGHTS,
    LIP_POINTS,
    landmark_loss,
)


def test_named_groups_partition_the_ibug_points_and_mirror_onto_each_other():
    parts = [scheme.JAW, scheme.RIGHT_BROW, scheme.LEFT_BROW, scheme.NOSE_BRIDGE, scheme.NOSTRILS, scheme.RIGHT_EYE,
             scheme.LEFT_EYE, scheme.OUTER_LIP, scheme.INNER_LIP]
    np.testing.assert_array_equal(np.sort(np.concatenate(parts)), IBUG68)
    np.testing.assert_array_equal(np.concatenate([scheme.RIGHT_BROW, scheme.LEFT_BROW]), scheme.BROWS)
    np.testing.assert_array_equal(np.concatenate([scheme.RIGHT_EYE, scheme.LEFT_EYE]), scheme.EYES)
    np.testing.assert_array_equal(np.concatenate([scheme.NOSE_BRIDGE, scheme.NOSTRILS]), scheme.NOSE)
    np.testing.assert_array_equal(np.concatenate([scheme.OUTER_LIP, scheme.INNER_LIP]), scheme.MOUTH)
    np.testing.assert_array_equal(np.setdiff1d(IBUG68, scheme.JAW), scheme.INNER_FACE)
    assert sorted(IBUG_MIRROR[scheme.RIGHT_EYE]) == list(scheme.LEFT_EYE)
    assert sorted(IBUG_MIRROR[scheme.RIGHT_BROW]) == list(scheme.LEFT_BROW)
    assert list(IBUG_MIRROR[scheme.OUTER_EYE_CORNERS]) == list(scheme.OUTER_EYE_CORNERS[::-1])
    assert list(IBUG_MIRROR[scheme.JAW_ENDS]) == list(scheme.JAW_ENDS[::-1]) and IBUG_MIRROR[scheme.CHIN] == scheme.CHIN
    assert len(LIP_POINTS) == len(scheme.MOUTH) and scheme.N_IBUG == 68


def test_mirror_tables_are_involutions():
    for table, n in ((IBUG_MIRROR, 68), (HYBRID_MIRROR, 88)):
        assert sorted(table) == list(range(n))
        np.testing.assert_array_equal(table[table], np.arange(n))
    # fixed points: chin, nose bridge and tip, lip centres
    assert {int(i) for i in np.flatnonzero(IBUG_MIRROR == np.arange(68))} == {8, 27, 28, 29, 30, 33, 51, 57, 62, 66}


def test_lip_points_weighted_up_and_symmetric():
    assert LANDMARK_WEIGHTS[LIP_POINTS].min() > LANDMARK_WEIGHTS[IBUG68].max()
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
