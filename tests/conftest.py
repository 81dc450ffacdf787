from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

import fgcal

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
SEED_CELL = REPO / "datasets" / "cells" / "kr125_seed.yaml"


def random_parameters(robot: fgcal.Robot, rng: np.random.Generator) -> dict[str, float]:
    """Nominal parameters with random deviations of every kind, compliances included, and the
    motion terms if the robot's model has them (otherwise no draws: the stream stays as it was)."""
    params = robot.nominal_parameters()
    for name in params:
        kind = name.rstrip("0123456789")
        if kind in ("lm", "lv") and not robot.history:
            continue
        if kind in ("kx", "ky", "kz"):
            params[name] = rng.uniform(1e-6, 1e-5)
        elif kind in ("sx", "sy") or name.startswith(("base.r", "tool.r")):
            params[name] = rng.normal(0.0, 0.05)
        else:
            params[name] += rng.normal(0.0, 0.01)
    return params


@pytest.fixture(scope="session")
def seed_sim(tmp_path_factory) -> Path:
    """The bundled seed cell simulated once with seed 1."""
    from fgcal.simulation.simulate import simulate

    out = tmp_path_factory.mktemp("seed_sim")
    simulate(SEED_CELL, out, seed=1)
    return out


@pytest.fixture(scope="session")
def bundled_sim(tmp_path_factory):
    """A bundled cell simulated once per session, by name and seed, with the calibration.yaml
    fgcal simulate writes beside it: ``bundled_sim("irb120_ballbar", 2)`` is the dataset's
    directory. Tests must not change it (copy it first)."""
    from fgcal.calibration.suggest import write_suggested_config
    from fgcal.data.dataset import load_dataset
    from fgcal.simulation.cell import load_cell
    from fgcal.simulation.simulate import simulate

    cache: dict[tuple[str, int], Path] = {}

    def get(cell: str, seed: int = 1) -> Path:
        if (cell, seed) not in cache:
            path = REPO / "datasets" / "cells" / f"{cell}.yaml"
            out = tmp_path_factory.mktemp(f"{cell}_{seed}")
            simulate(path, out, seed=seed)
            write_suggested_config(load_cell(path), load_dataset(out))
            cache[cell, seed] = out
        return cache[cell, seed]

    return get


def calibrate(config, progress=None):
    """fgcal.calibration.run.calibrate, then scored against the simulation's truth as the
    CLI does (when the dataset has one)."""
    from fgcal.calibration import run, scoring

    return scoring.score_with_truth(run.calibrate(config, progress))


def calibrate_dataset(dataset, config, progress=None):
    """fgcal.calibration.run.calibrate_dataset, then scored against the truth (if any)."""
    from fgcal.calibration import run, scoring

    return scoring.score_with_truth(run.calibrate_dataset(dataset, config, progress))


def random_urdf(path: Path, rng: np.random.Generator, n_joints: int = 6, prismatic: int | None = None) -> Path:
    """A random serial URDF written by hand (independent of fgcal's exporter): revolute
    joints with random origins and unit axes, fixed joints between some of them, an
    off-chain sensor link, inertials, and a tool0 tip after two fixed joints. Joint
    ``prismatic`` (1-based), if given, is prismatic."""

    def origin() -> str:
        xyz = " ".join(repr(float(v)) for v in rng.uniform(-0.3, 0.3, 3))
        rpy = " ".join(repr(float(v)) for v in rng.uniform(-np.pi, np.pi, 3))
        return f'<origin xyz="{xyz}" rpy="{rpy}"/>'

    def link(name: str) -> str:
        mass = rng.uniform(0.5, 20.0)
        com = " ".join(repr(float(v)) for v in rng.uniform(-0.2, 0.2, 3))
        return (
            f'<link name="{name}"><inertial><origin xyz="{com}" rpy="0.1 0.2 0.3"/><mass value="{mass!r}"/>'
            '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>'
        )

    def fixed(name: str, parent: str, child: str) -> str:
        return f'<joint name="{name}" type="fixed"><parent link="{parent}"/><child link="{child}"/>{origin()}</joint>'

    parts = ['<?xml version="1.0"?>', '<robot name="random_arm">', '<link name="root"/>']
    parent = "root"
    for i in range(1, n_joints + 1):
        if rng.uniform() < 0.4:  # a fixed joint (an adapter plate) before this joint
            parts += [link(f"adapter_{i}"), fixed(f"adapter_{i}_joint", parent, f"adapter_{i}")]
            parent = f"adapter_{i}"
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        kind = "prismatic" if i == prismatic else "revolute"
        lower, upper = (-0.2, 0.3) if kind == "prismatic" else (-2.5, 2.7)
        parts += [
            link(f"link_{i}"),
            f'<joint name="j{i}" type="{kind}"><parent link="{parent}"/><child link="link_{i}"/>{origin()}'
            f'<axis xyz="{" ".join(repr(float(v)) for v in axis)}"/>'
            f'<limit lower="{lower}" upper="{upper}" effort="1" velocity="1"/></joint>',
        ]
        parent = f"link_{i}"
        if i == 2:  # a sensor hanging off the chain
            parts += [link("sensor"), fixed("sensor_joint", parent, "sensor")]
    parts += [link("flange"), fixed("flange_joint", parent, "flange"), '<link name="tool0"/>']
    parts += [fixed("tool0_joint", "flange", "tool0"), "</robot>"]
    path.write_text("\n".join(parts), encoding="utf-8")
    return path


def merge_datasets(sources: dict[str, Path], out: Path) -> Path:
    """One dataset folder holding the tables of several simulated datasets of the same robot (a
    cell measured by several instruments): each one's configuration ids prefixed with its key
    (``tracker/c0000``), its tables and noise merged; the first one's payload. No truth."""
    import csv

    out.mkdir(parents=True, exist_ok=True)
    header: dict = {}
    rows: list[list[str]] = []
    tables: dict[str, list[list[str]]] = {}
    for key, source in sources.items():
        doc = yaml.safe_load((source / "dataset.yaml").read_text())
        if not header:
            header = {k: v for k, v in doc.items() if k not in ("files", "measured", "noise", "source")}
            header.update(measured=[], files={"configurations": "configurations.csv"}, noise={})
        header["noise"].update(doc.get("noise") or {})
        header.update({k: v for k, v in doc.items() if k == "tracker"})
        with open(source / "configurations.csv") as f:
            lines = list(csv.reader(f))
        rows = rows or [lines[0]]
        rows += [[f"{key}/{line[0]}", *line[1:]] for line in lines[1:]]
        for table in doc["measured"]:
            with open(source / doc["files"][table]) as f:
                lines = list(csv.reader(f))
            columns = [i for i, name in enumerate(lines[0]) if name.startswith("config")]
            body = [[f"{key}/{v}" if i in columns else v for i, v in enumerate(line)] for line in lines[1:]]
            tables.setdefault(table, [lines[0]]).extend(body)
            if table not in header["measured"]:
                header["measured"].append(table)
                header["files"][table] = f"{table}.csv"
        for name in doc["files"]:
            if name not in doc["measured"] and name != "configurations" and not (out / doc["files"][name]).exists():
                header["files"][name] = doc["files"][name]
                (out / doc["files"][name]).write_bytes((source / doc["files"][name]).read_bytes())
    for table, lines in {"configurations": rows, **tables}.items():
        with open(out / f"{table}.csv", "w", newline="") as f:
            csv.writer(f).writerows(lines)
    (out / "dataset.yaml").write_text(yaml.safe_dump(header, sort_keys=False))
    return out
