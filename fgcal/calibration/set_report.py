"""What each measurement set of a calibration with several (a config's ``sets:``) says: per set its
rows, its residual RMS in its own unit and its chi2/dof at the estimate, its held-out score and
its prediction, and each released parameter's sigma from each fitting set alone and from all (as
"Shared by the chains" gives per chain of a tree: fgcal.calibration.chains).

A set's degrees of freedom are its redundancy, its rows less the share of the unknowns they
determine: ``n_k - trace(J_k C J_k')`` with J_k its whitened rows' Jacobian and C the declared
covariance of every unknown (the priors included); the sets' shares add up to the fit's
unknowns. Under the declared noise each set's chi2 is then about its dof: a chi2/dof well above
1 says that set's noise is under-declared (or the model does not fit its measurements)."""

from __future__ import annotations

import numpy as np

from ..model.parameters import is_mass
from .chains import parameter_sigmas
from .formulations.sets import Combined
from .problem import Part, dense_jacobian, key_columns, keys_of, values_of
from .results import CalibrationResult


def set_summary(result: CalibrationResult) -> dict | None:
    """``{"headline_set", "sets": [...], "parameters": {name: {"sigma_by_set", "sigma_all"}}}``
    (SI); None for a calibration of one formulation."""
    problem, state = result.problem, result.state
    formulation = problem.formulation
    if not isinstance(formulation, Combined):
        return None
    parts = formulation.parts(problem)
    released = result.released
    kinematics = problem.kinematics(state, released, problem.observations)
    keys = keys_of(state, bool(released))
    values = values_of(state, keys, kinematics.base[kinematics.index])
    measurements = formulation.measurement_sets(problem, problem.observations, kinematics, keys, state, None)
    columns, width = key_columns(state, keys, len(released))
    covariance = result.covariance_declared
    sets, jacobians = [], {}
    for part in parts:
        entry = {"name": part.name, "formulation": part.formulation.name, "use": part.use,
                 "unit": part.formulation.unit}  # fmt: skip
        if part.use == "fit":
            J, chi2, sums = _rows(part, measurements, values, columns, width)
            jacobians[part.name] = J
            share = 0.0
            if covariance is not None:
                names = ["P", *state.aux] if keys.params is not None else list(state.aux)
                index = np.concatenate([np.arange(*_span(covariance.offsets[n])) for n in names])
                C = covariance.matrix[np.ix_(index, index)]
                share = float(np.einsum("ij,jk,ik->", J, C, J))
            dof = len(J) - share
            entry.update(n_rows=len(J), **{f"residual_rms_{unit}": v for unit, v in sums.items()}, chi2=chi2, dof=dof,
                         chi2_per_dof=chi2 / dof if dof > 0 else None)  # fmt: skip
        else:
            registered_on = problem.observations.registered_on[part.index]
            if result.test_observations is not None:  # "all": nothing of it held out, scored where registered
                registered_on = result.test_observations.registered_on[part.index]
            entry["registered_on"] = registered_on
        scores = result.measured  # against the held-out measurements (validation: the truth, when scored)
        entry["held_out"] = {label: _own(scores.get(label, {}), part.name) for label in ("before", "after")}
        predicted = None
        if result.covariance is not None and result.test_observations is not None and released:
            factor = result.fit.variance_factor if result.fit is not None else 1.0
            predicted = formulation.set_prediction(
                problem, result.test_observations, state, result.covariance, factor, part.index
            )
        entry["predicted_rms_m"] = None if predicted is None else predicted.rms
        sets.append(entry)
    headline = formulation.members[formulation.headline].name
    return {"headline_set": headline, "sets": sets, "parameters": _sigmas(result, jacobians)}


def noise_ratios(result: CalibrationResult) -> dict[str, float]:
    """Per fitting set, the RMS of its whitened residuals at the estimate (about 1 when its
    declared noise is right; no Jacobians: the headline's check); empty for one formulation."""
    problem, state = result.problem, result.state
    formulation = problem.formulation
    if not isinstance(formulation, Combined):
        return {}
    released = result.released
    kinematics = problem.kinematics(state, released, problem.observations)
    keys = keys_of(state, bool(released))
    values = values_of(state, keys, kinematics.base[kinematics.index])
    measurements = formulation.measurement_sets(problem, problem.observations, kinematics, keys, state, None)
    out = {}
    for part in formulation.parts(problem):
        own = part.sets_of(measurements)
        if part.use == "fit" and own:
            whitened = np.concatenate([m.whitened(m.read(values), False, robust=False).residual for m in own])
            out[part.name] = float(np.sqrt(np.mean(whitened**2)))
    return out


def _own(scores: dict, name: str) -> dict[str, float]:
    """A set's held-out scores (``SET/score`` keys), by score: their RMS, the unit in the key
    (``tool_point_rms_m``, ``reprojection_rms_px``)."""
    out = {}
    for key, stat in scores.items():
        if key.startswith(f"{name}/"):
            score = key.split("/", 1)[1]
            unit = next((u for u in ("px", "rad") if score.endswith(f"_{u}")), "m")
            out[f"{score.removesuffix(f'_{unit}')}_rms_{unit}"] = stat.rms
    return out


def _span(offset: tuple[int, int]) -> tuple[int, int]:
    return offset[0], offset[0] + offset[1]


def _rows(part: Part, measurements, values, columns: dict, width: int) -> tuple[np.ndarray, float, dict]:
    """A fitting set's whitened Jacobian on every unknown, its chi2 and its raw residual RMS per
    unit of the rows (m, rad, px)."""
    blocks, chi2, sums = [], 0.0, {}
    for s in part.sets_of(measurements):
        evaluation = s.whitened(s.read(values), True, robust=False)
        blocks.append(dense_jacobian(s, evaluation.blocks, columns, width))
        chi2 += float(np.sum(evaluation.residual**2))
        raw = evaluation.residual * s.sigma
        for unit, rows in s.row_units().items():
            total = sums.setdefault(unit, [0.0, 0])
            total[0] += float(np.sum(raw[rows] ** 2))
            total[1] += int(np.count_nonzero(rows))
    return np.vstack(blocks), chi2, {u: float(np.sqrt(s / max(n, 1))) for u, (s, n) in sums.items()}


def _sigmas(result: CalibrationResult, jacobians: dict[str, np.ndarray]) -> dict:
    """Each released parameter's sigma from each fitting set's rows alone (its own unknowns
    projected out; None where that set alone does not identify it) and from all, under the
    declared noise, as fgcal.calibration.chains does per chain."""
    released = result.released
    if not released or not jacobians:
        return {}
    m = len(released)
    moments = result.problem.kinematics(result.state, released, result.problem.observations).data(None).moments
    min_information = result.config.min_information
    alone = {}
    for name, J in jacobians.items():
        alone[name] = parameter_sigmas(J[:, :m], _used(J[:, m:]), list(released), moments, min_information)
    J_all = np.vstack(list(jacobians.values()))
    everything = parameter_sigmas(J_all[:, :m], _used(J_all[:, m:]), list(released), moments, min_information)
    return {
        name: {"sigma_by_set": {s: alone[s].get(name) for s in jacobians}, "sigma_all": everything.get(name)}
        for name in released
        if not is_mass(name) or name in everything
    }


def _used(J_aux: np.ndarray) -> np.ndarray:
    return J_aux[:, np.linalg.norm(J_aux, axis=0) > 0.0]
