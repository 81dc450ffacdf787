"""The robot's motion history: how each configuration was reached, and the joint offsets it
causes (docs/model.md, "Motion history").

Per joint i, the chain sees, at a configuration reached by the move ``dq = q - q_before``::

    q_i' = q_i + lm_i tanh(dq_i / w) + lv_i v_i,        v_i = s dq_i / max_j |dq_j|

- ``lm_i`` (rad): lost motion, half the dead band a joint crosses when its motion reverses
  (gear backlash, elasticity against friction); it is taken up over ``w`` = 1 deg of travel.
- ``lv_i`` (rad): an offset proportional to the joint's speed in the last move. In a
  synchronised joint move every joint arrives together, so its speed is its share of the
  largest move, ``dq_i / max_j |dq_j|``, times the configuration's speed factor ``s`` (1 by
  default: the program's speed; 0.5 at half speed).

A configuration whose history is unknown (the first one measured, or a dataset whose rows are
not in measurement order) has no offsets: its features are zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .parameters import MOTION_KINDS

__all__ = ["LOST_MOTION_WIDTH_RAD", "MOTION_KINDS", "MotionHistory", "features"]

LOST_MOTION_WIDTH_RAD = float(np.radians(1.0))
# Below this, a move is no move (rad or m): the configuration was measured twice in a row.
STILL = 1e-9


@dataclass(frozen=True)
class MotionHistory:
    """How each of N configurations was reached: the joint values before its last move
    (N, n; rad or m; a row of NaN: unknown) and the move's speed factor (N,)."""

    before: np.ndarray
    speed: np.ndarray

    def __post_init__(self) -> None:
        before = np.asarray(self.before, dtype=float)
        speed = np.asarray(self.speed, dtype=float)
        if before.ndim != 2 or speed.shape != (before.shape[0],):
            raise ValueError(f"history shapes {before.shape} and {speed.shape} do not match")
        object.__setattr__(self, "before", before)
        object.__setattr__(self, "speed", speed)

    @staticmethod
    def in_order(q: np.ndarray, speed: np.ndarray | None = None) -> MotionHistory:
        """Configurations measured in the order given: each was reached from the one before
        (the first from an unknown state)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        before = np.vstack([np.full((1, q.shape[1]), np.nan), q[:-1]])
        return MotionHistory(before, np.ones(len(q)) if speed is None else speed)

    @staticmethod
    def unknown(n_configurations: int, n_joints: int) -> MotionHistory:
        return MotionHistory(np.full((n_configurations, n_joints), np.nan), np.ones(n_configurations))

    def subset(self, rows: np.ndarray) -> MotionHistory:
        return MotionHistory(self.before[rows], self.speed[rows])

    def known(self) -> np.ndarray:
        """(N,) True where the configuration's history is known."""
        return np.all(np.isfinite(self.before), axis=1)


def features(q: np.ndarray, history: MotionHistory | None) -> np.ndarray:
    """The (N, 2n) factors of lm_1..lm_n, lv_1..lv_n in each configuration's joint offsets."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    out = np.zeros((q.shape[0], 2 * q.shape[1]))
    if history is None:
        return out
    if history.before.shape != q.shape:
        raise ValueError(f"history of shape {history.before.shape} for joint values of shape {q.shape}")
    known = history.known()
    move = np.where(known[:, None], q - np.where(known[:, None], history.before, 0.0), 0.0)
    largest = np.abs(move).max(axis=1, keepdims=True)
    moved = largest[:, 0] > STILL
    n = q.shape[1]
    out[:, :n] = np.tanh(move / LOST_MOTION_WIDTH_RAD)
    out[moved, n:] = history.speed[moved, None] * move[moved] / largest[moved]
    return out
