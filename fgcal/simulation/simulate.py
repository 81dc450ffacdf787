"""``fgcal simulate``: the true robot, a design of configurations and the measurements,
written as a dataset; the ground truth goes to ``truth/``, which no estimation code reads."""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core.console import step
from ..core.errors import InputError
from ..core.noise import noise_document
from ..core.outputs import distinct, output_dir, subfolder, write_bytes
from ..core.se3 import inverse, pose, rotation_quaternion, rpy_from_rotation, so3_exp, transform_points
from ..data.dataset import FORMAT, write_csv, write_header
from ..data.truth import Truth
from ..model.motion import MotionHistory, features
from ..model.robot_io import embed_robot
from .ballbar import ballbar_design, ballbar_file_design, pairs_design, write_ballbar_table, write_pairs_table
from .cell import Cell, load_cell
from .contact import contact_design, contact_header, contact_truth, write_contact_tables
from .design import View, file_design, joint_space_design, seed_design, space_filling_design
from .self_observation import observation_design, observation_header, observation_truth, write_observed_pixels
from .static_camera import board_in_camera, board_seen, static_camera_design, write_static_camera_tables
from .touch import touch_design, touch_file_design, write_touch_tables
from .truth import perturb_parameters

# Every file fgcal simulate may write in its --out folder (fgcal simulate's calibration.yaml, the
# suggested config, too), and the rendered images/CONFIG.png: none may be one of its inputs.
WRITES = (
    "dataset.yaml", "calibration.yaml", "configurations.csv", "points.csv", "camera_points.csv", "pixels.csv",
    "tracker_points.csv", "tracker_poses.csv", "touch_points.csv", "distances.csv", "point_distances.csv",
    "tool_distances.csv", "tip_distances.csv", "observed_pixels.csv", "contacts.csv", "plane_contacts.csv",
    "truth/ground_truth.yaml", "truth/camera_points_noise.csv", "truth/pixels_noise.csv",
    "truth/tracker_points_noise.csv", "truth/tracker_poses_noise.csv", "truth/touch_points_noise.csv",
    "truth/distances_noise.csv", "truth/point_distances_noise.csv", "truth/tool_distances_noise.csv",
    "truth/tip_distances_noise.csv", "truth/observed_pixels_noise.csv", "truth/contacts_gap.csv",
    "truth/plane_contacts_gap.csv",
)  # fmt: skip


def check_inputs_kept(cell: Cell, out_dir: str | Path, configurations: str | Path | None) -> None:
    """Refuse an --out folder where the simulation would write over one of its inputs (the
    --configurations file, the cell, its robot file or the URDF that records): the same file,
    through symbolic and hard links too (fgcal.core.outputs.distinct), before anything is written."""
    out = Path(out_dir)
    reference = cell.robot_reference
    robot_file = reference.get("file") if isinstance(reference, dict) else reference
    inputs = {
        "--configurations": configurations,
        "CELL": cell.source,
        f"the robot file of {cell.source}": robot_file if robot_file and Path(robot_file).suffix else None,
        "the robot's URDF": None if cell.robot.urdf is None else cell.robot.urdf[0],
    }
    inputs = {role: path for role, path in inputs.items() if path is not None and Path(path).is_file()}
    images = sorted((out / "images").glob("*.png")) if (out / "images").is_dir() else []
    outputs = {f"--out ({name})": out / name for name in WRITES}
    outputs |= {f"--out (images/{path.name})": path for path in images}
    distinct(outputs, inputs)


@dataclass(frozen=True)
class Drift:
    """A step change of one true parameter (SI units) from configuration ``start`` on."""

    parameter: str
    change: float
    start: int


@dataclass
class SimulationResult:
    out_dir: Path
    seed: int
    design: str
    n_configurations: int
    n_observations: dict[str, int]
    deviation_mean_m: float
    deviation_max_m: float
    time_s: float

    def summary(self) -> str:
        obs = ", ".join(f"{k} {v}" for k, v in self.n_observations.items())
        return (
            f"simulated {self.n_configurations} configurations ({self.design} design, seed {self.seed}) "
            f"-> {self.out_dir}\n"
            f"  observations: {obs}\n"
            f"  true robot vs nominal model, flange position in the base frame over these configurations:\n"
            f"    deviation mean {self.deviation_mean_m * 1e3:#.4g} mm, max {self.deviation_max_m * 1e3:#.4g} mm\n"
            f"  time {self.time_s:.2g} s"
        )


def _pose_doc(T: np.ndarray) -> dict:
    # "+ 0.0" turns -0.0 into 0.0 so that files read cleanly.
    return {"xyz": [float(v) + 0.0 for v in T[:3, 3]], "rpy": [float(v) + 0.0 for v in rpy_from_rotation(T[:3, :3])]}


def positioning_deviation(cell: Cell, q: np.ndarray, true_params: dict[str, float]) -> np.ndarray:
    """Flange position error (m) of the nominal model against the true robot, in the base
    frame (the robot's own accuracy: base and tool perturbations excluded)."""
    robot = cell.robot
    kinematic = {k: v for k, v in true_params.items() if not k.startswith(("base.", "tool."))}
    T_0_true = inverse(robot.base_pose) @ robot.fk(q, kinematic)
    T_0_nominal = inverse(robot.base_pose) @ robot.fk(q)
    return np.linalg.norm(T_0_true[:, :3, 3] - T_0_nominal[:, :3, 3], axis=1)


def simulate(
    cell_path: str | Path,
    out_dir: str | Path,
    seed: int,
    design: str | None = None,
    n_configurations: int | None = None,
    progress: Callable[[str], None] | None = None,
    render: bool = False,
    drift: Drift | None = None,
    configurations: str | Path | None = None,
) -> SimulationResult:
    """Simulate a dataset of the cell. With ``drift``, one true parameter changes by a step
    from a configuration on (what online recalibration must notice). With
    ``configurations`` (a CSV as fgcal plan writes it), exactly those configurations, with
    the same true robot as any other design of the cell and seed."""
    started = time.perf_counter()
    say = progress or (lambda _msg: None)
    cell = load_cell(cell_path)
    check_inputs_kept(cell, out_dir, configurations)  # before the work, and before anything is written
    if design is not None or n_configurations is not None:
        cell = replace(
            cell,
            design=replace(
                cell.design,
                kind=design or cell.design.kind,
                n_configurations=n_configurations or cell.design.n_configurations,
            ),
        )
    sized = (cell.touch is None and cell.ballbar is None and cell.contact is None
             and (cell.camera is None or cell.design.kind == "space_filling"))  # fmt: skip
    if n_configurations is not None and configurations is None and not sized:  # it was read and ignored
        what = ("a touch, ballbar or contact cell's configurations are its readings" if cell.camera is None
                else "the cell's seed design has its own viewpoints: add --design space_filling")  # fmt: skip
        raise InputError(None, "--n", f"sets the size of a space-filling design; {what}")
    if configurations is not None:
        if design is not None or n_configurations is not None:
            raise InputError(None, "--configurations", "takes the place of --design and --n")
        cell = replace(cell, design=replace(cell.design, kind=f"file {Path(configurations).name}"))
    # A touch or ballbar plan (--configurations) names each one's point or pivot.
    if cell.ballbar is not None and configurations is not None and cell.ballbar.pairs:
        raise InputError(cell.source, "ballbar", "a plan of readings between configurations is not simulated yet")
    for setup, what in ((cell.touch, "touch"), (cell.ballbar, "ballbar"), (cell.contact, "contact")):
        if setup is not None and (design is not None or drift is not None or (what == "contact" and configurations)):
            raise InputError(
                cell.source, what, f"a {what} cell's configurations are its readings: no other design or drift"
            )
    if cell.static_camera is not None and drift is not None:
        raise InputError(cell.source, "static_camera", "a static-camera cell: no drift")
    if cell.camera is None and cell.design.kind == "seed":
        raise InputError(cell.source, "design.kind", "the seed design looks at the objects: a tracker cell has none")
    if drift is not None and cell.camera is None and not cell.has_tracker:
        raise InputError(
            None, "--drift", "the drift steps a true parameter under the camera's or the tracker's measurements, and "
            "this cell has neither",
        )  # fmt: skip
    if render and cell.camera is None:
        raise InputError(cell.source, "camera", "--render needs a camera: this is a tracker cell")
    robot = cell.robot
    # Independent streams: changing the design does not change the true robot or the noise.
    # Independent child streams (spawning four leaves the first three as they were).
    truth_rng, design_rng, noise_rng, image_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4)
    )
    true_params = perturb_parameters(robot, cell.perturbation, truth_rng)
    contact_true = contact_truth(cell, truth_rng) if cell.contact is not None else None  # after: the robot's stay
    seen_true = observation_truth(cell, truth_rng) if cell.self_observation is not None else None
    if cell.motion is not None:
        true_params |= cell.motion.parameters()
    if render and cell.motion is not None:
        raise InputError(cell.source, "motion_history", "--render does not simulate the motion history yet")
    if drift is not None and drift.parameter not in true_params:
        raise InputError(None, "drift", f"unknown parameter {drift.parameter!r} for {robot.name}")

    def true_camera(q: np.ndarray) -> np.ndarray:
        return robot.fk_tool(q, true_params)

    say(f"designing configurations ({cell.design.kind}) for {robot.name} in {cell.name}")
    if configurations is not None and cell.touch is not None:
        q_touch, touched, seating, unreached = touch_file_design(
            cell, Path(configurations), robot.parameter_vector(true_params), design_rng, noise_rng
        )
        views = [View(qi, None, ()) for qi in q_touch]
        if unreached:
            say(f"  {len(unreached)} touches left out: the true robot does not reach them ({', '.join(unreached[:5])})")
    elif configurations is not None and cell.ballbar is not None:
        q_bar, bar_pivots, bar_lengths, beyond = ballbar_file_design(
            cell, Path(configurations), robot.parameter_vector(true_params)
        )
        views = [View(qi, None, ()) for qi in q_bar]
        if beyond:
            say(f"  {len(beyond)} readings left out: beyond the bar's travel on the true robot ({beyond[0]}, ...)")
    elif configurations is not None:
        views, unseen = file_design(cell, Path(configurations), true_camera)
        if cell.static_camera is not None:  # what the true camera does not see of the board is left out
            q_file = np.array([v.q for v in views])
            seen = board_seen(cell, board_in_camera(cell, q_file, true_params))
            unseen = [f"line {i + 2}" for i in np.flatnonzero(~seen)]
            views = [v for v, s in zip(views, seen, strict=True) if s]
            if not views:
                raise InputError(configurations, None, "the simulated camera sees the board at none of them")
        if unseen:
            say(
                f"  {len(unseen)} configurations left out: the simulated true camera does not see their block or board "
                f"({', '.join(unseen[:5])}{', ...' if len(unseen) > 5 else ''})"
            )
    elif cell.touch is not None:
        q_touch, touched, seating = touch_design(cell, robot.parameter_vector(true_params), design_rng, noise_rng, say)
        views = [View(qi, None, ()) for qi in q_touch]
    elif cell.ballbar is not None:
        q_bar, bar_pivots, bar_lengths = ballbar_design(cell, robot.parameter_vector(true_params), design_rng, say)
        if cell.ballbar.pairs:  # after the readings to pivots: their configurations stay as they were
            q_bar = np.vstack([q_bar, pairs_design(cell, robot.parameter_vector(true_params), design_rng, say)])
        views = [View(qi, None, ()) for qi in q_bar]
    elif cell.contact is not None:
        contacts = contact_design(cell, robot.parameter_vector(true_params), contact_true, design_rng, noise_rng, say)
        views = [View(qi, None, ()) for qi in contacts.q]
        if seen_true is not None:  # after the contacts' draws, which stay as they were
            seeing = observation_design(cell, robot.parameter_vector(true_params), seen_true, design_rng, noise_rng)
            views += [View(qi, None, ()) for qi in seeing.q]
            say(f"  {len(seeing.q)} configurations where a camera sees a board ({len(seeing.rows)} pixels)")
    elif cell.static_camera is not None:
        views = static_camera_design(cell, true_params, design_rng)
    elif cell.camera is None:
        views = joint_space_design(cell, design_rng)
    elif cell.design.kind == "seed":
        views = seed_design(cell, true_camera, design_rng)
    else:
        views = space_filling_design(cell, true_camera, design_rng, progress=say)
    q = np.array([v.q for v in views])
    if drift is not None and not 0 <= drift.start < len(views):
        raise InputError(
            None, "--drift", f"starts at configuration {drift.start}, and the design has {len(views)} (0 to "
            f"{len(views) - 1})",
        )  # fmt: skip
    config_ids = [f"c{i:04d}" for i in range(len(views))]
    named = [v.config for v in views]
    if configurations is not None and all(named):  # a plan's ids stay: its pair_groups.csv names them
        repeated = sorted(c for c, k in Counter(named).items() if k > 1)
        if repeated:
            raise InputError(configurations, "config", f"{repeated[0]!r} names more than one configuration")
        config_ids = [str(c) for c in named]
    say(f"  {len(views)} configurations; measuring")
    # The configurations are measured in the design's order: that order is their motion history,
    # unless the design names a configuration's approach point.
    history = motion = None
    if cell.motion is not None:
        history = cell.motion.history(q)
        for k, view in enumerate(views):
            if view.before is not None:
                history.before[k] = view.before
        motion = features(q, history)

    out = output_dir(out_dir)
    subfolder(out, "truth")
    if cell.touch is not None:
        _write_configurations(out, cell, q, config_ids)
        counts = write_touch_tables(out, cell, config_ids, touched, seating, noise_rng)
    elif cell.ballbar is not None:
        _write_configurations(out, cell, q, config_ids)
        n_pivot = len(bar_pivots)
        counts = {}
        if n_pivot:
            counts = write_ballbar_table(out, cell, config_ids[:n_pivot], bar_pivots, bar_lengths, noise_rng)
        if cell.ballbar.pairs:
            ball_W = transform_points(robot.fk(q[n_pivot:], true_params, tip=cell.tip), cell.ballbar.ball)
            counts |= write_pairs_table(out, cell, config_ids[n_pivot:], ball_W, noise_rng)
    elif cell.contact is not None:
        _write_configurations(out, cell, q, config_ids)
        counts = write_contact_tables(out, contacts, config_ids)
        if seen_true is not None:
            counts |= write_observed_pixels(out, seeing, config_ids[len(contacts.q) :])
        if cell.has_tracker:  # the validation's reflectors, after the contacts' draws
            counts |= _write_tracker_points(out, cell, q, config_ids, true_params, noise_rng)
    elif cell.static_camera is not None:
        _write_configurations(out, cell, q, config_ids)
        counts = write_static_camera_tables(out, cell, q, config_ids, true_params, noise_rng)
    if cell.has_tracker and (cell.touch is not None or cell.ballbar is not None or cell.static_camera is not None):
        # A tracker besides (to fit with or validate on): its reflectors at the same configurations,
        # after the instrument's draws, which stay as they were.
        counts |= _write_tracker_points(out, cell, q, config_ids, true_params, noise_rng)
    if cell.touch is None and cell.ballbar is None and cell.contact is None and cell.static_camera is None:
        counts = _write_measurements(out, cell, views, q, config_ids, true_params, noise_rng, drift, history, motion)
    deviation = positioning_deviation(cell, q, true_params)
    boards = None
    if render:
        boards = _render_images(out, cell, views, q, config_ids, true_params, image_rng, say)
        counts["images"] = len(views)
    _write_header(out, cell, seed, len(views), counts, boards)
    Truth(
        seed=seed,
        cell=Path(cell.source).name,
        design=cell.design.kind,
        model=robot.model,  # the truth is scored with this model, whatever model is fitted
        parameters=true_params,
        camera_mounting_nominal=robot.tool_pose,
        base_pose_nominal=robot.base_pose,
        fixture_pose=cell.fixture_pose,
        tracker_pose=cell.tracker_pose,
        tracker_targets={f"t{i + 1}": t for i, t in enumerate(cell.tracker_targets)},
        touch_probe=cell.touch.probe if cell.touch is not None else None,
        touch_points=dict(zip(cell.touch.names, cell.touch.points, strict=True)) if cell.touch is not None else {},
        tracker_probe=cell.tracker_probe,
        ballbar_ball=cell.ballbar.ball if cell.ballbar is not None else None,
        ballbar_pivots=(
            dict(zip(cell.ballbar.names, cell.ballbar.pivots, strict=True)) if cell.ballbar is not None else {}
        ),
        static_camera_pose=cell.static_camera.pose if cell.static_camera is not None else None,
        static_camera_board_mount=cell.static_camera.board_mount if cell.static_camera is not None else None,
        contact_elements=contact_true.elements(cell) if contact_true is not None else {},
        contact_planes=contact_true.planes(cell) if contact_true is not None else {},
        link_cameras=seen_true.documents(cell)[0] if seen_true is not None else {},
        tip_boards=seen_true.documents(cell)[1] if seen_true is not None else {},
        noise_sigma={
            "camera_point_m": cell.camera_point_sigma_m,
            "pixel_px": cell.pixel_sigma_px,
            "tracker_m": cell.tracker_sigma_m,
            **({"touch_m": cell.touch_sigma_m, "spacing_m": cell.spacing_sigma_m} if cell.touch is not None else {}),
            **({"tracker_angle_rad": cell.tracker_angle_sigma_rad} if cell.tracker_probe is not None else {}),
            **({"distance_m": cell.distance_sigma_m} if cell.ballbar is not None else {}),
            **(
                {"contact_m": cell.contact_sigma_m, "distance_m": cell.distance_sigma_m}
                if cell.contact is not None
                else {}
            ),
            **({"pixel_px": cell.pixel_sigma_px} if cell.self_observation is not None else {}),
        },
        deviation_before_calibration_m={"mean": float(deviation.mean()), "max": float(deviation.max())},
        drift=(
            {"parameter": drift.parameter, "change": drift.change, "from_configuration": drift.start}
            if drift is not None
            else None
        ),
        motion_history=(
            {cid: (before, float(s)) for cid, before, s in zip(config_ids, history.before, history.speed, strict=True)}
            if history is not None
            else None
        ),
    ).write(out)
    return SimulationResult(
        out,
        seed,
        cell.design.kind,
        len(views),
        counts,
        float(deviation.mean()),
        float(deviation.max()),
        time.perf_counter() - started,
    )


def _write_measurements(
    out: Path,
    cell: Cell,
    views: list[View],
    q: np.ndarray,
    config_ids: list[str],
    true_params: dict[str, float],
    rng: np.random.Generator,
    drift: Drift | None = None,
    history: MotionHistory | None = None,
    motion: np.ndarray | None = None,
) -> dict[str, int]:
    """The measurements at configurations q, reached as ``history`` says (its features
    ``motion``; None: the robot has no motion terms)."""
    robot = cell.robot
    _write_configurations(out, cell, q, config_ids, history)
    if cell.camera is None:  # a tracker cell: the drift steps under its measurements
        return _write_tracker_points(out, cell, q, config_ids, true_params, rng, motion, drift)
    write_csv(
        out / "points.csv",
        ["point", "object", "side", "x", "y", "z"],
        [[p.name, p.obj, p.side, *map(float, p.position_F)] for p in cell.points()],
    )
    # Camera noise first, then the tracker's: the order of the draws is part of the seed.
    T_C_W = inverse(robot.fk_tool(q, true_params, motion))
    if drift is not None:
        drifted = {**true_params, drift.parameter: true_params[drift.parameter] + drift.change}
        later = None if motion is None else motion[drift.start :]
        T_C_W[drift.start :] = inverse(robot.fk_tool(q[drift.start :], drifted, later))
    cam_rows, cam_noise, px_rows, px_noise = [], [], [], []
    for cid, view, T in zip(config_ids, views, T_C_W, strict=True):
        names = [p.name for p in view.block]
        p_W = transform_points(cell.fixture_pose, np.array([p.position_F for p in view.block]))
        p_C = transform_points(T, p_W)
        noise = rng.normal(0.0, cell.camera_point_sigma_m, p_C.shape)
        pixels = cell.camera.project(p_C)
        pixel_noise = rng.normal(0.0, cell.pixel_sigma_px, pixels.shape)
        for name, p, n, px, pn in zip(names, p_C, noise, pixels, pixel_noise, strict=True):
            cam_rows.append([cid, name, *map(float, p + n)])
            cam_noise.append([cid, name, *map(float, n)])
            px_rows.append([cid, name, *map(float, px + pn)])
            px_noise.append([cid, name, *map(float, pn)])
    write_csv(out / "camera_points.csv", ["config", "point", "x", "y", "z"], cam_rows)
    write_csv(out / "pixels.csv", ["config", "point", "u", "v"], px_rows)
    write_csv(out / "truth" / "camera_points_noise.csv", ["config", "point", "x", "y", "z"], cam_noise)
    write_csv(out / "truth" / "pixels_noise.csv", ["config", "point", "u", "v"], px_noise)
    counts = _write_tracker_points(out, cell, q, config_ids, true_params, rng, motion)
    return {"camera_points": len(cam_rows), "pixels": len(px_rows), **counts}


def _write_configurations(
    out: Path, cell: Cell, q: np.ndarray, config_ids: list[str], history: MotionHistory | None = None
) -> None:
    """configurations.csv, in measurement order; with an approach other than the previous
    configuration, the joints each was approached from (before_q*)."""
    n = cell.robot.n_joints
    header = ["config"] + [f"q{i}" for i in range(1, n + 1)]
    rows = [[cid, *map(float, qi)] for cid, qi in zip(config_ids, q, strict=True)]
    if history is not None and not np.array_equal(history.before, MotionHistory.in_order(q).before, equal_nan=True):
        header += [f"before_q{i}" for i in range(1, n + 1)]
        # An unknown approach (the first configuration's) is empty cells: the previous row, none.
        rows = [[*row, *(map(float, before) if np.all(np.isfinite(before)) else [""] * n)]
                for row, before in zip(rows, history.before, strict=True)]  # fmt: skip
    write_csv(out / "configurations.csv", header, rows)


def _tip_entry(cell: Cell) -> dict:
    """dataset.yaml's ``tip``: the tree's tip carrying what is measured, when not the flange."""
    return {"tip": cell.tip} if cell.tip not in ("flange", cell.robot.flange_name) else {}


def _write_tracker_points(
    out: Path,
    cell: Cell,
    q: np.ndarray,
    config_ids: list[str],
    true_params: dict[str, float],
    rng,
    motion: np.ndarray | None = None,
    drift: Drift | None = None,
) -> dict[str, int]:
    def fk(tip: str) -> np.ndarray:
        """T_T_tip at every configuration, the drifted parameter from its start on."""
        T = inverse(cell.tracker_pose) @ cell.robot.fk(q, true_params, motion, tip=tip)
        if drift is not None:
            drifted = {**true_params, drift.parameter: true_params[drift.parameter] + drift.change}
            later = None if motion is None else motion[drift.start :]
            T[drift.start :] = inverse(cell.tracker_pose) @ cell.robot.fk(q[drift.start :], drifted, later, tip=tip)
        return T

    T_T_n = fk(cell.tip)  # the probe's tip
    tips = cell.tracker_target_tips or (cell.robot.flange_name,) * len(cell.tracker_targets)
    T_T_tip = {tip: fk(tip) for tip in set(tips)}
    trk_rows, trk_noise = [], []
    for j, cid in enumerate(config_ids):
        for i, target in enumerate(cell.tracker_targets):
            n = rng.normal(0.0, cell.tracker_sigma_m, 3)
            trk_rows.append([cid, f"t{i + 1}", *map(float, transform_points(T_T_tip[tips[i]][j], target) + n)])
            trk_noise.append([cid, f"t{i + 1}", *map(float, n)])
    write_csv(out / "tracker_points.csv", ["config", "target", "x", "y", "z"], trk_rows)
    write_csv(out / "truth" / "tracker_points_noise.csv", ["config", "target", "x", "y", "z"], trk_noise)
    counts = {"tracker_points": len(trk_rows)}
    if cell.tracker_probe is not None:  # after the points' draws, which stay as they were
        columns = ["config", "x", "y", "z", "qw", "qx", "qy", "qz"]
        rows, noise_rows = [], []
        for cid, T in zip(config_ids, T_T_n @ cell.tracker_probe, strict=True):
            angle, position = rng.normal(0.0, cell.tracker_angle_sigma_rad, 3), rng.normal(0.0, cell.tracker_sigma_m, 3)
            measured = pose(T[:3, :3] @ so3_exp(angle), T[:3, 3] + position)
            rows.append([cid, *map(float, measured[:3, 3]), *map(float, rotation_quaternion(measured[:3, :3]))])
            noise_rows.append([cid, *map(float, position), *map(float, angle)])
        write_csv(out / "tracker_poses.csv", columns, rows)
        write_csv(out / "truth" / "tracker_poses_noise.csv", ["config", "x", "y", "z", "rx", "ry", "rz"], noise_rows)
        counts["tracker_poses"] = len(rows)
    return counts


def _render_images(
    out: Path,
    cell: Cell,
    views: list[View],
    q: np.ndarray,
    config_ids: list[str],
    true_params: dict[str, float],
    rng: np.random.Generator,
    say: Callable[[str], None],
) -> list:
    """Synthetic images: each view's side board through the true camera (docs/simulation.md)."""
    import cv2

    from .markers import Renderer, board_pose_in_camera, side_boards

    boards = side_boards(cell.sides)
    by_side = {b.name: b for b in boards}
    renderer = Renderer(cell.camera)
    T_W_C = cell.robot.fk_tool(q, true_params)
    images = subfolder(out, "images")
    for i, (cid, view) in enumerate(zip(config_ids, views, strict=True)):
        board = by_side[f"{view.side.obj}{view.side.side}"]
        image = renderer.render(board, board_pose_in_camera(T_W_C[i], cell.fixture_pose, board), rng)
        write_bytes(images / f"{cid}.png", cv2.imencode(".png", image)[1].tobytes())
        step(say, "rendering images", i + 1, len(views))
        if (i + 1) % 50 == 0:
            say(f"  rendered {i + 1}/{len(views)} images")
    return boards


def stated_noise(cell: Cell, measured: list[str]) -> dict[str, float]:
    """The sigmas the simulated instruments state for the tables measured (SI, fgcal.core.noise's
    fields): what a real instrument's specification would declare; here, exactly the noise
    drawn."""
    sources = {
        "camera_points": {"camera_point_m": cell.camera_point_sigma_m},
        "pixels": {"pixel_px": cell.pixel_sigma_px},
        "tracker_points": {"tracker_m": cell.tracker_sigma_m},
        "tracker_poses": {"pose_m": cell.tracker_sigma_m, "pose_rad": cell.tracker_angle_sigma_rad},
        "touch_points": {"touch_m": cell.touch_sigma_m},
        "point_distances": {"spacing_m": cell.spacing_sigma_m},
        "distances": {"distance_m": cell.distance_sigma_m},
        "tool_distances": {"distance_m": cell.distance_sigma_m},
        "contacts": {"contact_m": cell.contact_sigma_m},
        "plane_contacts": {"contact_m": cell.contact_sigma_m},
        "tip_distances": {"distance_m": cell.distance_sigma_m},
        "observed_pixels": {"pixel_px": cell.pixel_sigma_px},
    }
    out: dict[str, float] = {}
    for table in measured:
        out.update(sources.get(table, {}))
    # A noise-free simulation states nothing: no weight can come from a zero sigma.
    return {field: sigma for field, sigma in out.items() if sigma > 0}


def _write_header(
    out: Path, cell: Cell, seed: int, n_configurations: int, counts: dict[str, int], boards: list | None = None
) -> None:
    robot = cell.robot
    noise = noise_document(stated_noise(cell, list(counts)))
    camera = cell.camera is not None  # a tracker cell has its tracker points only
    camera_files = {"points": "points.csv", "camera_points": "camera_points.csv", "pixels": "pixels.csv"}
    camera_noise = f"camera points {cell.camera_point_sigma_m} m, pixels {cell.pixel_sigma_px} px, " if camera else ""
    source = (
        f"fgcal simulate {Path(cell.source).name} --seed {seed} ({cell.design.kind} design, "
        f"{n_configurations} configurations); noise sigma: "
    )
    if cell.touch is not None or cell.ballbar is not None or cell.static_camera is not None or cell.contact is not None:
        if cell.contact is not None:
            noise_text = (
                f"contacts {cell.contact_sigma_m} m, gauge {cell.distance_sigma_m} m"
                + (f", pixels {cell.pixel_sigma_px} px" if cell.self_observation is not None else "")
                + (f", tracker {cell.tracker_sigma_m} m (validation)" if cell.has_tracker else "")
            )
        elif cell.touch is not None:
            noise_text = f"touch {cell.touch_sigma_m} m, known distances {cell.spacing_sigma_m} m"
        elif cell.ballbar is not None:
            noise_text = f"ballbar {cell.distance_sigma_m} m"
        else:
            noise_text = f"pixels {cell.pixel_sigma_px} px (a static camera watching a board on the flange)"
        if cell.contact is None and "tracker_points" in counts:
            noise_text += f", tracker {cell.tracker_sigma_m} m"
        files = {k: f"{k}.csv" for k in counts}
        write_header(
            out,
            {
                "format": FORMAT,
                "robot": embed_robot(cell.robot_reference, out),
                "units": {"length": "m", "angle": "rad"},
                "measured": list(counts),
                "files": {
                    "configurations": "configurations.csv",
                    **({"points": "points.csv"} if cell.static_camera is not None else {}),
                    **files,
                },
                **({"camera": cell.static_camera.camera.to_document()} if cell.static_camera is not None else {}),
                **({"contact": contact_header(cell)} if cell.contact is not None else {}),
                **({"self_observation": observation_header(cell)} if cell.self_observation is not None else {}),
                **({"tracker": _tracker_header(cell)} if "tracker_points" in counts else {}),
                "payload": {"mass": float(robot.payload_mass), "com": [float(v) for v in robot.payload_com]},
                **_tip_entry(cell),
                "noise": noise,
                "source": source + noise_text,
            },
        )
        return
    header = {
        "format": FORMAT,
        "robot": embed_robot(cell.robot_reference, out),
        "units": {"length": "m", "angle": "rad"},
        **_tip_entry(cell),
        "measured": [k for k in counts if k != "images"],
        "files": {
            "configurations": "configurations.csv",
            **(camera_files if camera else {}),
            "tracker_points": "tracker_points.csv",
            **({"tracker_poses": "tracker_poses.csv"} if "tracker_poses" in counts else {}),
        },
        **(
            {
                "images": "images",
                "markers": {
                    "dictionary": "DICT_5X5_1000",
                    "marker_ratio": 0.75,
                    "boards": [b.to_document() for b in boards],
                },
            }
            if boards
            else {}
        ),
        **({"camera": {**cell.camera.to_document(), "mounting": _pose_doc(robot.tool_pose)}} if camera else {}),
        "payload": {"mass": float(robot.payload_mass), "com": [float(v) for v in robot.payload_com]},
        **({"fixture": _pose_doc(cell.fixture_pose)} if camera else {}),
        "tracker": _tracker_header(cell),
        "noise": noise,
        "source": source + f"{camera_noise}tracker {cell.tracker_sigma_m} m",
    }
    write_header(out, header)


def _tracker_header(cell: Cell) -> dict:
    """dataset.yaml tracker: the reflectors' names and, on a tree, their tips."""
    tips = cell.tracker_target_tips
    return {
        "targets": [f"t{i + 1}" for i in range(len(cell.tracker_targets))],
        **({"tips": {f"t{i + 1}": tip for i, tip in enumerate(tips)}} if tips else {}),
    }
