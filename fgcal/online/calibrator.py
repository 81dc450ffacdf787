"""``OnlineCalibrator``: fold each new image into the calibration with iSAM2.

Graph, per work cycle c, a parameter vector ``p_c`` (the released parameters), tied to the
previous cycle's by a random walk ``p_c - p_{c-1} ~ N(0, k Q)`` (k cycles elapsed); the
fixture pose O (unknown, constant); per image one projection factor on ``(p_c, O)``
(fgcal.factors.Projections: the camera pose comes from the kinematics, no pose variable).
A prior on ``p_0`` around the starting model makes every early state well posed: the first
images give an estimate dominated by the prior, never an exception.

The solver is GTSAM's IncrementalFixedLagSmoother (iSAM2, QR). Images older than the window
are frozen: their factors, linearised at the current linearisation point, are replaced by
one QR-compressed linear factor on ``(p_c, O)`` (what marginalising a per-image pose would
leave), so memory and the cost of relinearising ``p_c`` stay bounded however long the run;
the smoother marginalises the parameter vectors of past cycles. Outliers are gated when an
image arrives (its points against the image's common offset from the prediction), so that
the graph is purely Gaussian: a robust loss would freeze down-weighted information into the
marginals. After each image a drift test (:mod:`.drift`) compares the estimate with the one a
few images earlier; an alarm lets the flagged parameters jump (their random-walk sigma is
the prior sigma) at the next image.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from ..core.console import warn
from ..core.errors import InputError
from ..factors import BehindCameraError, FactorError, Projections, RandomWalkFactor, gaussian
from ..model.camera import Camera, solve_pnp
from ..model.parameters import default_compliant_joints, unit_of
from ..model.robot import Robot
from .compression import merge_marginals, merged_factor
from .drift import Alarm, DriftTest
from .growing import GrowingKinematics, RowKinematics
from .released import candidates, structural_identifiability

OBJECT_KEY = gtsam.symbol("o", 0)


# The flange camera's default compliance prior (rad/(N m)): on the KR 125 seed cell (compliances
# 2e-7 to 7e-7) a wider one let the weakly seen compliances wander early (false alarms at images
# 16 and 29; 0.16 sigma from the batch solve with 1e-4); a light arm with a camera needs its own.
CAMERA_PRIOR_SIGMA_COMPLIANCE = 1e-6


def params_key(cycle: int) -> int:
    return gtsam.symbol("p", cycle)


@dataclass(frozen=True)
class OnlineSettings:
    """Settings of an online calibration (SI units; per-cycle sigmas of the random walk)."""

    pixel_sigma_px: float = 0.1
    prior_sigma_m: float = 5e-3
    prior_sigma_rad: float = 5e-3
    # rad/(N m); None: the estimator's default, wider than plausible compliances so as not to
    # pull them to zero (fgcal.online.protocol: PRIOR_SIGMA_COMPLIANCE, 1e-4; this camera
    # calibrator: CAMERA_PRIOR_SIGMA_COMPLIANCE, 1e-6; docs/online.md).
    prior_sigma_compliance: float | None = None
    drift_sigma_m: float = 1e-6  # per cycle
    drift_sigma_rad: float = 1e-6
    drift_sigma_compliance: float = 1e-10
    window_images: int = 20
    marginalise_every: int = 5  # images leave the window in blocks: fewer, larger reorderings
    alarm_lag_images: int = 5
    alarm_false_rate: float = 1e-3  # per image, over all parameters
    outlier_gate_px: float = 3.0
    # A formulation's measurement (fgcal.online.protocol) whose residual at the current estimate
    # exceeds this many of its predicted sigmas (noise and the estimate's uncertainty) is logged
    # and not folded in; None: no gate. On by default: one gross reading folded in ruined the
    # estimate for good (issue 41: a reflector 50 m off, d4 -574 m 60 measurements later).
    outlier_gate_sigma: float | None = 5.0
    # ``gate_run`` consecutive gated configurations are a change of the robot, not the
    # instrument erring: a drift alarm (a change point, every released parameter restarting from
    # its prior sigma) and they are folded in (docs/online.md).
    gate_run: int = 3
    # A geometric parameter (m, rad) is released by the formulations' calibrator
    # (fgcal.online.protocol, without a released list) only when the reference data determine
    # it: marginal sigma at their solution at most this fraction of the prior sigma (None: every
    # identifiable parameter, however weakly; docs/online.md).
    determined_fraction: float | None = 0.05
    # Measurements held back and folded in together before the first update (formulations
    # other than the camera's, fgcal.online.protocol): they start the auxiliary unknowns.
    start_measurements: int = 10
    compliant_joints: tuple[int, ...] | None = None  # None: the seed's 1-3 that the robot has
    # Relinearise p_c when it moved by this fraction of its prior sigma, a pose by this (rad, m).
    relinearize_fraction: float = 0.1
    relinearize_pose: float = 1e-4

    def by_kind(self, name: str, what: str) -> float:
        suffix = {"m": "m", "rad": "rad", "rad/(N m)": "compliance"}[unit_of(name)]
        return getattr(self, f"{what}_sigma_{suffix}")


@dataclass
class OnlineUpdate:
    """The estimate after an image: released parameters and their marginal sigmas (SI)."""

    n_images: int
    cycle: int
    params: dict[str, float]  # every parameter of the robot
    sigmas: dict[str, float]  # the released ones
    fixture_pose: np.ndarray | None  # T_W_F; None until an image has placed the objects
    alarms: list[Alarm]
    rejected_points: list[str]
    update_s: float
    extra: dict = field(default_factory=dict)


class OnlineCalibrator:
    """Incremental calibration from camera images (projection formulation).

    ``robot`` carries the starting model (a calibrated robot file or the nominal model) with
    the camera as its tool; ``points_F`` the calibration points (drawings, fixture frame).
    ``released`` defaults to the parameters that camera poses determine in general position
    (:mod:`.released`). With ``keep_graph`` every factor and initial value is also kept, for
    comparing with a batch solve (memory then grows with the images).
    """

    def __init__(
        self,
        robot: Robot,
        camera: Camera,
        points_F: dict[str, np.ndarray],
        settings: OnlineSettings | None = None,
        released: list[str] | None = None,
        keep_graph: bool = False,
    ) -> None:
        self.settings = settings or OnlineSettings()
        if self.settings.prior_sigma_compliance is None:
            self.settings = replace(self.settings, prior_sigma_compliance=CAMERA_PRIOR_SIGMA_COMPLIANCE)
        s = self.settings
        if s.marginalise_every < 1 or s.window_images < 2 * s.marginalise_every:
            raise InputError(
                None,
                "window_images",
                f"must be at least twice marginalise_every ({s.marginalise_every}), got {s.window_images}",
            )
        if robot.history:
            # An inbox's images carry no motion history: the terms cannot be applied here.
            warn(
                f"{robot.name} is calibrated with lost motion (model {robot.model}); online recalibration applies "
                "no motion-history offsets (its images carry no history) and fits model DH,s,e"
            )
            robot = robot.with_model("DH,s,e")
        self.robot = robot
        self.camera = camera
        self.points_F = {name: np.asarray(p, dtype=float) for name, p in points_F.items()}
        self.intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion])
        self.start = robot.parameter_vector()
        if released is None:
            joints = s.compliant_joints if s.compliant_joints is not None else default_compliant_joints(robot.n_joints)
            found = candidates(robot, joints)
            released = structural_identifiability(robot, self.start, found).identifiable
        if not released:
            raise InputError(None, "released", "no parameter to estimate")
        unknown = [n for n in released if n not in robot.parameter_names]
        if unknown:
            raise InputError(None, "released", f"unknown parameter {unknown[0]!r} for {robot.name}")
        self.released = list(released)
        self.model = GrowingKinematics(robot, self.start, self.released, "tool")
        self.prior_sigmas = np.array([s.by_kind(n, "prior") for n in self.released])
        self.drift_sigmas = np.array([s.by_kind(n, "drift") for n in self.released])
        self.drift = DriftTest(self.released, self.drift_sigmas**2, s.alarm_lag_images, s.alarm_false_rate)
        self.smoother = gtsam.IncrementalFixedLagSmoother(
            float(s.window_images // s.marginalise_every), self._isam_params()
        )
        self.n_images = 0
        self.cycle = 0  # index of the current parameter variable p_c
        self.drift_time = 0.0  # cycles elapsed, summed over the random-walk factors
        self._cycle_label: int | None = None
        self._jump: set[int] = set()
        self._p = self.start[self.model.index].copy()
        self._sigmas = self.prior_sigmas.copy()
        self._fixture: np.ndarray | None = None
        self._pending: list[tuple[np.ndarray, list, int | None]] = []
        self._scanned = 0  # factor slots of the smoother already looked at
        self._marginals: list[int] = []  # slots holding marginal factors
        self._image_slots: dict[int, int] = {}  # row -> smoother slot of its live image factor
        self.keep_graph = keep_graph
        self.graph = gtsam.NonlinearFactorGraph()
        self.initial = gtsam.Values()

    def _isam_params(self) -> gtsam.ISAM2Params:
        s = self.settings
        params = gtsam.ISAM2Params()
        params.setFactorization("QR")
        thresholds = gtsam.ISAM2ThresholdMap()
        thresholds.insert(("p", s.relinearize_fraction * self.prior_sigmas))
        thresholds.insert(("o", np.full(6, s.relinearize_pose)))
        params.setRelinearizeThreshold(thresholds)
        params.relinearizeSkip = 1
        # Full back-substitution: the default wildfire threshold (1e-3) would leave the
        # compliances (1e-7) unchanged.
        params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
        return params

    # -- one image ------------------------------------------------------------------------

    def add(self, q: np.ndarray, observations: list[tuple[str, np.ndarray]], cycle: int | None = None) -> OnlineUpdate:
        """Fold one image into the estimate: joint angles ``q`` (rad), observations
        ``[(point name, pixel (u, v))]`` and optionally the work-cycle number it was taken
        in (images of one cycle share a parameter vector).

        Until an image places the calibration objects (PnP needs four points), images are
        held back and the estimate is the prior; they are folded in, in order, with that
        image."""
        started = time.perf_counter()
        q = self.robot.check_q(q)[0]
        known = self._check_observations(observations)
        latest = next((c for _, _, c in reversed(self._pending) if c is not None), self._cycle_label)
        if cycle is not None and latest is not None and cycle < latest:
            raise InputError(None, "cycle", f"cycle {cycle} is before the current cycle {latest}")
        if self._fixture is None:
            fixture = self._place_fixture(q, known)
            if fixture is None:
                self._pending.append((q, known, cycle))
                return OnlineUpdate(
                    0,
                    0,
                    self.robot.parameter_dict(self.current_params()),
                    dict(zip(self.released, self.prior_sigmas.tolist(), strict=True)),
                    None,
                    [],
                    [],
                    time.perf_counter() - started,
                    {"pending_images": len(self._pending)},
                )
            self._fixture = fixture
            # The placing image first: its points determine the objects' pose in the graph.
            update = self._fold(q, known, cycle, started)
            pending, self._pending = self._pending, []
            for pending_q, pending_known, _ in pending:  # into the placing image's cycle
                update = self._fold(pending_q, pending_known, None, started)
            return update
        return self._fold(q, known, cycle, started)

    def _fold(self, q: np.ndarray, known: list, cycle: int | None, started: float) -> OnlineUpdate:
        new_cycle = self._starts_cycle(cycle)
        row = self.model.add(q, self.cycle + (1 if new_cycle else 0))
        # Checked and gated before anything changes: an image that cannot be folded in is an
        # input error that leaves the estimate as it was (and a replay skips it the same way).
        # Where iSAM2 will linearise the new factor, so that it reuses this evaluation: a new
        # parameter vector enters at the current estimate.
        if self.n_images == 0:
            p_lin, fixture_lin = self._p, gtsam.Pose3(self._fixture)
        else:
            linearization_point = self.smoother.getLinearizationPoint()
            p_lin = self._p if new_cycle else linearization_point.atVector(params_key(self.cycle))
            fixture_lin = linearization_point.atPose3(OBJECT_KEY)
        P = params_key(self.cycle + (1 if new_cycle else 0))
        try:
            measurements = self.image_measurements(P, row, known)
            kept, rejected = self._gate(measurements, known, p_lin, fixture_lin)
        except InputError:
            self.model.forget_row(row)
            raise
        if rejected and kept:
            measurements = self.image_measurements(P, row, kept)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        P = params_key(self.cycle)
        if self.n_images == 0:
            graph.add(gtsam.PriorFactorVector(P, self._p, gaussian(self.prior_sigmas)))
            values.insert(P, self._p)
            values.insert(OBJECT_KEY, gtsam.Pose3(self._fixture))
            self._cycle_label = cycle
        elif new_cycle:
            elapsed = max(1, cycle - self._cycle_label) if cycle is not None and self._cycle_label is not None else 1
            sigmas = self.drift_sigmas * np.sqrt(elapsed)
            jumped = sorted(self._jump)
            sigmas[jumped] = self.prior_sigmas[jumped]
            self.cycle += 1
            self.drift_time += elapsed
            P = params_key(self.cycle)
            graph.add(RandomWalkFactor(params_key(self.cycle - 1), P, sigmas).factor)
            values.insert(P, self._p)
            self._jump = set()
            if cycle is not None:
                self._cycle_label = cycle
        if kept:
            graph.add(measurements.factor().factor)
        frozen, removed = self._freeze(row)
        update = gtsam.NonlinearFactorGraph(graph)
        update.push_back(frozen)
        stamp = float(row // self.settings.marginalise_every)
        # New factors take the next slots, in order (ISAM2 does not reuse freed slots by default).
        first_slot = self.smoother.getFactors().size()
        self.smoother.update(update, values, {P: stamp, OBJECT_KEY: stamp}, removed)
        if kept:
            self._image_slots[row] = first_slot + graph.size() - 1
        self._merge_marginals()
        if not self.keep_graph:
            self.model.forget_before(min(self._image_slots, default=row))
        else:
            self.graph.push_back(graph)
            self.initial.insert(values)
        self._p = self.smoother.calculateEstimateVector(P)
        self._fixture = self.smoother.calculateEstimatePose3(OBJECT_KEY).matrix()
        covariance = self.smoother.marginalCovariance(P)
        self._sigmas = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        self._covariance = covariance
        self.n_images += 1
        alarms = self.drift.check(self.n_images - 1, self.drift_time, self._p, self._sigmas)
        if alarms:
            self._jump = {self.released.index(a.parameter) for a in alarms}
            self.drift.reset()
        return OnlineUpdate(
            self.n_images,
            self.cycle,
            self.robot.parameter_dict(self.current_params()),
            dict(zip(self.released, self._sigmas.tolist(), strict=True)),
            self._fixture.copy(),
            alarms,
            rejected,
            time.perf_counter() - started,
        )

    def _starts_cycle(self, cycle: int | None) -> bool:
        if self.n_images == 0:
            return False
        return bool(self._jump) or (cycle is not None and cycle != self._cycle_label)

    def _merge_marginals(self) -> None:
        """Merge the marginal factors of the images that left the window (compression.merge_marginals)."""
        self._marginals, self._scanned = merge_marginals(self.smoother, self._marginals, self._scanned)


    def image_measurements(self, P: int, row: int, observations: list[tuple[str, np.ndarray]]) -> Projections:
        """The image's projections on (p_c, O): one factor for all its points, which keeps its
        Jacobians (the gate and iSAM2's later updates linearise it at the same point)."""
        measurements = Projections(
            RowKinematics(self.model, row),
            P,
            OBJECT_KEY,
            np.zeros(len(observations), dtype=int),
            np.array([self.points_F[name] for name, _ in observations]),
            np.array([uv for _, uv in observations]),
            self.settings.pixel_sigma_px,
            intrinsics=self.intrinsics,
        )
        measurements.keep_jacobians = True
        return measurements

    def _freeze(self, row: int) -> tuple[gtsam.NonlinearFactorGraph, list[int]]:
        """Linear factors replacing the image factors that leave the window with this image
        (in blocks of ``marginalise_every``), and the slots to remove."""
        every = self.settings.marginalise_every
        cutoff = (row // every - self.settings.window_images // every) * every
        leaving = [r for r in self._image_slots if r < cutoff]
        out = gtsam.NonlinearFactorGraph()
        if not leaving:
            return out, []
        factors = self.smoother.getFactors()
        by_keys: dict[tuple[int, ...], list] = {}
        removed = []
        for r in leaving:
            slot = self._image_slots.pop(r)
            factor = factors.at(slot)
            if factor is None:  # marginalised with its cycle's parameter vector
                continue
            by_keys.setdefault(tuple(factor.keys()), []).append(factor)
            removed.append(slot)
        linearization_point = self.smoother.getLinearizationPoint()
        for keys, group in by_keys.items():
            out.add(merged_factor(keys, group, linearization_point))
        return out, removed

    def _check_observations(self, observations: list[tuple[str, np.ndarray]]) -> list[tuple[str, np.ndarray]]:
        known = []
        for name, uv in observations:
            if name not in self.points_F:
                raise InputError(None, "observations", f"unknown calibration point {name!r}")
            uv = np.asarray(uv, dtype=float)
            if uv.shape != (2,) or not np.isfinite(uv).all():
                raise InputError(None, f"observations.{name}", f"a pixel is two finite numbers, got {uv.tolist()}")
            known.append((name, uv))
        if not known:
            raise InputError(None, "observations", "an image needs at least one observed point")
        return known

    def _gate(
        self, measurements: Projections, known: list, p_lin: np.ndarray, fixture_lin: gtsam.Pose3
    ) -> tuple[list, list[str]]:
        """Reject points whose residual against the prediction differs from the image's
        median residual by more than the gate: a model error or drift moves all the points
        of an image together, a wrong detection moves one.

        The prediction is at the current estimate, to first order from the linearisation
        point (where iSAM2 linearises the new factor, so that evaluation is shared): early on
        the linearisation point lags the estimate by pixels that differ from point to point,
        which the gate would take for outliers. Every image is evaluated here, however few
        its points: one whose points fall behind the camera is an InputError, not a failure
        inside iSAM2."""
        try:
            evaluation = measurements.whitened([p_lin, fixture_lin], True, robust=False)
        except (BehindCameraError, FactorError) as error:
            raise InputError(None, "observations", f"cannot be folded in at the current estimate: {error}") from None
        if len(known) < 3:
            return known, []
        J_P, J_O = evaluation.blocks
        step = J_P @ (self._p - p_lin) + J_O @ fixture_lin.localCoordinates(gtsam.Pose3(self._fixture))
        residuals = ((evaluation.residual + step) * measurements.sigma).reshape(-1, 2)
        offset = np.linalg.norm(residuals - np.median(residuals, axis=0), axis=1)
        kept = [obs for obs, d in zip(known, offset, strict=True) if d <= self.settings.outlier_gate_px]
        rejected = [name for (name, _), d in zip(known, offset, strict=True) if d > self.settings.outlier_gate_px]
        return kept, rejected

    def _place_fixture(self, q: np.ndarray, known: list) -> np.ndarray | None:
        """T_W_F from one image by PnP and the current model, or None (fewer than four
        points, or PnP failed)."""
        if len(known) < 4:
            return None
        T_C_F = solve_pnp(
            np.array([self.points_F[n] for n, _ in known]), np.array([uv for _, uv in known]), self.camera
        )
        if T_C_F is None:
            return None
        T_W_C = self.robot.fk_tool(q[None, :], self.robot.parameter_dict(self.current_params()))[0]
        return T_W_C @ T_C_F

    # -- the service's measurements (fgcal.online.measurement) ----------------------------

    def check(self, measurement, source) -> None:
        """InputError for a measurement file this calibrator cannot take (before it is logged)."""
        if measurement.batch:
            raise InputError(source, "configurations", "a flange camera's images come one per file")
        if not measurement.pixels:
            raise InputError(source, "pixels", "a flange camera's image needs pixels")
        unknown = [n for n, _ in measurement.pixels if n not in self.points_F]
        if unknown:
            raise InputError(source, f"pixels.{unknown[0]}", "unknown calibration point")

    def fold(self, measurement) -> OnlineUpdate:
        """:meth:`add` of a measurement file's image (its other tables are not read)."""
        return self.add(measurement.q, list(measurement.pixels), measurement.cycle)

    def window_q(self) -> np.ndarray:
        """The configurations of the images in the window (rad)."""
        rows = sorted(self.model.q)[-self.settings.window_images :]
        return np.array([self.model.q[r] for r in rows]).reshape(-1, self.robot.n_joints)

    # -- the estimate ---------------------------------------------------------------------

    def batch_initial(self) -> gtsam.Values:
        """Where a batch solve of ``graph`` (``keep_graph``) starts, as a batch calibration
        would: every parameter vector at the starting model, the fixture pose as the first
        image placed it."""
        if not self.keep_graph:
            raise RuntimeError("batch_initial needs keep_graph=True")
        start = self.start[self.model.index]
        initial = gtsam.Values()
        for cycle in range(self.cycle + 1):
            initial.insert(params_key(cycle), start)
        initial.insert(OBJECT_KEY, self.initial.atPose3(OBJECT_KEY))
        return initial

    def current_params(self) -> np.ndarray:
        """Every parameter of the robot (SI), the released ones at their current estimate."""
        return self.model.full(self._p)

    @property
    def sigmas(self) -> np.ndarray:
        """Marginal sigmas of the released parameters (SI), in ``released`` order."""
        return self._sigmas.copy()

    @property
    def covariance(self) -> np.ndarray:
        """Marginal covariance of the released parameters (current cycle)."""
        return self._covariance.copy() if self.n_images else np.diag(self.prior_sigmas**2)

    @property
    def fixture_pose(self) -> np.ndarray | None:
        return None if self._fixture is None else self._fixture.copy()
