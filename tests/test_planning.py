"""fgcal plan (issue 14): rank-r updates, gains, indices, the command and simulating a plan."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from conftest import SEED_CELL

from fgcal.commands.cli import main
from fgcal.planning.exchange import DesignState, _d_gains, _position_gains, information_of, plan_design
from fgcal.planning.indices import observability
from fgcal.planning.information import Information


def _synthetic(rng: np.random.Generator, n_candidates: int = 60, r: int = 4, m: int = 5, n_aux: int = 2):
    region = rng.normal(size=(30, m + n_aux))
    region[:, m:] = 0.0
    return Information(
        names=[f"p{i}" for i in range(m)],
        aux_labels=[f"a{i}" for i in range(n_aux)],
        rows=rng.normal(size=(n_candidates, r, m + n_aux)),
        prior=np.full(m + n_aux, 1e-2),
        region=region,
        scale=np.ones(m),
        unidentifiable={},
        sigma_m=1e-4,
        gauge="none",
    )


def _logdet_schur(M: np.ndarray, m: int) -> float:
    return np.linalg.slogdet(M)[1] - np.linalg.slogdet(M[m:, m:])[1]


def test_rank_updates_match_direct_inverse():
    info = _synthetic(np.random.default_rng(0))
    state = DesignState.empty(info)
    for c in (3, 7, 11, 20, 21):
        state.add(c)
    state.remove(7)
    state.remove(21)
    M = information_of(info, [3, 11, 20])
    np.testing.assert_allclose(state.M, M, atol=1e-12)
    np.testing.assert_allclose(state.M_inv, np.linalg.inv(M), rtol=1e-8, atol=1e-10)


def test_gains_match_recomputed_criteria():
    info = _synthetic(np.random.default_rng(1))
    state = DesignState.empty(info)
    for c in (0, 1, 2):
        state.add(c)
    W = info.region.T @ info.region
    d, position = _d_gains(state, info.rows), _position_gains(state, info.rows, W)
    for c in (5, 17, 40):
        M_new = information_of(info, [0, 1, 2, c])
        assert d[c] == pytest.approx(_logdet_schur(M_new, 5) - _logdet_schur(state.M, 5), rel=1e-9)
        before, after = np.trace(W @ state.M_inv), np.trace(W @ np.linalg.inv(M_new))
        assert position[c] == pytest.approx(before - after, rel=1e-9)


@pytest.mark.parametrize("criterion", ["d-optimal", "position", "o3"])
def test_exchange_beats_greedy_and_random(criterion):
    info = _synthetic(np.random.default_rng(2), n_candidates=80)
    chosen, greedy = plan_design(info, 6, criterion)
    assert len(set(chosen)) == 6 and len(greedy) == 6

    def value(design):
        M = information_of(info, design)
        if criterion == "d-optimal":
            return _logdet_schur(M, 5)
        if criterion == "position":
            return -np.trace(info.region.T @ info.region @ np.linalg.inv(M))
        return observability(M, info, 24)["O3"]

    randoms = [value(np.random.default_rng(k).choice(80, 6, replace=False)) for k in range(20)]
    assert value(chosen) >= value(greedy) - 1e-12
    assert value(chosen) > max(randoms)


def test_observability_indices_of_known_singular_values():
    info = _synthetic(np.random.default_rng(3), m=3, n_aux=0)
    s = np.array([4.0, 2.0, 0.5])
    M = np.diag(s**2 + info.prior)
    indices = observability(M, info, n_rows=16, with_prior=False)
    assert indices["O1"] == pytest.approx(np.prod(s) ** (1 / 3) / 4)
    assert indices["O2"] == pytest.approx(0.5 / 4)
    assert indices["O3"] == pytest.approx(0.5)
    assert indices["O4"] == pytest.approx(0.25 / 4)
    assert indices["O5"] == pytest.approx(1 / (1 / 4 + 1 / 2 + 2))
    assert indices["condition_number"] == pytest.approx(8.0)


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan")
    assert main(["plan", str(SEED_CELL), "--n", "24", "--candidates", "600", "--out", str(out / "plan")]) == 0
    return out


def test_plan_command_writes_its_files(planned):
    plan = json.loads((planned / "plan" / "plan.json").read_text())
    header = (planned / "plan" / "configurations.csv").read_text().splitlines()
    assert header[0] == "config,q1,q2,q3,q4,q5,q6,block" and len(header) == 25
    assert plan["n_configurations"] == 24 and plan["n_candidates"] == 600
    # The exchange algorithm's design is predicted better than a space-filling one of its size.
    assert plan["predicted_position_sigma_rms_m"] < plan["space_filling_same_n_sigma_rms_m"]
    assert set(plan["observability"]) == {"O1", "O2", "O3", "O4", "O5", "condition_number"}
    assert "theta2" in plan["parameters"] and "base.tx" in plan["unidentifiable"]
    assert (planned / "plan" / "predicted_accuracy.png").stat().st_size > 10_000
    assert "mm RMS" in (planned / "plan" / "plan.md").read_text()


def test_simulate_a_plan_exactly_with_the_same_truth(planned, tmp_path):
    configurations = planned / "plan" / "configurations.csv"
    assert (
        main(["simulate", str(SEED_CELL), "--configurations", str(configurations), "--out", str(tmp_path / "a")]) == 0
    )
    assert main(["simulate", str(SEED_CELL), "--design", "seed", "--out", str(tmp_path / "b")]) == 0
    q_plan = np.loadtxt(configurations, delimiter=",", skiprows=1, usecols=range(1, 7))
    q_sim = np.loadtxt(tmp_path / "a" / "configurations.csv", delimiter=",", skiprows=1, usecols=range(1, 7))
    # Configurations whose block the true camera does not see are left out (and said so).
    assert len(q_sim) >= 20
    assert all(np.min(np.abs(q_plan - q).max(axis=1)) < 1e-12 for q in q_sim)
    truth = [yaml.safe_load((tmp_path / d / "truth" / "ground_truth.yaml").read_text()) for d in ("a", "b")]
    assert truth[0]["parameters"] == truth[1]["parameters"]


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda rows: [rows[0], rows[1].rsplit(",", 1)[0] + ",Z+z_r00c00"], "column block"),
        (lambda rows: [rows[0], "p0," + ",".join(["9.0"] * 6) + ",A+z_r00c00"], "line 2"),
        (lambda rows: [rows[0].replace("q6", "q7"), *rows[1:]], "q6"),
        (lambda rows: [rows[0], ",".join([rows[1].split(",")[0], "nan", *rows[1].split(",")[2:]])], "must be finite"),
    ],
)
def test_bad_configurations_file(planned, tmp_path, capsys, edit, field):
    rows = (planned / "plan" / "configurations.csv").read_text().splitlines()
    path = tmp_path / "configurations.csv"
    path.write_text("\n".join(edit(rows)) + "\n")
    code = main(["simulate", str(SEED_CELL), "--configurations", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "configurations.csv" in err and field in err and "Traceback" not in err


def test_plan_bad_sizes_are_clear_errors(tmp_path, capsys):
    assert main(["plan", str(SEED_CELL), "--n", "2", "--candidates", "100", "--out", str(tmp_path)]) == 2
    assert "plan more configurations" in capsys.readouterr().err
    assert main(["plan", str(SEED_CELL), "--n", "10", "--candidates", "0", "--out", str(tmp_path)]) == 2
    assert main(["plan", str(SEED_CELL), "--n", "10", "--criterion", "best", "--out", str(tmp_path)]) == 2
    assert "argument --criterion: invalid choice: 'best'" in capsys.readouterr().err


def test_tracker_plan(tmp_path):
    out = tmp_path / "plan"
    argv = ["plan", str(SEED_CELL), "--n", "20", "--candidates", "500", "--formulation", "tracker", "--out", str(out)]
    assert main([*argv, "--no-plots"]) == 0
    plan = json.loads((out / "plan.json").read_text())
    assert "tracker.tx" in plan["auxiliary_unknowns"] and "reflector1.x" in plan["auxiliary_unknowns"]
    assert plan["predicted_position_sigma_rms_m"] < plan["space_filling_same_n_sigma_rms_m"]
    assert (out / "configurations.csv").read_text().splitlines()[0] == "config,q1,q2,q3,q4,q5,q6"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    from fgcal.planning.study import design_study

    return design_study(SEED_CELL, tmp_path_factory.mktemp("study"), seeds=(1, 2, 3))


@pytest.mark.study
def test_planned_36_beat_the_seed_design(study):
    """Issue 14: 36 planned configurations reach at most 0.5x the RMS of the seed's 36-image
    design (scored on the truth at 200 independent configurations, translation gauge removed),
    mean over seeds 1-3."""
    seeds = study["seeds"]
    planned = np.mean([row["planned"][36]["rms_m"] for row in seeds])
    seed_design = np.mean([row["seed_design_m"] for row in seeds])
    assert planned <= 0.5 * seed_design, (planned, seed_design)


@pytest.mark.study
@pytest.mark.xfail(reason="issue 14 open: the planned design reaches 3e-5 m at ~0.7x, not 1/3, of the space-filling N")
def test_planned_reach_3e5_with_a_third_of_the_configurations(study):
    seeds = study["seeds"]
    planned = np.mean([row["planned_n_reaching_m"] for row in seeds])
    space_filling = np.mean([row["space_filling_n_reaching_m"] for row in seeds])
    assert planned <= space_filling / 3, (planned, space_filling)


TRACKER_CELL = SEED_CELL.parent / "irb120_tracker.yaml"


def test_tracker_cell_simulates_plans_and_calibrates(tmp_path):
    """A cell with no camera and no objects: joint-space designs, tracker points only, a plan
    for the tracker formulation simulated exactly and calibrated against the truth."""
    from conftest import calibrate

    from fgcal.calibration.config import CalibrationConfig
    from fgcal.data.dataset import load_dataset

    assert main(["plan", str(TRACKER_CELL), "--n", "30", "--candidates", "800", "--formulation", "tracker",
                 "--out", str(tmp_path / "plan"), "--no-plots"]) == 0  # fmt: skip
    configurations = tmp_path / "plan" / "configurations.csv"
    assert (
        main(["simulate", str(TRACKER_CELL), "--configurations", str(configurations), "--out", str(tmp_path / "a")])
        == 0
    )
    dataset = load_dataset(tmp_path / "a")
    assert set(dataset.tables) == {"tracker_points"} and len(dataset.q) == 30
    q_plan = np.loadtxt(configurations, delimiter=",", skiprows=1, usecols=range(1, 7))
    np.testing.assert_allclose(dataset.q, q_plan, atol=1e-12)
    result = calibrate(CalibrationConfig.defaults(tmp_path / "a", formulation="tracker"))
    before, after = result.validation["before"]["tool_point"].rms, result.validation["after"]["tool_point"].rms
    assert after < before / 20, (before, after)
    assert main(["simulate", str(TRACKER_CELL), "--design", "seed", "--out", str(tmp_path / "b")]) == 2


@pytest.mark.parametrize(
    ("cell", "formulation", "status", "planned"),
    [
        ("irb120_tracker", None, 0, "tracker"),  # crashed without --formulation
        ("kr125_seed", None, 0, "pairs"),
        ("irb120_static_camera", None, 0, "static_camera"),  # issue 42: planned through its protocol
        ("seven_axis_touch", None, 2, "plan more configurations"),  # issue 42: planned (8 touches are too few)
        ("irb120_ballbar", None, 2, "plan more configurations"),  # issue 42: planned (8 readings are too few)
        ("irb120_ball_pairs", None, 2, "not planned yet"),  # readings between configurations
        ("irb120_ballbar", "tracker", 2, "needs a tracker"),  # planned for a tracker the cell has not
        ("irb120_tracker", "pairs", 2, "needs a camera"),
        ("kr125_seed", "touch", 2, "needs a touch"),
        ("kr125_seed", "sonar", 2, "unknown formulation"),
    ],
)
def test_plan_chooses_what_the_cell_measures_with(tmp_path, capsys, cell, formulation, status, planned):
    """Issue 22, item 3: without --formulation fgcal plan plans for the cell's instrument; a
    formulation the cell cannot measure, or that the planner does not model, is a clear error."""
    argv = ["plan", cell, "--n", "8", "--out", str(tmp_path / "p"), "--candidates", "100", "--no-plots"]
    assert main([*argv, *(["--formulation", formulation] if formulation else [])]) == status
    _, err = capsys.readouterr()
    if status == 0:
        assert json.loads((tmp_path / "p" / "plan.json").read_text())["formulation"] == planned
    else:
        assert planned in err and "Traceback" not in err, err
