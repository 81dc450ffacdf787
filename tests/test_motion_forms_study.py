"""Issue 25's study of the motion history's functional form on the real FARO set, on demand
(``pytest -m study tests/test_motion_forms_study.py``, about 3 minutes): the table in
docs/calibration.md, "The form, and why".

Each candidate form adds, per joint, a joint offset coefficient times a feature of the last move.
Starting from fgcal's DH,s,e calibration of one half (seed 0), every released parameter, the
tracker pose, the three reflectors and the coefficients are fitted by plain least squares
(numerical Jacobians) on that half and scored on the other; then the halves swap."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SHARED

from fgcal.calibration.config import CalibrationConfig
from fgcal.calibration.run import calibrate
from fgcal.core.se3 import so3_exp
from fgcal.model import kinematics

FARO = SHARED / "data" / "irb120_faro"
pytestmark = [pytest.mark.study, pytest.mark.skipif(not FARO.exists(), reason="../shared/data/irb120_faro is absent")]
AXIS_SPEEDS = np.radians([250, 250, 250, 320, 320, 420])  # IRB 120, deg/s


def _dahl(move: np.ndarray, width: float) -> np.ndarray:
    """Exponential take-up of the dead band, carried from move to move."""
    state, out = np.zeros(move.shape[1]), np.zeros_like(move)
    for t, dq in enumerate(move):
        sign = np.sign(dq)
        state = sign + (state - sign) * np.exp(-np.abs(dq) / width)
        out[t] = state
    return out


def _forms(move: np.ndarray) -> dict[str, np.ndarray]:
    time = np.max(np.abs(move) / AXIS_SPEEDS, axis=1, keepdims=True)
    time[time == 0] = 1.0
    largest = np.maximum(np.abs(move).max(axis=1, keepdims=True), 1e-12)
    share = move / largest
    forms = {"none": np.zeros((len(move), 0)), "sign": np.sign(move), "linear": move,
             "speed": move / time * 0.01, "share": share, "share+sign": np.hstack([share, np.sign(move)])}  # fmt: skip
    for width in (1, 30):
        forms[f"tanh{width}"] = np.tanh(move / np.radians(width))
    forms["dahl3"] = _dahl(move, np.radians(3))
    return forms


def test_the_share_of_the_move_explains_most_on_both_halves(tmp_path):
    from fgcal.data.faro import convert_faro

    convert_faro(FARO, tmp_path / "faro")
    config = CalibrationConfig.defaults(
        tmp_path / "faro", formulation="tracker", units={"length": "mm"}, noise={"tracker_sigma": 0.05},
        validation={"holdout": 0.5, "seed": 0},
    )  # fmt: skip
    result = calibrate(config)
    robot, dataset, state = result.problem.robot, result.problem.dataset, result.state
    table = dataset.tables["tracker_points"]
    config = dataset.config_index(np.asarray(table.ids["config"]))
    labels = list(state.aux["tool_points"].labels)
    target = np.array([labels.index(t) for t in table.ids["target"]])
    names = list(result.released)
    index = [robot.parameter_names.index(n) for n in names]
    L0, S0 = state.value("tracker"), state.value("tool_points")
    move = np.vstack([np.zeros((1, 6)), np.diff(dataset.q, axis=0)])

    def residuals(x: np.ndarray, F: np.ndarray, rows: np.ndarray) -> np.ndarray:
        params = state.params.copy()
        params[index] = x[: len(names)]
        k = len(names)
        xi, S, b = x[k : k + 6], S0 + x[k + 6 : k + 15].reshape(3, 3), x[k + 15 :]
        q = dataset.q + sum(F[:, j * 6 : (j + 1) * 6] * b[j * 6 : (j + 1) * 6] for j in range(F.shape[1] // 6))
        used = np.unique(config[rows])
        X = kinematics.frame_pose(robot, kinematics.forward(robot, params, q[used]), "flange")
        at = np.searchsorted(used, config[rows])
        R = so3_exp(xi[3:]) @ L0[:3, :3]
        p = np.einsum("oij,oj->oi", X[at, :3, :3], S[target[rows]]) + X[at, :3, 3]
        return (p @ R.T + L0[:3, 3] + xi[:3] - table.values[rows]).ravel()

    def held_out(F: np.ndarray, fit: np.ndarray, test: np.ndarray) -> float:
        x = np.zeros(len(names) + 15 + F.shape[1])
        x[: len(names)] = state.params[index]
        for _ in range(8):
            e = residuals(x, F, fit)
            J = np.column_stack([(residuals(x + 1e-7 * np.eye(len(x))[c], F, fit) - e) / 1e-7 for c in range(len(x))])
            dx = np.linalg.lstsq(J, -e, rcond=None)[0]
            x += dx
            if np.abs(dx).max() < 1e-10:
                break
        return float(np.sqrt(np.mean(np.sum(residuals(x, F, test).reshape(-1, 3) ** 2, axis=1))))

    in_fit = np.isin(config, result.problem.fit)
    rms = {name: (held_out(F, in_fit, ~in_fit), held_out(F, ~in_fit, in_fit)) for name, F in _forms(move).items()}
    for name, (a, b) in rms.items():
        print(f"{name:10s} half A {a * 1e3:.3f} mm, half B {b * 1e3:.3f} mm")
    # docs/calibration.md's table: the share of the move wins on both halves, the sign alone does not.
    assert rms["share"][0] < 0.28e-3 and rms["share"][1] < 0.32e-3, rms
    assert rms["share"][0] < rms["sign"][0] < rms["none"][0] and rms["share"][1] < rms["sign"][1] < rms["none"][1]
