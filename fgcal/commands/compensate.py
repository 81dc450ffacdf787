"""``fgcal compensate ROBOT TARGETS``: corrected commands, for a targets CSV or a robot program."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from ..core.console import Reporter, say, warn
from ..data.compensation import ORIENTATIONS
from .options import JSON_HELP, count, emit, payload_com, real


def cmd_compensate(args: argparse.Namespace) -> int:
    from ..core.errors import InputError
    from ..core.outputs import distinct, output_file
    from ..data.assumptions import Assumptions, frame_text, payload_text
    from ..data.compensation import SOLVED, TargetUnits, compensate, nominal_of, read_targets, write_compensation
    from ..data.program_filter import controller_frame
    from ..model.robot_io import load_robot

    output_file(args.out, "--out")  # before the work, not after it

    # At the calibration's payload: the controller's base frame is placed there, whatever the tool
    # carries; the deflection of each target is that of its tool's load (docs/using.md).
    robot = load_robot(args.robot)
    nominal = nominal_of(robot, args.nominal)
    from ..data.programs import KRL_SUFFIXES, RAPID_SUFFIXES

    if args.tip is not None and robot.tip_error(args.tip):
        raise InputError(args.robot, "--tip", robot.tip_error(args.tip))
    if Path(args.targets).suffix.lower() == ".src":  # KRL: the motions; the targets are in the .dat
        data = Path(args.targets).with_suffix(".dat")
        raise InputError(
            args.targets, None, f"a KRL .src holds the motions; its targets are declared in {data.name}"
            f"{'' if data.exists() else ' (not found beside it)'}: compensate that file (a target written inline "
            "in the .src, LIN {X ...}, is not corrected: declare it in the .dat)",
        )  # fmt: skip
    if Path(args.targets).suffix.lower() in RAPID_SUFFIXES + KRL_SUFFIXES:
        if args.tip is not None:
            raise InputError(args.targets, "--tip", "a robot program drives its robot's flange: --tip is for a CSV")
        from .filter_program import compensate_program

        return compensate_program(args, robot, nominal, _inputs(args, "PROGRAM"), _unsolved_motion)
    if args.tool is not None or args.base is not None or args.declarations:
        print("fgcal: error: --tool, --base and --declarations apply to robot programs (RAPID, KRL), not to a CSV",
              file=sys.stderr)  # fmt: skip
        return 2
    if Path(args.out).suffix.lower() != ".csv":
        raise InputError(args.out, "--out", "the commands of a targets CSV are a .csv file")
    distinct({"--out": args.out}, _inputs(args, "TARGETS"))
    units = TargetUnits(args.length_unit, args.angle_unit, args.orientation)
    targets = read_targets(args.targets, robot.n_joints, units, robot.prismatic)
    tcp = _tcp(args.tcp, units.to_m)
    frame = args.targets_frame or "controller"
    T_W_ctrl = controller_frame(robot, nominal)
    wanted = _in_calibration_frame(targets.as_ik_targets(), T_W_ctrl, frame)
    loaded, source = robot, "the robot file's: the calibration's payload"
    if args.payload_mass is not None or args.payload_com is not None:
        mass = robot.payload_mass if args.payload_mass is None else args.payload_mass
        com = robot.payload_com if args.payload_com is None else payload_com(args.payload_com, units.to_m, robot)
        loaded = robot.with_tool(robot.tool_pose, float(mass), com)
        source = " and ".join(o for o, v in (("--payload-mass", args.payload_mass), ("--payload-com", args.payload_com))
                              if v is not None) + ("" if args.payload_mass is not None and args.payload_com is not None
                                                   else "; the rest the robot file's")  # fmt: skip
    payload = payload_text(loaded.payload_mass, loaded.payload_com, source, robot.payload_mass)
    say(f"  payload: {payload}")
    approach, approach_words = _approach(args, robot, targets.approach, len(targets.names))
    result = compensate(
        loaded, nominal, wanted, targets.hints, tcp, "tool" if args.tip is None else args.tip,
        tol_m=1e-6 * args.tolerance_um, tol_rad=1e-6, progress=Reporter(), approach=approach, speed=targets.speed,
    )  # fmt: skip
    on = "the robot's tool frame" if args.tip is None else f"tip {args.tip}'s frame"
    orientation = f", orientation {units.orientation} ({ORIENTATION_WORDS[units.orientation]})"
    assumptions = Assumptions(
        what=f"commands from fgcal compensate: {robot.name} as {Path(args.robot).name} calibrated it, for a controller "
        f"running the nominal model of {nominal.name}",
        frame=frame_text(frame, T_W_ctrl),
        tool=f"TCP at ({', '.join(f'{v * 1e3:.12g}' for v in tcp)}) mm in {on}",
        payload=payload,
        units=f"lengths {units.length}, angles {units.angle}"
        + (orientation if targets.rotations is not None else "; positions only"),
        approach=approach_words,
        notes=("a row without joints and command was not compensated: its status says why",),
    )  # fmt: skip
    write_compensation(
        args.out, targets.names, result, targets.rotations is not None, units, robot.prismatic,
        assumptions.commented("#"),
    )  # fmt: skip
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
        "targets_frame": frame, "controller_in_W": T_W_ctrl.tolist(), "tcp_m": tcp.tolist(),
        "payload_mass_kg": float(loaded.payload_mass), "payload_com_m": [float(v) for v in loaded.payload_com],
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


ORIENTATION_WORDS = {
    "rotvec": "rx ry rz, a rotation vector",
    "rpy": "roll pitch yaw, R = Rz(yaw) Ry(pitch) Rx(roll)",
    "abc": "a b c, R = Rz(A) Ry(B) Rx(C)",
    "quaternion": "qw qx qy qz",
}


def _tcp(given: list[float] | None, to_m: float) -> np.ndarray:
    """--tcp in metres: given in --length-unit, within 10 m."""
    from ..core.errors import InputError

    tcp = np.zeros(3) if given is None else np.array(given, dtype=float) * to_m
    if np.abs(tcp).max() > MAX_TCP_M:
        raise InputError(None, "--tcp", f"{' '.join(map(str, given))}: a TCP within {MAX_TCP_M:g} m of the tool frame")
    return tcp


MAX_TCP_M = 10.0


def _inputs(args: argparse.Namespace, targets: str) -> dict[str, str | None]:
    """Every file the command reads, by the name the command line gives it (a bundled robot's
    name is none)."""
    return {
        targets: args.targets,
        "ROBOT": args.robot if Path(args.robot).suffix else None,
        "--nominal": args.nominal if args.nominal is not None and Path(args.nominal).suffix else None,
        **{f"--declarations {path}": path for path in args.declarations or []},
    }


def _approach(
    args: argparse.Namespace, robot, given: np.ndarray | None, n_targets: int
) -> tuple[np.ndarray | None, str]:
    """The approach of each target for compensate (None: not allowed for), and what it
    assumes, said and returned in words."""
    if not robot.history:
        if given is not None and np.isfinite(given).any():
            say(f"  the before_q columns are not used: {robot.name}'s model ({robot.model}) has no lost motion")
        return None, f"not modelled: {robot.name}'s model ({robot.model}) has no lost motion"
    if args.approach == "none":
        words = "lost motion not allowed for (--approach none): the commands are the joints the calibrated model needs"
        say(f"  {words}")
        return None, words
    n_given = 0 if given is None else int(np.all(np.isfinite(given), axis=1).sum())
    words = (
        "lost motion allowed for: each target approached from the previous one in the file's order"
        + (f" ({n_given} from the joints their before_q columns give)" if n_given else "")
        + "; the first gets no allowance"
    )
    say(f"  allowing for {words.removeprefix('lost motion allowed for: ')} (--approach none: none at all)")
    return (given if given is not None else np.full((n_targets, robot.n_joints), np.nan)), words


def _unsolved_motion(names: list[str]) -> None:
    if names:
        shown = ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")
        warn(
            f"{count(len(names), 'target')} ({shown}): no lost-motion allowance could be solved (a move of a "
            "fraction of a degree, where the speed term's model does not hold): commanded without it"
        )


def _in_calibration_frame(targets: np.ndarray, T_W_ctrl: np.ndarray, frame: str) -> np.ndarray:
    """Targets (N, 3) or (N, 4, 4) in the calibration's W: from the controller's base frame
    (``controller``, the default, placed as program filtering places it), or as given (``W``).
    Says which, and how far the two frames are."""
    from ..core.se3 import so3_log

    offset_m, turn_rad = np.linalg.norm(T_W_ctrl[:3, 3]), np.linalg.norm(so3_log(T_W_ctrl[:3, :3]))
    apart = f"{offset_m * 1e3:.3g} mm and {np.degrees(turn_rad) * 1e3:.3g} mdeg"
    if frame == "controller":
        say(f"  targets in the controller's base frame, which lies {apart} from the calibration's frame W "
            "(--targets-frame W reads them in W)")  # fmt: skip
        return T_W_ctrl @ targets if targets.ndim == 3 else targets @ T_W_ctrl[:3, :3].T + T_W_ctrl[:3, 3]
    say(f"  targets in the calibration's frame W (--targets-frame W); the controller's base frame lies {apart} from it")
    return targets


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("compensate", help="corrected commands: joints and nominal-model targets reaching TARGETS")
    p.add_argument("robot", help="the calibrated robot (calibrated_robot.yaml) or a bundled name")
    p.add_argument(
        "targets",
        help="a robot program (ABB RAPID .mod/.modx/.prg/.sys, KUKA KRL .dat) or a CSV: target, x, y, z (m, the "
        "controller's base frame) "
        "[, rx, ry, rz (rad)] [, q1..qn hints (rad)]",
    )
    p.add_argument(
        "--out", required=True, help="the corrected program (and OUT.corrections.csv beside it), or the output CSV"
    )
    p.add_argument(
        "--targets-frame", choices=("W", "controller"),
        help="a targets CSV's frame: the controller's base frame, placed as program filtering places it (default, "
        "as a program's), or the calibration's W",
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
    p.add_argument(
        "--tcp", type=real(-1e4, 1e4, "m, or mm with --length-unit mm"), nargs=3,
        help="TCP in the robot's tool frame, in --length-unit (default m; within 10 m; default the tool's origin)",
    )  # fmt: skip
    p.add_argument(
        "--tip", metavar="NAME",
        help="a tree's tip the targets are for (the robot's tip names, fgcal fk lists them; --tcp is then in that "
        "tip's frame); default the tool on the flange",
    )  # fmt: skip
    p.add_argument(
        "--declarations", nargs="+", metavar="FILE",
        help="files declaring a program's tools and work objects: RAPID modules (user.sys: tooldata, wobjdata), or "
        "KUKA's $config.dat (TOOL_DATA, BASE_DATA, LOAD_DATA), which each target's FDAT (TOOL_NO, BASE_NO) names",
    )  # fmt: skip
    p.add_argument("--nominal", help="the controller's nominal model (default: the bundled robot of the same name)")
    p.add_argument(
        "--payload-mass",
        type=real(0.0, 10000.0, "kg"),
        help="payload (kg) for the deflection (default the robot file's)",
    )
    p.add_argument(
        "--payload-com", type=real(-1e4, 1e4, "m, or mm with --length-unit mm"), nargs=3,
        help="payload centre of mass in the flange frame, in --length-unit (default m; a program's: m)",
    )  # fmt: skip
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
