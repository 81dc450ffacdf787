"""A dual-arm robot measuring itself (issue 39): self-contact, planes, the hands' gauge and the
torso's cameras fitted as the sets of one config, a laser tracker validating (use: validation).
The study on the bundled cell (seeds 1-3: every kind alone, every pair, all together) runs with
pytest -m study; a small self-contained calibration runs by default."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml
from selfcontained_study import CELL, KINDS, combinations, study, table

from fgcal.calibration import scoring
from fgcal.calibration.config import load_config
from fgcal.calibration.run import calibrate, calibrate_dataset
from fgcal.data.dataset import load_dataset
from fgcal.reports.calibration import write_report
from fgcal.simulation.simulate import simulate

# The bundled cell cut down (fewer contacts and readings, no compliance, distortion or mass
# error, fitted with DH): seconds to simulate and calibrate.
SMALL = {
    "contact": {"self_contacts": 120, "plane_contacts": 40, "gauge": {"readings": 120}},
    "self_observation": {"views": 60},
    "perturbation": {"compliance": [0, 0], "distortion": 0, "mass_scale": 0},
}


def _merge(base: dict, edits: dict) -> dict:
    return {**base, **{k: _merge(base.get(k, {}), v) if isinstance(v, dict) else v for k, v in edits.items()}}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """The cut-down cell simulated at seed 4: its directory (data/ in it)."""
    root = tmp_path_factory.mktemp("small")
    cell = root / "cell.yaml"
    cell.write_text(yaml.safe_dump(_merge(yaml.safe_load(CELL.read_text()), SMALL)))
    simulate(cell, root / "data", seed=4)
    return root


def test_a_small_self_contained_calibration_lands_far_below_nominal(small, tmp_path):
    """Contacts, the gauge and the torso's cameras alone, scored on the tracker they never fitted: the held-out error
    is at least 20x below the nominal robot's, on the tracker and against the truth."""
    (tmp_path / "data").symlink_to(small / "data")
    sets = [{"name": kind, "formulation": kind} for kind in KINDS]
    sets.append({"name": "tracker", "formulation": "tracker", "use": "validation"})
    config = tmp_path / "calibration.yaml"
    config.write_text(yaml.safe_dump({"dataset": "data", "model": "DH", "sets": sets}))
    measured = calibrate(load_config(config))
    assert all(any(name.startswith(f"{kind}/") for name in measured.state.aux) for kind in KINDS)
    assert not any(name.startswith("tracker/") for name in measured.state.aux)  # never fitted
    before, after = (measured.validation[k]["tracker/tool_point"].rms for k in ("before", "after"))
    assert after * 20 <= before, (before, after)
    scored = scoring.score_with_truth(measured)
    truth_before, truth_after = (scored.validation[k]["tool_point"].rms for k in ("before", "after"))
    assert truth_after * 20 <= truth_before, (truth_before, truth_after)


@pytest.mark.study
def test_the_self_contained_study_meets_the_acceptance():
    """Seeds 1-3 of dual_arm_selfcontained: every kind alone, every pair and all together are
    reported; contacts, planes and cameras (the issue's kit, no gauge) and all four kinds, each
    scored on the tracker, lie within 1.5x of their prediction and at least 20x below the
    nominal robot; all four do at least as well as any kind alone. (Measured, tracker after /
    predicted: the three 0.92, 0.81, 1.02, 80-110x below nominal; all four 1.01-1.02. Seed 1's
    planes alone, 0.0278 mm, beat the three, 0.0303: its prediction assumes the lengths that
    carry the scale, which the planes cannot see, and their errors happen to be small there;
    seeds 2 and 3 give 0.28 and 0.82 mm.)"""
    rows = study([1, 2, 3])
    print(table(rows))
    for seed in (1, 2, 3):
        mine = {r.kinds: r for r in rows if r.seed == seed}
        assert set(mine) == set(combinations())
        for kit in (("self_contact", "planes", "self_observation"), KINDS):
            together = mine[kit]
            assert together.failed is None, together.failed
            assert 1 / 1.5 <= together.after_m / together.predicted_m <= 1.5, together
            assert together.after_m * 20 <= together.before_m, together
        singles = [r.after_m for kinds, r in mine.items() if len(kinds) == 1 and r.failed is None]
        assert mine[KINDS].after_m <= min(singles), (mine[KINDS], singles)


def test_a_gross_pixel_and_a_gross_gauge_reading_are_rejected_and_named(small, tmp_path):
    """Issue 39 trial: observed_pixels and tip_distances had no robust loss, so no rejection (one
    corner moved far gave chi2/dof 190,469). A pixel 60 px off (600 sigma) and a gauge reading
    1 mm off (200 sigma) in the fitting set are named in report.json's rejected measurements,
    and the estimate comes back near the clean one (against the truth)."""
    (tmp_path / "data").symlink_to(small / "data")
    sets = [{"name": kind, "formulation": kind} for kind in KINDS]
    config_path = tmp_path / "calibration.yaml"
    config_path.write_text(yaml.safe_dump({"dataset": "data", "model": "DH", "sets": sets}))
    config = load_config(config_path)
    dataset = load_dataset(tmp_path / "data")
    clean = calibrate_dataset(dataset, config)
    fit = {str(c) for c in np.asarray(dataset.configs)[clean.problem.fit]}
    damaged = copy.deepcopy(dataset)
    injected = set()
    for kind, shift in (("observed_pixels", np.array([60.0, 0.0])), ("tip_distances", np.array([1e-3]))):
        table = damaged.tables[kind]
        row = next(k for k, c in enumerate(table.ids["config"]) if str(c) in fit and k > 10)
        table.values[row] += shift
        injected.add((kind, str(table.ids["config"][row])))
    result = calibrate_dataset(damaged, config)
    doc = write_report(result, tmp_path / "report", plots=False)
    named = {(r["kind"], r["config"]) for r in doc["rejected_measurements"]}
    assert injected <= named, (injected, doc["rejected_measurements"])
    truth_clean, truth_damaged = (
        scoring.score_with_truth(r).validation["after"]["tool_point"].rms for r in (clean, result)
    )
    assert truth_damaged <= 1.3 * truth_clean, (truth_clean, truth_damaged)


def test_a_split_that_leaves_a_set_or_a_camera_no_fitting_image_is_refused(small, tmp_path):
    """Issue 39 trial: the simulated views come last, so an ordered split held every view out and
    the factor raised a ValueError (exit 1); a split leaving one camera no fitting image (while
    one image was refused) fitted without it and scored its never-fitted mounting."""
    from fgcal.calibration.formulations.self_observation import SelfObservation
    from fgcal.core.errors import InputError

    (tmp_path / "data").symlink_to(small / "data")
    sets = [{"name": kind, "formulation": kind} for kind in ("planes", "self_observation")]
    config = tmp_path / "calibration.yaml"
    doc = {"dataset": "data", "model": "DH", "sets": sets, "validation": {"split": "ordered"}}
    config.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match="none of its 60 configurations is in the fitting split"):
        calibrate(load_config(config))
    dataset = load_dataset(small / "data")
    table = dataset.tables["observed_pixels"]
    right = {c for c, camera in zip(table.ids["config"], table.ids["camera"], strict=True) if camera == "right_eye"}
    fit = np.array([i for i, c in enumerate(dataset.configs) if str(c) not in right])
    settings = load_config(config).measurement
    with pytest.raises(InputError, match="camera 'right_eye' is in 0 images of the fitting set"):
        SelfObservation().fit_observations(dataset, settings, fit)


def test_a_validation_set_noise_stated_far_too_large_is_said(small, tmp_path):
    """Issue 39 trial: a tracker validating with its noise typed in mm in a config in m (0.015:
    15 mm) headlined 'after 0.0303 mm (predicted 26.01 mm)' without a word (its residuals are
    never fitted, so never checked against its noise)."""
    (tmp_path / "data").symlink_to(small / "data")
    sets = [{"name": kind, "formulation": kind} for kind in ("planes", "tip_gauge")]
    for sigma, warned in ((0.015, True), (1.5e-5, False)):
        tracker = {"name": "tracker", "formulation": "tracker", "use": "validation", "noise": {"tracker_sigma": sigma}}
        config = tmp_path / "calibration.yaml"
        config.write_text(yaml.safe_dump({"dataset": "data", "model": "DH", "sets": [*sets, tracker]}))
        doc = write_report(calibrate(load_config(config)), tmp_path / f"r{sigma}", plots=False)
        said = [w for w in doc["warnings"] if "times smaller than the measurement noise its prediction declares" in w]
        assert bool(said) == warned, doc["warnings"]
