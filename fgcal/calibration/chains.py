"""What each chain of a tree determines alone: a robot with several tips (two arms on one torso, a
robot and its positioner) shares parameters between its chains, and each chain's measurements
determine the shared ones only in part. At the calibrated estimate, the sigmas of the shared
parameters from each tip's measurements alone and from all of them, under the declared noise:
the linearised covariance of the same measurement model the fit used (its main set), with the
auxiliary unknowns (the tracker's pose, the reflectors) estimated alongside, and of each subset
only the parameters it identifies (fgcal.calibration.identifiability)."""

from __future__ import annotations

import numpy as np

from ..model.kinematics import path_parameters
from ..model.parameters import is_mass
from .identifiability import select
from .problem import Observations, main_set
from .results import CalibrationResult


def chain_sigmas(result: CalibrationResult) -> dict | None:
    """``{"tips": [...], "parameters": {name: {"sigma_by_tip": {tip: sigma or None}, "sigma_all":
    sigma}}}`` (SI) for the released parameters that move more than one tip's measurements;
    None when the measurements are on one tip (or nothing is released)."""
    problem = result.problem
    observations = problem.observations
    units = problem.formulation.unit_tips(problem, observations)
    released = result.released
    if units is None or not released:
        return None
    tips = [tip for tip in problem.robot.tip_names if tip in set(units)]
    if len(tips) < 2:
        return None
    moments = problem.kinematics(result.state, released, observations).data(None).moments
    on_path = {tip: path_parameters(problem.robot, tip) for tip in tips}
    by_tip = {}
    for tip in tips:
        # A chain alone calibrates its own path and the mass scales: the other chains' parameters
        # reach its measurements only through the trunk's bending, too weakly to stand for them.
        mine = [k for k, name in enumerate(released) if name in on_path[tip] or is_mass(name)]
        J_p, J_aux = _whitened(result, observations.select(units == tip))
        names = [released[k] for k in mine]
        by_tip[tip] = parameter_sigmas(J_p[:, mine], J_aux, names, moments, result.config.min_information)
    J_p, J_aux = _whitened(result, observations)
    everything = parameter_sigmas(J_p, J_aux, released, moments, result.config.min_information)
    shared = [k for k, name in enumerate(released) if is_mass(name) or sum(name in on_path[tip] for tip in tips) > 1]
    return {
        "tips": tips,
        "noise": "declared",
        "parameters": {
            released[k]: {
                "sigma_by_tip": {tip: by_tip[tip].get(released[k]) for tip in tips},
                "sigma_all": everything.get(released[k]),
            }
            for k in shared
        },
    }


def _whitened(result: CalibrationResult, observations: Observations) -> tuple[np.ndarray, np.ndarray]:
    """The main set's whitened Jacobians w.r.t. P and the auxiliary unknowns, at the estimate."""
    main, inputs = main_set(result.problem, observations, result.state, result.released)
    evaluation = main.whitened(inputs, True, robust=False)
    key_p = main.variables[0][0]
    J_p = evaluation.blocks[0]
    aux = [block for (key, _, _), block in zip(main.variables, evaluation.blocks, strict=True) if key != key_p]
    J_aux = np.hstack(aux) if aux else np.zeros((J_p.shape[0], 0))
    return J_p, J_aux[:, np.linalg.norm(J_aux, axis=0) > 0.0]


def parameter_sigmas(
    J_p: np.ndarray, J_aux: np.ndarray, names: list[str], moments: np.ndarray, min_information: float
) -> dict[str, float]:
    """Sigma of each parameter these rows identify, the auxiliary unknowns projected out."""
    identifiable = select(J_p, J_aux, names, moments, min_information).identifiable
    if not identifiable:
        return {}
    if J_aux.shape[1]:
        Q, R = np.linalg.qr(J_aux)
        keep = np.abs(np.diag(R)) > 1e-9 * max(1.0, np.abs(np.diag(R)).max())
        J_p = J_p - Q[:, keep] @ (Q[:, keep].T @ J_p)
    columns = [names.index(name) for name in identifiable]
    covariance = np.linalg.pinv(J_p[:, columns].T @ J_p[:, columns])
    return {name: float(np.sqrt(max(covariance[i, i], 0.0))) for i, name in enumerate(identifiable)}
