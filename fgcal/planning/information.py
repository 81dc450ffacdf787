"""What each candidate configuration tells about the unknowns: whitened Jacobian rows.

Columns are the identifiable parameters of the cell's model and formulation, then the
auxiliary unknowns of the formulation. What the formulation measures at a candidate (its
rows, auxiliary unknowns and their prior sigmas, the measurement sigma, the scored point and
the gauge) is its own: ``Formulation.planning`` (fgcal.calibration.plan_model). The region
where accuracy counts is the scored point over the candidates, with the score's gauge
removed, as the calibration's own prediction does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..calibration.config import CalibrationConfig
from ..calibration.gauge import without_gauge
from ..calibration.identifiability import parameter_scale, select
from ..calibration.plan_model import Candidates, PairRows, Planning
from ..calibration.problem import candidate_parameters
from ..core.se3 import transform_points
from ..model import kinematics
from ..model.motion import MotionHistory, features
from ..model.robot import Robot
from ..simulation.cell import Cell


@dataclass(frozen=True)
class GroupRows:
    """The rows of the pairs' exact groups (plan_model.PairRows) on the plan's columns."""

    rows: np.ndarray  # (M, r, p) whitened, ungrouped
    turn: np.ndarray  # (M, 3, 3) R_W_C
    size: int


@dataclass
class Information:
    names: list[str]  # identifiable parameters
    aux_labels: list[str]
    rows: np.ndarray  # (M, r, p) whitened rows of each candidate, p = len(names) + len(aux_labels)
    prior: np.ndarray  # (p,) prior information 1 / sigma^2
    region: np.ndarray  # (3E, p) scored-point Jacobian over the region (m per unit), gauge removed
    scale: np.ndarray  # (len(names),) plausible deviation of each parameter (for the indices)
    unidentifiable: dict[str, str]
    sigma_m: float  # measurement sigma (in ``unit``)
    gauge: str
    unit: str = "m"  # of the measurement sigma: m or px
    fixed: np.ndarray | None = None  # (p, p) information every design has (known distances), or None
    # Pairs: each candidate's rows before the pair groups (M, r, p) as ``rows``, their turn into
    # W (M, 3, 3) and the group size; None: no groups (fgcal.planning.groups).
    grouping: GroupRows | None = None

    @property
    def prior_matrix(self) -> np.ndarray:
        """The information before any configuration: the priors and the fixed rows."""
        M = np.diag(self.prior)
        return M if self.fixed is None else M + self.fixed

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def n_region(self) -> int:
        return self.region.shape[0] // 3


def build_information(
    cell: Cell,
    robot: Robot,
    cand: Candidates,
    config: CalibrationConfig,
    planning: Planning,
    reference: np.ndarray,
    n_region: int = 400,
    seed: int = 0,
    before: np.ndarray | None = None,
    region_before: Callable[[np.ndarray], np.ndarray | None] | None = None,
) -> Information:
    """Rows of every candidate on the parameters identifiable from the ``reference``
    candidates (indices: a generous space-filling design, so that the plan's unknowns are
    those the cell can determine); ``planning``: what the config's formulation measures.
    ``before`` (M, n): each candidate's approach point, whose move a model with the motion
    history's terms sees (None: not known, no such offsets); ``region_before``: the approach
    points of the region's configurations, drawn as the candidates'."""
    names = candidate_parameters(robot, config.model, config.compliant_joints)
    params = robot.parameter_vector()
    data = kinematics.forward(robot, params, cand.q, _motion(cand.q, before))
    measured = planning.rows(robot, data, cell, cand, names)
    J_p, J_aux, frame, point, gauge = measured.params, measured.aux, measured.frame, measured.point, measured.gauge
    moments = data.moments[reference]
    aux_rows = J_aux[reference].reshape(-1, J_aux.shape[2])
    param_rows = J_p[reference].reshape(-1, len(names))
    if measured.fixed is not None:  # rows every design has count for the identifiability too
        aux_rows = np.vstack([aux_rows, measured.fixed])
        param_rows = np.vstack([param_rows, np.zeros((len(measured.fixed), len(names)))])
    identifiability = select(
        param_rows,
        aux_rows,
        names,
        moments,
        config.min_information,
    )
    keep = [names.index(n) for n in identifiability.identifiable]
    kept = [names[i] for i in keep]
    moments_rms = np.sqrt(np.mean(moments**2, axis=0))
    scale = np.array([parameter_scale(n, moments_rms) for n in kept])
    # Where accuracy counts: the workspace the formulation gives, else the candidates.
    pool = cand.q if cand.workspace is None else cand.workspace
    region_q = pool[np.random.default_rng(seed).permutation(len(pool))[:n_region]]
    region_data = kinematics.forward(
        robot, params, region_q, _motion(region_q, None if region_before is None else region_before(region_q))
    )
    G = kinematics.jacobian(robot, region_data, kept, frame=frame, point=point)  # (E, 3, m)
    positions = transform_points(kinematics.frame_pose(robot, region_data, frame), point)
    G = without_gauge(G.reshape(-1, len(kept)), positions, gauge)
    region = np.hstack([G, np.zeros((G.shape[0], J_aux.shape[2]))])
    return Information(
        names=kept,
        aux_labels=measured.aux_labels,
        rows=np.concatenate([J_p[:, :, keep], J_aux], axis=2),
        prior=np.concatenate([1.0 / scale**2, 1.0 / measured.aux_sigma**2]),
        region=region,
        scale=scale,
        unidentifiable=identifiability.unidentifiable,
        sigma_m=measured.sigma_m,
        gauge=gauge,
        unit=measured.unit,
        fixed=None if measured.fixed is None else _fixed(measured.fixed, len(kept)),
        grouping=group_rows(measured.grouping, keep),
    )


def group_rows(grouping: PairRows | None, keep: list[int]) -> GroupRows | None:
    if grouping is None:
        return None
    rows = np.concatenate([grouping.params[:, :, keep], grouping.aux], axis=2)
    return GroupRows(rows, grouping.turn, grouping.size)


def _motion(q: np.ndarray, before: np.ndarray | None) -> np.ndarray | None:
    """The motion history's features (N, 2n) of configurations reached from ``before`` at the
    program's speed, or None."""
    if before is None:
        return None
    return features(q, MotionHistory(before, np.ones(len(q))))


def _fixed(rows: np.ndarray, n_params: int) -> np.ndarray:
    """The information (p, p) of rows on the auxiliary unknowns alone, p = parameters + aux."""
    F = np.zeros((n_params + rows.shape[1],) * 2)
    F[n_params:, n_params:] = rows.T @ rows
    return F
