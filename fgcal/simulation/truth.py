"""The simulated "true" robot: parameters perturbed from nominal within the cell's ranges."""

from __future__ import annotations

import numpy as np

from ..model.parameters import MASS_KIND, MOTION_KINDS, split_name
from ..model.robot import Robot
from .cell import Perturbation


def perturb_parameters(robot: Robot, pert: Perturbation, rng: np.random.Generator) -> dict[str, float]:
    """True parameter values (SI): uniform deviations of +-half-width on lengths and angles,
    uniform compliances in [low, high] on the compliant joints, zero compliance elsewhere, mass
    scales within 1 +- the cell's mass_scale (no draw without one: seeded cells keep their truth). The
    motion terms are not drawn (nominal zero; a cell's motion_history sets them). A fixed frame's
    six take the deviation of its mount, and the parameters of the row after it that they duplicate
    exactly (a DH row's theta, d, sx, sy) stay nominal: one deviation, drawn once (what the
    calibration estimates, identifiability keeping the frame's)."""
    true = robot.nominal_parameters()
    framed = set(robot.framed_parameters)
    low, high = pert.compliance_range
    for name in robot.parameter_names:
        kind, owner = split_name(name)
        if kind in MOTION_KINDS or name in framed:
            continue
        if kind == MASS_KIND:  # a body group's mass scale, nominal 1
            true[name] += float(rng.uniform(-pert.mass_scale, pert.mass_scale)) if pert.mass_scale else 0.0
            continue
        if owner == "base":
            # A base is leveled at installation (or its measured tilt is in the robot file):
            # its unknown rotation is about the vertical, plus an optional unmeasured tilt.
            width = {"rz": pert.base_angle_rad, "rx": pert.base_tilt_rad, "ry": pert.base_tilt_rad}.get(
                kind, pert.base_length_m
            )
        elif owner == "tool":
            width = pert.tool_length_m if kind.startswith("t") else pert.tool_angle_rad
        elif kind in ("d", "a", "tx", "ty", "tz"):
            width = pert.length_m
        elif kind in ("theta", "alpha"):
            width = pert.angle_rad
        elif kind in ("sx", "sy", "rx", "ry", "rz"):
            width = pert.distortion_rad
        else:  # compliance
            if owner in pert.compliant_joints and high > 0:
                true[name] = float(rng.uniform(low, high))
            continue
        true[name] += float(rng.uniform(-width, width))
    return true
