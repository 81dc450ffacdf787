"""Generic importer: instrument and controller exports (CSV or text tables) to an fgcal dataset.

A mapping YAML (``format: fgcal-import/1``, documented in docs/formats.md) says which file and
which columns hold the joint angles and each measurement, in which units, with which delimiter
and decimal mark. Tracker points, fixed references, 6D poses (quaternion or Euler angles) and
ballbar distances share one mechanism: a table mapping names a file, its reading options, the
column joining each row to a configuration (or none: row i is configuration i) and the columns
of the measured values. Values are written as exported, in the mapping's units; only Euler
angles become quaternions and a table's own units are converted to the mapping's.
"""

from __future__ import annotations

import csv
import re
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..core.errors import InputError
from ..core.fields import Fields, check_name, first_repeat, is_plain_number, read_file_text, read_yaml
from ..core.outputs import output_dir
from ..core.schema import validate
from ..core.units import Units, parse_units
from ..model.robot_io import embed_robot, referenced_robot, robot_reference
from .dataset import (
    FORMAT,
    LIMITS,
    QUATERNION_TOLERANCE,
    UNORDERED,
    load_dataset,
    target_tips,
    write_csv,
    write_header,
)
from .schema import ImportMapping

READ_KEYS = ("file", "delimiter", "decimal", "header", "skip_rows", "encoding", "units", "not_found")
# What each table mapping may name besides its reading options: the dataset's id columns (each
# from a column, or one fixed name for every row with the ``_name`` form) and its values.
TABLE_KEYS = {
    "configurations": ("config", "joints", "approach", "speed"),
    "tracker_points": ("config", "target", "target_name", "xyz", "zeros_mean_not_found"),
    "tracker_references": ("config", "target", "target_name", "xyz", "zeros_mean_not_found"),
    "tracker_poses": ("config", "xyz", "quaternion", "euler", "zeros_mean_not_found"),
    "distances": ("config", "pivot", "pivot_name", "distance", "zeros_mean_not_found"),
    "tool_distances": ("config_a", "config_b", "distance", "zeros_mean_not_found"),
}
DELIMITERS = {",": ",", ";": ";", "tab": "\t", "whitespace": None}
# Cells that mean "not measured" in common exports (a reflector out of sight), besides any the
# mapping declares; a row whose measured cells are all such is dropped and counted.
NOT_FOUND = ("",)


@dataclass
class SourceTable:
    """One exported file as read: its column names and data rows with their line numbers."""

    path: Path
    columns: list[str]
    rows: list[list[str]]
    lines: list[int]
    decimal: str
    not_found: tuple[str, ...]

    def index(self, fields: Fields, key: str, reference: object) -> int:
        """Position of a column given by name (header) or 1-based number."""
        if isinstance(reference, bool) or not isinstance(reference, (str, int)):
            raise fields.error(key, f"expected a column name or number, got {reference!r}")
        if isinstance(reference, int):
            if not 1 <= reference <= len(self.columns):
                raise fields.error(
                    key, f"column {reference} does not exist in {self.path} ({len(self.columns)} columns)"
                )
            return reference - 1
        if reference not in self.columns:
            hint = "; one column only: is the delimiter right?" if len(self.columns) == 1 else ""
            raise fields.error(
                key, f"no column {reference!r} in {self.path} (columns: {', '.join(self.columns)}{hint})"
            )
        return self.columns.index(reference)

    def text(self, row: int, column: int) -> str:
        return self.rows[row][column].strip()

    def name(self, row: int, column: int) -> str:
        """An id cell (a configuration, a target, a pivot): text without control characters."""
        return check_name(self.text(row, column), self.path, f"line {self.lines[row]}, column {self.columns[column]}")

    def missing(self, row: int, columns: list[int]) -> bool:
        return all(self.text(row, c) in self.not_found for c in columns)

    def number(self, row: int, column: int, kind: str, to_si: float) -> float:
        """One cell as a float in the file's units, checked like a dataset's values."""
        raw = self.text(row, column)
        text = raw.replace(",", ".") if self.decimal == "," else raw
        where = f"line {self.lines[row]}, column {self.columns[column]}"
        if not is_plain_number(text):
            problem = "must be finite" if text.lower().lstrip("+-") in ("nan", "inf", "infinity") else "not a number"
            raise InputError(self.path, where, f"{problem}: {raw!r}")
        value = float(text)
        if not abs(value * to_si) <= LIMITS[kind]:
            raise InputError(self.path, where, f"implausible value {raw!r} (beyond {LIMITS[kind]:g} SI)")
        return value


def _delimiter(fields: Fields, first_line: str, decimal: str) -> str | None:
    """The declared delimiter, or the one the first non-empty line uses (None: whitespace)."""
    if fields.has("delimiter"):
        delimiter = DELIMITERS[fields.string("delimiter", choices=tuple(DELIMITERS))]
        if decimal == "," and delimiter == ",":
            raise fields.error("decimal", "a decimal comma needs another delimiter (';', tab or whitespace)")
        return delimiter
    for candidate in (";", "\t", ","):
        if candidate in first_line and not (candidate == "," and decimal == ","):
            return candidate
    return None


def read_source(fields: Fields, base: Path) -> SourceTable:
    """Read the file a table mapping names (relative to the mapping's directory)."""
    name = fields.string("file")
    if "\x00" in name:  # no file has it in its name, and pathlib refuses it with a ValueError (as dataset._inside)
        raise fields.error("file", f"a file name with a NUL character: {name!r}")
    path = (base / name).resolve()
    encoding = fields.string("encoding", "utf-8-sig")
    try:
        lines = read_file_text(path, encoding).splitlines()
    except LookupError:
        raise fields.error("encoding", f"unknown encoding {encoding!r}") from None
    except InputError as exc:
        raise fields.error("file", f"{path}: {exc.message}") from None
    skip = fields.integer("skip_rows", 0, minimum=0)
    numbered = [(i + 1, line) for i, line in enumerate(lines) if i >= skip and line.strip()]
    if not numbered:
        raise InputError(path, None, f"no rows after the first {skip} lines")
    decimal = fields.string("decimal", ".", choices=(".", ","))
    delimiter = _delimiter(fields, numbered[0][1], decimal)
    if delimiter is None:
        cells = [line.split() for _, line in numbered]
    else:
        reader = csv.reader([line for _, line in numbered], delimiter=delimiter)
        try:
            cells = list(reader)
        except csv.Error as exc:
            raise InputError(path, f"line {numbered[reader.line_num - 1][0]}", f"not CSV: {exc}") from None
    if fields.raw("header", True):
        columns = [c.strip() for c in cells[0]]
        repeated = sorted(c for c, count in Counter(columns).items() if c and count > 1)
        if repeated:
            raise InputError(path, f"line {numbered[0][0]}", f"the header names column {repeated[0]!r} twice")
        rows, line_numbers = cells[1:], [n for n, _ in numbered[1:]]
    else:
        columns = [str(i) for i in range(1, len(cells[0]) + 1)]
        rows, line_numbers = cells, [n for n, _ in numbered]
    if not rows:
        raise InputError(path, None, "no data rows")
    for line, row in zip(line_numbers, rows, strict=True):
        if len(row) != len(columns):
            raise InputError(path, f"line {line}", f"expected {len(columns)} columns, got {len(row)}")
    tokens = fields.items("not_found", [])  # texts or numbers: the schema's NotFound
    return SourceTable(path, columns, rows, line_numbers, decimal, NOT_FOUND + tuple(str(t) for t in tokens))


@dataclass
class Imported:
    """Rows of one fgcal table, in the mapping's units, and what was dropped."""

    header: list[str]
    rows: list[list[object]]
    dropped: int = 0


def _units(fields: Fields, default: Units) -> Units:
    return parse_units(fields.raw("units", None), fields.source, fields.path("units"), default)


def _configurations(fields: Fields, base: Path, units: Units, n_joints: int) -> tuple[Imported, dict[str, int]]:
    source = read_source(fields, base)
    own = _units(fields, units)
    joints = fields.items("joints")
    if len(joints) != n_joints:
        raise fields.error("joints", f"the robot has {n_joints} joints: name {n_joints} columns, got {len(joints)}")
    joint_columns = _columns(fields, source, "joints", n_joints)
    id_column = source.index(fields, "config", fields.raw("config")) if fields.has("config") else None
    # The motion history: the rows' order is the measurement order; optionally each one's
    # approach point (joint columns, all empty: the previous row) and its move's speed factor.
    approach = _columns(fields, source, "approach", n_joints) if fields.has("approach") else None
    speed = source.index(fields, "speed", fields.raw("speed")) if fields.has("speed") else None
    scale = own.to_rad / units.to_rad
    rows, seen = [], {}
    for r in range(len(source.rows)):
        config = source.name(r, id_column) if id_column is not None else f"c{r:04d}"
        if not config:
            raise InputError(source.path, f"line {source.lines[r]}, column {source.columns[id_column]}", "empty id")
        if config in seen:
            raise InputError(source.path, f"line {source.lines[r]}", f"configuration {config!r} appears twice")
        seen[config] = r
        row = [config, *(source.number(r, c, "angle", own.to_rad) * scale for c in joint_columns)]
        if approach is not None:
            empty = all(not source.text(r, c) for c in approach)
            row += [""] * n_joints if empty else [source.number(r, c, "angle", own.to_rad) * scale for c in approach]
        if speed is not None:
            row.append(source.number(r, speed, "unitless", 1.0) if source.text(r, speed) else 1.0)
        rows.append(row)
    header = ["config", *(f"q{i}" for i in range(1, n_joints + 1))]
    header += [f"before_q{i}" for i in range(1, n_joints + 1)] if approach is not None else []
    header += ["speed"] if speed is not None else []
    return Imported(header, rows), seen


def _id(fields: Fields, source: SourceTable, key: str) -> tuple[int | None, str | None]:
    """An id column of the dataset table: from a column (``key``) or one name (``key_name``)."""
    if fields.has(key) == fields.has(f"{key}_name"):
        raise fields.error(key, f"give either {key} (a column) or {key}_name (one name for every row)")
    if fields.has(key):
        return source.index(fields, key, fields.raw(key)), None
    name = fields.raw(f"{key}_name")
    if not isinstance(name, (str, int)) or isinstance(name, bool) or not str(name).strip():
        raise fields.error(f"{key}_name", f"expected a name, got {name!r}")
    return None, check_name(str(name).strip(), fields.source, fields.path(f"{key}_name"))


def _columns(fields: Fields, source: SourceTable, key: str, count: int) -> list[int]:
    names = fields.items(key)
    if len(names) != count:
        raise fields.error(key, f"expected {count} columns, got {len(names)}")
    indices = [source.index(fields, f"{key}[{i}]", c) for i, c in enumerate(names)]
    for i, index in enumerate(indices):
        if index in indices[:i]:
            raise fields.error(f"{key}[{i}]", f"column {names[i]!r} is already {key}[{indices.index(index)}]")
    return indices


def _rotation(fields: Fields, source: SourceTable) -> tuple[list[int], str | None]:
    """The quaternion columns (w, x, y, z), or the Euler-angle columns and their sequence."""
    if fields.has("quaternion") == fields.has("euler"):
        raise fields.error("quaternion", "give either quaternion: [w, x, y, z] or euler: {columns, sequence}")
    if fields.has("quaternion"):
        return _columns(fields, source, "quaternion", 4), None
    euler = fields.sub("euler")
    sequence = euler.string("sequence")
    # scipy's notation: lower case extrinsic (fixed axes), upper case intrinsic (moving axes).
    if not re.fullmatch(r"[xyz]{3}|[XYZ]{3}", sequence) or sequence[0] == sequence[1] or sequence[1] == sequence[2]:
        raise euler.error(
            "sequence", f"{sequence!r} is no Euler sequence (e.g. xyz: fixed axes, ZYX: moving axes, ZYZ)"
        )
    return _columns(euler, source, "columns", 3), sequence


def _measurements(
    name: str, fields: Fields, base: Path, units: Units, configs: dict[str, int], n_configs: int
) -> Imported:
    source = read_source(fields, base)
    own = _units(fields, units)
    length_scale = own.to_m / units.to_m
    # The columns joining a row to its configuration(s); a single one may be left to row order.
    joins = ("config_a", "config_b") if name == "tool_distances" else ("config",)
    if name == "tool_distances" and not all(fields.has(k) for k in joins):
        raise fields.error("config_a", "a distance between configurations names both: config_a and config_b columns")
    config_columns = [source.index(fields, k, fields.raw(k)) for k in joins if fields.has(k)]
    if not config_columns and len(source.rows) != n_configs:
        raise InputError(
            source.path,
            None,
            f"{len(source.rows)} rows, but there are {n_configs} configurations "
            f"(without a config column, row i is configuration i; {fields.path('config')} names one)",
        )
    ids = [id_name for id_name in ("target", "pivot") if id_name in TABLE_KEYS[name]]
    id_sources = {k: _id(fields, source, k) for k in ids}
    rotation: tuple[list[int], str | None] = ([], None)
    if name in ("distances", "tool_distances"):
        value_columns = [source.index(fields, "distance", fields.raw("distance"))]
    else:
        value_columns = _columns(fields, source, "xyz", 3)
        if name == "tracker_poses":
            rotation = _rotation(fields, source)
    measured = value_columns + rotation[0]
    zeros = fields.raw("zeros_mean_not_found", False)
    config_ids = list(configs)
    imported = Imported([*joins, *ids], [])
    lines = []  # of the rows kept
    for r in range(len(source.rows)):
        where = f"line {source.lines[r]}"
        row: list[object] = [source.name(r, c) for c in config_columns] if config_columns else [config_ids[r]]
        for config, column in zip(row, config_columns, strict=False):
            if config not in configs:
                raise InputError(
                    source.path, f"{where}, column {source.columns[column]}", f"unknown configuration {config!r}"
                )
        if source.missing(r, measured):
            imported.dropped += 1
            continue
        for k in ids:
            column, fixed = id_sources[k]
            row.append(fixed if column is None else source.name(r, column))
            if not row[-1]:
                raise InputError(source.path, f"{where}, column {source.columns[column]}", f"empty {k} name")
        values = [source.number(r, c, "length", own.to_m) * length_scale for c in value_columns]
        if rotation[0]:
            kind, to_si = ("angle", own.to_rad) if rotation[1] else ("unitless", 1.0)
            rotation_values = [source.number(r, c, kind, to_si) for c in rotation[0]]
            values += _quaternion(source, r, rotation_values, rotation[1], own)
        if zeros and not any(values):
            imported.dropped += 1
            continue
        imported.rows.append(row + values)
        lines.append(source.lines[r])
    keys = (tuple(sorted(row[:len(imported.header)])) if name in UNORDERED else tuple(row[:len(imported.header)])
            for row in imported.rows)  # fmt: skip
    repeat = first_repeat(zip(lines, keys, strict=True))  # each measurement once (a dataset's tables require it)
    if repeat is not None:
        raise InputError(
            source.path, f"lines {repeat[0]} and {repeat[1]}", f"{', '.join(imported.header)} "
            f"{' '.join(map(repr, repeat[2]))} given twice: each measurement once",
        )  # fmt: skip
    if name in ("distances", "tool_distances"):
        imported.header.append("distance")
    elif name == "tracker_poses":
        imported.header += ["x", "y", "z", "qw", "qx", "qy", "qz"]
    else:
        imported.header += ["x", "y", "z"]
    return imported


def _quaternion(source: SourceTable, row: int, values: list[float], sequence: str | None, units: Units) -> list[float]:
    """(qw, qx, qy, qz) of a row's rotation columns."""
    if sequence is None:
        norm = float(np.linalg.norm(values))
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise InputError(
                source.path, f"line {source.lines[row]}", f"quaternion norm {norm:.6g} is not 1 (a rotation's is)"
            )
        return values
    x, y, z, w = Rotation.from_euler(sequence, np.array(values) * units.to_rad).as_quat()
    return [float(w), float(x), float(y), float(z)]


def import_tables(mapping_path: str | Path, out: str | Path) -> dict[str, int]:
    """Write the dataset a mapping file describes into ``out``; returns row and dropped counts.
    The mapping's relative file names are relative to its directory."""
    mapping_path = Path(mapping_path)
    return import_mapping(
        read_yaml(mapping_path),
        mapping_path,
        mapping_path.resolve().parent,
        out,
        f"fgcal import-csv {mapping_path.name}",
    )


def import_mapping(raw: object, source: str | Path, base: Path, out: str | Path, origin: str) -> dict[str, int]:
    """The importer on a mapping document read from ``source`` (errors name it); ``origin``
    opens the dataset's ``source`` text."""
    out = Path(out)
    validate(raw, ImportMapping, source)  # keys, types, nulls and choices; the checks below need the files
    doc = Fields(raw, source)
    units = parse_units(doc.raw("units", None), source)
    robot_ref, robot = referenced_robot(doc, base)
    configurations, configs = _configurations(doc.sub("configurations"), base, units, robot.n_joints)
    tables: dict[str, Imported] = {}
    for name in ("tracker_points", "tracker_references", "tracker_poses", "distances", "tool_distances"):
        if not doc.has(name):
            continue
        raw = doc.raw(name)
        parts = doc.sub_list(name) if isinstance(raw, list) else [doc.sub(name)]
        for part in parts:
            imported = _measurements(name, part, base, units, configs, len(configs))
            if name in tables:
                tables[name].rows += imported.rows
                tables[name].dropped += imported.dropped
            else:
                tables[name] = imported
    if not tables:
        raise InputError(source, None, "no measurement table (tracker_points, tracker_poses, distances, ...)")
    if "tracker_references" in tables and "tracker_points" not in tables:
        raise doc.error("tracker_references", "references check a tracker's stability: tracker_points are needed too")
    out = output_dir(out)
    write_csv(out / "configurations.csv", configurations.header, configurations.rows)
    counts = {"configurations": len(configurations.rows)}
    for name, imported in tables.items():
        write_csv(out / f"{name}.csv", imported.header, imported.rows)
        counts[name] = len(imported.rows)
        counts[f"{name}_dropped_not_found"] = imported.dropped
    header: dict = {
        "format": FORMAT,
        "robot": embed_robot(robot_reference(base, robot_ref), out),
        "units": {"length": units.length, "angle": units.angle},
        "measured": [name for name in tables],
        "files": {"configurations": "configurations.csv", **{name: f"{name}.csv" for name in tables}},
    }
    if "tracker_points" in tables:
        header["tracker"] = {"targets": sorted({row[1] for row in tables["tracker_points"].rows})}
        if doc.has("target_tips"):
            header["tracker"]["tips"] = target_tips(doc.sub("target_tips"), set(header["tracker"]["targets"]), robot)
    elif doc.has("target_tips"):
        raise doc.error("target_tips", "the tips of tracker targets: tracker_points are needed too")
    if doc.has("tip"):
        if robot.tip_error(doc.string("tip")):
            raise doc.error("tip", robot.tip_error(doc.string("tip")))
        header["tip"] = doc.string("tip")
    if doc.has("payload"):
        header["payload"] = doc.raw("payload")
    header["order"] = doc.string("order", "measured", ("measured", "unknown"))
    described = doc.raw("source", "")
    header["source"] = origin + (f": {described}" if described else "")
    if doc.has("notes"):
        header["notes"] = doc.raw("notes")
    write_header(out, header)
    load_dataset(out)  # the result must read back: it then holds every check a dataset has
    return counts
