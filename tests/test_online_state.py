"""The online state directory survives crashes: log checks, lock, SIGKILL at random points."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import SEED_CELL

import fgcal
from fgcal.online.feed import feed_dataset
from fgcal.online.service import OnlineService
from fgcal.online.state import LOG, StateDir, encode_record
from fgcal.simulation.simulate import simulate


def test_damaged_log_records_are_reported_and_skipped(tmp_path):
    with StateDir(tmp_path) as state:
        for i in range(3):
            state.append({"name": f"m{i}", "i": i})
    log = tmp_path / LOG
    lines = log.read_bytes().splitlines(keepends=True)
    corrupted = lines[1].replace(b'"i":1', b'"i":7')  # checksum no longer matches
    log.write_bytes(lines[0] + corrupted + lines[2] + encode_record({"name": "m3"})[:-9])  # torn last record
    with StateDir(tmp_path) as state:
        contents = state.read_log()
        assert [r["name"] for r in contents.records] == ["m0", "m2"]
        assert any("record 2 is corrupted" in p for p in contents.problems)
        assert any("record 4 is truncated" in p for p in contents.problems)
        state.append({"name": "m4"})  # the torn tail was cut off: appends start clean
        assert [r["name"] for r in state.read_log().records] == ["m0", "m2", "m4"]


def test_a_second_process_is_refused(tmp_path):
    with StateDir(tmp_path):
        code = (
            "import sys; from fgcal.online.state import StateDir\n"
            "try:\n    StateDir(sys.argv[1]).lock()\nexcept fgcal.InputError as e:\n    print(e); sys.exit(3)\n"
        )
        # cwd away from the repository: there ``fgcal`` would be the source tree, not the install.
        result = subprocess.run(
            [sys.executable, "-c", "import fgcal\n" + code, str(tmp_path)], capture_output=True, text=True, cwd=tmp_path
        )
    assert result.returncode == 3 and f"in use by another process (pid {os.getpid()})" in result.stdout


@pytest.fixture(scope="module")
def small_case(tmp_path_factory):
    root = tmp_path_factory.mktemp("crash")
    simulate(SEED_CELL, root / "data", seed=4, design="space_filling", n_configurations=40)
    (root / "setup.yaml").write_text("dataset: data\n")
    return root


@pytest.fixture(scope="module")
def tracker_case(tmp_path_factory):
    """The bundled laser-tracker cell, 40 configurations, online through its formulation."""
    root = tmp_path_factory.mktemp("crash_tracker")
    cell = Path(__file__).resolve().parents[1] / "datasets" / "cells" / "irb120_tracker.yaml"
    simulate(cell, root / "data", seed=4, design="space_filling", n_configurations=40)
    (root / "setup.yaml").write_text(
        "dataset: data\nformulation: tracker\nsettings: {prior_sigma_compliance: 1.0e-4}\n"
    )
    return root


def _estimate(state) -> tuple[np.ndarray, np.ndarray]:
    """Released estimates and sigmas of a state's report."""
    report = json.loads((state / "report.json").read_text())
    released = sorted(n for n, e in report["parameters"].items() if e["status"] == "released")
    entries = [report["parameters"][n] for n in released]
    return np.array([e["estimate"] for e in entries]), np.array([e["sigma"] for e in entries])


@pytest.mark.parametrize("case", ["small_case", "tracker_case"], ids=["camera", "tracker"])
def test_sigkill_at_random_points_loses_nothing(case, request, tmp_path):
    small_case = request.getfixturevalue(case)
    # The uninterrupted run.
    reference_inbox = tmp_path / "inbox_ref"
    n = feed_dataset(small_case / "data", reference_inbox, cycle_size=10)
    service = OnlineService(tmp_path / "state_ref", reference_inbox, small_case / "setup.yaml")
    service.run(once=True)
    service.close()
    expected = _estimate(tmp_path / "state_ref")

    inbox, state = tmp_path / "inbox", tmp_path / "state"
    feed_dataset(small_case / "data", inbox, cycle_size=10)
    names = sorted(p.name for p in inbox.glob("*.json"))
    command = [sys.executable, "-m", "fgcal", "online", "--state", str(state), "--inbox", str(inbox)]
    command += ["--setup", str(small_case / "setup.yaml"), "--once"]
    rng = np.random.default_rng(0)
    log = state / LOG

    def logged_count() -> int:
        return log.read_bytes().count(b"\n") if log.exists() else 0

    progress = []  # records logged when each kill landed
    for _ in range(5):
        if logged_count() >= n - 1:
            break
        # Kill once the log reaches a random count, after a random extra moment (so that the
        # kill lands in the append, the move, the solve or the outputs).
        target = int(rng.integers(logged_count() + 1, n))
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path)
        deadline = time.monotonic() + 120
        while process.poll() is None and logged_count() < target and time.monotonic() < deadline:
            time.sleep(0.005)
        time.sleep(rng.uniform(0.0, 0.03))
        if process.poll() is None:
            process.send_signal(signal.SIGKILL)
            process.wait()
            progress.append(logged_count())
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert finished.returncode == 0, finished.stderr
    assert any(0 < p < n for p in progress), progress  # some kills landed mid-run
    with StateDir(state) as locked:
        logged = [r["name"] for r in locked.read_log().records]
    assert sorted(logged) == names  # every acknowledged measurement, once
    assert not list(inbox.glob("*.json"))
    assert sorted(p.name for p in (state / "processed").iterdir()) == names
    # The log replays to the same estimate; GTSAM's multithreaded elimination does not sum in
    # a fixed order, so equal means equal to rounding, here 1e-6 sigma.
    estimate, sigma = _estimate(state)
    assert np.all(np.abs(estimate - expected[0]) <= 1e-6 * sigma)
    assert json.loads((state / "report.json").read_text())["n_images"] == n


def test_bad_measurement_files_are_rejected_with_the_reason(small_case, tmp_path):
    inbox = tmp_path / "inbox"
    feed_dataset(small_case / "data", inbox, n=3)
    (inbox / "zz_bad.json").write_text('{"joints": [0, 0, 0], "pixels": {}}')
    service = OnlineService(tmp_path / "state", inbox, small_case / "setup.yaml")
    service.run(once=True)
    service.close()
    reason = (tmp_path / "state" / "rejected" / "zz_bad.json.error.txt").read_text()
    assert "joints" in reason and "6 numbers" in reason
    assert service.calibrator.n_images == 3
    with pytest.raises(fgcal.InputError, match=r"no config\.yaml"):
        OnlineService(tmp_path / "other", inbox)


def test_a_bad_setup_names_the_field_and_leaves_no_config(small_case, tmp_path):
    inbox = tmp_path / "inbox"
    inbox.mkdir()
    setup = small_case / "bad_setup.yaml"
    setup.write_text("dataset: data\nsettings: {window_images: 3}\n")
    with pytest.raises(fgcal.InputError, match=r"bad_setup\.yaml: settings\.window_images: must be at least twice"):
        OnlineService(tmp_path / "state", inbox, setup)
    assert not (tmp_path / "state" / "config.yaml").exists()
    setup.write_text("dataset: data\nsettings: {window_imgs: 30}\n")
    with pytest.raises(fgcal.InputError, match=r"settings\.window_imgs: unknown field"):
        OnlineService(tmp_path / "state", inbox, setup)


def test_a_reused_name_is_rejected_not_lost(small_case, tmp_path):
    inbox = tmp_path / "inbox"
    feed_dataset(small_case / "data", inbox, n=5)
    first = sorted(inbox.glob("*.json"))[0]
    reused = first.read_text()
    service = OnlineService(tmp_path / "state", inbox, small_case / "setup.yaml")
    service.run(once=True)
    # The same file again (a writer's retry after a crash): moved aside, not counted twice.
    first.write_text(reused)
    # Another measurement under a used name: rejected with the reason.
    other = json.loads(reused)
    other["joints"][0] += 0.01
    (inbox / sorted((tmp_path / "state" / "processed").iterdir())[1].name).write_text(json.dumps(other))
    service.run(once=True)
    service.close()
    assert service.calibrator.n_images == 5 and not list(inbox.glob("*.json"))
    reasons = [p.read_text() for p in (tmp_path / "state" / "rejected").glob("*.error.txt")]
    assert len(reasons) == 1 and "names must be unique" in reasons[0]


def _service(small_case, state, inbox):
    return OnlineService(state, inbox, small_case / "setup.yaml")


def _fed(small_case, tmp_path, count: int):
    inbox = tmp_path / "inbox"
    feed_dataset(small_case / "data", inbox, n=count)
    return inbox


def test_a_damaged_record_is_recovered_from_its_file_or_quarantined(small_case, tmp_path):
    # Issue 13, defect 8: a damaged complete record vanished from the state, its file in
    # processed/ never read again.
    inbox, state = _fed(small_case, tmp_path, 8), tmp_path / "state"
    service = _service(small_case, state, inbox)
    service.run(once=True)
    service.close()
    expected = _estimate(state)
    lines = (state / LOG).read_bytes().splitlines(keepends=True)
    names = [json.loads(line[9:])["name"] for line in lines]
    lines[3] = lines[3].replace(b'"joints":[', b'"joints":[9,')  # checksum no longer matches
    (state / LOG).write_bytes(b"".join(lines))
    service = _service(small_case, state, inbox)
    assert any("recovered from processed/" + names[3] in p for p in service.problems), service.problems
    service.close()
    with StateDir(state) as locked:
        assert [r["name"] for r in locked.read_log().records] == names  # repaired in place
    estimate, sigma = _estimate(state)
    assert np.all(np.abs(estimate - expected[0]) <= 1e-6 * sigma)
    # Without its file the record cannot be recovered: quarantined, with a message.
    lines = (state / LOG).read_bytes().splitlines(keepends=True)
    lines[5] = lines[5].replace(b'"joints":[', b'"joints":[9,')
    (state / LOG).write_bytes(b"".join(lines))
    (state / "processed" / names[5]).unlink()
    service = _service(small_case, state, inbox)
    assert any("quarantined" in p for p in service.problems), service.problems
    assert service.calibrator.n_images == 7
    service.close()
    assert len(list((state / "quarantine").iterdir())) == 1


def test_a_truncated_last_record_whose_file_was_processed_is_recovered(small_case, tmp_path):
    """Issue 41: the log's last record cut short while processed/ holds its file (acknowledged,
    then damaged on disk), with a damaged record before it: the run warned "records were lost"
    and replayed one measurement fewer for good. Now recovered from processed/ as the middle ones."""
    inbox, state = _fed(small_case, tmp_path, 8), tmp_path / "state"
    service = _service(small_case, state, inbox)
    service.run(once=True)
    service.close()
    expected = _estimate(state)
    lines = (state / LOG).read_bytes().splitlines(keepends=True)
    names = [json.loads(line[9:])["name"] for line in lines]
    lines[3] = lines[3].replace(b'"joints":[', b'"joints":[9,')  # checksum no longer matches
    lines[-1] = lines[-1][: len(lines[-1]) // 2]  # truncated
    (state / LOG).write_bytes(b"".join(lines))
    service = _service(small_case, state, inbox)
    assert any("lost last log record recovered from processed/" + names[-1] in p for p in service.problems)
    assert service.calibrator.n_images == 8, service.problems
    assert not any("shorter than the checkpoint" in p for p in service.problems), service.problems
    service.close()
    with StateDir(state) as locked:
        contents = locked.read_log()
        assert [r["name"] for r in contents.records] == names and not contents.problems  # repaired in place
    estimate, sigma = _estimate(state)
    assert np.all(np.abs(estimate - expected[0]) <= 1e-6 * sigma)


@pytest.mark.parametrize(
    "damage",
    [
        lambda doc: doc.pop("estimate"),
        lambda doc: doc.update(n_records="many"),
        lambda doc: doc["sigma"].update({next(iter(doc["sigma"])): None}),
        None,  # not JSON at all
    ],
    ids=["missing_key", "wrong_type", "null_sigma", "garbage"],
)
def test_a_damaged_checkpoint_is_reported_and_rebuilt(small_case, tmp_path, damage):
    # Issue 13, defect 7: a checkpoint with missing keys or wrong types gave a traceback on
    # every restart; a garbage one was ignored without a word.
    from fgcal.online.state import CHECKPOINT

    inbox, state = _fed(small_case, tmp_path, 30), tmp_path / "state"  # a checkpoint every 25
    service = _service(small_case, state, inbox)
    service.run(once=True)
    service.close()
    path = state / CHECKPOINT
    if damage is None:
        path.write_bytes(b"\x00garbage{")
    else:
        doc = json.loads(path.read_text())
        damage(doc)
        path.write_text(json.dumps(doc))
    service = _service(small_case, state, inbox)
    assert any("checkpoint.json" in p for p in service.problems), service.problems
    service.close()
    rebuilt = json.loads(path.read_text())
    assert rebuilt["n_records"] == 30 and set(rebuilt["estimate"]) == set(service.calibrator.released)


def test_a_damaged_state_config_is_a_clear_error(small_case, tmp_path):
    inbox, state = _fed(small_case, tmp_path, 2), tmp_path / "state"
    _service(small_case, state, inbox).close()
    for text in ("dataset: [unclosed\n", "dataset: 3\nsettings: {window_images: many}\n", "- a list\n"):
        (state / "config.yaml").write_text(text)
        with pytest.raises(fgcal.InputError, match=r"config\.yaml"):
            OnlineService(state, inbox)


def test_a_full_disk_loses_no_acknowledged_measurement(small_case, tmp_path, monkeypatch):
    inbox, state = _fed(small_case, tmp_path, 10), tmp_path / "state"
    names = sorted(p.name for p in inbox.glob("*.json"))
    original = StateDir.append
    calls = {"n": 0}

    def failing_append(self, record):
        calls["n"] += 1
        if calls["n"] == 6:  # half a record reaches the disk, then it is full
            with open(self.path / LOG, "ab") as handle:
                handle.write(encode_record(record)[:20])
            raise OSError(28, "No space left on device")
        original(self, record)

    monkeypatch.setattr(StateDir, "append", failing_append)
    service = _service(small_case, state, inbox)
    with pytest.raises(fgcal.InputError, match="No space left"):
        service.run(once=True)
    service.close()
    monkeypatch.setattr(StateDir, "append", original)
    assert names[5] in [p.name for p in inbox.iterdir()]  # not acknowledged: still in the inbox
    service = _service(small_case, state, inbox)
    service.run(once=True)
    service.close()
    with StateDir(state) as locked:
        assert [r["name"] for r in locked.read_log().records] == names
    assert not list(inbox.glob("*.json"))


def _damage_a_record(log, rng) -> str | None:
    """Flip one byte inside a complete record's JSON (not the last line, which a crash may
    be writing); returns the damaged record's name."""
    lines = log.read_bytes().splitlines(keepends=True) if log.exists() else []
    if len(lines) < 3:
        return None
    i = int(rng.integers(0, len(lines) - 1))
    name = json.loads(lines[i][9:])["name"]
    position = 9 + int(rng.integers(1, len(lines[i]) - 11))
    line = bytearray(lines[i])
    line[position] = ord("#") if line[position] != ord("#") else ord("%")
    lines[i] = bytes(line)
    log.write_bytes(b"".join(lines))
    return name


@pytest.mark.parametrize("n_kills", [12, pytest.param(25, marks=pytest.mark.study)])
def test_sigkills_on_a_shared_inbox_with_links_and_fifos(small_case, tmp_path, n_kills):
    """Issues 13 and 23, the scripted crash test: SIGKILLs at random moments (12 in the suite,
    the 25 of the issue with the studies: 30 s, and the suite keeps under 6 minutes); between them, at
    random, a complete log record or the checkpoint is damaged, or an append is torn, and the
    inbox gets symbolic links (to a measurement outside it, and to a FIFO outside it, which
    would block whoever opened it) and FIFOs of its own. After each kill the next process starts
    cleanly; at the end every acknowledged measurement is logged exactly once, nothing outside
    the inbox was read (its measurement never logged, no run blocked on its FIFO), and the
    estimate equals an uninterrupted run's over the same measurements."""
    inbox, state = tmp_path / "inbox", tmp_path / "state"
    feed_dataset(small_case / "data", inbox)
    names = sorted(p.name for p in inbox.glob("*.json"))
    outside = tmp_path / "outside"
    outside.mkdir()
    shutil.copy(inbox / names[0], outside / "stranger.json")
    os.mkfifo(outside / "pipe.json")
    command = [sys.executable, "-m", "fgcal", "online", "--state", str(state), "--inbox", str(inbox)]
    command += ["--setup", str(small_case / "setup.yaml"), "--once"]
    rng = np.random.default_rng(13)
    log = state / LOG

    def logged_count() -> int:
        return log.read_bytes().count(b"\n") if log.exists() else 0

    kills, damaged_records, damaged_checkpoints, torn, planted, refed = 0, 0, 0, 0, 0, 0
    expected = list(names)
    for _ in range(100):
        if kills == n_kills:
            break
        if rng.uniform() < 0.3 and _damage_a_record(log, rng):
            damaged_records += 1
        # (half-way without one, the checkpoint is damaged: each kind of damage happens in the run)
        damage = rng.uniform() < 0.3 or (damaged_checkpoints == 0 and kills >= n_kills // 2)
        if damage and (state / "checkpoint.json").exists():
            (state / "checkpoint.json").write_bytes(b'{"n_records": "x"')
            damaged_checkpoints += 1
        if rng.uniform() < 0.2 and log.exists():  # a crash in the middle of an append
            with open(log, "ab") as handle:
                handle.write(encode_record({"name": "torn", "joints": []})[: int(rng.integers(3, 30))])
            torn += 1
        if rng.uniform() < 0.3:
            planted += 1
            os.symlink(outside / "stranger.json", inbox / f"link{planted:02d}.json")
            os.symlink(outside / "pipe.json", inbox / f"pipelink{planted:02d}.json")
            os.mkfifo(inbox / f"fifo{planted:02d}.json")
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=tmp_path)
        # Kill once the log has grown by a few records (however slow the machine), a random
        # moment later: in the append, the move, the solve or the outputs.
        target = logged_count() + int(rng.integers(1, 4))
        while process.poll() is None and logged_count() < target:
            time.sleep(0.005)
        time.sleep(rng.uniform(0.0, 0.05))
        if process.poll() is None:
            process.send_signal(signal.SIGKILL)
            process.wait()
            kills += 1
        else:
            assert process.returncode == 0, process.stderr.read().decode()  # usable: a clean run
        if not list(inbox.glob("[0-9r]*.json")):  # all processed: the same images again, as new files
            refed += 1
            for name in names[:10]:
                copy = f"r{refed:02d}_{name}"
                shutil.copy(state / "processed" / name, inbox / copy)
                expected.append(copy)
    finished = subprocess.run(command, capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert finished.returncode == 0, finished.stderr
    print(f"{kills} SIGKILLs, {damaged_records} damaged records, {damaged_checkpoints} damaged checkpoints, "
          f"{torn} torn appends, {planted} rounds of links and FIFOs")  # fmt: skip
    assert kills == n_kills, kills
    assert damaged_records >= 3 and damaged_checkpoints >= 1 and torn >= 1 and planted >= 3
    with StateDir(state) as locked:
        logged = [r["name"] for r in locked.read_log().records]
    assert sorted(logged) == sorted(expected)  # every acknowledged measurement, once; no stranger
    assert not list(inbox.glob("*.json")) and (outside / "stranger.json").exists()
    rejected = {p.name for p in (state / "rejected").glob("*.json")}
    assert {f"link{k:02d}.json" for k in range(1, planted + 1)} <= rejected
    assert {f"fifo{k:02d}.json" for k in range(1, planted + 1)} <= rejected
    assert json.loads((state / "report.json").read_text())["n_images"] == len(expected)
    # The uninterrupted run over the same measurement files, in the same order.
    again = tmp_path / "inbox_again"
    again.mkdir()
    for name in expected:
        shutil.copy(state / "processed" / name, again / name)
    service = OnlineService(tmp_path / "state_again", again, small_case / "setup.yaml")
    service.run(once=True)
    service.close()
    (estimate, sigma), (reference, _) = _estimate(state), _estimate(tmp_path / "state_again")
    assert np.all(np.abs(estimate - reference) <= 1e-6 * sigma)


def test_a_measurement_whose_fold_fails_is_quarantined_and_never_blocks_a_replay(small_case, tmp_path, monkeypatch):
    # Issue 13: a measurement that passes validation but makes the solver fail was logged
    # before it was folded in, so every replay failed again.
    from fgcal.online.calibrator import OnlineCalibrator

    inbox, state = _fed(small_case, tmp_path, 12), tmp_path / "state"
    names = sorted(p.name for p in inbox.glob("*.json"))
    poisoned = json.loads((inbox / names[6]).read_text())["joints"]
    original = OnlineCalibrator.add

    def add(self, q, observations, cycle=None):
        if np.allclose(q, poisoned):
            raise RuntimeError("Indeterminant linear system detected while working near variable p0")
        return original(self, q, observations, cycle)

    monkeypatch.setattr(OnlineCalibrator, "add", add)
    service = _service(small_case, state, inbox)
    service.run(once=True)
    assert service.calibrator.n_images == 11 and list(service.quarantined) == [names[6]]
    service.close()
    report = json.loads((state / "report.json").read_text())
    assert [q["name"] for q in report["quarantined"]] == [names[6]]
    expected = _estimate(state)
    for _ in range(2):  # restarts replay past it, without calling the solver on it
        service = _service(small_case, state, inbox)
        assert service.calibrator.n_images == 11
        service.close()
    estimate, sigma = _estimate(state)
    assert np.all(np.abs(estimate - expected[0]) <= 1e-6 * sigma)
    # A failure during a replay (the first time it is seen there) is quarantined the same way.
    with StateDir(state) as locked:
        records = [r for r in locked.read_log().records if "quarantined" not in r]
        locked.rewrite_log(records)
    service = _service(small_case, state, inbox)
    assert service.calibrator.n_images == 11 and list(service.quarantined) == [names[6]]
    service.close()


@pytest.mark.parametrize(
    ("case", "stop"),
    [("small_case", signal.SIGTERM), ("small_case", signal.SIGINT), ("tracker_case", signal.SIGTERM)],
    ids=["camera-sigterm", "camera-sigint", "tracker-sigterm"],
)
def test_a_stop_signal_finishes_the_measurement_writes_the_report_and_exits_0(case, request, tmp_path, stop):
    """Issue 41: SIGTERM (systemd, docker stop) and SIGINT stop the service cleanly in the
    middle of a run: the measurement under way is finished, report.md and report.json are
    written, the exit status is 0, and every acknowledged measurement is in the log, folded
    in and moved aside; the rest wait in the inbox (which the command created)."""
    small_case = request.getfixturevalue(case)
    inbox, state = tmp_path / "new" / "inbox", tmp_path / "state"
    n = feed_dataset(small_case / "data", tmp_path / "staging", cycle_size=10)
    command = [sys.executable, "-m", "fgcal", "online", "--state", str(state), "--inbox", str(inbox)]
    command += ["--setup", str(small_case / "setup.yaml"), "--poll", "0.05"]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    log = state / LOG
    deadline = time.monotonic() + 120
    while not inbox.is_dir() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert inbox.is_dir() and process.poll() is None
    # Measurements arrive one by one while the service runs; the stop comes after 12 are logged.
    staged = sorted((tmp_path / "staging").glob("*.json"))
    for path in staged:
        os.replace(path, inbox / path.name)
        time.sleep(0.01)
        if log.exists() and log.read_bytes().count(b"\n") >= 12:
            break
    while (not log.exists() or log.read_bytes().count(b"\n") < 12) and time.monotonic() < deadline:
        time.sleep(0.005)
    process.send_signal(stop)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    assert f"{stop.name}: finishing the current measurement" in out, out
    with StateDir(state) as locked:
        logged = [r["name"] for r in locked.read_log().records]
    processed = sorted(p.name for p in (state / "processed").iterdir())
    waiting = sorted(p.name for p in inbox.glob("*.json"))
    assert len(logged) >= 12 and sorted(logged) == processed  # acknowledged: logged and moved aside
    assert sorted(processed + waiting + [p.name for p in staged if (tmp_path / "staging" / p.name).exists()]) == \
        sorted(p.name for p in staged) and len(staged) == n  # fmt: skip
    report = json.loads((state / "report.json").read_text())
    assert report["n_images"] == report["n_logged"] == len(logged)  # each one folded in
    assert f"measurements folded in: {len(logged)}" in (state / "report.md").read_text()
    assert f"{len(logged)} measurements; predicted RMS flange sigma" in out and f"(stopped by {stop.name})" in out
