"""``FormulationCalibrator``: online recalibration of any registered formulation with iSAM2.

What a measurement is and which factors it gives are the formulation's
(fgcal.calibration.problem.Formulation): each measurement (one configuration's observations,
in the formulation's tables) becomes a one-configuration dataset, the formulation reads its
observations (``online_observations``) and gives its measurement sets on the graph's keys
(``measurement_sets``). Nothing here knows a formulation by name.

Graph, as the camera's (fgcal.online.calibrator): a parameter vector ``p_c`` per work cycle,
tied by a random walk, a prior on ``p_0`` around the starting model, and the formulation's
auxiliary unknowns (a tracker's pose, the reflectors on the flange, ...), constant. The first
``start_measurements`` measurements, and at least as many residual rows as the start's
unknowns, are held back: together they are a small batch problem whose ``initial_state``
starts the auxiliary unknowns (as a batch calibration starts them, from the data at the
nominal model), solved by Levenberg-Marquardt, and they enter iSAM2 in one update at that
solution; later measurements enter one at a time. Measurements older than the
window are frozen into linear factors (what marginalising leaves), so memory stays bounded.
A motion history travels with a measurement (the joints before its last move and the move's
speed), so that a model with the history's terms (DH,s,e,h) is refined online.

Released parameters: the setup's list, or the batch identifiability analysis
(fgcal.calibration.identifiability.analyse) of the formulation's graph over the reference
dataset's own measurements (the calibration the online run refines), at the starting model and
again at that data's solution, and of those the geometric parameters the data determine (sigma
at most ``determined_fraction`` of the prior): a near-gauge direction held by the prior drifts
online, as its frozen linearisations lend it information (docs/online.md).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from ..calibration.formulations import formulation as registered
from ..calibration.graph import build_graph
from ..calibration.identifiability import analyse, reduced_jacobian
from ..calibration.priors import Priors
from ..calibration.problem import Keys, Observations, Problem, candidate_parameters
from ..calibration.settings import MeasurementSettings, Noise
from ..calibration.solve import ABSOLUTE_TOLERANCE, RELATIVE_TOLERANCE, solve_stage
from ..calibration.state import State
from ..core.console import warn
from ..core.errors import InputError
from ..data.dataset import Dataset, Table
from ..factors import RandomWalkFactor, gaussian
from ..model.motion import MotionHistory
from ..model.parameters import unit_of
from ..model.robot import Robot
from .calibrator import OnlineSettings, OnlineUpdate, params_key
from .compression import copy_value, merge_marginals
from .drift import Alarm, DriftTest
from .growing import GrowingKinematics

# Units of the parameters the online graph releases (a mass scale needs many configurations'
# gravity moments at once: it is left at its starting value).
RELEASABLE_UNITS = ("m", "rad", "rad/(N m)")


@dataclass(frozen=True)
class Reading:
    """One measurement: a configuration (rad), its observations in the formulation's tables
    (per table, the id columns other than ``config`` and the values, SI), and how it was
    reached (the joints before its last move, rad, and the move's speed factor; None: not
    given, then the previous configuration's joints, as in a dataset; the first of a run's:
    unknown, as a dataset's first row)."""

    q: np.ndarray
    tables: dict[str, tuple[dict[str, list[str]], np.ndarray]]
    before: np.ndarray | None = None
    speed: float = 1.0
    label: str | None = None  # what readings between two configurations call it (config_a, config_b)

    @property
    def n_observations(self) -> int:
        return sum(len(values) for _, values in self.tables.values())


# The compliance prior (rad/(N m)) when the setup states none: wider than plausible compliances
# (a light arm's 1e-5 to 8.4e-5: the IRB 120 cells, the touch cell's 30-84 urad/(N m)), so that
# it does not pull them to zero; the batch calibration puts no prior on them unless stated. The
# former 1e-6 did (14 false drift alarms on the touch cell with its documented setup; docs/online.md).
PRIOR_SIGMA_COMPLIANCE = 1e-4

# A reference fit whose chi2 per degree of freedom exceeds this is a model that cannot fit the
# cell (a chi2 this large at 100 degrees of freedom has probability 1e-8).
MISFIT = 2.0

# Id columns that name configurations by their labels: a reading between two configurations.
REFERS = "config_"
# Configurations remembered for readings between two configurations, and readings waiting for
# their other configuration: at most this many each (the oldest forgotten).
MAX_REMEMBERED = 100_000


def _refers(ids) -> list[str]:
    return [k for k in ids if k.startswith(REFERS)]


def aux_key(i: int) -> int:
    """Key of the i-th auxiliary unknown: its own symbol letter (A, B, ...), so that each has
    its relinearisation threshold of its own dimension."""
    return gtsam.symbol(chr(ord("A") + i), 0)


class FormulationCalibrator:
    """Incremental calibration of ``formulation`` (a registered name) from measurements.

    ``reference`` is a dataset of the cell (its robot, the instrument's stated noise, its
    static tables such as a camera's calibration points); with the formulation's measurements
    it also decides the released parameters. ``robot`` (default the reference's) is the
    starting model, ``model`` (default the robot's) the model fitted.
    """

    def __init__(
        self,
        reference: Dataset,
        formulation: str,
        settings: OnlineSettings | None = None,
        released: list[str] | None = None,
        robot: Robot | None = None,
        model: str | None = None,
        keep_graph: bool = False,
    ) -> None:
        s = settings or OnlineSettings()
        if s.prior_sigma_compliance is None:
            s = replace(s, prior_sigma_compliance=PRIOR_SIGMA_COMPLIANCE)
        self.settings = s
        if s.marginalise_every < 1 or s.window_images < 2 * s.marginalise_every:
            raise InputError(
                None,
                "window_images",
                f"must be at least twice marginalise_every ({s.marginalise_every}), got {s.window_images}",
            )
        self.formulation = registered(formulation)
        if self.formulation.not_incremental:
            raise InputError(
                None, "formulation", f"the {formulation} formulation cannot be refined online: "
                f"{self.formulation.not_incremental}",
            )  # fmt: skip
        robot = robot or reference.robot
        self.robot = robot.with_model(model or robot.model)
        self.measurement_settings = replace(MeasurementSettings(), noise=Noise.stated(reference.noise))
        # The measurements' tables come from the inbox; the rest (calibration points) stays.
        static = {name: t for name, t in reference.tables.items() if "config" not in t.ids and not _refers(t.ids)}
        self.measured = sorted(name for name, t in reference.tables.items() if "config" in t.ids or _refers(t.ids))
        self.template = replace(
            reference, robot=self.robot, configs=np.zeros(0, dtype=object), q=np.zeros((0, robot.n_joints)),
            tables=static, history=None,
        )  # fmt: skip
        self.start = self.robot.parameter_vector()
        if released is None:
            released = self._identifiable(reference)
        unknown = [n for n in released if n not in self.robot.parameter_names]
        if unknown:
            raise InputError(None, "released", f"unknown parameter {unknown[0]!r} for {self.robot.name}")
        if not released:
            raise InputError(None, "released", "no parameter to estimate")
        self.released = list(released)
        self.model = GrowingKinematics(self.robot, self.start, self.released, "flange")  # bookkeeping of q
        self.prior_sigmas = np.array([s.by_kind(n, "prior") for n in self.released])
        self.drift_sigmas = np.array([s.by_kind(n, "drift") for n in self.released])
        self.drift = DriftTest(self.released, self.drift_sigmas**2, s.alarm_lag_images, s.alarm_false_rate)
        self.smoother: gtsam.IncrementalFixedLagSmoother | None = None
        self.n_images = 0  # measurements folded in
        self.cycle = 0
        self.drift_time = 0.0
        self._cycle_label: int | None = None
        self._jump: set[int] = set()
        self._p = self.start[self.model.index].copy()
        self._sigmas = self.prior_sigmas.copy()
        self._covariance = np.diag(self.prior_sigmas**2)
        self._pending: list[tuple[Reading, int | None]] = []
        self._gated_run: list[Reading] = []  # the last consecutive gated configurations
        # The joints of the last configuration that arrived: the approach of a measurement without
        # its own (before_joints), as a dataset's row is reached from the row before.
        self._last_q: np.ndarray | None = None
        # Labelled configurations that arrived: label -> (q, before, speed); and readings between
        # two configurations waiting for one of them: (table, {id column: value}, values).
        self._arrived: dict[str, tuple[np.ndarray, np.ndarray | None, float]] = {}
        self._waiting: list[tuple[str, dict[str, str], np.ndarray]] = []
        self.state: State | None = None  # the auxiliary unknowns' starting values, once started
        self.like: Observations | None = None
        self._once: tuple[Problem | None, Observations | None] = (None, None)
        self.keys: dict[str, int] = {}
        self._slots: dict[int, list[int]] = {}  # row -> smoother slots of its live factors
        self._scanned = 0
        self._marginals: list[int] = []
        self.keep_graph = keep_graph
        self.graph = gtsam.NonlinearFactorGraph()
        self.initial = gtsam.Values()

    # -- the released set ---------------------------------------------------------------------

    def _candidates(self) -> list[str]:
        names = candidate_parameters(self.robot, self.robot.model, self.settings.compliant_joints)
        return [n for n in names if unit_of(n) in RELEASABLE_UNITS]

    def _identifiable(self, reference: Dataset) -> list[str]:
        """The batch analysis on the reference dataset's measurements at the starting model."""
        fit = np.arange(len(reference.configs))
        try:
            problem = self._problem(replace(reference, robot=self.robot), fit)
        except InputError as error:
            raise InputError(
                reference.path, "released", f"{error.message}: give the released parameters in the setup, or a "
                f"dataset with the {self.formulation.kind} of a calibration to analyse",
            ) from None  # fmt: skip
        state = self.formulation.initial_state(problem)
        state = state.with_params(self.start)
        at_start = analyse(build_graph(problem, self._candidates(), state)).identifiable
        if not at_start:
            return at_start
        # Again at the reference data's solution, as the batch calibration does: at the start
        # the model error (mm) lends a direction that the auxiliary unknowns absorb exactly at the
        # solution (the touch cell's base rotations theta1, ry1 against its points in W) an
        # information it does not have. Released online, such a near-gauge direction is held
        # by the prior alone and drifts tens of sigmas (docs/online.md).
        solved, report, _, _ = solve_stage(problem, "reference", at_start, state)
        fit = report.fit
        if fit.dof > 0 and fit.chi2 / fit.dof > MISFIT:
            # The drift test then takes the misfit for drift (the touch cell fitted with the
            # default compliant joints 1-3 instead of its 2 and 4: 13 alarms in 100 touches).
            warn(
                f"the model fitted online leaves the reference data's residuals at {np.sqrt(fit.chi2 / fit.dof):.1f} "
                f"times their stated noise (residual RMS {report.rms_text()}): the online estimate will not be "
                "consistent; check the model and compliant_joints in the setup's settings"
            )
        released = analyse(build_graph(problem, at_start, solved)).identifiable
        return self._determined(problem, released, solved)

    def _determined(self, problem: Problem, released: list[str], solved: State) -> list[str]:
        """Of ``released``, those the reference data determine: at the reference solution, with
        the online prior on the parameters, a geometric parameter (m, rad) is released when its
        marginal sigma is at most ``determined_fraction`` of its prior sigma (the weakest left out,
        one at a time, until all are). One the data barely
        inform is a near-gauge direction the prior holds (the touch cell's base tilts rx1, ry1
        against its points in W: 0.48 and 0.54 of the prior; the ballbar's wrist theta5, alpha5:
        0.13, 0.14): along it the measurements frozen out of the window, each linearised at another
        point of that nonlinear direction, lend it information it does not have, and the online
        estimate ended 1-100 sigmas from the batch solution of the same graph (docs/online.md). A
        compliance enters the measurements linearly (a deflection proportional to its torque):
        weak, it is still consistent, and stays released."""
        fraction = self.settings.determined_fraction
        if fraction is None:
            return released
        while released:
            J_p, J_aux = reduced_jacobian(build_graph(problem, released, solved))
            prior = np.array([self.settings.by_kind(n, "prior") for n in released])
            J = np.hstack([J_p * prior[None, :], J_aux])  # the parameters in prior units
            information = J.T @ J
            information[: len(released), : len(released)] += np.eye(len(released))
            ratio = np.sqrt(np.diag(np.linalg.pinv(information))[: len(released)])
            ratio[[unit_of(n) not in ("m", "rad") for n in released]] = 0.0
            if ratio.max() <= fraction:
                return released
            # The weakest first, one at a time: weak parameters come in correlated groups (the
            # touch cell's rx1, ry1, rx7 and tz6), and without the weakest the others may be
            # determined (dropping all four left a 0.14 mm misfit).
            released = [n for i, n in enumerate(released) if i != int(np.argmax(ratio))]
        return released

    def _problem(self, dataset: Dataset, fit: np.ndarray, observations: Observations | None = None) -> Problem:
        if observations is None:
            observations = self.formulation.fit_observations(dataset, self.measurement_settings, fit)
        return Problem(
            formulation=self.formulation,
            settings=self.measurement_settings,
            dataset=dataset,
            robot=self.robot,
            fit=fit,
            test=np.zeros(0, dtype=int),
            candidates=tuple(self._candidates()),
            observations=observations,
            priors=Priors(),
            max_iterations=100,
        )

    def _dataset(self, readings: list[Reading], first: int) -> Dataset:
        """The readings as a dataset of their configurations (ids: their labels, or m<row>),
        followed by the configurations that arrived before and that their readings between two
        configurations name."""
        ids = [r.label if r.label is not None else f"m{first + i}" for i, r in enumerate(readings)]
        named = [ids[i] for i in range(len(readings))]
        for reading in readings:
            for row_ids, _ in reading.tables.values():
                for key in _refers(row_ids):
                    named += [label for label in row_ids[key] if label not in named]
        extra = [label for label in named[len(readings) :] if label in self._arrived]
        tables: dict[str, Table] = dict(self.template.tables)
        for name in sorted({t for r in readings for t in r.tables}):
            columns: dict[str, list] = {}
            values = []
            for config, reading in zip(ids, readings, strict=True):
                if name not in reading.tables:
                    continue
                row_ids, row_values = reading.tables[name]
                if not _refers(row_ids):  # one configuration's: this one
                    columns.setdefault("config", []).extend([config] * len(row_values))
                for key, entries in row_ids.items():
                    columns.setdefault(key, []).extend(entries)
                values.append(np.asarray(row_values, dtype=float))
            tables[name] = Table({k: np.array(v, dtype=object) for k, v in columns.items()}, np.vstack(values))
        n = self.robot.n_joints
        q = [r.q for r in readings] + [self._arrived[label][0] for label in extra]
        before = [r.before for r in readings] + [self._arrived[label][1] for label in extra]
        before = [b if b is not None else np.full(n, np.nan) for b in before]
        speed = [r.speed for r in readings] + [self._arrived[label][2] for label in extra]
        history = MotionHistory(np.array(before), np.array(speed))
        configs = np.array(ids + extra, dtype=object)
        return replace(self.template, configs=configs, q=np.array(q), tables=tables, history=history)

    # -- one measurement ------------------------------------------------------------------------

    def add(self, reading: Reading, cycle: int | None = None) -> OnlineUpdate:
        """Fold one measurement in (the first ``start_measurements`` are held back and folded in
        together, into the last one's work cycle)."""
        return self.add_batch([reading], cycle)

    def add_batch(self, readings: list[Reading], cycle: int | None = None) -> OnlineUpdate:
        """Fold a work cycle's measurements in together, in one update (an inbox file with
        several configurations); before the start they are held back as :meth:`add`'s."""
        started = time.perf_counter()
        checked = []
        previous = self._last_q
        for reading in readings:
            q = self.robot.check_q(reading.q)[0]
            if not reading.n_observations and reading.label is None:
                raise InputError(None, "observations", "a measurement needs at least one observation")
            if reading.before is None:  # the batch's rule (configurations.csv): from the one before
                reading = replace(reading, before=previous)
            checked.append(replace(reading, q=q))
            previous = q
        # The robot was there, whether or not the measurement folds in: the next one's approach.
        self._last_q = previous
        latest = next((c for _, c in reversed(self._pending) if c is not None), self._cycle_label)
        if cycle is not None and latest is not None and cycle < latest:
            raise InputError(None, "cycle", f"cycle {cycle} is before the current cycle {latest}")
        joined, waiting = self._join(checked)
        arrived, waited = dict(self._arrived), list(self._waiting)
        for reading in checked:
            if reading.label is not None:
                self._arrived[reading.label] = (reading.q, reading.before, reading.speed)
        while len(self._arrived) > MAX_REMEMBERED:  # the oldest forgotten: memory stays bounded
            del self._arrived[next(iter(self._arrived))]
        self._waiting = waiting
        try:
            return self._add_joined([r for r in joined if r.n_observations], cycle, started)
        except BaseException:  # nothing changed: the configurations have not arrived
            self._arrived, self._waiting = arrived, waited
            raise

    def _add_joined(self, readings: list[Reading], cycle: int | None, started: float) -> OnlineUpdate:
        if not readings:  # configurations that readings between two configurations will name
            return self._update(started, [], {"waiting_readings": len(self._waiting)})
        if self.state is None:
            self._pending += [(reading, cycle) for reading in readings]
            if not self._start():
                return self._update(started, [], {"pending_images": len(self._pending)})
            pending, self._pending = self._pending, []
            return self._fold([r for r, _ in pending], pending[-1][1], started)
        return self._fold(readings, cycle, started)

    def _join(self, readings: list[Reading]) -> tuple[list[Reading], list]:
        """The readings with their rows between two configurations that can join the graph (both
        configurations arrived, now or before), and the rows left waiting for one: a waiting row
        joins with the last reading of this batch that it names."""
        here = [r.label for r in readings if r.label is not None]
        again = sorted({label for label in here if label in self._arrived} | {x for x in here if here.count(x) > 1})
        if again:
            raise InputError(None, "config", f"configuration {again[0]!r} has arrived before: labels must be unique")
        known = set(self._arrived) | set(here)
        tables = [dict(r.tables) for r in readings]
        still = []
        for name, row, values in self._waiting:
            labels = {row[k] for k in _refers(row)}
            if not labels <= known:
                still.append((name, row, values))
                continue
            i = max(i for i, r in enumerate(readings) if r.label in labels)
            _append(tables[i], name, row, values)
        out = []
        for reading, mine in zip(readings, tables, strict=True):
            kept: dict = {}
            for name, (ids, values) in mine.items():
                refers = _refers(ids)
                for i in range(len(values)):
                    row = {k: v[i] for k, v in ids.items()}
                    if refers and not {row[k] for k in refers} <= known:
                        still.append((name, row, np.asarray(values[i], dtype=float)))
                    else:
                        _append(kept, name, row, values[i])
            out.append(replace(reading, tables=kept))
        return out, still[-MAX_REMEMBERED:]

    def _start(self) -> bool:
        """With enough measurements held back, the auxiliary unknowns' starting values and the
        labels of the observations (True); False while they cannot calibrate yet."""
        if len(self._pending) < self.settings.start_measurements:
            return False
        readings = [r for r, _ in self._pending]
        dataset = self._dataset(readings, 0)
        try:
            problem = self._problem(dataset, np.arange(len(dataset.configs)))
        except InputError:
            return False
        state = self.formulation.initial_state(problem)
        # The start must determine its unknowns by itself, as a batch calibration's data must:
        # with fewer rows than unknowns the auxiliary unknowns (a ballbar's pivots) rest on the
        # nominal model's guess and the prior, and Gauss-Newton steps from there diverged
        # (irb120_ballbar: 22 readings for 26 parameters and 12 coordinates, docs/online.md).
        if problem.observations.n_residuals < len(self.released) + state.n_auxiliary:
            return False
        self.state = state.with_params(self.start)
        self.like = problem.observations
        self._once = problem, self.formulation.online_once(problem)
        self.keys = {name: aux_key(i) for i, name in enumerate(self.state.aux)}
        self.smoother = gtsam.IncrementalFixedLagSmoother(
            float(self.settings.window_images // self.settings.marginalise_every), self._isam_params()
        )
        return True

    def _isam_params(self) -> gtsam.ISAM2Params:
        s = self.settings
        params = gtsam.ISAM2Params()
        params.setFactorization("QR")
        thresholds = gtsam.ISAM2ThresholdMap()
        thresholds.insert(("p", s.relinearize_fraction * self.prior_sigmas))
        for i, aux in enumerate(self.state.aux.values()):
            thresholds.insert((chr(ord("A") + i), np.full(aux.dim, s.relinearize_pose)))
        params.setRelinearizeThreshold(thresholds)
        params.relinearizeSkip = 1
        params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
        return params

    def factors(self, readings: list[Reading], first_row: int, P: int) -> list[gtsam.NonlinearFactorGraph]:
        """Per reading, its formulation's factors on (P, the auxiliary unknowns)."""
        out = []
        for i, reading in enumerate(readings):
            dataset = self._dataset([reading], first_row + i)
            subset = np.arange(len(dataset.configs))  # this one, and those its readings name
            observations = self.formulation.online_observations(dataset, self.measurement_settings, subset, self.like)
            if not observations.n_residuals:
                raise InputError(None, "observations", f"none that the {self.formulation.name} formulation reads")
            problem = self._problem(dataset, subset, observations)
            kinematics = problem.kinematics(self.state, self.released, observations)
            keys = Keys(P, self.keys)
            graph = gtsam.NonlinearFactorGraph()
            for measurements in self.formulation.measurement_sets(
                problem, observations, kinematics, keys, self.state, None
            ):
                graph.add(measurements.factor().factor)
            out.append(graph)
        return out

    def _fold(
        self, readings: list[Reading], cycle: int | None, started: float, change_point: bool = False
    ) -> OnlineUpdate:
        new_cycle = self.n_images > 0 and (bool(self._jump) or (cycle is not None and cycle != self._cycle_label))
        P = params_key(self.cycle + (1 if new_cycle else 0))
        first_row = self.model._next
        per_reading = self.factors(readings, first_row, P)  # an InputError here changes nothing
        gated: list[str] = []
        gate = self.settings.outlier_gate_sigma
        if self.n_images and gate is not None and not change_point:  # the start's batch is not gated
            z = self._innovations(per_reading, P, self._walk_sigmas(cycle) if new_cycle else None)
            gated = [f"configuration {i + 1}: {value:.1f} sigma" for i, value in enumerate(z) if value > gate]
            keep = [i for i, value in enumerate(z) if value <= gate]
            # A run of gated configurations (the last ones, with those gated just before) is
            # the robot changing, not the instrument erring: a change point (docs/online.md).
            run, carried = [], list(self._gated_run)
            for i, value in enumerate(z):
                if value > gate:
                    run.append(i)
                else:
                    run, carried = [], []
            if len(carried) + len(run) >= self.settings.gate_run:
                self._gated_run = []
                return self._change_point(
                    [*carried, *(readings[i] for i in keep), *(readings[i] for i in run)], cycle, started, gated
                )
            self._gated_run = [*carried, *(readings[i] for i in run)]
            readings, per_reading = [readings[i] for i in keep], [per_reading[i] for i in keep]
            if not readings:  # nothing folded in: the estimate and the cycle stay
                update = self._update(started, [], {"gated": gated})
                update.rejected_points = gated
                return update
        rows = [self.model.add(r.q, self.cycle + (1 if new_cycle else 0)) for r in readings]
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if self.n_images == 0:
            graph.add(gtsam.PriorFactorVector(P, self._p, gaussian(self.prior_sigmas)))
            values.insert(P, self._p)
            for name, aux in self.state.aux.items():
                values.insert(self.keys[name], aux.to_gtsam())
                if aux.prior_sigmas is not None:  # the batch graph's (build_graph): a drawing's balls, planes
                    graph.add(gtsam.PriorFactorVector(self.keys[name], aux.prior_mean, gaussian(aux.prior_sigmas)))
            self._cycle_label = cycle
            graph.push_back(self._once_factors(P))
            # iSAM2 takes one Gauss-Newton step per update, and what leaves the window is frozen
            # where it stands: the start's batch is solved first (Levenberg-Marquardt, as the
            # batch calibration), so that iSAM2 starts at its solution.
            start = gtsam.NonlinearFactorGraph(graph)
            for g in per_reading:
                start.push_back(g)
            values = _solved(start, values)
        elif new_cycle:
            elapsed = max(1, cycle - self._cycle_label) if cycle is not None and self._cycle_label is not None else 1
            sigmas = self._walk_sigmas(cycle)
            self.cycle += 1
            self.drift_time += elapsed
            graph.add(RandomWalkFactor(params_key(self.cycle - 1), P, sigmas).factor)
            values.insert(P, self._p)
            self._jump = set()
            if cycle is not None:
                self._cycle_label = cycle
        first_measurement = graph.size()
        for g in per_reading:
            graph.push_back(g)
        frozen, removed = self._freeze(rows[-1])
        update = gtsam.NonlinearFactorGraph(graph)
        update.push_back(frozen)
        stamp = float(rows[-1] // self.settings.marginalise_every)
        first_slot = self.smoother.getFactors().size()
        stamps = {P: stamp, **{key: stamp for key in self.keys.values()}}
        self.smoother.update(update, values, stamps, removed)
        slot = first_slot + first_measurement
        for row, g in zip(rows, per_reading, strict=True):
            self._slots[row] = list(range(slot, slot + g.size()))
            slot += g.size()
        self._merge_marginals()
        if not self.keep_graph:
            self.model.forget_before(min(self._slots, default=rows[-1]))
        else:
            self.graph.push_back(graph)
            self.initial.insert(values)
        self._p = self.smoother.calculateEstimateVector(P)
        covariance = self.smoother.marginalCovariance(P)
        self._sigmas = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        self._covariance = covariance
        self.n_images += len(readings)
        if change_point:  # the alarm is the change point's (_change_point); the test starts again
            self.drift.reset()
            self.drift.check(self.n_images - 1, self.drift_time, self._p, self._sigmas)
            alarms = []
        else:
            alarms = self.drift.check(self.n_images - 1, self.drift_time, self._p, self._sigmas)
        if alarms:
            self._jump = {self.released.index(a.parameter) for a in alarms}
            self.drift.reset()
        update = self._update(started, alarms, {"gated": gated} if gated else None)
        update.rejected_points = gated
        return update

    def _change_point(
        self, readings: list[Reading], cycle: int | None, started: float, gated: list[str]
    ) -> OnlineUpdate:
        """``gate_run`` consecutive configurations gated: the robot changed. Every released
        parameter starts a new parameter vector whose random-walk sigma is its prior sigma (the
        drift alarm's change point; which parameter moved, a few configurations cannot tell),
        and the gated configurations are folded in with it. The alarm lists the parameters that
        moved by more than the drift test's threshold in sigmas before the change (at least the
        one that moved most)."""
        before, sigmas = self._p.copy(), self._sigmas.copy()
        self._jump = set(range(len(self.released)))
        update = self._fold(readings, cycle, started, change_point=True)
        z = (self._p - before) / sigmas
        order = [int(i) for i in np.argsort(-np.abs(z))]
        flagged = [i for i in order if abs(z[i]) > self.drift.threshold] or order[:1]
        update.alarms = [
            Alarm(self.n_images - 1, self.released[i], float(z[i]), float(self._p[i] - before[i]), self.drift.threshold)
            for i in flagged
        ]
        update.extra = {**update.extra, "change_point": len(readings), "gated": gated}
        update.rejected_points = []
        return update

    def _once_factors(self, P: int) -> gtsam.NonlinearFactorGraph:
        """The factors of what no configuration carries (Formulation.online_once), folded in
        with the start: on the auxiliary unknowns, which stay in the window."""
        graph = gtsam.NonlinearFactorGraph()
        problem, observations = self._once
        if observations is None:
            return graph
        kinematics = problem.kinematics(self.state, self.released, observations)
        for measurements in self.formulation.measurement_sets(
            problem, observations, kinematics, Keys(P, self.keys), self.state, None
        ):
            graph.add(measurements.factor().factor)
        return graph

    def _walk_sigmas(self, cycle: int | None) -> np.ndarray:
        """The random walk's sigmas from the current cycle to the next one (``cycle``, its label):
        the drift over the cycles elapsed, a parameter that raised an alarm its prior again."""
        elapsed = max(1, cycle - self._cycle_label) if cycle is not None and self._cycle_label is not None else 1
        sigmas = self.drift_sigmas * np.sqrt(elapsed)
        jumped = sorted(self._jump)
        sigmas[jumped] = self.prior_sigmas[jumped]
        return sigmas

    def _innovations(
        self, per_reading: list[gtsam.NonlinearFactorGraph], P: int, walk: np.ndarray | None
    ) -> list[float]:
        """Per reading, its largest normalised innovation: each whitened residual row r_i at the
        current estimate over its predicted sigma, ``|r_i| / sqrt(S_ii)``, ``S = I + A C A^T``
        (A: the rows' whitened Jacobian on the parameters and the auxiliary unknowns, C their
        joint marginal covariance; ``walk``: a new cycle's random walk, added to the parameters').
        A measurement the current estimate predicts to within its own noise and the estimate's
        uncertainty scores about 1; a gross error (a wrong target, a knocked reflector) many."""
        current = params_key(self.cycle)
        estimate = self.smoother.calculateEstimate()
        keys = [current, *self.keys.values()]
        joint = self.smoother.getISAM2().jointMarginalCovariance(gtsam.KeyVector(keys))
        dims = [len(self._p), *(aux.dim for aux in self.state.aux.values())]
        offsets = np.concatenate([[0], np.cumsum(dims)])
        C = np.zeros((offsets[-1], offsets[-1]))
        for i, a in enumerate(keys):
            for j, b in enumerate(keys):
                C[offsets[i] : offsets[i + 1], offsets[j] : offsets[j + 1]] = joint.at(a, b)
        if walk is not None:
            C[: dims[0], : dims[0]] += np.diag(walk**2)
        values = gtsam.Values()
        values.insert(P, self._p)
        for key in self.keys.values():
            copy_value(values, estimate, key)
        column = {P: 0, **{key: offsets[i + 1] for i, key in enumerate(self.keys.values())}}
        out = []
        for graph in per_reading:
            largest = 0.0
            for k in range(graph.size()):
                linear = graph.at(k).linearize(values)
                A_blocks, b = linear.jacobian()
                A = np.zeros((len(b), offsets[-1]))
                start = 0
                for key in list(linear.keys()):  # a KeyVector
                    width = next(d for d, o in zip(dims, offsets[:-1], strict=True) if o == column[key])
                    A[:, column[key] : column[key] + width] = A_blocks[:, start : start + width]
                    start += width
                S = 1.0 + np.einsum("ij,jk,ik->i", A, C, A)
                largest = max(largest, float(np.max(np.abs(b) / np.sqrt(S), initial=0.0)))
            out.append(largest)
        return out

    def _update(self, started: float, alarms: list, extra: dict | None = None) -> OnlineUpdate:
        return OnlineUpdate(
            self.n_images,
            self.cycle,
            self.robot.parameter_dict(self.current_params()),
            dict(zip(self.released, self._sigmas.tolist(), strict=True)),
            None,
            alarms,
            [],
            time.perf_counter() - started,
            extra or {},
        )

    # -- the service's measurements (fgcal.online.measurement) ------------------------------------

    def check(self, measurement, source) -> None:
        """InputError for a measurement file without a table the reference dataset measures
        (before it is logged); what the formulation reads of it is checked as it is folded in."""
        for k, part in enumerate(measurement.configurations):
            tables = {"pixels"} if part.pixels else set()
            tables |= {name for name, _, _ in part.observations}
            if not tables and part.label is not None:  # a configuration readings will name
                continue
            if self.formulation.kind not in tables and not tables & set(self.measured):
                field_ = f"configurations[{k}].observations" if measurement.batch else "observations"
                raise InputError(
                    source, field_, f"no table the {self.formulation.name} formulation reads (the reference "
                    f"dataset measures {', '.join(sorted(self.measured)) or 'none'}; got {', '.join(sorted(tables))})",
                )  # fmt: skip

    def fold(self, measurement) -> OnlineUpdate:
        """A measurement file's configurations, folded in together."""
        return self.add_batch(measurement.readings(), measurement.cycle)

    # -- bounded memory -------------------------------------------------------------------------

    def _freeze(self, row: int) -> tuple[gtsam.NonlinearFactorGraph, list[int]]:
        """Linear factors (at the current linearisation point) replacing the factors of the
        measurements that leave the window with this one, and the slots to remove."""
        every = self.settings.marginalise_every
        cutoff = (row // every - self.settings.window_images // every) * every
        leaving = [r for r in self._slots if r < cutoff]
        out = gtsam.NonlinearFactorGraph()
        if not leaving:
            return out, []
        factors = self.smoother.getFactors()
        point = self.smoother.getLinearizationPoint()
        removed = []
        for r in leaving:
            for slot in self._slots.pop(r):
                factor = factors.at(slot)
                if factor is None:  # marginalised with its cycle's parameter vector
                    continue
                out.add(gtsam.LinearContainerFactor(factor.linearize(point), _subset(point, factor.keys())))
                removed.append(slot)
        return out, removed

    def _merge_marginals(self) -> None:
        """Merge the marginal factors on the same variables, as the camera's calibrator does
        (compression.merge_marginals)."""
        self._marginals, self._scanned = merge_marginals(self.smoother, self._marginals, self._scanned)

    # -- the estimate ---------------------------------------------------------------------------

    def batch_initial(self) -> gtsam.Values:
        """Where a batch solve of ``graph`` (``keep_graph``) starts, as a batch calibration
        would: every parameter vector at the starting model, the auxiliary unknowns at the
        formulation's starting values."""
        if not self.keep_graph:
            raise RuntimeError("batch_initial needs keep_graph=True")
        initial = gtsam.Values()
        for cycle in range(self.cycle + 1):
            initial.insert(params_key(cycle), self.start[self.model.index])
        for name, aux in self.state.aux.items():
            initial.insert(self.keys[name], aux.to_gtsam())
        return initial

    def current_params(self) -> np.ndarray:
        return self.model.full(self._p)

    def aux_estimate(self) -> State | None:
        """The auxiliary unknowns at their current estimate (None before the start)."""
        if self.state is None or self.smoother is None or not self.n_images:
            return self.state
        estimate = self.smoother.calculateEstimate()
        aux = {name: a.from_values(estimate, self.keys[name]) for name, a in self.state.aux.items()}
        return State(self.current_params(), aux)

    def window_q(self) -> np.ndarray:
        rows = sorted(self.model.q)[-self.settings.window_images :]
        return np.array([self.model.q[r] for r in rows]).reshape(-1, self.robot.n_joints)

    @property
    def sigmas(self) -> np.ndarray:
        return self._sigmas.copy()

    @property
    def covariance(self) -> np.ndarray:
        return self._covariance.copy()


def _append(tables: dict, name: str, row: dict[str, str], values: np.ndarray) -> None:
    """Add one row (its ids, its values) to a reading's table ``name``."""
    ids, stack = tables.get(name, ({k: [] for k in row}, np.zeros((0, len(values)))))
    ids = {k: [*ids.get(k, []), row[k]] for k in row}
    tables[name] = (ids, np.vstack([stack, np.asarray(values, dtype=float)[None, :]]))


def _solved(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> gtsam.Values:
    """``graph`` minimised from ``values`` by Levenberg-Marquardt, as the batch calibration's
    stages (fgcal.calibration.solve.optimise)."""
    params = gtsam.LevenbergMarquardtParams()
    params.setLinearSolverType("MULTIFRONTAL_QR")
    params.setDiagonalDamping(True)
    params.setMaxIterations(100)
    params.setRelativeErrorTol(RELATIVE_TOLERANCE)
    params.setAbsoluteErrorTol(ABSOLUTE_TOLERANCE)
    return gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()


def _subset(values: gtsam.Values, keys) -> gtsam.Values:
    out = gtsam.Values()
    for key in keys:
        copy_value(out, values, key)
    return out
