"""The calibration problem and the formulation protocol.

A :class:`Problem` is constant once built: the dataset, the robot with the chosen model, the
split into fitting and held-out configurations, the candidate parameters, and the fitting
observations of its :class:`Formulation`. What varies between calibrations of different
setups (a camera on the flange, a laser tracker, a ballbar, ...) is the formulation: one module
each in fgcal.calibration.formulations, each implementing the protocol below, and the
pipeline (fgcal.calibration.run) calls only the protocol.

A formulation knows:

- its observations, typed, built from a dataset and a subset of its configurations;
- its auxiliary unknowns and their starting values (:meth:`Formulation.initial_state`);
- its measurement sets, the GTSAM factors (:meth:`Formulation.measurement_sets`), written
  once and used for the fit, for the held-out score and for the score's prediction;
- how its held-out score is read off the measurement set, and what a simulation's truth
  says about its unknowns (:meth:`Formulation.true_state`, :meth:`Formulation.scored`);
- the gauge of its score, and the likely causes of a first stage that cannot fit;
- what fgcal plan models of its measurements (:meth:`Formulation.planning`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import ClassVar

import gtsam
import numpy as np

from ..core.errors import InputError
from ..data.dataset import Dataset, Table
from ..data.truth import Truth
from ..factors import MeasurementSet, RobustLoss
from ..model.parameters import COMPLIANCE_KINDS, MASS_KIND, MOTION_KINDS, default_compliant_joints, split_name
from ..model.robot import Robot
from .batch import BatchKinematics
from .goodness import chi_median
from .plan_model import Planning
from .priors import Priors
from .settings import MeasurementSettings
from .state import State

# -- observations -------------------------------------------------------------------------


@dataclass(frozen=True)
class Observations:
    """Measurements of a formulation at a set of configurations: the configurations' ids and
    joint angles (what the measurement sets' kinematics are evaluated at), and per robust unit
    the index of its configuration and the name of what it measures (for rejection records).
    Formulations add their own arrays."""

    config_ids: np.ndarray  # (N,) ids of the configurations the observations index
    q: np.ndarray  # (N, n) rad

    @property
    def n_residuals(self) -> int:
        raise NotImplementedError

    def unit_label(self, unit: int) -> tuple[str, str]:
        """(configuration id, name of the point, target or pivot) of a robust unit."""
        raise NotImplementedError

    def select(self, keep: np.ndarray) -> Observations:
        """The observations whose robust units ``keep`` (a boolean mask) marks."""
        raise NotImplementedError


def take(observations: Observations, keep: np.ndarray, names: Sequence[str]) -> dict:
    """``{name: array[keep]}`` for per-unit arrays of ``observations``: a helper of select."""
    return {name: getattr(observations, name)[keep] for name in names}


@dataclass(frozen=True)
class Rejection:
    """A measurement removed as a gross error (``held_out``: flagged among the held-out ones
    and left out of their score); its size in sigmas and in the measurement's unit."""

    config: str
    kind: str  # the measurement table: tracker_points, pixels, camera_points, ...
    name: str  # what it measures: a point, a target, a pivot
    size_sigma: float
    size: float
    unit: str  # m or px
    held_out: bool = False
    name_key: str = "point"  # report.json's key of the name: point or target

    def as_dict(self) -> dict:
        out = {"config": self.config, "kind": self.kind, self.name_key: self.name, "size_sigma": self.size_sigma}
        out[f"size_{self.unit}"] = self.size
        if self.held_out:
            out["held_out"] = True
        return out


@dataclass(frozen=True)
class Detection:
    """What marker detection found in a dataset's images (pixels_from: images)."""

    images: int
    corners: int
    rejected_by_gate: int
    skipped: tuple[tuple[str, str], ...]  # (configuration id, reason)

    def as_dict(self) -> dict:
        return {
            "images": self.images,
            "skipped": len(self.skipped),
            "corners": self.corners,
            "rejected_by_gate": self.rejected_by_gate,
        }


# -- the problem ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Problem:
    """One calibration problem; constant: outlier rejection builds a new one (``with_fit``)."""

    formulation: Formulation
    settings: MeasurementSettings
    dataset: Dataset
    robot: Robot  # the dataset's robot with the config's model
    fit: np.ndarray  # indices into dataset configurations
    test: np.ndarray
    candidates: tuple[str, ...]
    observations: Observations  # of the fitting configurations
    priors: Priors  # prior sigmas around nominal: stated ones and fgcal's soft bounds
    max_iterations: int  # of the optimiser, per stage
    rejected: tuple[Rejection, ...] = ()
    detection: Detection | None = None
    # Separate validation sets: (directory, indices of their configurations in the dataset).
    validation_sets: tuple[tuple[str, np.ndarray], ...] = ()

    @property
    def frame(self) -> str | tuple[str, ...]:
        """What the kinematics give the measurements: a frame (flange, tool) or several tips of
        a tree (BatchKinematics: then frame-major)."""
        return self.formulation.frames(self)

    def scored_frame(self, state: State) -> str:
        """The frame of the first scored point (what a report's tool point is in, and a
        compensation drives)."""
        frames = self.frame
        if isinstance(frames, str):
            return frames
        tips = self.formulation.scored(self, state).tips
        return frames[0 if tips is None else int(tips[0])]

    @property
    def n_residuals(self) -> int:
        return self.observations.n_residuals

    def with_fit(self, observations: Observations, rejected: Sequence[Rejection]) -> Problem:
        return replace(self, observations=observations, rejected=(*self.rejected, *rejected))

    def kinematics(self, state: State, released: Sequence[str], observations: Observations) -> BatchKinematics:
        """The formulation's frame at the observations' configurations (reached as the
        dataset's motion history says) as a function of the ``released`` parameters, the
        others at the state's values."""
        motion = self.dataset.motion_of(observations.config_ids)
        return BatchKinematics(self.robot, state.params, released, observations.q, self.frame, motion)


@dataclass(frozen=True)
class Keys:
    """GTSAM keys of a graph's variables: the parameter vector (None when nothing is released)
    and each auxiliary unknown by name."""

    params: int | None
    aux: dict[str, int]

    def __getitem__(self, name: str) -> int:
        return self.aux[name]

    def __contains__(self, name: str) -> bool:
        return name in self.aux


P_KEY = gtsam.symbol("p", 0)


def keys_of(state: State, released: bool) -> Keys:
    """Keys for a state's unknowns: P, then the auxiliary unknowns in their order."""
    return Keys(P_KEY if released else None, {name: gtsam.symbol("x", i) for i, name in enumerate(state.aux)})


def values_of(state: State, keys: Keys, released_values: np.ndarray | None = None) -> gtsam.Values:
    """A state's unknowns as GTSAM values at ``keys`` (P at ``released_values``)."""
    values = gtsam.Values()
    if keys.params is not None:
        values.insert(keys.params, np.asarray(released_values, dtype=float))
    for name, aux in state.aux.items():
        values.insert(keys[name], aux.to_gtsam())
    return values


def key_columns(state: State, keys: Keys, n_released: int) -> tuple[dict[int, tuple[int, int]], int]:
    """Per key, its columns (start, width) in a dense Jacobian on [P, the auxiliary unknowns in
    the state's order], and the Jacobian's width."""
    columns, width = {}, 0
    if keys.params is not None:
        columns[keys.params], width = (0, n_released), n_released
    for name, aux in state.aux.items():
        columns[keys[name]] = (width, aux.dim)
        width += aux.dim
    return columns, width


def dense_jacobian(measurements: MeasurementSet, blocks: Sequence[np.ndarray], columns: dict, width: int) -> np.ndarray:
    """A measurement set's Jacobian blocks (one per variable) laid on ``columns`` (key_columns)."""
    J = np.zeros((measurements.n_rows, width))
    for (key, _, _), block in zip(measurements.variables, blocks, strict=True):
        a, d = columns[key]
        J[:, a : a + d] = block
    return J


def read_state(state: State, keys: Keys, values: gtsam.Values, kinematics: BatchKinematics) -> State:
    """The state whose released parameters and auxiliary unknowns are those of ``values``."""
    params = kinematics.full(values.atVector(keys.params)) if keys.params is not None else state.params.copy()
    aux = {name: a.from_values(values, keys[name]) for name, a in state.aux.items()}
    return State(params, aux)


@dataclass(frozen=True)
class Scored:
    """What a score against a simulation's truth measures: points s_t fixed in the robot's
    frame (the formulation's), carried to the score's frame, ``p = L X(q) s_t``.

    ``instrument`` is L (4x4; None: the score is in W); ``points_from`` and ``instrument_from``
    name the auxiliary unknowns they are (a ``points`` unknown, or a ``pose3`` one whose origin
    is the point), for the score's prediction; None: constants. ``extra`` are further points
    scored on their own (name -> point in the frame)."""

    points: np.ndarray  # (k, 3)
    instrument: np.ndarray | None = None
    points_from: str | None = None
    instrument_from: str | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    tips: np.ndarray | None = None  # (k,) per point, its frame among the problem's frames (None: the one)


@dataclass(frozen=True)
class Prediction:
    """Predicted RMS (m) of a held-out score: from the estimate's uncertainty (parameters and
    auxiliary unknowns) and, against measurements, their noise."""

    rms: float
    parameters_rms: float
    noise_rms: float
    variance_factor: float
    # Fixed parameters the score depends on beyond what the released unknowns take
    # (fgcal.calibration.blind_spots.BlindSpot): the prediction assumes them at their values.
    assumes: tuple = ()

    def as_dict(self) -> dict:
        return {
            "rms": self.rms,
            "parameters_rms": self.parameters_rms,
            "noise_rms": self.noise_rms,
            "variance_factor": self.variance_factor,
            "assumes_at_their_values": [spot.as_dict() for spot in self.assumes],
        }


@dataclass(frozen=True)
class HeldOut:
    """Errors of a held-out score (m, px or rad as the name says) and the configuration
    (index into the scored observations' config_ids) of each."""

    errors: np.ndarray  # (K,) norms or (K, 3) vectors
    configs: np.ndarray  # (K,)


@dataclass(frozen=True)
class Part:
    """One measurement set of a calibration (fgcal.calibration.formulations.sets): its name
    (None: a config's one formulation), its formulation, the problem as that formulation sees it
    (its settings and observations), its use (fit or validation) and its index (the ``part`` tag of
    its measurement sets)."""

    name: str | None
    formulation: Formulation
    problem: Problem
    use: str = "fit"
    index: int = 0

    def sets_of(self, measurements: Sequence[MeasurementSet]) -> list[MeasurementSet]:
        """This part's among a graph's measurement sets (the first is its main set)."""
        return [m for m in measurements if getattr(m, "part", 0) == self.index]


# -- the formulation protocol -------------------------------------------------------------------


class Formulation(ABC):
    """How one measurement setup enters the calibration (see the module docstring)."""

    name: ClassVar[str]
    frame: ClassVar[str]  # what the kinematics give the measurements: flange or tool
    unit: ClassVar[str] = "m"  # of the residuals (m or px), in stage reports
    kind: ClassVar[str]  # the measurement table, and its robust.* entry
    # The formulation-specific config settings it reads (noise.<key>, pairs, intrinsics, ...;
    # robust.<kind> always): a config stating another has it said, not silently ignored.
    settings_read: ClassVar[tuple[str, ...]] = ()
    rejection_name: ClassVar[str] = "point"  # report.json's key of a rejected measurement's name
    score: ClassVar[str] = "tool_point"  # the held-out score against measurements
    score_width: ClassVar[int] = 3  # rows of the main set's residual per scored measurement
    score_rows: ClassVar[slice] = slice(None)  # of those, the rows the score measures
    score_vectors: ClassVar[bool] = True  # the score's errors are 3-vectors (RMS per axis too)
    likely_causes: ClassVar[str]
    # What measures (fgcal.simulation.cell.INSTRUMENTS): "camera" (on the flange, seeing the
    # cell's calibration objects), "tracker" (reflectors on the flange), "tracker_probe" (a 6D
    # probe), "touch", "ballbar", "static_camera". fgcal simulate suggests, for a cell's first
    # instrument, the first registered formulation that reads it; fgcal plan, the first planned
    # one (:meth:`planning`).
    instrument: ClassVar[str]
    # Why online recalibration (fgcal.online) cannot take it one configuration at a time; None: it can.
    not_incremental: ClassVar[str | None] = None
    # The measurement set whose held-out score the headline gives (a config's sets:); None: the one.
    headline_name: ClassVar[str | None] = None

    # -- what the setup measures --------------------------------------------------------

    @abstractmethod
    def sigma(self, settings: MeasurementSettings) -> float:
        """Declared noise of one residual row of the main set, in ``unit``."""

    @abstractmethod
    def fit_observations(self, dataset: Dataset, settings: MeasurementSettings, fit: np.ndarray) -> Observations:
        """The observations of the fitting configurations; InputError when they cannot
        calibrate (missing table, too few)."""

    def online_observations(
        self, dataset: Dataset, settings: MeasurementSettings, subset: np.ndarray, like: Observations
    ) -> Observations:
        """The observations of ``subset`` (one configuration, or a work cycle's) for online
        recalibration (fgcal.online), labelled as ``like`` (the observations the online
        calibration started from: their names index its auxiliary unknowns), without the check
        that they alone could calibrate; InputError for what ``like`` does not know. The
        default, :meth:`fit_observations`, suits a formulation whose observations carry no
        labels of auxiliary unknowns and no such check."""
        return self.fit_observations(dataset, settings, subset)

    def online_once(self, problem: Problem) -> Observations | None:
        """The observations no configuration carries (a drawing's known distances between
        touched points), which online recalibration folds in once, when it starts (``problem``:
        the start's measurements); None (the default): none. Their measurement sets must not
        need a configuration."""
        return None

    @abstractmethod
    def test_observations(self, problem: Problem, state: State) -> tuple[Observations | None, list[Rejection]]:
        """The held-out observations (None: nothing held out) and the held-out measurements
        flagged as gross errors at ``state`` (left out of the score)."""

    @abstractmethod
    def initial_state(self, problem: Problem) -> State:
        """Starting values: the nominal parameters (or a start from the data where the
        formulation has one) and the auxiliary unknowns, from the measurements alone."""

    @abstractmethod
    def measurement_sets(
        self,
        problem: Problem,
        observations: Observations,
        kinematics: BatchKinematics,
        keys: Keys,
        state: State,
        robust: RobustLoss | None,
    ) -> list[MeasurementSet]:
        """The measurement sets of ``observations`` on the variables ``keys`` (the first is
        the main set: its rows are scored and its robust loss is ``robust``)."""

    def gauge(self, settings: MeasurementSettings) -> str:
        """What a score against the truth removes first: none, translation or rigid."""
        return "none"

    def frames(self, problem: Problem) -> str | tuple[str, ...]:
        """The frame the kinematics give the measurements, or the tips of a tree they are on: a
        flange formulation's measured target (probe, ball, board) is on the dataset's ``tip``."""
        tip = problem.dataset.tip
        if tip is not None and self.frame == "flange":
            return tip
        if tip is not None and tip != problem.robot.flange_name:
            raise InputError(
                problem.dataset.path / "dataset.yaml", "tip",
                f"the {self.name} formulation's camera is the flange's tool: a tree's other tips carry targets "
                "(tracker, poses, touch, ballbar, static camera), not the camera",
            )  # fmt: skip
        return self.frame

    def unit_tips(self, problem: Problem, observations: Observations) -> np.ndarray | None:
        """Per robust unit of ``observations``, the tree's tip it measures (None: all one frame)."""
        return None

    def planning(self, settings: MeasurementSettings) -> Planning | None:
        """What fgcal plan models of these measurements (fgcal.calibration.plan_model): how its
        candidates are drawn, their whitened rows, the auxiliary unknowns' labels and prior
        sigmas, the scored point and the gauge. None: not planned yet (whatever the settings)."""
        return None

    def parts(self, problem: Problem) -> list[Part]:
        """The measurement sets of the calibration (a config's ``sets:``); one formulation is one."""
        return [Part(None, self, problem)]

    def robust_loss(
        self, problem: Problem, measurements: list[MeasurementSet], values: gtsam.Values
    ) -> tuple[RobustLoss, float] | None:
        """The robust loss :meth:`measurement_sets` takes, with its threshold in units of the
        main set's robust scale at ``values`` (robust_scale), and that scale; None: least squares."""
        robust = problem.settings.robust.get(self.kind)
        if robust is None:
            return None
        kind, threshold = robust
        scale = robust_scale(measurements[:1], values)
        return RobustLoss(kind, threshold * scale), scale

    # -- held-out scores and their prediction --------------------------------------------

    def held_out_errors(self, problem: Problem, observations: Observations, state: State) -> dict[str, HeldOut]:
        """Errors of the held-out measurements at ``state``, read off the main measurement set:
        per scored measurement, the score rows' norm (or vector) times metric_scale."""
        main, inputs = main_set(problem, observations, state)
        residual = main.compute(inputs, False).residual.reshape(-1, self.score_width)[:, self.score_rows]
        scale = self.metric_scale(problem, main, inputs, state)
        errors = residual * scale[:, None] if self.score_vectors else np.linalg.norm(residual, axis=1) * scale
        out = {self.score: HeldOut(errors, self.score_configs(main))}
        out.update(self.extra_errors(problem, main, inputs, state))
        return out

    def predicted_held_out(
        self, problem: Problem, observations: Observations, state: State, covariance: JointCovariance, factor: float
    ) -> Prediction | None:
        """Predicted RMS of :meth:`held_out_errors`' main score (held_out_variances)."""
        parameters, noise = self.held_out_variances(problem, observations, state, covariance, factor)
        return prediction(parameters, noise, factor)

    def held_out_variances(
        self, problem: Problem, observations: Observations, state: State, covariance: JointCovariance, factor: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per scored measurement, the variance its error takes from the estimate (the main
        set's Jacobian, score rows, through the joint covariance of the set's variables) and
        from the noise of the score rows (scaled by the fit's variance factor ``factor``)."""
        main, inputs = main_set(problem, observations, state, released=covariance.released)
        evaluation = main.compute(inputs, True)
        width = sum(dim for _, _, dim in main.variables)
        J = np.hstack(evaluation.blocks).reshape(-1, self.score_width, width)[:, self.score_rows]
        scale = self.metric_scale(problem, main, inputs, state)
        parameters = through(J, covariance.block_of_keys(main, state)) * scale**2
        rows_sigma = main.sigma.reshape(-1, self.score_width)[:, self.score_rows]
        return parameters, factor * np.sum(rows_sigma**2, axis=1) * scale**2

    def metric_scale(self, problem: Problem, main: MeasurementSet, inputs: list, state: State) -> np.ndarray:
        """Per scored measurement, what turns its residual into metres (pixels: depth over
        focal length); ones for metric measurements."""
        return np.ones(main.n_rows // self.score_width)

    def score_configs(self, main: MeasurementSet) -> np.ndarray:
        """Configuration index of each scored measurement of the main set."""
        return np.asarray(main.configs)

    def extra_errors(self, problem: Problem, main: MeasurementSet, inputs: list, state: State) -> dict[str, HeldOut]:
        """Further held-out scores (reprojection in px, orientation in rad)."""
        return {}

    # -- against a simulation's truth -----------------------------------------------------

    @abstractmethod
    def scored(self, problem: Problem, state: State) -> Scored:
        """The points a score against the truth measures, with the state's values."""

    @abstractmethod
    def true_state(self, problem: Problem, truth: Truth) -> tuple[Robot, State]:
        """The simulated true robot (its full model) and the truth's values of the auxiliary
        unknowns this formulation estimates (where the score needs them)."""

    # -- outliers ----------------------------------------------------------------------------

    def reject(
        self, problem: Problem, sets: list[MeasurementSet], values: gtsam.Values, scale: float
    ) -> tuple[Observations, list[Rejection]] | None:
        """Gross errors among the fitting observations after the last stage, when the config
        asks for a robust loss on them: a robust unit whose whitened residual RMS exceeds
        REJECT_SIGMA times the residuals' robust ``scale``. None when nothing is removed, or
        when more than MAX_REJECTED_FRACTION would go (a model problem, not bad data)."""
        if problem.settings.robust.get(self.kind) is None:
            return None
        main = sets[0]
        rms = main.unit_rms(values)
        outlier = rms > REJECT_SIGMA * scale
        if not outlier.any() or outlier.sum() > MAX_REJECTED_FRACTION * len(outlier):
            return None
        sigma = float(main.sigma[-1])  # the declared sigma the set was whitened by (a pose: its position's)
        records = []
        for unit in np.flatnonzero(outlier):
            config, name = problem.observations.unit_label(int(unit))
            records.append(self.rejection(config, name, float(rms[unit]), float(rms[unit]) * sigma))
        return problem.observations.select(~outlier), records

    def rejection(self, config: str, name: str, sigmas: float, size: float, held_out: bool = False) -> Rejection:
        return Rejection(config, self.kind, name, sigmas, size, self.unit, held_out, self.rejection_name)

    # -- what else a calibration hands on ---------------------------------------------------

    def details(self, problem: Problem) -> dict:
        """What else report.json says about this formulation's data (SI)."""
        return {}

    def test_point_modes(self, problem: Problem, observations: Observations) -> dict[str, str]:
        """How each test point (a point only the held-out configurations measure) is scored:
        ``declared`` (at its drawing's position) or ``leave-one-out``."""
        return {}

    def tool_frame(self, state: State) -> np.ndarray | None:
        """The tool the calibration estimated on the flange, T_n_tool (a touch probe, a ball, a 6D
        probe's frame), which the calibrated robot file carries as its tool; None: the robot's
        own tool (the camera mounting is among the parameters, tool.*)."""
        return None

    def default_tool_point(self, problem: Problem, state: State) -> np.ndarray:
        """The point (in the formulation's frame) a report scores and a compensation drives."""
        return self.scored(problem, state).points[0].copy()


REJECT_SIGMA = 5.0
MAX_REJECTED_FRACTION = 0.1


# -- shared by the formulations and the pipeline ------------------------------------------------


class JointCovariance:
    """Covariance of the released parameters and the auxiliary unknowns together (SI, tangent
    spaces for poses), by name (``P`` for the parameter vector)."""

    def __init__(self, offsets: dict[str, tuple[int, int]], matrix: np.ndarray, released: Sequence[str]) -> None:
        self.offsets = offsets
        self.matrix = matrix
        self.released = list(released)

    def block(self, names: Sequence[str]) -> np.ndarray:
        index = np.concatenate([np.arange(a, a + d) for a, d in (self.offsets[n] for n in names)])
        return self.matrix[np.ix_(index, index)]

    def sigmas(self, name: str) -> np.ndarray | None:
        if name not in self.offsets:
            return None
        return np.sqrt(np.clip(np.diag(self.block([name])), 0.0, None))

    def scaled(self, factor: float) -> JointCovariance:
        return JointCovariance(self.offsets, self.matrix * factor, self.released)

    def block_of_keys(self, measurements: MeasurementSet, state: State) -> np.ndarray:
        """The block of a measurement set's variables, in its order (built by main_set)."""
        keys = keys_of(state, bool(self.released))
        by_key = {keys.params: "P", **{key: name for name, key in keys.aux.items()}}
        return self.block([by_key[key] for key, _, _ in measurements.variables])


def main_set(
    problem: Problem, observations: Observations, state: State, released: Sequence[str] = ()
) -> tuple[MeasurementSet, list]:
    """The main measurement set of ``observations`` at ``state`` (P over ``released``, for
    Jacobians) and its inputs."""
    kinematics = problem.kinematics(state, released, observations)
    keys = keys_of(state, bool(released))
    sets = problem.formulation.measurement_sets(problem, observations, kinematics, keys, state, None)
    values = values_of(state, keys, kinematics.base[kinematics.index])
    return sets[0], sets[0].read(values)


def robust_scale(measurements: list[MeasurementSet], values: gtsam.Values) -> float:
    """Robust scale of the whitened residuals, at least 1: the median norm of the robust
    units over the median of a chi distribution of their dimension (1.4826 MAD for 1-D).

    A robust loss's threshold is in units of this scale: while the model is still far off,
    residuals are many sigmas and a fixed 3-sigma threshold would treat them all as
    outliers; once the model fits, the scale returns to 1 and the threshold to k sigma.
    """
    scaled = [m.unit_norms(values) / chi_median(m.unit_dims) for m in measurements]
    if not scaled:
        return 1.0
    return max(1.0, float(np.median(np.concatenate(scaled))))


def through(J: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """Trace of J C J^T per item: J (n, k, m), C (m, m)."""
    return np.einsum("oij,jk,oik->o", J, covariance, J)


def prediction(parameters: np.ndarray, noise: np.ndarray, factor: float) -> Prediction | None:
    """A Prediction from per-item variances from the estimate and from the noise."""
    if not len(parameters):
        return None
    p, n = float(np.mean(parameters)), float(np.mean(noise))
    return Prediction(float(np.sqrt(p + n)), float(np.sqrt(p)), float(np.sqrt(n)), factor)


def rows_of(dataset: Dataset, table: Table, key: str, subset: np.ndarray) -> Iterator[tuple[int, str, np.ndarray]]:
    """(index in ``subset``, id in column ``key``, values) of each row of ``table`` that belongs
    to a configuration of ``subset`` (indices into the dataset's configurations)."""
    config_pos = {c: i for i, c in enumerate(dataset.configs)}
    subset_pos = {int(c): i for i, c in enumerate(subset)}
    for cid, name, values in zip(table.ids["config"], table.ids[key], table.values, strict=True):
        index = subset_pos.get(config_pos[cid])
        if index is not None:
            yield index, str(name), values


def refuse_unstarted(seen: Iterable[str], known: Sequence[str], path: Path, column: str, what: str, lost: str) -> None:
    """An online measurement naming a ``what`` (a reflector, a point) the online calibration did
    not start with is refused: its unknown (``lost``) is not estimated."""
    unknown = sorted(set(seen) - set(known))
    if unknown:
        raise InputError(path, column, f"{what} {unknown[0]!r} is not one the online calibration started with "
                         f"({', '.join(known)}): {lost}")  # fmt: skip


def measured_table(dataset: Dataset, table: str, formulation: str) -> Table:
    """The dataset's table that the formulation needs, or an error naming it."""
    if table not in dataset.tables:
        raise InputError(dataset.path / "dataset.yaml", "measured", f"the {formulation} formulation needs {table}")
    return dataset.tables[table]


def subset_of(dataset: Dataset, subset: np.ndarray) -> dict:
    """The configuration ids and joint angles of ``subset``: the base of its Observations."""
    subset = np.asarray(subset, dtype=int)
    return {"config_ids": np.asarray(dataset.configs, dtype=object)[subset], "q": dataset.q[subset]}


def source_of(settings: MeasurementSettings) -> Path:
    return settings.source


# -- candidates and the split ---------------------------------------------------------------


def compliant_joints(robot: Robot, joints: tuple[int, ...] | None) -> tuple[int, ...]:
    """The config's compliant joints, or by default: on a serial arm the seed's 1-3 that it has;
    on a tree (tips besides the flange) every revolute joint that carries a mass, identifiability
    deciding which the data determine (the seed's three left a 20-joint tree with its torso's
    compliances only, and twice the error the data support)."""
    if joints is not None:
        return joints
    if robot.tips:
        return loaded_joints(robot)
    return default_compliant_joints(robot.n_links)


def loaded_joints(robot: Robot) -> tuple[int, ...]:
    """The revolute joints (1-based) whose motion carries a body with mass (a link's or the
    payload): their torque bends them."""
    model = robot.compiled
    carried_kg = model.carried.astype(float) @ model.masses
    prismatic = np.asarray(robot.prismatic, dtype=bool)
    return tuple(int(i) + 1 for i in range(len(carried_kg)) if carried_kg[i] > 0
                 and not (i < len(prismatic) and prismatic[i]))  # fmt: skip


def candidate_parameters(robot: Robot, model: str, joints: tuple[int, ...] | None) -> list[str]:
    """Parameters the model could estimate: the model's kinds, compliances of the compliant
    joints, the motion history's terms of every joint (model DH,s,e,h), base and tool.
    Identifiability analysis decides which the data determine."""
    terms = model.split(",")
    kinds = {"theta", "d", "a", "alpha", "tx", "ty", "tz", "rx", "ry", "rz"}
    if "s" in terms:
        kinds |= {"sx", "sy"}
    if "h" in terms:
        kinds |= set(MOTION_KINDS)
    if "e" in terms:
        kinds.add(MASS_KIND)  # mass scales: only the compliances' moments see them
    compliant = compliant_joints(robot, joints)
    names = []
    for name in robot.parameter_names:
        kind, owner = split_name(name)
        if (
            owner in ("base", "tool")
            or kind in kinds
            or ("e" in terms and kind in COMPLIANCE_KINDS and owner in compliant)
        ):
            names.append(name)
    return names


def fold_split(n: int, folds: int, fold: int, order: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Fitting and held-out indices of fold ``fold`` (1-based) of ``folds``: consecutive parts of
    a seeded permutation (``order`` random) or of the run's order (ordered)."""
    sequence = np.arange(n) if order == "ordered" else np.random.default_rng(seed).permutation(n)
    parts = np.array_split(sequence, folds)
    test = parts[fold - 1]
    return np.sort(np.concatenate([p for k, p in enumerate(parts) if k != fold - 1])), np.sort(test)


def split(n: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Seeded random split of n configurations into fitting and held-out indices."""
    order = np.random.default_rng(seed).permutation(n)
    n_test = round(holdout * n)
    return np.sort(order[n_test:]), np.sort(order[:n_test])
