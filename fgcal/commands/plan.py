"""``fgcal plan CELL``: the measurement configurations of a cell, chosen before measuring."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from ..core.console import Reporter, say
from ..planning import MAX_CANDIDATES
from .options import JSON_HELP, SEED, bundled_cell, emit, integer, real


def cmd_plan(args: argparse.Namespace) -> int:
    from ..core.errors import InputError
    from ..data.joint_programs import check_program
    from ..planning.plan import (
        APPROACH_OFFSET_RAD,
        check_out,
        default_approach,
        model_error_from_report,
        plan,
        remove_earlier_plan,
        write_plan,
    )
    from ..simulation.cell import load_cell

    approach = args.approach or default_approach(args.model)
    if args.approach_offset is not None and approach == "previous":  # read and ignored: refused
        raise InputError(
            None, "--approach-offset", "sets the approach points of --approach unidirectional or varied; this plan "
            "reaches each configuration from the one before (previous): give --approach unidirectional, or drop it",
        )  # fmt: skip
    offset_rad = APPROACH_OFFSET_RAD if args.approach_offset is None else float(np.radians(args.approach_offset))
    cell_path = bundled_cell(args.cell)
    cell = load_cell(cell_path)
    for kind in args.program or []:  # before the work: a refused program would come after the plan's files
        check_program(kind, cell.robot.n_joints)
    reference = cell.robot_reference
    robot_file = reference.get("file") if isinstance(reference, dict) else reference
    check_out(args.out, {"CELL": cell_path, "--model-error-from": args.model_error_from,
                         "the cell's robot file": robot_file if Path(robot_file).suffix else None})  # fmt: skip
    had_plan = (Path(args.out) / "plan.json").is_file()
    model_error_m, source = None, None
    if args.model_error is not None:
        model_error_m, source = args.model_error * 1e-3, "--model-error"
    elif args.model_error_from is not None:
        model_error_m = model_error_from_report(args.model_error_from, cell.robot.name, args.model)
        source = f"held out beyond its prediction in {args.model_error_from}"
    result = plan(
        cell_path,
        args.n,
        criterion=args.criterion,
        n_candidates=args.candidates,
        formulation=args.formulation,
        model=args.model,
        seed=args.seed,
        progress=Reporter(),
        approach=args.approach,
        approach_offset_rad=offset_rad,
        model_error_m=model_error_m,
        model_error_source=source,
    )
    written = write_plan(result, args.out, plot=not args.no_plots)
    for kind in args.program or []:
        written += [path.name for path in _program(kind, result, args)]
    if removed := remove_earlier_plan(args.out, written, had_plan):
        say(f"  removed the earlier plan's {', '.join(removed)} from {args.out} (this plan does not write them)")
    for line in result.discarded_lines():
        say(f"  {line}")
    floor, real = result.prediction_lines()
    say(
        f"  {floor} (space-filling design of {args.n}: {result.space_filling_sigma_m * 1e3:.4f} mm); "
        f"condition number {result.indices['condition_number']:.3g}"
    )
    say(f"  {real}")
    if (groups := result.pair_groups_line()) is not None:
        say(f"  {groups}")
    t = result.timing_s
    say(f"  CPU time: candidates {t['candidates']:.1f} s, selection {t['selection']:.1f} s")
    if result.lost_motion is not None:
        lost = result.lost_motion
        advice = {
            "unidirectional": "this plan: calibrate it with DH,s,e",
            "varied": "this plan approaches each configuration its own way: calibrate it with DH,s,e,h",
        }.get(result.approach, "--approach unidirectional; visited in order, calibrate with DH,s,e,h")
        say(
            f"  the cell's lost motion, beyond what constant joint offsets absorb: {lost['in_order_rms_m'] * 1e3:.4g} "
            f"mm RMS with the plan visited in order, {lost['unidirectional_rms_m'] * 1e3:.4g} mm with each "
            f"configuration approached from below ({advice})"
        )
    say(f"wrote {args.out}: {', '.join(written)}")
    emit(args, {
        "out": str(args.out), "files": {name: str(Path(args.out) / name) for name in written},
        "n_configurations": args.n, "criterion": args.criterion,
        "predicted_sigma_m": result.predicted_sigma_m, "space_filling_sigma_m": result.space_filling_sigma_m,
        "condition_number": result.indices["condition_number"], "cpu_s": dict(result.timing_s),
        "approach": result.approach, "lost_motion": result.lost_motion,
        "prediction": result.prediction(), "n_drawn": result.drawn, "discarded": dict(result.candidates.discarded),
        "out_of_view": result.unseen,
    })  # fmt: skip
    return 0


def _program(kind: str, result, args: argparse.Namespace) -> list[Path]:
    """The plan as a program of ``kind`` (RAPID, KRL, CSV in degrees), stating its assumptions."""
    from ..data.assumptions import Assumptions
    from ..data.joint_programs import NAME, RAPID_SPEED, SETTLE_S, write_joint_program
    from ..simulation.cell import load_cell

    robot = load_cell(bundled_cell(args.cell)).robot
    q = result.candidates.q[result.chosen]
    approach = result.approach_points
    com_mm = ", ".join(f"{v * 1e3:.6g}" for v in robot.payload_com)
    motion = {"rapid": f"MoveAbsJ at {RAPID_SPEED}, fine, then {SETTLE_S:g} s",
              "krl": f"PTP at 20 %, exact stop, then {SETTLE_S:g} s", "csv-deg": "a row each, in order"}  # fmt: skip
    assumptions = Assumptions(
        what=f"calibration measurement plan from fgcal plan: {result.n} configurations of {result.robot} for the "
        f"cell {result.cell} ({result.criterion}, {result.formulation}, model {result.model}, seed {result.seed}); "
        f"stop at each ({motion[kind]}) and measure it",
        frame=f"joint positions as the model of {result.robot} defines each joint's zero and sign (the "
        "controller's, for fgcal's bundled models): no Cartesian frame, no work object",
        tool="the motions are in joints (the TCP sets only their speed: tool0, the flange); mount the measuring "
        "tool the cell describes (its reflectors, camera, probe or ball)",
        payload=f"{robot.payload_mass:g} kg, centre of mass ({com_mm}) mm in the flange frame: the cell's, which the "
        "plan's compliances assume; set the controller's load data to it",
        units="deg for a revolute joint, mm for a prismatic one",
        approach=_approach_words(result) if approach is not None
        else "each configuration from the one before, in this order (the plan's)",
    )  # fmt: skip
    names = [f"p{k:04d}" for k in range(len(q))]  # as configurations.csv names them
    cand = result.candidates
    labels = None if cand.blocks is None else (cand.label_column, [str(cand.blocks[c]) for c in result.chosen])
    prismatic = np.asarray(robot.prismatic, bool)
    paths = write_joint_program(kind, args.out, names, q, approach, assumptions, prismatic, labels)
    say(f"  {kind} program of the plan: {', '.join(p.name for p in paths)} ({NAME})")
    return paths


def _approach_words(result) -> str:
    offset = f"{np.degrees(result.approach_offset_rad):g} deg"
    if result.approach == "varied":
        return (
            f"each configuration from its own approach point, up to {offset} above or below on each joint, "
            "visited just before it (a_ / XA_ points): the lost motion the plan's model fits depends on it"
        )
    return f"each configuration from its approach point {offset} below on every joint, visited just before it " + (
        "(a_ / XA_ points)"
    )


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("plan", help="choose the measurement configurations of a cell (docs/planning.md)")
    p.add_argument("cell", help="cell YAML file, or a bundled cell name (kr125_seed)")
    p.add_argument(
        "--n",
        type=integer(1, MAX_CANDIDATES, "configurations"),
        required=True,
        help="number of configurations to plan (at most --candidates)",
    )
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument(
        "--criterion",
        default="d-optimal",
        choices=("d-optimal", "position", "o1", "o2", "o3", "o4", "o5"),
        help="design criterion (default d-optimal)",
    )
    p.add_argument(
        "--candidates",
        type=integer(1, MAX_CANDIDATES, "candidates"),
        default=5000,
        help=f"candidate configurations (default 5000, at most {MAX_CANDIDATES})",
    )
    p.add_argument(
        "--formulation", help="what to plan for (pairs, projection, tracker; default: what the cell measures with)"
    )
    p.add_argument(
        "--model", choices=("DH", "DH,s", "DH,s,e", "DH,s,e,h"), default="DH,s,e", metavar="MODEL",
        help="kinematic model whose parameters the plan determines: DH, DH,s, DH,s,e or DH,s,e,h (the motion "
        "history's lost motion and speed terms: planned with --approach varied) (default DH,s,e)",
    )  # fmt: skip
    p.add_argument("--seed", type=SEED, default=1, help="seed of the candidates (default 1)")
    p.add_argument(
        "--approach", choices=("previous", "unidirectional", "varied"), default=None,
        help="each configuration reached from the one before (previous, the default for a static model), from "
        "--approach-offset below on every joint (unidirectional: approach points in configurations.csv, lost motion "
        "absorbed), or from its own approach point above or below on each joint (varied, the default for DH,s,e,h: "
        "the lost motion and speed terms become identifiable)",
    )  # fmt: skip
    p.add_argument(
        "--approach-offset", type=real(0.0, 30.0, "deg", above_low=True), default=None,
        help="how far from each configuration its approach point is, deg (default 2; varied: 0.25 to 1 times it)",
    )  # fmt: skip
    p.add_argument(
        "--program", nargs="+", choices=("rapid", "krl", "csv-deg"), metavar="KIND",
        help="also write the plan as a program to drive it: rapid (cal_plan.mod, MoveAbsJ), krl (cal_plan.src and "
        ".dat, PTP to E6AXIS) or csv-deg (configurations_deg.csv), joints in degrees, in the plan's order with its "
        "approach points",
    )  # fmt: skip
    error = p.add_mutually_exclusive_group()
    error.add_argument(
        "--model-error", type=real(0.0, 1000.0, "mm"), metavar="MM",
        help="what the model does not describe on the real robot, mm RMS at a point: the plan then predicts what the "
        "robot will show, sqrt(floor^2 + MM^2) (without it, the prediction is the floor if the model holds)",
    )  # fmt: skip
    error.add_argument(
        "--model-error-from", metavar="REPORT",
        help="an earlier calibration's report.json: the model error is its held-out error beyond its prediction",
    )  # fmt: skip
    p.add_argument("--no-plots", action="store_true", help="no predicted_accuracy.png")
    p.add_argument("--json", action="store_true", help=JSON_HELP)
    p.set_defaults(func=cmd_plan)
