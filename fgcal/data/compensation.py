"""Compensation: the calibrated model turned into corrected commands (the seed's fourth step).

For each target (a TCP position, optionally with an orientation, in the robot's W), the
joints at which the *calibrated* model puts the TCP on the target are found by inverse
kinematics on the full model (fgcal.model.ik). A controller that runs its *nominal* model is then
sent the Cartesian command at which its nominal model is at those joints: it moves there, and
the real robot, which the calibrated model describes, lands on the target.

A robot whose model has the motion history's terms (DH,s,e,h: lost motion, fgcal.model.motion)
lands where the joints it is commanded to are moved by how it got there. The commands then
allow for it: each target's joints are those the chain must see, minus the offsets its approach
causes, the approach being the previous target's command (the targets are a program, in its
order) or the joints given for it (``before_q1..before_qn``).

Targets file (CSV): ``target, x, y, z``, optionally an orientation, ``q1..qn`` (branch hints
such as the program's joints; without them each target starts from the nominal model's IK
within the joint limits), ``before_q1..before_qn`` (the joints a target is approached from:
empty, the previous target) and ``speed`` (each move's speed factor, 1 by default). Units and
the orientation's convention are the user's (:class:`TargetUnits`): m or mm, rad or deg, and
a rotation vector ``rx, ry, rz``, URDF ``roll, pitch, yaw`` (R = Rz(yaw) Ry(pitch) Rx(roll)),
KUKA ``a, b, c`` (R = Rz(A) Ry(B) Rx(C)) or a quaternion ``qw, qx, qy, qz``. Output CSV, in
the same units and convention, each column named with its unit where it is not SI: ``target,
q1..qn, x_cmd, y_cmd, z_cmd[, orientation], residual_m[, residual_rad], status`` (SI), or e.g.
``q1_deg, x_cmd_mm, a_cmd_deg, residual_um, residual_mdeg`` (mm and deg); with the approach
allowed for, the expected lost motion per joint too (``lost_motion_q1..``, rad or mdeg).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.console import step
from ..core.errors import InputError
from ..core.fields import check_name, first_repeat
from ..core.se3 import pose, pose_from_xyz_rpy, rpy_from_rotation, so3_exp, so3_log
from ..model import kinematics
from ..model.ik import TOL_M, TOL_RAD
from ..model.motion import MotionHistory, features
from ..model.robot import SAME_ROBOT_M, Robot
from ..model.robot_io import bundled_robots, load_robot
from .dataset import (
    QUATERNION_TOLERANCE,
    approach_columns,
    line_numbers,
    numbered,
    parse_numbers,
    read_csv,
    speed_column,
    write_csv,
)

ORIENTATIONS = {
    "rotvec": ("rx", "ry", "rz"),
    "rpy": ("roll", "pitch", "yaw"),
    "abc": ("a", "b", "c"),
    "quaternion": ("qw", "qx", "qy", "qz"),
}


@dataclass(frozen=True)
class TargetUnits:
    """Units and orientation convention of a targets file and its output (default SI, rotation vector)."""

    length: str = "m"  # m or mm
    angle: str = "rad"  # rad or deg
    orientation: str = "rotvec"  # a key of ORIENTATIONS

    @property
    def to_m(self) -> float:
        return 1e-3 if self.length == "mm" else 1.0

    @property
    def to_rad(self) -> float:
        return float(np.pi / 180) if self.angle == "deg" else 1.0

    @property
    def si(self) -> bool:
        return self.length == "m" and self.angle == "rad"

    def rotations(self, values: np.ndarray) -> np.ndarray:
        """(N, 3, 3) from the orientation columns' values (file units)."""
        if self.orientation == "quaternion":
            from scipy.spatial.transform import Rotation

            w, x, y, z = values.T
            return Rotation.from_quat(np.column_stack([x, y, z, w])).as_matrix()
        angles = values * self.to_rad
        if self.orientation == "rotvec":
            return so3_exp(angles)
        if self.orientation == "abc":  # A about z, B about y, C about x: the same matrix as yaw, pitch, roll
            angles = angles[:, ::-1]
        return np.array([pose_from_xyz_rpy(np.zeros(3), rpy)[:3, :3] for rpy in angles])

    def orientation_values(self, R: np.ndarray) -> list[float]:
        """The orientation columns' values (file units) of a rotation."""
        if self.orientation == "quaternion":
            from scipy.spatial.transform import Rotation

            x, y, z, w = Rotation.from_matrix(R).as_quat()
            return [w, x, y, z] if w >= 0 else [-w, -x, -y, -z]
        if self.orientation == "rotvec":
            return [float(v) / self.to_rad for v in so3_log(R)]
        roll, pitch, yaw = rpy_from_rotation(R)
        ordered = (roll, pitch, yaw) if self.orientation == "rpy" else (yaw, pitch, roll)
        return [float(v) / self.to_rad for v in ordered]

    def column(self, name: str, kind: str) -> str:
        """An output column's name with its unit where it is not SI (kind: length, angle or none)."""
        if self.si or kind == "none":
            return name
        return f"{name}_{self.length if kind == 'length' else self.angle}"


@dataclass
class Targets:
    names: list[str]
    positions: np.ndarray  # (N, 3) m
    rotations: np.ndarray | None  # (N, 3, 3), when the file gives rx, ry, rz
    hints: np.ndarray | None  # (N, n) rad
    approach: np.ndarray | None = None  # (N, n) joints each target is approached from; NaN rows: the previous
    speed: np.ndarray | None = None  # (N,) speed factors of the moves

    def as_ik_targets(self) -> np.ndarray:
        if self.rotations is None:
            return self.positions
        return np.array([pose(R, p) for R, p in zip(self.rotations, self.positions, strict=True)])


def read_targets(
    path: str | Path, n_joints: int, units: TargetUnits | None = None, prismatic: np.ndarray | None = None
) -> Targets:
    """The targets of a CSV in ``units`` (SI rotation vectors by default); ``prismatic`` marks
    the joints whose hints are lengths."""
    units = units or TargetUnits()
    joint_scale = np.where(np.zeros(n_joints, bool) if prismatic is None else prismatic, units.to_m, units.to_rad)
    path = Path(path)
    if not path.exists():
        raise InputError(path, None, "file not found")
    header, body = read_csv(path, ["target", "x", "y", "z"])
    repeated = first_repeat(enumerate(header, start=1))
    if repeated is not None:
        raise InputError(
            path, "header", f"column {repeated[2]!r} given twice (columns {repeated[0]} and {repeated[1]})"
        )
    if not body:
        raise InputError(path, None, "no targets")
    positions = parse_numbers(path, header, body, ["x", "y", "z"], "length", units.to_m)
    rotations = None
    for convention, columns in ORIENTATIONS.items():
        present = [c for c in columns if c in header]
        if present and convention != units.orientation:
            raise InputError(
                path, "header", f"columns {', '.join(present)} are the {convention} orientation: give --orientation "
                f"{convention} (the targets are read as {units.orientation})",
            )  # fmt: skip
        if present and len(present) != len(columns):
            together = f"{', '.join(columns[:-1])} and {columns[-1]}"
            raise InputError(path, "header", f"{together} come together (the {convention} orientation)")
        if present:
            values = parse_numbers(path, header, body, list(columns), "angle", 1.0)  # bounds: quaternions too
            if convention == "quaternion":
                norms = np.linalg.norm(values, axis=1)
                bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_TOLERANCE)
                if len(bad):
                    line = line_numbers(body)[bad[0]]
                    raise InputError(path, f"line {line}", f"a quaternion of norm {norms[bad[0]]:.6g}, not 1")
            rotations = units.rotations(values)
    joint_columns = [c for c in header if c.startswith("q") and c[1:].isdigit()]
    hints = None
    if joint_columns:
        expected = [f"q{i}" for i in range(1, n_joints + 1)]
        if joint_columns != expected:
            raise InputError(
                path, "header", f"hints need columns {', '.join(expected)}, got {', '.join(joint_columns)}"
            )
        linear = np.zeros(n_joints, bool) if prismatic is None else np.asarray(prismatic, bool)
        hints = np.column_stack(
            [  # each joint in its unit, checked in SI
                parse_numbers(path, header, body, [column], "length" if linear[j] else "angle", joint_scale[j])[:, 0]
                for j, column in enumerate(expected)
            ]
        )
    names = [
        check_name(row[header.index("target")].strip(), path, f"line {line}, column target")
        for line, row in numbered(body)
    ]
    empty = next((line for line, name in zip(line_numbers(body), names, strict=True) if not name), None)
    if empty is not None:
        raise InputError(path, f"line {empty}, column target", "an empty target name")
    repeat = first_repeat(zip(line_numbers(body), names, strict=True))
    if repeat is not None:
        raise InputError(path, f"lines {repeat[0]} and {repeat[1]}", f"target {repeat[2]!r} given twice")
    approach = approach_columns(path, header, body, n_joints, units.to_rad, prismatic, units.to_m)
    _no_other_columns(path, header, n_joints)
    return Targets(names, positions, rotations, hints, approach, speed_column(path, header, body))


def _no_other_columns(path: Path, header: list[str], n_joints: int) -> None:
    """A column fgcal does not read is refused, naming it: KUKA's A, B, C (upper case) or hints
    named j1..j6 were ignored without a word, and the targets solved for their positions only."""
    known = {"target", "x", "y", "z", "speed", *(c for columns in ORIENTATIONS.values() for c in columns)}
    known |= {f"{prefix}{i}" for prefix in ("q", "before_q") for i in range(1, n_joints + 1)}
    for column in header:
        if column in known:
            continue
        near = next((k for k in sorted(known) if k.lower() == column.strip().lower()), None)
        hint = f" (column names are lower case: {near!r})" if near else (
            f" (fgcal reads target, x, y, z, an orientation's columns, q1..q{n_joints}, before_q1..before_q{n_joints}"
            " and speed)"
        )  # fmt: skip
        raise InputError(path, "header", f"column {column!r} is not one fgcal reads{hint}")


def nominal_of(robot: Robot, nominal: str | Path | None) -> Robot:
    """The controller's nominal model: ``nominal`` if given, else the bundled robot of the
    same name (with the calibrated robot's tool and payload)."""
    if nominal is not None:
        given = load_robot(nominal)
        gap = robot.flange_gap_m(given)
        if gap > SAME_ROBOT_M:
            raise InputError(
                None, "--nominal", f"{nominal} is not a nominal model of {robot.name}: "
                + (f"their flanges are up to {gap * 1e3:.0f} mm apart" if np.isfinite(gap)
                   else f"it has {given.n_joints} joints, the robot {robot.n_joints}"),
            )  # fmt: skip
        return given
    for name in bundled_robots():
        candidate = load_robot(name)
        if candidate.name == robot.name:
            return candidate.with_tool(robot.tool_pose, robot.payload_mass, robot.payload_com)
    raise InputError(None, "--nominal", f"no bundled robot is named {robot.name!r}: give the nominal model")


@dataclass
class Compensation:
    q: np.ndarray  # (N, n) joints to command: the calibrated model reaches each target from them
    commands: np.ndarray  # (N, 4, 4) nominal-model TCP pose at those joints
    residual_m: np.ndarray
    residual_rad: np.ndarray | None
    status: np.ndarray
    # (N, n) the joint offsets the approach is expected to cause, which the commands allow for
    # (rad or m; None: not allowed for)
    motion_offset: np.ndarray | None = None
    # (N,) whether each target's allowance was solved (a move of a fraction of a degree may not
    # be: its command is then the chain's joints; fgcal.data.compensation.approach_commands)
    motion_solved: np.ndarray | None = None


def approach_commands(
    robot: Robot,
    q_chain: np.ndarray,
    approach: np.ndarray,
    speed: np.ndarray | None = None,
    predecessor: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Commands (N, n) under which the robot's chain sees ``q_chain`` when each is approached
    from ``approach`` (N, n; a NaN row: the previous command, none for the first; with
    ``predecessor``, the command of that earlier row, none for -1), the offsets (N, n) the
    approaches cause, and (N,) whether each was solved.

    Row after row (each row's approach is the command before it, once final), Newton's method
    on ``q_cmd + offsets(q_cmd - before) = q_chain`` with a line search. The speed term changes
    by lv / |move| per radian of a move: for moves of a fraction of a degree the model asks for
    a step it cannot give (it has the full speed offset at any move), and such a row is left
    unsolved: its command is the chain's joints, without an allowance."""
    params = robot.parameter_vector()
    n_rows, n = q_chain.shape
    speed = np.ones(n_rows) if speed is None else np.asarray(speed, dtype=float)
    given = np.all(np.isfinite(approach), axis=1)
    q_cmd, offsets, solved = q_chain.copy(), np.zeros_like(q_chain), np.ones(n_rows, dtype=bool)
    step = 1e-7 * np.eye(n)

    def residual_and_offsets(q: np.ndarray, before: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """F(q) = q + offsets(q) - q_chain[k] at q (m, n) rows, and the offsets."""
        history = MotionHistory(np.tile(before, (len(q), 1)), np.full(len(q), speed[k]))
        off = kinematics.motion_offsets(robot, params, features(q, history))
        return q + off - q_chain[k], off

    for k in range(n_rows):
        came_from = (k - 1) if predecessor is None else int(predecessor[k])
        if not came_from < k:
            raise ValueError(f"row {k} is approached from row {came_from}, which is not before it")
        before = approach[k] if given[k] else (q_cmd[came_from] if came_from >= 0 else np.full(n, np.nan))
        if not np.all(np.isfinite(before)):  # unknown: nothing to allow for
            continue
        q = q_chain[k].copy()
        F, off = residual_and_offsets(q[None], before, k)
        F, off = F[0], off[0]
        for _ in range(NEWTON_ITERATIONS):
            size = float(np.abs(F).max())
            if size < 1e-13:
                break
            probes, _ = residual_and_offsets(q + step, before, k)
            J = (probes - F).T / 1e-7  # (n, n): column j, the change of F with q_j
            try:
                direction = -np.linalg.solve(J, F)
            except np.linalg.LinAlgError:
                break
            for scale in (1.0, 0.5, 0.25, 0.125, 0.0625):  # the largest step that shrinks F
                trial, trial_off = residual_and_offsets((q + scale * direction)[None], before, k)
                if np.abs(trial[0]).max() < size:
                    q, F, off = q + scale * direction, trial[0], trial_off[0]
                    break
            else:
                break
        # Where the largest move changes joints (equal moves), the speed share has a kink that
        # Newton's method stalls on: damped fixed-point steps q <- q - a F(q) get through it.
        for damping in (0.5, 0.25):
            if float(np.abs(F).max()) < 1e-13:
                break
            for _ in range(DAMPED_ITERATIONS):
                trial, trial_off = residual_and_offsets((q - damping * F)[None], before, k)
                q, F, off = q - damping * F, trial[0], trial_off[0]
                if float(np.abs(F).max()) < 1e-13:
                    break
        if float(np.abs(F).max()) < 1e-12:
            q_cmd[k], offsets[k] = q, off
        else:
            solved[k] = False
    return q_cmd, offsets, solved


NEWTON_ITERATIONS = 30
DAMPED_ITERATIONS = 200


def compensate(
    robot: Robot,
    nominal: Robot,
    targets: np.ndarray,
    hints: np.ndarray | None,
    tcp: np.ndarray | None = None,
    frame: str = "tool",
    tol_m: float = TOL_M,
    tol_rad: float = TOL_RAD,
    progress: Callable[[str], None] | None = None,
    approach: np.ndarray | None = None,
    speed: np.ndarray | None = None,
) -> Compensation:
    """Joints on the calibrated ``robot`` for ``targets`` (N, 3) or (N, 4, 4), and the
    commands (the ``nominal`` model's TCP pose there); the TCP ``tcp`` is fixed in ``frame``
    (tool, flange, or a tree's tip by name). A target counts as reached within ``tol_m`` (m) and ``tol_rad``. Without
    hints each target starts from default_hints. ``progress`` hears of each chunk solved.
    ``approach`` (N, n): the joints each target is approached from (NaN rows: the previous
    target's command), allowed for when the robot's model has the motion history's terms;
    None: not allowed for (the commands are the joints the chain must see)."""
    tcp = np.zeros(3) if tcp is None else np.asarray(tcp, dtype=float)
    parts = []
    started = time.monotonic()
    for chunk in range(0, len(targets), CHUNK):  # arrays of a few thousand rows stay in the cache
        rows = slice(chunk, chunk + CHUNK)
        start = default_hints(nominal, targets[rows], tcp, frame=frame) if hints is None else hints[rows]
        parts.append(robot.ik(targets[rows], start, tcp=tcp, frame=frame, tol_m=tol_m, tol_rad=tol_rad))
        chunk_done(progress, min(chunk + CHUNK, len(targets)), len(targets), started)
    q = np.concatenate([p.q for p in parts])
    motion_offset = motion_solved = None
    if approach is not None and robot.history:
        q, motion_offset, motion_solved = approach_commands(robot, q, np.asarray(approach, dtype=float), speed)
    commands = nominal.fk(q, tip=None if frame == "flange" else frame).copy()  # (N, 4, 4)
    commands[:, :3, 3] += commands[:, :3, :3] @ tcp
    residual_rad = None if parts[0].residual_rad is None else np.concatenate([p.residual_rad for p in parts])
    return Compensation(
        q, commands, np.concatenate([p.residual_m for p in parts]), residual_rad,
        np.concatenate([p.status for p in parts]), motion_offset, motion_solved,
    )  # fmt: skip


CHUNK = 2000  # targets solved together


def chunk_done(progress: Callable[[str], None] | None, done: int, total: int, started: float) -> None:
    """Tell ``progress`` that ``done`` of ``total`` targets are solved (a bar on a terminal, a
    line with the time left between chunks); ``started``: time.monotonic() at the first."""
    step(progress, "compensating: targets", done, total)
    if progress is not None and done < total:
        elapsed = time.monotonic() - started
        left = elapsed / done * (total - done)
        progress(f"  {done} of {total} targets solved ({elapsed:.0f} s, about {left:.0f} s left)")


SOLVED = ("ok", "near singularity")
SEARCH_ITERATIONS = 40  # per start of the hint search: from the middle of the ranges 89 % converge in 20, 90 % in 40


def default_hints(
    nominal: Robot, targets: np.ndarray, tcp: np.ndarray, starts: int = 24, frame: str = "tool", first: int = 4
) -> np.ndarray:
    """Without a program's joints: the nominal model's IK from the middle of the joint ranges
    and from seeded random starts, each step kept within the limits. Of the solutions, the
    one nearest the middle of the ranges (in fractions of each range) is kept: ``first``
    starts for every target, then further ones, up to ``starts``, for targets still without
    one (those keep the middle of the ranges: the calibrated model's IK then says why)."""
    low, high = nominal.limits[:, 0], nominal.limits[:, 1]
    middle = 0.5 * (low + high)
    span = np.maximum(high - low, 1e-9)
    rng = np.random.default_rng(0)
    hints = np.tile(middle, (len(targets), 1))
    distance = np.full(len(targets), np.inf)
    for k in range(starts):
        todo = np.arange(len(targets)) if k < first else np.flatnonzero(~np.isfinite(distance))
        if not len(todo):
            break
        start = hints[todo] if k == 0 else rng.uniform(low, high, (len(todo), len(low)))
        solved = nominal.ik(targets[todo], start, tcp=tcp, frame=frame, clamp=True, iterations=SEARCH_ITERATIONS)
        far = np.linalg.norm((solved.q - middle) / span, axis=1)
        better = np.isin(solved.status, SOLVED) & (far < distance[todo])
        hints[todo[better]] = solved.q[better]
        distance[todo[better]] = far[better]
    return hints


def write_compensation(
    path: str | Path,
    names: list[str],
    result: Compensation,
    with_rotation: bool,
    units: TargetUnits | None = None,
    prismatic: np.ndarray | None = None,
    comments: list[str] | None = None,
) -> None:
    """The output CSV in the targets' units and orientation convention (columns named with
    their units where not SI), after ``comments`` (# lines: what it assumed)."""
    units = units or TargetUnits()
    n = result.q.shape[1]
    prismatic = np.zeros(n, bool) if prismatic is None else np.asarray(prismatic, bool)
    joint_scale = np.where(prismatic, units.to_m, units.to_rad)
    header = ["target", *[units.column(f"q{i}", "length" if prismatic[i - 1] else "angle") for i in range(1, n + 1)]]
    header += [units.column(f"{axis}_cmd", "length") for axis in "xyz"]
    if with_rotation:
        kind = "none" if units.orientation == "quaternion" else "angle"
        header += [units.column(f"{c}_cmd", kind) for c in ORIENTATIONS[units.orientation]]
    if units.si:
        header += ["residual_m"] + (["residual_rad"] if with_rotation else [])
    else:
        header += ["residual_um"] + ([f"residual_m{units.angle}"] if with_rotation else [])
    # The expected lost motion the commands allow for: rad and m, or mdeg and um.
    motion_scale = np.ones(n) if units.si else np.where(prismatic, 1e6, 1e3 / units.to_rad)
    if result.motion_offset is not None:
        suffixes = ["" if units.si else ("_um" if prismatic[i] else f"_m{units.angle}") for i in range(n)]
        header += [f"lost_motion_q{i + 1}{suffix}" for i, suffix in enumerate(suffixes)]
    header.append("status")
    rows = []
    for i, name in enumerate(names):
        # A target that was not compensated (unreachable, outside the joint limits) has no joints
        # and no command to send: its cells are empty, its residual says how far it stays.
        solved = result.status[i] in SOLVED
        row = [name, *((float(v) for v in result.q[i] / joint_scale) if solved else [""] * n)]
        row += [float(v) / units.to_m for v in result.commands[i, :3, 3]] if solved else ["", "", ""]
        if with_rotation:
            width = len(ORIENTATIONS[units.orientation])
            row += units.orientation_values(result.commands[i, :3, :3]) if solved else [""] * width
        row.append(float(result.residual_m[i]) * (1.0 if units.si else 1e6))
        if with_rotation:
            row.append(float(result.residual_rad[i]) * (1.0 if units.si else 1e3 / units.to_rad))
        if result.motion_offset is not None:
            row += [float(v) for v in result.motion_offset[i] * motion_scale] if solved else [""] * n
        row.append(str(result.status[i]))
        rows.append(row)
    write_csv(Path(path), header, rows, comments or [])
