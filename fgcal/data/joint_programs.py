"""Joint positions as a program a controller runs: a plan's measurement configurations as an ABB
RAPID module of ``MoveAbsJ`` to ``jointtarget``s, a KUKA KRL ``.src``/``.dat`` pair of ``PTP``
to ``E6AXIS`` points, or a CSV in degrees; each states what it assumed (fgcal.data.assumptions)
in comments, and fgcal's own program reader reads the joints back (programs.joint_path).

Every configuration is reached with an exact stop (RAPID ``fine``, KRL ``PTP`` without
approximation) and a settling wait, the measurement's moment; an approach point, where the plan
has one, is visited just before its configuration.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.outputs import write_text
from .assumptions import Assumptions
from .dataset import write_csv

PROGRAM_KINDS = ("rapid", "krl", "csv-deg")
DIGITS = 6  # decimals of a degree (a millimetre) written: fgcal reads the joints back to 1e-6
SETTLE_S = 1.0  # the wait at each configuration before it is measured
RAPID_SPEED, KRL_PTP_PERCENT = "v100", 20
NAME = "cal_plan"  # the program's name (KRL: the DEF's and the files')


def check_program(kind: str, n_joints: int) -> None:
    """Refuse a program of ``kind`` for a robot of ``n_joints``: an unknown kind, or RAPID or KRL
    (6 robot axes) for another robot. fgcal plan asks before planning, not after."""
    if kind not in PROGRAM_KINDS:
        raise InputError(None, "--program", f"unknown program kind {kind!r} (one of {', '.join(PROGRAM_KINDS)})")
    if kind != "csv-deg" and n_joints != 6:
        raise InputError(None, "--program", f"a RAPID or KRL program drives 6 robot axes; this robot has {n_joints} "
                         "joints: use --program csv-deg")  # fmt: skip


def write_joint_program(
    kind: str,
    folder: str | Path,
    names: list[str],
    q: np.ndarray,
    approach: np.ndarray | None,
    assumptions: Assumptions,
    prismatic: np.ndarray,
    labels: tuple[str, list[str]] | None = None,
) -> list[Path]:
    """The program of ``kind`` (PROGRAM_KINDS) in ``folder`` for joint positions ``q`` (N, n; rad,
    m for a prismatic joint) named ``names``, each reached from ``approach`` (N, n) when given.
    ``labels``: (column, one per configuration) what each measures (a plan's block, point or
    pivot): a comment on each target's line (RAPID ``! block b3``, KRL ``; block b3``), a column
    of the CSV. Returns the files written."""
    check_program(kind, q.shape[1])
    values = np.where(prismatic, q * 1e3, np.degrees(q))
    before = None if approach is None else np.where(prismatic, approach * 1e3, np.degrees(approach))
    folder = Path(folder)
    if kind == "csv-deg":
        return [_csv(folder, names, values, before, assumptions, prismatic, labels)]
    notes = [""] * len(names) if labels is None else [f"{labels[0]} {label}" for label in labels[1]]
    return _rapid(folder, names, values, before, assumptions, notes) if kind == "rapid" else _krl(
        folder, names, values, before, assumptions, notes
    )


def _number(value: float) -> str:
    return f"{value:.{DIGITS}f}"


def _rapid(folder: Path, names, values, before, assumptions: Assumptions, notes: list[str]) -> list[Path]:
    extax = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
    lines = [f"MODULE {NAME.upper()}", *assumptions.commented("!")]
    moves = []
    for k, name in enumerate(names):
        if before is not None:
            lines.append(f"    CONST jointtarget a_{name} := [[{','.join(map(_number, before[k]))}],{extax}];")
            moves.append(f"        MoveAbsJ a_{name}, {RAPID_SPEED}, fine, tool0;")
        note = f"  ! {notes[k]}" if notes[k] else ""
        lines.append(f"    CONST jointtarget {name} := [[{','.join(map(_number, values[k]))}],{extax}];{note}")
        moves += [f"        MoveAbsJ {name}, {RAPID_SPEED}, fine, tool0;",
                  f"        WaitTime \\InPos, {SETTLE_S:g};  ! measure {name} here"]  # fmt: skip
    lines += ["", "    PROC main()", *moves, "    ENDPROC", "ENDMODULE", ""]
    path = folder / f"{NAME}.mod"
    write_text(path, "\r\n".join(lines))
    return [path]


def _krl(folder: Path, names, values, before, assumptions: Assumptions, notes: list[str]) -> list[Path]:
    def axis(row) -> str:
        joints = ",".join(f"A{i} {_number(v)}" for i, v in enumerate(row, 1))
        return f"{{{joints},E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}}"

    comments = assumptions.commented(";")
    data = [f"DEFDAT {NAME.upper()} PUBLIC", *comments, "EXT BAS (BAS_COMMAND :IN,REAL :IN)"]
    source = [f"DEF {NAME.upper()}( )", *comments, "BAS(#INITMOV,0)", f"BAS(#VEL_PTP,{KRL_PTP_PERCENT})"]
    for k, name in enumerate(names):
        point = f"X{name.upper()}"
        if before is not None:
            data.append(f"DECL E6AXIS XA_{name.upper()}={axis(before[k])}")
            source.append(f"PTP XA_{name.upper()}")
        data.append(f"DECL E6AXIS {point}={axis(values[k])}" + (f" ; {notes[k]}" if notes[k] else ""))
        source += [f"PTP {point}", f"WAIT SEC {SETTLE_S:g} ; measure {name} here"]
    paths = [folder / f"{NAME}.dat", folder / f"{NAME}.src"]
    write_text(paths[0], "\r\n".join([*data, "ENDDAT", ""]))
    write_text(paths[1], "\r\n".join([*source, "END", ""]))
    return paths


def _csv(folder: Path, names, values, before, assumptions: Assumptions, prismatic, labels=None) -> Path:
    unit = ["mm" if linear else "deg" for linear in prismatic]
    header = ["config", *[f"q{i}_{u}" for i, u in enumerate(unit, 1)]]
    rows = [[name, *map(float, np.round(row, DIGITS))] for name, row in zip(names, values, strict=True)]
    if labels is not None:  # as configurations.csv: the label after the joints
        header.append(labels[0])
        rows = [[*row, label] for row, label in zip(rows, labels[1], strict=True)]
    if before is not None:
        header += [f"before_q{i}_{u}" for i, u in enumerate(unit, 1)]
        rows = [[*row, *map(float, np.round(b, DIGITS))] for row, b in zip(rows, before, strict=True)]
    path = folder / "configurations_deg.csv"
    write_csv(path, header, rows, assumptions.commented("#"))
    return path
