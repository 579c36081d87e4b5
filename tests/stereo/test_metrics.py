import numpy as np
import pytest

from skyrecon.errors import InputError
from skyrecon.eval.stereo_metrics import evaluate_disparity


def test_hand_made_errors_and_missing_predictions():
    gt = np.array([[10.0, 10.0, 10.0, 100.0, np.nan]])
    pred = np.array([[10.5, 11.5, np.nan, 104.0, 3.0]])
    m = evaluate_disparity(pred, gt)
    # scored: 4 pixels (the NaN gt is ignored); errors 0.5, 1.5, missing, 4.0
    assert m["n_gt"] == 4
    assert m["bad1"] == pytest.approx(3 / 4)  # 1.5, missing, 4.0
    assert m["bad2"] == pytest.approx(2 / 4)  # missing, 4.0
    # D1: > 3 px and > 5 %: 4.0 px on 100 is 4 % -> not an outlier; missing counts
    assert m["d1"] == pytest.approx(1 / 4)
    assert m["epe"] == pytest.approx((0.5 + 1.5 + 4.0) / 3)
    assert m["density"] == pytest.approx(3 / 4)


def test_d1_needs_both_conditions():
    gt = np.array([[10.0, 100.0, 100.0]])
    pred = np.array([[13.5, 103.5, 106.0]])  # 3.5 px = 35 %; 3.5 px = 3.5 %; 6 px = 6 %
    m = evaluate_disparity(pred, gt)
    assert m["d1"] == pytest.approx(2 / 3)


def test_perfect_prediction_and_mask():
    gt = np.arange(12, dtype=np.float64).reshape(3, 4)
    m = evaluate_disparity(gt.copy(), gt)
    assert m["bad1"] == 0 and m["bad2"] == 0 and m["d1"] == 0 and m["epe"] == 0 and m["density"] == 1
    pred = gt.copy()
    pred[0, 0] = np.nan
    mask = np.ones_like(gt, bool)
    mask[0, 0] = False
    assert evaluate_disparity(pred, gt, mask)["bad1"] == 0
    assert evaluate_disparity(pred, gt)["bad1"] == pytest.approx(1 / 12)


def test_infinite_prediction_is_missing_and_empty_gt():
    gt = np.array([[5.0, 5.0]])
    m = evaluate_disparity(np.array([[np.inf, 5.0]]), gt)
    assert m["density"] == 0.5 and m["bad1"] == 0.5
    empty = evaluate_disparity(np.zeros((2, 2)), np.full((2, 2), np.nan))
    assert empty["n_gt"] == 0 and np.isnan(empty["bad1"])


def test_shape_errors():
    with pytest.raises(InputError, match="ground truth"):
        evaluate_disparity(np.zeros((2, 3)), np.zeros((3, 2)))
    with pytest.raises(InputError):
        evaluate_disparity(np.zeros(4), np.zeros(4))
    with pytest.raises(InputError, match="valid_gt"):
        evaluate_disparity(np.zeros((2, 2)), np.zeros((2, 2)), np.ones((3, 3), bool))
