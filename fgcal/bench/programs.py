"""Program filtering against the targets CSV: CPU seconds per target of ``fgcal compensate`` on
one set of targets written as a KRL ``.dat`` and as a CSV (issue 43: a program's targets may
cost at most twice a CSV's)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..core.outputs import output_dir, write_text
from ..data.program_filter import configurations
from ..data.programs import krl_abc_deg
from ..simulation.cell import load_cell

PROGRAM_RATIO_TARGET = 2.0  # a program's CPU per target at most this times the CSV's


def write_targets(robot, n: int, folder: Path, seed: int) -> tuple[Path, Path]:
    """``n`` seeded targets of ``robot``'s flange (joints in the middle 60 % of each range),
    as a KRL .dat with their S and T and as a CSV in mm and deg (A B C)."""
    low, high = robot.limits[:, 0], robot.limits[:, 1]
    q = low + (high - low) * (0.2 + 0.6 * np.random.default_rng(seed).random((n, robot.n_joints)))
    T = robot.fk(q)
    config = configurations(robot, "krl", q)
    dat, csv = ["&ACCESS RVP", f"DEFDAT  BENCH{n} PUBLIC"], ["target,x,y,z,a,b,c"]
    for k in range(n):
        x, y, z = T[k, :3, 3] * 1e3
        a, b, c = krl_abc_deg(T[k, :3, :3])
        pose = f"X {x:.3f},Y {y:.3f},Z {z:.3f},A {a:.5f},B {b:.5f},C {c:.5f}"
        dat.append(f"DECL E6POS XP{k + 1}={{{pose},S {config[k]['S']},T {config[k]['T']}}}")
        csv.append(f"XP{k + 1},{x:.3f},{y:.3f},{z:.3f},{a:.5f},{b:.5f},{c:.5f}")
    dat.append("ENDDAT")
    paths = folder / f"targets{n}.dat", folder / f"targets{n}.csv"
    write_text(paths[0], "\r\n".join(dat) + "\r\n")
    write_text(paths[1], "\n".join(csv) + "\n")
    return paths


def program_bench(
    out: Path,
    robot_file: Path,
    cell: Path,
    child_usage: Callable[[list[str]], tuple[float, float, float]],
    command: Callable[..., list[str]],
    say: Callable[[str], None],
    sizes: tuple[int, int] = (200, 4000),
) -> dict:
    """CPU per target of ``fgcal compensate`` on a KRL program and on the same targets as a CSV,
    from the difference between two sizes (the start-up, the same for both, drops out); the
    robot ``robot_file`` a calibration of ``cell`` wrote (the memory bench's: no second one)."""
    folder = output_dir(out / "programs")
    nominal = load_cell(cell).robot
    cpu: dict[str, list[float]] = {"program": [], "csv": []}
    for n in sizes:
        dat, csv = write_targets(nominal, n, folder, seed=n)
        cpu["program"].append(child_usage(command("compensate", str(robot_file), str(dat), "--out",
                                                  str(folder / f"out{n}.dat"), "-q"))[0])  # fmt: skip
        cpu["csv"].append(child_usage(command("compensate", str(robot_file), str(csv), "--out",
                                              str(folder / f"out{n}.csv"), "--length-unit", "mm", "--angle-unit",
                                              "deg", "--orientation", "abc", "-q"))[0])  # fmt: skip
    span = sizes[1] - sizes[0]
    per_target = {kind: (values[1] - values[0]) / span for kind, values in cpu.items()}
    # With few targets the difference is within the start-up's own spread: no ratio then.
    measurable = min(per_target.values()) > 0
    ratio = per_target["program"] / per_target["csv"] if measurable else None
    if ratio is None:
        verdict = "not measurable at this size: give more --program-targets"
    else:
        verdict = f"{ratio:.2f}x (target at most {PROGRAM_RATIO_TARGET:g}x: "
        verdict += ("met" if ratio <= PROGRAM_RATIO_TARGET else "NOT met") + ")"
    say(
        f"  fgcal compensate, {nominal.name}, {sizes[0]} and {sizes[1]} targets: KRL program "
        f"{per_target['program'] * 1e3:.3f} ms, targets CSV {per_target['csv'] * 1e3:.3f} ms CPU per target: {verdict}"
    )
    return {
        "program_targets": list(sizes),
        "program_cpu_per_target_s": per_target["program"],
        "csv_cpu_per_target_s": per_target["csv"],
        "program_to_csv_ratio": ratio,
    }
