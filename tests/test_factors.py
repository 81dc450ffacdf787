"""Every factor type: linearised by GTSAM and compared with central differences; the checked
base turns malformed Jacobians into exceptions instead of crashes."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

import fgcal
from fgcal.calibration.batch import BatchKinematics
from fgcal.factors import (
    CheckedFactor,
    DistanceFactor,
    FactorError,
    KinematicFactor,
    ParameterBoundFactor,
    PointPairFactor,
    PoseFactor,
    ProjectionFactor,
    RandomWalkFactor,
    TrackerPointFactor,
    gaussian,
)

RNG = np.random.default_rng(7)


def _pose() -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.8, 3)), RNG.normal(0, 1.0, 3))


def _kinematic_case(values: gtsam.Values):
    robot = fgcal.load_robot("kuka_kr125_2").with_tool(np.eye(4), payload_mass=10.0, payload_com=[0, 0, 0.1])
    released = ["theta2", "d3", "alpha1", "sx2", "sy3", "kz2", "ky3", "tool.tx", "tool.rz"]
    model = BatchKinematics(
        robot, robot.parameter_vector({"kz2": 6e-7, "ky3": 4e-7}), released, RNG.uniform(-1, 1, (3, 6)), "tool"
    )
    params = model.base[model.index] + RNG.normal(0, 1e-3, len(released))
    values.insert(100, params)
    # The pose variable near, not at, FK: the residual is non-zero, as during optimisation.
    values.insert(1, gtsam.Pose3(model.poses(params)[1]).compose(gtsam.Pose3.Expmap(RNG.normal(0, 0.05, 6))))
    return KinematicFactor(100, 1, 1, model, np.full(6, 1e-3))


def _cases():
    """(factor, values) for every factor type."""
    cases = []
    values = gtsam.Values()
    cases.append((_kinematic_case(values), values))

    values = gtsam.Values()
    values.insert(1, _pose())
    values.insert(2, _pose())
    values.insert(3, gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)))
    pts = RNG.normal(0, 0.3, (6, 3))
    drawings = RNG.normal(0, 0.5, (6, 3))
    cases.append(
        (
            PointPairFactor(
                [1, 2],
                np.array([0, 0, 0, 1, 1, 1]),
                pts,
                drawings,
                gaussian(np.full(15, 1e-4)),
                np.full(15, 1e-4),
                fixture_key=3,
            ),
            values,
        )
    )
    cases.append(
        (
            PointPairFactor(
                [1],
                np.zeros(3, dtype=int),
                pts[:3],
                drawings[:3],
                gaussian(np.full(6, 1e-4)),
                np.full(6, 1e-4),
                fixture_rotation=gtsam.Rot3.Rz(0.3).matrix(),
            ),
            values,
        )
    )

    values = gtsam.Values()
    values.insert(1, _pose())
    values.insert(2, _pose())
    values.insert(3, RNG.normal(0, 0.2, 3))
    values.insert(4, _pose())
    values.insert(5, RNG.normal(0, 1.0, 3))
    cases.append(
        (TrackerPointFactor(1, 2, 3, RNG.normal(0, 1, 3), gaussian(np.full(3, 1e-5)), np.full(3, 1e-5)), values)
    )
    cases.append((DistanceFactor(5, 2, 3, 1.7, gaussian(np.array([1e-5])), np.array([1e-5])), values))
    cases.append((PoseFactor(1, 2, 4, _pose(), gaussian(np.full(6, 1e-4)), np.full(6, 1e-4)), values))

    values = gtsam.Values()
    camera = gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)), RNG.normal(0, 0.3, 3))
    values.insert(1, camera)
    # An object 0.5 m in front of the camera, so that its points project.
    values.insert(
        2, camera.compose(gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)), np.array([0.02, -0.03, 0.5])))
    )
    intrinsics = np.array([1500.0, 1450.0, 640.0, 480.0, -0.2, 0.15, 1e-3, -2e-3, -0.05])
    values.insert(3, intrinsics)
    point = np.array([0.05, -0.04, 0.02])
    cases.append(
        (
            ProjectionFactor(
                1, 2, point, np.array([700.0, 400.0]), gaussian(np.full(2, 0.5)), np.full(2, 0.5), intrinsics_key=3
            ),
            values,
        )
    )
    cases.append(
        (
            ProjectionFactor(
                1, 2, point, np.array([700.0, 400.0]), gaussian(np.full(2, 0.5)), np.full(2, 0.5), intrinsics=intrinsics
            ),
            values,
        )
    )

    values = gtsam.Values()
    values.insert(7, RNG.normal(0, 1, 5))
    cases.append((ParameterBoundFactor(7, 5, np.array([1, 3]), np.array([0.2, -0.1]), np.array([0.01, 0.02])), values))
    values = gtsam.Values()
    values.insert(8, RNG.normal(0, 1, 4))
    values.insert(9, RNG.normal(0, 1, 4))
    cases.append((RandomWalkFactor(8, 9, np.array([1e-6, 2e-6, 1e-3, 1e-9])), values))
    return cases


def _retract(values: gtsam.Values, key: int, kind: str, delta: np.ndarray) -> gtsam.Values:
    out = gtsam.Values(values)
    if kind == "pose3":
        out.update(key, values.atPose3(key).retract(delta))
    elif kind == "rot3":
        out.update(key, values.atRot3(key).retract(delta))
    elif kind == "point3":
        out.update(key, values.atPoint3(key) + delta)
    else:
        out.update(key, values.atVector(key) + delta)
    return out


CASES = _cases()


def test_every_factor_type_is_covered():
    def subclasses(cls):
        return {c for s in cls.__subclasses__() for c in (s, *subclasses(s))}

    shipped = {c for c in subclasses(CheckedFactor) if c.__module__.startswith("fgcal.factors")}
    assert {type(f) for f, _ in CASES} == shipped


@pytest.mark.parametrize(("factor", "values"), CASES, ids=[type(f).__name__ for f, _ in CASES])
def test_linearize_matches_central_differences(factor, values):
    linear = factor.factor.linearize(values)  # through GTSAM: a wrong Jacobian would crash here
    A, b = linear.jacobian()
    whiten = 1.0 / factor.sigmas
    np.testing.assert_allclose(-b, whiten * factor.factor.unwhitenedError(values), rtol=1e-12, atol=1e-12)
    column = 0
    for key, kind, dim in factor.variables:
        numeric = np.zeros((factor.dim, dim))
        for i in range(dim):
            step = np.zeros(dim)
            step[i] = 1e-6
            plus = factor.factor.unwhitenedError(_retract(values, key, kind, step))
            minus = factor.factor.unwhitenedError(_retract(values, key, kind, -step))
            numeric[:, i] = (plus - minus) / 2e-6
        analytic = A[:, column : column + dim] / whiten[:, None]
        scale = max(np.linalg.norm(numeric), 1e-9)
        assert np.linalg.norm(analytic - numeric) / scale < 1e-6, f"{type(factor).__name__} key {key} ({kind})"
        column += dim


class _WrongShape(CheckedFactor):
    def __init__(self):
        super().__init__([(1, "point3", None)], gaussian(np.ones(3)), np.ones(3))

    def evaluate(self, inputs, jacobians):
        # A non-zero residual, so that the optimiser has to linearise.
        return np.ones(3), [np.zeros((3, 2))] if jacobians else []


def test_helmert_contrasts_are_orthonormal_and_carry_the_pair():
    from fgcal.factors.point_pair import helmert

    H = helmert(5)
    np.testing.assert_allclose(H @ H.T, np.eye(4), atol=1e-15)
    np.testing.assert_allclose(H.sum(axis=1), 0.0, atol=1e-15)
    # Two observations: the seed's pair residual x_u - x_v + (p_V - p_U), over sqrt(2).
    values = gtsam.Values()
    pose_j, pose_k = _pose(), _pose()
    values.insert(1, pose_j)
    values.insert(2, pose_k)
    c = RNG.normal(0, 0.3, (2, 3))
    p_F = RNG.normal(0, 0.5, (2, 3))
    factor = PointPairFactor([1, 2], np.array([0, 1]), c, p_F, gaussian(np.full(3, 1.0)), np.full(3, 1.0))
    seed_pair = pose_j.transformFrom(c[0]) - pose_k.transformFrom(c[1]) + (p_F[1] - p_F[0])
    np.testing.assert_allclose(factor.factor.unwhitenedError(values), seed_pair / np.sqrt(2), atol=1e-12)


def test_projection_matches_opencv():
    import cv2

    from fgcal.factors import project

    intrinsics = np.array([1500.0, 1450.0, 640.0, 480.0, -0.2, 0.15, 1e-3, -2e-3, -0.05])
    points = RNG.normal(0, 0.1, (20, 3)) + np.array([0.0, 0.0, 0.6])
    K = np.array([[1500.0, 0, 640.0], [0, 1450.0, 480.0], [0, 0, 1]])
    expected, _ = cv2.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, intrinsics[4:])
    ours = np.array([project(intrinsics, p) for p in points])
    np.testing.assert_allclose(ours, expected.reshape(-1, 2), rtol=0, atol=1e-9)


def test_malformed_jacobian_raises_instead_of_crashing():
    values = gtsam.Values()
    values.insert(1, np.zeros(3))
    bad = _WrongShape()
    with pytest.raises(FactorError, match="shape"):
        bad.factor.linearize(values)
    graph = gtsam.NonlinearFactorGraph()
    graph.add(bad.factor)
    with pytest.raises(FactorError):
        gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
