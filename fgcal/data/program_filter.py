"""Program filtering: a robot program's targets corrected so that a controller running its
nominal model lands where the program means (ABB RAPID, KUKA KRL; fgcal.data.programs reads and
writes them).

For each target (the TCP pose in a work object or base, in the controller's terms):

1. the flange pose the program asks for, in the controller's base frame:
   ``F = T_base_wobj X T_tcp^-1`` (the work object or $BASE, the tool or $TOOL);
2. the joints the nominal controller would take for it (``q_nominal``: its IK, from a start in
   the quadrants and signs the target's configuration names);
3. the joints at which the *calibrated* model puts the flange there (``q``: IK on the full
   model, deflection at the tool's load, from ``q_nominal``);
4. the corrected target: the nominal model's flange at ``q``, back through the tool and work
   object. The controller, running its nominal model, goes to ``q``; the real robot lands on F.

The controller's base frame in the calibrated model: the calibration's frame W is its own (the
tracker's registration, a gauge), so the base frame is placed where the nominal model best
matches the calibrated one over the calibrated region (a rigid fit of flange poses at the
calibration's fitting configurations, which calibrated_robot.yaml keeps): the calibrated model
is known there, and only there. A program thus keeps its average place; what the calibration corrects is the
rest: the robot's distortion of it.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..core.fields import is_plain_number
from ..core.se3 import inverse, kabsch, pose_from_xyz_rpy, so3_log
from ..model.ets import homogeneous
from ..model.ik import IKResult
from ..model.rigid_fit import region_sample
from ..model.robot import Robot
from ..model.wrist_ik import WristArm, branches, rotation, wrist_arm, zero_pose_axes
from .compensation import CHUNK, SEARCH_ITERATIONS, SOLVED, approach_commands, chunk_done, default_hints

QUADRANT = np.pi / 2


@dataclass(frozen=True)
class Frames:
    """The program's frames (SI): per target, the work object (or base) in the controller's
    base frame and the TCP in the flange frame, and the load the tool carries."""

    work_objects: np.ndarray  # (N, 4, 4)
    tools: np.ndarray  # (N, 4, 4)
    payload_mass_kg: float | None = None  # None: the robot file's (the calibration's payload)
    payload_com_m: np.ndarray | None = None
    payload_source: str = "the robot file's: the calibration's payload"  # whose load it is, in words
    tool_names: tuple[str, ...] = ()  # per target: a tooldata's name, tool0 or the --tool numbers
    work_object_names: tuple[str, ...] = ()  # per target: a wobjdata's name, wobj0 or the --base numbers
    # Where the targets' tools carry different loads: per target [mass kg, centre of mass m (3)]
    # and whose load it is (payload_* then unused); None: one load for every target.
    loads: np.ndarray | None = None
    load_sources: tuple[str, ...] = ()


@dataclass(frozen=True)
class Filtered:
    poses: np.ndarray  # (N, 4, 4) corrected targets, in the program's frames (m)
    q: np.ndarray  # (N, n) joints the controller goes to (rad)
    q_nominal: np.ndarray  # (N, n) joints it went to before
    configs: list  # the configuration data of q (the controller's numbers)
    correction_m: np.ndarray  # (N,) how far each target moved
    correction_rad: np.ndarray  # (N,) and turned
    residual_m: np.ndarray  # calibrated-model IK residual
    status: np.ndarray  # ok, near singularity, configuration changed or not found, unreachable, outside limits
    controller_in_W: np.ndarray  # (4, 4) the controller's base frame in the calibration's W
    in_region: np.ndarray | None  # (N,) solved, joints within the calibrated region's ranges; None: no region
    payload_mass_kg: float  # the load the deflection was computed for
    payload_com_m: np.ndarray  # (3,) its centre of mass in the flange frame
    motion_offset: np.ndarray | None = None  # (N, n) lost motion allowed for (rad or m); None: not allowed for
    motion_unsolved: np.ndarray | None = None  # (N,) the allowance could not be solved (a tiny move)


def controller_frame(robot: Robot, nominal: Robot, count: int = 2000) -> np.ndarray:
    """T_W_ctrl: the nominal model's base frame placed in the calibrated robot's W, the rigid
    motion that best maps the nominal flange onto the calibrated one (origin and points 0.1 m
    along its axes) over the calibrated region (the robot file's fitting configurations; without
    them, ``count`` seeded configurations within the joint ranges)."""
    q = region_sample(robot, count)
    offsets = np.array([[0, 0, 0, 1], [0.1, 0, 0, 1], [0, 0.1, 0, 1], [0, 0, 0.1, 1]], dtype=float)
    calibrated = np.einsum("nij,kj->nki", robot.fk(q), offsets)[..., :3].reshape(-1, 3)
    commanded = np.einsum("nij,kj->nki", nominal.fk(q), offsets)[..., :3].reshape(-1, 3)
    R, t = kabsch(commanded, calibrated)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def configurations(nominal: Robot, kind: str, q: np.ndarray) -> list[dict[str, int]]:
    """The controller's configuration data of joints ``q`` (N, n) on the nominal model.

    ABB (``rapid``): cf1, cf4, cf6 the quadrants of joints 1, 4, 6 (floor(q / 90 deg)); cfx =
    4 (wrist centre behind axis 1) + 2 (wrist centre behind the lower arm) + 1 (joint 5
    negative). KUKA (``krl``): S = 1 (wrist centre behind axis 1) + 2 (elbow on the side of
    the mastering pose, A3 = 90 deg) + 4 (A5 negative); T bit i set when joint i+1 is negative. In front and
    behind are taken against the zero pose, for a 6-axis arm; other arms get the quadrants and
    signs only."""
    n = q.shape[1]
    quadrants = np.floor(q / QUADRANT).astype(int)
    negative = q < 0
    shoulder = elbow = np.zeros(len(q), dtype=bool)
    if n == 6:
        # ABB's zero pose has the wrist in front of the lower arm. KUKA's zero pose stretches the
        # elbow (A3 = 0 is its boundary); its mastering pose, A3 = 90 deg, sets S bit 1.
        shoulder, elbow = _arm_sides(nominal, q, 0.0 if kind == "rapid" else np.pi / 2)
    wrist = negative[:, 4] if n > 4 else np.zeros(len(q), dtype=bool)
    out = []
    for row in range(len(q)):
        if kind == "rapid":
            cfx = 4 * int(shoulder[row]) + 2 * int(elbow[row]) + int(wrist[row])
            out.append({"cf1": int(quadrants[row, 0]), "cf4": int(quadrants[row, min(3, n - 1)]),
                        "cf6": int(quadrants[row, min(5, n - 1)]), "cfx": cfx})  # fmt: skip
        else:
            S = int(shoulder[row]) + 2 * int(not elbow[row]) + 4 * int(wrist[row])
            out.append({"S": S, "T": sum(1 << j for j in range(min(6, n)) if negative[row, j])})
    return out


def _arm_sides(nominal: Robot, q: np.ndarray, elbow_reference: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(behind axis 1, on the other side of the lower arm) of the wrist centre: against the zero
    pose, and for the elbow against the pose with joint 3 at ``elbow_reference`` (rad; the elbow's
    side depends on joint 3 alone)."""

    def sides(frames: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        first, second, centre = frames[0], frames[1], frames[4][:, :3, 3]
        in_first = np.einsum("nji,nj->ni", first[:, :3, :3], centre - first[:, :3, 3])
        elbow = np.einsum(
            "ni,ni->n", np.cross(second[:, :3, 3] - first[:, :3, 3], centre - second[:, :3, 3]), first[:, :3, 2]
        )
        return in_first, elbow

    frames = kinematics_frames(nominal, q)
    ahead, elbow = sides(frames)
    frames0 = kinematics_frames(nominal, np.zeros((1, nominal.n_joints)))
    ahead0, _ = sides(frames0)
    reference = np.zeros((1, nominal.n_joints))
    reference[0, 2] = elbow_reference
    _, elbow0 = sides(kinematics_frames(nominal, reference))
    axes = zero_pose_axes(nominal)
    if axes is None:  # in the plane of frame 1's x and y, on the side the zero pose reaches to
        behind = np.einsum("ni,i->n", ahead[:, :2], ahead0[0, :2]) < 0
    else:
        # The wrist centre against axis 1 itself, as the vendors define it (not against frame 1's
        # origin, which lies on axis 2: a KUKA's wrist centre between the two axes, 0.35 m apart,
        # read as behind whichever way joint 1 turned), on the side joint 1 turns the zero pose's to.
        axis, point = axes[0][0], axes[1][0]
        centre, centre0 = frames[4][:, :3, 3] - point, frames0[4][0, :3, 3] - point
        centre -= np.outer(centre @ axis, axis)
        front = rotation(axis, q[:, 0]) @ (centre0 - (centre0 @ axis) * axis)
        behind = np.einsum("ni,ni->n", centre, front) < 0
    return behind, np.sign(elbow) != np.sign(elbow0[0])


def controller_ik(
    nominal: Robot, flange: np.ndarray, kind: str, configs: list[dict[str, int]], starts: int = 64
) -> tuple[np.ndarray, np.ndarray]:
    """The nominal controller's joints for flange poses (N, 4, 4): from seeded starts, the first
    solution whose configuration data are the target's (every key given); without one, the
    solution nearest the middle of the ranges (default_hints). Returns (q, found)."""
    low, high = nominal.limits[:, 0], nominal.limits[:, 1]
    rng = np.random.default_rng(0)
    # A target with configuration data starts in its quadrants; one without, from the usual search.
    q = _starts(np.random.default_rng(1), low, high, kind, configs)
    plain = np.array([not config for config in configs])
    if plain.any():
        q[plain] = default_hints(nominal, flange[plain], np.zeros(3), frame="flange")
    found = np.zeros(len(flange), dtype=bool)
    arm = wrist_arm(nominal)
    if arm is not None and not plain.all():
        # As the controller does: its closed-form branches, the one the configuration names.
        given = np.flatnonzero(~plain)
        q[given], found[given] = _named_branch(nominal, arm, flange[given], kind, [configs[t] for t in given])
    for k in range(starts):
        todo = np.flatnonzero(~found)
        if not len(todo):
            break
        start = q[todo] if k == 0 else _starts(rng, low, high, kind, [configs[t] for t in todo])
        solved = nominal.ik(flange[todo], start, frame="flange", clamp=True)
        singular = np.flatnonzero(solved.status == "near singularity")
        if len(singular):  # free joints (a wrist's 4 and 6 at joint 5 = 0): into the configuration's quadrants
            boxes = _boxes(low, high, kind, [configs[todo[row]] for row in singular])
            solved.q[singular] = _into_box(nominal, flange[todo[singular]], solved.q[singular], *boxes)
        below = configurations(nominal, kind, solved.q - BOUNDARY_RAD)
        above = configurations(nominal, kind, solved.q + BOUNDARY_RAD)
        exact = configurations(nominal, kind, solved.q)
        for row, target in enumerate(todo):
            if solved.status[row] in SOLVED and _consistent(configs[target], exact[row], below[row], above[row]):
                q[target], found[target] = solved.q[row], True
    if kind == "krl":
        q = _least_turn(nominal, q)
    return q, found


def _named_branch(
    nominal: Robot, arm: WristArm, flange: np.ndarray, kind: str, configs: list[dict[str, int]]
) -> tuple[np.ndarray, np.ndarray]:
    """The closed-form branch (wrist_ik.branches) each flange pose's configuration names, each
    joint moved by whole turns into that configuration's quadrant or sign within the ranges,
    confirmed by the nominal IK (status, and the singular wrist's free joints into their
    quadrants). Returns (q, found) (N, n), (N,). Beyond a few hundred CPU microseconds per target
    for the branches, a random-start search took 3 ms (60 % of its starts converged elsewhere)."""
    N, n = len(flange), nominal.n_joints
    lower, upper = _boxes(nominal.limits[:, 0], nominal.limits[:, 1], kind, configs)
    candidates = branches(arm, flange)  # (N, 8, n) in (-pi, pi]
    boxed = np.full_like(candidates, np.nan)
    for turns in (0, -1, 1, -2, 2):  # the smallest turn inside the box first
        value = candidates + 2 * np.pi * turns
        inside = (value >= lower[:, None]) & (value <= upper[:, None]) & np.isnan(boxed)
        boxed[inside] = value[inside]
    usable = np.flatnonzero(np.all(np.isfinite(boxed), axis=2).ravel())
    flat = boxed.reshape(-1, n)[usable]
    exact = configurations(nominal, kind, flat)
    below = configurations(nominal, kind, flat - BOUNDARY_RAD)
    above = configurations(nominal, kind, flat + BOUNDARY_RAD)
    q, found = np.zeros((N, n)), np.zeros(N, dtype=bool)
    for row, index in enumerate(usable):
        target = index // candidates.shape[1]
        if not found[target] and _consistent(configs[target], exact[row], below[row], above[row]):
            q[target], found[target] = flat[row], True
    if found.any():
        rows = np.flatnonzero(found)
        solved = nominal.ik(flange[rows], q[rows], frame="flange", clamp=True, iterations=SEARCH_ITERATIONS)
        singular = np.flatnonzero(solved.status == "near singularity")
        if len(singular):  # at joint 5 = 0, joints 4 and 6 turn together: into their quadrants
            box = (lower[rows[singular]], upper[rows[singular]])
            solved.q[singular] = _into_box(nominal, flange[rows[singular]], solved.q[singular], *box)
        check = configurations(nominal, kind, solved.q)
        check_below = configurations(nominal, kind, solved.q - BOUNDARY_RAD)
        check_above = configurations(nominal, kind, solved.q + BOUNDARY_RAD)
        for row, target in enumerate(rows):
            keep = solved.status[row] in SOLVED and _consistent(
                configs[target], check[row], check_below[row], check_above[row]
            )
            q[target], found[target] = solved.q[row], keep
    return q, found


def _least_turn(nominal: Robot, q: np.ndarray) -> np.ndarray:
    """KRL's T gives each axis's sign, not its turn: an axis found a whole turn out (A6 at 379.6
    deg where 19.6 is the same pose, the same sign and within the range) is taken back, so that the
    corrected target keeps the turn the controller uses (found by an engineer's trial: the turn-out
    solution also read as outside the calibrated region)."""
    out = q.copy()
    revolute = ~np.asarray(nominal.prismatic, dtype=bool)
    low, high = nominal.limits[:, 0], nominal.limits[:, 1]
    for shift in (-2 * np.pi, 2 * np.pi):
        moved = out + shift * revolute
        closer = (np.abs(moved) < np.abs(out)) & (np.sign(moved) == np.sign(out))
        out = np.where(closer & (moved >= low) & (moved <= high), moved, out)
    return out


def _consistent(wanted: dict[str, int], exact: dict, below: dict, above: dict) -> bool:
    """Whether joints have the configuration ``wanted``: each number as at the joints, or, for a
    joint on a quadrant's edge (0, 90 deg...), as on either side of it (``below``/``above``: the
    data of the joints moved by BOUNDARY_RAD). The arm's sides are compared as they are."""
    for key, value in wanted.items():
        if key in ("cf1", "cf4", "cf6"):
            if value not in (exact[key], below[key], above[key]):
                return False
        elif key in ("cfx", "S"):  # the lowest bit of cfx and bit 2 of S: joint 5's sign
            bit = 1 if key == "cfx" else 4
            if (value & ~bit) != (exact[key] & ~bit) or (value & bit) not in (below[key] & bit, above[key] & bit):
                return False
        elif key == "T":
            for j in range(6):
                b = 1 << j
                if (value & b) not in (exact[key] & b, below[key] & b, above[key] & b):
                    return False
        elif value != exact.get(key):
            return False
    return True


def _into_box(
    nominal: Robot, flange: np.ndarray, q: np.ndarray, lower: np.ndarray, upper: np.ndarray, rounds: int = 3
) -> np.ndarray:
    """Joints (N, n) at a singularity moved along the Jacobian's null space (the motions that
    leave the flange where it is) toward the middle of the box [lower, upper] their
    configuration names, then put back on the flange pose. At ABB's calibration home (joint 5 at
    0) joints 4 and 6 turn together: the IK from a random start ends anywhere along that line,
    mostly outside the quadrants cf4 and cf6 name, and the target was "configuration not found"."""
    names = [f"q{i + 1}" for i in range(nominal.n_joints)]
    middle = 0.5 * (lower + upper)
    for _ in range(rounds):
        J = nominal.jacobian(q, names, frame="flange")  # (N, 6, n)
        _, sv, Vt = np.linalg.svd(J)
        rank = (np.pad(sv, ((0, 0), (0, max(0, nominal.n_joints - sv.shape[1])))) > NULL_SV).sum(axis=1)
        for row in range(len(q)):
            null = Vt[row, rank[row] :]  # (k, n): the directions of no flange motion
            q[row] += null.T @ (null @ (middle[row] - q[row]))
        refined = nominal.ik(flange, q, frame="flange")
        q = np.where(np.isin(refined.status, SOLVED)[:, None], refined.q, q)
    return q


NULL_SV = 1e-6  # a singular value of the flange Jacobian below this (m or rad per rad): a free motion


def _boxes(
    low: np.ndarray, high: np.ndarray, kind: str, configs: list[dict[str, int]]
) -> tuple[np.ndarray, np.ndarray]:
    """(N, n) lower and upper joint values within the ranges, in the quadrants and signs the
    configurations name."""
    lower = np.tile(low, (len(configs), 1))
    upper = np.tile(high, (len(configs), 1))
    for row, config in enumerate(configs):
        bounds = {}
        if kind == "rapid":
            for joint, key in ((0, "cf1"), (3, "cf4"), (5, "cf6")):
                if key in config and joint < len(low):
                    bounds[joint] = (config[key] * QUADRANT, (config[key] + 1) * QUADRANT)
            if "cfx" in config and len(low) > 4:
                bounds[4] = (-np.inf, 0.0) if config["cfx"] & 1 else (0.0, np.inf)
        elif "T" in config:
            for joint in range(min(6, len(low))):
                bounds[joint] = (-np.inf, 0.0) if config["T"] >> joint & 1 else (0.0, np.inf)
        for joint, (a, b) in bounds.items():
            lower[row, joint] = max(lower[row, joint], a)
            upper[row, joint] = max(lower[row, joint], min(upper[row, joint], b))
    return lower, upper


def _starts(rng, low: np.ndarray, high: np.ndarray, kind: str, configs: list[dict[str, int]]) -> np.ndarray:
    """Random joints within the ranges, in the quadrants and signs the configurations name."""
    return rng.uniform(*_boxes(low, high, kind, configs))


def kinematics_frames(robot: Robot, q: np.ndarray) -> list[np.ndarray]:
    """The link frames (after each joint) in W, rigid, (n) x (N, 4, 4)."""
    from ..model import kinematics

    vector, out = robot.parameter_vector(), [np.empty((len(q), 4, 4)) for _ in robot.chain.link_end]
    for start in range(0, len(q), CHUNK):  # a forward pass keeps every frame: in chunks, as Robot.fk
        rows = slice(start, start + CHUNK)
        data = kinematics.forward(robot, vector, q[rows])
        for frames, k in zip(out, robot.chain.link_end, strict=True):
            frames[rows] = homogeneous(data.frames_rigid[k])
    return out


def filter_targets(
    robot: Robot,
    nominal: Robot,
    poses: np.ndarray,
    configs: list[dict[str, int]],
    kind: str,
    frames: Frames,
    path: tuple[np.ndarray, np.ndarray] | None = None,
    progress: Callable[[str], None] | None = None,
) -> Filtered:
    """Corrected targets for a program's ``poses`` (N, 4, 4; TCP in its work object, m). With
    ``path`` (program_path: the target indices in the order the robot first goes to them, and
    the target each comes from, -1 unknown) and a robot calibrated with lost motion, each
    corrected target allows for its approach (fgcal.data.compensation.approach_commands).
    ``progress`` hears of each chunk of targets solved."""
    # The base frame is the robot's, whatever it carries: placed at the calibration's payload, so
    # that the sag of the tool's load is corrected, not absorbed into the frame.
    T_W_ctrl = controller_frame(robot, nominal)
    if frames.loads is not None:  # each target's tool's own load: solved in groups of one load
        groups, group_of = np.unique(frames.loads, axis=0, return_inverse=True)
        loaded = [robot.with_tool(robot.tool_pose, float(g[0]), g[1:]) for g in groups]
        robot = loaded[0]  # (no lost motion with mixed loads: program_frames refuses it)
    else:
        if frames.payload_mass_kg is not None:
            robot = robot.with_tool(robot.tool_pose, frames.payload_mass_kg, frames.payload_com_m)
        loaded, group_of = [robot], np.zeros(len(poses), dtype=int)
    flange = frames.work_objects @ poses @ inverse(frames.tools)  # in the controller's base frame
    # Beyond the arm's reach the controller's IK need not search (thousands of far targets would
    # take minutes); the calibrated IK then fails fast from the middle of the ranges.
    origin, reach = nominal.reach_m()
    within = np.linalg.norm(flange[:, :3, 3] - origin, axis=1) <= 1.1 * reach + 0.1
    q_nominal = np.tile(0.5 * nominal.limits.sum(axis=1), (len(poses), 1))
    found = np.zeros(len(poses), dtype=bool)
    parts, started = [], time.monotonic()
    for chunk in range(0, len(poses), CHUNK):  # as the CSV path: arrays of a few thousand rows, progress
        rows = np.arange(chunk, min(chunk + CHUNK, len(poses)))
        near = rows[within[rows]]
        if len(near):
            q_nominal[near], found[near] = controller_ik(nominal, flange[near], kind, [configs[k] for k in near])
        for group, carrying in enumerate(loaded):
            mine = rows[group_of[rows] == group]
            if len(mine):
                parts.append((mine, carrying.ik(T_W_ctrl @ flange[mine], q_nominal[mine], frame="flange")))
        chunk_done(progress, int(rows[-1]) + 1, len(poses), started)
    solved = IKResult(q_nominal.copy(), np.empty(len(poses), dtype=object), np.zeros(len(poses)), np.zeros(len(poses)))
    for mine, part in parts:
        solved.q[mine], solved.status[mine] = part.q, part.status
        solved.residual_m[mine], solved.residual_rad[mine] = part.residual_m, part.residual_rad
    solved.status = solved.status.astype(str)
    solved.status[~within] = "unreachable"
    motion_offset = motion_unsolved = None
    if path is not None and robot.history:
        # Along the path, each target allows for the approach from the one the robot comes from.
        order, came_from = path
        position = {int(k): p for p, k in enumerate(order)}
        reached = np.isin(solved.status, SOLVED)
        predecessor = np.array(
            [position[came_from[k]] if came_from[k] >= 0 and reached[came_from[k]] else -1 for k in order], dtype=int
        )
        unknown = np.full((len(order), robot.n_joints), np.nan)
        commands, offsets, allowed = approach_commands(robot, solved.q[order], unknown, predecessor=predecessor)
        motion_offset = np.zeros_like(solved.q)
        keep = reached[order]  # a target that is not reached keeps its joints (it is not written)
        solved.q[order[keep]], motion_offset[order[keep]] = commands[keep], offsets[keep]
        motion_unsolved = np.zeros(len(poses), dtype=bool)
        motion_unsolved[order[keep & ~allowed]] = True
    corrected = inverse(frames.work_objects) @ nominal.fk(solved.q) @ frames.tools
    correction_m = np.linalg.norm(corrected[:, :3, 3] - poses[:, :3, 3], axis=1)
    correction_rad = np.linalg.norm(so3_log((inverse(poses) @ corrected)[:, :3, :3]), axis=-1)
    moved = (correction_m > UNCHANGED_M) | (correction_rad > UNCHANGED_RAD)  # else the target keeps its text
    after = configurations(nominal, kind, solved.q)
    reached = np.isin(solved.status, SOLVED)
    status = solved.status.astype(object)
    status[reached & found & significant_change(nominal, q_nominal, solved.q)] = "configuration changed"
    # The same path, other configuration data (a joint that was within BOUNDARY_RAD of a quadrant's
    # edge or of 0 crossed it): written, and said, never a plain "ok".
    plain = reached & found & moved & np.isin(status, ("ok", "near singularity"))
    for k in np.flatnonzero(plain):
        changed = {key for key, value in configs[k].items() if after[k].get(key, value) != value}
        if changed:
            status[k] = "turn changed" if "T" in changed else "configuration data changed"
    status[within & ~found] = "configuration not found"  # the controller itself has no such branch
    in_region = None
    if robot.region is not None:  # each joint within the range the calibration saw (and a degree)
        low, high = robot.region.min(axis=0) - REGION_MARGIN_RAD, robot.region.max(axis=0) + REGION_MARGIN_RAD
        in_region = np.all((solved.q >= low) & (solved.q <= high), axis=1) & np.isin(status, WRITTEN)
    return Filtered(
        poses=corrected,
        q=solved.q,
        q_nominal=q_nominal,
        configs=after,
        correction_m=correction_m,
        correction_rad=correction_rad,
        residual_m=solved.residual_m,
        status=status.astype(str),
        controller_in_W=T_W_ctrl,
        in_region=in_region,
        payload_mass_kg=float(robot.payload_mass),
        payload_com_m=np.array(robot.payload_com, dtype=float),
        motion_offset=motion_offset,
        motion_unsolved=motion_unsolved,
    )


def program_path(program) -> tuple[tuple[np.ndarray, np.ndarray], str]:
    """The path the robot is assumed to take through the program's targets: their indices in the
    order it first goes to them, the target it comes from to each (-1: unknown), and the
    assumption in words. RAPID: the module's motion instructions in text order; a target is
    approached from the target of the instruction before its first (plain) use; one reached from
    an Offs/RelTool point, an inline target or nothing gets no allowance. KRL's .dat: the
    declaration order, each from the one before."""
    targets = program.targets
    if program.kind != "rapid":
        order = np.arange(len(targets))
        return (order, order - 1), "the targets in the order the .dat file declares them, each from the one before"
    unused = len(targets) + np.arange(len(targets))
    key = np.array([t.first_move if t.first_move is not None else u for t, u in zip(targets, unused, strict=True)])
    order = np.argsort(key, kind="stable")
    index = {t.name.lower(): k for k, t in enumerate(targets)}
    came_from = np.array(
        [index.get(t.approached_from, -1) if t.approached_from is not None else -1 for t in targets], dtype=int
    )
    unknown = [t.name for k, t in enumerate(targets) if t.first_move is not None and came_from[k] < 0]
    again = [t.name for t in targets if t.moves > 1]
    note = "each target approached from the one the module's motion instruction before its first use goes to"
    if unknown:
        note += f"; {len(unknown)} ({_names(unknown)}) come from an Offs/RelTool point or nothing: no allowance"
    if again:
        note += f"; {len(again)} used by several instructions ({_names(again)}) allow for their first approach only"
    return (order, came_from), note


def _names(names: list[str]) -> str:
    return ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")


REGION_MARGIN_RAD = np.radians(1.0)
UNCHANGED_M, UNCHANGED_RAD = 5e-7, 1e-8  # a correction below these is none (the files hold um and 1e-9)
BOUNDARY_RAD = np.radians(0.1)  # a joint this close to a quadrant's edge may cross it for any correction


def significant_change(nominal: Robot, before: np.ndarray, after: np.ndarray) -> np.ndarray:
    """(N,) whether the joints ``after`` take another branch than ``before``: a joint changes
    quadrant or sign from farther than BOUNDARY_RAD from the edge, or the arm's sides (wrist
    centre against axis 1 and the lower arm) change. A joint at 0 that a correction moves to
    -0.01 deg changes its configuration data, not its path: that is not significant."""
    crossed = (np.floor(before / QUADRANT) != np.floor(after / QUADRANT)) | ((before < 0) != (after < 0))
    near_edge = np.abs(before - np.round(before / QUADRANT) * QUADRANT) < BOUNDARY_RAD
    out = np.any(crossed & ~near_edge, axis=1)
    if nominal.n_joints == 6:
        sides_before, sides_after = _arm_sides(nominal, before), _arm_sides(nominal, after)
        out |= (sides_before[0] != sides_after[0]) | (sides_before[1] != sides_after[1])
    return out


# -- a program file in, a corrected program and a table out --------------------------------------

# The statuses whose targets are corrected: on the same branch (the last two with configuration
# data rewritten near a quadrant's edge: KUKA's T, else confdata or S), or on another.
WRITTEN = ("ok", "near singularity", "turn changed", "configuration data changed", "configuration changed")


def frame_from_numbers(values: list[float]) -> np.ndarray:
    """A frame given as X Y Z (mm) A B C (deg; R = Rz(A) Ry(B) Rx(C), KUKA's $TOOL and $BASE)."""
    x, y, z, a, b, c = values
    return pose_from_xyz_rpy(np.array([x, y, z]) * 1e-3, np.radians([c, b, a]))


def program_frames(
    program,
    tool: list[str] | None,
    base: list[str] | None,
    robot: Robot,
    payload_mass: float | None = None,
    payload_com: np.ndarray | None = None,
) -> Frames:
    """Each target's work object and TCP: ``tool``/``base`` from the command line (a name the
    RAPID module declares, or X Y Z A B C in mm and deg) before the module's own (the tool and
    \\WObj of the first instruction using the target), else the flange and the base frame. The
    deflection's payload is the tool's load: ``payload_mass``/``payload_com`` as given (KRL has
    no tooldata; either alone keeps the other of the load it replaces), else the tooldata's tload
    (RAPID), else the robot file's."""
    from ..core.errors import InputError

    def given(values: list[str] | None, declared: dict, what: str):
        if values is None:
            return None
        if len(values) == 6 and all(is_plain_number(v) for v in values):
            numbers = np.array([float(v) for v in values])
            if np.all(np.abs(numbers[:3]) <= MAX_FRAME_MM) and np.all(np.abs(numbers[3:]) <= 360.0):
                return frame_from_numbers(list(numbers))
            raise InputError(
                program.path, f"--{what}", f"{' '.join(values)}: X Y Z within {MAX_FRAME_MM:g} mm and A B C within "
                "360 deg",
            )  # fmt: skip
        if len(values) == 1 and _declared(values[0], declared) is not None:
            return _declared(values[0], declared)
        names = ", ".join(sorted(declared)) or "none"
        raise InputError(
            program.path, f"--{what}", f"{' '.join(values)!r}: give X Y Z A B C (mm, deg) or a {what} the module "
            f"declares ({names})",
        )  # fmt: skip

    tool_given = given(tool, program.tools, "tool")
    base_given = given(base, program.work_objects, "base")

    def resolve(target, chosen, declared: dict, neutral: str, what: str, option: str):
        """The frame (or the declared data) a target uses and its name: given, the module's, or the neutral one."""
        if isinstance(chosen, np.ndarray):
            return chosen, f"{option} {' '.join(tool if option == '--tool' else base)}"
        if chosen is None or chosen.lower() == neutral:  # KRL's TOOL_NO 0, BASE_NO 0: the flange and the base frame
            return np.eye(4), neutral if program.kind == "rapid" else {"tool0": "flange", "wobj0": "base"}[neutral]
        if _declared(chosen, declared) is not None:
            return declared[_declared(chosen, declared)], _declared(chosen, declared)
        holder = ("KUKA's $config.dat" if program.kind == "krl" else "the module that declares it (user.sys)")
        raise InputError(program.path, f"line {target.line}, {target.name}", f"{what} {chosen!r} is not declared "
                         f"in the program: give {holder} with --declarations, or {option} X Y Z A B C "
                         "(mm, deg)")  # fmt: skip

    tools, objects, tool_names, object_names = [], [], [], []
    carried: list[tuple[float, tuple[float, ...], str] | None] = []  # per target: its tool's load, None: unknown
    for target in program.targets:
        if target.fixed_tool:
            raise InputError(program.path, f"line {target.line}, {target.name}", "its FDAT's IPO_FRAME #TCP (an "
                             "external TCP: the robot moves the part) is not supported")  # fmt: skip
        used = tool_given if tool_given is not None else target.tool
        tool_data, name = resolve(target, used, program.tools, "tool0", "tool", "--tool")
        tool_names.append(name)
        load = None
        if isinstance(tool_data, np.ndarray):
            tools.append(tool_data)
        else:
            if not tool_data.robhold:
                raise InputError(program.path, f"tooldata {used}", "a stationary tool (robhold FALSE) is not supported")
            tools.append(tool_data.tcp)
            if tool_data.mass_kg > 0:  # 0 (RAPID), M -1 (KUKA's "no load data"): not known
                source = f"LOAD_DATA[{name[10:-1]}]" if name.startswith("TOOL_DATA[") else f"tooldata {name}'s tload"
                load = (tool_data.mass_kg, tuple(tool_data.cog_m), source)
        if target.tool_load is not None:  # RAPID \TLoad: the load the motion states, before the tool's
            declared_load = _declared(target.tool_load, program.loads)
            if declared_load is None:
                raise InputError(program.path, f"line {target.line}, {target.name}", f"\\TLoad {target.tool_load!r} is "
                                 "not declared: give the module that declares it with --declarations")  # fmt: skip
            mass, cog = program.loads[declared_load]
            load = (mass, tuple(cog), f"loaddata {declared_load} (\\TLoad)")
        carried.append(load)
        used = base_given if base_given is not None else target.work_object
        frame, name = resolve(target, used, program.work_objects, "wobj0", "work object", "--base")
        objects.append(frame)
        object_names.append(name)
    known = {load for load in carried if load is not None}
    mixed = len({(m, c) for m, c, _ in known}) + (None in carried and bool(known)) > 1
    loads = load_sources = None
    mass, cog = None, None
    source = Frames.payload_source + (
        "; --payload-mass and --payload-com state the tool's load" if program.kind == "krl"
        else "; a tooldata's tload, or --payload-mass and --payload-com, state the tool's load"
    )  # fmt: skip
    stated = payload_mass is not None or payload_com is not None
    if mixed and stated and (payload_mass is None or payload_com is None):
        raise InputError(program.path, "tooldata", "the targets' tools carry different loads: state both "
                         "--payload-mass and --payload-com (one load for every target), or neither (each target its "
                         "tool's)")  # fmt: skip
    if mixed and not stated:
        if robot.history:
            raise InputError(program.path, "tooldata", "the targets' tools carry different loads, and with lost motion "
                             "each target's allowance depends on the one before: state one load (--payload-mass and "
                             "--payload-com), or split the program by tool")  # fmt: skip
        own = (float(robot.payload_mass), tuple(float(v) for v in robot.payload_com), "the robot file's payload")
        rows = [load or own for load in carried]
        loads = np.array([[m, *c] for m, c, _ in rows], dtype=float)
        load_sources = tuple(whose for _, _, whose in rows)
    elif known:
        mass, cog, source = next(iter(known))
    if payload_mass is not None or payload_com is not None:  # stated: before the tooldata's
        named = [option for option, value in (("--payload-mass", payload_mass), ("--payload-com", payload_com))
                 if value is not None]  # fmt: skip
        rest = "" if len(named) == 2 else f"; the rest: {source.split(';')[0]}"
        mass = float(payload_mass) if payload_mass is not None else (robot.payload_mass if mass is None else mass)
        if payload_com is not None:
            cog = tuple(float(v) for v in payload_com)
        elif cog is None:
            cog = tuple(float(v) for v in robot.payload_com)
        source = " and ".join(named) + rest
    return Frames(
        np.array(objects).reshape(-1, 4, 4), np.array(tools).reshape(-1, 4, 4), mass,
        None if cog is None else np.array(cog), source, tuple(tool_names), tuple(object_names), loads,
        load_sources or (),
    )  # fmt: skip


MAX_FRAME_MM = 1e5  # a tool or base frame farther than 100 m is a typo


def _declared(name: str, declared: dict) -> str | None:
    """The declared name ``name`` refers to: RAPID names are not case-sensitive."""
    return next((key for key in declared if key.lower() == name.lower()), None)


CONFIG_RANGES = {"cfx": (0, 7), "S": (0, 7), "T": (0, 63), "cf1": (-8, 7), "cf4": (-8, 7), "cf6": (-8, 7)}


def check_program(program, tool_given: bool, base_given: bool) -> list[str]:
    """Refuse configuration data no controller writes; the notes a person should read about
    frames the program does not name (they default to the flange and the base frame)."""
    from ..core.errors import InputError
    from .programs import inline_targets, krl_inline_targets

    for target in program.targets:
        for key, value in target.config.items():
            low, high = CONFIG_RANGES.get(key, (-(2**31), 2**31))
            if not low <= value <= high:
                raise InputError(program.path, f"line {target.line}, {target.name}", f"{key} {value} is not "
                                 f"{low} to {high}")  # fmt: skip
    notes = []
    if program.kind == "rapid" and not tool_given:
        unused = [t.name for t in program.targets if t.tool is None]
        if unused:
            named = ", ".join(unused[:5]) + (", ..." if len(unused) > 5 else "")
            notes.append(
                f"{len(unused)} of the targets ({named}) are used by no MoveL, MoveJ or MoveC of the module: they "
                "are taken with tool0 and wobj0 (give --tool and --base)"
            )
    inline = inline_targets(program)
    if inline:
        shown = ", ".join(map(str, inline[:8])) + (", ..." if len(inline) > 8 else "")
        notes.append(
            f"{len(inline)} motions with a target written inline ([[x, y, z], ...]; lines {shown}) are not "
            "corrected: they have no name to correct them by; declare them as robtargets"
        )
    moved = [t.name for t in program.targets if t.external_axes]
    if moved:
        named = ", ".join(moved[:5]) + (", ..." if len(moved) > 5 else "")
        notes.append(f"{len(moved)} targets ({named}) give external axes' values (a track, a positioner): fgcal "
                     "models the robot alone, and corrects them as if the robot's base did not move with those "
                     "axes")  # fmt: skip
    source, lines = krl_inline_targets(program)
    if lines:
        shown = ", ".join(map(str, lines[:8])) + (", ..." if len(lines) > 8 else "")
        notes.append(f"{source.name} beside it has {len(lines)} motions with a target written inline ({{X ...}}; "
                     f"lines {shown}): they are not corrected; declare them in {program.path.name}")  # fmt: skip
    if program.kind == "krl" and not (tool_given and base_given):
        plain = [t.name for t in program.targets if (t.tool is None and not tool_given) or
                 (t.work_object is None and not base_given)]  # fmt: skip
        if plain:
            named = ", ".join(plain[:5]) + (", ..." if len(plain) > 5 else "")
            notes.append(f"{len(plain)} KRL targets ({named}) have TOOL_NO or BASE_NO 0, or no FDAT: they are "
                         "taken with $TOOL = the flange or $BASE = the robot's base frame where --tool and --base do "
                         "not give them")  # fmt: skip
    return notes


def correction_rows(
    program, result: Filtered, written: np.ndarray, frames: Frames, shift: int = 0
) -> tuple[list[str], list[list]]:
    """The table of corrections (mm, mdeg, um, deg: named in the header), with each target's line
    in the corrected program (``shift``: the lines its header added), tool and work object. A
    target that was not solved (unreachable, outside the limits, no branch of its configuration)
    has no figures."""
    n = result.q.shape[1]
    header = ["target", "line", "tool", "work_object", "status", "corrected", "in_calibrated_region", "dx_mm",
              "dy_mm", "dz_mm", "correction_mm", "rotation_mdeg", "residual_um",
              *[f"q{i}_deg" for i in range(1, n + 1)]]  # fmt: skip
    if result.motion_offset is not None:
        header += [f"lost_motion_q{i}_mdeg" for i in range(1, n + 1)]
    rows = []
    for k, target in enumerate(program.targets):
        unsolved = result.status[k] not in WRITTEN
        region = "-" if result.in_region is None or unsolved else "yes" if result.in_region[k] else "no"
        row = [target.name, target.line + shift, frames.tool_names[k], frames.work_object_names[k],
               str(result.status[k]), "yes" if written[k] else "no", region]  # fmt: skip
        if result.status[k] not in WRITTEN:
            rows.append(row + [""] * (len(header) - len(row)))
            continue
        delta = (result.poses[k, :3, 3] - target.pose[:3, 3]) * 1e3
        rows.append(
            [*row, *[round(float(v), 4) + 0.0 for v in delta], round(float(result.correction_m[k] * 1e3), 4),
             round(float(np.degrees(result.correction_rad[k]) * 1e3), 3), round(float(result.residual_m[k] * 1e6), 3),
             *[round(float(np.degrees(v)), 4) + 0.0 for v in result.q[k]],
             *([] if result.motion_offset is None
               else [round(float(np.degrees(v) * 1e3), 3) + 0.0 for v in result.motion_offset[k]])]
        )  # fmt: skip
    return header, rows
