"""One online measurement: an image's joint angles and observed pixels (docs/online.md).

Inbox files are JSON (``*.json``)::

    {"format": "fgcal-measurement/1", "cycle": 12, "units": {"angle": "deg"},
     "joints": [10.0, -45.0, 80.0, 0.0, 30.0, 0.0],
     "pixels": {"X+x_r00c00": [812.4, 533.1], "X+x_r00c01": [901.7, 530.2]}}

``cycle`` (optional, integer, non-decreasing) is the work cycle the image was taken in.

Any formulation's observations of one configuration go in ``observations``, by table, one
entry per row (its id columns other than the configuration, and its values in SI: m, rad,
px)::

    {"format": "fgcal-measurement/1", "cycle": 3, "units": {"angle": "deg"},
     "joints": [10.0, -45.0, 80.0, 0.0, 30.0, 0.0],
     "before_joints": [12.0, -40.0, 75.0, 0.0, 25.0, 0.0], "speed": 1.0,
     "observations": {"tracker_points": [{"target": "t1", "value": [2.2833, 0.4800, 0.4869]}]}}

``pixels`` is the short form of the ``pixels`` table (its id column ``point``). ``config``
(optional) labels the configuration; a reading between two configurations (a table whose id
columns are ``config_a``, ``config_b``, as tool_distances) names both by their labels, and joins
the graph once both have arrived. A labelled configuration may carry no observation of its own
(the first end of such readings).
``before_joints`` (same units as ``joints``) and ``speed`` (the move's speed factor, default
1) say how the configuration was reached: the motion history a model DH,s,e,h fits.
A work cycle's batch goes in one file as ``configurations``: each entry one configuration's
``joints``, ``observations`` (or ``pixels``), ``before_joints`` and ``speed``; ``format``,
``cycle`` and ``units`` are the file's::

    {"format": "fgcal-measurement/1", "cycle": 3, "units": {"angle": "deg"},
     "configurations": [{"joints": [...], "observations": {...}}, {"joints": [...], ...}]}

The file is one measurement of the log (logged, replayed and named as one) whose
configurations are folded in together, in one update (fgcal.online.protocol; a flange camera's
images come one per file).

Writers write a temporary file whose name does not end in ``.json`` (``write_measurement``
uses ``.NAME.tmp``) in the inbox and rename it to ``NAME.json`` when complete: rename is atomic
on one filesystem, so fgcal never reads a half-written file. Names must be unique.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fields import Fields, check_name, first_repeat
from ..core.outputs import output_dir, write_text
from ..core.units import parse_units
from ..data.dataset import KEY_COLUMNS, UNORDERED
from .inbox import read_regular
from .protocol import Reading

FORMAT = "fgcal-measurement/1"
KEYS = ["format", "name", "cycle", "units", "config", "joints", "pixels", "observations", "before_joints", "speed"]
CONFIGURATION_KEYS = ["config", "joints", "pixels", "observations", "before_joints", "speed"]
MAX_CONFIGURATIONS = 1000  # a work cycle's batch


@dataclass(frozen=True)
class Measurement:
    name: str  # the inbox file name: the measurement's identity
    q: np.ndarray  # rad
    pixels: tuple[tuple[str, np.ndarray], ...]  # (point, (u, v) px)
    cycle: int | None = None
    # Other tables: (table, {id column: names}, values (rows, k) SI), in the file's order.
    observations: tuple[tuple[str, dict[str, tuple[str, ...]], np.ndarray], ...] = ()
    before: np.ndarray | None = None  # joints before the last move (rad); None: not given
    speed: float | None = None  # the move's speed factor; None: not given (1)
    # The file's further configurations (a work cycle's batch; name, cycle: this one's), folded
    # in with this one; () : the file carries one configuration.
    batch: tuple[Measurement, ...] = ()
    # The configuration's label, which readings between two configurations name (their
    # config_a, config_b); None: none.
    label: str | None = None

    @property
    def configurations(self) -> tuple[Measurement, ...]:
        """Every configuration of the file, this one first."""
        return (self, *self.batch)

    @property
    def n_observations(self) -> int:
        return sum(
            len(m.pixels) + sum(len(values) for _, _, values in m.observations) for m in self.configurations
        )

    def readings(self) -> list[Reading]:
        """What fgcal.online.protocol folds in, one reading per configuration."""
        return [m.reading() for m in self.configurations]

    def reading(self) -> Reading:
        """What fgcal.online.protocol folds in: the tables (pixels as the pixels table)."""
        tables = {name: ({k: list(v) for k, v in ids.items()}, values) for name, ids, values in self.observations}
        if self.pixels:
            tables["pixels"] = ({"point": [n for n, _ in self.pixels]}, np.array([uv for _, uv in self.pixels]))
        return Reading(self.q, tables, self.before, 1.0 if self.speed is None else self.speed, self.label)

    def to_record(self) -> dict:
        """JSON-ready, SI units (what the state log stores)."""
        record = {"format": FORMAT, "name": self.name, "cycle": self.cycle}
        if self.batch:
            record["configurations"] = [m._configuration_record() for m in self.configurations]
            return record
        return {**record, **self._configuration_record()}

    def _configuration_record(self) -> dict:
        record: dict = {"config": self.label} if self.label is not None else {}
        record["joints"] = [float(v) for v in self.q]
        # A camera's image: as the log always held it.
        if self.pixels or not (self.observations or self.label is not None):
            record["pixels"] = {n: [float(u), float(v)] for n, (u, v) in self.pixels}
        if self.observations:
            record["observations"] = {
                table: [{**{k: v[i] for k, v in ids.items()}, "value": [float(x) for x in values[i]]}
                        for i in range(len(values))]
                for table, ids, values in self.observations
            }  # fmt: skip
        if self.before is not None:
            record["before_joints"] = [float(v) for v in self.before]
        if self.speed is not None:
            record["speed"] = float(self.speed)
        return record


def parse_measurement(
    data: object, name: str, source: str | Path, n_joints: int, limits: np.ndarray | None = None
) -> Measurement:
    """A measurement document; JSON numbers only (a number in quotes is refused), and with
    ``limits`` (n, 2; rad or m) joint values within them. A document with ``configurations``
    carries several (a work cycle's batch): the first, with the others as its ``batch``."""
    fields = Fields(data, source)
    fields.check_keys([*KEYS, "configurations"])
    if fields.string("format", FORMAT) != FORMAT:
        raise fields.error("format", f"expected {FORMAT!r}, got {fields.raw('format')!r}")
    units = parse_units(fields.raw("units", None), source)
    # null: no cycle (what a measurement taken outside the cycles, and the feed, writes)
    cycle = fields.integer("cycle", minimum=0) if fields.raw("cycle", None, nullable=True) is not None else None
    if not fields.has("configurations"):
        return _configuration(fields, name, cycle, units, n_joints, limits)
    inline = [key for key in CONFIGURATION_KEYS if fields.has(key)]
    if inline:
        raise fields.error(inline[0], "a file with configurations gives each configuration's in its entry")
    entries = fields.sub_list("configurations")
    if not entries or len(entries) > MAX_CONFIGURATIONS:
        raise fields.error("configurations", f"expected 1 to {MAX_CONFIGURATIONS} configurations, got {len(entries)}")
    parts = [_configuration(entry, name, cycle, units, n_joints, limits) for entry in entries]
    return replace(parts[0], batch=tuple(parts[1:]))


def _configuration(
    fields: Fields, name: str, cycle: int | None, units, n_joints: int, limits: np.ndarray | None
) -> Measurement:
    """One configuration's joints, observations and motion history (``fields``: the file, or
    an entry of its ``configurations``)."""
    if fields.prefix:
        fields.check_keys(CONFIGURATION_KEYS)
    q = fields.vector("joints", n_joints, scale=units.to_rad) if isinstance(fields.raw("joints"), list) else None
    if q is None:
        raise fields.error("joints", "expected a list of joint angles")
    for i, value in enumerate(fields.raw("joints")):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fields.error(f"joints[{i}]", f"expected a number, got {value!r}")
    if limits is not None:
        outside = np.flatnonzero((q < limits[:, 0] - 1e-9) | (q > limits[:, 1] + 1e-9))
        if len(outside):
            i = outside[0]
            raise fields.error(
                f"joints[{i}]", f"{q[i]:.6g} rad is outside the joint's limits [{limits[i, 0]:.4g}, {limits[i, 1]:.4g}]"
            )
    raw_pixels = fields.sub("pixels", {})
    pixels = tuple((str(point), raw_pixels.vector(str(point), 2)) for point in raw_pixels.data)
    observations = _observations(fields.sub("observations", {}))
    label = check_name(fields.string("config"), fields.source, fields.path("config")) if fields.has("config") else None
    if not pixels and not observations and label is None:
        raise fields.error(
            "pixels" if fields.has("pixels") or not fields.has("observations") else "observations",
            "a measurement needs at least one observation (or a config label: a configuration that readings "
            "between two configurations name)",
        )
    before = None
    if fields.has("before_joints"):
        before = fields.vector("before_joints", n_joints, scale=units.to_rad)
    speed = fields.number("speed", positive=True) if fields.has("speed") else None
    return Measurement(name, q, pixels, cycle, observations, before, speed, label=label)


def _observations(tables: Fields) -> tuple:
    """The ``observations`` mapping: per table, rows of id strings and a ``value`` list."""
    out = []
    for table in tables.data:
        rows = tables.sub_list(str(table))
        if not rows:
            raise tables.error(str(table), "expected at least one row")
        keys = sorted(k for k in rows[0].data if k != "value")
        ids: dict[str, list[str]] = {k: [] for k in keys}
        values = []
        for row in rows:
            row.check_keys([*keys, "value"])
            for key in keys:
                ids[key].append(row.string(key))
            value = row.raw("value")
            width = len(value) if isinstance(value, list) else 0
            if values and width != len(values[0]):
                raise row.error("value", f"expected {len(values[0])} numbers as the rows before, got {value!r}")
            if not isinstance(value, list) or width > 16:  # a touch has none
                raise row.error("value", f"expected a list of numbers, got {value!r}")
            values.append(row.vector("value", width))
        _refuse_duplicates(str(table), rows, ids)
        out.append((str(table), {k: tuple(v) for k, v in ids.items()}, np.array(values).reshape(len(rows), -1)))
    return tuple(out)


def _refuse_duplicates(table: str, rows: list[Fields], ids: dict[str, list[str]]) -> None:
    """A measurement named twice in one configuration would count twice (a reflector's point
    folded in with double weight): refused, as a dataset's table refuses it
    (fgcal.data.dataset: the same id columns, a distance's ends in either order)."""
    columns = [c for c in KEY_COLUMNS.get(table, tuple(ids)) if c in ids]
    if not columns:
        return
    keys = zip(*(ids[c] for c in columns), strict=True)
    repeat = first_repeat((i, tuple(sorted(key)) if table in UNORDERED else key) for i, key in enumerate(keys))
    if repeat is not None:
        first, i, key = repeat
        raise rows[i].error(
            columns[0], f"{', '.join(columns)} {' '.join(map(repr, key))} given twice in one configuration (rows "
            f"{first} and {i} of {table}): each measurement once (repeated readings: give each its own configuration)",
        )  # fmt: skip


MAX_BYTES = 1 << 20  # an image's joints and pixels take a few kB


def read_measurement(
    path: Path, n_joints: int, name: str | None = None, source: Path | None = None, limits: np.ndarray | None = None
) -> Measurement:
    """The measurement in ``path`` (a regular file: read without following a link or blocking),
    named ``name`` (default the file's) and reported as ``source`` (default ``path``)."""
    source = path if source is None else source
    try:
        data = json.loads(read_regular(path, MAX_BYTES).decode("utf-8"))
    except json.JSONDecodeError as error:
        raise InputError(source, None, f"not valid JSON: {error}") from None
    except (OSError, UnicodeDecodeError) as error:
        raise InputError(source, None, f"cannot read: {error}") from None
    except RecursionError:
        raise InputError(source, None, "JSON nested too deeply") from None
    return parse_measurement(data, path.name if name is None else name, source, n_joints, limits)


def write_measurement(inbox: str | Path, measurement: Measurement) -> Path:
    """Drop a measurement into an inbox with the atomic-rename protocol."""
    inbox = output_dir(inbox, "--inbox")
    final = inbox / measurement.name
    temporary = inbox / f".{measurement.name}.tmp"
    record = measurement.to_record()
    record.pop("name")
    write_text(temporary, json.dumps(record), sync=True)
    os.replace(temporary, final)
    return final
