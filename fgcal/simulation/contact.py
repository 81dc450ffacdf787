"""A robot measuring itself by contact: balls on the tips of a tree touch each other and planes
of the cell (a table, a wall).

The truth: the balls' centres off the drawing's (``centre_error``), the planes tilted and moved
off their nominal (``plane_angle_error``, ``plane_offset_error``); the radii are the drawing's
(gauge balls). Each contact starts from a random configuration; the true robot then moves the
joints that carry only the touching ball (an arm's, the torso held) by inverse kinematics on
its position until the ball touches: self-contacts meet halfway between where the two balls
were, a plane contact where the ball was, dropped onto the plane. Where a contact closes is
off exact touching by the contact noise (``contact_sigma``: the compliance of the touch, the
robot's repeatability). A start that does not converge within the joint limits is drawn again.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.se3 import so3_exp, transform_points
from ..data.dataset import write_csv
from ..model import kinematics
from ..model.ik import wrap_into_limits
from ..model.robot import Robot
from .cell import Cell

ATTEMPTS = 20  # random starts per contact before the cell is declared out of reach
MIDDLE = 0.7  # random starts within this central fraction of each joint's range
MAX_DROP_M = 0.3  # a plane contact starts from a ball at most this far above the plane


@dataclass(frozen=True)
class ContactTruth:
    centres: np.ndarray  # (k, 3) on their tips
    radii: np.ndarray  # (k,)
    normals: np.ndarray  # (p, 3) unit, in W
    offsets: np.ndarray  # (p,)

    def elements(self, cell: Cell) -> dict[str, tuple[np.ndarray, float]]:
        return {n: (c, float(r)) for n, c, r in zip(cell.contact.names, self.centres, self.radii, strict=True)}

    def planes(self, cell: Cell) -> dict[str, tuple[np.ndarray, float]]:
        return {n: (v, float(d)) for n, v, d in zip(cell.contact.plane_names, self.normals, self.offsets, strict=True)}


@dataclass(frozen=True)
class ContactDesign:
    q: np.ndarray  # (N, n)
    self_rows: list[tuple[int, str, str]]  # (configuration, element a, element b)
    plane_rows: list[tuple[int, str, str]]  # (configuration, element, plane)
    self_noise: np.ndarray  # (S,) m: the gap each self-contact closes at
    plane_noise: np.ndarray  # (P,)
    gauge_rows: list[tuple[int, str, str]]  # (configuration, element a, element b)
    gauge_true: np.ndarray  # (G,) m: the true distance of the balls' centres
    gauge_noise: np.ndarray  # (G,) m: the reading's error


def contact_truth(cell: Cell, rng: np.random.Generator) -> ContactTruth:
    setup = cell.contact
    centres = setup.centres + rng.uniform(-setup.centre_error_m, setup.centre_error_m, setup.centres.shape)
    normals = []
    for normal in setup.normals:
        axis = np.cross(normal, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        normals.append(so3_exp(axis * rng.uniform(0.0, setup.plane_angle_error_rad)) @ normal)
    offsets = setup.offsets + rng.uniform(-setup.plane_offset_error_m, setup.plane_offset_error_m, len(setup.offsets))
    return ContactTruth(centres, setup.radii.copy(), np.array(normals).reshape(-1, 3), offsets)


def own_joints(robot: Robot, tips: tuple[str, ...], tip: str) -> np.ndarray:
    """The joints that move ``tip`` and no other of ``tips`` (an arm's, not the torso's)."""
    mine = kinematics.path_joints(robot, tip).copy()
    for other in set(tips) - {tip}:
        mine &= ~kinematics.path_joints(robot, other)
    if not mine.any():
        raise InputError(None, "contact.elements", f"every joint that moves tip {tip!r} moves another ball's tip too")
    return np.flatnonzero(mine)


def reach(
    robot: Robot, params: np.ndarray, q0: np.ndarray, tip: str, point: np.ndarray, targets: np.ndarray,
    joints: np.ndarray, iterations: int = 60, tol: float = 1e-10,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Joint angles (N, n) that put ``point`` (on ``tip``) at ``targets`` (N, 3) moving only
    ``joints`` from ``q0`` (damped least squares), and whether each converged within the limits."""
    names = [f"q{j + 1}" for j in joints]
    q = q0.copy()
    active = np.arange(len(q))
    for _ in range(iterations):
        data = kinematics.forward(robot, params, q[active])
        error = targets[active] - transform_points(kinematics.frame_pose(robot, data, tip), point)
        moving = np.linalg.norm(error, axis=1) >= tol  # the converged rows stop
        if not moving.any():
            break
        J = kinematics.jacobian(robot, data, names, frame=tip, point=point)[moving]  # (N, 3, m)
        active, error = active[moving], error[moving]
        JJt = J @ np.swapaxes(J, 1, 2) + 1e-6 * np.eye(3)
        step = (np.swapaxes(J, 1, 2) @ np.linalg.solve(JJt, error[..., None]))[..., 0]
        norm = np.linalg.norm(step, axis=1, keepdims=True)
        q[np.ix_(active, joints)] += step * np.minimum(1.0, 0.3 / np.maximum(norm, 1e-12))
    p = transform_points(kinematics.frame_pose(robot, kinematics.forward(robot, params, q), tip), point)
    wrapped = wrap_into_limits(robot.limits, q, robot.prismatic)
    within = np.all((wrapped >= robot.limits[:, 0]) & (wrapped <= robot.limits[:, 1]), axis=1)
    return wrapped, within & (np.linalg.norm(targets - p, axis=1) < 1e-8)


def _starts(cell: Cell, count: int, rng: np.random.Generator) -> np.ndarray:
    """Random configurations in the middle of the joints' ranges, the held joints where held."""
    robot = cell.robot
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    centre, half = (low + high) / 2, MIDDLE * (high - low) / 2
    q = rng.uniform(centre - half, centre + half, (count, robot.n_joints))
    q[:, list(cell.contact.held)] = cell.contact.held_at
    return q


def _ball(robot: Robot, params: np.ndarray, q: np.ndarray, tip: str, centre: np.ndarray) -> np.ndarray:
    return transform_points(kinematics.frame_pose(robot, kinematics.forward(robot, params, q), tip), centre)


def contact_design(
    cell: Cell,
    true_params: np.ndarray,
    truth: ContactTruth,
    design_rng: np.random.Generator,
    noise_rng: np.random.Generator,
    say: Callable[[str], None],
) -> ContactDesign:
    """The contact configurations on the true robot: the self-contacts of the first two balls,
    then each ball's contacts with each plane, shuffled together."""
    robot, setup = cell.robot, cell.contact
    tips = setup.tips
    q_all, self_rows, plane_rows, self_noise, plane_noise = [], [], [], [], []

    def solve(count: int, targets_of: Callable, moves: list[tuple[str, int]], what: str) -> list[np.ndarray]:
        """``count`` configurations: each start's targets for the balls ``moves`` (tip, ball) and
        whether the start may make the contact at all."""
        found: list[np.ndarray] = []
        for _ in range(ATTEMPTS):
            missing = count - len(found)
            if missing <= 0:
                break
            q = _starts(cell, 4 * missing + 16, design_rng)
            targets, ok = targets_of(q)
            # Moving one arm bends the torso under the arm's weight, which moves the other ball
            # a little: the arms take turns until both stay (compliant robots).
            for _ in range(3 if len(moves) > 1 else 1):
                reached = np.ones(len(q), dtype=bool)
                for (tip, k), target in zip(moves, targets, strict=True):
                    joints = np.setdiff1d(own_joints(robot, tips, tip), setup.held)
                    q, converged = reach(robot, true_params, q, tip, truth.centres[k], target, joints)
                    reached &= converged
            ok &= reached
            found += list(q[ok][:missing])
        if len(found) < count:
            raise InputError(
                cell.source, "contact", f"{what}: out of the robot's reach ({len(found)} of {count} found)"
            )
        return found

    def between(count: int, distance: Callable[[int], np.ndarray], what: str) -> list[np.ndarray]:
        """``count`` configurations of the first two balls' centres ``distance(n)`` apart."""
        a, b = 0, 1

        def meet(q: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
            p_a = _ball(robot, true_params, q, tips[a], truth.centres[a])
            p_b = _ball(robot, true_params, q, tips[b], truth.centres[b])
            u = p_b - p_a
            u /= np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
            middle, half = (p_a + p_b) / 2, distance(len(q))[:, None] / 2
            return [middle - half * u, middle + half * u], np.ones(len(q), dtype=bool)

        return solve(count, meet, [(tips[a], a), (tips[b], b)], what)

    def centres_apart(q: np.ndarray) -> float:
        p_a = _ball(robot, true_params, q[None], tips[0], truth.centres[0])[0]
        p_b = _ball(robot, true_params, q[None], tips[1], truth.centres[1])[0]
        return float(np.linalg.norm(p_a - p_b))

    if setup.self_contacts:
        touching = truth.radii[0] + truth.radii[1]
        count = setup.self_contacts
        gaps = noise_rng.normal(0.0, cell.contact_sigma_m, count)
        for q in between(count, lambda n: touching + np.resize(gaps, n), "self-contacts"):
            # The gap each configuration found closes at, measured on the true robot.
            self_noise.append(centres_apart(q) - touching)
            self_rows.append((len(q_all), setup.names[0], setup.names[1]))
            q_all.append(q)
        say(f"  {count} self-contacts of {setup.names[0]} and {setup.names[1]}")
    gauge_rows, gauge_true = [], []
    if setup.gauge_readings:
        count, length, travel = setup.gauge_readings, setup.gauge_length_m, setup.gauge_travel_m
        for q in between(count, lambda n: length + design_rng.uniform(-travel / 2, travel / 2, n), "gauge readings"):
            gauge_true.append(centres_apart(q))
            gauge_rows.append((len(q_all), setup.names[0], setup.names[1]))
            q_all.append(q)
        say(f"  {count} gauge readings between {setup.names[0]} and {setup.names[1]}")
    for k, (tip, name) in enumerate(zip(tips, setup.names, strict=True)):
        for p, plane in enumerate(setup.plane_names):
            normal, offset = truth.normals[p], truth.offsets[p]
            count = setup.plane_contacts
            if not count:
                continue
            gaps = noise_rng.normal(0.0, cell.contact_sigma_m, 4 * count)

            def drop(q: np.ndarray, normal=normal, offset=offset, k=k, gaps=gaps, tip=tip) -> list[np.ndarray]:
                ball = _ball(robot, true_params, q, tip, truth.centres[k])
                height = ball @ normal - offset - truth.radii[k] - np.resize(gaps, len(q))
                # From the side the normal points to, and not from across the cell.
                return [ball - height[:, None] * normal], (height > 0) & (height < MAX_DROP_M)

            for q in solve(count, drop, [(tip, k)], f"ball {name!r} on plane {plane!r}"):
                ball = _ball(robot, true_params, q[None], tip, truth.centres[k])[0]
                plane_noise.append(ball @ normal - offset - truth.radii[k])
                plane_rows.append((len(q_all), name, plane))
                q_all.append(q)
            say(f"  {count} contacts of {name} with {plane}")
    if not q_all:
        raise InputError(cell.source, "contact", "no contact to simulate: self_contacts and plane_contacts are 0")
    order = design_rng.permutation(len(q_all))
    position = np.empty(len(order), dtype=int)
    position[order] = np.arange(len(order))
    return ContactDesign(
        np.array(q_all)[order],
        [(int(position[j]), a, b) for j, a, b in self_rows],
        [(int(position[j]), e, p) for j, e, p in plane_rows],
        np.array(self_noise),
        np.array(plane_noise),
        [(int(position[j]), a, b) for j, a, b in gauge_rows],
        np.array(gauge_true),
        noise_rng.normal(0.0, cell.distance_sigma_m, len(gauge_rows)),
    )


def write_contact_tables(out: Path, design: ContactDesign, config_ids: list[str]) -> dict[str, int]:
    """contacts.csv and plane_contacts.csv (in configuration order), the gaps in truth/."""
    counts = {}
    for name, rows, noise, columns in (
        ("contacts", design.self_rows, design.self_noise, ["config", "element_a", "element_b"]),
        ("plane_contacts", design.plane_rows, design.plane_noise, ["config", "element", "plane"]),
    ):
        if not rows:
            continue
        order = np.argsort([j for j, _, _ in rows], kind="stable")
        write_csv(out / f"{name}.csv", columns, [[config_ids[rows[i][0]], rows[i][1], rows[i][2]] for i in order])
        write_csv(out / "truth" / f"{name}_gap.csv", [*columns, "gap"],
                  [[config_ids[rows[i][0]], rows[i][1], rows[i][2], float(noise[i])] for i in order])  # fmt: skip
        counts[name] = len(rows)
    if design.gauge_rows:
        rows, readings = design.gauge_rows, design.gauge_true + design.gauge_noise
        order = np.argsort([j for j, _, _ in rows], kind="stable")
        columns = ["config", "element_a", "element_b", "distance"]
        write_csv(
            out / "tip_distances.csv",
            columns,
            [[config_ids[rows[i][0]], rows[i][1], rows[i][2], float(readings[i])] for i in order],
        )
        write_csv(
            out / "truth" / "tip_distances_noise.csv",
            columns,
            [[config_ids[rows[i][0]], rows[i][1], rows[i][2], float(design.gauge_noise[i])] for i in order],
        )
        counts["tip_distances"] = len(rows)  # fmt: skip
    return counts


def contact_header(cell: Cell) -> dict:
    """dataset.yaml contact: the drawing's balls and planes (SI) and the prior on the centres."""
    setup = cell.contact
    return {
        "elements": {
            n: {"tip": t, "xyz": [float(v) for v in c], "radius": float(r)}
            for n, t, c, r in zip(setup.names, setup.tips, setup.centres, setup.radii, strict=True)
        },
        **(
            {"planes": {n: {"normal": [float(v) for v in normal], "offset": float(d)}
                        for n, normal, d in zip(setup.plane_names, setup.normals, setup.offsets, strict=True)}}
            if setup.plane_names else {}
        ),
        "position_sigma": float(setup.position_sigma_m),
    }  # fmt: skip
