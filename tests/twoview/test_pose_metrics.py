"""Pose error metrics."""

from __future__ import annotations

import numpy as np
import pytest

from skyrecon.core import Rigid3, rotvec_to_matrix
from skyrecon.errors import InputError
from skyrecon.eval.pose_metrics import (
    pose_auc,
    relative_pose_errors,
    rotation_error_deg,
    translation_direction_error_deg,
)


def test_rotation_error():
    R = rotvec_to_matrix([0.3, -0.2, 0.1])
    assert rotation_error_deg(R, R) == pytest.approx(0.0, abs=1e-12)
    d = rotvec_to_matrix(np.radians(0.001) * np.array([0, 0, 1.0]))
    assert rotation_error_deg(d @ R, R) == pytest.approx(0.001, rel=1e-6)  # accurate for tiny angles
    assert rotation_error_deg(rotvec_to_matrix([np.pi, 0, 0]), np.eye(3)) == pytest.approx(180.0)


def test_translation_direction_error():
    assert translation_direction_error_deg([1, 0, 0], [2, 0, 0]) == pytest.approx(0.0)
    assert translation_direction_error_deg([1, 0, 0], [-1, 0, 0]) == pytest.approx(180.0)
    assert translation_direction_error_deg([1, 0, 0], [1, 1, 0]) == pytest.approx(45.0)
    with pytest.raises(InputError):
        translation_direction_error_deg([0, 0, 0], [1, 0, 0])
    a = Rigid3(rotvec_to_matrix([0, 0.01, 0]), [1, 0, 0])
    b = Rigid3(np.eye(3), [1, 0.01, 0])
    r, t = relative_pose_errors(a, b)
    assert r == pytest.approx(np.degrees(0.01)) and t == pytest.approx(np.degrees(np.arctan(0.01)))


def test_auc():
    assert pose_auc(np.zeros(10)) == pytest.approx([1.0, 1.0, 1.0])
    assert pose_auc(np.full(10, 100.0)) == pytest.approx([0.0, 0.0, 0.0])
    assert 0 < pose_auc(np.array([1.0, 3.0, 30.0]))[0] < 1
