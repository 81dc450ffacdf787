"""``fgcal compensate ROBOT PROGRAM``: a RAPID module or KRL ``.dat`` corrected (program filtering),
with its corrections table; both state what they assumed (fgcal.data.assumptions)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.console import Reporter, say, warn
from .options import count, emit


def compensate_program(
    args: argparse.Namespace, robot, nominal, inputs: dict, unsolved_motion: Callable[[list[str]], None]
) -> int:
    """The program ``args.targets`` corrected to ``args.out``, the table beside it. ``robot`` is
    at the calibration's payload (the controller's base frame is placed there); the deflection is
    the tool's load's: --payload-mass/--payload-com, else the tooldata's tload, else the robot's."""
    from ..core.errors import InputError
    from ..core.outputs import distinct, output_file, write_bytes
    from ..data.assumptions import mixed_payload_text, payload_text
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
    from ..data.programs import (
        COMMENT,
        KRL_SUFFIXES,
        RAPID_SUFFIXES,
        corrected_at,
        read_program,
        with_declarations,
        with_header,
        write_program,
    )
    from .options import payload_com

    source, out = Path(args.targets), Path(args.out)
    table = out.with_name(f"{out.stem}.corrections.csv")
    distinct({"--out": out, "the corrections table": table}, inputs)
    if (source.suffix.lower() in KRL_SUFFIXES) != (out.suffix.lower() in KRL_SUFFIXES) or out.suffix.lower() not in (
        RAPID_SUFFIXES + KRL_SUFFIXES
    ):
        raise InputError(out, "--out", f"the corrected program is a {source.suffix} file like {source.name}")
    if args.tcp is not None:
        raise InputError(source, "--tcp", "a program's TCP is its tool: give --tool (a tooldata name, or X Y Z A B C)")
    for option, value, default in (("--length-unit", args.length_unit, "m"), ("--angle-unit", args.angle_unit, "rad"),
                                   ("--orientation", args.orientation, "rotvec"),
                                   ("--targets-frame", args.targets_frame, None)):  # fmt: skip
        if value != default:
            raise InputError(source, option, "applies to a targets CSV: a program's units and frames are its own")
    output_file(table)
    program = read_program(source)
    if args.declarations:
        program = with_declarations(program, args.declarations)
    if not program.targets:
        raise InputError(source, None, "no targets (robtarget, E6POS or POS declarations) to correct")
    line = corrected_at(program)
    if line is not None:  # its targets hold one correction already: a second would double it
        raise InputError(source, f"line {line}", "was corrected by fgcal compensate already: correct the original")
    for note in check_program(program, args.tool is not None, args.base is not None):
        warn(note)
    com = None if args.payload_com is None else payload_com(args.payload_com, 1.0, robot)
    frames = program_frames(program, args.tool, args.base, robot, args.payload_mass, com)
    poses = np.array([target.pose for target in program.targets])
    say(f"correcting {len(poses)} targets of {source.name} ({program.kind.upper()})")
    path, approach = None, f"not modelled: {robot.name}'s model ({robot.model}) has no lost motion"
    if robot.history:
        if args.approach == "none":
            approach = "lost motion not allowed for (--approach none)"
            say(f"  {approach}")
        else:
            path, assumption = program_path(program)
            approach = f"lost motion allowed for along the path: {assumption}"
            say(f"  allowing for lost motion along the path: {assumption} (--approach none: not allowed for)")
    configs = [t.config for t in program.targets]
    result = filter_targets(robot, nominal, poses, configs, program.kind, frames, path, progress=Reporter())
    if result.motion_unsolved is not None:
        unsolved_motion([t.name for t, bad in zip(program.targets, result.motion_unsolved, strict=True) if bad])
    # A target the calibration leaves where it was (below what the file's digits hold) keeps its text.
    moved = (result.correction_m > UNCHANGED_M) | (result.correction_rad > UNCHANGED_RAD)
    written = np.isin(result.status, WRITTEN) & moved
    corrected = {
        target.name: (result.poses[k], {key: v for key, v in result.configs[k].items() if key in target.config})
        for k, target in enumerate(program.targets)
        if written[k]
    }
    if frames.loads is None:
        payload = payload_text(result.payload_mass_kg, result.payload_com_m, frames.payload_source, robot.payload_mass)
    else:
        payload = mixed_payload_text(frames.loads, frames.load_sources, robot.payload_mass)
    assumptions = _assumptions(program, robot, nominal, frames, result.controller_in_W, payload, approach)
    text, shift = with_header(program, write_program(program, corrected, out), assumptions.commented(
        COMMENT[program.kind]))  # fmt: skip
    write_bytes(out, text.encode(program.encoding))
    write_csv(table, *correction_rows(program, result, written, frames, shift), assumptions.commented("#"))
    counts = {s: int(np.sum(result.status == s)) for s in sorted(set(result.status.tolist()))}
    say(f"wrote {out} and {table}: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    emit(args, {
        "out": str(out), "table": str(table), "n_targets": len(poses), "n_corrected": int(written.sum()),
        "status": counts,
        "correction_max_m": float(result.correction_m[written].max()) if written.any() else 0.0,
        "rotation_max_rad": float(result.correction_rad[written].max()) if written.any() else 0.0,
        "controller_in_W": result.controller_in_W.tolist(),
        # One load for every target; where the tools carry different ones, null and each under payloads.
        "payload_mass_kg": result.payload_mass_kg if frames.loads is None else None,
        "payload_com_m": [float(v) for v in result.payload_com_m] if frames.loads is None else None,
        "payloads": None if frames.loads is None else [
            {"source": whose, "mass_kg": float(row[0]), "com_m": [float(v) for v in row[1:]]}
            for row, whose in dict(zip(map(tuple, frames.loads), frames.load_sources, strict=True)).items()
        ],
    })  # fmt: skip
    if written.any():
        say(
            f"  corrections {result.correction_m[written].mean() * 1e3:.3f} mm mean, "
            f"{result.correction_m[written].max() * 1e3:.3f} mm max, "
            f"{np.degrees(result.correction_rad[written]).max() * 1e3:.1f} mdeg max"
        )
    say(f"  payload: {payload}")
    if not shift:
        warn(f"{source.name} has no {'MODULE' if program.kind == 'rapid' else 'DEFDAT'} line: its assumptions are "
             f"stated in {table.name} only")  # fmt: skip
    _said(result, written, moved, program.kind, table.name)
    return 0


def _assumptions(program, robot, nominal, frames, T_W_ctrl: np.ndarray, payload: str, approach: str):
    """What the corrected program and its table assumed: the work objects and the controller's base
    frame, the tools, the payload, the units, the approach (mm and deg, for people)."""
    from ..data.assumptions import Assumptions, pose_text

    def listed(names: tuple[str, ...], poses: np.ndarray) -> str:
        first: dict[str, int] = {}
        for k, name in enumerate(names):
            first.setdefault(name, k)
        return "; ".join(
            f"{name} ({count(names.count(name), 'target')}): {pose_text(poses[k])}" for name, k in first.items()
        )

    krl = program.kind == "krl"
    used = {name.lower(): name for name in (*frames.tool_names, *frames.work_object_names)}
    declared = [f"{used[name]} in {file}" for name, file in program.declared_in.items() if name in used]
    from_files = f"; declared by --declarations: {', '.join(declared)}" if declared else ""
    return Assumptions(
        what=f"corrected by fgcal compensate for a controller running the nominal model of {nominal.name} "
        f"({robot.name} as calibrated; the table beside this file lists each target)",
        frame="targets in their work objects (" + ("$BASE" if krl else "wobjdata") + f"): "
        f"{listed(frames.work_object_names, frames.work_objects)}; the controller's base frame lies in the "
        f"calibration's frame W at {pose_text(T_W_ctrl)}",
        tool=("$TOOL" if krl else "tooldata") + f": {listed(frames.tool_names, frames.tools)}{from_files}",
        payload=payload,
        units="mm, and A B C in deg (R = Rz(A) Ry(B) Rx(C))" if krl else "mm, and quaternions q1..q4 = w x y z",
        approach=approach,
    )  # fmt: skip


def _said(result, written: np.ndarray, moved: np.ndarray, kind: str, table: str) -> None:
    """What a person should know of the targets' statuses."""
    from ..data.program_filter import WRITTEN

    solved = np.isin(result.status, WRITTEN)
    if (solved & ~moved).any():
        say(f"  {count(int((solved & ~moved).sum()), 'target')} need no correction (below 0.5 um and 0.01 urad): kept")
    if not solved.any():
        warn(f"none of the {count(len(solved), 'target')} was corrected (see their status in {table}): is the "
             "calibrated robot the program's, and are its tool and work objects right?")  # fmt: skip
    elif (~solved).any():
        say(f"  {count(int((~solved).sum()), 'target')} left as they were: see their status in {table}")
    if result.in_region is not None and (solved & ~result.in_region).any():
        warn(
            f"{count(int((solved & ~result.in_region).sum()), 'target')} need joints outside the range the "
            f"calibration measured: their correction is the model's extrapolation (in_calibrated_region in {table})"
        )
    if (result.status == "configuration changed").any():
        warn("some corrected targets need another configuration (new confdata or S/T): check their path")
    rewritten = np.isin(result.status, ("turn changed", "configuration data changed"))
    if rewritten.any():
        data = "T (turn)" if kind == "krl" else "confdata"
        warn(
            f"{count(int(rewritten.sum()), 'target')} got new {data} on the same path (a joint within 0.1 deg of a "
            f"quadrant's edge or of 0 crossed it): see their status in {table}"
        )
