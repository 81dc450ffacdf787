"""The self-contained study (issue 39): a dual-arm robot measuring itself on the bundled cell
dual_arm_selfcontained, scored on the laser tracker that validates it.

For each seed, the cell is simulated once (as fgcal simulate does); then every self-contained
kind alone, every pair, the contacts and cameras without the gauge, and all together are
calibrated as sets of one config (sets:), each with the tracker as its validation set (use:
validation: measured, never fitted, its own pose and reflectors registered with the robot
held). Each row gives the tracker's held-out RMS before (the nominal robot) and after, its
prediction, and the truth's score of the first set's points (the balls, or the boards' tips;
gauge removed). A combination that cannot calibrate (too few measurements for its unknowns)
is reported with the reason.

Run: ``python tests/selfcontained_study.py [seeds...]`` (prints the table), or through
tests/test_selfcontained.py (pytest -m study), which checks the acceptance criteria."""

from __future__ import annotations

import itertools
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
CELL = REPO / "datasets" / "cells" / "dual_arm_selfcontained.yaml"
# The cell's self-contained kinds, as its sets name them.
KINDS = ("self_contact", "planes", "tip_gauge", "self_observation")


@dataclass(frozen=True)
class Row:
    seed: int
    kinds: tuple[str, ...]
    before_m: float | None = None  # the tracker's held-out RMS, nominal robot
    after_m: float | None = None
    predicted_m: float | None = None
    truth_after_m: float | None = None  # the fitted balls against the truth, gauge removed
    truth_predicted_m: float | None = None
    failed: str | None = None

    @property
    def label(self) -> str:
        return " + ".join(self.kinds)


def combinations() -> list[tuple[str, ...]]:
    """Every kind alone, every pair, the contacts and the cameras without the gauge (no length
    but the balls' radii and the boards' squares), and all together."""
    pairs = [c for n in (1, 2) for c in itertools.combinations(KINDS, n)]
    return [*pairs, ("self_contact", "planes", "self_observation"), KINDS]


def simulate_cell(seed: int, out: Path) -> dict:
    """The cell simulated at ``seed`` into ``out``; the sets of the config fgcal simulate writes."""
    from fgcal.calibration.suggest import write_suggested_config
    from fgcal.data.dataset import load_dataset
    from fgcal.simulation.cell import load_cell
    from fgcal.simulation.simulate import simulate

    simulate(CELL, out, seed=seed)
    config = write_suggested_config(load_cell(CELL), load_dataset(out))
    return yaml.safe_load(config.read_text())


def calibrate_kinds(seed: int, data: Path, suggested: dict, kinds: tuple[str, ...]) -> Row:
    from fgcal.calibration import scoring
    from fgcal.calibration.config import load_config
    from fgcal.calibration.run import calibrate
    from fgcal.core.errors import InputError

    sets = [s for s in suggested["sets"] if s["name"] in kinds or s.get("use") == "validation"]
    doc = {**{k: v for k, v in suggested.items() if k != "sets"}, "dataset": str(data), "sets": sets}
    path = data.parent / f"config_{seed}_{'_'.join(kinds)}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    try:
        measured = calibrate(load_config(path))
    except InputError as error:
        return Row(seed, kinds, failed=error.message)
    tracker = {label: measured.validation[label]["tracker/tool_point"].rms for label in ("before", "after")}
    scored = scoring.score_with_truth(measured)
    return Row(
        seed, kinds, tracker["before"], tracker["after"], measured.prediction.rms,
        scored.validation["after"]["tool_point"].rms, scored.prediction.rms,
    )  # fmt: skip


def study(seeds: list[int]) -> list[Row]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            data = Path(tmp) / f"seed{seed}" / "data"
            suggested = simulate_cell(seed, data)
            rows += [calibrate_kinds(seed, data, suggested, kinds) for kinds in combinations()]
    return rows


def table(rows: list[Row]) -> str:
    """The figures as a Markdown table (mm)."""
    lines = [
        "| seed | kinds | tracker before | tracker after | predicted | after / predicted | before / after | "
        "truth after | truth predicted |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if r.failed is not None:
            lines.append(f"| {r.seed} | {r.label} | not calibrated: {r.failed} | | | | | | |")
            continue
        lines.append(
            f"| {r.seed} | {r.label} | {r.before_m * 1e3:.3f} | {r.after_m * 1e3:.4f} | {r.predicted_m * 1e3:.4f} | "
            f"{r.after_m / r.predicted_m:.2f} | {r.before_m / r.after_m:.0f} | {r.truth_after_m * 1e3:.4f} | "
            f"{r.truth_predicted_m * 1e3:.4f} |"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    print(table(study([int(s) for s in sys.argv[1:]] or [1, 2, 3])))
