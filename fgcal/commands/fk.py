"""``fgcal fk ROBOT Q...``: forward kinematics at one configuration."""

from __future__ import annotations

import argparse

import numpy as np

from .options import add_package_option, real, xacro_packages


def cmd_fk(args: argparse.Namespace) -> int:
    with xacro_packages(args):
        return _fk(args)


def _fk(args: argparse.Namespace) -> int:
    from ..core.errors import InputError
    from ..model.robot_io import is_urdf_reference, load_robot

    is_urdf = is_urdf_reference(args.robot)
    robot = load_robot(args.robot, args.tip if is_urdf or args.tip is None else None)
    if args.tip is not None and not is_urdf and robot.tip_error(args.tip):
        raise InputError(args.robot, "--tip", f"{robot.tip_error(args.tip)}; a URDF's tip link applies to URDF files")
    if args.tool and args.tip is not None and not is_urdf and args.tip not in ("flange", robot.flange_name):
        raise InputError(args.robot, "--tool", f"the tool is on the flange ({robot.flange_name}), not on {args.tip}")
    q = np.array(args.q, dtype=float)
    if len(q) != robot.n_joints:
        raise InputError(None, "q", f"{robot.name} has {robot.n_joints} joints: {robot.n_joints} values, got {len(q)}")
    if args.deg:
        q = np.where(robot.prismatic, q, np.deg2rad(q))
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    outside = np.flatnonzero((q < low - 1e-12) | (q > high + 1e-12))
    if len(outside):
        i = outside[0]
        unit = "m" if robot.prismatic[i] else "rad"
        hint = " (degrees need --deg)" if not args.deg and not robot.prismatic[i] else ""
        raise InputError(
            None, f"q{i + 1}", f"{args.q[i]:g} is {q[i]:.4g} {unit}, outside the joint's limits "
            f"[{low[i]:.4g}, {high[i]:.4g}] {unit}{hint}",
        )  # fmt: skip
    np.set_printoptions(precision=6, suppress=True)
    if robot.tips and not args.tool:  # a tree: every tip, or the one asked for
        for tip in robot.tip_names if args.tip is None or is_urdf else [args.tip]:
            print(f"T_W_{tip} (m) of {robot.name}:\n{np.round(robot.fk(q, tip=tip), 12) + 0.0}")
        return 0
    T = robot.fk_tool(q) if args.tool else robot.fk(q)
    print(f"T_W_{'C' if args.tool else 'n'} (m) of {robot.name}:\n{np.round(T, 12) + 0.0}")  # no -0.
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("fk", help="forward kinematics of a robot (bundled, or a robot file) at one configuration")
    p.add_argument("robot", help="bundled robot name, robot YAML file, URDF or xacro")
    p.add_argument(
        "--tip", help="tip link of a URDF (default tool0, else its only leaf), or the one tip of a tree to print"
    )
    p.add_argument("q", nargs="+", type=real(-1e6, 1e6, "rad, deg or m"), help="joint angles (rad, or deg with --deg)")
    p.add_argument("--deg", action="store_true", help="joint angles in degrees")
    p.add_argument("--tool", action="store_true", help="tool frame instead of the flange")
    add_package_option(p)
    p.set_defaults(func=cmd_fk)
