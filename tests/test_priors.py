"""Priors for every parameter kind (issue 38): a config's bounds: states a prior sigma per class,
kind or parameter, in its units; it is a factor of the graph, information for the
identifiability analysis, and reported with the estimates."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SEED_CELL, calibrate

import fgcal
from fgcal.calibration.config import CalibrationConfig, parse_config
from fgcal.reports.calibration import report_dict
from fgcal.simulation.simulate import simulate

TRACKER_CELL = SEED_CELL.parent / "irb120_tracker.yaml"


def test_the_most_specific_prior_wins_in_the_configs_units(tmp_path):
    raw = {"dataset": "d", "units": {"length": "mm", "angle": "deg"},
           "bounds": {"length": 2.0, "angle": 0.5, "alpha": 0.1, "alpha3": 0.01, "kz": 1e-5, "lm": 0.02, "base.tx": 1}}
    priors = parse_config(raw, tmp_path / "c.yaml").priors
    assert priors.sigma("d2") == pytest.approx(2e-3) and priors.sigma("a3") == pytest.approx(2e-3)
    assert priors.sigma("theta1") == pytest.approx(np.radians(0.5))
    assert priors.sigma("alpha2") == pytest.approx(np.radians(0.1))
    assert priors.sigma("alpha3") == pytest.approx(np.radians(0.01))
    assert priors.sigma("kz2") == pytest.approx(np.radians(1e-5))  # angle units per N m
    assert priors.sigma("lm4") == pytest.approx(np.radians(0.02))
    assert priors.sigma("base.tx") == pytest.approx(1e-3) and priors.sigma("base.rx") is None  # base: by name only
    default = parse_config({"dataset": "d"}, tmp_path / "c.yaml").priors
    assert default.sigma("d2") == 0.01 and default.stated("d2") is None and default.sigma("theta1") is None
    assert default.sigma("lv3") == pytest.approx(np.radians(0.5))


@pytest.mark.parametrize(
    ("bounds", "field"),
    [({"warp": 1.0}, "bounds.warp"), ({"alpha": -1.0}, "bounds.alpha"), ({"alpha": None}, "bounds.alpha")],
)
def test_a_bad_prior_names_its_field(tmp_path, bounds, field):
    with pytest.raises(fgcal.InputError, match=field.replace(".", r"\.")):
        parse_config({"dataset": "d", "bounds": bounds}, tmp_path / "c.yaml")


def test_a_parameter_the_robot_does_not_have_is_refused(tmp_path):
    simulate(TRACKER_CELL, tmp_path / "data", seed=1, n_configurations=30)
    config = CalibrationConfig.defaults(tmp_path / "data", formulation="tracker", bounds={"alpha9": 0.1})
    with pytest.raises(fgcal.InputError, match=r"bounds\.alpha9.*not a parameter of ABB IRB 120"):
        calibrate(config)


def test_a_stated_prior_holds_a_parameter_and_determines_a_weak_direction(tmp_path):
    """A tight prior keeps its parameter at nominal; a prior determines what a noise declared 300x
    too large left fixed (alpha4, sx5 on irb120_tracker), as a ridge term would; the report lists
    the priors in effect."""
    simulate(TRACKER_CELL, tmp_path / "data", seed=1)
    noisy = {"tracker_sigma": 3e-3}
    free = calibrate(CalibrationConfig.defaults(tmp_path / "data", formulation="tracker", noise=noisy))
    assert "alpha4" not in free.released and free.fixed_evidence_sigmas["alpha4"] > 10
    ridge = calibrate(CalibrationConfig.defaults(
        tmp_path / "data", formulation="tracker", noise=noisy, bounds={"alpha": 1e-3},
    ))  # fmt: skip
    assert "alpha4" in ridge.released
    rms = [r.validation["after"]["tool_point"].rms for r in (free, ridge)]
    assert rms[1] < rms[0], rms
    names = free.problem.robot.parameter_names
    held = calibrate(CalibrationConfig.defaults(tmp_path / "data", formulation="tracker", bounds={"theta2": 1e-9}))
    plain = calibrate(CalibrationConfig.defaults(tmp_path / "data", formulation="tracker"))
    i = names.index("theta2")
    nominal = plain.problem.robot.nominal_parameters()["theta2"]
    assert abs(held.state.params[i] - nominal) < 1e-10 < abs(plain.state.params[i] - nominal)
    entry = report_dict(held)["parameters"]
    assert entry["theta2"]["prior"] == "stated" and entry["theta2"]["prior_sigma"] == pytest.approx(1e-9)
    assert entry["d4"]["prior"] == "soft bound" and entry["d4"]["prior_sigma"] == 0.01


def test_a_prior_keeps_its_sigma_when_the_noise_is_scaled(tmp_path, capsys):
    """When chi2/dof scales the measurements' noise, a parameter only its stated prior
    determines keeps the prior's sigma (the whole covariance was scaled: base.tz read 3.6 mm
    under a 0.5 mm prior); one the data determine is scaled by sqrt(chi2/dof)."""
    import json

    from fgcal.commands.cli import main

    assert main(["simulate", "dual_arm_tracker", "--out", str(tmp_path / "sim"), "--n", "120", "--seed", "1"]) == 0
    # A declared noise a tenth of the simulation's (0.015 mm): chi2/dof about 100, whatever the model.
    (tmp_path / "u.yaml").write_text("dataset: sim\nformulation: tracker\nunits: {length: mm, angle: deg}\n"
                                     "noise: {tracker_sigma: 0.0015}\n"
                                     "bounds: {base.tz: 0.5, d2: 0.2, alpha: 0.01}\n")  # fmt: skip
    assert main(["calibrate", str(tmp_path / "u.yaml"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    capsys.readouterr()
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    factor = report["goodness_of_fit"]["variance_factor"]
    assert factor > 10  # the declared noise does not explain the fit
    p = report["parameters"]
    assert abs(p["base.tz"]["sigma"] / 5e-4 - 1) < 1e-6  # nothing but the prior determines base.tz
    assert p["alpha2"]["sigma"] <= p["alpha2"]["prior_sigma"] * (1 + 1e-6)
    a2 = p["a2"]  # well determined by the data: its sigma scales with the noise
    assert abs(a2["sigma"] / (a2["sigma_declared_noise"] * factor**0.5) - 1) < 0.05


def test_parameters_held_from_an_earlier_stage_are_said(tmp_path, capsys):
    """stages: [[theta], [a]]: the thetas move in the first stage and the last holds them. They
    read "fixed", with no sigma and no reason, and the prediction left their uncertainty out;
    now their status names the stage, and the headline warns."""
    import json

    from fgcal.commands.cli import main

    assert main(["simulate", "irb120_tracker", "--out", str(tmp_path / "sim"), "--n", "60", "--seed", "1"]) == 0
    (tmp_path / "s.yaml").write_text("dataset: sim\nformulation: tracker\nstages: [[theta], [a]]\n")
    assert main(["calibrate", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "out"), "--no-plots"]) == 0
    capsys.readouterr()
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    p = report["parameters"]
    held = [n for n, e in p.items() if e["status"].startswith("held at stage")]
    assert "theta2" in held and all(p[n]["sigma"] is None and n.startswith("theta") for n in held)
    assert p["a2"]["status"] == "estimated"
    assert any("estimated in an earlier stage and held there" in w for w in report["warnings"])
