"""How accurate another model of the calibrated robot is on the calibration's own data: the
URDF alone (compliances dropped), or its rigid refit, beside the full model.

Each model is scored as its user would get it: the instrument's unknowns (tracker pose,
reflectors, camera mounting...) registered to that model on the fitting data (a solve of the
auxiliary unknowns alone, the robot held), then the formulation's held-out score on the
held-out measurements. Nothing held out enters the registration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import InputError
from ..model.robot import SAME_ROBOT_M, Robot
from .results import CalibrationResult, ErrorStats, stats
from .solve import solve_stage


@dataclass(frozen=True)
class ModelAccuracy:
    fit: ErrorStats  # on the fitting measurements (SI)
    held_out: ErrorStats | None  # on the held-out ones; None when nothing is held out


def model_accuracy(result: CalibrationResult, robot: Robot) -> ModelAccuracy:
    """``robot``'s parameters (the calibration's robot, another model of it) scored on the
    calibration's data, the auxiliary unknowns registered to it on the fitting data."""
    problem = result.problem
    check_same_robot(result, robot)
    state = result.state.with_params(robot.parameter_vector())
    if state.n_auxiliary:
        state = solve_stage(problem, "registration", [], state)[0]
    formulation = problem.formulation

    def scored(observations) -> ErrorStats:
        errors = formulation.held_out_errors(problem, observations, state)[formulation.score]
        return stats(errors.errors, errors.configs)

    held = None if result.test_observations is None else scored(result.test_observations)
    return ModelAccuracy(scored(problem.observations), held)


def check_same_robot(result: CalibrationResult, robot: Robot) -> None:
    """The calibration must be of ``robot`` (the same joints, flanges within SAME_ROBOT_M)."""
    problem = result.problem
    if robot.parameter_names != problem.robot.parameter_names or problem.robot.flange_gap_m(robot) > SAME_ROBOT_M:
        raise InputError(None, "--calibration", f"the calibration is of another robot than {robot.name}")


def fitting_configurations(result: CalibrationResult) -> np.ndarray:
    """The joint values (N, n; rad) of the calibration's fitting configurations: its region."""
    return result.problem.dataset.q[result.problem.fit]
