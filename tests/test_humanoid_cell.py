"""Issue 40's bundled cell: the elastic humanoid upper body (fixed rotated arm mounts, hands as tip
payloads, a head, compliances about the parent's axes and a coupled compliance) seen by a
motion-capture system, simulated and calibrated with the config fgcal simulate writes.

The fixed frames' estimates are compared with their *effective* truth: the same parameters fitted
to the same configurations measured without noise. A tracker (or a motion-capture system) in an
unknown pose cannot tell some of the mounts' deviations from the torso's: the torso's pitch
axes keep their direction in the shoulders' link (the coupled joint keeps it level), so a shift
of both mounts along them is the pitch joints' d; a shift along the yaw axis is the tracker's.
Those deviations go to the parameters they are a combination of, in the data as in the fit."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from conftest import REPO

from fgcal.commands.cli import main

CELL = REPO / "datasets" / "cells" / "humanoid_mocap.yaml"


def _cell(tmp: Path, name: str, **change) -> Path:
    """A copy of the bundled cell with some sections changed (the robot is the bundled one)."""
    doc = yaml.safe_load(CELL.read_text())
    for section, values in change.items():
        doc[section] = {**doc[section], **values}
    path = tmp / f"{name}.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def _run(cell: Path, out: Path, seed: int, capsys, stages: list | None = None) -> dict:
    assert main(["simulate", str(cell), "--out", str(out / "data"), "--seed", str(seed)]) == 0
    config = out / "data" / "calibration.yaml"
    if stages is not None:
        doc = yaml.safe_load(config.read_text())
        doc["stages"] = stages
        config.write_text(yaml.safe_dump(doc))
    assert main(["calibrate", str(config), "--out", str(out / "report"), "--no-plots"]) == 0
    capsys.readouterr()
    return json.loads((out / "report" / "report.json").read_text())


def _held_out(report: dict) -> tuple[float, float, float]:
    validation = report["validation"]
    return (
        validation["before"]["position_error_m"]["rms"],
        validation["after"]["position_error_m"]["rms"],
        validation["predicted_position_sigma_m"]["rms"],
    )


def test_a_small_humanoid_cell_calibrates(tmp_path, capsys):
    """The cheap check (80 configurations): held out within 1.5x of its prediction and far below
    nominal, the coupled and a parent-axis compliance among the estimates, within 3 sigma."""
    cell = _cell(tmp_path, "small", design={"n_configurations": 80})
    report = _run(cell, tmp_path / "small", 1, capsys)
    before, after, predicted = _held_out(report)
    assert before / after >= 50.0, (before, after)
    assert 1 / 1.5 <= after / predicted <= 1.5, (after, predicted)
    parameters = report["parameters"]
    for name in ("kc3", "kx2", "kx6"):
        p = parameters[name]
        assert p["status"] == "estimated" and abs(p["truth"] - p["estimate"]) <= 3 * p["sigma"], (name, p)
    assert sum(parameters[n]["status"] == "estimated" for n in parameters if n.startswith("frame.")) >= 10


@pytest.mark.study
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_humanoid_mocap_cell_acceptance(seed, tmp_path, capsys):
    """Issue 40's acceptance, per seed: held out within 1.5x of its prediction and at least 50x
    below nominal; every estimated compliance (kx, ky, kz about the parent's axes, kc) within 3
    sigma of the truth; every estimated fixed-frame parameter within 3 sigma of its effective truth
    (the module's docstring), at least 11 of the 12 estimated."""
    report = _run(CELL, tmp_path / "noisy", seed, capsys)
    before, after, predicted = _held_out(report)
    held_out = f"seed {seed}: held out before {before * 1e3:.3f} mm, after {after * 1e3:.5f} mm, predicted " + (
        f"{predicted * 1e3:.5f} mm"
    )
    assert before / after >= 50.0, (before, after)
    assert 1 / 1.5 <= after / predicted <= 1.5, (after, predicted)
    parameters = report["parameters"]
    estimated = [n for n, p in parameters.items() if p["status"] == "estimated"]
    compliances = [n for n in estimated if n[0] == "k"]
    frames = [n for n in estimated if n.startswith("frame.")]
    assert {"kc3", "kx2", "kz3", "kx6", "kx13"} <= set(compliances) and len(frames) >= 11, (compliances, frames)
    # The effective truth: the same parameters fitted to the same cell measured without noise.
    twin = _cell(tmp_path, "noise_free", noise={"tracker_sigma": 1e-5})
    effective = _run(twin, tmp_path / "twin", seed, capsys, stages=[estimated])["parameters"]
    worst = {}
    print(held_out)  # (the runs above capture what is printed before them)
    for name in compliances + frames + ["mass.arms"]:
        p = parameters[name]
        reference = p["truth"] if name in compliances else effective[name]["estimate"]
        worst[name] = (p["estimate"] - reference) / p["sigma"]
        print(f"  {name}: z {worst[name]:+.2f} (against the truth {(p['estimate'] - p['truth']) / p['sigma']:+.2f})")
    largest = {kind: max(abs(z) for n, z in worst.items() if (n[0] == "k") == (kind == "k")) for kind in ("k", "f")}
    print(f"  largest |z|: compliances {largest['k']:.2f}, frames and mass scale {largest['f']:.2f}")
    bad = {name: z for name, z in worst.items() if abs(z) > 3}
    assert not bad, bad
