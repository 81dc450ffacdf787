"""``fgcal export ROBOT``: a robot as URDF (and a UR arm's default_kinematics.yaml)."""

from __future__ import annotations

import argparse
import sys

from ..core.console import say
from .options import LENGTH_M, add_package_option, real, xacro_packages


def cmd_export(args: argparse.Namespace) -> int:
    from ..reports.export import export_command

    if args.urdf is None and args.ur_kinematics is None:
        print("fgcal: error: fgcal export: give --urdf OUT.urdf, --ur-kinematics OUT.yaml or both", file=sys.stderr)
        return 2
    if args.nominal is not None and args.ur_kinematics is None and args.template is None:
        print("fgcal: error: fgcal export: --nominal applies to --ur-kinematics and --template", file=sys.stderr)
        return 2
    with xacro_packages(args):
        return export_command(
            args.robot, args.urdf, tip=args.tip, template=args.template, calibration=args.calibration,
            rigid_fit=args.rigid_fit, payload_mass=args.payload_mass, payload_com=args.payload_com,
            ur_kinematics=args.ur_kinematics, nominal=args.nominal, say=say,
        )  # fmt: skip


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write a robot (calibrated or nominal) as URDF, compliances in a sidecar YAML")
    p.add_argument("robot", help="robot file (calibrated_robot.yaml, a URDF) or a bundled name")
    p.add_argument("--urdf", help="output URDF file; the sidecar <stem>.compliance.yaml goes beside it")
    p.add_argument(
        "--ur-kinematics",
        help="also (or only) write the calibrated kinematics of a UR arm as the UR ROS 2 description's "
        "default_kinematics.yaml (x y z roll pitch yaw per joint)",
    )
    p.add_argument(
        "--nominal",
        help="the controller's nominal model, for --ur-kinematics and for --template with a robot not read from "
        "that URDF (default: the bundled robot of the same name)",
    )
    p.add_argument("--tip", help="tip link of a URDF input (default tool0, else its only leaf)")
    p.add_argument(
        "--template",
        help="the robot's own URDF (or the vendor's xacro, expanded) to write the calibration into (default: the "
        "URDF the robot came from, if any); a DH robot goes into the URDF of the same robot (same FK)",
    )
    p.add_argument(
        "--calibration",
        help="the calibration's config: state the URDF's accuracy on its data (fitting and held out) beside the "
        "full model's; its fitting configurations are the region of --rigid-fit",
    )
    p.add_argument(
        "--rigid-fit",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="refit the rigid parameters to the full model (with the deflection at the payload) over the "
        "calibrated region, so that the URDF holds what it can of the compliances (the default for a robot "
        "with compliances; --no-rigid-fit writes the calibrated rigid values as they are)",
    )
    p.add_argument(
        "--payload-mass", type=real(0.0, 10000.0, "kg"), help="payload of --rigid-fit (kg; default the robot's)"
    )
    p.add_argument("--payload-com", type=LENGTH_M, nargs=3, help="payload centre of mass in the flange frame (m)")
    add_package_option(p)
    p.set_defaults(func=cmd_export)
