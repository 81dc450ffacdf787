"""The rigid model nearest a compliant one: what a URDF (which cannot bend) can hold.

A calibrated model with gravity compliances moves the tool by the deflection at its payload.
Zeroing the compliances drops that; refitting the rigid parameters (DH or origins, offsets,
distortions, base and tool) to the full model's tool poses over the calibrated region folds
the deflection's average into the geometry, and leaves only what no rigid chain can follow:

    p_rigid = argmin_p  sum_q sum_k | T_W_C(q; p, k = 0) c_k - T_W_C(q; p_full, k_full) c_k |^2

over configurations q and points c_k of the tool frame (its origin and 0.1 m along each axis,
so that the orientation is fitted too), by Gauss-Newton on the analytic Jacobians.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.errors import InputError
from .parameters import COMPLIANCE_KINDS, is_motion, split_name
from .robot import Robot

# Tool-frame points the fit matches (m): the origin and 0.1 m along each axis.
POINTS = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, 0.1]])
ITERATIONS = 20
MIN_CONFIGURATIONS = 10  # fewer cannot fix the rigid parameters a URDF holds


@dataclass(frozen=True)
class RigidFit:
    robot: Robot  # the rigid robot (compliances zero, refitted parameters)
    dropped_rms_m: float  # the full model against the compliances dropped, before the refit
    dropped_max_m: float
    remaining_rms_m: float  # the full model against the refitted rigid one (tool origin)
    remaining_max_m: float
    n_configurations: int


def without_compliances(robot: Robot) -> Robot:
    """The robot with its compliances and motion-history terms at zero: what a URDF holds."""
    values = robot.nominal_parameters()
    return replace(robot, overrides={k: (0.0 if _compliance(k) else v) for k, v in values.items()})


def _compliance(name: str) -> bool:
    """Not a rigid parameter: a compliance, or a motion-history term (fgcal.model.motion)."""
    return split_name(name)[0] in COMPLIANCE_KINDS or is_motion(name)


def _points(robot: Robot, q: np.ndarray, params: dict | None = None) -> np.ndarray:
    T = robot.fk_tool(q, params)
    return np.einsum("nij,kj->nki", T[:, :3, :3], POINTS) + T[:, None, :3, 3]  # (N, 4, 3)


def _origin_errors(robot: Robot, rigid: Robot, q: np.ndarray) -> np.ndarray:
    return np.linalg.norm(robot.fk_tool(q)[:, :3, 3] - rigid.fk_tool(q)[:, :3, 3], axis=1)


def rigid_refit(robot: Robot, q: np.ndarray) -> RigidFit:
    """The rigid robot nearest ``robot`` (full model, at its payload) over configurations ``q``
    (N, n; rad): every rigid parameter refitted, compliances zero."""
    q = robot.check_q(q)
    distinct = len(np.unique(np.round(q, 9), axis=0))
    if distinct < MIN_CONFIGURATIONS:
        raise InputError(
            None, "--rigid-fit", f"{distinct} distinct configurations: a rigid fit needs at least {MIN_CONFIGURATIONS}"
        )
    wanted = _points(robot, q)
    dropped = without_compliances(robot)
    names = [name for name in robot.parameter_names if not _compliance(name)]
    values = dropped.nominal_parameters()
    for _ in range(ITERATIONS):
        current = replace(dropped, overrides=values)
        residual = (_points(current, q) - wanted).reshape(-1)
        J = np.concatenate([current.jacobian(q, names, frame="tool", point=c)[:, None] for c in POINTS], axis=1)
        J = J.reshape(-1, len(names))
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0] = 1.0
        # Minimum-norm steps: redundant parameters (a base rotation against a first offset) share the move.
        step = np.linalg.lstsq(J / scale, -residual, rcond=1e-10)[0] / scale
        values = {**values, **{n: values[n] + float(s) for n, s in zip(names, step, strict=True)}}
        if np.abs(step).max() < 1e-13:
            break
    fitted = replace(dropped, overrides=values)
    before, after = _origin_errors(robot, dropped, q), _origin_errors(robot, fitted, q)
    return RigidFit(
        robot=fitted,
        dropped_rms_m=float(np.sqrt(np.mean(before**2))),
        dropped_max_m=float(before.max()),
        remaining_rms_m=float(np.sqrt(np.mean(after**2))),
        remaining_max_m=float(after.max()),
        n_configurations=len(q),
    )


def region_sample(robot: Robot, count: int = 2000, seed: int = 0) -> np.ndarray:
    """The robot's calibrated region (the configurations its calibration was fitted on), else
    ``count`` seeded configurations within the joint limits (angles within +-pi)."""
    if robot.region is not None:
        return robot.region
    low = np.maximum(robot.limits[:, 0], -np.pi)
    high = np.minimum(robot.limits[:, 1], np.pi)
    return np.random.default_rng(seed).uniform(low, np.maximum(low, high), (count, robot.n_joints))
