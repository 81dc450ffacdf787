"""``fgcal bench``: times measured in one run, printed with their ratios.

1. fgcal's full four-stage calibration of the seed cell's 300-configuration space-filling
   case (pair formulation, DH,s,e), on the GTSAM factor graph.
2. The same calibration with ``scipy.optimize.least_squares`` (trust-region reflective,
   finite-difference Jacobian): the same residuals (the point-pair contrasts of the same
   groups, vectorised in NumPy, poses computed directly from the parameters), the same
   released parameters per stage, the same starting point.
3. The ceiling of that ratio: the baseline's residual evaluations against one FK + analytic
   Jacobian and one residual per Jacobian, at the baseline's number of Jacobians.
4. Online recalibration: ``OnlineCalibrator.add`` latency over the case's 300 images, and a
   batch re-solve of the same graph beside it.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import scipy.optimize
import scipy.sparse

from . import kinematics
from .calibration.config import CalibrationConfig
from .calibration.graph import build_graph, initial_state
from .calibration.identifiability import analyse
from .calibration.problem import Problem, build_problem
from .calibration.run import calibrate_dataset
from .calibration.solve import solve_stage, stage_parameters
from .dataset import load_dataset
from .factors.point_pair import helmert
from .robot_io import robots_dir
from .simulation.simulate import simulate


class PairResiduals:
    """Whitened point-pair contrasts of all groups as a function of the released parameters."""

    def __init__(self, problem: Problem, full_params: np.ndarray, released: list[str]) -> None:
        self.problem = problem
        self.base = full_params.copy()
        self.index = np.array([problem.robot.parameter_names.index(n) for n in released], dtype=int)
        images, c, p_F, blocks = [], [], [], []
        for group in problem.pairs:
            images.append(np.array(group.images)[group.owner])
            c.append(group.c)
            p_F.append(group.p_F)
            blocks.append(helmert(len(group.c)))
        self.images = np.concatenate(images)
        self.c = np.concatenate(c)
        self.p_W = np.concatenate(p_F) @ problem.fixture_rotation.T
        self.H = scipy.sparse.block_diag(blocks, format="csr")
        self.sigma = problem.config.camera_point_sigma_m

    def __call__(self, released_values: np.ndarray) -> np.ndarray:
        params = self.base.copy()
        params[self.index] = released_values
        data = kinematics.forward(self.problem.robot, params, self.problem.q_fit)
        T = kinematics.frame_pose(self.problem.robot, data, "tool")[self.images]
        world = np.einsum("oij,oj->oi", T[:, :3, :3], self.c) + T[:, :3, 3] - self.p_W
        return (self.H @ world).reshape(-1) / self.sigma


def scipy_calibration(problem: Problem, identifiable: list[str]) -> tuple[np.ndarray, float, list[dict]]:
    """The baseline; per stage the released count m, scipy's nfev and njev (each 2-point
    finite-difference Jacobian costs m residual evaluations on top of nfev)."""
    params = problem.robot.parameter_vector()
    stages = []
    started = time.perf_counter()
    for kinds in problem.config.stages:
        released = stage_parameters(kinds, identifiable)
        residuals = PairResiduals(problem, params, released)
        solution = scipy.optimize.least_squares(residuals, params[residuals.index], jac="2-point", method="trf")
        params[residuals.index] = solution.x
        stages.append({"released": len(released), "nfev": int(solution.nfev), "njev": int(solution.njev)})
    return params, time.perf_counter() - started, stages


def ratio_ceiling(problem: Problem, params: np.ndarray, identifiable: list[str], stages: list[dict]) -> dict:
    """How much faster than the baseline any analytic-Jacobian solver can be at the same
    number of Jacobians: the baseline's residual evaluations against one FK+Jacobian plus
    one residual per Jacobian, with no other overhead."""
    residuals = PairResiduals(problem, params, identifiable)
    x = params[residuals.index]
    repeats = 5
    started = time.perf_counter()
    for _ in range(repeats):
        residuals(x)
    residual_s = (time.perf_counter() - started) / repeats
    started = time.perf_counter()
    for _ in range(repeats):
        data = kinematics.forward(problem.robot, params, problem.q_fit)
        kinematics.jacobian(problem.robot, data, identifiable, frame="tool")
    jacobian_s = (time.perf_counter() - started) / repeats
    evaluations = sum(s["nfev"] + s["released"] * s["njev"] for s in stages)
    jacobians = sum(s["njev"] for s in stages)
    return {
        "scipy_residual_evaluations": evaluations,
        "scipy_jacobians": jacobians,
        "residual_evaluation_s": residual_s,
        "fk_and_jacobian_s": jacobian_s,
        "ratio_ceiling": evaluations * residual_s / (jacobians * (jacobian_s + residual_s)),
    }


def fgcal_stages(problem: Problem, identifiable: list[str]) -> tuple[np.ndarray, float]:
    state = initial_state(problem)
    started = time.perf_counter()
    for i, kinds in enumerate(problem.config.stages, start=1):
        state, _, _, _ = solve_stage(problem, str(i), stage_parameters(kinds, identifiable), state)
    return state.params, time.perf_counter() - started


def run_bench(out: Path, seed: int = 1, n: int = 300, repeats: int = 3) -> dict:
    data_dir = out / f"seed{seed}_n{n}"
    if not (data_dir / "dataset.yaml").exists():
        print(f"simulating the seed cell, space-filling design of {n} configurations (seed {seed}) -> {data_dir}")
        simulate(
            robots_dir().parent / "cells" / "kr125_seed.yaml",
            data_dir,
            seed,
            design="space_filling",
            n_configurations=n,
        )
    dataset = load_dataset(data_dir)
    config = CalibrationConfig.defaults(data_dir)
    problem = build_problem(dataset, config)
    identifiable = analyse(
        build_graph(problem, problem.candidates, initial_state(problem)), config.min_information
    ).identifiable
    sizes = [len(stage_parameters(k, identifiable)) for k in config.stages]
    print(
        f"{len(problem.fit)} configurations for fitting, {problem.n_residuals} residuals, "
        f"{len(identifiable)} identifiable parameters, parameters per stage {sizes}"
    )

    stage_times, total_times = [], []
    for _ in range(repeats):
        fg_params, stage_time = fgcal_stages(problem, identifiable)
        stage_times.append(stage_time)
        started = time.perf_counter()
        calibrate_dataset(dataset, config)
        total_times.append(time.perf_counter() - started)
    sp_params, sp_time, sp_stages = scipy_calibration(problem, identifiable)
    ceiling = ratio_ceiling(problem, fg_params, identifiable, sp_stages)
    final = PairResiduals(problem, fg_params, identifiable)
    cost_fgcal = float(np.sum(final(fg_params[final.index]) ** 2))
    cost_scipy = float(np.sum(final(sp_params[final.index]) ** 2))
    result = {
        "fgcal_four_stages_s": min(stage_times),
        "fgcal_calibrate_total_s": min(total_times),
        "scipy_four_stages_s": sp_time,
        "scipy_stages": sp_stages,
        **ceiling,
        "ratio_scipy_over_fgcal": sp_time / min(stage_times),
        "chi2_fgcal": cost_fgcal,
        "chi2_scipy": cost_scipy,
    }
    print(f"fgcal, four stages (best of {repeats}):          {result['fgcal_four_stages_s']:.3f} s")
    print(
        f"fgcal, whole calibrate() incl. identifiability, covariance, validation: "
        f"{result['fgcal_calibrate_total_s']:.3f} s"
    )
    print(
        f"scipy least_squares, finite differences:   {sp_time:.3f} s ({ceiling['scipy_residual_evaluations']} "
        f"residual evaluations, {ceiling['scipy_jacobians']} finite-difference Jacobians)"
    )
    print(f"ratio scipy / fgcal (four stages):         {result['ratio_scipy_over_fgcal']:.1f}")
    print(f"final chi2: fgcal {cost_fgcal:.6g}, scipy {cost_scipy:.6g} (same residuals)")
    print(
        f"ceiling of the ratio at the same number of Jacobians: one residual evaluation "
        f"{ceiling['residual_evaluation_s'] * 1e3:.2f} ms, FK + analytic Jacobian "
        f"{ceiling['fk_and_jacobian_s'] * 1e3:.2f} ms -> at most {ceiling['ratio_ceiling']:.1f}x"
    )
    result.update(online_bench(data_dir))
    return result


def online_bench(data_dir: Path) -> dict:
    """Latency of OnlineCalibrator.add over the dataset's images, and a batch re-solve (LM on
    the same graph, from the nominal model) beside it."""
    import gtsam

    from .online import OnlineCalibrator
    from .online.calibrator import params_key
    from .online.feed import dataset_measurements

    dataset = load_dataset(data_dir)
    points = dataset.points_F()
    measurements = dataset_measurements(data_dir)
    calibrator = OnlineCalibrator(dataset.robot, dataset.camera, points, keep_graph=True)
    latency = np.array([calibrator.add(m.q, list(m.pixels), m.cycle).update_s for m in measurements]) * 1e3
    initial = calibrator.batch_initial()
    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    params.setDiagonalDamping(True)
    started = time.perf_counter()
    batch = gtsam.LevenbergMarquardtOptimizer(calibrator.graph, initial, params).optimize()
    batch_s = time.perf_counter() - started
    online = calibrator.current_params()[calibrator.model.index]
    difference = np.abs(online - batch.atVector(params_key(calibrator.cycle))) / calibrator.sigmas
    result = {
        "online_images": len(measurements),
        "online_update_median_ms": float(np.median(latency)),
        "online_update_p99_ms": float(np.percentile(latency, 99)),
        "online_update_max_ms": float(latency.max()),
        "online_batch_resolve_s": batch_s,
        "online_minus_batch_max_sigma": float(difference.max()),
    }
    print(
        f"online update latency over {len(measurements)} images: median {result['online_update_median_ms']:.1f} ms, "
        f"p99 {result['online_update_p99_ms']:.1f} ms, max {result['online_update_max_ms']:.1f} ms"
    )
    print(
        f"batch re-solve of the same graph (LM from the nominal model): {batch_s:.2f} s; online estimate "
        f"within {difference.max():.3f} sigma of it ({calibrator.released[int(np.argmax(difference))]})"
    )
    return result
