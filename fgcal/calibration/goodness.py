"""Goodness of fit: does the declared measurement noise explain the residuals?

chi2 is the sum of squared whitened measurement residuals (declared sigmas, no robust loss)
at the solution, with dof = residuals - unknowns (released parameters and auxiliary
unknowns). Under the declared noise chi2 follows a chi-square distribution with dof degrees
of freedom. When it does not (a two-sided p-value below ``CONSISTENT_P``), the noise was
misdeclared or the model cannot fit the data, and the covariance is scaled by
sigma0^2 = chi2/dof, the variance factor of the data (the usual a-posteriori estimate).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

CONSISTENT_P = 1e-3


@dataclass(frozen=True)
class Fit:
    chi2: float
    dof: int
    p_value: float  # P(chi-square >= chi2): small when the residuals are too large for the noise

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    @property
    def consistent(self) -> bool:
        """chi2 within the two-sided CONSISTENT_P band of its distribution."""
        return self.dof > 0 and CONSISTENT_P / 2 <= self.p_value <= 1 - CONSISTENT_P / 2

    @property
    def variance_factor(self) -> float:
        """sigma0^2: 1 when consistent, chi2/dof otherwise."""
        return 1.0 if self.consistent or self.dof <= 0 else self.chi2_per_dof

    def as_dict(self) -> dict:
        return {
            "chi2": self.chi2,
            "dof": self.dof,
            "chi2_per_dof": self.chi2_per_dof,
            "chi2_p_value": self.p_value,
            "consistent_with_declared_noise": self.consistent,
            "variance_factor": self.variance_factor,
        }

    def sentence(self) -> str:
        """What the fit says, in words, for report.md."""
        if self.dof <= 0:
            return "No degrees of freedom left: the fit cannot be tested against the declared noise."
        ratio = math.sqrt(self.chi2_per_dof)
        if self.consistent:
            return (
                f"The residuals agree with the declared noise (chi2/dof {self.chi2_per_dof:.3g}, "
                f"p = {self.p_value:.3g}): the covariances stand as computed."
            )
        side = "larger" if self.chi2_per_dof > 1 else "smaller"
        return (
            f"The residuals are {max(ratio, 1 / ratio):.3g} times {side} than the declared noise explains (chi2/dof "
            f"{self.chi2_per_dof:.3g} over {self.dof} degrees of freedom, p = {self.p_value:.3g}): the noise "
            "was misdeclared or the model does not fit the data. In every covariance and predicted accuracy "
            f"below the measurements' noise is scaled by chi2/dof = {self.chi2_per_dof:.3g} (a stated prior keeps "
            "its sigma); the sigmas under the declared noise are given too."
        )


def goodness_of_fit(chi2: float, n_residuals: int, n_unknowns: int) -> Fit:
    from scipy.special import gammaincc  # imported here: only a finished fit needs it

    dof = int(n_residuals - n_unknowns)
    p_value = float(gammaincc(dof / 2.0, chi2 / 2.0)) if dof > 0 else math.nan
    return Fit(float(chi2), dof, p_value)


# Medians of the chi distribution for 1..12 degrees of freedom (sqrt(2 gammaincinv(k/2, 1/2)),
# from scipy.special, which costs a seventh of a second to import).
_CHI_MEDIANS = np.array(
    [0.67449, 1.17741, 1.538172, 1.832128, 2.086015, 2.3126, 2.519089, 2.710004, 2.888396, 3.056439, 3.215742, 3.36754]
)


def chi_median(dims: np.ndarray) -> np.ndarray:
    """Median of the norm of a standard normal vector of ``dims`` components (1-D: 0.6745);
    beyond 12 components Wilson-Hilferty's approximation (relative error below 2e-4)."""
    k = np.asarray(dims, dtype=int)
    approximate = np.sqrt(k * (1.0 - 2.0 / (9.0 * np.maximum(k, 1))) ** 3)
    return np.where(k <= len(_CHI_MEDIANS), _CHI_MEDIANS[np.clip(k, 1, len(_CHI_MEDIANS)) - 1], approximate)
