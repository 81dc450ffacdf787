"""What reaches the robot is what the calibration found (issue 43): the statuses of compensated
targets and programs (item 5), the payload and frames they use (items 2 and 3), and the
assumptions each controller-facing file states (item 4). The calibrations here are the bundled
robots with a few parameters moved (a calibration's result, without the solve)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import fgcal
from fgcal.commands.cli import main
from fgcal.data.program_filter import WRITTEN, configurations
from fgcal.data.programs import format_krl_pose, format_rapid_pose, read_program
from fgcal.model.robot_io import save_robot


def _calibrated(folder: Path, name: str, moved: dict[str, float]) -> Path:
    """The bundled robot ``name`` with parameters moved by ``moved`` (added to their values)."""
    robot = fgcal.load_robot(name)
    values = robot.nominal_parameters()
    path = folder / f"{name}_calibrated.yaml"
    save_robot(path, robot, {key: float(values[key] + change) for key, change in moved.items()})
    return path


def _rows(path: Path) -> list[dict[str, str]]:
    """A CSV fgcal wrote, as its own reader reads it (comment lines first)."""
    from fgcal.data.dataset import read_csv

    header, body = read_csv(path, [])
    return [dict(zip(header, row, strict=True)) for row in body]


def _rapid(targets: list[tuple[str, np.ndarray, dict]], tool: str = "tool0", declarations: str = "") -> str:
    lines = ["MODULE M"]
    for name, T, c in targets:
        position, quaternion = format_rapid_pose(T)
        lines.append(f"  CONST robtarget {name}:=[{position},{quaternion},[{c['cf1']},{c['cf4']},{c['cf6']},"
                     f"{c['cfx']}],[9E9,9E9,9E9,9E9,9E9,9E9]];")  # fmt: skip
    lines += [declarations, "  PROC main()"] if declarations else ["  PROC main()"]
    lines += [f"    MoveJ {name}, v100, fine, {tool};" for name, _, _ in targets]
    return "\n".join([*lines, "  ENDPROC", "ENDMODULE", ""])


def _krl(targets: list[tuple[str, np.ndarray, dict]]) -> str:
    lines = ["DEFDAT P"]
    lines += [f"DECL E6POS {name}={{{format_krl_pose(T)},S {c['S']},T {c['T']}}}" for name, T, c in targets]
    return "\n".join([*lines, "ENDDAT", ""])


# -- item 5: statuses ------------------------------------------------------------------------------


def test_abbs_calibration_home_is_found(tmp_path, capsys):
    """ABB's calibration home (every joint 0, joint 5 too: joints 4 and 6 turn together) was
    "configuration not found": the controller's IK ended anywhere along that line, outside the
    quadrants cf4 and cf6 name. It is now corrected, on its own configuration."""
    robot_file = _calibrated(tmp_path, "abb_irb120", {"a2": 2e-4, "theta3": 3e-4, "theta5": 2e-4})
    nominal = fgcal.load_robot("abb_irb120")
    q = np.zeros((1, 6))
    (tmp_path / "home.mod").write_text(_rapid([("home", nominal.fk(q)[0], configurations(nominal, "rapid", q)[0])]))
    assert main(["compensate", str(robot_file), str(tmp_path / "home.mod"), "--out", str(tmp_path / "o.mod")]) == 0
    (row,) = _rows(tmp_path / "o.corrections.csv")
    assert row["status"] in WRITTEN and row["corrected"] == "yes", row
    assert abs(float(row["q4_deg"]) + float(row["q6_deg"])) < 1.0, row  # on the branch of the home's quadrants
    capsys.readouterr()


def test_a_kuka_turn_changed_is_said(tmp_path, capsys):
    """A4 at +0.05 deg (T bit 3 clear), corrected to -0.15 deg: T is rewritten, and the target's
    status says so (it was "ok")."""
    robot_file = _calibrated(tmp_path, "kuka_kr125_2", {"theta4": np.radians(0.2), "a2": 3e-4})
    nominal = fgcal.load_robot("kuka_kr125_2")
    q = np.radians([[10, -80, 100, 0.05, 40, 20]])
    (tmp_path / "p.dat").write_text(_krl([("XP1", nominal.fk(q)[0], configurations(nominal, "krl", q)[0])]))
    assert main(["compensate", str(robot_file), str(tmp_path / "p.dat"), "--out", str(tmp_path / "o.dat")]) == 0
    (row,) = _rows(tmp_path / "o.corrections.csv")
    assert row["status"] == "turn changed" and row["corrected"] == "yes", row
    assert read_program(tmp_path / "o.dat").targets[0].config == {"S": 2, "T": 2 | 8}
    printed = "".join(capsys.readouterr())  # the command's lines go to stdout, warnings too (not to logging's root)
    assert "new T (turn)" in printed, printed


def test_unreachable_rows_carry_no_commands(tmp_path, capsys):
    """An unreachable target's row has no joints and no command (they were the IK's last guess);
    --json's worst residual is of the compensated targets, the unreachable ones' gap apart."""
    (tmp_path / "t.csv").write_text("target,x,y,z\nnear,0.4,0.05,0.5\nfar,25,0,0\n")
    argv = ["compensate", "abb_irb120", str(tmp_path / "t.csv"), "--out", str(tmp_path / "o.csv"), "--json"]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    near, far = _rows(tmp_path / "o.csv")
    assert near["status"] == "ok" and all(near[c] for c in ("q1", "x_cmd", "z_cmd"))
    assert far["status"] == "unreachable" and float(far["residual_m"]) > 20
    assert all(far[c] == "" for c in ("q1", "q6", "x_cmd", "y_cmd", "z_cmd")), far
    assert out["residual_max_m"] < 1e-9 and out["unreachable_gap_max_m"] > 20, out


# -- item 2: the payload ---------------------------------------------------------------------------

COMPLIANT = {"ky2": 5e-5, "ky3": 5e-5, "ky5": 5e-5}  # rad/(N m): a tool's load sags the arm by tenths of a mm
LOAD_KG, LOAD_COM = 4.0, (0.0, 0.0, 0.1)


MIDDLE = {"ABB IRB 120": [0.3, 0.2, 0.2, 0.3, 0.8, 0.3], "KUKA KR 125/2": [0.3, -1.2, 1.4, 0.3, 0.8, 0.3]}


def _targets(robot, n: int = 6, seed: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Joints about a pose well inside the workspace (no singularity, no quadrant's edge), and
    the nominal flange there."""
    q = np.array(MIDDLE[robot.name]) + np.random.default_rng(seed).uniform(-0.25, 0.25, (n, robot.n_joints))
    return q, robot.fk(q)


def _table_figures(path: Path) -> dict[str, np.ndarray]:
    return {row["target"]: np.array([float(row[c]) for c in ("dx_mm", "dy_mm", "dz_mm")]) for row in _rows(path)}


def test_the_tools_load_stated_gives_the_tooldatas_corrections(tmp_path):
    """Stating the tool's own load with --payload-mass/--payload-com gives the corrections of the
    tooldata's tload (within 1 um): the base frame stays at the calibration's payload (before, it
    moved to the stated load, and the deflection was the tload's)."""
    robot_file = _calibrated(tmp_path, "abb_irb120", {**COMPLIANT, "a2": 2e-4})
    nominal = fgcal.load_robot("abb_irb120")
    q, poses = _targets(nominal)
    tool = f"PERS tooldata gun:=[TRUE,[[0,0,0],[1,0,0,0]],[{LOAD_KG},[0,0,{LOAD_COM[2] * 1e3}],[1,0,0,0],0,0,0]];"
    targets = [(f"p{k}", poses[k], c) for k, c in enumerate(configurations(nominal, "rapid", q))]
    (tmp_path / "p.mod").write_text(_rapid(targets, "gun", tool))
    out = str(tmp_path / "a.mod")
    assert main(["compensate", str(robot_file), str(tmp_path / "p.mod"), "--out", out]) == 0
    stated = ["--payload-mass", str(LOAD_KG), "--payload-com", *map(str, LOAD_COM)]
    argv = ["compensate", str(robot_file), str(tmp_path / "p.mod"), "--out", str(tmp_path / "b.mod"), *stated]
    assert main(argv) == 0
    tload, given = _table_figures(tmp_path / "a.corrections.csv"), _table_figures(tmp_path / "b.corrections.csv")
    assert max(np.abs(tload[k] - given[k]).max() for k in tload) <= 1e-3  # mm
    # The load matters: without it (the robot file's, none) the corrections differ by far more.
    (tmp_path / "plain.mod").write_text(_rapid(targets))
    assert main(["compensate", str(robot_file), str(tmp_path / "plain.mod"), "--out", str(tmp_path / "c.mod")]) == 0
    none = _table_figures(tmp_path / "c.corrections.csv")
    assert max(np.abs(tload[k] - none[k]).max() for k in tload) > 0.02  # mm


def test_a_krl_load_stated_is_the_rapid_tloads(tmp_path, caplog):
    """KRL has no tooldata: --payload-mass/--payload-com state the tool's load, and the .dat's
    corrections are those of the same targets in a RAPID module whose tooldata carries that load
    (within 1 um). What the command says of the load names no tooldata."""
    robot_file = _calibrated(tmp_path, "kuka_kr125_2", {**COMPLIANT, "a2": 5e-4})
    nominal = fgcal.load_robot("kuka_kr125_2")
    q, poses = _targets(nominal, seed=7)
    stated = ["--payload-mass", "60", "--payload-com", "0", "0", "0.25"]
    krl = [(f"XP{k}", poses[k], c) for k, c in enumerate(configurations(nominal, "krl", q))]
    (tmp_path / "p.dat").write_text(_krl(krl))
    argv = ["compensate", str(robot_file), str(tmp_path / "p.dat"), "--out", str(tmp_path / "k.dat"), *stated]
    assert main(argv) == 0
    assert "tooldata" not in caplog.text and "--payload-mass and --payload-com" in caplog.text, caplog.text
    caplog.clear()
    assert main(["compensate", str(robot_file), str(tmp_path / "p.dat"), "--out", str(tmp_path / "n.dat")]) == 0
    assert "tooldata" not in caplog.text, caplog.text  # KUKA users are told of --payload-*, not of tload
    tool = "PERS tooldata gun:=[TRUE,[[0,0,0],[1,0,0,0]],[60,[0,0,250],[1,0,0,0],0,0,0]];"
    rapid = [(f"XP{k}", poses[k], c) for k, c in enumerate(configurations(nominal, "rapid", q))]
    (tmp_path / "p.mod").write_text(_rapid(rapid, "gun", tool))
    assert main(["compensate", str(robot_file), str(tmp_path / "p.mod"), "--out", str(tmp_path / "r.mod")]) == 0
    dat, mod = _table_figures(tmp_path / "k.corrections.csv"), _table_figures(tmp_path / "r.corrections.csv")
    assert dat.keys() == mod.keys()
    assert max(np.abs(dat[k] - mod[k]).max() for k in dat) <= 1e-3  # mm


# -- item 3: a targets CSV's frame and --tcp ------------------------------------------------------


def _csv(path: Path, positions: np.ndarray, scale: float = 1.0) -> None:
    rows = "".join(f"t{k}," + ",".join(f"{v * scale:.17g}" for v in p) + "\n" for k, p in enumerate(positions))
    path.write_text("target,x,y,z\n" + rows)


def test_csv_targets_default_to_the_controllers_base_frame(tmp_path):
    """Like a program's, a CSV's targets are in the controller's base frame unless --targets-frame W
    says otherwise (it was W: on the FARO calibration the two differ by about 2 mm); the file says which."""
    robot_file = _calibrated(tmp_path, "abb_irb120", {"a2": 2e-3, "theta3": 3e-3})
    nominal = fgcal.load_robot("abb_irb120")
    _, poses = _targets(nominal)
    _csv(tmp_path / "t.csv", poses[:, :3, 3])
    runs = {"default": [], "controller": ["--targets-frame", "controller"], "W": ["--targets-frame", "W"]}
    tables = {}
    for name, extra in runs.items():
        out = tmp_path / f"{name}.csv"
        assert main(["compensate", str(robot_file), str(tmp_path / "t.csv"), "--out", str(out), *extra]) == 0
        tables[name] = np.array([[float(r[c]) for c in ("x_cmd", "y_cmd", "z_cmd")] for r in _rows(out)])
        header = [line for line in out.read_text().splitlines() if line.startswith("#")]
        frame = next(line for line in header if line.startswith("# frame:"))
        assert ("calibration's frame W" in frame.split(";")[0]) == (name == "W"), frame
    np.testing.assert_array_equal(tables["default"], tables["controller"])
    assert np.abs(tables["default"] - tables["W"]).max() > 1e-4  # the frames differ here by tenths of a mm


def test_tcp_follows_the_length_unit(tmp_path):
    """--tcp 0 0 100 with --length-unit mm is the TCP of --tcp 0 0 0.1 in m (it was read as 100 m)."""
    _, poses = _targets(fgcal.load_robot("abb_irb120"))
    _csv(tmp_path / "m.csv", poses[:, :3, 3])
    _csv(tmp_path / "mm.csv", poses[:, :3, 3], 1e3)
    base = ["compensate", "abb_irb120"]
    assert main([*base, str(tmp_path / "m.csv"), "--out", str(tmp_path / "m_out.csv"), "--tcp", "0", "0", "0.1"]) == 0
    assert main([*base, str(tmp_path / "mm.csv"), "--out", str(tmp_path / "mm_out.csv"), "--tcp", "0", "0", "100",
                 "--length-unit", "mm"]) == 0  # fmt: skip
    m = np.array([[float(r[c]) for c in ("x_cmd", "y_cmd", "z_cmd")] for r in _rows(tmp_path / "m_out.csv")])
    mm = np.array([[float(r[c]) for c in ("x_cmd_mm", "y_cmd_mm", "z_cmd_mm")] for r in _rows(tmp_path / "mm_out.csv")])
    np.testing.assert_allclose(mm * 1e-3, m, atol=1e-9)
    assert "TCP at (0, 0, 100) mm" in (tmp_path / "mm_out.csv").read_text()


def test_a_tcp_beyond_10_m_is_refused_in_any_unit(tmp_path, capsys):
    _csv(tmp_path / "mm.csv", np.array([[400.0, 0.0, 500.0]]))
    argv = ["compensate", "abb_irb120", str(tmp_path / "mm.csv"), "--out", str(tmp_path / "o.csv"), "--tcp", "0", "0",
            "10001", "--length-unit", "mm"]  # fmt: skip
    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert "--tcp" in error and "\n" not in error, error


# -- item 4: every controller-facing file states its assumptions -------------------------------------


def test_the_commands_csv_states_its_assumptions_and_reads_back(tmp_path):
    """The commands CSV opens with # lines (frame with the transform, tool, payload, units,
    approach); fgcal's reader skips them and reads the table as written."""
    from fgcal.data.dataset import read_csv

    _, poses = _targets(fgcal.load_robot("abb_irb120"))
    _csv(tmp_path / "t.csv", poses[:, :3, 3] * 1e3)
    argv = ["compensate", "abb_irb120", str(tmp_path / "t.csv"), "--out", str(tmp_path / "o.csv"), "--length-unit",
            "mm", "--angle-unit", "deg", "--payload-mass", "2"]  # fmt: skip
    assert main(argv) == 0
    text = (tmp_path / "o.csv").read_text()
    comments = [line for line in text.splitlines() if line.startswith("#")]
    for key in ("# frame:", "# tool:", "# payload:", "# units:", "# approach:"):
        assert any(line.startswith(key) for line in comments), (key, comments)
    assert "origin (" in text and "rotation vector (" in text  # the controller's base frame in W
    assert "deflection at 2 kg" in text and "lengths mm, angles deg" in text
    header, body = read_csv(tmp_path / "o.csv", ["target", "q1_deg", "x_cmd_mm", "status"])
    assert len(body) == len(poses) and all(row[header.index("status")] == "ok" for row in body)


@pytest.mark.parametrize("kind", ["rapid", "krl"])
def test_a_corrected_program_states_its_assumptions_and_reads_back(tmp_path, kind):
    """The corrected program carries the header in its own comments (RAPID !, KRL ;) after its
    MODULE or DEFDAT line; fgcal reads it back with the targets as corrected; the table's lines
    are the corrected program's; and a corrected program is refused a second correction."""
    name = "abb_irb120" if kind == "rapid" else "kuka_kr125_2"
    robot_file = _calibrated(tmp_path, name, {"a2": 3e-4})
    nominal = fgcal.load_robot(name)
    q, poses = _targets(nominal)
    targets = [(f"p{k}", poses[k], c) for k, c in enumerate(configurations(nominal, kind, q))]
    suffix, mark = (".mod", "!") if kind == "rapid" else (".dat", ";")
    (tmp_path / f"p{suffix}").write_text(_rapid(targets) if kind == "rapid" else _krl(targets))
    out = tmp_path / f"o{suffix}"
    assert main(["compensate", str(robot_file), str(tmp_path / f"p{suffix}"), "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert lines[1].startswith(f"{mark} corrected by fgcal compensate"), lines[:3]
    assert all(len(line) <= 100 for line in lines if line.startswith(mark))
    program = read_program(out)
    assert [t.name for t in program.targets] == [name for name, _, _ in targets]
    for row, target in zip(_rows(tmp_path / "o.corrections.csv"), program.targets, strict=True):
        assert int(row["line"]) == target.line and row["corrected"] == "yes"
        dx = np.array([float(row[c]) for c in ("dx_mm", "dy_mm", "dz_mm")]) * 1e-3
        original = poses[int(target.name[1:])]
        np.testing.assert_allclose(target.pose[:3, 3] - original[:3, 3], dx, atol=1e-6)
    again = main(["compensate", str(robot_file), str(out), "--out", str(tmp_path / f"twice{suffix}")])
    assert again == 2 and not (tmp_path / f"twice{suffix}").exists()


def test_inline_targets_of_the_src_beside_a_dat_are_listed(tmp_path, capsys):
    """KRL: the .dat is corrected; motions of the .src beside it whose target is written inline
    (LIN {X ...}) are not, and were skipped without a word: the warning lists their lines
    (an axis-specific PTP {A1 ...} is no Cartesian target and is not listed)."""
    robot_file = _calibrated(tmp_path, "kuka_kr125_2", {"a2": 3e-4})
    nominal = fgcal.load_robot("kuka_kr125_2")
    q = np.radians([[10, -80, 100, 5, 40, 20]])
    (tmp_path / "P.dat").write_text(_krl([("XP1", nominal.fk(q)[0], configurations(nominal, "krl", q)[0])]))
    (tmp_path / "p.src").write_text(  # KUKA's names are not case-sensitive: P.dat goes with p.src
        "DEF P()\nPTP {A1 0,A2 -90,A3 90,A4 0,A5 0,A6 0}\nPTP XP1\nLIN {X 1500,Y 0,Z 1500,A 0,B 90,C 0} C_DIS\n"
        "; LIN {X 1,Y 2,Z 3} a comment\nSLIN {E6POS: X 1400,Y 10,Z 1500,A 0,B 90,C 0}\nEND\n"
    )
    assert main(["compensate", str(robot_file), str(tmp_path / "P.dat"), "--out", str(tmp_path / "o.dat")]) == 0
    printed = "".join(capsys.readouterr())
    assert "p.src beside it has 2 motions with a target written inline ({X ...}; lines 4, 6)" in printed, printed


def test_payload_com_follows_the_length_unit(tmp_path, capsys):
    """--payload-com is in --length-unit, as --tcp is (it stayed in m with --length-unit mm, and
    a centre of mass typed in mm read as metres); one beyond the arm's reach is refused."""
    robot_file = _calibrated(tmp_path, "abb_irb120", {**COMPLIANT, "a2": 2e-4})
    nominal = fgcal.load_robot("abb_irb120")
    _, poses = _targets(nominal)
    rows = [(f"p{k}", T[:3, 3]) for k, T in enumerate(poses)]
    (tmp_path / "m.csv").write_text(
        "target,x,y,z\n" + "".join(f"{n},{x:.9f},{y:.9f},{z:.9f}\n" for n, (x, y, z) in rows)
    )
    (tmp_path / "mm.csv").write_text(
        "target,x,y,z\n" + "".join(f"{n},{x * 1e3:.6f},{y * 1e3:.6f},{z * 1e3:.6f}\n" for n, (x, y, z) in rows)
    )
    base = ["compensate", str(robot_file), "--payload-mass", str(LOAD_KG)]
    assert main([*base, str(tmp_path / "m.csv"), "--out", str(tmp_path / "o_m.csv"), "--payload-com", "0", "0",
                 "0.1"]) == 0  # fmt: skip
    assert main([*base, str(tmp_path / "mm.csv"), "--out", str(tmp_path / "o_mm.csv"), "--length-unit", "mm",
                 "--payload-com", "0", "0", "100"]) == 0  # fmt: skip
    in_m, in_mm = _rows(tmp_path / "o_m.csv"), _rows(tmp_path / "o_mm.csv")
    for a, b in zip(in_m, in_mm, strict=True):
        assert abs(float(a["x_cmd"]) * 1e3 - float(b["x_cmd_mm"])) < 1e-3 and a["status"] == b["status"] == "ok"
    assert "centre of mass (0, 0, 100) mm" in "".join(capsys.readouterr())
    (tmp_path / "p.mod").write_text(_rapid([("p0", poses[0], configurations(nominal, "rapid", np.zeros((1, 6)))[0])]))
    assert main([*base, str(tmp_path / "p.mod"), "--out", str(tmp_path / "o.mod"), "--payload-com", "0", "0",
                 "8"]) == 2  # fmt: skip
    assert "beyond the arm's reach" in capsys.readouterr().err


def _module(targets, moves: list[str], declarations: str) -> str:
    lines = ["MODULE M", declarations]
    for name, T, c in targets:
        position, quaternion = format_rapid_pose(T)
        lines.append(f"  CONST robtarget {name}:=[{position},{quaternion},[{c['cf1']},{c['cf4']},{c['cf6']},"
                     f"{c['cfx']}],[9E9,9E9,9E9,9E9,9E9,9E9]];")  # fmt: skip
    return "\n".join([*lines, "  PROC main()", *[f"    {m}" for m in moves], "  ENDPROC", "ENDMODULE", ""])


def test_each_target_takes_its_own_tools_load(tmp_path, capsys):
    """Targets moved with tools of different loads each get their own tool's deflection (they
    were refused, with advice to filter with one --tool that then applied to every target), a
    RAPID \\TLoad replaces its tool's load (it was ignored: 0.9 mm on a 5 kg load), and a tool
    with no load data (tool0; KUKA's M -1) takes the robot file's payload (it took another
    tool's). Each target's corrections are those of the same target alone with its load stated."""
    robot_file = _calibrated(tmp_path, "abb_irb120", {**COMPLIANT, "a2": 2e-4})
    nominal = fgcal.load_robot("abb_irb120")
    q, poses = _targets(nominal, n=3)
    targets = [(f"p{k}", poses[k], c) for k, c in enumerate(configurations(nominal, "rapid", q))]
    declarations = ("  PERS tooldata gun:=[TRUE,[[0,0,0],[1,0,0,0]],[2,[0,0,50],[1,0,0,0],0,0,0]];\n"
                    "  PERS loaddata heavy:=[5,[0,0,100],[1,0,0,0],0,0,0];")  # fmt: skip
    moves = ["MoveJ p0, v100, fine, gun;", "MoveJ p1, v100\\T:=5, fine, gun\\TLoad:=heavy;",
             "MoveJ p2, v100, fine, tool0;"]
    (tmp_path / "mixed.mod").write_text(_module(targets, moves, declarations))
    assert main(["compensate", str(robot_file), str(tmp_path / "mixed.mod"), "--out", str(tmp_path / "m.mod")]) == 0
    mixed = _table_figures(tmp_path / "m.corrections.csv")
    header = " ".join(line[1:].strip() for line in (tmp_path / "m.mod").read_text().splitlines() if line[:1] == "!")
    assert "each target's tool's load" in header and "loaddata heavy (\\TLoad) 5 kg" in header, header
    alone = {"p0": ("2", ["0", "0", "0.05"]), "p1": ("5", ["0", "0", "0.1"]), "p2": ("0", ["0", "0", "0"])}
    for k, (name, (mass, com)) in enumerate(alone.items()):
        (tmp_path / f"{name}.mod").write_text(_module([targets[k]], [f"MoveJ {name}, v100, fine, tool0;"], ""))
        argv = ["compensate", str(robot_file), str(tmp_path / f"{name}.mod"), "--out", str(tmp_path / f"a{k}.mod"),
                "--payload-mass", mass, "--payload-com", *com]  # fmt: skip
        assert main(argv) == 0
        np.testing.assert_allclose(mixed[name], _table_figures(tmp_path / f"a{k}.corrections.csv")[name], atol=1e-3)
    # The load matters: p1 with its tool's 2 kg rather than the \TLoad's 5 kg lands elsewhere.
    argv = ["compensate", str(robot_file), str(tmp_path / "p1.mod"), "--out", str(tmp_path / "g.mod"),
            "--payload-mass", "2", "--payload-com", "0", "0", "0.05"]  # fmt: skip
    assert main(argv) == 0
    assert np.abs(mixed["p1"] - _table_figures(tmp_path / "g.corrections.csv")["p1"]).max() > 0.005  # mm
    capsys.readouterr()


def test_a_kuka_tool_without_load_data_takes_the_robot_files_payload(tmp_path, capsys):
    """$config.dat: TOOL_DATA[2] with LOAD_DATA[2] M -1 (KUKA's "no load data") beside a 50 kg
    tool 1: XP2 is corrected at the robot file's payload (it took tool 1's 50 kg: 1.6 mm)."""
    robot_file = _calibrated(tmp_path, "kuka_kr125_2", {**COMPLIANT, "a2": 5e-4})
    nominal = fgcal.load_robot("kuka_kr125_2")
    q, poses = _targets(nominal, n=2, seed=7)
    krl = _krl([(f"XP{k + 1}", poses[k], c) for k, c in enumerate(configurations(nominal, "krl", q))])
    fdat = "DECL FDAT FP1={TOOL_NO 1,BASE_NO 0}\nDECL FDAT FP2={TOOL_NO 2,BASE_NO 0}\nENDDAT"
    (tmp_path / "p.dat").write_text(krl.replace("ENDDAT", fdat))
    (tmp_path / "c.dat").write_text(
        "TOOL_DATA[1]={X 0,Y 0,Z 0,A 0,B 0,C 0}\nTOOL_DATA[2]={X 0,Y 0,Z 0,A 0,B 0,C 0}\n"
        "LOAD_DATA[1]={M 50,CM {X 0,Y 0,Z 250,A 0,B 0,C 0},J {X 0,Y 0,Z 0}}\n"
        "LOAD_DATA[2]={M -1,CM {X 0,Y 0,Z 0,A 0,B 0,C 0},J {X 0,Y 0,Z 0}}\n"
    )
    argv = ["compensate", str(robot_file), str(tmp_path / "p.dat"), "--out", str(tmp_path / "o.dat"),
            "--declarations", str(tmp_path / "c.dat")]  # fmt: skip
    assert main(argv) == 0
    both = _table_figures(tmp_path / "o.corrections.csv")
    (tmp_path / "p2.dat").write_text(_krl([("XP2", poses[1], configurations(nominal, "krl", q)[1])]))
    assert main(["compensate", str(robot_file), str(tmp_path / "p2.dat"), "--out", str(tmp_path / "o2.dat")]) == 0
    np.testing.assert_allclose(both["XP2"], _table_figures(tmp_path / "o2.corrections.csv")["XP2"], atol=1e-3)
    header = " ".join(line[1:].strip() for line in (tmp_path / "o.dat").read_text().splitlines() if line[:1] == ";")
    assert "LOAD_DATA[1] 50 kg" in header and "the robot file's payload" in header, header
    capsys.readouterr()


def test_a_program_of_another_robot_is_said(tmp_path, capsys):
    """An IRB 120 module compensated with the KR 125: no target is reached on its configuration,
    and the command says so rather than only counting statuses."""
    nominal = fgcal.load_robot("abb_irb120")
    q, poses = _targets(nominal, n=2)
    (tmp_path / "p.mod").write_text(_rapid([(f"p{k}", poses[k], c) for k, c in
                                            enumerate(configurations(nominal, "rapid", q))]))  # fmt: skip
    assert main(["compensate", "kuka_kr125_2", str(tmp_path / "p.mod"), "--out", str(tmp_path / "o.mod")]) == 0
    assert "none of the 2 targets was corrected" in "".join(capsys.readouterr())
