"""First contact (issue 22): every command and option that README.md and docs/cli.md show, run
as documented with fast settings; every bundled cell simulated and calibrated with the config
fgcal simulate writes beside it; and the Python examples of the docs executed, so that docs
and behaviour cannot drift apart."""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import REPO, SHARED

from fgcal.commands.cli import main

FARO = SHARED / "data" / "irb120_faro"
# The humanoid motion-capture cell (issue 40) takes 7 s at its 500 configurations: its default
# check is tests/test_humanoid_cell.py's (80 configurations), this one runs with the studies.
SLOW_CELLS = {"humanoid_mocap"}
CELLS = [
    pytest.param(p.stem, marks=pytest.mark.study) if p.stem in SLOW_CELLS else p.stem
    for p in sorted((REPO / "datasets" / "cells").glob("*.yaml"))
]

# Each command as the docs write it, with fast settings; {ws} is the test's workspace. The runs
# of one group share it, in order (the calibration reads what the simulation wrote).
RUNS = {
    "simulate and calibrate": [
        ["simulate", "kr125_seed", "--out", "{ws}/seed", "--seed", "2"],
        ["calibrate", "{ws}/seed/calibration.yaml", "--out", "{ws}/calibrated"],
        ["calibrate", "{ws}/seed/calibration.yaml", "--out", "{ws}/calibrated_text", "--no-plots", "--json", "-q",
         "-v"],
        ["simulate", "kr125_seed", "--out", "{ws}/rendered", "--design", "space_filling", "--n", "6", "--render",
         "--json"],
        ["simulate", "kr125_seed", "--out", "{ws}/drifted", "--design", "space_filling", "--n", "12",
         "--drift", "a2=0.001@6"],
        ["plan", "kr125_seed", "--n", "12", "--out", "{ws}/plan", "--criterion", "position", "--candidates", "300",
         "--formulation", "pairs", "--model", "DH,s,e", "--seed", "2", "--no-plots"],
        ["plan", "irb120_tracker", "--n", "12", "--out", "{ws}/plan_tracker", "--candidates", "300", "--json",
         "--model-error", "0.3"],
        ["plan", "kr125_seed", "--n", "12", "--out", "{ws}/plan_real", "--candidates", "300", "--no-plots",
         "--model-error-from", "{ws}/calibrated/report.json"],
        ["plan", "irb120_tracker_lost_motion", "--n", "12", "--out", "{ws}/plan_lost", "--candidates", "300",
         "--approach", "unidirectional", "--approach-offset", "3", "--program", "rapid", "krl", "csv-deg"],
        ["simulate", "kr125_seed", "--out", "{ws}/planned", "--configurations", "{ws}/plan/configurations.csv"],
    ],
    "use the result": [
        ["compensate", "{ws}/calibrated/calibrated_robot.yaml", "{ws}/targets.csv", "--out", "{ws}/commands.csv"],
        ["compensate", "{ws}/calibrated/calibrated_robot.yaml", "{ws}/targets.csv", "--out", "{ws}/commands2.csv",
         "--tcp", "0", "0", "0.1", "--nominal", "kuka_kr125_2", "--payload-mass", "50", "--payload-com", "0", "0",
         "0.1", "--tolerance-um", "2"],
        ["export", "{ws}/calibrated/calibrated_robot.yaml", "--urdf", "{ws}/urdf/calibrated.urdf"],
        ["export", "seven_axis", "--urdf", "{ws}/urdf/seven_axis.urdf", "--tip", "link_7"],
        ["export", "{ws}/calibrated/calibrated_robot.yaml", "--urdf", "{ws}/urdf/rigid.urdf", "--calibration",
         "{ws}/seed/calibration.yaml", "--rigid-fit", "--payload-mass", "50", "--payload-com", "0", "0", "0.1"],
        ["export", "seven_axis", "--urdf", "{ws}/urdf/templated.urdf", "--template",
         str(REPO / "datasets" / "robots" / "seven_axis.urdf")],
        ["robots"],
        ["list", "cells"],
        ["--version"],
        ["fk", "abb_irb120", "0", "0.5", "0", "0", "0", "0"],
        ["fk", "kuka_kr125_2", "0", "-30", "20", "0", "45", "0", "--deg", "--tool"],
        ["fk", "seven_axis", "0", "0.1", "0", "0.2", "0", "0.3", "0", "--tip", "link_7"],
        ["export", "ur10e", "--ur-kinematics", "{ws}/urdf/ur10e_kinematics.yaml", "--nominal", "ur10e"],
        ["compensate", "{ws}/calibrated/calibrated_robot.yaml", "{ws}/targets_mm.csv", "--out", "{ws}/commands_mm.csv",
         "--length-unit", "mm", "--angle-unit", "deg", "--orientation", "abc", "--json", "--targets-frame",
         "controller"],
        ["compensate", "{ws}/calibrated/calibrated_robot.yaml", "{ws}/targets.csv", "--out", "{ws}/commands3.csv",
         "--approach", "none"],
        ["compensate", "{ws}/calibrated/calibrated_robot.yaml", "{ws}/targets.csv", "--out", "{ws}/commands_tip.csv",
         "--tip", "flange"],
        ["export", "dual_arm_torso", "--urdf", "{ws}/urdf/dual_arm.urdf"],
        ["fk", "dual_arm_torso", *["0.1"] * 17, "--tip", "right_hand"],
        ["fk", "humanoid_upper_body", *["0.1"] * 17, "--tip", "right_hand"],
        ["export", "humanoid_upper_body", "--urdf", "{ws}/urdf/humanoid.urdf"],
        ["export", "{ws}/calibrated/calibrated_robot.yaml", "--urdf", "{ws}/urdf/raw.urdf", "--no-rigid-fit"],
        ["fk", "{ws}/arm_description/urdf/arm.xacro", "0", "0.1", "0", "0.2", "0", "0.3", "0", "--package",
         "{ws}/arm_description"],
        ["export", "seven_axis", "--urdf", "{ws}/urdf/from_xacro.urdf", "--template",
         "{ws}/arm_description/urdf/arm.xacro", "--package", "arm_description={ws}/arm_description"],
        ["compensate", "{ws}/calibrated/calibrated_robot.yaml", "{ws}/PALLET.dat", "--out", "{ws}/PALLET_cal.dat",
         "--tool", "0", "0", "100", "0", "0", "0", "--base", "1000", "0", "0", "0", "0", "0"],
        ["compensate", "{ws}/calibrated/calibrated_robot.yaml", "{ws}/FDAT.dat", "--out", "{ws}/FDAT_cal.dat",
         "--declarations", "{ws}/$config.dat"],
    ],
    "online": [
        ["online-feed", "{ws}/seed", "--inbox", "{ws}/inbox", "--first", "0", "--n", "20", "--cycle-size", "10"],
        ["online", "--state", "{ws}/state", "--inbox", "{ws}/inbox", "--setup", "{ws}/setup.yaml", "--once",
         "--poll", "0.1"],
        ["schema", "online"],
        # One table of a cell with several (the seed cell's tracker beside its camera).
        ["online-feed", "{ws}/seed", "--inbox", "{ws}/inbox_tracker", "--n", "5", "--table", "tracker_points"],
    ],
    "demo": [
        ["demo", "--out", "{ws}/demo", "--seed", "2", "--n", "60"],
        ["demo", "--out", "{ws}/demo_tracker", "--n", "40", "--formulation", "tracker"],
    ],
    "import": [
        ["simulate", "irb120_tracker", "--out", "{ws}/session", "--n", "30"],
        ["import-csv", "{ws}/mapping.yaml", "--out", "{ws}/imported"],
        ["convert-faro", str(FARO), "--out", "{ws}/faro"],
        ["bench", "--kinematics", "--repeats", "1", "--json"],
        ["bench", "--out", "{ws}/bench", "--seed", "2", "--sizes", "20", "--repeats", "1", "--json",
         "--memory-n", "20", "--program-targets", "40", "--faro", "{ws}/faro"],
    ],
}  # fmt: skip
# What each run must leave behind (paths relative to the workspace).
WRITES = {
    "calibrate": ["report.md", "report.json", "calibrated_robot.yaml", "estimates.yaml"],
    "simulate": ["dataset.yaml", "configurations.csv", "calibration.yaml"],
    "plan": ["configurations.csv", "plan.json", "plan.md"],
    "demo": ["report/report.md", "report/report.json", "calibration.yaml"],
}


def _documented() -> dict[str, set[str]]:
    """Command -> options, from the headings of docs/cli.md (## `fgcal COMMAND ... --option ...`)."""
    out: dict[str, set[str]] = {}
    for line in (REPO / "docs" / "cli.md").read_text().splitlines():
        match = re.match(r"## `fgcal ([a-z-]+)(.*)`", line)
        if match:
            out[match.group(1)] = set(re.findall(r"--[a-z-]+", match.group(2)))
    return out


def test_every_documented_command_and_option_is_run():
    """The runs below cover every command docs/cli.md documents, with every option it shows,
    and every command README.md names."""
    documented = _documented()
    readme = set(re.findall(r"`fgcal ([a-z-]+)", (REPO / "README.md").read_text()))
    assert readme <= set(documented), readme - set(documented)
    run = {}
    for runs in RUNS.values():
        for argv in runs:
            run.setdefault(argv[0], set()).update(a for a in argv if a.startswith("--"))
    assert set(run) == set(documented)
    missing = {command: options - run[command] for command, options in documented.items() if options - run[command]}
    assert not missing, missing


def _run(argv: list[str], ws: Path, capsys) -> str:
    argv = [a.format(ws=ws) for a in argv]
    status = main(argv)
    out, err = capsys.readouterr()
    assert status == 0, (argv, err)
    assert "Traceback" not in err, err
    return out


def _check_writes(argv: list[str], ws: Path) -> None:
    if argv[0] not in WRITES:
        return
    folder = Path(argv[argv.index("--out") + 1].format(ws=ws))
    for name in WRITES[argv[0]]:
        assert (folder / name).exists(), (argv, name)


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("smoke")


def test_simulate_plan_and_calibrate_as_documented(ws, capsys):
    for argv in RUNS["simulate and calibrate"]:
        _run(argv, ws, capsys)
        _check_writes(argv, ws)
    assert (ws / "calibrated" / "errors.png").exists() and not (ws / "calibrated_text" / "errors.png").exists()
    assert len(list((ws / "rendered" / "images").glob("*.png"))) == 6
    assert yaml.safe_load((ws / "drifted" / "truth" / "ground_truth.yaml").read_text())["drift"]["parameter"] == "a2"
    assert json.loads((ws / "plan_tracker" / "plan.json").read_text())["formulation"] == "tracker"
    planned = (ws / "plan" / "configurations.csv").read_text().splitlines()
    assert len(planned) == 13 and len((ws / "planned" / "configurations.csv").read_text().splitlines()) >= 2


def test_use_the_result_as_documented(ws, capsys):
    import fgcal

    robot = fgcal.load_robot(ws / "calibrated" / "calibrated_robot.yaml")
    q = np.random.default_rng(1).uniform(-0.4, 0.4, (5, 6)) + np.array([0, -1.2, 1.2, 0, 0.5, 0])
    positions = robot.fk_tool(q)[:, :3, 3]
    (ws / "targets.csv").write_text(
        "target,x,y,z\n" + "".join(f"p{i},{x:.17g},{y:.17g},{z:.17g}\n" for i, (x, y, z) in enumerate(positions))
    )
    from fgcal.data.program_filter import configurations, frame_from_numbers
    from fgcal.data.programs import krl_abc_deg

    taught = (
        np.linalg.inv(frame_from_numbers([1000, 0, 0, 0, 0, 0]))
        @ robot.fk(q)
        @ frame_from_numbers([0, 0, 100, 0, 0, 0])
    )
    lines = ["DEFDAT PALLET", "; taught on the nominal controller"]
    for i, (T, c) in enumerate(zip(taught, configurations(robot, "krl", q), strict=True)):
        a, b, cc = krl_abc_deg(T[:3, :3])
        x, y, z = T[:3, 3] * 1e3
        lines.append(f"DECL E6POS XP{i}={{X {x:.3f},Y {y:.3f},Z {z:.3f},A {a:.4f},B {b:.4f},C {cc:.4f},S {c['S']},"
                     f"T {c['T']}}}")  # fmt: skip
    abc = [krl_abc_deg(T[:3, :3]) for T in robot.fk_tool(q)]
    (ws / "targets_mm.csv").write_text(
        "target,x,y,z,a,b,c\n"
        + "".join(f"p{i},{x * 1e3:.6f},{y * 1e3:.6f},{z * 1e3:.6f},{a:.6f},{b:.6f},{c:.6f}\n"
                  for i, ((x, y, z), (a, b, c)) in enumerate(zip(positions, abc, strict=True)))
    )  # fmt: skip
    (ws / "PALLET.dat").write_text("\n".join([*lines, "ENDDAT"]) + "\n")
    # The same targets naming their tool and base in FDATs, KUKA's $config.dat declaring them.
    fdat = [line for line in lines if line.startswith("DECL E6POS")]
    fdat += [f"DECL FDAT FP{i}={{TOOL_NO 1,BASE_NO 1,IPO_FRAME #BASE}}" for i in range(len(fdat))]
    (ws / "FDAT.dat").write_text("\n".join(["DEFDAT FDAT", *fdat, "ENDDAT"]) + "\n")
    (ws / "$config.dat").write_text("DEFDAT $CONFIG\nTOOL_DATA[1]={X 0,Y 0,Z 100,A 0,B 0,C 0}\n"
                                    "BASE_DATA[1]={X 1000,Y 0,Z 0,A 0,B 0,C 0}\nENDDAT\n")  # fmt: skip
    # A vendor-style xacro package: arm.xacro includes $(find arm_description)/urdf/macro.xacro.
    urdf = (REPO / "datasets" / "robots" / "seven_axis.urdf").read_text()
    body = urdf[urdf.index(">", urdf.index("<robot")) + 1 : urdf.index("</robot>")]
    (ws / "arm_description" / "urdf").mkdir(parents=True)
    (ws / "arm_description" / "urdf" / "macro.xacro").write_text(
        f'<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:macro name="arm">{body}</xacro:macro></robot>'
    )
    (ws / "arm_description" / "urdf" / "arm.xacro").write_text(
        '<robot name="seven_axis" xmlns:xacro="http://www.ros.org/wiki/xacro">'
        '<xacro:include filename="$(find arm_description)/urdf/macro.xacro"/><xacro:arm/></robot>'
    )
    printed = [_run(argv, ws, capsys) for argv in RUNS["use the result"]]
    for name in ("commands.csv", "commands2.csv"):
        rows = [line for line in (ws / name).read_text().splitlines() if not line.startswith("#")][1:]
        assert len(rows) == 5 and all(row.endswith(",ok") for row in rows), rows
    assert (ws / "urdf" / "calibrated.urdf").exists() and (ws / "urdf" / "seven_axis.compliance.yaml").exists()
    assert "kuka_kr125_2" in printed[6] and "kr125_seed" in printed[7] and "T_W_n" in printed[9]
    assert "T_W_C" in printed[10] and printed[8].startswith("fgcal ")
    assert "URDF alone, rigid fit" in printed[4]
    assert "ok 5" in printed[-2] and (ws / "PALLET_cal.corrections.csv").exists()
    # --declarations: the FDATs' TOOL_DATA[1] and BASE_DATA[1] are the --tool and --base given above.
    tables = [[line.split(",")[4:] for line in (ws / f"{name}.corrections.csv").read_text().splitlines()
               if line[:1] not in ("#", "t")] for name in ("PALLET_cal", "FDAT_cal")]  # fmt: skip
    assert "ok 5" in printed[-1] and tables[0] == tables[1] and len(tables[0]) == 5
    assert "kinematics" in yaml.safe_load((ws / "urdf" / "ur10e_kinematics.yaml").read_text())
    assert (ws / "commands_mm.csv").read_text().startswith("# commands from fgcal compensate")
    assert "\ntarget,q1_deg," in (ws / "commands_mm.csv").read_text()
    assert "accuracy" in yaml.safe_load((ws / "urdf" / "rigid.compliance.yaml").read_text())
    assert "rigid fit" in printed[2] and "rigid fit" not in printed[-5]  # the default, and --no-rigid-fit
    assert "T_W_n" in printed[-4] and "arm.xacro with the calibrated joint origins" in printed[-3]


def test_online_as_documented(ws, capsys):
    (ws / "setup.yaml").write_text(f"dataset: {ws / 'seed'}\nsettings: {{window_images: 10}}\n")
    printed = [_run(argv, ws, capsys) for argv in RUNS["online"]]
    assert "wrote 20 measurement files" in printed[0] and "wrote 5 measurement files" in printed[3]
    assert json.loads((ws / "state" / "report.json").read_text())["n_images"] == 20


def test_demo_as_documented(ws, capsys):
    for argv in RUNS["demo"]:
        printed = _run(argv, ws, capsys)
        _check_writes(argv, ws)
        assert "compensation of 200 random targets" in printed
    report = json.loads((ws / "demo_tracker" / "report" / "report.json").read_text())
    assert report["formulation"] == "tracker" and report["compensation"]["improvement"] > 50
    for folder in ("demo", "demo_tracker"):
        assert_headline_is_the_reports(ws / folder / "report")


def assert_headline_is_the_reports(folder: Path) -> None:
    """report.md opens (after its title) with the headline, whose figures are report.json's."""
    from fgcal.reports.headline import figure

    headline = json.loads((folder / "report.json").read_text())["headline"]
    lines = (folder / "report.md").read_text().splitlines()
    assert lines[0].startswith("# Calibration report") and lines[2] == f"**{headline['text']}**", lines[:3]
    for label in ("after_m", "before_m"):
        for key in ("rms", "p95", "max"):
            assert figure(headline[label][key] * 1e3) in lines[2], (label, key)
    assert headline["after_m"]["rms"] < headline["before_m"]["rms"]


def test_import_convert_and_bench_as_documented(ws, capsys):
    mapping = {
        "format": "fgcal-import/1",
        "robot": "abb_irb120",
        "configurations": {"file": str(ws / "session" / "configurations.csv"), "config": "config",
                           "joints": [f"q{i}" for i in range(1, 7)]},
        "tracker_points": {"file": str(ws / "session" / "tracker_points.csv"), "config": "config",
                           "target": "target", "xyz": ["x", "y", "z"]},
    }  # fmt: skip
    (ws / "mapping.yaml").write_text(yaml.safe_dump(mapping))
    runs = RUNS["import"] if FARO.exists() else [a for a in RUNS["import"] if a[0] != "convert-faro"]
    for argv in runs:
        if argv[0] == "bench" and "--faro" in argv and not FARO.exists():
            argv = argv[: argv.index("--faro")]
        printed = _run(argv, ws, capsys)
        if "--kinematics" in argv:  # the kinematics alone, issue 37's targets stated (skipped without Pinocchio)
            targets = json.loads(printed)["kernel_targets"]
            assert set(targets) == {"rigid_batched", "rigid_single", "param_single"}
            pinocchio = importlib.util.find_spec("pinocchio") is not None
            assert (targets["rigid_single"]["met"] is None) != pinocchio and targets["param_single"]["value"] > 0
    bench = json.loads(printed)
    assert bench["sizes"]["20"]["cpu_s"]["fgcal"] > 0 and (FARO.exists() == ("faro_cpu_s" in bench))
    assert bench["demo_cpu_s"] > 0 and bench["memory_peak_rss_mb"] > 0 and bench["memory_n_configurations"] == 20
    assert bench["program_targets"] == [2, 40] and "program_to_csv_ratio" in bench  # 40 targets: timing noise
    assert bench["kernel_fk_param_jacobian_batched_us"] > 0 and bench["kernel_fk_joint_jacobian_single_us"] > 0
    assert (bench["pinocchio_fk_joint_jacobian_us"] is None) == (importlib.util.find_spec("pinocchio") is None)
    assert (ws / "imported" / "dataset.yaml").exists()


@pytest.mark.parametrize("cell", CELLS)
def test_every_bundled_cell_calibrates_with_the_config_simulate_writes(cell, bundled_sim, tmp_path, capsys):
    """Each bundled cell simulated (as fgcal simulate does: conftest.bundled_sim), then calibrated
    with the calibration.yaml written beside it: the declared noise explains the residuals (no
    noise warning), the held-out error against the truth is within 1.5x of its prediction and
    at least 50x below the nominal model's where the cell's geometry allows (seed 2)."""
    # What the geometry allows where it is less: the seed paper's 36-image design (its figures
    # need thousands of coordinates; 300 space-filling configurations give 200x, fgcal demo),
    # and a two-axis positioner under a static camera (the camera's pose and the board's
    # mounting absorb all but the axes' relative geometry and the compliances).
    least = {"kr125_seed": 20, "positioner_static_camera": 10}.get(cell, 50)
    printed = _run(["calibrate", str(bundled_sim(cell, 2) / "calibration.yaml"), "--out", str(tmp_path / "r"),
                    "--no-plots"], tmp_path, capsys)  # fmt: skip
    assert "declared noise explains" not in printed and "times larger" not in printed, printed
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["goodness_of_fit"]["consistent_with_declared_noise"]
    validation = report["validation"]
    assert validation["reference"] == "ground truth"
    before, after = (validation[k]["position_error_m"]["rms"] for k in ("before", "after"))
    # What the prediction says it assumes (fixed parameters the score sees), carried by its stated
    # effect (a lower bound) at their true deviations: dual_arm_selfcontained's base tilt (sy1 0.51
    # mrad off, 0.19 um per 0.1 mrad) takes it from 1.50x to 1.43x; 1.20x without the tilt.
    predicted, parameters = validation["predicted_position_sigma_m"], report["parameters"]
    deviation = {name: entry.get("truth", entry["estimate"]) - entry["estimate"] for name, entry in parameters.items()}
    spots = predicted["assumes_at_their_values"]
    assumed = sum((spot["effect_rms_m"] * deviation[spot["name"]] / spot["step"]) ** 2 for spot in spots)
    assert after <= 1.5 * np.sqrt(predicted["rms"] ** 2 + assumed), predicted
    assert after * least <= before, (before, after)


def test_two_measurement_sets_calibrate(bundled_sim, tmp_path, capsys):
    """The seed cell's camera and its tracker as two sets of one config (docs/calibration.md,
    "Several measurement sets"): it calibrates, the declared noise explains each set, the
    held-out error against the truth is within 1.5x of its prediction and 20x below the nominal
    model's, and the report gives each set."""
    config = tmp_path / "two_sets.yaml"
    config.write_text(yaml.safe_dump({"dataset": str(bundled_sim("kr125_seed", 2)), "sets": [
        {"name": "camera", "formulation": "pairs"}, {"name": "tracker", "formulation": "tracker"}]}))  # fmt: skip
    printed = _run(["calibrate", str(config), "--out", str(tmp_path / "r"), "--no-plots"], tmp_path, capsys)
    assert "set camera: pairs formulation, fit" in printed and "set tracker: tracker formulation, fit" in printed
    report = json.loads((tmp_path / "r" / "report.json").read_text())
    assert report["goodness_of_fit"]["consistent_with_declared_noise"]
    sets = {entry["name"]: entry for entry in report["sets"]["sets"]}
    assert set(sets) == {"camera", "tracker"} and all(0.7 < e["chi2_per_dof"] < 1.3 for e in sets.values()), sets
    tracker = sets["tracker"]  # against its held-out measurements, in its own unit
    assert tracker["held_out"]["after"]["tool_point_rms_m"] <= 1.5 * tracker["predicted_rms_m"], tracker
    validation = report["validation"]
    before, after = (validation[k]["position_error_m"]["rms"] for k in ("before", "after"))
    assert after <= 1.5 * validation["predicted_position_sigma_m"]["rms"], validation["predicted_position_sigma_m"]
    assert after * 20 <= before, (before, after)
    assert "## Measurement sets" in (tmp_path / "r" / "report.md").read_text()
    from fgcal.reports.estimates import load_estimates

    assert {"tracker/tracker", "tracker/tool_points"} <= set(load_estimates(tmp_path / "r" / "estimates.yaml"))


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), re.S)


DOCS_WITH_CODE = [p for p in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))] if _python_blocks(p)]


@pytest.fixture(scope="module")
def docs_workspace(tmp_path_factory) -> Path:
    """What the docs' examples read: calibration.yaml of a simulated tracker session (data/), and
    a camera session (camera_data/)."""
    from fgcal.simulation.simulate import simulate

    root = tmp_path_factory.mktemp("docs")
    simulate(REPO / "datasets" / "cells" / "irb120_tracker.yaml", root / "data", seed=1, n_configurations=40)
    (root / "calibration.yaml").write_text("dataset: data\nformulation: tracker\n")
    simulate(REPO / "datasets" / "cells" / "kr125_seed.yaml", root / "camera_data", seed=1)
    return root


@pytest.mark.parametrize("doc", DOCS_WITH_CODE, ids=[p.name for p in DOCS_WITH_CODE])
def test_the_docs_python_examples_run(doc, docs_workspace, tmp_path, monkeypatch, capsys):
    """A document's ```python blocks run in order, in one namespace, in a folder holding what
    they read (docs_workspace)."""
    for item in docs_workspace.iterdir():
        target = tmp_path / item.name
        (shutil.copytree if item.is_dir() else shutil.copy)(item, target)
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for i, block in enumerate(_python_blocks(doc)):
        try:
            exec(compile(block, f"{doc.name}, python block {i + 1}", "exec"), namespace)
        except Exception as exc:
            pytest.fail(f"{doc.name}, python block {i + 1}: {type(exc).__name__}: {exc}")
