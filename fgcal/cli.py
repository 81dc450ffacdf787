"""The ``fgcal`` command. Errors in user input print one clear line and exit with 2."""

from __future__ import annotations

import argparse
import os
import sys
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

import numpy as np

from .console import Reporter, detail, say, warn
from .errors import FgcalError


def bundled_cells() -> list[str]:
    from .robot_io import robots_dir

    return sorted(p.stem for p in (robots_dir().parent / "cells").glob("*.yaml"))


def _bundled_cell(path: str) -> Path:
    """A cell file as given (a path ending in .yaml), or a bundled cell's name such as
    ``kr125_seed``: a name without the suffix is a bundled cell, whatever local folder is
    called the same."""
    from .errors import InputError
    from .robot_io import robots_dir

    candidate = Path(path)
    if candidate.suffix in (".yaml", ".yml"):
        return candidate
    bundled = robots_dir().parent / "cells" / f"{path}.yaml"
    if bundled.exists():
        return bundled
    if candidate.is_file():
        return candidate
    raise InputError(path, None, f"no such cell file or bundled cell (bundled: {', '.join(bundled_cells())})")


def _emit(args: argparse.Namespace, document: dict) -> None:
    """With --json: the command's one strict JSON object (SI units) on stdout."""
    if getattr(args, "json", False):
        from . import strict_json

        print(strict_json.dumps({"command": args.command, **document}))


def cmd_simulate(args: argparse.Namespace) -> int:
    from .calibration.suggest import write_suggested_config
    from .dataset import load_dataset
    from .simulation.cell import load_cell
    from .simulation.simulate import simulate

    result = simulate(
        _bundled_cell(args.cell),
        args.out,
        args.seed,
        design=args.design,
        n_configurations=args.n,
        progress=Reporter(),
        render=args.render,
        drift=_parse_drift(args.drift),
        configurations=args.configurations,
    )
    say(result.summary())
    config = write_suggested_config(load_cell(_bundled_cell(args.cell)), load_dataset(args.out))
    say(f"  calibration config: {config} (fgcal calibrate {config} --out REPORT)")
    _emit(args, {
        "dataset": str(result.out_dir), "calibration_config": str(config), "seed": result.seed,
        "design": result.design, "n_configurations": result.n_configurations, "observations": result.n_observations,
        "nominal_deviation_mean_m": result.deviation_mean_m, "nominal_deviation_max_m": result.deviation_max_m,
        "time_s": result.time_s,
    })  # fmt: skip
    return 0


def _parse_drift(text: str | None):
    from .errors import InputError
    from .simulation.simulate import Drift

    if text is None:
        return None
    try:
        name, rest = text.split("=", 1)
        value, start = rest.split("@", 1)
        drift = Drift(name.strip(), float(value), int(start))
    except ValueError:
        raise InputError(None, "--drift", f"expected NAME=CHANGE@CONFIGURATION (SI units), got {text!r}") from None
    if not (np.isfinite(drift.change) and abs(drift.change) <= 1.0):
        raise InputError(None, "--drift", f"the change is a step of at most 1 (m or rad), got {drift.change:g}")
    return drift


def cmd_online(args: argparse.Namespace) -> int:
    from .online.service import OnlineService

    service = OnlineService(args.state, args.inbox, args.setup, say=say)
    try:
        service.run(once=args.once, poll_s=args.poll)
    except KeyboardInterrupt:
        service.write_final()
    finally:
        service.close()
    report = service.report()
    if not report["n_images"]:
        say(f"no image folded in yet ({report['n_logged']} logged); nothing written to {args.state}")
        return 0
    accuracy = report["predicted_accuracy"]
    say(
        f"{report['n_images']} images; predicted RMS flange sigma {accuracy['rms_m'] * 1e3:#.4g} mm; "
        f"{len(report['alarms'])} drift alarms; wrote {args.state}/report.json, report.md, calibrated_robot.yaml"
    )
    return 0


def cmd_online_feed(args: argparse.Namespace) -> int:
    from .online.feed import feed_dataset

    written = feed_dataset(args.dataset, args.inbox, args.first, args.n, args.cycle_size)
    say(f"wrote {written} measurement files to {args.inbox}")
    return 0


def _score(result):
    """After the calibration: a simulated dataset is scored against its truth (truth/)."""
    from .calibration.run import held_out_summary
    from .calibration.scoring import score_with_truth

    result = score_with_truth(result)
    line = held_out_summary(result)
    if line:
        say(line)
    return result


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .calibration.config import load_config
    from .calibration.run import calibrate
    from .reports.calibration import write_report

    result = _score(calibrate(load_config(args.config), progress=Reporter()))
    started = time.perf_counter()
    doc = write_report(result, args.out, plots=not args.no_plots)
    say(
        f"wrote {args.out}/report.md, report.json, calibrated_robot.yaml, estimates.yaml "
        f"(calibration {result.timing['total_s']:.2f} s, report {time.perf_counter() - started:.2f} s)"
    )
    for name, entry in doc["parameters"].items():  # with -v: every estimate, in the units of report.md
        if entry.get("sigma") is not None:
            scale, unit = {"m": (1e3, "mm"), "rad": (180e3 / np.pi, "mdeg")}.get(entry["unit"], (1.0, entry["unit"]))
            detail(
                f"  {name:10s} {entry['difference_from_nominal'] * scale:+#.4g} {unit} from nominal, "
                f"sigma {entry['sigma'] * scale:#.3g} {unit}"
            )
    out = Path(args.out)
    files = ["report.md", "report.json", "calibrated_robot.yaml", "estimates.yaml"]
    _emit(args, {
        "out": str(out), "files": {name: str(out / name) for name in files},
        "model": doc["model"], "formulation": doc["formulation"], "headline": doc["headline"],
        "goodness_of_fit": doc["goodness_of_fit"], "seed": doc["seed"],
    })  # fmt: skip
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    import dataclasses

    import yaml

    from .calibration.config import load_config
    from .calibration.run import calibrate
    from .outputs import output_dir, write_text
    from .reports.calibration import write_report
    from .simulation.simulate import simulate

    out = output_dir(args.out)
    say(f"1/3 simulating the seed cell: space-filling design of {args.n} configurations, seed {args.seed}")
    sim = simulate(
        _bundled_cell("kr125_seed"),
        out / "data",
        args.seed,
        design="space_filling",
        n_configurations=args.n,
        progress=Reporter(),
    )
    say(sim.summary())
    config_path = write_text(
        out / "calibration.yaml",
        yaml.safe_dump({"dataset": "data", "formulation": args.formulation, "model": "DH,s,e"}, sort_keys=False),
    )
    say(f"2/3 calibrating ({config_path})")
    result = _score(calibrate(load_config(config_path), progress=Reporter()))
    if result.truth is not None:
        from .calibration.scoring import compensation_study

        study = compensation_study(result)
        result = dataclasses.replace(result, compensation=study)
        say(
            f"  compensation of {study.n_targets} random targets, driven through the true robot: "
            f"{study.uncompensated_rms_m * 1e3:.4g} mm RMS with the nominal model's joints, "
            f"{study.compensated_rms_m * 1e3:.4g} mm with the calibrated model's ({study.improvement:.0f}x)"
        )
    say("3/3 writing the report")
    write_report(result, out / "report")
    say(f"report: {out / 'report' / 'report.md'}")
    return 0


def cmd_compensate(args: argparse.Namespace) -> int:
    from .compensation import TargetUnits, compensate, nominal_of, read_targets, write_compensation
    from .errors import InputError
    from .outputs import distinct, output_file
    from .robot_io import load_robot

    output_file(args.out, "--out")  # before the work, not after it

    robot = load_robot(args.robot)
    calibrated = robot  # at the calibration's payload: where the controller's base frame is placed
    if args.payload_mass is not None or args.payload_com is not None:
        mass = robot.payload_mass if args.payload_mass is None else args.payload_mass
        com = robot.payload_com if args.payload_com is None else np.array(args.payload_com)
        robot = robot.with_tool(robot.tool_pose, float(mass), com)
    nominal = nominal_of(robot, args.nominal)
    from .programs import KRL_SUFFIXES, RAPID_SUFFIXES

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
    distinct({"--out": args.out}, {"TARGETS": args.targets, "ROBOT": args.robot if Path(args.robot).suffix else None})
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
    _emit(args, {
        "out": str(args.out), "n_targets": len(targets.names), "status": counts,
        "residual_max_m": float(result.residual_m.max()),
    })  # fmt: skip
    reached = result.status != "unreachable"
    if reached.any():
        say(f"  reached in the calibrated model to {result.residual_m[reached].max() * 1e6:.3g} um at worst")
    if (~reached).any():
        gaps = result.residual_m[~reached] * 1e3
        span = (
            f"{gaps.min():.4g} mm" if np.isclose(gaps.min(), gaps.max()) else f"{gaps.min():.4g} to {gaps.max():.4g} mm"
        )
        say(f"  {_count(int((~reached).sum()), 'target')} unreachable: the calibrated model stays {span} away")
    return 0


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
            f"{_count(len(names), 'target')} ({shown}): no lost-motion allowance could be solved (a move of a "
            "fraction of a degree, where the speed term's model does not hold): commanded without it"
        )


def _in_calibration_frame(targets: np.ndarray, robot, nominal, frame: str) -> np.ndarray:
    """Targets (N, 3) or (N, 4, 4) in the calibration's W: as given (``W``), or from the
    controller's base frame (``controller``), placed as program filtering places it. With
    ``W``, says how far the controller's frame is, when that is more than 1 mm or 1 mrad."""
    from .program_filter import controller_frame
    from .se3 import so3_log

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


UNCHANGED_M, UNCHANGED_RAD = 5e-7, 1e-8  # a correction below these is none (the files hold um and 1e-9)


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _compensate_program(args: argparse.Namespace, robot, nominal) -> int:
    from .dataset import write_csv
    from .errors import InputError
    from .outputs import distinct, output_file, write_bytes
    from .program_filter import WRITTEN, check_program, correction_rows, filter_targets, program_frames, program_path
    from .programs import KRL_SUFFIXES, RAPID_SUFFIXES, read_program, write_program

    source, out = Path(args.targets), Path(args.out)
    distinct({"--out": out, "the corrections table": out.with_name(f"{out.stem}.corrections.csv")},
             {"PROGRAM": source, "ROBOT": args.robot if Path(args.robot).suffix else None})  # fmt: skip
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
    _emit(args, {
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
        say(f"  {_count(int((solved & ~moved).sum()), 'target')} need no correction (below 0.5 um and 0.01 urad): kept")
    if (~solved).any():
        say(f"  {_count(int((~solved).sum()), 'target')} left as they were: see their status in {table.name}")
    if result.in_region is not None and (solved & ~result.in_region).any():
        warn(
            f"{_count(int((solved & ~result.in_region).sum()), 'target')} need joints outside the range the "
            "calibration measured: their correction is the model's extrapolation "
            f"(in_calibrated_region in {table.name})"
        )
    if (result.status == "configuration changed").any():
        warn("some corrected targets need another configuration (new confdata or S/T): check their path")
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    from . import strict_json
    from .bench import run_bench

    sizes = tuple(args.sizes)
    # With --json, stdout carries the JSON object alone; the progress goes to stderr.
    faro = Path(args.faro) if args.faro else None
    if faro is not None and not (faro / "dataset.yaml").exists():
        print(
            f"fgcal: error: {faro}: no dataset.yaml (convert the FARO files with fgcal convert-faro)", file=sys.stderr
        )
        return 2
    result = run_bench(
        Path(args.out), seed=args.seed, sizes=sizes, repeats=args.repeats, say=say, faro=faro, memory_n=args.memory_n
    )
    if args.json:
        print(strict_json.dumps(result))
    return 0


def cmd_convert_faro(args: argparse.Namespace) -> int:
    from .faro import convert_faro

    counts = convert_faro(args.src, args.out)
    say(f"wrote {args.out}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0


def cmd_import_csv(args: argparse.Namespace) -> int:
    from .csv_import import import_tables

    counts = import_tables(args.mapping, args.out)
    say(f"wrote {args.out}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return 0


def cmd_plan(args: argparse.Namespace) -> int:
    from .planning.plan import plan, write_plan

    result = plan(
        _bundled_cell(args.cell),
        args.n,
        criterion=args.criterion,
        n_candidates=args.candidates,
        formulation=args.formulation,
        model=args.model,
        seed=args.seed,
        progress=Reporter(),
        approach=args.approach,
        approach_offset_rad=float(np.radians(args.approach_offset)),
    )
    written = write_plan(result, args.out, plot=not args.no_plots)
    say(
        f"  predicted position accuracy {result.predicted_sigma_m * 1e3:.4f} mm RMS over the region "
        f"(space-filling design of {args.n}: {result.space_filling_sigma_m * 1e3:.4f} mm); "
        f"condition number {result.indices['condition_number']:.3g}"
    )
    t = result.timing_s
    say(f"  CPU time: candidates {t['candidates']:.1f} s, selection {t['selection']:.1f} s")
    if result.lost_motion is not None:
        lost = result.lost_motion
        advice = (
            "this plan: calibrate it with DH,s,e" if result.approach == "unidirectional"
            else "--approach unidirectional; visited in order, calibrate with DH,s,e,h"
        )  # fmt: skip
        say(
            f"  the cell's lost motion, beyond what constant joint offsets absorb: {lost['in_order_rms_m'] * 1e3:.4g} "
            f"mm RMS with the plan visited in order, {lost['unidirectional_rms_m'] * 1e3:.4g} mm with each "
            f"configuration approached from below ({advice})"
        )
    say(f"wrote {args.out}: {', '.join(written)}")
    _emit(args, {
        "out": str(args.out), "files": {name: str(Path(args.out) / name) for name in written},
        "n_configurations": args.n, "criterion": args.criterion,
        "predicted_sigma_m": result.predicted_sigma_m, "space_filling_sigma_m": result.space_filling_sigma_m,
        "condition_number": result.indices["condition_number"], "cpu_s": dict(result.timing_s),
        "approach": result.approach, "lost_motion": result.lost_motion,
    })  # fmt: skip
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    from .reports.export import export_command

    if args.urdf is None and args.ur_kinematics is None:
        print("fgcal: error: fgcal export: give --urdf OUT.urdf, --ur-kinematics OUT.yaml or both", file=sys.stderr)
        return 2
    if args.nominal is not None and args.ur_kinematics is None:
        print("fgcal: error: fgcal export: --nominal applies to --ur-kinematics", file=sys.stderr)
        return 2
    return export_command(
        args.robot, args.urdf, tip=args.tip, template=args.template, calibration=args.calibration,
        rigid_fit=args.rigid_fit, payload_mass=args.payload_mass, payload_com=args.payload_com,
        ur_kinematics=args.ur_kinematics, nominal=args.nominal, say=say,
    )  # fmt: skip


def cmd_list(args: argparse.Namespace) -> int:
    if args.what == "robots":
        return cmd_robots(args)
    from .simulation.cell import load_cell

    names = bundled_cells()
    width = max(map(len, names)) + 2
    for name in names:
        cell = load_cell(_bundled_cell(name))
        print(f"{name:{width}s} {cell.name} ({cell.robot.name})")
    return 0


def cmd_robots(args: argparse.Namespace) -> int:
    from .robot_io import bundled_robots, load_robot

    names = bundled_robots()
    width = max(map(len, names)) + 2
    for name in names:
        robot = load_robot(name)
        coupled = f", {len(robot.coupled)} more coupled" if robot.coupled else ""
        tips = f"; tips {', '.join(robot.tip_names)}" if robot.tips else ""
        print(f"{name:{width}s} {robot.name} ({robot.n_joints} joints{coupled}{tips})")
    return 0


def cmd_fk(args: argparse.Namespace) -> int:
    from .errors import InputError
    from .robot_io import is_urdf_reference, load_robot

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


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line, like every other error: ``fgcal: error: ...``, exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"fgcal: error: {self.prog}: {message} (see {self.prog} --help)\n")


def _integer(low: int, high: int, what: str) -> Callable[[str], int]:
    """An argparse type: a whole number of ``what`` from ``low`` to ``high``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number of {what}, got {text!r}") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{low} to {high} {what}, got {value}")
        return value

    return parse


def _real(low: float, high: float, unit: str, *, above_low: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in [low, high] (``above_low``: in (low, high])."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number ({unit}), got {text!r}") from None
        inside = (value > low if above_low else value >= low) and value <= high
        if not (np.isfinite(value) and inside):
            bracket = "(" if above_low else "["
            raise argparse.ArgumentTypeError(f"a number in {bracket}{low:g}, {high:g}] {unit}, got {text}")
        return value

    return parse


SEED = _integer(0, 2**32 - 1, "(the random seed)")
LENGTH_M = _real(-10.0, 10.0, "m")


def build_parser() -> argparse.ArgumentParser:
    from .compensation import ORIENTATIONS
    from .planning import MAX_CANDIDATES
    from .simulation import MAX_CONFIGURATIONS

    configurations = _integer(1, MAX_CONFIGURATIONS, "configurations")
    parser = _Parser(prog="fgcal", description="Robot calibration with factor graphs (GTSAM).")
    parser.add_argument("--version", action="version", version=f"fgcal {_version()}")
    _verbosity(parser, argparse.SUPPRESS)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("simulate", help="simulate a calibration cell: true robot, configurations, measurements")
    p.add_argument("cell", help="cell YAML file, or a bundled cell name (kr125_seed)")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.add_argument("--seed", type=SEED, default=1, help="random seed (default 1); same seed, same files")
    p.add_argument("--design", choices=("seed", "space_filling"), help="override the cell's design kind")
    p.add_argument(
        "--n",
        type=configurations,
        help=f"number of configurations of a space-filling design (1 to {MAX_CONFIGURATIONS})",
    )
    p.add_argument(
        "--configurations", help="CSV of configurations (config, q1..qn, block) to simulate exactly, e.g. fgcal plan's"
    )
    p.add_argument("--render", action="store_true", help="also render the camera images (ChArUco boards)")
    p.add_argument(
        "--drift", help="step change of one true parameter for the camera measurements, NAME=CHANGE@CONFIG (SI)"
    )
    p.add_argument(
        "--json", action="store_true", help="print one JSON object (SI units) on stdout; the lines go to stderr"
    )
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("calibrate", help="calibrate from a dataset as a calibration config describes")
    p.add_argument("config", help="calibration config YAML (docs/calibration.md)")
    p.add_argument("--out", required=True, help="output directory for the report and calibrated robot")
    p.add_argument("--no-plots", action="store_true", help="write report.md without the PNG plots")
    p.add_argument(
        "--json", action="store_true", help="print one JSON object (SI units) on stdout; the lines go to stderr"
    )
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("demo", help="simulate the seed cell, calibrate it and write the report")
    p.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    p.add_argument("--seed", type=SEED, default=1, help="simulation seed (default 1)")
    p.add_argument(
        "--n", type=configurations, default=300, help="configurations of the space-filling design (default 300)"
    )
    p.add_argument(
        "--formulation", choices=("pairs", "tracker"), default="pairs", help="what to calibrate from (default pairs)"
    )
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser(
        "bench", help="time fgcal's solve against a NumPy Gauss-Newton and scipy, and online latency (docs/cli.md)"
    )
    p.add_argument(
        "--out", default="out/bench", help="where the simulated cases are kept between runs (default out/bench)"
    )
    p.add_argument("--seed", type=SEED, default=1, help="simulation seed (default 1)")
    p.add_argument(
        "--sizes",
        type=_integer(20, 20000, "configurations"),
        nargs="+",
        default=[300, 1000],
        help="configurations per case (default 300 1000)",
    )
    p.add_argument(
        "--repeats",
        type=_integer(1, 100, "rounds"),
        default=3,
        help="interleaved rounds; the best of each is kept (default 3)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object (SI units) on stdout")
    p.add_argument("--faro", help="a dataset from fgcal convert-faro: time the whole calibrate command on it too")
    p.add_argument(
        "--memory-n",
        type=_integer(20, 20000, "configurations"),
        default=3000,
        help="configurations of the seed cell whose calibrate command's peak RSS is measured (default 3000)",
    )
    p.set_defaults(func=cmd_bench)

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
        type=_real(0.0, 10000.0, "kg"),
        help="payload (kg) for the deflection (default the robot file's)",
    )
    p.add_argument("--payload-com", type=LENGTH_M, nargs=3, help="payload centre of mass in the flange frame (m)")
    p.add_argument(
        "--tolerance-um",
        type=_real(0.0, 1e6, "um", above_low=True),
        default=1.0,
        help="how close counts as reached, um (default 1; angles 1 urad)",
    )
    p.add_argument(
        "--approach", choices=("previous", "none"), default="previous",
        help="with a robot calibrated with lost motion (model DH,s,e,h): each target is approached from the "
        "previous one, in the file's order, unless before_q1.. give its approach (previous, the default), or the "
        "approach is not allowed for (none)",
    )  # fmt: skip
    p.add_argument(
        "--json", action="store_true", help="print one JSON object (SI units) on stdout; the lines go to stderr"
    )
    p.set_defaults(func=cmd_compensate)

    p = sub.add_parser("online", help="online recalibration: fold measurement files from an inbox into the estimate")
    p.add_argument("--state", required=True, help="state directory (log, checkpoints, outputs)")
    p.add_argument("--inbox", required=True, help="directory where measurement files appear (docs/online.md)")
    p.add_argument("--setup", help="setup YAML for a new state directory (dataset with robot, camera, points)")
    p.add_argument("--once", action="store_true", help="process what is in the inbox, then exit")
    p.add_argument(
        "--poll", type=_real(0.0, 3600.0, "s"), default=1.0, help="seconds between looks at the inbox (default 1)"
    )
    p.set_defaults(func=cmd_online)

    p = sub.add_parser("online-feed", help="write a dataset's images as measurement files into an inbox")
    p.add_argument("dataset", help="dataset directory with pixels")
    p.add_argument("--inbox", required=True, help="the inbox folder fgcal online watches (created)")
    p.add_argument(
        "--first", type=_integer(0, 10**9, "configurations"), default=0, help="first configuration (default 0)"
    )
    p.add_argument("--n", type=_integer(1, 10**9, "images"), help="number of images (default all)")
    p.add_argument("--cycle-size", type=_integer(1, 10**9, "images"), help="images per work cycle (default: no cycles)")
    p.set_defaults(func=cmd_online_feed)

    p = sub.add_parser("convert-faro", help="convert the IRB 120 / FARO tracker text files to an fgcal dataset")
    p.add_argument("src", help="folder with measured_joints.txt and measured_SMR_*.txt")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.set_defaults(func=cmd_convert_faro)

    p = sub.add_parser(
        "import-csv", help="convert tracker, probe or ballbar exports (CSV, text) to a dataset (docs/formats.md)"
    )
    p.add_argument("mapping", help="mapping YAML (format: fgcal-import/1): files, columns, units")
    p.add_argument("--out", required=True, help="output dataset directory")
    p.set_defaults(func=cmd_import_csv)

    p = sub.add_parser("plan", help="choose the measurement configurations of a cell (docs/planning.md)")
    p.add_argument("cell", help="cell YAML file, or a bundled cell name (kr125_seed)")
    p.add_argument(
        "--n",
        type=_integer(1, MAX_CANDIDATES, "configurations"),
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
        type=_integer(1, MAX_CANDIDATES, "candidates"),
        default=5000,
        help=f"candidate configurations (default 5000, at most {MAX_CANDIDATES})",
    )
    p.add_argument(
        "--formulation", help="what to plan for (pairs, projection, tracker; default: what the cell measures with)"
    )
    p.add_argument(
        "--model", choices=("DH", "DH,s", "DH,s,e"), default="DH,s,e", metavar="MODEL",
        help="kinematic model whose parameters the plan determines: DH, DH,s or DH,s,e (default DH,s,e)",
    )  # fmt: skip
    p.add_argument("--seed", type=SEED, default=1, help="seed of the candidates (default 1)")
    p.add_argument(
        "--approach", choices=("previous", "unidirectional"), default="previous",
        help="each configuration reached from the one before (previous, the default), or from --approach-offset "
        "below on every joint (unidirectional: approach points in configurations.csv, lost motion absorbed)",
    )  # fmt: skip
    p.add_argument(
        "--approach-offset", type=_real(0.0, 30.0, "deg", above_low=True), default=2.0,
        help="how far below each configuration its approach point is, deg (default 2)",
    )  # fmt: skip
    p.add_argument("--no-plots", action="store_true", help="no predicted_accuracy.png")
    p.add_argument(
        "--json", action="store_true", help="print one JSON object (SI units) on stdout; the lines go to stderr"
    )
    p.set_defaults(func=cmd_plan)

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
        help="the controller's nominal model, for --ur-kinematics (default: the bundled robot of the same name)",
    )
    p.add_argument("--tip", help="tip link of a URDF input (default tool0, else its only leaf)")
    p.add_argument(
        "--template",
        help="the robot's own URDF to write the calibration into (default: the URDF the robot came from, if any)",
    )
    p.add_argument(
        "--calibration",
        help="the calibration's config: state the URDF's accuracy on its data (fitting and held out) beside the "
        "full model's; its fitting configurations are the region of --rigid-fit",
    )
    p.add_argument(
        "--rigid-fit",
        action="store_true",
        help="refit the rigid parameters to the full model (with the deflection at the payload) over the "
        "calibrated region, so that the URDF holds what it can of the compliances",
    )
    p.add_argument(
        "--payload-mass", type=_real(0.0, 10000.0, "kg"), help="payload of --rigid-fit (kg; default the robot's)"
    )
    p.add_argument("--payload-com", type=LENGTH_M, nargs=3, help="payload centre of mass in the flange frame (m)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("robots", help="list the bundled robot descriptions (as fgcal list robots)")
    p.set_defaults(func=cmd_robots)

    p = sub.add_parser("list", help="list the bundled robots or cells")
    p.add_argument("what", choices=("robots", "cells"), help="robots or cells")
    p.set_defaults(func=cmd_list)

    p = sub.add_parser("fk", help="forward kinematics of a robot (bundled, or a robot file) at one configuration")
    p.add_argument("robot", help="bundled robot name, robot YAML file or URDF")
    p.add_argument(
        "--tip", help="tip link of a URDF (default tool0, else its only leaf), or the one tip of a tree to print"
    )
    p.add_argument("q", nargs="+", type=_real(-1e6, 1e6, "rad, deg or m"), help="joint angles (rad, or deg with --deg)")
    p.add_argument("--deg", action="store_true", help="joint angles in degrees")
    p.add_argument("--tool", action="store_true", help="tool frame instead of the flange")
    p.set_defaults(func=cmd_fk)
    for command in sub.choices.values():  # fgcal -q calibrate ... and fgcal calibrate ... -q alike
        _verbosity(command, argparse.SUPPRESS)  # only when given: -q before the command is kept
    return parser


def _verbosity(parser: argparse.ArgumentParser, default) -> None:
    parser.add_argument("-q", "--quiet", action="count", default=default, help="only warnings and errors")
    parser.add_argument("-v", "--verbose", action="count", default=default, help="more detail")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("fgcal")
    except PackageNotFoundError:  # a source tree without an install
        return "unknown (not installed)"


def main(argv: list[str] | None = None) -> int:
    from .console import setup

    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, or a usage error already printed
        return exc.code if isinstance(exc.code, int) else 2
    setup(getattr(args, "verbose", 0) - getattr(args, "quiet", 0), to_stderr=getattr(args, "json", False))
    from threadpoolctl import threadpool_limits

    try:
        # fgcal's dense algebra is small (tens of columns): one BLAS thread is fastest, and
        # threads would stall each other on a busy machine.
        with threadpool_limits(limits=1, user_api="blas"):
            return args.func(args)
    except FgcalError as exc:  # the user's input: one line naming the file and field
        print(f"fgcal: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgcal: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader of stdout went away (| head): stop quietly, as a shell tool does
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (the interpreter's last flush must not fail)
        return 141
    except Exception:  # a bug of fgcal's, never dressed as the user's
        print("fgcal: internal error (please report it with the traceback below)", file=sys.stderr)
        traceback.print_exc()
        return 1


if __name__ == "__main__":
    sys.exit(main())
