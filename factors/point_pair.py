"""Point-pair factors of the seed's relative formulation (SPEC section 4, eq. 3)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.compiled import compiled
from ..core.se3 import skew
from .base import Evaluation, MeasurementSet, RobustLoss, row_starts
from .kinematics import Kinematics, params_variable


def helmert(count: int) -> np.ndarray:
    """(count-1, count) orthonormal contrasts: rows sum to zero and are orthonormal.

    Row 0 is (e_1 - e_2)/sqrt(2); row r contrasts observation r+2 with the mean of the
    first r+1 ones.
    """
    rows = np.zeros((count - 1, count))
    for r in range(count - 1):
        k = r + 1
        rows[r, :k] = 1.0
        rows[r, k] = -k
        rows[r] /= np.sqrt(k * (k + 1))
    return rows


class PointPairs(MeasurementSet):
    """``r_g = H_g (X(P, q_j(o)) c_o - R_W_F p_o)`` over the observations o of group g  (m).

    Observation o: a point with drawing coordinates ``p_o`` (fixture frame F) measured at
    ``c_o`` in the camera frame at configuration j(o); X(P, q) is the camera pose from the
    kinematics. ``H_g`` holds orthonormal contrasts (:func:`helmert`): each row is a
    combination of the seed's point-pair residuals ``X_j c_u - X_k c_v + R_W_F (p_V - p_U)``
    (eq. 3; row 0 is the pair of the first two observations over sqrt 2), and together they
    carry every point pair of the group. With independent noise sigma per coordinate the
    rows have covariance sigma^2 I exactly, however many pairs share an observation. The
    unknown common position of the points (the base) cancels. ``R_W_F`` is a constant or,
    with ``fixture_key``, a Rot3 variable. The robust unit is the group.

    ``groups``: per group, (configuration index of each observation (O,), c (O, 3), p_F (O, 3)).
    """

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        groups: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]],
        sigma_m: float,
        fixture_key: int | None = None,
        fixture_rotation: np.ndarray | None = None,
        robust: RobustLoss | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.configs = np.concatenate([np.asarray(g[0], dtype=int) for g in groups])
        self.c = np.concatenate([np.asarray(g[1], dtype=float).reshape(-1, 3) for g in groups])
        self.p_F = np.concatenate([np.asarray(g[2], dtype=float).reshape(-1, 3) for g in groups])
        sizes = [len(g[0]) for g in groups]
        if min(sizes) < 2 or not len(self.configs) == len(self.c) == len(self.p_F):
            raise ValueError("a point-pair group needs at least two observations, each with a drawing point")
        self.contrasts = Contrasts(sizes)
        self.fixture_rotation = np.eye(3) if fixture_rotation is None else np.asarray(fixture_rotation, float)
        self.estimate_fixture = fixture_key is not None
        self.variables = params_variable(params_key, kinematics)
        if fixture_key is not None:
            self.variables.append((fixture_key, "rot3", None))
        self.sigma = np.full(3 * sum(n - 1 for n in sizes), float(sigma_m))
        self.unit_starts = row_starts([3 * (n - 1) for n in sizes])
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        released = self.params_key is not None
        params = inputs[0] if released else None
        R_W_F = inputs[-1].matrix() if self.estimate_fixture else self.fixture_rotation
        T = self.kinematics.poses(params)[self.configs]
        R = T[:, :3, :3]
        arm = np.einsum("oij,oj->oi", R, self.c)  # R_j c_o
        world = arm + T[:, :3, 3] - self.p_F @ R_W_F.T
        residual = (self.contrasts @ world).reshape(-1)
        if not jacobians:
            return Evaluation(residual, [])
        blocks = []
        if released:
            # d world_o / dP = [-R [c_o]x, R] J_j = R_j v_j + (R_j w_j) x (R_j c_o), with (w_j, v_j)
            # the rows of the body Jacobian J_j: turned per configuration, crossed per observation,
            # without an (O, 6, m) copy of the Jacobians.
            # Block by block of whole groups, so no (O, 3, m) array is ever alive: at thousands of
            # configurations it would set the command's peak memory.
            J = self.kinematics.jacobians(params)
            R_all = self.kinematics.poses(params)[:, :3, :3]
            turned, moved = R_all @ J[:, :3], R_all @ J[:, 3:]  # (N, 3, m)
            block = np.empty((self.n_rows, J.shape[2]))
            for observations, rows, contrasts in self.contrasts.blocks:
                configs, lever = self.configs[observations], arm[observations]
                per_obs = moved[configs]
                for k in range(3):
                    a, b = (k + 1) % 3, (k + 2) % 3
                    per_obs[:, k] += turned[configs, a] * lever[:, b, None] - turned[configs, b] * lever[:, a, None]
                block[3 * rows.start : 3 * rows.stop] = _contrast(contrasts, per_obs)
            blocks.append(block)
        if self.estimate_fixture:
            # d(-R Exp(w) p)/dw = R [p]x
            blocks.append(_contrast(self.contrasts, R_W_F @ skew(self.p_F)))
        return Evaluation(residual, blocks)


# Observations per block of the contrasts (Contrasts.blocks): a block's Jacobian, (2048, 3, m),
# is a few MB at a full model's m.
BLOCK_OBSERVATIONS = 2048


class Contrasts:
    """The block-diagonal contrasts ``diag(helmert(n_1), helmert(n_2), ...)`` of consecutive
    groups of observations, applied as ``contrasts @ X`` in one pass, O(O c): row k (1..n-1)
    of a group is ``(sum_{i<k} x_i - k x_k) / sqrt(k (k+1))``, its sums running over the
    group's differences from its first observation (:func:`_helmert_rows`). A sparse product
    costs O(n^2) per group.

    ``blocks`` splits the groups into runs of about BLOCK_OBSERVATIONS observations (their
    observations, their contrast rows and their contrasts), for a caller that builds its
    input block by block."""

    def __init__(self, sizes: Sequence[int]) -> None:
        self.sizes = np.asarray(sizes, dtype=np.int64)
        self.shape = (int(self.sizes.sum()) - len(self.sizes), int(self.sizes.sum()))
        self.blocks: list[tuple[slice, slice, Contrasts]] = []
        if len(self.sizes) <= 1 or self.shape[1] <= BLOCK_OBSERVATIONS:
            self.blocks.append((slice(0, self.shape[1]), slice(0, self.shape[0]), self))
            return
        first_group, first_obs, first_row = 0, 0, 0
        while first_group < len(self.sizes):
            last, count = first_group + 1, int(self.sizes[first_group])
            while last < len(self.sizes) and count + self.sizes[last] <= BLOCK_OBSERVATIONS:
                count += int(self.sizes[last])
                last += 1
            block = self.sizes[first_group:last]
            observations = slice(first_obs, first_obs + count)
            rows = slice(first_row, first_row + count - len(block))
            self.blocks.append((observations, rows, Contrasts(block)))
            first_group, first_obs, first_row = last, observations.stop, rows.stop

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=float)
        out = np.empty((self.shape[0], *x.shape[1:]))
        _helmert_rows(x.reshape(len(x), -1), self.sizes, out.reshape(len(out), -1))
        return out


@compiled
def _helmert_rows(x, sizes, out):
    """``out`` (O - G, c) = diag(helmert(n_g)) ``x`` (O, c), group by group. The running sum is
    of each observation's difference from its group's first (the rows sum to zero, so the
    group's constant cancels): its rounding is that of the group's differences, not of
    positions metres from the origin, nor of other groups."""
    running = np.zeros(x.shape[1])
    first, row = 0, 0
    for n in sizes:
        running[:] = 0.0
        for k in range(1, n):
            scale = 1.0 / np.sqrt(k * (k + 1.0))
            for c in range(x.shape[1]):
                origin = x[first, c]
                running[c] += x[first + k - 1, c] - origin
                out[row, c] = (running[c] - k * (x[first + k, c] - origin)) * scale
            row += 1
        first += n


def _contrast(contrasts: Contrasts, per_obs: np.ndarray) -> np.ndarray:
    """(O, 3, c) per observation -> (rows, c) through the contrasts."""
    n_obs, _, cols = per_obs.shape
    return (contrasts @ per_obs.reshape(n_obs, 3 * cols)).reshape(-1, cols)
