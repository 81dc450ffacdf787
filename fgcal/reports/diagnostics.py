"""What is left after the calibration, and what explains it: the held-out error of each
configuration against each joint's last move, the order of measurement and each joint's
angle (residual_diagnostics.png), and the motion history's fitted terms (report.json
``motion_history``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..calibration.results import CalibrationResult, primary_score
from ..core.outputs import save_figure


def held_out_by_configuration(result: CalibrationResult) -> tuple[np.ndarray, np.ndarray] | None:
    """The dataset indices of the held-out configurations and the RMS (m) of each one's
    held-out errors after calibration (over its scored points); None without a per-point score."""
    scored = primary_score(result.validation, "after")
    if scored is None or scored[1].configs is None:
        return None
    test = result.problem.test
    errors, configs = scored[1].errors, np.asarray(scored[1].configs, dtype=int)
    if not len(configs) or configs.max() >= len(test):
        return None
    present = np.unique(configs)
    rms = np.array([np.sqrt(np.mean(errors[configs == c] ** 2)) for c in present])
    return test[present], rms


def motion_terms(result: CalibrationResult) -> dict | None:
    """The fitted lost motion and speed term per joint (rad, or m for a prismatic joint) with
    their sigmas (None: fixed, unidentifiable), for a model with the motion history."""
    robot = result.problem.robot
    if not robot.history:
        return None
    names = robot.parameter_names
    sigmas = dict(zip(result.released, np.sqrt(np.diag(result.parameter_covariance)), strict=True))
    out: dict[str, list] = {"lost_motion": [], "lost_motion_sigma": [], "speed": [], "speed_sigma": []}
    for i in range(1, robot.n_joints + 1):
        for kind, key in (("lm", "lost_motion"), ("lv", "speed")):
            name = f"{kind}{i}"
            out[key].append(float(result.state.params[names.index(name)]))
            out[f"{key}_sigma"].append(float(sigmas[name]) if name in sigmas else None)
    return {"unit": "rad", "per_joint": out, "prismatic": [bool(p) for p in robot.prismatic]}


def plot_residual_diagnostics(result: CalibrationResult, out: Path) -> str | None:
    """residual_diagnostics.png: per held-out configuration its error (mm) against each joint's
    last move (deg; configurations whose history is unknown left out), against the order of
    measurement, and against each joint's angle (deg). None without a per-point score."""
    from matplotlib.figure import Figure

    by_config = held_out_by_configuration(result)
    if by_config is None:
        return None
    rows, rms = by_config
    dataset = result.problem.dataset
    q = dataset.q[rows]
    move = q - dataset.motion_history.before[rows]
    prismatic = result.problem.robot.prismatic
    scale = np.where(prismatic, 1e3, np.degrees(1.0))  # mm for a prismatic joint, else deg
    unit = ["mm" if p else "deg" for p in prismatic]
    n = q.shape[1]
    error_mm = rms * 1e3
    fig = Figure(figsize=(2.3 * n, 7.2))
    # Only the axes drawn (an axes costs about 10 ms to build); a row shares its error axis,
    # whose tick labels then show once.
    grid = fig.add_gridspec(3, n, left=0.05, right=0.99, bottom=0.07, top=0.93, wspace=0.3, hspace=0.45)
    moves, angles = [fig.add_subplot(grid[0, 0])], [fig.add_subplot(grid[2, 0])]
    for j in range(1, n):
        moves.append(fig.add_subplot(grid[0, j], sharey=moves[0]))
        angles.append(fig.add_subplot(grid[2, j], sharey=angles[0]))
    known = np.all(np.isfinite(move), axis=1)
    for j in range(n):
        moves[j].scatter(move[known, j] * scale[j], error_mm[known], s=4, alpha=0.6, edgecolors="none")
        moves[j].set_xlabel(f"last move of joint {j + 1} ({unit[j]})", fontsize=8)
        angles[j].scatter(q[:, j] * scale[j], error_mm, s=4, alpha=0.6, edgecolors="none")
        angles[j].set_xlabel(f"joint {j + 1} ({unit[j]})", fontsize=8)
        if j:
            moves[j].tick_params(labelleft=False)
            angles[j].tick_params(labelleft=False)
    for ax in (moves[0], angles[0]):
        ax.set_ylabel("held-out error (mm)", fontsize=8)
    timeline = fig.add_subplot(grid[1, :])
    timeline.scatter(rows, error_mm, s=5, alpha=0.7, edgecolors="none")
    timeline.set_xlabel("configuration, in the order measured (row of configurations.csv)", fontsize=8)
    timeline.set_ylabel("held-out error (mm)", fontsize=8)
    for ax in [*moves, *angles, timeline]:
        ax.tick_params(labelsize=7)
    fig.suptitle(
        "Held-out error per configuration (RMS over its points) against each joint's last move, the order of "
        "measurement and each joint's angle",
        fontsize=9,
    )
    save_figure(fig, out / "residual_diagnostics.png", dpi=90, pil_kwargs={"compress_level": 1})
    return "residual_diagnostics.png"
