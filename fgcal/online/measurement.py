"""One online measurement: an image's joint angles and observed pixels (docs/online.md).

Inbox files are JSON (``*.json``)::

    {"format": "fgcal-measurement/1", "cycle": 12, "units": {"angle": "deg"},
     "joints": [10.0, -45.0, 80.0, 0.0, 30.0, 0.0],
     "pixels": {"X+x_r00c00": [812.4, 533.1], "X+x_r00c01": [901.7, 530.2]}}

``cycle`` (optional, integer, non-decreasing) is the work cycle the image was taken in.
Writers write a temporary file whose name does not end in ``.json`` (``write_measurement``
uses ``.NAME.tmp``) in the inbox and rename it to ``NAME.json`` when complete: rename is atomic
on one filesystem, so fgcal never reads a half-written file. Names must be unique.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.fields import Fields
from ..core.outputs import output_dir, write_text
from ..core.units import parse_units
from .inbox import read_regular

FORMAT = "fgcal-measurement/1"


@dataclass(frozen=True)
class Measurement:
    name: str  # the inbox file name: the measurement's identity
    q: np.ndarray  # rad
    pixels: tuple[tuple[str, np.ndarray], ...]  # (point, (u, v) px)
    cycle: int | None = None

    def to_record(self) -> dict:
        """JSON-ready, SI units (what the state log stores)."""
        return {
            "format": FORMAT,
            "name": self.name,
            "cycle": self.cycle,
            "joints": [float(v) for v in self.q],
            "pixels": {n: [float(u), float(v)] for n, (u, v) in self.pixels},
        }


def parse_measurement(
    data: object, name: str, source: str | Path, n_joints: int, limits: np.ndarray | None = None
) -> Measurement:
    """A measurement document; JSON numbers only (a number in quotes is refused), and with
    ``limits`` (n, 2; rad or m) joint values within them."""
    fields = Fields(data, source)
    fields.check_keys(["format", "name", "cycle", "units", "joints", "pixels"])
    if fields.string("format", FORMAT) != FORMAT:
        raise fields.error("format", f"expected {FORMAT!r}, got {fields.raw('format')!r}")
    units = parse_units(fields.raw("units", None), source)
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
    raw_pixels = fields.sub("pixels")
    pixels = tuple((str(point), raw_pixels.vector(str(point), 2)) for point in raw_pixels.data)
    if not pixels:
        raise fields.error("pixels", "an image needs at least one observed point")
    # null: no cycle (what a measurement taken outside the cycles, and the feed, writes)
    cycle = fields.integer("cycle", minimum=0) if fields.raw("cycle", None, nullable=True) is not None else None
    return Measurement(name, q, pixels, cycle)


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
