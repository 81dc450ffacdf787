"""Several measurement sets in one calibration (a config's sets:): the estimate equals the graph
built by hand from the sets' formulations' factors, and a validation set's held-out score lies
near its prediction through the registration of its own unknowns."""

from __future__ import annotations

import dataclasses
import shutil

import gtsam
import numpy as np
import pytest
import yaml
from conftest import merge_datasets

from fgcal.calibration.config import load_config
from fgcal.calibration.formulations import REGISTRY
from fgcal.calibration.formulations.sets import Combined
from fgcal.calibration.problem import Keys
from fgcal.calibration.run import calibrate
from fgcal.calibration.settings import Noise
from fgcal.core.errors import InputError
from fgcal.factors import ParameterBoundFactor
from fgcal.reports.headline import warnings


@pytest.fixture(scope="module")
def two_sets(bundled_sim, tmp_path_factory):
    """A tracker's and a ballbar's measurements of one IRB 120 (the bundled cells, seed 2: the
    same true robot), in one dataset folder."""
    root = tmp_path_factory.mktemp("two_sets")
    sources = {"tracker": bundled_sim("irb120_tracker", 2), "bar": bundled_sim("irb120_ballbar", 2)}
    return merge_datasets(sources, root / "data")


def _config(root, sets: list[dict], **extra):
    path = root / "calibration.yaml"
    path.write_text(yaml.safe_dump({"dataset": "data", "model": "DH,s,e", "sets": sets, **extra}))
    return load_config(path)


def test_two_sets_give_the_estimate_of_the_graph_built_by_hand(two_sets):
    """A tracker set and a ballbar set, least squares: the calibration's estimate equals GTSAM's
    Levenberg-Marquardt on the graph of the two formulations' own measurement sets and the
    parameters' priors, built here from the formulations' protocol alone, at the released
    parameters the calibration chose."""
    sets = [
        {"name": "tracker", "formulation": "tracker", "robust": {"tracker_points": "none"}},
        {"name": "bar", "formulation": "distances", "robust": {"distances": "none"}},
    ]
    config = _config(two_sets.parent, sets, schedule="one_shot")
    result = calibrate(config)
    problem, released = result.problem, result.released
    assert set(result.state.aux) == {"tracker/tracker", "tracker/tool_points", "bar/tool_points", "bar/pivots"}
    assert len(released) > 20 and not problem.rejected

    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    p_key = gtsam.symbol("q", 0)
    nominal = problem.robot.nominal_parameters()
    start = problem.robot.parameter_vector()
    index = [problem.robot.parameter_names.index(n) for n in released]
    values.insert(p_key, start[index])
    bounded = [i for i, n in enumerate(released) if problem.priors.sigma(n) is not None]
    graph.add(ParameterBoundFactor(p_key, len(released), np.array(bounded), np.array([nominal[released[i]] for i in
              bounded]), np.array([problem.priors.sigma(released[i]) for i in bounded])).factor)  # fmt: skip
    views, n = [], 0
    for k, (name, formulation) in enumerate((("tracker", "tracker"), ("bar", "distances"))):
        # The noise in effect: the dataset's (the instruments'), the set's own winning.
        stated = config.sets[k].measurement
        settings = dataclasses.replace(stated, noise=Noise.stated(problem.dataset.noise, stated.noise_stated))
        view = dataclasses.replace(problem, formulation=REGISTRY[formulation](), settings=settings)
        view = dataclasses.replace(view, observations=view.formulation.fit_observations(view.dataset, view.settings,
                                                                                         problem.fit))  # fmt: skip
        state = view.formulation.initial_state(view)
        aux_keys = {}
        for aux_name, aux in state.aux.items():
            aux_keys[aux_name] = gtsam.symbol("a", n)
            values.insert(aux_keys[aux_name], aux.to_gtsam())
            n += 1
        # The parameters not released at the calibration's values (those it fixed at their estimates).
        kinematics = view.kinematics(state.with_params(result.state.params), released, view.observations)
        for s in view.formulation.measurement_sets(view, view.observations, kinematics, Keys(p_key, aux_keys), state,
                                                   None):  # fmt: skip
            graph.add(s.factor().factor)
        views.append((name, aux_keys, state))
    params = gtsam.LevenbergMarquardtParams()
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-16)
    params.setMaxIterations(200)
    solved = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    by_hand = solved.atVector(p_key)
    estimate = result.state.params[index]
    sigmas = np.sqrt(np.diag(result.covariance_declared.block(["P"])))
    # The same minimum: every parameter within a thousandth of its sigma.
    assert np.max(np.abs(by_hand - estimate) / sigmas) < 1e-3, np.max(np.abs(by_hand - estimate) / sigmas)
    for name, aux_keys, state in views:
        for aux_name, key in aux_keys.items():
            mine = state.aux[aux_name].from_values(solved, key).value
            np.testing.assert_allclose(result.state.value(f"{name}/{aux_name}"), mine, atol=1e-7)
    assert {"tracker/tool_point", "bar/distance", "tool_point"} <= set(result.validation["after"])

    # Each set's residuals against its own noise: a tracker sigma declared 20x too small is said.
    members = problem.formulation.members
    small = dataclasses.replace(members[0].settings.noise, tracker_m=members[0].settings.noise.tracker_m / 20)
    wrong = Combined([dataclasses.replace(members[0], settings=dataclasses.replace(members[0].settings, noise=small)),
                      members[1]])  # fmt: skip
    said = warnings(dataclasses.replace(result, problem=dataclasses.replace(problem, formulation=wrong)))
    assert not any("declared noise" in w for w in warnings(result))
    assert len(said) == 1 and said[0].startswith("set tracker's residuals are"), said


@pytest.mark.parametrize(
    ("sets", "extra", "field"),
    [
        ([{"name": "a", "formulation": "tracker"}, {"name": "a", "formulation": "distances"}], {}, "sets[1].name"),
        ([{"name": "a", "formulation": "tracker", "use": "validation"}], {}, "sets"),
        ([{"name": "a", "formulation": "touch"}], {}, "sets[0].formulation"),
        ([{"name": "a", "formulation": "tracker"}], {"noise": {"tracker_sigma": 0.01}}, "noise"),
        ([{"name": "a", "formulation": "tracker", "noise": {"touch_sigma": 0.01}}], {}, "sets[0].noise.touch_sigma"),
    ],
)
def test_bad_sets_are_refused_naming_the_field(two_sets, sets, extra, field):
    with pytest.raises(InputError) as error:
        _config(two_sets.parent, sets, **extra)
    assert error.value.field == field


def _validation_run_fit_ids(data):
    """The fitting configurations' ids of the default split of ``data``."""
    from fgcal.calibration.problem import split
    from fgcal.data.dataset import load_dataset

    dataset = load_dataset(data)
    fit, _ = split(len(dataset.configs), 0.25, 0)
    return dataset.configs[fit]


def _validation_run(root):
    sets = [{"name": "tracker", "formulation": "tracker"},
            {"name": "bar", "formulation": "distances", "use": "validation"}]  # fmt: skip
    return calibrate(_config(root, sets, schedule="one_shot"))


def test_a_validation_set_is_scored_not_fitted_within_its_prediction(two_sets, tmp_path):
    """A tracker set fits, a ballbar set validates: the ballbar's readings are not in the fit
    (neither its rows nor its unknowns), its ball and pivots are registered on its fitting
    configurations with the robot held at the calibration, and its held-out RMS lies within 1.5x
    of the prediction through that registration (the headline's score: the validation set's). A
    tracker reading 5 mm off is rejected, in the tracker set's own robust units."""
    shutil.copytree(two_sets, tmp_path / "data")
    table = tmp_path / "data" / "tracker_points.csv"
    lines = table.read_text().splitlines()
    fitted = {str(c) for c in _validation_run_fit_ids(two_sets)}
    row = next(i for i, line in enumerate(lines[1:], 1) if line.split(",")[0] in fitted)
    cells = lines[row].split(",")
    cells[2] = repr(float(cells[2]) + 0.005)
    lines[row] = ",".join(cells)
    table.write_text("\n".join(lines) + "\n")
    result = _validation_run(tmp_path)
    problem = result.problem
    assert [(r.config, r.kind, r.name) for r in problem.rejected] == [(cells[0], "tracker_points", cells[1])]
    tracker = problem.formulation.parts(problem)[0]
    assert problem.n_residuals == tracker.problem.n_residuals
    assert set(result.state.aux) == {"tracker/tracker", "tracker/tool_points"}
    after, before = result.validation["after"]["distance"], result.validation["before"]["distance"]
    assert after.rms == result.validation["after"]["bar/distance"].rms
    assert "tool_point" not in result.validation["after"]
    assert after.rms < before.rms / 10
    assert 1 / 1.5 <= after.rms / result.prediction.rms <= 1.5, (after.rms, result.prediction)


@pytest.mark.study
def test_a_validation_sets_score_lies_within_its_prediction_over_seeds(tmp_path):
    """The same on four seeds, the two cells carrying the same payload (one true robot): the
    ballbar's held-out RMS over the seeds within 1.5x of its predicted RMS over them (one seed's
    ratio spreads: its parameter error is one draw)."""
    from conftest import REPO

    from fgcal.simulation.simulate import simulate

    cells = REPO / "datasets" / "cells"
    tracker = yaml.safe_load((cells / "irb120_tracker.yaml").read_text())
    bar = yaml.safe_load((cells / "irb120_ballbar.yaml").read_text())
    bar["payload"] = tracker["payload"]
    measured, predicted = [], []
    for seed in (3, 4, 5, 6):
        root = tmp_path / str(seed)
        root.mkdir()
        sources = {}
        for name, doc in (("tracker", tracker), ("bar", bar)):
            (root / f"{name}.yaml").write_text(yaml.safe_dump(doc))
            simulate(root / f"{name}.yaml", root / name, seed=seed)
            sources[name] = root / name
        merge_datasets(sources, root / "data")
        result = _validation_run(root)
        measured.append(result.validation["after"]["distance"].rms)
        predicted.append(result.prediction.rms)
    ratio = np.sqrt(np.mean(np.square(measured)) / np.mean(np.square(predicted)))
    assert 1 / 1.5 <= ratio <= 1.5, (measured, predicted)


@pytest.mark.study
def test_a_validation_set_held_out_whole_is_registered_on_its_held_out_configurations(bundled_sim, tmp_path):
    """The tracker's configurations last and the run's last quarter held out (split: ordered): the
    split leaves the validation set no fitting configuration, so its unknowns are registered on
    its held-out ones, which the report says; its score still lies within 1.5x of its
    prediction, which counts the registration's fit to the same rows."""
    merge_datasets({"bar": bundled_sim("irb120_ballbar", 2), "tracker": bundled_sim("irb120_tracker", 2)},
                   tmp_path / "data")  # fmt: skip
    sets = [{"name": "bar", "formulation": "distances"},
            {"name": "tracker", "formulation": "tracker", "use": "validation"}]  # fmt: skip
    result = calibrate(_config(tmp_path, sets, validation={"split": "ordered", "holdout": 0.25}))
    assert result.problem.observations.registered_on == ("", "held-out")
    after = result.validation["after"]["tool_point"]
    assert 1 / 1.5 <= after.rms / result.prediction.rms <= 1.5, (after.rms, result.prediction)


def test_a_ballbar_cell_with_a_tracker_simulates_both_and_its_config_runs(tmp_path):
    """Issue 39 trial: irb120_ballbar.yaml with a tracker: block simulated the ballbar only, without a word, and
    with validation: [tracker] wrote a config whose tracker set failed at calibrate (exit 2). The tracker's
    reflectors are simulated at the same configurations, and the suggested config runs, the tracker scored."""
    from conftest import REPO

    from fgcal.calibration.suggest import write_suggested_config
    from fgcal.data.dataset import load_dataset
    from fgcal.simulation.cell import load_cell
    from fgcal.simulation.simulate import simulate

    cells = REPO / "datasets" / "cells"
    cell = yaml.safe_load((cells / "irb120_ballbar.yaml").read_text())
    cell["tracker"] = yaml.safe_load((cells / "irb120_tracker.yaml").read_text())["tracker"]
    cell["validation"] = ["tracker"]
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(cell))
    simulated = simulate(tmp_path / "cell.yaml", tmp_path / "sim", seed=1)
    assert simulated.n_observations["tracker_points"] == simulated.n_configurations * len(cell["tracker"]["targets"])
    config = write_suggested_config(load_cell(tmp_path / "cell.yaml"), load_dataset(tmp_path / "sim"))
    assert [s["use"] for s in yaml.safe_load(config.read_text())["sets"] if s["name"] == "tracker"] == ["validation"]
    result = calibrate(load_config(config))
    before, after = (result.validation[k]["tracker/tool_point"].rms for k in ("before", "after"))
    assert after < before / 5, (before, after)


def test_a_validation_set_with_nothing_held_out_is_scored_on_all_its_configurations(two_sets, tmp_path):
    """Issue 39 trial: with validation: {holdout: 0} a validation set was never scored, silently (its row all
    dashes). Never fitted, it is scored on all its configurations, its unknowns registered on the same rows,
    near the prediction through that registration (1.53x on this draw: one parameter error, the ratio spreads
    over seeds, as test_a_validation_sets_score_lies_within_its_prediction_over_seeds shows); the report says so."""
    from fgcal.reports.calibration import write_report

    shutil.copytree(two_sets, tmp_path / "data")
    sets = [{"name": "tracker", "formulation": "tracker"},
            {"name": "bar", "formulation": "distances", "use": "validation"}]  # fmt: skip
    result = calibrate(_config(tmp_path, sets, schedule="one_shot", validation={"holdout": 0}))
    assert not len(result.problem.test)
    after, before = result.validation["after"]["bar/distance"], result.validation["before"]["bar/distance"]
    assert after.errors.size == result.problem.observations.parts[1].n_residuals
    assert after.rms < before.rms / 10
    assert 1 / 2 <= after.rms / result.prediction.rms <= 2, (after.rms, result.prediction)
    doc = write_report(result, tmp_path / "report", plots=False)
    assert [s["registered_on"] for s in doc["sets"]["sets"] if s["name"] == "bar"] == ["all"]
