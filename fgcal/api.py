"""The Python API at the top level: ``fgcal.calibrate`` and ``fgcal.compensate``.

    import fgcal
    calibration = fgcal.calibrate("data", formulation="tracker", model="DH,s,e")
    calibration.estimates        # {name: value} of the estimated parameters (SI)
    calibration.sigmas           # {name: sigma} (SI)
    calibration.held_out         # the report's headline: RMS, P95, max after and before (m)
    calibration.robot            # the calibrated Robot (fk, ik, jacobian, save)
    fgcal.compensate(calibration.robot, targets)   # corrected commands for the nominal controller

Settings are a calibration config's keys (docs/calibration.md). A simulation's dataset is scored
against its truth, as ``fgcal calibrate`` does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .calibration.results import CalibrationResult
from .core.errors import InputError
from .data.compensation import Compensation, nominal_of
from .model.robot import Robot


@dataclass(frozen=True)
class Calibration:
    """A calibration's outcome: named estimates and sigmas, the held-out figures, the robot."""

    result: CalibrationResult  # everything (fgcal.calibration.results)
    headline: dict | None  # the report's headline figures (SI), with its sentence under "text"

    @property
    def robot(self) -> Robot:
        """The calibrated robot: the estimate, with the tool the calibration estimated."""
        from .reports.calibration import calibrated_robot

        robot, params = calibrated_robot(self.result)
        return replace(robot, overrides=params)

    @property
    def estimates(self) -> dict[str, float]:
        """The estimated (released) parameters by name (SI)."""
        values = self.result.parameters
        return {name: values[name] for name in self.result.released}

    @property
    def sigmas(self) -> dict[str, float]:
        """One sigma of each estimated parameter (SI), scaled by the fit's chi2/dof."""
        return self.result.sigmas

    @property
    def held_out(self) -> dict | None:
        """RMS, P95 and max of the held-out error after and before (m)."""
        if self.headline is None:
            return None
        return {"after_m": self.headline["after_m"], "before_m": self.headline["before_m"]}

    def write_report(self, out: str | Path, plots: bool = True) -> dict:
        """report.md, report.json, calibrated_robot.yaml and estimates.yaml into ``out``."""
        from .reports.calibration import write_report

        return write_report(self.result, out, plots=plots)

    def __repr__(self) -> str:
        problem = self.result.problem
        figures = "" if self.headline is None else f"; {self.headline['text']}"
        return (
            f"<Calibration of {problem.robot.name}, model {self.result.config.model}, "
            f"{problem.formulation.name} formulation, {len(self.result.released)} parameters estimated{figures}>"
        )


def calibrate(dataset: str | Path, **settings) -> Calibration:
    """Calibrate ``dataset`` (a folder with dataset.yaml) with a calibration config's
    ``settings`` (formulation, model, noise, validation, ...: docs/calibration.md)."""
    from .calibration.config import CalibrationConfig
    from .calibration.run import calibrate as run
    from .calibration.scoring import score_with_truth
    from .reports.headline import headline

    result = score_with_truth(run(CalibrationConfig.defaults(dataset, **settings)))
    return Calibration(result, headline(result))


def compensate(
    robot: Robot,
    targets: np.ndarray,
    hints: np.ndarray | None = None,
    nominal: Robot | str | None = None,
    tcp: np.ndarray | None = None,
    approach: str | np.ndarray = "previous",
    tip: str | None = None,
) -> Compensation:
    """Corrected commands for a controller running its nominal model: ``targets`` are TCP
    positions (N, 3) or poses (N, 4, 4) in the robot's W (m); ``hints`` the program's joints
    (N, n; rad) if known; ``nominal`` the controller's model (a Robot, a robot file, or by
    default the bundled robot of the same name). With a robot calibrated with lost motion
    (model DH,s,e,h), ``approach`` says how each target is reached: ``"previous"`` (the targets
    are a path, each from the one before), ``"none"`` (not allowed for) or (N, n) joints each is
    approached from (NaN rows: the previous). Returns the joints reaching each target on the
    calibrated model, the commands, residuals and a status per target (docs/using.md). ``tip``:
    a tree's tip the targets (and ``tcp``) are for (Robot.tip_names; default the tool on the
    flange)."""
    from .data.compensation import compensate as run

    if not isinstance(nominal, Robot):
        nominal = nominal_of(robot, nominal)
    targets = np.asarray(targets, dtype=float)
    if isinstance(approach, str):
        if approach not in ("previous", "none"):
            raise InputError(None, "approach", f"'previous', 'none' or joints per target, got {approach!r}")
        joints = None if approach == "none" else np.full((len(targets), robot.n_joints), np.nan)
    else:
        joints = np.asarray(approach, dtype=float)
        if joints.shape != (len(targets), robot.n_joints):
            raise InputError(None, "approach", f"one row of {robot.n_joints} joints per target, got {joints.shape}")
    if tip is not None and robot.tip_error(tip):
        raise InputError(None, "tip", robot.tip_error(tip))
    return run(robot, nominal, targets, hints, tcp, "tool" if tip is None else tip, approach=joints)
