"""``fgcal list robots|cells`` (and ``fgcal robots``): what is bundled."""

from __future__ import annotations

import argparse

from .options import bundled_cell, bundled_cells


def cmd_list(args: argparse.Namespace) -> int:
    if args.what == "robots":
        return cmd_robots(args)
    from ..simulation.cell import load_cell

    names = bundled_cells()
    width = max(map(len, names)) + 2
    for name in names:
        cell = load_cell(bundled_cell(name))
        print(f"{name:{width}s} {cell.name} ({cell.robot.name})")
    return 0


def cmd_robots(args: argparse.Namespace) -> int:
    from ..model.robot_io import bundled_robots, load_robot

    names = bundled_robots()
    width = max(map(len, names)) + 2
    for name in names:
        robot = load_robot(name)
        coupled = f", {len(robot.coupled)} more coupled" if robot.coupled else ""
        tips = f"; tips {', '.join(robot.tip_names)}" if robot.tips else ""
        print(f"{name:{width}s} {robot.name} ({robot.n_joints} joints{coupled}{tips})")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("robots", help="list the bundled robot descriptions (as fgcal list robots)")
    p.set_defaults(func=cmd_robots)
    p = sub.add_parser("list", help="list the bundled robots or cells")
    p.add_argument("what", choices=("robots", "cells"), help="robots or cells")
    p.set_defaults(func=cmd_list)
