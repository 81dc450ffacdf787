"""A prediction names the fixed parameters its held-out score sees and the fitting data cannot
(fgcal.calibration.blind_spots): the linear algebra on a small case, and a validation tracker
beside a kind that cannot see the whole robot."""

from __future__ import annotations

import numpy as np

from fgcal.calibration.blind_spots import STEPS, blind_spots, describe


def test_a_column_the_released_ones_span_is_not_a_blind_spot_and_one_outside_is():
    rng = np.random.default_rng(0)
    J_released = rng.normal(size=(30, 4))
    inside = J_released @ np.array([1.0, -2.0, 0.5, 0.0])  # sx2 against alpha1: the same effect
    outside = rng.normal(size=30)
    J_fixed = np.column_stack([inside, outside, np.zeros(30)])  # the last: no effect at all
    spots = blind_spots(J_released, J_fixed, ["d5", "theta5", "tool.tx"])
    assert [s.name for s in spots] == ["theta5"]
    Q, _ = np.linalg.qr(J_released)
    left = outside - Q @ (Q.T @ outside)
    expected = np.sqrt(np.mean(np.sum(left.reshape(-1, 3) ** 2, axis=1))) * STEPS["angle"]
    assert np.isclose(spots[0].effect_rms_m, expected, rtol=1e-12)
    assert "theta5 (0.1 mrad: " in describe(spots)


def test_nothing_released_leaves_every_effect_whole():
    J_fixed = np.ones((6, 1))
    (spot,) = blind_spots(np.zeros((6, 0)), J_fixed, ["a2"])
    assert np.isclose(spot.effect_rms_m, np.sqrt(3.0) * STEPS["length"])
