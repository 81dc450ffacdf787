"""Drift alarms: is a parameter's recent change more than the model allows?

Between the estimate ``p_ref`` (sigma ``s_ref``) of ``lag`` images ago and the current one
``p_now`` (sigma ``s_now``), a linear-Gaussian filter whose model holds (random walk of
variance ``q`` per cycle, k cycles in between) moves each parameter by an increment with
variance ``s_ref^2 + k q - s_now^2`` (the information the new images brought). The test
statistic per parameter is::

    z_i = (p_now,i - p_ref,i) / sqrt(s_ref,i^2 + k q_i - s_now,i^2)

which is standard normal under "no change beyond the model". An alarm is raised when
``max_i |z_i|`` exceeds the two-sided Bonferroni threshold for a family-wise false-alarm
probability ``alpha`` per image over the m tested parameters:
``z_alarm = Phi^-1(1 - alpha / (2 m))``. Parameters the recent images say nothing about
(variance reduction below 1e-3 of ``s_ref^2``) are not tested.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from ..core.errors import InputError


@dataclass
class Alarm:
    image: int  # index of the image that raised it (0-based)
    parameter: str
    z: float
    change: float  # p_now - p_ref, SI units of the parameter
    threshold: float


class DriftTest:
    """Keeps the last ``lag`` estimates and tests the newest against the oldest."""

    def __init__(self, names: list[str], drift_variance: np.ndarray, lag: int, false_alarm_rate: float) -> None:
        if lag < 1:
            raise InputError(None, "alarm_lag_images", f"must be at least 1, got {lag}")
        if not 0.0 < false_alarm_rate < 1.0:
            raise InputError(None, "alarm_false_rate", f"must be in (0, 1), got {false_alarm_rate}")
        self.names = list(names)
        self.drift_variance = np.asarray(drift_variance, dtype=float)
        self.lag = lag
        self.false_alarm_rate = false_alarm_rate
        self.threshold = NormalDist().inv_cdf(1.0 - false_alarm_rate / (2.0 * len(names)))
        self._past: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=lag)

    def reset(self) -> None:
        """Forget the past estimates (after the model was changed by an alarm)."""
        self._past.clear()

    def check(self, image: int, cycle: int, estimate: np.ndarray, sigmas: np.ndarray) -> list[Alarm]:
        """Test ``estimate`` against the one ``lag`` images ago; remember it. Returns the
        alarms (parameters over the threshold, largest |z| first)."""
        alarms: list[Alarm] = []
        if len(self._past) == self.lag:
            ref_cycle, ref_estimate, ref_sigmas = self._past[0]
            prior_variance = ref_sigmas**2 + (cycle - ref_cycle) * self.drift_variance
            variance = prior_variance - sigmas**2
            tested = variance > 1e-3 * prior_variance
            z = np.zeros_like(estimate)
            z[tested] = (estimate[tested] - ref_estimate[tested]) / np.sqrt(variance[tested])
            for i in np.argsort(-np.abs(z)):
                if abs(z[i]) <= self.threshold:
                    break
                alarms.append(
                    Alarm(image, self.names[i], float(z[i]), float(estimate[i] - ref_estimate[i]), self.threshold)
                )
        self._past.append((cycle, estimate.copy(), sigmas.copy()))
        return alarms
