"""``fgcal online``: the inbox loop around an :class:`OnlineCalibrator` (docs/online.md).

For each ``*.json`` file in the inbox, in name order: validate it, append it to the state's
log (fsync: acknowledged), move it to ``STATE/processed/``, fold it into the estimate, and
write ``calibrated_robot.yaml``, ``report.json`` and a row of ``history.csv``. A file that
fails validation goes to ``STATE/rejected/`` with the reason beside it. When the inbox is
empty, ``report.md`` and ``sigmas.png`` are written. At start the log is replayed, so that
a restart after a crash continues with every acknowledged measurement.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import time
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from ..calibration.covariance import position_covariance
from ..calibration.formulations import NAMES
from ..core import strict_json
from ..core.console import detail
from ..core.console import say as log_info
from ..core.errors import InputError
from ..core.fields import read_yaml
from ..core.outputs import output_dir, subfolder, write_bytes, write_text
from ..core.schema import validate
from ..data.dataset import load_dataset
from ..model.parameters import unit_of
from ..model.robot import SAME_ROBOT_M
from ..model.robot_io import load_referenced, robot_reference, save_robot
from .calibrator import OnlineCalibrator, OnlineSettings, OnlineUpdate
from .inbox import Entry, claim, entries, recover_claims, safe_name
from .measurement import Measurement, parse_measurement, read_measurement
from .protocol import FormulationCalibrator
from .report import human, write_final_report
from .schema import OnlineSetup
from .state import StateDir, encode_record, open_for_writing, write_atomic

CONFIG = "config.yaml"
QUARANTINE = "quarantined"  # key of a log record that marks a measurement as not to be folded in


class _Replayed(Exception):  # noqa: N818 (a signal, not an error)
    """Raised out of a replay that a quarantine has just redone from the start."""


CHECKPOINT_EVERY = 25
# An estimate not to be trusted without saying so (issue 41: a gross reading folded in left d4 at
# -574 m with sigmas of 1e-17): a parameter's step in one measurement beyond this many of its
# sigmas (a good run's largest step is the start's, tens of sigmas: 47 on irb120_tracker) ...
ABSURD_STEP_SIGMAS = 1000.0
# ... or a parameter moved from the start by more than this many of its prior sigmas (a prior is
# what the cell may plausibly be off by: 5 mm, 5 mrad). Both are headline warnings of report.md.
ABSURD_MOVE_PRIORS = 10.0


def load_config(path: Path) -> dict:
    """Validate a setup file (its schema: online.schema.OnlineSetup); returns it with paths made
    absolute and the settings it states (as the schema read them)."""
    setup = validate(read_yaml(path), OnlineSetup, path)
    config: dict = {"dataset": str((path.parent / setup.dataset).resolve())}
    if setup.formulation is not None:
        config["formulation"] = setup.formulation
    if setup.model is not None:
        if setup.formulation is None:
            raise InputError(path, "model", "a model is chosen with a formulation (formulation: NAME)")
        config["model"] = setup.model
    if setup.robot is not None:
        config["robot"] = robot_reference(path.parent, setup.robot, path, "robot")
    if setup.released is not None:
        config["released"] = list(setup.released)
    config["settings"] = setup.settings.model_dump(exclude_unset=True) if setup.settings is not None else {}
    config["target_accuracy_m"] = setup.target_accuracy_m
    return config


def _digest(record: dict) -> bytes:
    return hashlib.sha256(encode_record(record)).digest()[:16]


def _settings(config: dict) -> OnlineSettings:
    """The settings a setup states (load_config), over the defaults."""
    values = dict(config["settings"])
    if values.get("compliant_joints") is not None:  # None (the default): the seed's 1-3
        values["compliant_joints"] = tuple(values["compliant_joints"])
    return replace(OnlineSettings(), **values)


class OnlineService:
    """One process working on a state directory (holds its lock until :meth:`close`)."""

    def __init__(
        self,
        state_dir: str | Path,
        inbox: str | Path,
        setup: str | Path | None = None,
        say: Callable[[str], None] | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> None:
        # Lines go through the fgcal logger by default (fgcal -q keeps the warnings only).
        self.say = say or log_info
        # Asked between measurements: True once a stop was requested (SIGTERM or SIGINT in
        # fgcal online); the current measurement is finished first.
        self.stop_requested = stop or (lambda: False)
        self.state = StateDir(state_dir)
        self.state.lock()
        try:
            self._start(Path(inbox), setup)
        except BaseException:
            self.state.close()
            raise

    def _start(self, inbox: Path, setup: str | Path | None) -> None:
        self.inbox = output_dir(inbox, "--inbox")  # created, as fgcal online-feed creates it
        state, box = self.state.path.resolve(), self.inbox.resolve()
        if box == state or box.is_relative_to(state):
            raise InputError(self.inbox, "--inbox", f"is the state directory or inside it ({self.state.path}): "
                             "measurements come from elsewhere")  # fmt: skip
        config_path = self.state.path / CONFIG
        if setup is not None:
            self.config = load_config(Path(setup))
            if config_path.exists() and load_config(config_path) != self.config:
                raise InputError(setup, None, f"{self.state.path} was set up differently; use a new state directory")
        elif config_path.exists():
            # Validated like a setup file (its paths are absolute): a damaged one is a clear error.
            self.config = load_config(config_path)
        else:
            raise InputError(self.state.path, None, "no config.yaml: set the state directory up with --setup FILE")
        dataset = load_dataset(self.config["dataset"])
        robot = self._robot(dataset, setup or config_path)
        settings = _settings(self.config)
        missing = [j for j in settings.compliant_joints or () if not 1 <= j <= robot.n_joints]
        if missing:  # it read as no compliance at all (the batch calibration refuses it too)
            raise InputError(setup or config_path, "settings.compliant_joints", f"joint {missing[0]} does not exist: "
                             f"{robot.name} has joints 1 to {robot.n_joints}")  # fmt: skip
        if "formulation" in self.config:  # any registered formulation, through its protocol

            def new_calibrator():
                return FormulationCalibrator(
                    dataset, self.config["formulation"], settings, self.config.get("released"), robot,
                    self.config.get("model"),
                )  # fmt: skip
        else:  # a flange camera's images (fgcal.online.calibrator)
            new_calibrator = self._camera(dataset, robot, settings)
        self._new_calibrator = new_calibrator
        try:
            self.calibrator = new_calibrator()
        except InputError as error:
            if error.source is not None:
                raise
            field_ = error.field if error.field in ("released", "formulation") else f"settings.{error.field}"
            raise InputError(setup or config_path, field_, error.message) from None
        if not config_path.exists():  # written once the setup has proved usable
            write_atomic(config_path, yaml.safe_dump(self.config, sort_keys=False).encode("utf-8"))
        self.target_m = float(self.config["target_accuracy_m"])
        self.latencies: deque[float] = deque(maxlen=10000)  # bounded: the last 10000 updates
        self._history_handle = None
        self._left: set[str] = set()  # inbox folders named like measurements, reported once
        self.processed = subfolder(self.state.path, "processed")
        self.rejected = subfolder(self.state.path, "rejected")
        self._replay()
        for name in recover_claims(self.inbox):
            self.say(f"took back {name}: claimed by a process that stopped before it was logged")

    def _robot(self, dataset, setup: Path):
        """The starting model: the setup's robot file, or the dataset's robot."""
        if "robot" not in self.config:
            return dataset.robot
        robot = load_referenced(self.config["robot"])
        gap = robot.flange_gap_m(dataset.robot)
        if gap > SAME_ROBOT_M:
            raise InputError(
                setup, "robot", f"{robot.name} is not the dataset's {dataset.robot.name}: their "
                + (f"flanges are up to {gap * 1e3:.0f} mm apart" if np.isfinite(gap) else "joint counts differ"),
            )  # fmt: skip
        return robot

    def _camera(self, dataset, robot, settings: OnlineSettings):
        """The calibrator of a flange camera's images, checked against the dataset."""
        if dataset.camera is None or "points" not in dataset.tables:
            raise InputError(
                self.config["dataset"], None, "has no camera with calibration points: without a formulation, online "
                "calibration takes a flange camera's images; for another instrument name its formulation in the setup "
                f"(formulation: one of {', '.join(NAMES)})",
            )  # fmt: skip
        if dataset.camera_mounting is None:
            raise InputError(
                Path(self.config["dataset"]) / "dataset.yaml", "camera.mounting", "online calibration takes a camera "
                "on the flange, and this dataset's camera has no mounting (a camera fixed in the cell?)",
            )  # fmt: skip
        points = dataset.points_F()

        def new_calibrator() -> OnlineCalibrator:
            return OnlineCalibrator(robot, dataset.camera, points, settings, self.config.get("released"))

        return new_calibrator

    def _begin(self) -> None:
        """Everything a replay rebuilds: the estimate's companions and history.csv."""
        self.alarms: list[dict] = []
        self.skipped: list[dict] = []
        self.met_at: int | None = None
        self.predicted: dict | None = None  # after the last image folded in
        self._final_at = -1  # n_images when report.md was last written
        self.logged: dict[str, bytes] = {}  # name -> digest of the logged record
        cal = self.calibrator
        self._previous = cal.current_params()[cal.model.index].copy()  # before the last measurement
        self._cycle: dict = {"label": None, "n": 0, "start": self._previous.copy()}
        self.quarantined: dict[str, str] = {}  # name -> why folding it in failed
        self._folded = 0  # configurations folded in (n_images after the last update)
        self._gated_names: list[str] = []  # the measurements of the current run of gated ones
        if self._history_handle is not None:
            self._history_handle.close()
        self._history_handle = open_for_writing(self.state.path / "history.csv")
        self._history_handle.write(
            "image,name,cycle,update_ms,predicted_rms_m,alarms,"
            + ",".join(f"sigma_{n}" for n in self.calibrator.released)
            + "\n"
        )

    def _replay(self) -> None:
        self._begin()
        contents = self.state.read_log()
        self.problems = contents.problems
        for problem in contents.problems:
            self.say(f"warning: {problem}")
        records = self._repair(contents)
        markers = [r for r in records if QUARANTINE in r]
        self.quarantined = {str(r[QUARANTINE]): str(r.get("reason", "")) for r in markers}
        self.problems += [f"{name} quarantined: {why}" for name, why in self.quarantined.items()]
        records = [r for r in records if QUARANTINE not in r]
        checkpoint, problem = self.state.read_checkpoint(self.calibrator.released)
        if problem:
            self.say(f"warning: {problem}: ignored, rebuilt from the log")
            self.problems.append(problem)
        if records:
            self.say(f"replaying {len(records)} logged measurements")
        for number, record in enumerate(records, start=1):
            measurement = parse_measurement(
                record, record.get("name", "?"), self.state.path / "measurements.log", self.calibrator.robot.n_joints
            )
            self.logged[measurement.name] = _digest(measurement.to_record())
            if measurement.name in self.quarantined:
                self.say(f"skipped {measurement.name}: quarantined ({self.quarantined[measurement.name]})")
                continue
            try:
                self._fold(measurement, replaying=True)
            except _Replayed:
                return
            if checkpoint and checkpoint.get("n_records") == number:
                self._check_checkpoint(checkpoint)
        if checkpoint and checkpoint["n_records"] > len(records):
            self.say(
                f"warning: the checkpoint counts {checkpoint['n_records']} records, the log holds "
                f"{len(records)}: records were lost"
            )
            self.problems.append("log shorter than the checkpoint")
        if records:
            if problem or contents.damaged:
                self._checkpoint()
            self._write_outputs()

    def _repair(self, contents) -> list[dict]:
        """The log's records with each damaged one recovered from its measurement file in
        processed/ (the files moved there whose names the log lacks, in name order, which is
        the order they were logged in) or, failing that, quarantined; the log is rewritten."""
        names = {r.get("name") for r in contents.records}
        processed = sorted((self.state.path / "processed").glob("*.json"))
        if not contents.damaged and contents.truncated is None and all(p.name in names for p in processed):
            return contents.records
        robot = self.calibrator.robot
        recovered = []
        for path in processed:
            if path.name not in names:
                try:
                    recovered.append(read_measurement(path, robot.n_joints, limits=robot.limits).to_record())
                except InputError as error:
                    self.say(f"warning: cannot recover from {path}: {error}")
        records = list(contents.records)
        # The files left after the damaged records' are the log's lost last records: a truncated
        # last record (its file in processed/ means it was acknowledged: the file moves only
        # after the record is fsync'ed, so it was damaged on disk since), or one cut off by an
        # earlier start before this rule. A truncated record without its file was never
        # acknowledged: its file is still in the inbox and comes in again.
        for tail in recovered[len(contents.damaged) :]:
            records.append(tail)
            message = f"lost last log record recovered from processed/{tail['name']}"
            self.say(f"warning: {message}")
            self.problems.append(message)
        quarantine = self.state.path / "quarantine"
        for i, (position, raw) in reversed(list(enumerate(contents.damaged))):
            if i < len(recovered):
                records.insert(position, recovered[i])
                message = f"damaged log record recovered from processed/{recovered[i]['name']}"
            else:
                kept = write_bytes(subfolder(quarantine.parent, quarantine.name) / f"log-record-{position + i + 1}.bin",
                                   raw)  # fmt: skip
                message = f"damaged log record with no measurement file to recover it from: quarantined in {kept}"
            self.say(f"warning: {message}")
            self.problems.append(message)
        self.state.rewrite_log(records)
        return records

    def _check_checkpoint(self, checkpoint: dict) -> None:
        cal = self.calibrator
        values = np.array([checkpoint["estimate"][n] for n in cal.released])
        sigmas = np.array([checkpoint["sigma"][n] for n in cal.released])
        here = cal.current_params()[cal.model.index]
        # GTSAM's multithreaded elimination does not sum in a fixed order: equal to rounding.
        if np.any(np.abs(values - here) > 1e-6 * sigmas):
            message = "the replay does not reproduce the checkpoint's estimate (to 1e-6 sigma)"
            self.say(f"warning: {message}")
            self.problems.append(message)

    # -- one measurement --------------------------------------------------------------------

    def _fold(self, measurement: Measurement, replaying: bool = False) -> OnlineUpdate | None:
        if measurement.cycle != self._cycle["label"]:  # the cycle in progress has ended
            self._log_cycle(detail if replaying else None)
        try:
            update = self.calibrator.fold(measurement)
        except InputError as error:
            self.skipped.append({"name": measurement.name, "reason": error.message})
            self.say(f"skipped {measurement.name}: {error.message}")
            return None
        except Exception as error:  # a failure inside the solver: quarantined, never blocking a replay
            self._quarantine(measurement, error)
            if replaying:
                raise _Replayed from None  # the replay of the log was redone without it
            return None
        if not replaying:
            self.latencies.append(update.update_s)
        gated = update.extra.get("gated")
        if "change_point" in update.extra:  # a run of gated configurations: the robot changed
            run = set(self._gated_names)
            self.skipped = [s for s in self.skipped if s["name"] not in run]
            (detail if replaying else self.say)(
                f"{measurement.name}: {self.calibrator.settings.gate_run} consecutive configurations gated: taken for "
                f"a change of the robot (a drift alarm, every released parameter restarting from its prior sigma); "
                f"the {update.extra['change_point']} configurations folded in"
            )
            self._gated_names = []
        elif gated:  # logged, not folded in: a residual beyond the gate at the current estimate
            reason = (f"gated ({', '.join(gated)} beyond {self.calibrator.settings.outlier_gate_sigma:g} predicted "
                      "sigmas at the current estimate): not folded in")  # fmt: skip
            self.skipped.append({"name": measurement.name, "reason": reason})
            (detail if replaying else self.say)(f"{measurement.name}: {reason}")
            if update.n_images == self._folded:  # none of its configurations folded in
                self._gated_names.append(measurement.name)
                return update
        else:
            self._gated_names = []
        self._folded = update.n_images
        predicted = self.predicted = self.predicted_accuracy()
        self._log_measurement(measurement, update, predicted, replaying)
        if self.met_at is None and predicted["rms_m"] <= self.target_m:
            self.met_at = update.n_images
        if update.alarms:
            self.alarms.append(
                {
                    "image": update.n_images,
                    "name": measurement.name,
                    "threshold_z": update.alarms[0].threshold,
                    "parameters": [
                        {"parameter": a.parameter, "z": a.z, "change": a.change, "unit": unit_of(a.parameter)}
                        for a in update.alarms
                    ],
                }
            )
        if update.alarms:
            flagged = ", ".join(a.parameter for a in update.alarms[:5])
            self.say(f"drift alarm at image {update.n_images} ({measurement.name}): {flagged}")
        sigmas = self.calibrator.sigmas
        self._history_handle.write(
            f"{update.n_images},{measurement.name},{update.cycle},{update.update_s * 1e3:.3f},"
            f"{predicted['rms_m']:.6e},{len(update.alarms)}," + ",".join(f"{s:.6e}" for s in sigmas) + "\n"
        )
        self._history_handle.flush()
        return update

    def _log_measurement(
        self, measurement: Measurement, update: OnlineUpdate, predicted: dict, replaying: bool
    ) -> None:
        """One line per measurement, and one per work cycle when the next cycle starts (mm and
        mdeg); a replay's lines are details (fgcal -v)."""
        line = detail if replaying else self.say
        cal = self.calibrator
        if measurement.cycle != self._cycle["label"] or not self._cycle["n"]:
            self._cycle = {"label": measurement.cycle, "n": 0, "start": self._previous.copy()}
        self._cycle["n"] += 1
        if "waiting_readings" in update.extra:  # a configuration that readings between two will name
            line(f"{measurement.name}: arrived, nothing of its own to fold in ({update.extra['waiting_readings']} "
                 "readings between two configurations wait for their other one)")  # fmt: skip
            return
        if "pending_images" in update.extra:  # held back until the unknowns can be started
            line(f"{measurement.name}: held back ({update.extra['pending_images']} so far; the first ones start the "
                 "instrument's unknowns together)")  # fmt: skip
            return
        estimate = cal.current_params()[cal.model.index]
        step = (estimate - self._previous) / cal.sigmas
        i = int(np.argmax(np.abs(step)))
        name = cal.released[i]
        cycle = "-" if measurement.cycle is None else measurement.cycle
        if abs(step[i]) > ABSURD_STEP_SIGMAS:
            message = (f"{measurement.name}: {name} stepped {human(name, estimate[i] - self._previous[i])} "
                       f"({step[i]:+.3g} sigma) in one measurement: the estimate is not to be trusted")  # fmt: skip
            self.say(f"warning: {message}")
            self.problems.append(message)
        line(
            f"{measurement.name}: measurement {update.n_images}, cycle {cycle}, "
            f"{measurement.n_observations} observations, {update.update_s * 1e3:.1f} ms; predicted RMS flange sigma "
            f"{predicted['rms_m'] * 1e3:#.3g} mm; largest step {name} {human(name, estimate[i] - self._previous[i])} "
            f"({step[i]:+.2f} sigma)"
            + (f"; {len(update.rejected_points)} gated" if update.rejected_points else "")
        )
        self._previous = estimate

    def _log_cycle(self, line: Callable[[str], None] | None = None) -> None:
        """The line of the work cycle in progress: its measurements and its largest change."""
        cycle = self._cycle
        if not cycle["n"]:
            return
        cal = self.calibrator
        change = cal.current_params()[cal.model.index] - cycle["start"]
        i = int(np.argmax(np.abs(change) / cal.sigmas))
        name = cal.released[i]
        label = cycle["label"] if cycle["label"] is not None else "-"
        (line or self.say)(
            f"cycle {label}: {cycle['n']} measurements; predicted RMS flange sigma "
            f"{self.predicted['rms_m'] * 1e3:#.3g} mm; largest change {name} {human(name, change[i])} "
            f"({change[i] / cal.sigmas[i]:+.2f} sigma); {len(self.alarms)} drift alarms so far"
        )
        cycle["n"] = 0

    def _quarantine(self, measurement: Measurement, error: Exception) -> None:
        """Mark a logged measurement whose folding-in failed, durably (a marker record in the
        log, which replays honour), and rebuild the estimate from the log without it: the
        failed update may have left the smoother half changed."""
        reason = f"{type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ''}"
        self.say(f"quarantined {measurement.name}: folding it in failed ({reason}); rebuilding from the log")
        self.state.append({QUARANTINE: measurement.name, "reason": reason})
        self.calibrator = self._new_calibrator()
        self._replay()

    def predicted_accuracy(self) -> dict:
        """Predicted flange position sigma (m) at the configurations in the window."""
        cal = self.calibrator
        q = cal.window_q()
        if not len(q):
            return {"rms_m": float("nan"), "max_m": float("nan"), "n_configurations": 0}
        cov = position_covariance(
            cal.robot, cal.current_params(), cal.released, cal.covariance, q, "flange", np.zeros(3)
        )
        radial = np.sqrt(np.trace(cov, axis1=1, axis2=2))
        return {"rms_m": float(np.sqrt(np.mean(radial**2))), "max_m": float(radial.max()), "n_configurations": len(q)}

    def process_inbox(self) -> int:
        """Process every complete measurement file in the inbox (fgcal.online.inbox says which);
        returns how many were new."""
        count = 0
        for entry in entries(self.inbox):
            if self.stop_requested():
                break
            if entry.problem is not None:
                self._reject_entry(entry)
                continue
            claimed = claim(self.inbox, entry)
            if claimed is None:  # another process took it
                continue
            source = self.inbox / entry.name
            try:
                robot = self.calibrator.robot
                measurement = read_measurement(claimed, robot.n_joints, entry.name, source, robot.limits)
                self.calibrator.check(measurement, source)
                if entry.name in self.logged:
                    if _digest(measurement.to_record()) == self.logged[entry.name]:
                        # Acknowledged just before a crash, not yet moved aside.
                        shutil.move(str(claimed), self.processed / entry.name)
                        continue
                    raise InputError(
                        source, None, "an earlier, different measurement has this name: names must be unique"
                    )
            except InputError as error:
                self.say(f"rejected {entry.name}: {error}")
                shutil.move(str(claimed), self.rejected / entry.name)
                write_text(self.rejected / f"{entry.name}.error.txt", str(error) + "\n")
                continue
            record = measurement.to_record()
            try:
                self.state.append(record)
            except OSError as error:  # e.g. a full disk: not acknowledged, so back in the inbox
                os.replace(claimed, source)
                raise InputError(
                    self.state.path / "measurements.log",
                    None,
                    f"cannot append {entry.name}: {error}; it stays in the inbox",
                ) from None
            self.logged[measurement.name] = _digest(record)
            shutil.move(str(claimed), self.processed / entry.name)
            before = self.calibrator.n_images
            self._fold(measurement)
            count += 1
            # Every CHECKPOINT_EVERY configurations (a file may carry several).
            if self.calibrator.n_images // CHECKPOINT_EVERY > before // CHECKPOINT_EVERY:
                self._checkpoint()
            self._write_outputs()
        return count

    def _reject_entry(self, entry: Entry) -> None:
        """An inbox entry that is no measurement file (a link, a FIFO, an odd name) moved to
        rejected/ under a safe name, with the reason; a link or FIFO that cannot be moved there
        (another filesystem) is removed from the inbox instead, a folder left where it is."""
        name = safe_name(entry.name)
        reason = f"{entry.problem}"
        try:
            os.rename(entry.path, self.rejected / name)
        except FileNotFoundError:
            return  # taken by another process
        except OSError:
            if entry.path.is_dir() and not entry.path.is_symlink():
                if entry.name in self._left:
                    return
                self._left.add(entry.name)
                reason += "; left in the inbox"
            else:
                entry.path.unlink(missing_ok=True)
                reason += "; removed from the inbox (it could not be moved)"
        self.say(f"rejected {name}: {reason}")
        write_text(self.rejected / f"{name}.error.txt", f"{reason}\n")

    def _checkpoint(self) -> None:
        cal = self.calibrator
        self.state.write_checkpoint(
            {
                "n_records": len(self.logged),
                "n_images": cal.n_images,
                "estimate": dict(zip(cal.released, cal.current_params()[cal.model.index].tolist(), strict=True)),
                "sigma": dict(zip(cal.released, cal.sigmas.tolist(), strict=True)),
                "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            }
        )

    def run(self, once: bool, poll_s: float = 1.0, max_idle_s: float | None = None) -> None:
        """Process the inbox; with ``once`` until it is empty, otherwise until a stop is
        requested (then the current measurement is finished first) or ``max_idle_s`` passed."""
        idle_since = time.monotonic()
        while not self.stop_requested():
            if self.process_inbox():
                idle_since = time.monotonic()
                self.write_final()
            if once or (max_idle_s is not None and time.monotonic() - idle_since > max_idle_s):
                break
            waited = 0.0
            while waited < poll_s and not self.stop_requested():  # a stop is seen within 0.1 s
                time.sleep(min(0.1, poll_s - waited))
                waited += 0.1
        self._log_cycle()
        self.write_final()

    # -- outputs ----------------------------------------------------------------------------

    def report(self) -> dict:
        cal = self.calibrator
        params = cal.current_params()
        sigma = dict(zip(cal.released, cal.sigmas.tolist(), strict=True))
        prior = dict(zip(cal.released, cal.prior_sigmas.tolist(), strict=True))
        parameters = {
            name: {
                "unit": unit_of(name),
                "start": float(cal.start[i]),
                "estimate": float(params[i]),
                "sigma": sigma.get(name),
                "prior_sigma": prior.get(name),
                "status": "released" if name in sigma else "fixed",
            }
            for i, name in enumerate(cal.robot.parameter_names)
        }
        latency = np.array(self.latencies) * 1e3
        return {
            "format": "fgcal-online-report/1",
            "robot": cal.robot.name,
            "n_images": cal.n_images,
            "n_logged": len(self.logged),
            "cycle": cal.cycle,
            "parameters": parameters,
            "prior_dominated": [n for n in cal.released if sigma[n] > 0.5 * prior[n]],
            "implausible": [
                n for n in cal.released
                if abs(parameters[n]["estimate"] - parameters[n]["start"]) > ABSURD_MOVE_PRIORS * prior[n]
            ],
            "predicted_accuracy": self.predicted,
            "stopping_rule": {
                "rule": "predicted RMS flange position sigma over the window's configurations <= target",
                "target_m": self.target_m,
                "met": self.met_at is not None,
                "met_at_image": self.met_at,
            },
            "alarms": self.alarms,
            "alarm_test": {
                "false_alarm_rate_per_image": cal.settings.alarm_false_rate,
                "threshold_z": cal.drift.threshold,
                "lag_images": cal.settings.alarm_lag_images,
            },
            "skipped": self.skipped,
            "quarantined": [{"name": n, "reason": why} for n, why in self.quarantined.items()],
            "problems": self.problems,
            "identifiability": "released list from the setup file"
            if "released" in self.config
            else "batch analysis of the reference dataset's measurements at the starting model"
            if "formulation" in self.config
            else "structural: 300 configurations uniform in the joint limits, seed 0",
            "latency_ms": {
                "n_updates": len(latency),
                "median": float(np.median(latency)) if len(latency) else None,
                "p99": float(np.percentile(latency, 99)) if len(latency) else None,
            },
        }

    def _write_outputs(self) -> None:
        cal = self.calibrator
        if cal.n_images == 0:
            return
        robot_path = self.state.path / "calibrated_robot.yaml"
        temporary = robot_path.with_name(".calibrated_robot.yaml.tmp")
        save_robot(
            temporary,
            cal.robot,
            cal.robot.parameter_dict(cal.current_params()),
            notes=f"fgcal online: {cal.n_images} images",
        )
        temporary.replace(robot_path)
        write_atomic(self.state.path / "report.json", strict_json.dumps(self.report(), indent=1).encode("utf-8"))

    def write_final(self) -> None:
        if self.calibrator.n_images and self._final_at != self.calibrator.n_images:
            self._final_at = self.calibrator.n_images
            self._write_outputs()
            write_final_report(self.state.path, self.report())

    def close(self) -> None:
        if self._history_handle is not None:
            self._history_handle.close()
            self._history_handle = None
        self.state.close()
