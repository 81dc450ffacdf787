"""A validation set's own unknowns registered with the robot held at a calibration, and the
prediction of its held-out score through that registration (fgcal.calibration.formulations.sets).

A validation set (a tracker measuring a robot calibrated by touch) measures in its own frame with
its own unknowns a (the tracker's pose, its reflectors on the flange). They are fitted on the
set's registration rows r with the parameters P at the calibration; its held-out rows t are then
scored. Linearised, a parameter error dP moves the registration by
``da = -(J_ra' W J_ra)^-1 J_ra' W (J_rP dP + n_r)``, so the held-out residual is

    e_t = (J_tP - J_ta (J_ra' W J_ra)^-1 J_ra' W J_rP) dP - J_ta (J_ra' W J_ra)^-1 J_ra' W n_r + n_t,

whose variance is what the prediction states: the effective Jacobian through the calibration's
covariance of P, the registration's own noise J_ta (J_ra' W J_ra)^-1 J_ta', and the measurement
noise. Registered on the held-out rows themselves (no registration rows in the fitting split):
``e_t = (I - J_ta (J_ra' W J_ra)^-1 J_ta' W) (J_tP dP + n_t)``, the registration rows being the
held-out ones.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...core.errors import InputError
from ...factors import MeasurementSet
from ..blind_spots import blind_spots
from ..problem import (
    JointCovariance,
    Observations,
    Prediction,
    Problem,
    dense_jacobian,
    key_columns,
    keys_of,
    prediction,
    values_of,
)
from ..solve import solve_stage
from ..state import State


def register(problem: Problem, params: np.ndarray) -> State:
    """The formulation's unknowns fitted to its (fitting) observations with the parameters held
    at ``params``: its start from the data, then Levenberg-Marquardt on its graph with nothing
    released."""
    start = problem.formulation.initial_state(problem).with_params(params)
    if not start.n_auxiliary:
        return start
    if problem.n_residuals < 2 * start.n_auxiliary:
        raise InputError(
            problem.dataset.path, None, f"the {problem.formulation.name} validation set has {problem.n_residuals} "
            f"residuals to register its {start.n_auxiliary} unknowns (the instrument's frame, its points) on: at least "
            "twice as many needed",
        )  # fmt: skip
    state, _, stage, _ = solve_stage(problem, "registration", [], start)
    stage.forget()
    return state


def _columns(problem: Problem, observations: Observations, state: State, released: list[str], whiten: bool):
    """The rows of the formulation's measurement sets (whitened, or raw) as one Jacobian on
    [P, the unknowns in the state's order], their sigmas, and the main set with its inputs."""
    kinematics = problem.kinematics(state, released, observations)
    keys = keys_of(state, bool(released))
    values = values_of(state, keys, kinematics.base[kinematics.index])
    sets: list[MeasurementSet] = problem.formulation.measurement_sets(
        problem, observations, kinematics, keys, state, None
    )
    columns, width = key_columns(state, keys, len(released))
    blocks, sigmas = [], []
    for s in sets if whiten else sets[:1]:
        inputs = s.read(values)
        evaluation = s.whitened(inputs, True, robust=False) if whiten else s.compute(inputs, True)
        blocks.append(dense_jacobian(s, evaluation.blocks, columns, width))
        sigmas.append(s.sigma)
    return np.vstack(blocks), np.concatenate(sigmas), sets[0], sets[0].read(values)


def registered_prediction(
    problem: Problem,
    observations: Observations,
    state: State,
    covariance: JointCovariance,
    factor: float,
    same: bool,
) -> Prediction | None:
    """Predicted RMS of a validation set's main held-out score (module docstring): ``problem`` is
    the set's view (its registration observations), ``observations`` its held-out ones, ``state``
    its registration; ``covariance`` the calibration's (P), ``factor`` its variance factor (the
    set's own noise is as declared). ``same``: registered on the held-out rows themselves."""
    released = list(covariance.released)
    m = len(released)
    if not m or not len(getattr(observations, "configs", [1])):
        return None
    formulation = problem.formulation
    # The calibration's fixed candidates too: the validation set may see what the fit could not.
    fixed = [name for name in problem.candidates if name not in set(released)]
    columns = released + fixed
    J_r, _, _, _ = _columns(problem, problem.observations, state, columns, True)
    J_t, sigma_t, main, inputs = _columns(problem, observations, state, columns, False)
    C = covariance.block(["P"])
    n_p = len(columns)
    J_rP, J_ra = J_r[:, :n_p], J_r[:, n_p:]
    J_tP, J_ta = J_t[:, :n_p], J_t[:, n_p:]
    A_inv = np.linalg.pinv(J_ra.T @ J_ra)
    if same:
        M = np.eye(len(J_t)) - J_ta @ A_inv @ (J_ta / sigma_t[:, None] ** 2).T
        J_eff = M @ J_tP
        noise_rows = np.einsum("ij,j,ij->i", M, sigma_t**2, M)
    else:
        J_eff = J_tP - J_ta @ A_inv @ (J_ra.T @ J_rP)
        noise_rows = np.einsum("ij,jk,ik->i", J_ta, A_inv, J_ta) + sigma_t**2
    parameters_rows = np.einsum("ij,jk,ik->i", J_eff[:, :m], C, J_eff[:, :m])
    scale = formulation.metric_scale(problem, main, inputs, state)

    def per_score(rows: np.ndarray) -> np.ndarray:
        return rows.reshape(-1, formulation.score_width)[:, formulation.score_rows].sum(axis=1) * scale**2

    predicted = prediction(per_score(parameters_rows), per_score(noise_rows), factor)
    spots = blind_spots(J_eff[:, :m], J_eff[:, m:], fixed, per_score)
    return replace(predicted, assumes=spots) if predicted is not None else None
