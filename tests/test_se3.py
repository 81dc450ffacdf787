"""Rigid-body helpers: rotation vector and roll-pitch-yaw round trips, gimbal lock included."""

from __future__ import annotations

import numpy as np
import pytest

from fgcal.core.se3 import pose_from_xyz_rpy, rot_axis, rpy_from_rotation, so3_exp, so3_log


def test_rpy_round_trip_random():
    rng = np.random.default_rng(0)
    for _ in range(200):
        R = so3_exp(rng.normal(0, 2.0, 3))
        np.testing.assert_allclose(pose_from_xyz_rpy(np.zeros(3), rpy_from_rotation(R))[:3, :3], R, atol=1e-12)


@pytest.mark.parametrize("pitch", [np.pi / 2, -np.pi / 2])
def test_rpy_round_trip_at_gimbal_lock(pitch):
    # A board whose x axis is vertical (the seed cell's C-y side) has pitch -90 deg.
    for roll, yaw in ((0.3, -1.1), (2.0, 0.5), (0.0, 0.0)):
        R = rot_axis("z", yaw) @ rot_axis("y", pitch) @ rot_axis("x", roll)
        np.testing.assert_allclose(pose_from_xyz_rpy(np.zeros(3), rpy_from_rotation(R))[:3, :3], R, atol=1e-12)


def test_so3_log_round_trip_near_pi():
    rng = np.random.default_rng(1)
    for angle in (1e-9, 1e-3, 1.0, np.pi - 1e-4, np.pi):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        R = so3_exp(angle * axis)
        np.testing.assert_allclose(so3_exp(so3_log(R)), R, atol=1e-9)
