"""Fixed parameters a held-out score depends on: a prediction assumes them at their values.

A prediction carries the released unknowns' covariance to the score. A parameter the
identifiability analysis fixed (the fitting data cannot determine it) may still move the score
where nothing released, and no gauge the score removes, can take its effect: the fitting sets
cannot see it and the score can. A tracker validating sees the torso that cameras riding on it
cannot; a score in W sees where each arm hangs from the torso, which only its own camera's
mounting absorbed. Such a parameter's error lies outside the prediction, whatever the data: the
report names it and states what a small deviation of it does to the score.

With ``e = J_F dF`` the score's rows moved by the fixed parameters and ``J_U`` those of the
released unknowns (both with the score's gauge removed), the part no released combination can
take is ``r = (I - Q Q^T) J_F`` (Q an orthonormal basis of J_U's columns). The calibration fits
the released unknowns to the fitting data, not to the score, so the effect after calibration is
at least ``|r|``: the figures are lower bounds.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .priors import class_of

# The deviation each effect is stated for (SI): 0.1 mm, 0.1 mrad, 1 urad/(N m), 1 % of a mass.
STEPS = {"length": 1e-4, "angle": 1e-4, "compliance": 1e-6, "motion": 1e-4, "mass": 0.01}
# A fixed parameter is a blind spot when this part of its column's norm is left after the
# released unknowns took what they can (sx2 against alpha1 leaves ~1e-9: the same column) ...
UNABSORBED = 0.1
# ... and its step moves the score by at least this much RMS (m): below, no score could tell.
NEGLIGIBLE_M = 1e-7


@dataclass(frozen=True)
class BlindSpot:
    name: str
    step: float  # SI: the deviation the effect is stated for (STEPS)
    effect_rms_m: float  # at least this RMS movement of the score per step, nothing released taking it

    def as_dict(self) -> dict:
        return {"name": self.name, "step": self.step, "effect_rms_m": self.effect_rms_m}


def blind_spots(
    J_released: np.ndarray,
    J_fixed: np.ndarray,
    names: Sequence[str],
    per_score: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[BlindSpot, ...]:
    """The fixed parameters ``names`` (columns of ``J_fixed``, SI) whose effect on the score's
    rows the released unknowns' columns ``J_released`` cannot take (module docstring), largest
    effect first. ``per_score`` turns squared rows (n_rows,) into squared scores in m^2 (a
    score of several rows, a pixel score's metric scale); default: rows of 3 coordinates (m)."""
    if not len(names):
        return ()
    if per_score is None:
        per_score = lambda squared: squared.reshape(-1, 3).sum(axis=1)  # noqa: E731
    left = J_fixed
    if J_released.size:
        U, s, _ = np.linalg.svd(J_released, full_matrices=False)
        Q = U[:, s > s[0] * 1e-10] if len(s) and s[0] > 0 else U[:, :0]
        left = J_fixed - Q @ (Q.T @ J_fixed)
    found = []
    for j, name in enumerate(names):
        step = STEPS[class_of(name)]
        total = float(np.sqrt(np.mean(per_score(J_fixed[:, j] ** 2)))) * step
        effect = float(np.sqrt(np.mean(per_score(left[:, j] ** 2)))) * step
        if effect >= NEGLIGIBLE_M and effect >= UNABSORBED * total:
            found.append(BlindSpot(name, step, effect))
    return tuple(sorted(found, key=lambda b: -b.effect_rms_m))


def describe(spots: Sequence[BlindSpot], shown: int = 6) -> str:
    """``theta5 (0.1 mrad: 0.021 mm), ...`` for a report (mm), the largest first."""
    units = {"length": "0.1 mm", "angle": "0.1 mrad", "compliance": "1 urad/(N m)", "motion": "0.1 mrad",
             "mass": "1 %"}  # fmt: skip
    parts = [f"{b.name} ({units[class_of(b.name)]}: {b.effect_rms_m * 1e3:.3g} mm)" for b in spots[:shown]]
    more = f" and {len(spots) - shown} more" if len(spots) > shown else ""
    return ", ".join(parts) + more
