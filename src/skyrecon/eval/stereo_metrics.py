"""Disparity accuracy against ground truth (Middlebury bad-pixel rates, KITTI D1, EPE).

Disparities are (H, W) float pixels with ``x_right = x_left - d``; NaN (or +-inf) marks "no
value" in both the prediction and the ground truth.
"""

from __future__ import annotations

import numpy as np

from skyrecon.errors import InputError

__all__ = ["evaluate_disparity", "METRIC_NAMES"]

#: Keys of :func:`evaluate_disparity`'s result, in display order.
METRIC_NAMES = ("bad1", "bad2", "d1", "epe", "density", "n_gt")


def evaluate_disparity(
    pred: np.ndarray, gt: np.ndarray, valid_gt: np.ndarray | None = None
) -> dict[str, float]:
    """Score a disparity map against ground truth.

    Only pixels with ground truth count (``valid_gt``, by default where ``gt`` is finite).
    **Pixels without a prediction (NaN/inf in ``pred``) count as errors** in the bad-pixel
    and D1 rates, so a matcher cannot improve those by rejecting hard pixels; ``density``
    reports how many it predicted, and the end-point error is averaged over the predicted
    pixels only.

    Args:
        pred: (H, W) predicted disparity, pixels, NaN where none.
        gt: (H, W) ground-truth disparity, pixels, NaN where unknown.
        valid_gt: optional (H, W) bool mask of pixels to score (combined with finite ``gt``),
            e.g. a non-occluded mask.
    Returns:
        dict with fractions in [0, 1] (NaN when no pixel has ground truth):

        - ``bad1``, ``bad2``: share of scored pixels with ``|pred - gt| > 1`` (resp. 2) px or
          no prediction (Middlebury "bad 1.0 / 2.0");
        - ``d1``: KITTI D1, share with error ``> 3 px and > 5 % of gt``, or no prediction;
        - ``epe``: mean ``|pred - gt|`` over scored pixels that have a prediction, pixels;
        - ``density``: share of scored pixels that have a prediction;
        - ``n_gt``: number of scored pixels.
    Raises:
        InputError: shapes differ or the arrays are not 2-D.
    """
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.ndim != 2 or gt.ndim != 2:
        raise InputError(f"disparity maps must be 2-D (H, W), got {pred.shape} and {gt.shape}")
    if pred.shape != gt.shape:
        raise InputError(
            f"the prediction is {pred.shape[1]}x{pred.shape[0]} but the ground truth is "
            f"{gt.shape[1]}x{gt.shape[0]}; evaluate at the ground truth's resolution"
        )
    mask = np.isfinite(gt)
    if valid_gt is not None:
        valid_gt = np.asarray(valid_gt, dtype=bool)
        if valid_gt.shape != gt.shape:
            raise InputError(f"valid_gt has shape {valid_gt.shape}, expected {gt.shape}")
        mask &= valid_gt
    n = int(mask.sum())
    if n == 0:
        nan = float("nan")
        return {"bad1": nan, "bad2": nan, "d1": nan, "epe": nan, "density": nan, "n_gt": 0}
    p = pred[mask]
    g = gt[mask]
    has = np.isfinite(p)
    err = np.where(has, np.abs(p - g), np.inf)
    n_pred = int(has.sum())
    return {
        "bad1": float(np.mean(err > 1.0)),
        "bad2": float(np.mean(err > 2.0)),
        "d1": float(np.mean((err > 3.0) & (err > 0.05 * np.abs(g)))),
        "epe": float(err[has].mean()) if n_pred else float("nan"),
        "density": n_pred / n,
        "n_gt": n,
    }
