"""fgcal export: the calibrated robot as URDF, with what the URDF keeps of its accuracy.

A URDF cannot bend: the gravity compliances go to the sidecar, and a consumer that reads the
URDF alone gets the rigid model. This command says what that costs. With the calibration's
config, on its data (fitting and held out, each model with the instrument registered to it);
without, as the difference from the full model over the joint ranges. The rigid fit (the
default for a robot with compliances; ``--no-rigid-fit`` writes the rigid values as they are)
refits the rigid parameters to the full model over the calibrated region
(fgcal.model.rigid_fit): on the real FARO IRB 120 set the URDF alone with the compliances just
dropped is less accurate than the nominal robot (1.07 against 0.97 mm held out), the refit 0.61.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.console import warn
from ..core.errors import InputError
from ..core.outputs import distinct, output_file, write_text
from ..model.rigid_fit import RigidFit, region_sample, rigid_refit, without_compliances
from ..model.robot_io import load_robot
from ..model.urdf_export import check_outputs, export_urdf, is_tree, template_of, tip_link_names

LOSS_WARNING = 0.20  # the URDF alone losing more than this fraction of the held-out accuracy is warned of


def export_command(
    robot_file: str,
    urdf: str | None,
    tip: str | None = None,
    template: str | None = None,
    calibration: str | None = None,
    rigid_fit: bool | None = None,
    payload_mass: float | None = None,
    payload_com: list[float] | None = None,
    ur_kinematics: str | None = None,
    nominal: str | None = None,
    say: Callable[[str], None] = print,
) -> int:
    path = None if urdf is None else check_outputs(urdf, "--urdf")[0]  # before the work, not after it
    sidecar = None if path is None else path.with_name(f"{path.stem}.compliance.yaml")
    outputs = {"--urdf": path, "the sidecar": sidecar, "--ur-kinematics": ur_kinematics}
    inputs = {"ROBOT": robot_file, "--template": template, "--calibration": calibration, "--nominal": nominal}
    distinct(outputs, {k: v for k, v in inputs.items() if v is not None and Path(v).suffix})  # bundled names: none
    if ur_kinematics is not None:
        if Path(ur_kinematics).suffix.lower() not in (".yaml", ".yml"):
            raise InputError(ur_kinematics, "--ur-kinematics", "the kinematics file's name ends in .yaml")
        output_file(ur_kinematics, "--ur-kinematics")
    robot = load_robot(robot_file, tip)
    if path is not None and template is not None and is_tree(robot):  # before any work
        raise InputError(template, "--template", f"{robot.name} is a tree: it is written in fgcal's own layout")
    if rigid_fit is None:
        # The default: a URDF cannot bend, so it gets the rigid model nearest the full one over the
        # calibrated region (the robot file's, or the calibration's fitting configurations).
        has_region = robot.region is not None or calibration is not None
        rigid_fit = has_region and _has_compliances(robot) and not is_tree(robot)
        default_fit = rigid_fit
    else:
        default_fit = False
    if is_tree(robot) and (rigid_fit or calibration is not None):
        # Both score and refit the flange's tool alone; a tree's other tips would go unchecked.
        option = "--rigid-fit" if rigid_fit else "--calibration"
        raise InputError(robot_file, option, f"{robot.name} is a tree: {option} fits and scores the flange's tool "
                         "only, not every tip; export it without (the sidecar keeps the compliances)")  # fmt: skip
    # What the robot file names and the calibration reads are inputs too: the URDF the robot came
    # from (written into, never over), the calibration's datasets.
    recorded = None if robot.urdf is None else robot.urdf[0]
    distinct(
        outputs,
        {
            **inputs,
            f"urdf.file of {robot_file}": recorded,
            **_calibration_inputs(calibration),
            **_xacro_inputs(template, recorded, robot_file),
        },
    )
    if payload_mass is not None or payload_com is not None:
        mass = robot.payload_mass if payload_mass is None else payload_mass
        com = robot.payload_com if payload_com is None else np.array(payload_com, dtype=float)
        robot = robot.with_tool(robot.tool_pose, float(mass), com)
    result = None
    if calibration is not None:
        from ..calibration.config import load_config
        from ..calibration.model_accuracy import check_same_robot
        from ..calibration.run import calibrate

        say(f"repeating the calibration {calibration} to score the URDF on its data")
        result = calibrate(load_config(calibration))
        check_same_robot(result, robot)
    accuracy: dict = {}
    fitted: RigidFit | None = None
    if rigid_fit:
        from ..calibration.model_accuracy import fitting_configurations

        region = fitting_configurations(result) if result is not None else region_sample(robot)
        if result is not None:
            where = "the calibration's fitting configurations"
        elif robot.region is not None:
            where = "the calibrated region the robot file keeps"
        else:
            where = "seeded joint values within the limits"
        try:
            fitted = rigid_refit(robot, region)
        except InputError as exc:
            if not default_fit:
                raise
            warn(f"no rigid fit ({exc.message}): the URDF holds the calibrated rigid values, the compliances dropped")
            fitted = None
    if fitted is not None:
        say(
            f"rigid fit over {len(region)} configurations ({where}), payload {robot.payload_mass:g} kg: the URDF "
            f"alone was {fitted.dropped_rms_m * 1e3:.3f} mm RMS ({fitted.dropped_max_m * 1e3:.3f} max) from the full "
            f"model, the refit is {fitted.remaining_rms_m * 1e3:.3f} mm RMS ({fitted.remaining_max_m * 1e3:.3f} max)"
            + ("" if result is not None else "; --calibration CONFIG states the URDF's accuracy on the data")
            + ("; --no-rigid-fit writes the calibrated rigid values as they are" if default_fit else "")
        )
        accuracy["rigid_fit"] = {
            "configurations": fitted.n_configurations,
            "region": where,
            "payload_mass_kg": float(robot.payload_mass),
            "compliances_dropped_rms_m": fitted.dropped_rms_m,
            "compliances_dropped_max_m": fitted.dropped_max_m,
            "remaining_rms_m": fitted.remaining_rms_m,
            "remaining_max_m": fitted.remaining_max_m,
        }
    exported = fitted.robot if fitted is not None else robot
    if result is not None:
        accuracy["on_the_calibration_data"] = _on_data(result, robot, exported, fitted is not None, say)
    elif fitted is None:
        region = region_sample(robot)
        where = "the calibrated region's" if robot.region is not None else "seeded"
        gap = np.linalg.norm(
            robot.fk_tool(region)[:, :3, 3] - without_compliances(robot).fk_tool(region)[:, :3, 3], axis=1
        )
        if gap.max() > 0:
            say(
                f"the URDF alone ({_dropped(robot)}) is {np.sqrt(np.mean(gap**2)) * 1e3:.3f} mm RMS "
                f"({gap.max() * 1e3:.3f} max) from the full model over {where} {len(region)} configurations: "
                "--calibration CONFIG states it on the data, --rigid-fit folds what it can into the URDF"
            )
    if ur_kinematics is not None:
        _write_ur_kinematics(exported, nominal, Path(ur_kinematics), say)
    if path is None:
        return 0
    # The rigid fit folds what it can of the compliances into the geometry, but none of the lost
    # motion (a joint offset that depends on the last move): the sidecar keeps the robot's.
    written, sidecar = export_urdf(
        _with_history_of(exported, robot), path, template, accuracy=accuracy or None,
        nominal=_template_nominal(exported, template, nominal),
    )  # fmt: skip
    template_file = None if is_tree(exported) else template_of(exported, template)
    held = "joint compliances and lost motion" if robot.history else "joint compliances"
    say(f"wrote {written} ({robot.name}, {robot.n_links} joints) and {sidecar} ({held}, which URDF cannot")
    if template_file is None:
        # A tree's flange is a link by its name, as each tip (renamed where the layout has the name).
        links = tip_link_names(robot) if is_tree(robot) else {robot.flange_name: "flange"}
        flange, *tips = [links[name] for name in robot.tip_names]
        others = "".join(f", {link}" for link in tips)
        say(f"  express); links: world, base_link, link_1..link_{robot.n_links}, {flange}, tool0{others}")
    else:
        say(f"  express, and the robot's placement); {template_file[0].name} with the calibrated joint origins")
    return 0


def _with_history_of(exported, robot):
    """``exported`` with ``robot``'s motion-history terms (lost motion, speed), which no URDF holds
    and the rigid fit does not touch; they do not move the URDF's geometry (fgcal.model.motion)."""
    if exported is robot or not robot.history:
        return exported
    from dataclasses import replace

    from ..model.parameters import is_motion

    history = {name: value for name, value in robot.nominal_parameters().items() if is_motion(name)}
    return replace(exported, overrides={**exported.nominal_parameters(), **history})


def _xacro_inputs(*files: str | None) -> dict[str, Path]:
    """The files a xacro among ``files`` reads (its includes), which no output may overwrite."""
    from ..model.xacro_io import expand, is_xacro

    out = {}
    for file in files:
        if file is not None and is_xacro(file) and Path(file).is_file():
            for read in expand(file)[1][1:]:
                out[f"{Path(file).name}'s include {read.name}"] = read
    return out


def _template_nominal(robot, template: str | None, nominal: str | None):
    """The nominal model a template URDF is compared with, for a robot not read from it (a DH
    robot into the vendor's URDF): --nominal, else the bundled robot of the same name, else none."""
    if template is None or is_tree(robot):
        return None
    from ..data.compensation import nominal_of

    try:
        return nominal_of(robot, nominal)
    except InputError:
        if nominal is not None:
            raise
        return None  # a robot read from the template needs none; any other is refused for want of it


def _calibration_inputs(calibration: str | None) -> dict[str, Path]:
    """The files --calibration reads: its datasets' files (dataset.yaml, the tables, the robot)."""
    if calibration is None:
        return {}
    from ..calibration.config import load_config

    config = load_config(calibration)
    folders = [config.dataset, *config.validation_datasets]
    return {
        f"--calibration's dataset file {file.name}": file
        for folder in folders
        if folder.is_dir()
        for file in sorted(folder.iterdir())
        if file.is_file()
    }


def _write_ur_kinematics(robot, nominal: str | None, path: Path, say: Callable[[str], None]) -> None:
    import yaml

    from ..data.compensation import nominal_of
    from ..data.ur_kinematics import residual_text, ur_kinematics

    result = ur_kinematics(robot, nominal_of(robot, nominal))
    write_text(path, yaml.safe_dump(result.document, sort_keys=False))
    say(
        f"wrote {path}: {robot.name}'s calibrated kinematics as the UR description's default_kinematics.yaml "
        f"({_dropped(robot)}); what that layout cannot hold of the flange: {residual_text(result)}"
    )
    if result.tool0_tilt_rad > 1e-5 or result.tool0_offset_m > 1e-5:
        warn("the calibrated flange is not square to axis 6: the file puts tool0 off by that much")


def _on_data(result, robot, exported, refitted: bool, say: Callable[[str], None]) -> dict:
    from ..calibration.model_accuracy import model_accuracy

    rows = {"full model (with the compliances)": model_accuracy(result, robot)}
    rows[f"URDF alone ({_dropped(robot)})"] = model_accuracy(result, without_compliances(robot))
    if refitted:
        rows["URDF alone, rigid fit"] = model_accuracy(result, exported)
    say("accuracy on the calibration's data, mm (each model with the instrument registered to it on the fitting data):")
    say(f"  {'model':40s} {'fitting RMS':>12s} {'held-out RMS':>13s} {'held-out max':>13s}")
    out = {}
    for label, accuracy in rows.items():
        held = accuracy.held_out
        say(
            f"  {label:40s} {accuracy.fit.rms * 1e3:12.3f} "
            + (f"{held.rms * 1e3:13.3f} {held.max * 1e3:13.3f}" if held is not None else f"{'-':>13s} {'-':>13s}")
        )
        out[label] = {
            "fit_rms_m": accuracy.fit.rms,
            "held_out_rms_m": None if held is None else held.rms,
            "held_out_max_m": None if held is None else held.max,
        }
    label, urdf = list(rows.items())[-1]
    full = rows["full model (with the compliances)"]
    which = "held-out" if full.held_out is not None else "fitting"
    score = (lambda a: a.held_out.rms) if full.held_out is not None else (lambda a: a.fit.rms)
    ratio = score(urdf) / score(full)
    if ratio - 1.0 > LOSS_WARNING:
        warn(
            f"the {label} has {ratio:.2f}x the full model's {which} RMS error ({score(urdf) * 1e3:.3f} against "
            f"{score(full) * 1e3:.3f} mm)"
            + ("" if refitted else "; --rigid-fit folds what it can of the compliances into it")
            + "; for the full accuracy, correct the commands with fgcal compensate (docs/using.md)"
        )
    return out


def _has_compliances(robot) -> bool:
    """A robot whose model holds something a URDF cannot (a compliance or motion-history term not zero)."""
    rigid = without_compliances(robot).nominal_parameters()
    return any(value != rigid[name] for name, value in robot.nominal_parameters().items())


def _dropped(robot) -> str:
    """What a URDF cannot hold of the robot's model."""
    return "compliances and lost motion dropped" if robot.history else "compliances dropped"
