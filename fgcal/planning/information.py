"""What each candidate configuration tells about the unknowns: whitened Jacobian rows.

Columns are the identifiable parameters of the cell's model and formulation, then the
auxiliary unknowns of the formulation:

- camera (pairs, projection): the block's four points in the camera frame,
  ``p_C = R_C_W (T_W_F p_F - t_W_C)``, sigma the cell's camera point sigma; auxiliary: the
  fixture translation (the relative pairs do not see it), and its rotation when the
  formulation estimates it (projection).
- tracker: the reflectors in the tracker frame, ``p_T = T_T_W T_W_n(q) s_t``, sigma the
  cell's tracker sigma; auxiliary: the tracker pose and the reflector positions s_t.

A point pair is the difference of two such point measurements, so the absolute points in
an unknown fixture frame carry the same information about the robot as the pairs that
connect every image (up to the translation the pairs never see). The region where accuracy
counts is the scored point (the mean block point in the camera frame, or the first
reflector) over the candidates, with the score's gauge removed, as the calibration's own
prediction does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..calibration.config import CalibrationConfig
from ..calibration.formulations import formulation as registered
from ..calibration.gauge import without_gauge
from ..calibration.identifiability import parameter_scale, select
from ..calibration.problem import candidate_parameters
from ..core.se3 import inverse, skew, transform_points
from ..model import kinematics
from ..model.robot import Robot
from ..simulation.cell import Cell
from .candidates import Candidates

PRIOR_SIGMA_AUX = {"translation": 1.0, "rotation": 1.0, "reflector": 0.1}  # m, rad, m: weak priors


@dataclass
class Information:
    names: list[str]  # identifiable parameters
    aux_labels: list[str]
    rows: np.ndarray  # (M, r, p) whitened rows of each candidate, p = len(names) + len(aux_labels)
    prior: np.ndarray  # (p,) prior information 1 / sigma^2
    region: np.ndarray  # (3E, p) scored-point Jacobian over the region (m per unit), gauge removed
    scale: np.ndarray  # (len(names),) plausible deviation of each parameter (for the indices)
    unidentifiable: dict[str, str]
    sigma_m: float  # measurement sigma
    gauge: str

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def n_region(self) -> int:
        return self.region.shape[0] // 3


def _camera_rows(
    robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str], rotation: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows on the parameters and on the fixture, and the block points in the camera frame."""
    T_C_W = inverse(kinematics.frame_pose(robot, data, "tool"))
    J_body = kinematics.jacobian(robot, data, names, frame="tool")  # (M, 6, m)
    p_W = transform_points(cell.fixture_pose[None, None], cand.points_F)  # (M, 4, 3)
    p_C = transform_points(T_C_W[:, None], p_W)
    # The camera moves by its body twist (w, v): d p_C = p_C x w - v = [skew(p_C), -I] (w, v).
    lever = np.concatenate([skew(p_C), np.broadcast_to(-np.eye(3), (*p_C.shape, 3))], axis=-1)  # (M, 4, 3, 6)
    J_p = (lever @ J_body[:, None]).reshape(len(cand.q), -1, len(names))
    R_C_W = T_C_W[:, None, :3, :3]
    # The fixture moves in W by (w, t): d p_W = w x p_W + t.
    blocks = [np.broadcast_to(R_C_W, (*p_C.shape, 3))]
    if rotation:
        blocks.insert(0, -R_C_W @ skew(p_W))
    J_aux = np.concatenate(blocks, axis=-1).reshape(len(cand.q), -1, 3 * len(blocks))
    return J_p, J_aux, p_C


def _tracker_rows(
    robot: Robot, data: kinematics.KinematicsData, cell: Cell, cand: Candidates, names: list[str]
) -> tuple[np.ndarray, np.ndarray]:
    R_T_W = cell.tracker_pose[:3, :3].T
    n_conf, n_targets = len(cand.q), len(cell.tracker_targets)
    tips = cell.tracker_target_tips or ("flange",) * n_targets  # a tree's reflectors: on their tips
    J_p = np.zeros((n_conf, 3 * n_targets, len(names)))
    J_aux = np.zeros((n_conf, 3 * n_targets, 6 + 3 * n_targets))
    for t, s in enumerate(cell.tracker_targets):
        rows = slice(3 * t, 3 * t + 3)
        T_W_n = kinematics.frame_pose(robot, data, tips[t])
        J_p[:, rows] = R_T_W @ kinematics.jacobian(robot, data, names, frame=tips[t], point=s)
        p_W = transform_points(T_W_n, s)
        # The tracker moves in W by (w, t): d p_T = R_T_W (p_W x w - t); the reflector by d s.
        J_aux[:, rows, :3] = R_T_W @ skew(p_W)
        J_aux[:, rows, 3:6] = -R_T_W
        J_aux[:, rows, 6 + 3 * t : 9 + 3 * t] = R_T_W @ T_W_n[:, :3, :3]
    return J_p, J_aux


def build_information(
    cell: Cell,
    robot: Robot,
    cand: Candidates,
    config: CalibrationConfig,
    reference: np.ndarray,
    n_region: int = 400,
    seed: int = 0,
) -> Information:
    """Rows of every candidate on the parameters identifiable from the ``reference``
    candidates (indices: a generous space-filling design, so that the plan's unknowns are
    those the cell can determine)."""
    names = candidate_parameters(robot, config.model, config.compliant_joints)
    params = robot.parameter_vector()
    data = kinematics.forward(robot, params, cand.q)
    formulation = registered(config.formulation)
    if formulation.instrument == "tracker":
        J_p, J_aux = _tracker_rows(robot, data, cell, cand, names)
        sigma = cell.tracker_sigma_m
        aux_labels = ["tracker.rx", "tracker.ry", "tracker.rz", "tracker.tx", "tracker.ty", "tracker.tz"]
        aux_labels += [f"reflector{t + 1}.{a}" for t in range(len(cell.tracker_targets)) for a in "xyz"]
        aux_sigma = [PRIOR_SIGMA_AUX["rotation"]] * 3 + [PRIOR_SIGMA_AUX["translation"]] * 3
        aux_sigma += [PRIOR_SIGMA_AUX["reflector"]] * (3 * len(cell.tracker_targets))
        frame = cell.tracker_target_tips[0] if cell.tracker_target_tips else "flange"
        gauge, point = "none", cell.tracker_targets[0]
    else:
        rotation = formulation.fixture_rotation_unknown(config.measurement)
        J_p, J_aux, p_C = _camera_rows(robot, data, cell, cand, names, rotation)
        sigma = cell.camera_point_sigma_m
        aux_labels = (["fixture.rx", "fixture.ry", "fixture.rz"] if rotation else []) + [
            "fixture.tx",
            "fixture.ty",
            "fixture.tz",
        ]
        aux_sigma = ([PRIOR_SIGMA_AUX["rotation"]] * 3 if rotation else []) + [PRIOR_SIGMA_AUX["translation"]] * 3
        gauge = "rigid" if rotation else "translation"
        point, frame = p_C.reshape(-1, 3).mean(axis=0), "tool"
    J_p, J_aux = J_p / sigma, J_aux / sigma
    moments = data.moments[reference]
    identifiability = select(
        J_p[reference].reshape(-1, len(names)),
        J_aux[reference].reshape(-1, J_aux.shape[2]),
        names,
        moments,
        config.min_information,
    )
    keep = [names.index(n) for n in identifiability.identifiable]
    kept = [names[i] for i in keep]
    moments_rms = np.sqrt(np.mean(moments**2, axis=0))
    scale = np.array([parameter_scale(n, moments_rms) for n in kept])
    region_q = cand.q[np.random.default_rng(seed).permutation(len(cand.q))[:n_region]]
    region_data = kinematics.forward(robot, params, region_q)
    G = kinematics.jacobian(robot, region_data, kept, frame=frame, point=point)  # (E, 3, m)
    positions = transform_points(kinematics.frame_pose(robot, region_data, frame), point)
    G = without_gauge(G.reshape(-1, len(kept)), positions, gauge)
    region = np.hstack([G, np.zeros((G.shape[0], J_aux.shape[2]))])
    return Information(
        names=kept,
        aux_labels=aux_labels,
        rows=np.concatenate([J_p[:, :, keep], J_aux], axis=2),
        prior=np.concatenate([1.0 / scale**2, 1.0 / np.array(aux_sigma) ** 2]),
        region=region,
        scale=scale,
        unidentifiable=identifiability.unidentifiable,
        sigma_m=sigma,
        gauge=gauge,
    )
