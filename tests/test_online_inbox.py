"""What fgcal online takes from its inbox (issue 23): regular files only, never through a link,
never blocking on a FIFO; odd names stored safely; the state folder kept apart; two services
sharing one inbox each take their own files."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fgcal.commands.cli import main
from fgcal.online.feed import feed_dataset
from fgcal.online.state import LOG, StateDir


@pytest.fixture(scope="module")
def case(bundled_sim, tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("inbox_case")
    (root / "setup.yaml").write_text(f"dataset: {bundled_sim('kr125_seed', 2)}\n")
    return root


def _online(case: Path, inbox: Path, state: Path, *more: str) -> int:
    return main(["online", "--state", str(state), "--inbox", str(inbox), "--setup", str(case / "setup.yaml"),
                 "--once", *more])  # fmt: skip


def _fed(case: Path, inbox: Path, n: int) -> list[str]:
    feed_dataset(Path(case.joinpath("setup.yaml").read_text().split(": ", 1)[1].strip()), inbox, 0, n)
    return sorted(p.name for p in inbox.glob("*.json"))


def _logged(state: Path) -> list[str]:
    with StateDir(state) as locked:
        return [r["name"] for r in locked.read_log().records]


def test_links_fifos_and_odd_names_are_refused_not_followed(case, tmp_path, capsys):
    """A FIFO (it hung the service), a link to a measurement outside the inbox (it was read), a
    link to a FIFO outside, a folder named like a measurement, a name that is not UTF-8 and a
    name of 250 characters (tracebacks): each goes to rejected/ (under a safe name) with the
    reason, the good files are logged, and the command exits cleanly."""
    inbox, state, outside = tmp_path / "inbox", tmp_path / "state", tmp_path / "outside"
    good = _fed(case, inbox, 4)
    outside.mkdir()
    (outside / "stranger.json").write_bytes((inbox / good[0]).read_bytes())
    os.mkfifo(outside / "pipe.json")
    os.mkfifo(inbox / "fifo.json")
    os.symlink(outside / "stranger.json", inbox / "link.json")
    os.symlink(outside / "pipe.json", inbox / "pipelink.json")
    (inbox / "folder.json").mkdir()
    odd = os.fsencode(inbox) + b"/caf\xe9.json"  # Latin-1, not UTF-8
    Path(os.fsdecode(odd)).write_bytes((inbox / good[1]).read_bytes())
    (inbox / ("x" * 245 + ".json")).write_bytes((inbox / good[2]).read_bytes())  # its .error.txt: too long
    assert _online(case, inbox, state) == 0
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    assert _logged(state) == good
    reasons = {p.name.removesuffix(".error.txt"): p.read_text() for p in (state / "rejected").glob("*.error.txt")}
    assert "FIFO" in reasons["fifo.json"] and "symbolic link" in reasons["link.json"]
    assert "symbolic link" in reasons["pipelink.json"] and "folder" in reasons["folder.json"]
    odd_names = [name for name in reasons if name.startswith("odd-name-")]
    assert len(odd_names) == 2 and all("not UTF-8 text" in reasons[name] for name in odd_names)
    assert (outside / "stranger.json").exists() and not list(inbox.iterdir())


def test_the_inbox_is_not_the_state_nor_inside_it(case, tmp_path, capsys):
    state = tmp_path / "state"
    state.mkdir()
    (state / "inbox").mkdir()
    for inbox in (state, state / "inbox"):
        assert _online(case, inbox, state) == 2
        err = capsys.readouterr().err
        assert "--inbox" in err and "state directory" in err and "Traceback" not in err


@pytest.mark.parametrize("poll", ["-1", "nan", "1e9"])
def test_poll_is_a_sane_number_of_seconds(case, tmp_path, capsys, poll):
    (tmp_path / "inbox").mkdir()
    assert _online(case, tmp_path / "inbox", tmp_path / "state", "--poll", poll) == 2
    err = capsys.readouterr().err
    assert "--poll" in err and "Traceback" not in err


@pytest.mark.parametrize("name", [LOG, "checkpoint.json", "history.csv"])
def test_a_folder_or_link_where_a_state_file_goes_is_a_clear_error(case, tmp_path, capsys, name):
    inbox, state = tmp_path / "inbox", tmp_path / "state"
    _fed(case, inbox, 2)
    state.mkdir()
    (state / name).mkdir()
    assert _online(case, inbox, state) == 2
    err = capsys.readouterr().err
    assert name in err and "folder" in err and "Traceback" not in err
    (state / name).rmdir()
    os.symlink(tmp_path / "elsewhere", state / name)
    assert _online(case, inbox, state) == 2
    assert "symbolic link" in capsys.readouterr().err and not (tmp_path / "elsewhere").exists()


def test_two_services_share_one_inbox(case, tmp_path):
    """Two services with states of their own on one inbox (one claimed a file the other had
    listed: FileNotFoundError): each takes its own files, every file is taken once."""
    inbox = tmp_path / "inbox"
    names = _fed(case, inbox, 30)
    command = [sys.executable, "-m", "fgcal", "online", "--inbox", str(inbox), "--setup",
               str(case / "setup.yaml"), "--once"]  # fmt: skip
    runs = [
        subprocess.Popen([*command, "--state", str(tmp_path / f"state{k}")], cwd=tmp_path, stderr=subprocess.PIPE)
        for k in (1, 2)
    ]
    for run in runs:
        assert run.wait(timeout=600) == 0, run.stderr.read().decode()
    first, second = _logged(tmp_path / "state1"), _logged(tmp_path / "state2")
    assert sorted(first + second) == names and not set(first) & set(second)
    assert not list(inbox.iterdir())
    for k in (1, 2):
        assert not list((tmp_path / f"state{k}" / "rejected").iterdir())


def test_a_claim_left_by_a_dead_process_is_taken_back(case, tmp_path):
    inbox, state = tmp_path / "inbox", tmp_path / "state"
    names = _fed(case, inbox, 3)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    os.rename(inbox / names[1], inbox / f".{names[1]}.{int(dead.stdout)}.claim")
    assert _online(case, inbox, state) == 0
    assert _logged(state) == names
    report = json.loads((state / "report.json").read_text())
    assert report["n_images"] == 3


@pytest.mark.parametrize(
    ("document", "field", "says"),
    [
        ({"configurations": [], "cycle": 1}, "configurations", "1 to 1000 configurations"),
        ({"configurations": [{"joints": [0] * 6, "pixels": {"a": [1, 2]}}], "joints": [0] * 6}, "joints",
         "in its entry"),
        ({"configurations": [{"joints": [0] * 6, "pixels": {"a": [1, 2]}}, {"joints": [0] * 5}]},
         "configurations[1].joints", "6"),
        ({"configurations": [{"joints": [0] * 6}]}, "configurations[0].pixels", "at least one observation"),
        ({"configurations": [{"joints": [0] * 6, "cycle": 2, "pixels": {"a": [1, 2]}}]}, "configurations[0].cycle",
         "unknown field"),
    ],
    ids=["empty", "joints_beside", "short_joints", "nothing_observed", "cycle_inside"],
)
def test_a_bad_batch_file_names_its_field(document, field, says):
    """Issue 41: a file with a work cycle's configurations; a bad one names the field."""
    from fgcal.core.errors import InputError
    from fgcal.online.measurement import FORMAT, parse_measurement

    with pytest.raises(InputError) as error:
        parse_measurement({"format": FORMAT, **document}, "x.json", "x.json", 6)
    assert (error.value.field or "").startswith(field) and says in error.value.message, error.value


def test_a_batch_file_round_trips_with_its_labels():
    from fgcal.online.measurement import FORMAT, parse_measurement

    entries = [{"config": "c1", "joints": [0.1] * 6},
               {"config": "c2", "joints": [0.2] * 6, "observations": {"tool_distances": [
                   {"config_a": "c1", "config_b": "c2", "value": [0.05]}]}}]  # fmt: skip
    measurement = parse_measurement({"format": FORMAT, "cycle": 3, "configurations": entries}, "b.json", "b.json", 6)
    assert [m.label for m in measurement.configurations] == ["c1", "c2"] and measurement.cycle == 3
    assert measurement.n_observations == 1
    again = parse_measurement(measurement.to_record(), "b.json", "log", 6)
    assert again.to_record() == measurement.to_record()


@pytest.mark.parametrize(
    ("table", "rows", "field"),
    [
        ("tracker_points", [{"target": "t1", "value": [1, 2, 3]}, {"target": "t2", "value": [1, 2, 4]},
                            {"target": "t1", "value": [1, 2, 3]}], "observations.tracker_points[2].target"),
        ("tool_distances", [{"config_a": "c1", "config_b": "c2", "value": [0.05]},
                            {"config_a": "c2", "config_b": "c1", "value": [0.05]}], "observations.tool_distances[1]"),
    ],
    ids=["reflector", "distance_either_way"],
)  # fmt: skip
def test_a_measurement_named_twice_in_one_configuration_is_refused(table, rows, field):
    """Issue 41: a reflector named twice in one file was folded in twice (double weight). Refused
    as a dataset's table refuses it, naming the field."""
    from fgcal.core.errors import InputError
    from fgcal.online.measurement import FORMAT, parse_measurement

    with pytest.raises(InputError) as error:
        parse_measurement({"format": FORMAT, "joints": [0.1] * 6, "observations": {table: rows}}, "x.json", "x.json", 6)
    assert (error.value.field or "").startswith(field) and "given twice" in error.value.message, error.value
