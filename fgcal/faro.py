"""Converter for the ABB IRB 120 / FARO laser tracker data set (icelinker layout).

Input folder: ``measured_joints.txt`` (N x 6 joint angles, deg), ``measured_SMR_{k}.txt``
(N x 3, mm, tracker frame: reflectors on the tool) and optionally ``measured_base_{k}.txt``
(N x 3, mm: reflectors fixed in the cell; a row of zeros means "not found").
Output: an fgcal dataset (mm, deg, as measured) with ``tracker_points`` and
``tracker_references``; no value is altered, rows of zeros are dropped.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .dataset import FORMAT, write_csv, write_header
from .errors import InputError


def _load_matrix(path: Path, columns: int) -> np.ndarray:
    try:
        data = np.loadtxt(path, ndmin=2)
    except FileNotFoundError:
        raise InputError(path, None, "file not found") from None
    except ValueError as exc:
        raise InputError(path, None, f"not a whitespace-separated numeric table: {exc}") from None
    if data.shape[1] != columns:
        raise InputError(path, None, f"expected {columns} columns, got {data.shape[1]}")
    bad = np.argwhere(~np.isfinite(data))
    if len(bad):
        raise InputError(path, f"line {bad[0][0] + 1}", "non-finite value")
    return data


def convert_faro(src: str | Path, out: str | Path, robot: str = "abb_irb120") -> dict[str, int]:
    """Write the dataset; returns row counts (and dropped rows) for the summary."""
    src, out = Path(src), Path(out)
    joints = _load_matrix(src / "measured_joints.txt", 6)
    n = len(joints)
    smr_paths = sorted(src.glob("measured_SMR_*.txt"))
    if not smr_paths:
        raise InputError(src, None, "no measured_SMR_*.txt files (reflectors on the tool)")
    out.mkdir(parents=True, exist_ok=True)
    ids = [f"c{i:04d}" for i in range(n)]
    write_csv(
        out / "configurations.csv",
        ["config", "q1", "q2", "q3", "q4", "q5", "q6"],
        [[cid, *map(float, q)] for cid, q in zip(ids, joints, strict=True)],
    )
    counts = {"configurations": n}

    def table(paths: list[Path], prefix: str, name: str) -> None:
        rows, dropped = [], 0
        for path in paths:
            data = _load_matrix(path, 3)
            if len(data) != n:
                raise InputError(path, None, f"{len(data)} rows, but measured_joints.txt has {n}")
            target = f"{prefix}{path.stem.rsplit('_', 1)[-1]}"
            for cid, xyz in zip(ids, data, strict=True):
                if np.all(xyz == 0.0):
                    dropped += 1
                    continue
                rows.append([cid, target, *map(float, xyz)])
        write_csv(out / f"{name}.csv", ["config", "target", "x", "y", "z"], rows)
        counts[name] = len(rows)
        counts[f"{name}_dropped_not_found"] = dropped

    table(smr_paths, "smr", "tracker_points")
    base_paths = sorted(src.glob("measured_base_*.txt"))
    files = {"configurations": "configurations.csv", "tracker_points": "tracker_points.csv"}
    measured = ["tracker_points"]
    if base_paths:
        table(base_paths, "ref", "tracker_references")
        files["tracker_references"] = "tracker_references.csv"
        measured.append("tracker_references")
    write_header(
        out,
        {
            "format": FORMAT,
            "robot": robot,
            "units": {"length": "mm", "angle": "deg"},
            "measured": measured,
            "files": files,
            "tracker": {"targets": [f"smr{p.stem.rsplit('_', 1)[-1]}" for p in smr_paths]},
            "source": f"fgcal convert-faro {src.name}: FARO laser tracker, ABB IRB 120; rows of zeros "
            "(reflector not found) dropped; values as measured (outliers are kept: the estimator's "
            "robust losses deal with them)",
        },
    )
    return counts
