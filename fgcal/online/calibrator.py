"""``OnlineCalibrator``: fold each new image into the calibration with iSAM2.

Graph: the parameter vector P (every candidate of the model, except the base, which defines
W) under priors by kind; the fixture pose O (the calibration objects, unknown); per image a
camera pose variable tied to P by a KinematicFactor, and its ProjectionFactors. The priors make
every early state well posed, so the first images give an estimate dominated by the priors,
never an exception. iSAM2 uses QR and relinearises only when the estimate moves.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from ..camera import Camera, solve_pnp
from ..errors import InputError
from ..factors import KinematicFactor, ProjectionFactor, gaussian
from ..parameters import split_name
from ..robot import Robot
from .growing import GrowingKinematics

P_KEY = gtsam.symbol("p", 0)
OBJECT_KEY = gtsam.symbol("o", 0)

# Prior sigmas around the starting model, by kind (SI): what an earlier calibration or the
# manufacturer leaves open.
PRIOR_SIGMA = {"length": 5e-3, "angle": 5e-3, "compliance": 1e-6}


def pose_key(j: int) -> int:
    return gtsam.symbol("x", j)


@dataclass
class OnlineEstimate:
    """The current estimate after an image: parameters and marginal sigmas (SI)."""

    n_images: int
    params: dict[str, float]
    sigmas: dict[str, float]
    fixture_pose: np.ndarray
    update_s: float
    extra: dict = field(default_factory=dict)


class OnlineCalibrator:
    """Incremental calibration from camera images (projection formulation).

    ``robot`` carries the starting model (a calibrated robot file or the nominal model) with
    the camera as its tool; ``points_F`` the calibration points (drawings, fixture frame).
    """

    def __init__(
        self,
        robot: Robot,
        camera: Camera,
        points_F: dict[str, np.ndarray],
        pixel_sigma_px: float = 0.1,
        compliant_joints: tuple[int, ...] = (1, 2, 3),
        relinearize_fraction: float = 0.01,
        relinearize_skip: int = 1,
    ) -> None:
        self.robot = robot
        self.camera = camera
        self.points_F = points_F
        self.pixel_sigma = float(pixel_sigma_px)
        self.intrinsics = np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion])
        self.released = [n for n in robot.parameter_names if self._released(n, compliant_joints)]
        self.start = robot.parameter_vector()
        self.model = GrowingKinematics(robot, self.start, self.released, "tool")
        self.prior_sigmas = np.array([self._prior_sigma(n) for n in self.released])
        params = gtsam.ISAM2Params()
        params.setFactorization("QR")
        # Relinearise a variable when it has moved by a fraction of its prior sigma (per
        # component: P mixes rad, m and compliances of 1e-7), checked every few images:
        # relinearising P touches every kinematic factor.
        thresholds = gtsam.ISAM2ThresholdMap()
        thresholds.insert(("p", relinearize_fraction * self.prior_sigmas))
        thresholds.insert(("x", np.full(6, 1e-5)))
        thresholds.insert(("o", np.full(6, 1e-5)))
        params.setRelinearizeThreshold(thresholds)
        params.relinearizeSkip = relinearize_skip
        # Full back-substitution: the default wildfire threshold (1e-3) would leave P's small
        # components (compliances of 1e-7) unchanged.
        params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))
        self.isam = gtsam.ISAM2(params)
        self.n_images = 0
        self._p: np.ndarray | None = None
        self._fixture: np.ndarray | None = None

    @staticmethod
    def _released(name: str, compliant_joints: tuple[int, ...]) -> bool:
        kind, owner = split_name(name)
        if owner == "base":
            return False
        if kind in ("kx", "ky", "kz"):
            return owner in compliant_joints
        return True

    @staticmethod
    def _prior_sigma(name: str) -> float:
        kind, _ = split_name(name)
        if kind in ("kx", "ky", "kz"):
            return PRIOR_SIGMA["compliance"]
        return PRIOR_SIGMA["length"] if kind in ("d", "a", "tx", "ty", "tz") else PRIOR_SIGMA["angle"]

    def prior_factors(self) -> list:
        """The priors of the first update (also used by the batch comparison)."""
        return [gtsam.PriorFactorVector(P_KEY, self.start[self.model.index], gaussian(self.prior_sigmas))]

    def image_factors(self, j: int, observations: list[tuple[str, np.ndarray]]) -> list:
        sigmas = np.full(2, self.pixel_sigma)
        noise = gaussian(sigmas, ("cauchy", 3.0))
        factors = [KinematicFactor(P_KEY, pose_key(j), j, self.model, np.full(6, 1e-3 * self.pixel_sigma * 1e-2))]
        for name, uv in observations:
            factors.append(
                ProjectionFactor(
                    pose_key(j), OBJECT_KEY, self.points_F[name], uv, noise, sigmas, intrinsics=self.intrinsics
                )
            )
        return factors

    def add(self, q: np.ndarray, observations: list[tuple[str, np.ndarray]]) -> OnlineEstimate:
        """Fold one image (joint angles q in rad, [(point name, pixel)]) into the estimate."""
        started = time.perf_counter()
        q = self.robot.check_q(q)[0]
        known = [(n, np.asarray(uv, dtype=float)) for n, uv in observations if n in self.points_F]
        if len(known) != len(observations):
            unknown = next(n for n, _ in observations if n not in self.points_F)
            raise InputError(None, "observations", f"unknown calibration point {unknown!r}")
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        params = self.current_params()
        j = self.model.add(q)
        # The kinematic factor will evaluate this row at these parameters: compute it once.
        T_W_C = self.model.poses(params[self.model.index])[j]
        if self.n_images == 0:
            for factor in self.prior_factors():
                graph.add(factor)
            values.insert(P_KEY, params[self.model.index])
            values.insert(OBJECT_KEY, gtsam.Pose3(self._first_fixture_guess(T_W_C, known)))
        values.insert(pose_key(j), gtsam.Pose3(T_W_C))
        for factor in self.image_factors(j, known):
            graph.add(factor.factor)
        self.isam.update(graph, values)
        # Only P and the fixture pose are read back: the full estimate grows with the images.
        self._p = self.isam.calculateEstimateVector(P_KEY)
        self._fixture = self.isam.calculateEstimatePose3(OBJECT_KEY).matrix()
        self.n_images += 1
        return self.estimate(time.perf_counter() - started, with_sigmas=False)

    def _first_fixture_guess(self, T_W_C: np.ndarray, known: list) -> np.ndarray:
        if len(known) >= 4:
            T_C_F = solve_pnp(
                np.array([self.points_F[n] for n, _ in known]), np.array([uv for _, uv in known]), self.camera
            )
            if T_C_F is not None:
                return T_W_C @ T_C_F
        raise InputError(None, "observations", "the first image needs at least four points to place the objects")

    def current_params(self) -> np.ndarray:
        if self._p is None:
            return self.start.copy()
        return self.model.full(self._p)

    def estimate(self, update_s: float = 0.0, with_sigmas: bool = True) -> OnlineEstimate:
        params = self.current_params()
        sigmas = {}
        if with_sigmas:
            sigma = np.sqrt(np.clip(np.diag(self.isam.marginalCovariance(P_KEY)), 0.0, None))
            sigmas = dict(zip(self.released, sigma.tolist(), strict=True))
        return OnlineEstimate(
            self.n_images,
            self.robot.parameter_dict(params),
            sigmas,
            self._fixture,
            update_s,
        )
