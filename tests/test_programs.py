"""Robot programs (fgcal.data.programs): RAPID modules and KRL .dat files read, and written back with
corrected targets, every character outside the targets' values kept."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgcal.core.errors import InputError
from fgcal.core.se3 import pose, pose_from_xyz_rpy, quaternion_rotation, rot_axis, so3_exp, so3_log
from fgcal.data.programs import Program, format_krl_pose, format_rapid_pose, krl_abc_deg, read_program, write_program

EXTAX = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
RAPID_HEAD = f"""MODULE CellA
    ! Calibration test module: "quotes" and a robtarget in comments are not targets
    PERS tooldata tGripper := [TRUE, [[10.5, -2, 150], [0.7071068, 0, 0.7071068, 0]],
        [2.5, [0, 0, 75], [1, 0, 0, 0], 0, 0, 0]];
    TASK PERS wobjdata wTable := [FALSE, TRUE, "", [[1000, 0, 500], [1, 0, 0, 0]],
        [[10, 20, 0], [0.7071068, 0, 0, 0.7071068]]];
    CONST string sNote := "Stop! CONST robtarget pFake := [[0,0,0],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];";
    ! CONST robtarget pOld := [[1,2,3],[1,0,0,0],[0,0,0,0],{EXTAX}];
    CONST robtarget p10 := [[500,0,800],[0.7071068,0,0.7071068,0],[0,0,0,0],{EXTAX}];
    LOCAL PERS robtarget p20:=[[.5,-1.,+3],[1,0,0,0],[-1,0,-1,1],[9E9,9E9,9E9,9E9,9E9,9E9]];
    CONST robtarget p30 :=
        [[600, 100, 700], [0, 0, 1, 0], [0, -1, 2, 0], [9E+09, 9E+09, 9E+09, 9E+09, 9E+09, 9E+09]];
    const RobTarget p40 := [[ 1.5E2 , -2.5e+1 , 300 ] , [ -0.5 , 0.5 , -0.5 , 0.5 ] , [ 1 , 0 , 0 , 0 ] , {EXTAX}] ; ! x
    TASK PERS robtarget p50 := [[100,200,300],[1,0,0,0],[0,0,0,0],[10,9E9,9E9,9E9,9E9,9E9]];
    VAR robtarget p60 := [[-100,-200,
        -300],[0.9999999,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
    VAR jointtarget jHome := [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]];
    VAR robtarget pTemp;
"""
RAPID_TAIL = f"""
    PROC main()
        MoveAbsJ jHome, v1000, fine, tool0;
        MoveJ p10, v1000, z50, tGripper\\WObj:=wTable;
        MoveL p20, v100, fine, tool0;
        MoveC p30, p40, v200, z10, tGripper \\WObj:=wTable;
        MoveL Offs(p50, 0, 0, 100), v100, z10, tGripper\\WObj:=wTable;
        MoveL [[1,2,3],[1,0,0,0],[0,0,0,0],{EXTAX}], v100, fine, tool0;
        MoveL p10, v100, fine, tool0; ! a second use: the first one counts
        MoveL \\Conc, p60, v100 \\T:=2, z10, tGripper \\WObj:=wTable;
        moveJ P70, v500, z10, tool0;
        TPWrite "Done! MoveL p80, v100, fine, tGripper;";
    ENDPROC

    PROC approach(VAR robtarget pTarget)
        MoveL RelTool(pTarget, 0, 0, -50), v100, fine, tool0;
    ENDPROC
ENDMODULE
"""
STORAGE = ("CONST", "PERS", "LOCAL CONST", "TASK PERS", "VAR", "LOCAL VAR")


def _generated_robtargets() -> str:
    lines = []
    for k in range(14):
        half = math.radians(5 * k)
        quat = f"[{math.cos(half):.9f},0,0,{math.sin(half):.9f}]"
        trans = f"[{400 + 10 * k},{-50 + 7 * k},{600 - 3 * k}.25]"
        conf = f"[{k % 4 - 1},0,{k % 3},0]"
        split = "\n        " if k % 3 == 0 else ""
        lines.append(f"    {STORAGE[k % 6]} robtarget p{70 + 10 * k} := {split}[{trans},{quat},{conf},{EXTAX}];")
    return "\n".join(lines)


RAPID = RAPID_HEAD + _generated_robtargets() + RAPID_TAIL

KRL_HEAD = """&ACCESS RVP
&REL 3
&PARAM TEMPLATE = C:\\KRC\\Roboter\\Template\\vorgabe
DEFDAT  CELLA
;FOLD EXTERNAL DECLARATIONS;%{PE}%MKUKATPBASIS,%CEXT,%VCOMMON,%P
EXT  BAS (BAS_COMMAND  :IN,REAL  :IN )
;ENDFOLD (EXTERNAL DECLARATIONS)
DECL BASIS_SUGG_T LAST_BASIS={POINT1[] "P0       ",POINT2[] "P0    "}
DECL E6POS XP1={X 1200.5,Y -50,Z 900,A 90,B 0,C 0,S 2,T 10,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
DECL FDAT FP1={TOOL_NO 1,BASE_NO 0,IPO_FRAME #BASE,POINT2[] " ; not a comment",TQ_STATE FALSE}
DECL PDAT PPDAT1={VEL 100.000,ACC 100.000,APO_DIST 100.000,APO_MODE #CDIS}
DECL LDAT LCPDAT1={VEL 2.0,ACC 100.0,APO_DIST 100.0,APO_FAC 50.0,ORI_TYP #VAR,CIRC_TYP #BASE,JERK_FAC 50.0}
DECL E6AXIS XHOME={A1 0.0,A2 -90.0,A3 90.0,A4 0.0,A5 0.0,A6 0.0,E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}
DECL POS XP2={X 100,Y 0,Z 0,A 0,B 90,C 0,S 'B110',T 'B011011'}   ; binary S and T
; DECL E6POS XOLD={X 1,Y 2,Z 3,A 0,B 0,C 0}
GLOBAL DECL E6POS XP3={Y 10,X 20,Z 30,C 180,B 0,A 0}
e6pos XP4 = { X 1.5E+02 , Y -2.5e1 , Z .5 , A -45 , B 30 , C 60 , S 6 , T 27 }
DECL E6POS XP5={E6POS: X 1,Y 2,Z 3,A 10,B 20,C 30,S 2,T 'H1A'}
DECL AXIS XAX={A1 0,A2 -90,A3 90,A4 0,A5 0,A6 0}
"""


def _generated_krl() -> str:
    lines = []
    for k in range(6, 21):
        xyz = f"X {800 + 11 * k}.5,Y {-300 + 23 * k},Z {1000 - 17 * k}"
        abc = f"A {-170 + 19 * k},B {-80 + 9 * k}.125,C {175 - 21 * k}"
        st = ("", f",S {k % 8},T {k}", f",S 'B{k % 8:03b}',T 'B{k:06b}'")[k % 3]
        kind = "POS" if k % 4 == 0 else "E6POS"
        extra = ",E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0" if kind == "E6POS" else ""
        lines.append(f"DECL {kind} XP{k}={{{xyz},{abc}{st}{extra}}} ; point {k}")
        lines.append(f'DECL FDAT FP{k}={{TOOL_NO 1,BASE_NO 2,IPO_FRAME #BASE,POINT2[] " "}}')
        lines.append(f"DECL PDAT PPDAT{k}={{VEL 100,ACC 100,APO_DIST 100}}")
    return "\n".join(lines) + "\n"


KRL = KRL_HEAD + _generated_krl() + "ENDDAT\n"


def _read(tmp_path, text: str, name: str) -> Program:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return read_program(path)


def _rotation_error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(so3_log(a[:3, :3].T @ b[:3, :3])))


def _outside_spans(program: Program) -> list[str]:
    """The text between the targets' values."""
    spans = sorted(span for target in program.targets for span in target.spans.values())
    pieces, at = [], 0
    for start, end in spans:
        pieces.append(program.text[at:start])
        at = end
    return [*pieces, program.text[at:]]


def _declaration_text(program: Program, name: str) -> str:
    target = next(t for t in program.targets if t.name == name)
    return program.text[min(s for s, _ in target.spans.values()) : max(e for _, e in target.spans.values())]


def _by_name(program: Program) -> dict:
    return {target.name: target for target in program.targets}


# ---------------------------------------------------------------------------------------------
# Reading


def test_rapid_targets_read(tmp_path):
    program = _read(tmp_path, RAPID, "cell.mod")
    assert program.kind == "rapid"
    names = [t.name for t in program.targets]
    assert names == ["p10", "p20", "p30", "p40", "p50", "p60"] + [f"p{70 + 10 * k}" for k in range(14)]
    t = _by_name(program)
    np.testing.assert_allclose(t["p10"].pose, pose(rot_axis("y", math.pi / 2), [0.5, 0.0, 0.8]), atol=1e-12)
    np.testing.assert_allclose(t["p20"].pose, pose(np.eye(3), [0.0005, -0.001, 0.003]), atol=1e-12)
    np.testing.assert_allclose(t["p30"].pose[:3, :3], rot_axis("y", math.pi), atol=1e-12)
    axis = np.array([-1.0, 1.0, -1.0]) / math.sqrt(3)  # q = -(0.5, -0.5, 0.5, -0.5): 120 deg about axis
    np.testing.assert_allclose(t["p40"].pose, pose(so3_exp(axis * 2 * math.pi / 3), [0.15, -0.025, 0.3]), atol=1e-12)
    np.testing.assert_allclose(t["p60"].pose, pose(np.eye(3), [-0.1, -0.2, -0.3]), atol=1e-12)
    p100 = pose(rot_axis("z", math.radians(30)), [0.43, -0.029, 0.59125])
    np.testing.assert_allclose(t["p100"].pose, p100, atol=1e-9)
    assert t["p20"].config == {"cf1": -1, "cf4": 0, "cf6": -1, "cfx": 1}
    assert t["p30"].config == {"cf1": 0, "cf4": -1, "cf6": 2, "cfx": 0}
    assert t["p10"].line == 9 and t["p30"].line == 11 and t["p60"].line == 15


def test_rapid_tools_and_work_objects(tmp_path):
    program = _read(tmp_path, RAPID, "cell.mod")
    uses = {t.name: (t.tool, t.work_object) for t in program.targets}
    assert uses["p10"] == ("tGripper", "wTable")  # MoveJ; the later MoveL with tool0 does not count
    assert uses["p20"] == ("tool0", None)
    assert uses["p30"] == uses["p40"] == ("tGripper", "wTable")  # MoveC's two targets
    assert uses["p50"] == ("tGripper", "wTable")  # through Offs(p50, ...)
    assert uses["p60"] == ("tGripper", "wTable")  # after \Conc and with \T:=2
    assert uses["p70"] == ("tool0", None)  # RAPID names are case-insensitive: P70
    assert uses["p80"] == (None, None)  # only in a string
    tool = program.tools["tGripper"]
    np.testing.assert_allclose(tool.tcp, pose(rot_axis("y", math.pi / 2), [0.0105, -0.002, 0.15]), atol=1e-12)
    assert tool.mass_kg == 2.5 and tool.robhold is True
    np.testing.assert_allclose(tool.cog_m, [0.0, 0.0, 0.075])
    wobj = program.work_objects["wTable"]
    np.testing.assert_allclose(wobj, pose(rot_axis("z", math.pi / 2), [1.01, 0.02, 0.5]), atol=1e-12)
    assert set(program.tools) == {"tGripper"} and set(program.work_objects) == {"wTable"}


def test_krl_targets_read(tmp_path):
    program = _read(tmp_path, KRL, "cell.dat")
    assert program.kind == "krl" and program.tools == {} and program.work_objects == {}
    assert [t.name for t in program.targets] == [f"XP{k}" for k in range(1, 21)]
    t = _by_name(program)
    np.testing.assert_allclose(t["XP1"].pose, pose(rot_axis("z", math.pi / 2), [1.2005, -0.05, 0.9]), atol=1e-12)
    np.testing.assert_allclose(t["XP2"].pose, pose(rot_axis("y", math.pi / 2), [0.1, 0, 0]), atol=1e-12)
    np.testing.assert_allclose(t["XP3"].pose, pose(rot_axis("x", math.pi), [0.02, 0.01, 0.03]), atol=1e-12)
    expected = rot_axis("z", math.radians(-45)) @ rot_axis("y", math.radians(30)) @ rot_axis("x", math.radians(60))
    np.testing.assert_allclose(t["XP4"].pose, pose(expected, [0.15, -0.025, 0.0005]), atol=1e-12)
    assert t["XP1"].config == {"S": 2, "T": 10}
    assert t["XP2"].config == {"S": 6, "T": 27}  # 'B110', 'B011011'
    assert t["XP3"].config == {}
    assert t["XP4"].config == {"S": 6, "T": 27}
    assert t["XP5"].config == {"S": 2, "T": 26}  # 'H1A'
    assert t["XP7"].config == {"S": 7, "T": 7} and t["XP8"].config == {"S": 0, "T": 8} and t["XP6"].config == {}
    assert t["XP1"].line == 9
    # Each target's FDAT (FP1 for XP1) names its tool and base: TOOL_NO 1, BASE_NO 0 (the base frame).
    assert (t["XP1"].tool, t["XP1"].work_object) == ("TOOL_DATA[1]", None)
    assert (t["XP6"].tool, t["XP6"].work_object) == ("TOOL_DATA[1]", "BASE_DATA[2]")
    assert (t["XP2"].tool, t["XP2"].work_object) == (None, None)  # no FDAT FP2


def test_crlf_and_latin1_files_read_as_the_same_program(tmp_path):
    lf = _read(tmp_path, RAPID, "lf.mod")
    crlf = _read(tmp_path, RAPID.replace("\n", "\r\n"), "crlf.MOD")
    assert crlf.text.count("\r\n") == RAPID.count("\n")
    for a, b in zip(lf.targets, crlf.targets, strict=True):
        assert (a.name, a.line, a.config, a.tool) == (b.name, b.line, b.config, b.tool)
        np.testing.assert_array_equal(a.pose, b.pose)
    path = tmp_path / "umlaut.dat"
    path.write_bytes(("; Punkt anfahren \xe4\xf6\xfc\n" + KRL).encode("latin-1"))
    program = read_program(path)
    assert program.encoding == "latin-1" and len(program.targets) == 20
    assert write_program(program, {}).encode(program.encoding) == path.read_bytes()


# ---------------------------------------------------------------------------------------------
# Writing


def _small_motion(rng: np.random.Generator) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    shift = rng.normal(size=3)
    shift *= rng.uniform(0, 2e-3) / np.linalg.norm(shift)
    return pose(so3_exp(axis * math.radians(rng.uniform(0, 0.2))), shift)


def _corrections(program: Program, seed: int) -> dict[str, tuple[np.ndarray, dict[str, int]]]:
    """Every target but each fourth moved by a small rigid motion; some configs changed."""
    rng = np.random.default_rng(seed)
    corrected = {}
    for i, target in enumerate(program.targets):
        if i % 4 == 3:
            continue
        config = dict(target.config)
        if i % 3 == 0 and "cf1" in config:
            config["cf1"] += 1
            config["cfx"] = 7
        elif i % 3 == 0 and "S" in config:
            config["S"] = (config["S"] + 1) % 8
            config["T"] ^= 5
        corrected[target.name] = (target.pose @ _small_motion(rng), config)
    return corrected


VARIANTS = [("cell.mod", RAPID), ("crlf.mod", RAPID.replace("\n", "\r\n"))]
VARIANTS += [("cell.dat", KRL), ("crlf.dat", KRL.replace("\n", "\r\n"))]


@pytest.mark.parametrize(("name", "text"), VARIANTS)
def test_write_corrected_changes_only_the_values(tmp_path, name, text):
    program = _read(tmp_path, text, name)
    corrected = _corrections(program, seed=len(name) + len(text))
    new_text = write_program(program, corrected)
    again = _read(tmp_path, new_text, "again" + program.path.suffix)
    assert [t.name for t in again.targets] == [t.name for t in program.targets]
    assert _outside_spans(again) == _outside_spans(program)
    if "crlf" in name:
        assert new_text.count("\n") == new_text.count("\r\n") == text.count("\n")
    for old, new in zip(program.targets, again.targets, strict=True):
        if old.name not in corrected:
            assert _declaration_text(again, new.name) == _declaration_text(program, old.name)
            np.testing.assert_array_equal(new.pose, old.pose)
            continue
        wanted, config = corrected[old.name]
        assert np.max(np.abs(new.pose[:3, 3] - wanted[:3, 3])) < 1e-6
        assert _rotation_error(new.pose, wanted) < 1e-6
        assert new.config == config
        assert (new.tool, new.work_object) == (old.tool, old.work_object)


def test_config_written_in_its_style(tmp_path):
    program = _read(tmp_path, KRL, "cell.dat")
    t = _by_name(program)
    new_text = write_program(program, {"XP2": (t["XP2"].pose, {"S": 1, "T": 2}), "XP4": (t["XP4"].pose, {"S": 7})})
    assert "S 'B001',T 'B000010'" in new_text and "S 7 , T 27 }" in new_text
    again = _by_name(_read(tmp_path, new_text, "again.dat"))
    assert again["XP2"].config == {"S": 1, "T": 2} and again["XP4"].config == {"S": 7, "T": 27}
    rapid = _read(tmp_path, RAPID, "cell.mod")
    p20 = _by_name(rapid)["p20"]
    new_text = write_program(rapid, {"p20": (p20.pose, {"cf4": 3})})
    assert "[[0.500,-1.000,3.000],[1.000000000,0.000000000,0.000000000,0.000000000],[-1,3,-1,1]," in new_text


@pytest.mark.parametrize(("name", "text"), [("cell.mod", RAPID), ("cell.dat", KRL)])
def test_identity_round_trip(tmp_path, name, text):
    program = _read(tmp_path, text, name)
    identity = {t.name: (t.pose, dict(t.config)) for t in program.targets}
    new_text = write_program(program, identity)
    assert new_text != text  # the values are reformatted
    again = _read(tmp_path, new_text, "again" + program.path.suffix)
    assert _outside_spans(again) == _outside_spans(program)
    for old, new in zip(program.targets, again.targets, strict=True):
        assert np.max(np.abs(new.pose[:3, 3] - old.pose[:3, 3])) <= 5e-7
        assert _rotation_error(new.pose, old.pose) < 1e-6
        assert new.config == old.config
    assert write_program(again, {t.name: (t.pose, t.config) for t in again.targets}) == new_text  # a fixed point


def test_rapid_quaternion_keeps_the_original_sign(tmp_path):
    program = _read(tmp_path, RAPID, "cell.mod")
    p40 = _by_name(program)["p40"]
    new_text = write_program(program, {"p40": (p40.pose, p40.config)})
    assert "[ -0.500000000 , 0.500000000 , -0.500000000 , 0.500000000 ]" in new_text
    trans, rot = format_rapid_pose(p40.pose, near=np.array([-0.5, 0.5, -0.5, 0.5]))
    assert (trans, rot) == ("[150.000,-25.000,300.000]", "[-0.500000000,0.500000000,-0.500000000,0.500000000]")
    np.testing.assert_allclose(quaternion_rotation(np.array([-0.5, 0.5, -0.5, 0.5])), p40.pose[:3, :3], atol=1e-12)


def test_krl_gimbal_lock_writes_c_zero(tmp_path):
    for b_deg in (90.0, -90.0):
        R = rot_axis("z", 0.3) @ rot_axis("y", math.radians(b_deg)) @ rot_axis("x", 0.2)
        a, b, c = krl_abc_deg(R)
        assert c == 0.0 and b == b_deg
        assert _rotation_error(pose_from_xyz_rpy(np.zeros(3), np.radians([c, b, a])), pose(R, np.zeros(3))) < 1e-12
    program = _read(tmp_path, KRL, "cell.dat")
    xp2 = _by_name(program)["XP2"]
    assert format_krl_pose(xp2.pose) == "X 100.000,Y 0.000,Z 0.000,A 0.00000,B 90.00000,C 0.00000"
    new_text = write_program(program, {"XP2": (xp2.pose, xp2.config)})
    assert "DECL POS XP2={X 100.000,Y 0.000,Z 0.000,A 0.00000,B 90.00000,C 0.00000,S 'B110',T 'B011011'}" in new_text


def test_write_refuses_programming_errors(tmp_path):
    program = _read(tmp_path, KRL, "cell.dat")
    xp3 = _by_name(program)["XP3"]
    with pytest.raises(ValueError, match="not targets of the program: XNOPE"):
        write_program(program, {"XNOPE": (np.eye(4), {})})
    with pytest.raises(ValueError, match="has no S"):
        write_program(program, {"XP3": (xp3.pose, {"S": 2})})
    with pytest.raises(ValueError, match="not a rotation"):
        write_program(program, {"XP3": (2 * np.eye(4), {})})


# ---------------------------------------------------------------------------------------------
# Bad input


def _robtarget(trans: str = "[1,2,3]", quat: str = "[1,0,0,0]", end: str = ";") -> str:
    return f"MODULE M\n  CONST robtarget p1 := [{trans},{quat},[0,0,0,0],{EXTAX}]{end}\nENDMODULE\n"


BAD_RAPID = {
    "unterminated at the end of the file": (_robtarget(end="").split("\nENDMODULE")[0], "line 2, p1: unterminated"),
    "unterminated aggregate": ("MODULE M\n  CONST robtarget p1 := [[1,2,3],[1,0,0,0]\nENDMODULE\n", "line 3, p1"),
    "missing semicolon": (_robtarget(end=""), "line 3, p1: expected ';'"),
    "NaN": (_robtarget(trans="[1,2,NaN]"), "not a number"),
    "letters in a number": (_robtarget(trans="[1,2,3abc]"), "expected ',' or ']'"),
    "two dots": (_robtarget(trans="[1,2.5.5,3]"), "expected ',' or ']'"),
    "out of range": (_robtarget(trans="[1,2,1e999]"), "out of range"),
    "quaternion of norm 0": (_robtarget(quat="[0,0,0,0]"), "norm 0"),
    "quaternion of norm 2": (_robtarget(quat="[2,0,0,0]"), "norm 2"),
    "two numbers in the position": (_robtarget(trans="[1,2]"), "expected \\[...\\] of 3 items"),
    "four numbers in the position": (_robtarget(trans="[1,2,3,4]"), "expected \\[...\\] of 3 items"),
    "a robtarget array short of elements": (
        "MODULE M\n  CONST robtarget pts{2} := [[[1,2,3],[1,0,0,0],[0,0,0,0],[0,0,0,0,0,0]]];",
        "line 2, pts: array of 2 elements: expected \\[...\\] of 2 items, found 1"),
    "an array of no elements": ("MODULE M\n  CONST robtarget pts{0} := [];", "array dimension '0'"),
    "an array's element malformed": (
        "MODULE M\n  CONST robtarget pts{2} := [[[1,2,3],[1,0,0,0],[0,0,0,0],[0,0,0,0,0,0]],\n"
        "    [[1,2],[1,0,0,0],[0,0,0,0],[0,0,0,0,0,0]]];", "line 3, pts\\{2\\}: position"),
    "a value that is not an aggregate": ("MODULE M\n  CONST robtarget p2 := p1;\n", "expected \\[...\\]"),
    "a fractional confdata": (_robtarget().replace("[0,0,0,0]", "[0,0.5,0,0]"), "not an integer"),
    "declared twice": (_robtarget() + _robtarget(), "declared twice"),
    "a bad tooldata": ("PERS tooldata t := [TRUE, [[0,0,0],[1,0,0,0]], [1, [0,0,0], [1,0,0,0], 0, 0]];", "6 items"),
    "a bad wobjdata robhold": ('PERS wobjdata w := [1, TRUE, "", [[0,0,0],[1,0,0,0]], [[0,0,0],[1,0,0,0]]];', "TRUE"),
}  # fmt: skip
BAD_KRL = {
    "missing X": ("DECL E6POS XP1={Y 1,Z 2,A 0,B 0,C 0}\n", "missing X"),
    "letters in X": ("DECL E6POS XP1={X 1a,Y 1,Z 2,A 0,B 0,C 0}\n", "X: '1a' is not a number"),
    "NaN": ("DECL POS XP1={X nan,Y 1,Z 2,A 0,B 0,C 0}\n", "not a number"),
    "bad binary": ("DECL POS XP1={X 0,Y 1,Z 2,A 0,B 0,C 0,S 'B012'}\n", "S: "),
    "fractional T": ("DECL POS XP1={X 0,Y 1,Z 2,A 0,B 0,C 0,T 2.5}\n", "T: "),
    "unterminated": ("DECL E6POS XP1={X 0,Y 1,Z 2,A 0,B 0,C 0\nENDDAT\n", "no '}'"),
    "empty component": ("DECL E6POS XP1={X 0,,Y 1,Z 2,A 0,B 0,C 0}\n", "malformed component"),
    "repeated component": ("DECL E6POS XP1={X 0,X 1,Y 1,Z 2,A 0,B 0,C 0}\n", "given twice"),
    "an array of size 0": ("DECL E6POS XP[0]\n", "declared as DECL E6POS NAME\\[n\\]"),
    "an array given a value": ("DECL E6POS XP[2]={X 0,Y 1,Z 2,A 0,B 0,C 0}\n", "element by element"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD_RAPID))
def test_bad_rapid_is_an_input_error(tmp_path, case):
    text, message = BAD_RAPID[case]
    with pytest.raises(InputError, match=message) as info:
        _read(tmp_path, text, "bad.mod")
    assert info.value.source.endswith("bad.mod")


@pytest.mark.parametrize("case", sorted(BAD_KRL))
def test_bad_krl_is_an_input_error(tmp_path, case):
    text, message = BAD_KRL[case]
    with pytest.raises(InputError, match=message) as info:
        _read(tmp_path, "DEFDAT BAD\n" + text, "bad.dat")
    assert info.value.field.startswith("line 2, XP")


@pytest.mark.parametrize("name", ["prog.txt", "prog", "prog.src"])
def test_unknown_suffix_is_an_input_error(tmp_path, name):
    with pytest.raises(InputError, match=r"unknown program suffix .*\.mod, \.modx, \.prg, \.sys, \.dat"):
        _read(tmp_path, RAPID, name)


def test_missing_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="file not found"):
        read_program(tmp_path / "absent.mod")


@pytest.mark.parametrize(
    ("name", "text"),
    [("empty.mod", ""), ("empty.sys", "MODULE Empty(SYSMODULE)\n  ! nothing\nENDMODULE\n"), ("empty.dat", ""),
     ("home.dat", "DEFDAT HOME\nDECL E6AXIS XHOME={A1 0,A2 -90}\nDECL E6POS XP\nENDDAT\n"),
     ("noval.prg", "MODULE M\n  VAR robtarget p;\n  PROC f(VAR robtarget q{*}) ENDPROC\nENDMODULE")],
)  # fmt: skip
def test_programs_without_targets(tmp_path, name, text):
    program = _read(tmp_path, text, name)
    assert program.targets == () and write_program(program, {}) == text


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-be", "utf-8-sig"])
def test_a_program_saved_as_utf16_or_with_a_bom_reads_and_writes_back_so(tmp_path, encoding):
    """Issue 43, item 5: a UTF-16 module (as Windows editors save) reported "no targets"."""
    plain = tmp_path / "plain.mod"
    plain.write_text(RAPID, encoding="utf-8")
    saved = tmp_path / "saved.mod"
    data = RAPID.encode(encoding)
    saved.write_bytes((b"\xfe\xff" + data) if encoding == "utf-16-be" else data)  # -be writes no mark itself
    program, reference = read_program(saved), read_program(plain)
    assert [t.name for t in program.targets] == [t.name for t in reference.targets] and program.targets
    assert all(np.allclose(a.pose, b.pose) for a, b in zip(program.targets, reference.targets, strict=True))
    assert program.encoding == ("utf-8-sig" if encoding == "utf-8-sig" else "utf-16")  # written back so


def test_utf16_without_a_mark_is_refused_clearly(tmp_path):
    path = tmp_path / "bare.mod"
    path.write_bytes(RAPID.encode("utf-16-le"))
    with pytest.raises(InputError, match="NUL bytes: UTF-16 without a byte-order mark"):
        read_program(path)


def test_a_krl_src_is_pointed_to_its_dat(tmp_path, capsys):
    from fgcal.commands.cli import main

    (tmp_path / "weld.src").write_text("DEF weld()\nLIN XP1\nEND\n")
    (tmp_path / "weld.dat").write_text(KRL)
    assert main(["compensate", "kuka_kr125_2", str(tmp_path / "weld.src"), "--out", str(tmp_path / "o.src")]) == 2
    error = capsys.readouterr().err
    assert "weld.src" in error and "targets are declared in weld.dat" in error and error[-1] == "\n"


def test_inline_targets_are_listed_not_silently_kept(tmp_path):
    """Issue 43, item 5: RAPID motions with a target written inline were skipped without a word
    ("correcting 4 targets")."""
    from fgcal.data.program_filter import check_program

    inline = (
        "    MoveL [[500,0,600],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]], v100, z10, tool0;\n"
        "    ! MoveL [[1,2,3],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]], v100, fine, tool0;\n"
        "    MoveJ \\Conc, [[400,0,500],[0,0,1,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]], v100, z10, tool0;\n"
    )
    text = RAPID.replace("ENDMODULE", "  PROC extra()\n" + inline + "  ENDPROC\nENDMODULE")
    path = tmp_path / "inline.mod"
    path.write_text(text)
    program = read_program(path)
    # The module's own inline MoveL, and the two added (not the one in a comment).
    lines = text.splitlines()
    expected = [k + 1 for k, line in enumerate(lines) if "[[" in line and line.strip().startswith("Move")]
    notes = [n for n in check_program(program, True, True) if "inline" in n]
    assert len(expected) == 3 and len(notes) == 1, (expected, notes)
    shown = ", ".join(map(str, expected))
    assert notes[0].startswith(f"3 motions with a target written inline ([[x, y, z], ...]; lines {shown})"), notes


@pytest.mark.parametrize("value", ["1e300", "-2E11"])
def test_a_krl_number_beyond_any_place_is_refused_as_in_rapid(tmp_path, value):
    """Issue 43, item 5: KRL's X 1e300 was read, and the target left as it was with a status,
    where RAPID refuses any number beyond 1e10."""
    path = tmp_path / "p.dat"
    path.write_text(f"DEFDAT P\nDECL E6POS XP1={{X {value},Y 0,Z 1500,A 0,B 90,C 0,S 2,T 2}}\nENDDAT\n")
    with pytest.raises(InputError, match=rf"line 2, XP1: X: '{value}' is out of range \(beyond 1e\+10\)"):
        read_program(path)


def _rt(x: float) -> str:
    return f"[[{x},0,800],[0,0,1,0],[0,0,0,0],{EXTAX}]"


ARRAYS = f"""MODULE CELL_ARRAYS
    PERS tooldata guns{{2}} := [[TRUE,[[0,0,100],[1,0,0,0]],[1,[0,0,50],[1,0,0,0],0,0,0]],
        [TRUE,[[0,0,200],[1,0,0,0]],[2,[0,0,80],[1,0,0,0],0,0,0]]];
    TASK PERS wobjdata tables{{2}} := [[FALSE,TRUE,"",[[1000,0,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]],
        [FALSE,TRUE,"",[[0,1000,0],[1,0,0,0]],[[0,0,0],[1,0,0,0]]]];
    CONST robtarget pts{{3}} := [{_rt(501)}, {_rt(502)},
        {_rt(503)}];
    CONST robtarget grid {{ 2, 2 }} := [[{_rt(611)}, {_rt(612)}], [{_rt(621)}, {_rt(622)}]];
    PROC main()
        MoveL pts{{1}}, v100, fine, guns{{2}}\\WObj:=tables{{1}};
        MoveL Offs(pts{{2}}, 0, 0, 10), v100, fine, guns{{1}};
        FOR i FROM 1 TO 2 DO
            MoveL grid{{i, 1}}, v100, z10, guns{{1}}\\WObj:=tables{{2}};
        ENDFOR
        MoveL grid{{2,2}}, v100, fine, guns{{2}};
    ENDPROC
ENDMODULE
"""


def test_rapid_arrays_give_their_elements_with_their_tools_and_work_objects(tmp_path):
    """Arrays of robtargets, tooldata and wobjdata: one of each per element, named as RAPID
    indexes them; an element moved by a literal index takes that instruction's tool and work
    object (guns{2}: it was read as no tool), one moved through a loop's index the loop's."""
    program = _read(tmp_path, ARRAYS, "arrays.mod")
    names = [t.name for t in program.targets]
    assert names == ["pts{1}", "pts{2}", "pts{3}", "grid{1,1}", "grid{1,2}", "grid{2,1}", "grid{2,2}"]
    by_name = {t.name: t for t in program.targets}
    assert np.allclose([by_name[n].pose[0, 3] for n in names], [0.501, 0.502, 0.503, 0.611, 0.612, 0.621, 0.622])
    assert (by_name["pts{1}"].tool, by_name["pts{1}"].work_object) == ("guns{2}", "tables{1}")
    assert (by_name["pts{2}"].tool, by_name["pts{2}"].work_object) == ("guns{1}", None)
    assert by_name["pts{3}"].tool is None
    for name in ("grid{1,1}", "grid{1,2}", "grid{2,1}"):  # the loop's use, with no place in the path
        assert (by_name[name].tool, by_name[name].work_object, by_name[name].first_move) == ("guns{1}", "tables{2}",
                                                                                             None)
    assert by_name["grid{2,2}"].tool == "guns{2}" and by_name["grid{2,2}"].first_move is not None
    assert by_name["grid{2,1}"].line == 8 and by_name["pts{3}"].line == 7
    assert np.isclose(program.tools["guns{2}"].tcp[2, 3], 0.2) and program.tools["guns{2}"].mass_kg == 2
    assert np.allclose(program.work_objects["tables{2}"][:3, 3], [0, 1, 0])
    moved = by_name["grid{2,1}"].pose.copy()
    moved[:3, 3] += [0.001, -0.002, 0.0005]
    text = write_program(program, {"grid{2,1}": (moved, {})})
    changed = [k for k, (a, b) in enumerate(zip(ARRAYS.splitlines(), text.splitlines(), strict=True), 1) if a != b]
    assert changed == [8]  # the line of grid{2,1}, and no other
    again = _read(tmp_path, text, "again.mod")
    for old, new in zip(program.targets, again.targets, strict=True):
        expected = moved if old.name == "grid{2,1}" else old.pose
        np.testing.assert_allclose(new.pose, expected, atol=1e-9)


KRL_ARRAYS = """DEFDAT PALLET
DECL E6POS XPS[3]
XPS[1]={X 1000,Y 0,Z 800,A 0,B 90,C 0,S 2,T 2}
XPS[3]={X 1000,Y 200,Z 800,A 0,B 90,C 0,S 2,T 2} ; the last
DECL POS XGRID[2,2]
XGRID[2, 1]={X 900,Y 0,Z 700,A 10,B 80,C 0}
FDAT_NOT_A_TARGET[1]={TOOL_NO 1}
ENDDAT
"""


def test_krl_arrays_give_their_elements(tmp_path):
    """DECL E6POS XPS[3] then XPS[1]={...}: a target per element (it was refused: 'arrays of
    positions are not supported'); the write-back changes the element's line only."""
    program = _read(tmp_path, KRL_ARRAYS, "pallet.dat")
    assert [(t.name, t.line) for t in program.targets] == [("XPS[1]", 3), ("XPS[3]", 4), ("XGRID[2,1]", 6)]
    assert np.allclose(program.targets[1].pose[:3, 3], [1.0, 0.2, 0.8])
    assert program.targets[1].config == {"S": 2, "T": 2}
    moved = program.targets[2].pose.copy()
    moved[:3, 3] += [0.0005, 0, 0]
    text = write_program(program, {"XGRID[2,1]": (moved, {})})
    changed = [k for k, (a, b) in enumerate(zip(KRL_ARRAYS.splitlines(), text.splitlines(), strict=True), 1) if a != b]
    assert changed == [6]
    np.testing.assert_allclose(_read(tmp_path, text, "again.dat").targets[2].pose, moved, atol=1e-9)
    with pytest.raises(InputError, match="outside the array's declared size") as info:
        _read(tmp_path, KRL_ARRAYS.replace("XPS[3]={", "XPS[4]={"), "bad.dat")
    assert info.value.field == "line 4, XPS[4]"


def test_external_axes_are_noticed(tmp_path):
    """A target with an external axis's value (a track: RAPID eax_a not 9E9, KRL E1 not 0) is
    marked, so that the command says fgcal corrects it as if the base did not move."""
    rapid = _read(tmp_path, _robtarget().replace(EXTAX, "[1500,9E9,9E9,9E9,9E9,9E9]"), "track.mod")
    assert rapid.targets[0].external_axes
    assert not _read(tmp_path, _robtarget(), "plain.mod").targets[0].external_axes
    krl = _read(tmp_path, "DEFDAT P\nDECL E6POS XP1={X 1,Y 2,Z 3,A 0,B 0,C 0,E1 1000.0,E2 0.0}\n"
                "DECL E6POS XP2={X 1,Y 2,Z 3,A 0,B 0,C 0,E1 0.0}\nENDDAT\n", "track.dat")  # fmt: skip
    assert [t.external_axes for t in krl.targets] == [True, False]
