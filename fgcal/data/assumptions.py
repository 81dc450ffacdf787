"""What a controller-facing output assumed, stated in the file a user keeps (issue 43, item 4).

A corrected program, a corrections table or a CSV of commands is only right for the frame, tool,
payload, units and approach it was computed for. Each states them in its own comment syntax
(``#`` in CSV, which fgcal's reader skips before the header; ``!`` in RAPID; ``;`` in KRL), in mm
and deg for people, in ASCII (a program keeps its encoding).
"""

from __future__ import annotations

import textwrap
from dataclasses import dataclass

import numpy as np

from ..core.se3 import so3_log


@dataclass(frozen=True)
class Assumptions:
    """The lines an output states: what it is, then frame, tool, payload, units, approach."""

    what: str
    frame: str
    tool: str
    payload: str
    units: str
    approach: str
    notes: tuple[str, ...] = ()

    def lines(self) -> list[str]:
        return [
            self.what,
            f"frame: {self.frame}",
            f"tool: {self.tool}",
            f"payload: {self.payload}",
            f"units: {self.units}",
            f"approach: {self.approach}",
            *self.notes,
        ]

    def commented(self, mark: str) -> list[str]:
        """The lines behind a comment mark, ASCII only (a program's encoding may be Latin-1), each
        at most WIDTH characters (controllers' editors show short lines; a long one continues
        indented)."""
        out = []
        for line in self.lines():
            ascii_line = line.encode("ascii", "replace").decode("ascii")
            out += textwrap.wrap(ascii_line, WIDTH, initial_indent=f"{mark} ", subsequent_indent=f"{mark}   ",
                                 break_on_hyphens=False)  # fmt: skip
        return out


WIDTH = 100


def _vector(values, scale: float, unit: str) -> str:
    """``(x, y, z) unit``, to 4 decimals, without -0 or trailing zeros."""
    return "(" + ", ".join(f"{round(float(v) * scale, 4) + 0.0:.12g}" for v in values) + f") {unit}"


def pose_text(T: np.ndarray) -> str:
    """A pose for people: its origin in mm and its rotation vector in deg."""
    return f"origin {_vector(T[:3, 3], 1e3, 'mm')}, rotation vector {_vector(so3_log(T[:3, :3]), 180 / np.pi, 'deg')}"


def frame_text(frame: str, T_W_ctrl: np.ndarray) -> str:
    """``frame`` (``controller`` or ``W``) and where the controller's base frame is in W."""
    placed = f"the controller's base frame lies in the calibration's frame W at {pose_text(T_W_ctrl)}"
    if frame == "W":
        return f"targets in the calibration's frame W (--targets-frame W); commands in the controller's base frame; " \
               f"{placed}"  # fmt: skip
    return f"targets and commands in the controller's base frame ({placed}, where the nominal model best matches " \
           "the calibrated one over the calibrated region)"  # fmt: skip


def mixed_payload_text(loads: np.ndarray, sources: tuple[str, ...], calibration_kg: float) -> str:
    """Where the targets' tools carry different loads (rows [kg, centre of mass m]): each load,
    whose it is and how many targets have it, and the payload the base frame was placed at."""
    groups: dict[tuple, list] = {}
    for row, whose in zip(map(tuple, loads), sources, strict=True):
        groups.setdefault((row, whose), []).append(1)
    listed = "; ".join(
        f"{whose} {row[0]:g} kg, centre of mass {_vector(np.array(row[1:]), 1e3, 'mm')} ({len(n)} targets)"
        for (row, whose), n in groups.items()
    )
    return (
        f"deflection at each target's tool's load (in the flange frame): {listed}; the controller's base frame "
        f"placed at the calibration's payload, {calibration_kg:g} kg"
    )


def payload_text(mass_kg: float, com_m: np.ndarray, source: str, calibration_kg: float) -> str:
    """The load the deflection was computed for, whose it is, and the payload the base frame was placed at."""
    return (
        f"deflection at {mass_kg:g} kg, centre of mass {_vector(com_m, 1e3, 'mm')} in the flange frame ({source}); "
        f"the controller's base frame placed at the calibration's payload, {calibration_kg:g} kg"
    )
