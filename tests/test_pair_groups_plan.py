"""The pair groups a plan prescribes (issue 42): the calibration fits the groups a file names
(``pairs.groups``), the planner's information of a grouping is the information the
calibration's point-pair rows carry, and the planner's swaps never make its grouping worse."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import SEED_CELL

from fgcal.calibration.formulations.pairs import pair_observations
from fgcal.core.errors import InputError
from fgcal.core.se3 import inverse, transform_points
from fgcal.factors import PointPairs
from fgcal.model import kinematics
from fgcal.planning.groups import group_information, improve_groups, plan_groups, random_groups, variance


@pytest.fixture(scope="module")
def small_plan():
    """A plan of 12 configurations of the seed cell from 300 candidates."""
    from fgcal.planning.plan import plan, prepare

    planner = prepare(SEED_CELL, 300, formulation="pairs", seed=3, reference_size=150)
    return planner, plan(SEED_CELL, 12, planner=planner, curve_max=0)


class _Fixed:
    """Kinematics at fixed poses and body Jacobians (factors.kinematics.Kinematics)."""

    def __init__(self, poses, jacobians):
        self._poses, self._jacobians, self.n_released = poses, jacobians, jacobians.shape[2]

    def poses(self, _values):
        return self._poses

    def jacobians(self, _values):
        return self._jacobians


def test_planner_information_of_groups_is_the_point_pair_rows_information(small_plan):
    planner, result = small_plan
    info, cell, robot = planner.info, planner.cell, planner.cell.robot
    chosen = result.chosen
    q, p_F = planner.candidates.q[chosen], planner.candidates.points_F[chosen]
    data = kinematics.forward(robot, robot.parameter_vector(), q)
    T_W_C = kinematics.frame_pose(robot, data, "tool")
    J_body = kinematics.jacobian(robot, data, info.names, frame="tool")
    c = transform_points(inverse(T_W_C)[:, None], transform_points(cell.fixture_pose[None, None], p_F))
    groups = [[0, 5, 7], [1, 2, 3, 4], [6, 8], [9, 10, 11]]
    sigma = info.sigma_m
    factor = PointPairs(
        _Fixed(T_W_C, J_body),
        0,
        [(np.repeat(g, 4), c[g].reshape(-1, 3), p_F[g].reshape(-1, 3)) for g in groups],
        sigma,
        fixture_rotation=cell.fixture_pose[:3, :3],
    )
    B = factor.compute([np.zeros(len(info.names))], True).blocks[0] / sigma
    m = info.n_params
    M = group_information(info, chosen, groups) - info.prior_matrix
    expected = B.T @ B
    assert np.allclose(M[:m, :m], expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    # The fixture's position is each group's common translation: the pairs carry nothing of it.
    assert np.allclose(M[m:], 0.0, atol=1e-9 * np.abs(expected).max())


def test_swaps_never_make_the_grouping_worse(small_plan):
    planner, result = small_plan
    info, chosen = planner.info, result.chosen
    rng = np.random.default_rng(0)
    for _ in range(3):
        start = random_groups(len(chosen), 4, rng)
        improved = improve_groups(info, chosen, start)
        assert sorted(j for g in improved for j in g) == list(range(len(chosen)))
        assert sorted(map(len, improved)) == sorted(map(len, start))
        before = variance(info, group_information(info, chosen, start))
        assert variance(info, group_information(info, chosen, improved)) <= before
    assert improve_groups(info, chosen[:3], [[0, 1, 2]]) == [[0, 1, 2]]  # one group: nothing to swap
    best = plan_groups(info, chosen, 1)
    assert result.pair_groups is not None
    planned = group_information(info, chosen, result.pair_groups)
    assert result.predicted_sigma_m == pytest.approx(np.sqrt(variance(info, planned)))
    assert variance(info, group_information(info, chosen, best)) < variance(
        info, group_information(info, chosen, random_groups(len(chosen), 4, np.random.default_rng(1)))
    )


def test_plan_writes_its_groups_and_the_calibration_fits_them(small_plan, tmp_path):
    from fgcal.calibration.config import load_config
    from fgcal.data.dataset import load_dataset, read_csv
    from fgcal.planning.plan import write_plan
    from fgcal.planning.study import planned_groups
    from fgcal.simulation.simulate import simulate

    _, result = small_plan
    written = write_plan(result, tmp_path / "plan", plot=False)
    assert "pair_groups.csv" in written
    assert "pairs: {groups: pair_groups.csv}" in (tmp_path / "plan" / "plan.md").read_text()
    simulate(SEED_CELL, tmp_path / "sim", 3, configurations=tmp_path / "plan" / "configurations.csv")
    dataset = load_dataset(tmp_path / "sim")
    # The simulation numbers the configurations afresh: the plan's groups by joint values.
    _, body = read_csv(planned_groups(tmp_path / "plan", tmp_path / "sim"), ["config", "group"])
    (tmp_path / "groups.csv").write_text("config,group\n" + "".join(f"{c},{g}\n" for c, g in body))
    assert len(body) == len(dataset.configs)
    (tmp_path / "calibration.yaml").write_text("dataset: sim\nformulation: pairs\npairs: {groups: groups.csv}\n")
    config = load_config(tmp_path / "calibration.yaml")
    assert config.measurement.pairs.groups_file == tmp_path / "groups.csv"
    subset = np.arange(len(dataset.configs))
    got = pair_observations(dataset, config.measurement, subset).groups
    by_file: dict[str, list[str]] = {}
    for cid, label in body:
        by_file.setdefault(label, []).append(cid)
    assert [[str(dataset.configs[j]) for j in g.images] for g in got] == list(by_file.values())
    # Held-out images are grouped by the file too, restricted to them.
    half = subset[::2]
    held = pair_observations(dataset, config.measurement, half).groups
    names = {str(dataset.configs[c]) for c in half}
    wanted = [[c for c in g if c in names] for g in by_file.values()]
    assert [[str(dataset.configs[half[j]]) for j in g.images] for g in held] == [w for w in wanted if w]


GROUPS_CASES = [
    # (name, groups.csv text or None: no file, what the one error line must name)
    ("missing", None, ["calibration.yaml", "pairs.groups", "file not found"]),
    ("empty", "", ["groups.csv", "empty file"]),
    ("header_only", "config,group\n", ["groups.csv", "no configurations"]),
    ("no_group_column", "config,label\nc0000,a\n", ["groups.csv", "group"]),
    ("ragged", "config,group\nc0000,a,b\n", ["groups.csv", "line 2"]),
    ("empty_label", "config,group\nc0000,\n", ["groups.csv", "line 2, column group"]),
    ("duplicate", "config,group\nc0000,a\nc0001,a\nc0000,b\n", ["groups.csv", "lines 2 and 4, column config"]),
    ("unknown_config", "config,group\nc0000,a\nnot_a_config,a\n", ["groups.csv", "line 3, column config"]),
    # The file's own line numbers: fgcal plan's pair_groups.csv starts with a comment (a user trial
    # was told "line 3" for line 4); blank lines count too.
    ("unknown_config_after_a_comment", "# fgcal plan's groups\nconfig,group\nc0000,a\nnot_a_config,a\n",
     ["groups.csv", "line 4, column config"]),
    ("duplicate_after_comments_and_a_blank", "# one\n# two\nconfig,group\nc0000,a\n\nc0000,b\n",
     ["groups.csv", "lines 4 and 6, column config"]),
    ("empty_label_after_a_comment", "# one\nconfig,group\nc0000,\n", ["groups.csv", "line 3, column group"]),
]


@pytest.mark.parametrize(("text", "named"), [c[1:] for c in GROUPS_CASES], ids=[c[0] for c in GROUPS_CASES])
def test_bad_groups_files_are_one_error_naming_the_file(seed_sim, tmp_path, capsys, text, named):
    from fgcal.commands.cli import main

    if text is not None:
        (tmp_path / "groups.csv").write_text(text)
    config = tmp_path / "calibration.yaml"
    config.write_text(f"dataset: {seed_sim}\nformulation: pairs\npairs: {{groups: groups.csv}}\n")
    status = main(["calibrate", str(config), "--out", str(tmp_path / "out"), "--no-plots"])
    error = capsys.readouterr().err.strip()
    assert status == 2, error
    assert error.startswith("fgcal: error: ") and "\n" not in error and "Traceback" not in error, error
    assert all(part in error for part in named), error


def test_groups_are_a_setting_only_the_pairs_formulation_reads(seed_sim, tmp_path):
    from fgcal.calibration.config import load_config
    from fgcal.calibration.formulations import formulation as registered

    (tmp_path / "groups.csv").write_text("config,group\nc0000,a\n")
    (tmp_path / "c.yaml").write_text(f"dataset: {seed_sim}\nformulation: tracker\npairs: {{groups: groups.csv}}\n")
    config = load_config(tmp_path / "c.yaml")
    # The headline says a stated setting the formulation does not read (tests/test_config_unread.py).
    assert "pairs.groups" in config.stated_options - set(registered("tracker").settings_read)
    assert "pairs.groups" in registered("pairs").settings_read
    sets = (f"dataset: {seed_sim}\nsets:\n- {{name: t, formulation: tracker, use: fit, "
            "pairs: {groups: groups.csv}}\n")  # fmt: skip
    (tmp_path / "s.yaml").write_text(sets)
    with pytest.raises(InputError, match="does not read it"):
        load_config(tmp_path / "s.yaml")
