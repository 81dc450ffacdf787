"""The planning study of issue 14: planned designs against the seed's 36-image design and
space-filling designs, each simulated (same true robot per seed), calibrated with nothing
held out and scored against the truth at independent configurations.

Run on demand (``pytest -m study tests/test_planning.py``, or :func:`design_study`): it
simulates and calibrates some fifty datasets.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..calibration.config import CalibrationConfig
from ..calibration.plan_model import PAIR_GROUPS_FILE, Candidates, pair_groups_setting
from ..calibration.run import calibrate
from ..calibration.scoring import truth_errors
from ..data.dataset import load_dataset, read_csv, write_csv
from ..data.truth import load_truth
from ..model import kinematics
from ..simulation.design import max_min_selection
from ..simulation.simulate import simulate
from .exchange import predicted_sigma
from .information import group_rows
from .plan import SCORED_POINT_C, Planner, plan, prepare, write_plan


def truth_rms(
    dataset: Path,
    q_eval: np.ndarray,
    formulation: str,
    compliant_joints: Sequence[int] = (),
    groups: Path | None = None,
) -> float:
    """RMS (m) of the scored point's error against the truth at ``q_eval`` (pairs: the
    translation gauge removed; tracker: the reflectors in the tracker frame), after
    calibrating ``dataset`` with nothing held out (``compliant_joints``: the cell's, where it
    declares them; ``groups``: the pairs' groups file, pairs.groups)."""
    joints = {"compliant_joints": [int(j) for j in compliant_joints]} if len(compliant_joints) else {}
    if groups is not None:
        joints |= pair_groups_setting(str(Path(groups).resolve()))
    config = CalibrationConfig.defaults(
        dataset, formulation=formulation, model="DH,s,e", validation={"holdout": 0.0}, **joints
    )
    result = calibrate(config)
    # A camera's scored point is the fixed SCORED_POINT_C, whatever the designs measured.
    points = SCORED_POINT_C[None, :] if result.problem.frame == "tool" else None
    errors = truth_errors(result.problem, result.state, load_truth(dataset), q=q_eval, points=points)["tool_point"]
    return float(np.sqrt(np.mean(np.sum(errors.errors**2, axis=1))))


def evaluation_configurations(planner: Planner, seed: int, n_eval: int = 200) -> np.ndarray:
    """Independent configurations where a design is scored against the truth: another
    candidate stream, thinned max-min; over the workspace where the formulation gives it (the
    robot works where the instrument cannot see it too)."""
    pool = planner.planning.candidates(planner.cell, 5 * n_eval, np.random.default_rng(10_000 + seed))
    pool_q = pool.q if pool.workspace is None else pool.workspace
    return pool_q[max_min_selection(pool_q, planner.cell.robot.limits, n_eval, np.random.default_rng(seed))]


def planned_against_space_filling(
    cell: Path,
    out_dir: Path,
    n: int,
    seed: int = 1,
    n_candidates: int = 2000,
    criterion: str = "d-optimal",
    formulation: str | None = None,
) -> dict:
    """A plan of ``n`` and the space-filling design of ``n`` from the same candidates (those
    the cell can measure), each simulated (the same true robot), calibrated with nothing held
    out and scored against the truth (RMS, m) at independent configurations."""
    out_dir = Path(out_dir)
    planner = prepare(cell, n_candidates, formulation=formulation, seed=seed)
    q_eval = evaluation_configurations(planner, seed)
    result = plan(cell, n, criterion, planner=planner, curve_max=0)
    write_plan(result, out_dir / "plan", plot=False)
    q_sf = planner.candidates.q[planner.space_filling(n)]
    header = ["config", *[f"q{i}" for i in range(1, q_sf.shape[1] + 1)]]
    write_csv(out_dir / "space_filling.csv", header, [[f"s{k:04d}", *q] for k, q in enumerate(q_sf)])
    scores = {"predicted_m": result.predicted_sigma_m, "plan": result}
    for name, path in (("planned_m", out_dir / "plan" / "configurations.csv"),
                       ("space_filling_m", out_dir / "space_filling.csv")):  # fmt: skip
        simulate(cell, out_dir / name, seed, configurations=path)
        joints = planner.cell.perturbation.compliant_joints
        scores[name] = truth_rms(out_dir / name, q_eval, planner.formulation, joints)
    return scores


def dataset_groups(planner: Planner, dataset: Path, seed: int) -> dict:
    """The pair groups the planner chooses for a simulated pairs dataset's images (its
    configurations and the drawing points each sees), as for a plan's (planning.groups), written
    to ``pair_groups.csv`` in the dataset; and the planner's prediction (m) with them and with the
    calibration's own random groups."""
    from ..calibration.formulations.pairs import pair_observations
    from ..calibration.settings import MeasurementSettings
    from .groups import group_information, plan_groups

    d = load_dataset(dataset)
    table, points = d.tables["camera_points"], d.points_F()
    configs = [str(c) for c in d.configs if np.any(table.ids["config"] == c)]
    p_F = np.array([[points[name] for name in table.ids["point"][table.ids["config"] == c]] for c in configs])
    q = d.q[d.config_index(np.array(configs, dtype=object))]
    robot, info = planner.cell.robot, planner.info
    measured = planner.planning.rows(
        robot, kinematics.forward(robot, robot.parameter_vector(), q), planner.cell, Candidates(q, None, p_F),
        info.names,
    )  # fmt: skip
    rows = np.concatenate([measured.params, measured.aux], axis=2)
    design = replace(info, rows=rows, grouping=group_rows(measured.grouping, list(range(len(info.names)))))
    everything = list(range(len(configs)))
    groups = plan_groups(design, everything, seed)
    path = Path(dataset) / PAIR_GROUPS_FILE
    write_csv(
        path, ["config", "group"], [[configs[j], f"g{g + 1:02d}"] for g, group in enumerate(groups) for j in group]
    )
    # The calibration's own groups (nothing held out: positions in the dataset's configurations).
    drawn = pair_observations(d, MeasurementSettings(), np.arange(len(d.configs))).groups
    where = {c: j for j, c in enumerate(configs)}
    own = [[where[str(d.configs[i])] for i in g.images] for g in drawn]
    return {
        "file": path,
        "predicted_m": predicted_sigma(design, group_information(design, everything, groups)),
        "random_groups_predicted_m": predicted_sigma(design, group_information(design, everything, own)),
    }


def planned_groups(plan_dir: Path, dataset: Path) -> Path:
    """A plan's pair_groups.csv for the dataset simulated from it, written in the dataset: fgcal
    simulate leaves out the configurations whose block the simulated camera does not see, so the
    file names only the dataset's, each taking the group of the planned one with its joint values
    (the same floats: the plan's file is read back exactly)."""
    header, body = read_csv(Path(plan_dir) / "configurations.csv", ["config"])
    joints = [i for i, name in enumerate(header) if name.startswith("q") and name[1:].isdigit()]
    planned = {tuple(float(row[i]) for i in joints): row[header.index("config")] for row in body}
    _, labelled = read_csv(Path(plan_dir) / PAIR_GROUPS_FILE, ["config", "group"])
    group = dict((row[0], row[1]) for row in labelled)
    d = load_dataset(dataset)
    ids = {str(c): planned[tuple(map(float, q))] for c, q in zip(d.configs, d.q, strict=True)}
    order = {cid: k for k, (cid, _) in enumerate(labelled)}
    rows = sorted(([c, group[p]] for c, p in ids.items()), key=lambda row: order[ids[row[0]]])
    path = Path(dataset) / PAIR_GROUPS_FILE
    write_csv(path, ["config", "group"], rows)
    return path


def n_reaching(sizes: Sequence[int], rms: Sequence[float], target_m: float) -> float | None:
    """The N at which an RMS-against-N curve first reaches ``target_m`` (log-log
    interpolation between the bracketing sizes; None if it never does)."""
    for k, value in enumerate(rms):
        if value <= target_m:
            if k == 0:
                return float(sizes[0])
            x0, x1, y0, y1 = np.log(sizes[k - 1]), np.log(sizes[k]), np.log(rms[k - 1]), np.log(value)
            return float(np.exp(x0 + (np.log(target_m) - y0) * (x1 - x0) / (y1 - y0)))
    return None


def design_study(
    cell: Path,
    out_dir: Path,
    seeds: Sequence[int] = (1, 2, 3),
    planned_sizes: Sequence[int] = (24, 36, 48, 72, 100),
    space_filling_sizes: Sequence[int] = (36, 72, 100, 150, 200, 300),
    criterion: str = "d-optimal",
    n_eval: int = 200,
    target_m: float = 3e-5,
    with_seed_design: bool = True,
    formulation: str | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict:
    say = progress or (lambda _msg: None)
    out_dir = Path(out_dir)
    rows = []
    for seed in seeds:
        started = time.perf_counter()
        planner = prepare(cell, seed=seed, formulation=formulation)
        formulation = planner.formulation
        q_eval = evaluation_configurations(planner, seed, n_eval)
        base = out_dir / f"seed{seed}"
        row = {"seed": seed, "planned": {}, "space_filling": {}}
        grouped = planner.info.grouping is not None
        if with_seed_design:
            simulate(cell, base / "seed_design", seed, design="seed")
            row["seed_design_m"] = truth_rms(base / "seed_design", q_eval, formulation)
            if grouped:  # what the planner's groups alone gain on the seed's own design
                chosen = dataset_groups(planner, base / "seed_design", seed)
                row["seed_design_groups"] = {
                    "rms_m": truth_rms(base / "seed_design", q_eval, formulation, groups=chosen["file"]),
                    "predicted_m": chosen["predicted_m"],
                    "random_groups_predicted_m": chosen["random_groups_predicted_m"],
                }
        for n in planned_sizes:
            result = plan(cell, n, criterion, formulation=formulation, planner=planner, curve_max=0)
            write_plan(result, base / f"plan{n}", plot=False)
            simulate(cell, base / f"planned{n}", seed, configurations=base / f"plan{n}" / "configurations.csv")
            groups = planned_groups(base / f"plan{n}", base / f"planned{n}") if grouped else None
            rms = truth_rms(base / f"planned{n}", q_eval, formulation, groups=groups)
            row["planned"][n] = {"rms_m": rms, "predicted_m": result.predicted_sigma_m}
            if grouped:  # the same design with the calibration's random groups
                row["planned"][n]["random_groups_rms_m"] = truth_rms(base / f"planned{n}", q_eval, formulation)
                row["planned"][n]["random_groups_predicted_m"] = result.random_groups_sigma_m
        for n in space_filling_sizes:
            simulate(cell, base / f"space_filling{n}", seed, design="space_filling", n_configurations=n)
            row["space_filling"][n] = {"rms_m": truth_rms(base / f"space_filling{n}", q_eval, formulation)}
        for kind in ("planned", "space_filling"):
            sizes = sorted(row[kind])
            if sizes:
                row[f"{kind}_n_reaching_m"] = n_reaching(sizes, [row[kind][s]["rms_m"] for s in sizes], target_m)
        say(f"seed {seed}: {row} ({time.perf_counter() - started:.0f} s)")
        rows.append(row)
    return {"criterion": criterion, "target_m": target_m, "n_eval": n_eval, "seeds": rows}
