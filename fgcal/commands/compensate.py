"""``fgcal compensate ROBOT TARGETS``: corrected commands, for a targets CSV or a robot program."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..core.console import Reporter, say, warn
from ..data.compensation import ORIENTATIONS
from .options import JSON_HELP, LENGTH_M, count, emit, real


def cmd_compensate(args: argparse.Namespace) -> int:
    from ..core.errors import InputError
    from ..core.outputs import distinct, output_file
    from ..data.compensation import SOLVED, TargetUnits, compensate, nominal_of, read_targets, write_compensation
    from ..model.robot_io import load_robot

    output_file(args.out, "--out")  # before the work, not after it

    robot = load_robot(args.robot)
    calibrated = robot  # at the calibration's payload: where the controller's base frame is placed
    if args.payload_mass is not None or args.payload_com is not None:
        mass = robot.payload_mass if args.payload_mass is None else args.payload_mass
        com = robot.payload_com if args.payload_com is None else np.array(args.payload_com)
        robot = robot.with_tool(robot.tool_pose, float(mass), com)
    nominal = nominal_of(robot, args.nominal)
    from ..data.programs import KRL_SUFFIXES, RAPID_SUFFIXES

    if args.tip is not None and robot.tip_error(args.tip):
        raise InputError(args.robot, "--tip", robot.tip_error(args.tip))
    if Path(args.targets).suffix.lower() in RAPID_SUFFIXES + KRL_SUFFIXES:
        if args.tip is not None:
            raise InputError(args.targets, "--tip", "a robot program drives its robot's flange: --tip is for a CSV")
        return _compensate_program(args, robot, nominal)
    if args.tool is not None or args.base is not None:
        print("fgcal: error: --tool and --base apply to robot programs (RAPID, KRL), not to a CSV", file=sys.stderr)
        return 2
    if Path(args.out).suffix.lower() != ".csv":
        raise InputError(args.out, "--out", "the commands of a targets CSV are a .csv file")
    distinct({"--out": args.out}, _inputs(args, "TARGETS"))
    units = TargetUnits(args.length_unit, args.angle_unit, args.orientation)
    targets = read_targets(args.targets, robot.n_joints, units, robot.prismatic)
    tcp = None if args.tcp is None else np.array(args.tcp)
    wanted = _in_calibration_frame(targets.as_ik_targets(), calibrated, nominal, args.targets_frame)
    approach = _approach(args, robot, targets.approach, len(targets.names))
    result = compensate(
        robot, nominal, wanted, targets.hints, tcp, "tool" if args.tip is None else args.tip,
        tol_m=1e-6 * args.tolerance_um, tol_rad=1e-6, progress=Reporter(), approach=approach, speed=targets.speed,
    )  # fmt: skip
    write_compensation(args.out, targets.names, result, targets.rotations is not None, units, robot.prismatic)
    if result.motion_solved is not None:
        _unsolved_motion([n for n, ok in zip(targets.names, result.motion_solved, strict=True) if not ok])
    counts = {s: int(np.sum(result.status == s)) for s in sorted(set(result.status.tolist()))}
    say(f"wrote {args.out}: {len(targets.names)} targets (" + ", ".join(f"{k} {v}" for k, v in counts.items()) + ")")
    solved, unreachable = np.isin(result.status, SOLVED), result.status == "unreachable"
    emit(args, {
        "out": str(args.out), "n_targets": len(targets.names), "status": counts,
        # of the compensated targets only: an unreachable one's residual is how far it stays
        "residual_max_m": float(result.residual_m[solved].max()) if solved.any() else None,
        "unreachable_gap_max_m": float(result.residual_m[unreachable].max()) if unreachable.any() else None,
    })  # fmt: skip
    if solved.any():
        say(f"  reached in the calibrated model to {result.residual_m[solved].max() * 1e6:.3g} um at worst")
    if unreachable.any():
        gaps = result.residual_m[unreachable] * 1e3
        span = (
            f"{gaps.min():.4g} mm" if np.isclose(gaps.min(), gaps.max()) else f"{gaps.min():.4g} to {gaps.max():.4g} mm"
        )
        say(f"  {count(int(unreachable.sum()), 'target')} unreachable: the calibrated model stays {span} away")
    if (~solved).any():
        say(f"  {count(int((~solved).sum()), 'target')} not compensated: no joints and no command in their rows")
    return 0


def _inputs(args: argparse.Namespace, targets: str) -> dict[str, str | None]:
    """Every file the command reads, by the name the command line gives it (a bundled robot's
    name is none)."""
    return {
        targets: args.targets,
        "ROBOT": args.robot if Path(args.robot).suffix else None,
        "--nominal": args.nominal if args.nominal is not None and Path(args.nominal).suffix else None,
    }


def _approach(args: argparse.Namespace, robot, given: np.ndarray | None, n_targets: int) -> np.ndarray | None:
    """The approach of each target for compensate (None: not allowed for), and what it
    assumes, said."""
    if not robot.history:
        if given is not None and np.isfinite(given).any():
            say(f"  the before_q columns are not used: {robot.name}'s model ({robot.model}) has no lost motion")
        return None
    if args.approach == "none":
        say("  lost motion not allowed for (--approach none): the commands are the joints the calibrated model needs")
        return None
    n_given = 0 if given is None else int(np.all(np.isfinite(given), axis=1).sum())
    say(
        "  allowing for lost motion: each target approached from the previous one in the file's order"
        + (f" ({n_given} from the joints their before_q columns give)" if n_given else "")
        + "; the first gets no allowance (--approach none: none at all)"
    )
    return given if given is not None else np.full((n_targets, robot.n_joints), np.nan)


def _unsolved_motion(names: list[str]) -> None:
    if names:
        shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        warn(
            f"{count(len(names), 'target')} ({shown}): no lost-motion allowance could be solved (a move of a "
            "fraction of a degree, where the speed term's model does not hold): commanded without it"
        )


def _in_calibration_frame(targets: np.ndarray, robot, nominal, frame: str) -> np.ndarray:
    """Targets (N, 3) or (N, 4, 4) in the calibration's W: as given (``W``), or from the
    controller's base frame (``controller``), placed as program filtering places it. With
    ``W``, says how far the controller's frame is, when that is more than 1 mm or 1 mrad."""
    from ..core.se3 import so3_log
    from ..data.program_filter import controller_frame

    T_W_ctrl = controller_frame(robot, nominal)
    if frame == "controller":
        return T_W_ctrl @ targets if targets.ndim == 3 else targets @ T_W_ctrl[:3, :3].T + T_W_ctrl[:3, 3]
    offset_m, turn_rad = np.linalg.norm(T_W_ctrl[:3, 3]), np.linalg.norm(so3_log(T_W_ctrl[:3, :3]))
    if offset_m > 1e-3 or turn_rad > 1e-3:
        say(
            f"  the targets are in the calibration's frame W; the controller's base frame lies {offset_m * 1e3:.3g} mm "
            f"and {np.degrees(turn_rad) * 1e3:.3g} mdeg from it (--targets-frame controller reads them there)"
        )
    return targets


def _compensate_program(args: argparse.Namespace, robot, nominal) -> int:
    from ..core.errors import InputError
    from ..core.outputs import distinct, output_file, write_bytes
    from ..data.dataset import write_csv
    from ..data.program_filter import (
        UNCHANGED_M,
        UNCHANGED_RAD,
        WRITTEN,
        check_program,
        correction_rows,
        filter_targets,
        program_frames,
        program_path,
    )
    from ..data.programs import KRL_SUFFIXES, RAPID_SUFFIXES, read_program, write_program

    source, out = Path(args.targets), Path(args.out)
    distinct({"--out": out, "the corrections table": out.with_name(f"{out.stem}.corrections.csv")},
             _inputs(args, "PROGRAM"))  # fmt: skip
    if (source.suffix.lower() in KRL_SUFFIXES) != (out.suffix.lower() in KRL_SUFFIXES) or out.suffix.lower() not in (
        RAPID_SUFFIXES + KRL_SUFFIXES
    ):
        raise InputError(out, "--out", f"the corrected program is a {source.suffix} file like {source.name}")
    if args.tcp is not None:
        raise InputError(source, "--tcp", "a program's TCP is its tool: give --tool (a tooldata name, or X Y Z A B C)")
    for option, value, default in (("--length-unit", args.length_unit, "m"), ("--angle-unit", args.angle_unit, "rad"),
                                   ("--orientation", args.orientation, "rotvec"),
                                   ("--targets-frame", args.targets_frame, "W")):  # fmt: skip
        if value != default:
            raise InputError(source, option, "applies to a targets CSV: a program's units and frames are its own")
    table = out.with_name(f"{out.stem}.corrections.csv")
    output_file(table)
    program = read_program(source)
    if not program.targets:
        raise InputError(source, None, "no targets (robtarget, E6POS or POS declarations) to correct")
    for note in check_program(program, args.tool is not None, args.base is not None):
        warn(note)
    frames = program_frames(program, args.tool, args.base, robot)
    poses = np.array([target.pose for target in program.targets])
    say(f"correcting {len(poses)} targets of {source.name} ({program.kind.upper()})")
    path = None
    if robot.history:
        if args.approach == "none":
            say("  lost motion not allowed for (--approach none)")
        else:
            path, assumption = program_path(program)
            say(f"  allowing for lost motion along the path: {assumption} (--approach none: not allowed for)")
    configs = [t.config for t in program.targets]
    result = filter_targets(robot, nominal, poses, configs, program.kind, frames, path)
    if result.motion_unsolved is not None:
        _unsolved_motion([t.name for t, bad in zip(program.targets, result.motion_unsolved, strict=True) if bad])
    # A target the calibration leaves where it was (below what the file's digits hold) keeps its text.
    moved = (result.correction_m > UNCHANGED_M) | (result.correction_rad > UNCHANGED_RAD)
    written = np.isin(result.status, WRITTEN) & moved
    corrected = {
        target.name: (result.poses[k], {key: v for key, v in result.configs[k].items() if key in target.config})
        for k, target in enumerate(program.targets)
        if written[k]
    }
    text = write_program(program, corrected, out)
    write_bytes(out, text.encode(program.encoding))
    write_csv(table, *correction_rows(program, result, written))
    counts = {s: int(np.sum(result.status == s)) for s in sorted(set(result.status.tolist()))}
    say(f"wrote {out} and {table}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    emit(args, {
        "out": str(out), "table": str(table), "n_targets": len(poses), "n_corrected": int(written.sum()),
        "status": counts,
        "correction_max_m": float(result.correction_m[written].max()) if written.any() else 0.0,
        "rotation_max_rad": float(result.correction_rad[written].max()) if written.any() else 0.0,
    })  # fmt: skip
    if written.any():
        say(
            f"  corrections {result.correction_m[written].mean() * 1e3:.3f} mm mean, "
            f"{result.correction_m[written].max() * 1e3:.3f} mm max, "
            f"{np.degrees(result.correction_rad[written]).max() * 1e3:.1f} mdeg max"
        )
    solved = np.isin(result.status, WRITTEN)
    whose = "the tool's load" if frames.payload_mass_kg is not None else "the robot file's; a tooldata's tload sets it"
    say(f"  deflection computed for a payload of {result.payload_mass_kg:g} kg ({whose})")
    if (solved & ~moved).any():
        say(f"  {count(int((solved & ~moved).sum()), 'target')} need no correction (below 0.5 um and 0.01 urad): kept")
    if (~solved).any():
        say(f"  {count(int((~solved).sum()), 'target')} left as they were: see their status in {table.name}")
    if result.in_region is not None and (solved & ~result.in_region).any():
        warn(
            f"{count(int((solved & ~result.in_region).sum()), 'target')} need joints outside the range the "
            "calibration measured: their correction is the model's extrapolation "
            f"(in_calibrated_region in {table.name})"
        )
    if (result.status == "configuration changed").any():
        warn("some corrected targets need another configuration (new confdata or S/T): check their path")
    rewritten = np.isin(result.status, ("turn changed", "configuration data changed"))
    if rewritten.any():
        data = "T (turn)" if program.kind == "krl" else "confdata"
        warn(
            f"{count(int(rewritten.sum()), 'target')} got new {data} on the same path (a joint within 0.1 deg of a "
            f"quadrant's edge or of 0 crossed it): see their status in {table.name}"
        )
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="corrected commands: joints and nominal-model targets reaching TARGETS")
    p.add_argument("robot", help="the calibrated robot (calibrated_robot.yaml) or a bundled name")
    p.add_argument(
        "targets",
        help="a robot program (ABB RAPID .mod/.modx/.prg/.sys, KUKA KRL .dat) or a CSV: target, x, y, z (m, W) "
        "[, rx, ry, rz (rad)] [, q1..qn hints (rad)]",
    )
    p.add_argument(
        "--out", required=True, help="the corrected program (and OUT.corrections.csv beside it), or the output CSV"
    )
    p.add_argument(
        "--targets-frame", choices=("W", "controller"), default="W",
        help="a targets CSV's frame: the calibration's W (default), or the controller's base frame, placed as "
        "program filtering places it",
    )  # fmt: skip
    p.add_argument(
        "--length-unit", choices=("m", "mm"), default="m", help="of a targets CSV and its output (default m)"
    )
    p.add_argument(
        "--angle-unit", choices=("rad", "deg"), default="rad", help="of a targets CSV and its output (default rad)"
    )
    p.add_argument(
        "--orientation", choices=tuple(ORIENTATIONS), default="rotvec",
        help="a targets CSV's orientation columns, and its output's: rotvec (rx ry rz), rpy (roll pitch yaw: "
        "Rz(yaw) Ry(pitch) Rx(roll)), abc (a b c, KUKA: Rz(A) Ry(B) Rx(C)) or quaternion (qw qx qy qz); "
        "default rotvec",
    )  # fmt: skip
    p.add_argument(
        "--tool", nargs="+", metavar="TOOL",
        help="a program's TCP: a tooldata the module declares, or X Y Z A B C (mm, deg; KUKA $TOOL); default the "
        "tool of each target's first instruction, else the flange",
    )  # fmt: skip
    p.add_argument(
        "--base", nargs="+", metavar="BASE",
        help="a program's work object: a wobjdata the module declares, or X Y Z A B C (mm, deg; KUKA $BASE) in the "
        "robot's base frame; default each target's \\WObj, else the base frame",
    )  # fmt: skip
    p.add_argument("--tcp", type=LENGTH_M, nargs=3, help="TCP in the robot's tool frame (m; default its origin)")
    p.add_argument(
        "--tip", metavar="NAME",
        help="a tree's tip the targets are for (the robot's tip names, fgcal fk lists them; --tcp is then in that "
        "tip's frame); default the tool on the flange",
    )  # fmt: skip
    p.add_argument("--nominal", help="the controller's nominal model (default: the bundled robot of the same name)")
    p.add_argument(
        "--payload-mass",
        type=real(0.0, 10000.0, "kg"),
        help="payload (kg) for the deflection (default the robot file's)",
    )
    p.add_argument("--payload-com", type=LENGTH_M, nargs=3, help="payload centre of mass in the flange frame (m)")
    p.add_argument(
        "--tolerance-um",
        type=real(0.0, 1e6, "um", above_low=True),
        default=1.0,
        help="how close counts as reached, um (default 1; angles 1 urad)",
    )
    p.add_argument(
        "--approach", choices=("previous", "none"), default="previous",
        help="with a robot calibrated with lost motion (model DH,s,e,h): each target is approached from the "
        "previous one, in the file's order, unless before_q1.. give its approach (previous, the default), or the "
        "approach is not allowed for (none)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help=JSON_HELP)
    p.set_defaults(func=cmd_compensate)
