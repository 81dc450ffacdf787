"""``fgcal bench``: fgcal's batch solve against two baselines, and online latency, measured in
one run.

For each size (default 300 and 1000 configurations of the seed cell's space-filling design,
pair formulation, DH,s,e, the four stages), from the same start and with the same released
parameters per stage, on the same residuals (the point-pair contrasts of the same groups and
the length bounds):

1. fgcal: the stages on the factor graph (graph building included);
2. a bare NumPy Gauss-Newton with the analytic Jacobian (the shared kinematics, the contrasts
   as one sparse matrix), with backtracking and the same stopping rule;
3. ``scipy.optimize.least_squares`` with finite differences (trust-region reflective).

The methods run interleaved, ``repeats`` times each, and the best CPU time (and wall time) of
each is kept: the machine is shared, and the minimum is the least disturbed figure. Each
method's result is scored on the held-out configurations against the simulation's truth.
Online: ``OnlineCalibrator.add`` CPU time per image over the dataset's images, the best of
the repeats per image, then its median and 99th percentile.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from importlib import resources
from pathlib import Path

import gtsam
import numpy as np
import scipy.optimize
import scipy.sparse

from ..calibration.config import CalibrationConfig
from ..calibration.formulations.pairs import fixture_rotation
from ..calibration.graph import StageGraph, build_graph
from ..calibration.identifiability import analyse
from ..calibration.problem import Problem, read_state
from ..calibration.results import stats
from ..calibration.run import build_problem, calibrate_dataset
from ..calibration.scoring import truth_errors
from ..calibration.solve import ABSOLUTE_TOLERANCE, RELATIVE_TOLERANCE, solve_stage, stage_parameters
from ..calibration.state import State
from ..core.outputs import output_dir, write_text
from ..core.se3 import skew, so3_exp, so3_log
from ..data.dataset import load_dataset
from ..data.truth import load_truth
from ..factors.point_pair import helmert
from ..model import kinematics
from ..model.robot_io import robots_dir
from ..simulation.simulate import simulate
from .kernel import kernel_bench
from .programs import program_bench


class PairResiduals:
    """Whitened point-pair contrasts of all groups and the length bounds, as a function of
    the released parameters, with their analytic Jacobian: the baselines' residuals."""

    def __init__(self, problem: Problem, full_params: np.ndarray, released: list[str]) -> None:
        self.problem = problem
        self.base = full_params.copy()
        self.released = list(released)
        self.index = np.array([problem.robot.parameter_names.index(n) for n in released], dtype=int)
        groups = problem.observations.groups
        self.images = np.concatenate([g.configs for g in groups])
        self.c = np.concatenate([g.c for g in groups])
        self.p_W = np.concatenate([g.p_F for g in groups]) @ fixture_rotation(problem.dataset).T
        self.H = scipy.sparse.block_diag([helmert(len(g.c)) for g in groups], format="csr")
        self.sigma = problem.settings.noise.camera_point_m
        nominal = problem.robot.nominal_parameters()
        prior = [problem.priors.sigma(n) for n in released]
        self.bounded = np.array([i for i, sigma in enumerate(prior) if sigma is not None], dtype=int)
        self.bound_nominal = np.array([nominal[released[i]] for i in self.bounded])
        self.bound_sigma = np.array([prior[i] for i in self.bounded])

    def _poses(self, x: np.ndarray) -> tuple[kinematics.KinematicsData, np.ndarray]:
        params = self.base.copy()
        params[self.index] = x
        data = kinematics.forward(self.problem.robot, params, self.problem.observations.q)
        return data, kinematics.frame_pose(self.problem.robot, data, "tool")[self.images]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        _, T = self._poses(x)
        world = np.einsum("oij,oj->oi", T[:, :3, :3], self.c) + T[:, :3, 3] - self.p_W
        pairs = np.asarray(self.H @ world).reshape(-1) / self.sigma
        return np.concatenate([pairs, (x[self.bounded] - self.bound_nominal) / self.bound_sigma])

    def with_jacobian(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        data, T = self._poses(x)
        R = T[:, :3, :3]
        world = np.einsum("oij,oj->oi", R, self.c) + T[:, :3, 3] - self.p_W
        J = kinematics.jacobian(self.problem.robot, data, self.released, frame="tool")[self.images]
        per_obs = np.matmul(-R @ skew(self.c), J[:, :3]) + np.matmul(R, J[:, 3:])  # (O, 3, m)
        m = len(x)
        J_pairs = np.asarray(self.H @ per_obs.reshape(len(R), 3 * m)).reshape(-1, m) / self.sigma
        J_bounds = np.zeros((len(self.bounded), m))
        J_bounds[np.arange(len(self.bounded)), self.bounded] = 1.0 / self.bound_sigma
        residual = np.concatenate(
            [
                np.asarray(self.H @ world).reshape(-1) / self.sigma,
                (x[self.bounded] - self.bound_nominal) / self.bound_sigma,
            ]
        )
        return residual, np.vstack([J_pairs, J_bounds])


def gauss_newton(residuals: PairResiduals, x0: np.ndarray, max_iterations: int = 100) -> np.ndarray:
    """Gauss-Newton with column scaling, backtracking while the cost grows, and the same
    stopping rule as fgcal's solver (relative cost change below 1e-8)."""
    x = x0.copy()
    r, J = residuals.with_jacobian(x)
    cost = float(r @ r)
    for _ in range(max_iterations):
        scale = np.linalg.norm(J, axis=0)
        scale[scale == 0] = 1.0
        step = np.linalg.lstsq(J / scale, -r, rcond=None)[0] / scale
        t = 1.0
        while t >= 1e-4:
            candidate = residuals(x + t * step)
            new_cost = float(candidate @ candidate)
            if new_cost <= cost:
                break
            t /= 2.0
        else:
            break
        x = x + t * step
        converged = cost - new_cost <= 1e-8 * cost + 1e-14
        cost = new_cost
        if converged:
            break
        r, J = residuals.with_jacobian(x)
    return x


def _staged(problem: Problem, stages, identifiable: list[str], fit_stage: Callable) -> np.ndarray:
    params = problem.robot.parameter_vector()
    for kinds in stages:
        released = stage_parameters(kinds, identifiable)
        if released:
            residuals = PairResiduals(problem, params, released)
            params[residuals.index] = fit_stage(residuals, params[residuals.index])
    return params


def numpy_gauss_newton(problem: Problem, stages, identifiable: list[str]) -> np.ndarray:
    return _staged(problem, stages, identifiable, gauss_newton)


def scipy_finite_differences(problem: Problem, stages, identifiable: list[str]) -> np.ndarray:
    return _staged(
        problem,
        stages,
        identifiable,
        lambda residuals, x0: scipy.optimize.least_squares(residuals, x0, jac="2-point", method="trf").x,
    )


def fgcal_solve(problem: Problem, stages, identifiable: list[str]) -> np.ndarray:
    """fgcal's stages on the factor graph, GTSAM's LevenbergMarquardtOptimizer (the default)."""
    state = problem.formulation.initial_state(problem)
    for i, kinds in enumerate(stages, start=1):
        released = stage_parameters(kinds, identifiable)
        if released:
            state, _, _, _ = solve_stage(problem, str(i), released, state)
    return state.params


def hand_lm(stage: StageGraph, max_iterations: int) -> gtsam.Values:
    """Levenberg-Marquardt written out over the same graph, as fgcal's default solve was before
    it used GTSAM's optimiser: GTSAM's lambda schedule (1e-5, times or over 10, diagonal
    damping, the same stopping rule), each step by GTSAM's QR elimination. Kept as the
    yardstick that GTSAM's own optimiser must match in speed."""
    values, error = stage.values, stage.graph.error(stage.values)
    dims = {key: dim for _, (key, dim) in stage.dims.items()}
    damping, iterations = 1e-5, 0
    while iterations < max_iterations and damping < 1e5:
        iterations += 1
        linear = stage.graph.linearize(values)
        diagonal: dict[int, np.ndarray] = {}
        for i in range(linear.size()):
            A, _ = linear.at(i).jacobian()
            column = 0
            for key in linear.at(i).keys():  # noqa: SIM118 (a GaussianFactor, not a dict)
                diagonal[key] = diagonal.get(key, 0.0) + np.sum(A[:, column : column + dims[key]] ** 2, axis=0)
                column += dims[key]
        while damping < 1e5:
            damped = linear.clone()
            for key, d in diagonal.items():
                weights = np.sqrt(damping * np.clip(d, 1e-6, 1e32))
                damped.push_back(
                    gtsam.JacobianFactor(key, np.diag(weights), np.zeros(len(d)), gtsam.noiseModel.Unit.Create(len(d)))
                )
            candidate = values.retract(damped.optimize(gtsam.EliminateQR))
            new_error = stage.graph.error(candidate)
            if new_error < error:
                damping /= 10.0
                break
            damping *= 10.0
        else:
            break  # no step decreases the error: at the minimum to the precision available
        converged = error - new_error <= RELATIVE_TOLERANCE * error or error - new_error <= ABSOLUTE_TOLERANCE
        values, error = candidate, new_error
        if converged:
            break
    return values


def fgcal_hand_lm(problem: Problem, stages, identifiable: list[str]) -> np.ndarray:
    """The same stages and graphs, solved by hand_lm."""
    state = problem.formulation.initial_state(problem)
    for kinds in stages:
        released = stage_parameters(kinds, identifiable)
        if released:
            stage = build_graph(problem, released, state)
            state = read_state(state, stage.keys, hand_lm(stage, problem.max_iterations), stage.kinematics)
    return state.params


METHODS = {
    "fgcal": fgcal_solve,
    "hand_lm": fgcal_hand_lm,
    "numpy_gauss_newton": numpy_gauss_newton,
    "scipy_fd": scipy_finite_differences,
}


def _timed(function: Callable, *args) -> tuple[object, float, float]:
    cpu, wall = time.process_time(), time.perf_counter()
    out = function(*args)
    return out, time.process_time() - cpu, time.perf_counter() - wall


SEED_CELL = robots_dir().parent / "cells" / "kr125_seed.yaml"


_PEAK_MARK = "fgcal-bench-peak-rss-kB:"

# Runs the fgcal command and, at exit, prints the process's own peak RSS (VmHWM). wait4's
# ru_maxrss is no measure here: Linux carries the forking parent's peak across exec into it.
_REPORTING_CLI = f"""import atexit, sys
def _peak():
    try:
        status = open('/proc/self/status').read().splitlines()
    except OSError:  # not Linux: no figure
        return
    for line in status:
        if line.startswith('VmHWM:'):
            print('{_PEAK_MARK}', line.split()[1], file=sys.stderr)
atexit.register(_peak)
import fgcal.commands.cli
sys.exit(fgcal.commands.cli.main(sys.argv[1:]))
"""


def child_usage(command: list[str]) -> tuple[float, float, float]:
    """Run ``command``; its CPU seconds (user + system, the kernel's accounting of that one
    child: os.wait4) and wall seconds, and its peak RSS (MiB, 2^20 bytes) as it reports it (NaN when it
    does not: see ``_fgcal_command``)."""
    import os
    import subprocess
    import tempfile

    # stderr to a file, not a pipe: a child writing more than a pipe holds would block while
    # wait4 waits for it.
    with tempfile.TemporaryFile() as stderr:
        started = time.perf_counter()
        child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - started
        child.returncode = os.waitstatus_to_exitcode(status)
        stderr.seek(0)
        errors = stderr.read().decode(errors="replace")
    if child.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} exited with {child.returncode}: {errors[-2000:]}")
    peaks = [line.split()[1] for line in errors.splitlines() if line.startswith(_PEAK_MARK)]
    peak_mb = float(peaks[-1]) / 1024.0 if peaks else math.nan
    return usage.ru_utime + usage.ru_stime, wall, peak_mb


def _fgcal_command(*arguments: str) -> list[str]:
    import sys

    # -P: from a source checkout's root, the current folder must not hide the installed package.
    return [sys.executable, "-P", "-c", _REPORTING_CLI, *arguments]


def demo_bench(out: Path, repeats: int, say: Callable[[str], None]) -> dict:
    """``fgcal demo`` as a whole command (simulation, calibration, report with plots): its CPU
    seconds, the best of ``repeats``."""
    cpu, wall = [], []
    for _ in range(repeats):
        c, w, _ = child_usage(_fgcal_command("demo", "--out", str(out / "demo"), "-q"))
        cpu.append(c)
        wall.append(w)
    say(f"  fgcal demo: {min(cpu):.2f} s CPU, {min(wall):.2f} s wall")
    return {"demo_cpu_s": min(cpu), "demo_wall_s": min(wall)}


def memory_bench(out: Path, seed: int, n: int, say: Callable[[str], None]) -> dict:
    """Peak RSS of ``fgcal calibrate`` (report and plots included) on the seed cell at ``n``
    configurations."""
    from ..calibration.suggest import write_suggested_config
    from ..simulation.cell import load_cell

    data_dir = simulated_case(out, seed, n, say)
    config = write_suggested_config(load_cell(SEED_CELL), load_dataset(data_dir))  # as fgcal simulate does
    cpu, _, rss = child_usage(_fgcal_command("calibrate", str(config), "--out", str(out / f"memory_n{n}"), "-q"))
    say(
        f"  fgcal calibrate, seed cell at {n} configurations: peak RSS {rss:.0f} MiB ({rss * 1.048576:.0f} MB), "
        f"{cpu:.1f} s CPU"
    )
    # None (JSON null) where the platform has no /proc to report the peak from.
    peak = None if math.isnan(rss) else rss
    return {"memory_n_configurations": n, "memory_peak_rss_mb": peak, "memory_calibrate_cpu_s": cpu}


def simulated_case(out: Path, seed: int, n: int, say: Callable[[str], None]) -> Path:
    data_dir = out / f"seed{seed}_n{n}"
    if not (data_dir / "dataset.yaml").exists():
        say(f"simulating the seed cell, space-filling design of {n} configurations (seed {seed}) -> {data_dir}")
        simulate(
            SEED_CELL,
            data_dir,
            seed,
            design="space_filling",
            n_configurations=n,
        )
    return data_dir


def batch_bench(data_dir: Path, repeats: int, say: Callable[[str], None]) -> dict:
    dataset = load_dataset(data_dir)
    config = CalibrationConfig.defaults(data_dir)
    problem = build_problem(dataset, config)
    identifiable = analyse(
        build_graph(problem, problem.candidates, problem.formulation.initial_state(problem)), config.min_information
    ).identifiable
    say(
        f"  {len(dataset.configs)} configurations, {len(problem.fit)} for fitting, {problem.n_residuals} residuals, "
        f"{len(identifiable)} identifiable parameters, per stage "
        f"{[len(stage_parameters(k, identifiable)) for k in config.stages]}"
    )
    cpu = {name: [] for name in METHODS}
    wall = {name: [] for name in METHODS}
    params = {}
    for r in range(repeats):
        for name, method in METHODS.items():  # interleaved: each round runs every method once
            params[name], c, w = _timed(method, problem, config.stages, identifiable)
            cpu[name].append(c)
            wall[name].append(w)
        say(f"  round {r + 1}/{repeats}: " + ", ".join(f"{n} {cpu[n][-1]:.3f} s" for n in METHODS))
    truth = load_truth(data_dir)
    held_out = {
        name: stats(truth_errors(problem, State(p), truth)["tool_point"].errors).rms for name, p in params.items()
    }
    final = PairResiduals(problem, problem.robot.parameter_vector(), identifiable)
    chi2 = {name: float(np.sum(final(p[final.index]) ** 2)) for name, p in params.items()}
    return {
        "n_configurations": len(dataset.configs),
        "n_fit": len(problem.fit),
        "cpu_s": {n: min(v) for n, v in cpu.items()},
        "wall_s": {n: min(v) for n, v in wall.items()},
        "held_out_rms_m": held_out,
        "chi2": chi2,
        "max_parameter_difference": {
            name: float(np.max(np.abs(p - params["hand_lm"]))) for name, p in params.items() if name != "hand_lm"
        },
    }


def online_bench(data_dir: Path, repeats: int, compare_batch: bool) -> dict:
    """CPU time of OnlineCalibrator.add per image (best of the repeats per image); with
    ``compare_batch``, also a batch LM re-solve of the same graph and the online estimate's
    distance to it in sigma."""
    import gtsam

    from ..online import OnlineCalibrator
    from ..online.calibrator import params_key
    from ..online.feed import dataset_measurements

    dataset = load_dataset(data_dir)
    points = dataset.points_F()
    measurements = dataset_measurements(data_dir)
    per_image = np.full(len(measurements), np.inf)
    for r in range(repeats):
        calibrator = OnlineCalibrator(dataset.robot, dataset.camera, points, keep_graph=compare_batch and r == 0)
        for i, m in enumerate(measurements):
            _, cpu, _ = _timed(calibrator.add, m.q, list(m.pixels), m.cycle)
            per_image[i] = min(per_image[i], cpu)
        if compare_batch and r == 0:
            kept = calibrator
    per_image *= 1e3
    quarter = max(1, len(per_image) // 4)
    result = {
        "online_images": len(measurements),
        "online_median_ms": float(np.median(per_image)),
        "online_p99_ms": float(np.percentile(per_image, 99)),
        "online_max_ms": float(per_image.max()),
        "online_median_last_quarter_ms": float(np.median(per_image[-quarter:])),
    }
    if compare_batch:
        params = gtsam.LevenbergMarquardtParams()
        params.setLinearSolverType("MULTIFRONTAL_QR")
        params.setDiagonalDamping(True)
        batch, cpu, _ = _timed(gtsam.LevenbergMarquardtOptimizer(kept.graph, kept.batch_initial(), params).optimize)
        online = kept.current_params()[kept.model.index]
        difference = np.abs(online - batch.atVector(params_key(kept.cycle))) / kept.sigmas
        result["online_batch_resolve_s"] = cpu
        result["online_minus_batch_max_sigma"] = float(difference.max())
        result["online_minus_batch_worst"] = kept.released[int(np.argmax(difference))]
    return result


TRACKER_CELL = robots_dir().parent / "cells" / "irb120_tracker.yaml"
TRACKER_CYCLE = 10  # configurations per work cycle in the tracker cell's online figures


def tracker_online_bench(out: Path, seed: int, n: int, repeats: int, say: Callable[[str], None]) -> dict:
    """The laser-tracker cell's online recalibration through its formulation (issue 41): CPU
    time per measurement (best of the repeats per measurement) over ``n`` configurations fed
    in cycles of TRACKER_CYCLE, and the online estimate's distance to a batch LM re-solve of
    the same graph from the nominal model."""
    import gtsam

    from ..online import OnlineSettings
    from ..online.calibrator import params_key
    from ..online.feed import dataset_measurements
    from ..online.protocol import FormulationCalibrator

    data_dir = out / f"tracker_seed{seed}_n{n}"
    if not (data_dir / "dataset.yaml").exists():
        say(f"simulating the laser-tracker cell, space-filling design of {n} configurations (seed {seed})")
        simulate(TRACKER_CELL, data_dir, seed, design="space_filling", n_configurations=n)
    dataset = load_dataset(data_dir)
    measurements = dataset_measurements(data_dir, TRACKER_CYCLE)
    # The cell's light arm: compliances of 1e-5 to 5e-5 rad/(N m), a prior wider than the KR 125's.
    settings = OnlineSettings(prior_sigma_compliance=1e-4)
    per_measurement = np.full(len(measurements), np.inf)
    for r in range(repeats):
        calibrator = FormulationCalibrator(dataset, "tracker", settings, keep_graph=r == 0)
        for i, m in enumerate(measurements):
            _, cpu, _ = _timed(calibrator.fold, m)
            per_measurement[i] = min(per_measurement[i], cpu)
        if r == 0:
            kept = calibrator
    # The first TRACKER_CYCLE measurements are held back and folded in with the last of them:
    # their latencies are the holding back (microseconds) and that one update.
    per_measurement *= 1e3
    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    params.setDiagonalDamping(True)
    batch, cpu, _ = _timed(gtsam.LevenbergMarquardtOptimizer(kept.graph, kept.batch_initial(), params).optimize)
    difference = np.abs(kept.current_params()[kept.model.index] - batch.atVector(params_key(kept.cycle))) / kept.sigmas
    result = {
        "tracker_online_measurements": len(measurements),
        "tracker_online_cycle_size": TRACKER_CYCLE,
        "tracker_online_released": len(kept.released),
        "tracker_online_median_ms": float(np.median(per_measurement)),
        "tracker_online_p99_ms": float(np.percentile(per_measurement, 99)),
        "tracker_online_max_ms": float(per_measurement.max()),
        "tracker_online_batch_resolve_s": cpu,
        "tracker_online_minus_batch_max_sigma": float(difference.max()),
        "tracker_online_minus_batch_worst": kept.released[int(np.argmax(difference))],
    }
    say(
        f"  online, {len(measurements)} measurements in cycles of {TRACKER_CYCLE}, {len(kept.released)} released: "
        f"median {result['tracker_online_median_ms']:.2f} ms, p99 {result['tracker_online_p99_ms']:.2f} ms, max "
        f"{result['tracker_online_max_ms']:.2f} ms CPU per measurement; batch LM re-solve of the online graph "
        f"{cpu:.2f} s CPU; online estimate within {result['tracker_online_minus_batch_max_sigma']:.3f} sigma of it "
        f"({result['tracker_online_minus_batch_worst']})"
    )
    return result


# The FARO acceptance case: tracker formulation, DH,s,e, half the configurations held out.
FARO_CONFIG = {
    "formulation": "tracker",
    "units": {"length": "mm"},
    "noise": {"tracker_sigma": 0.05},
    "validation": {"holdout": 0.5, "seed": 0},
}


class TrackerDHResiduals:
    """Whitened tracker residuals ``(L (FK_DH(q_j) s_t) - m) / sigma`` of the fitting half as a
    function of x = (DH parameters, tracker rotation vector and translation, tool points): the
    plain DH fit a user would write with scipy."""

    def __init__(self, problem: Problem, released: list[str]) -> None:
        self.problem = problem
        self.base = problem.robot.parameter_vector()
        self.index = np.array([problem.robot.parameter_names.index(n) for n in released], dtype=int)
        observations = problem.observations
        self.j, self.t, self.measured = observations.configs, observations.targets, observations.measured
        self.sigma = problem.settings.noise.tracker_m

    def unpack(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The parameter vector, the tracker pose T_T_W and the tool points of x."""
        m = len(self.index)
        params = self.base.copy()
        params[self.index] = x[:m]
        T_L = np.eye(4)
        T_L[:3, :3], T_L[:3, 3] = so3_exp(x[m : m + 3]), x[m + 3 : m + 6]
        return params, T_L, x[m + 6 :].reshape(-1, 3)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        params, T_L, points = self.unpack(x)
        data = kinematics.forward(self.problem.robot, params, self.problem.observations.q)
        flange = kinematics.frame_pose(self.problem.robot, data, "flange")[self.j]
        p_W = np.einsum("oij,oj->oi", flange[:, :3, :3], points[self.t]) + flange[:, :3, 3]
        return ((p_W @ T_L[:3, :3].T + T_L[:3, 3] - self.measured) / self.sigma).reshape(-1)


def scipy_dh_fit(dataset_dir: Path, released: list[str]) -> tuple[Problem, State]:
    """The yardstick: load, start the tracker pose and tool points as fgcal does, and fit the
    DH parameters ``released`` with scipy least_squares and finite differences."""
    dataset = load_dataset(dataset_dir)
    config = CalibrationConfig.defaults(dataset_dir, **FARO_CONFIG, model="DH")
    problem = build_problem(dataset, config)
    start = problem.formulation.initial_state(problem)
    T_L, points = start.value("tracker"), start.value("tool_points")
    residuals = TrackerDHResiduals(problem, released)
    x0 = np.concatenate([residuals.base[residuals.index], so3_log(T_L[:3, :3]), T_L[:3, 3], points.reshape(-1)])
    solution = scipy.optimize.least_squares(residuals, x0, jac="2-point", method="trf")
    params, T_L, points = residuals.unpack(solution.x)
    return problem, start.with_params(params).with_aux(tracker=T_L, tool_points=points)


def faro_bench(dataset_dir: Path, out: Path, repeats: int, say: Callable[[str], None]) -> dict:
    """``fgcal calibrate`` on the FARO set as a whole command (a subprocess: start-up,
    loading, calibration, report with plots) against the plain scipy DH fit of the same
    fitting half (in this process), interleaved, best wall time of each."""
    import json

    import yaml

    config_path = write_text(
        output_dir(out) / "faro_calibrate.yaml", yaml.safe_dump({"dataset": str(dataset_dir.resolve()), **FARO_CONFIG})
    )
    dataset = load_dataset(dataset_dir)
    dh_config = CalibrationConfig.defaults(dataset_dir, **FARO_CONFIG, model="DH")
    problem = build_problem(dataset, dh_config)
    stage = build_graph(problem, problem.candidates, problem.formulation.initial_state(problem))
    released = [n for n in analyse(stage, dh_config.min_information).identifiable if "." not in n]
    command = _fgcal_command("calibrate", str(config_path), "--out", str(out / "faro_report"))
    wall = {"fgcal_calibrate_command": [], "scipy_dh_fit": [], "calibrate_dataset": []}
    cpu = {"fgcal_calibrate_command": [], "scipy_dh_fit": []}
    fgcal_config = CalibrationConfig.defaults(dataset_dir, **FARO_CONFIG)
    for r in range(repeats):
        c, w, _ = child_usage(command)
        cpu["fgcal_calibrate_command"].append(c)
        wall["fgcal_calibrate_command"].append(w)
        (dh_problem, dh_state), c, w = _timed(scipy_dh_fit, dataset_dir, released)
        cpu["scipy_dh_fit"].append(c)
        wall["scipy_dh_fit"].append(w)
        wall["calibrate_dataset"].append(_timed(calibrate_dataset, dataset, fgcal_config)[2])  # in this process
        say(f"  round {r + 1}/{repeats}: " + ", ".join(f"{n} {v[-1]:.2f} s" for n, v in wall.items()))
    report = json.loads((out / "faro_report" / "report.json").read_text(encoding="utf-8"))
    test, _ = dh_problem.formulation.test_observations(dh_problem, dh_state)
    dh_errors = stats(dh_problem.formulation.held_out_errors(dh_problem, test, dh_state)["tool_point"].errors).errors
    result = {
        "faro_wall_s": {n: min(v) for n, v in wall.items()},
        "faro_cpu_s": {n: min(v) for n, v in cpu.items()},
        "faro_dh_released": len(released),
        "faro_held_out_mean_m": {
            "fgcal": report["validation"]["after"]["position_error_m"]["mean"],
            "scipy_dh_fit": float(dh_errors.mean()),
        },
    }
    command_cpu, fit_cpu = result["faro_cpu_s"]["fgcal_calibrate_command"], result["faro_cpu_s"]["scipy_dh_fit"]
    say(
        f"  whole fgcal calibrate command {command_cpu:.2f} s CPU "
        f"({result['faro_wall_s']['fgcal_calibrate_command']:.2f} s wall), plain scipy DH fit ({len(released)} DH "
        f"parameters, finite differences) {fit_cpu:.2f} s CPU: {command_cpu / fit_cpu:.1f}x; held-out mean: fgcal "
        f"{result['faro_held_out_mean_m']['fgcal'] * 1e3:.3f} mm, DH fit "
        f"{result['faro_held_out_mean_m']['scipy_dh_fit'] * 1e3:.3f} mm"
    )
    say(f"  calibrate_dataset alone (no start-up, no report): {result['faro_wall_s']['calibrate_dataset']:.2f} s")
    return result


def run_bench(
    out: Path,
    seed: int = 1,
    sizes: tuple[int, ...] = (300, 1000),
    repeats: int = 3,
    say=print,
    faro: Path | None = None,
    memory_n: int = 3000,
    program_targets: int = 4000,
) -> dict:
    """Every figure of ``fgcal bench``; ``say`` gets the human-readable lines. ``faro``: a
    dataset converted from the IRB 120 / FARO set (``fgcal convert-faro``), timed too."""
    from threadpoolctl import threadpool_info

    say(
        f"fgcal bench: CPU and wall seconds, best of {repeats} interleaved round{'s' if repeats > 1 else ''}; "
        f"seed {seed}; threads of each BLAS library {[i.get('num_threads') for i in threadpool_info()]}"
    )
    result: dict = {"seed": seed, "repeats": repeats, "sizes": {}}
    for n in sizes:
        data_dir = simulated_case(out, seed, n, say)
        say(f"batch calibration, {n} configurations:")
        batch = batch_bench(data_dir, repeats, say)
        _print_batch(batch, say)
        say(f"online recalibration, {n} images:")
        online = online_bench(data_dir, repeats, compare_batch=n == sizes[0])
        _print_online(online, say)
        result["sizes"][str(n)] = {**batch, **online}
    say(f"online recalibration, laser-tracker cell, {sizes[0]} configurations:")
    result.update(tracker_online_bench(out, seed, sizes[0], repeats, say))
    say("planning:")
    result.update(plan_bench(repeats, say))
    say("kinematics:")
    result.update(kernel_bench(repeats, say))
    say("whole commands:")
    result.update(demo_bench(out, repeats, say))
    result.update(memory_bench(out, seed, memory_n, say))
    say("program filtering:")
    calibrated = out / f"memory_n{memory_n}" / "calibrated_robot.yaml"  # the memory bench's calibration
    result.update(program_bench(out, calibrated, SEED_CELL, child_usage, _fgcal_command, say,
                                (program_targets // 20, program_targets)))  # fmt: skip
    if faro is not None:
        say(f"FARO set ({faro}): whole calibrate command against a plain scipy DH fit")
        result.update(faro_bench(Path(faro), out / "faro", repeats, say))
    first = result["sizes"][str(sizes[0])]
    result.update(
        {
            "n_configurations": first["n_configurations"],
            "fgcal_s": first["cpu_s"]["fgcal"],
            "numpy_gauss_newton_s": first["cpu_s"]["numpy_gauss_newton"],
            "scipy_fd_s": first["cpu_s"]["scipy_fd"],
            "online_median_ms": first["online_median_ms"],
            "online_p99_ms": first["online_p99_ms"],
            "held_out_rms_m": first["held_out_rms_m"],
        }
    )
    return result


def plan_bench(repeats: int, say: Callable[[str], None], n: int = 36, n_candidates: int = 5000) -> dict:
    """CPU time of fgcal plan on the seed cell: candidates, then the selection of ``n`` of
    ``n_candidates`` (greedy and exchange with rank-r updates), best of ``repeats``."""
    import tempfile

    from ..planning.exchange import plan_design
    from ..planning.plan import plan, prepare, write_plan

    cell = Path(str(resources.files("fgcal.datasets").joinpath("cells", "kr125_seed.yaml")))
    candidates, selection, whole = [], [], []
    for _ in range(repeats):
        started = time.process_time()
        planner = prepare(cell, n_candidates)
        candidates.append(planner.timing_s["candidates"] + planner.timing_s["information"])
        selection_started = time.process_time()
        plan_design(planner.info, n, "d-optimal")
        selection.append(time.process_time() - selection_started)
        # What the command does besides: the curves against N, plan.json, plan.md and the plot.
        with tempfile.TemporaryDirectory() as out:
            write_plan(plan(cell, n, planner=planner), out)
        whole.append(time.process_time() - started - selection[-1])
    result = {"plan_n": n, "plan_candidates": n_candidates, "plan_candidates_cpu_s": min(candidates)}
    result["plan_selection_cpu_s"] = min(selection)
    result["plan_command_cpu_s"] = min(whole)
    say(
        f"  plan {n} of {n_candidates} candidates (seed cell, d-optimal): candidates and their information "
        f"{result['plan_candidates_cpu_s']:.2f} s, selection {result['plan_selection_cpu_s']:.2f} s, the whole "
        f"plan with its curves, files and plot {result['plan_command_cpu_s']:.2f} s CPU"
    )
    return result


def _print_batch(r: dict, say: Callable[[str], None]) -> None:
    gn = r["cpu_s"]["numpy_gauss_newton"]
    say(f"  {'method':<20} {'CPU s':>8} {'wall s':>8} {'CPU/numpy GN':>13} {'held-out RMS':>14} {'chi2':>12}")
    for name in METHODS:
        say(
            f"  {name:<20} {r['cpu_s'][name]:8.3f} {r['wall_s'][name]:8.3f} {r['cpu_s'][name] / gn:13.2f} "
            f"{r['held_out_rms_m'][name] * 1e3:11.5f} mm {r['chi2'][name]:12.6g}"
        )
    spread = max(r["held_out_rms_m"].values()) / min(r["held_out_rms_m"].values()) - 1.0
    say(f"  held-out RMS spread over the methods: {100 * spread:.3f} %")


def _print_online(r: dict, say: Callable[[str], None]) -> None:
    say(
        f"  online, {r['online_images']} images: median {r['online_median_ms']:.2f} ms, "
        f"p99 {r['online_p99_ms']:.2f} ms, max {r['online_max_ms']:.2f} ms CPU per image; median of the last quarter "
        f"{r['online_median_last_quarter_ms']:.2f} ms"
    )
    if "online_batch_resolve_s" in r:
        say(
            f"  batch LM re-solve of the online graph {r['online_batch_resolve_s']:.2f} s CPU; online estimate within "
            f"{r['online_minus_batch_max_sigma']:.3f} sigma of it ({r['online_minus_batch_worst']})"
        )
