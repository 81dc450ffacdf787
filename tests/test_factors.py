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
    Distances,
    FactorError,
    LinkProjections,
    MeasurementFactor,
    MeasurementSet,
    ParameterBoundFactor,
    PlaneContacts,
    PointPairs,
    Poses,
    Projections,
    RandomWalkFactor,
    RobustLoss,
    SelfContacts,
    SocketSpacings,
    StaticProjections,
    TipDistances,
    TouchPoints,
    TrackerPoints,
    gaussian,
)
from fgcal.model.motion import MotionHistory, features

RNG = np.random.default_rng(7)
P_KEY = 100


def _pose() -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.8, 3)), RNG.normal(0, 1.0, 3))


def _kinematics(values: gtsam.Values, n_configs: int = 3) -> BatchKinematics:
    """Camera poses of a KR 125/2 with compliances, distortions and motion terms (reached by
    random moves), P near (not at) nominal."""
    robot = fgcal.load_robot("kuka_kr125_2").with_tool(np.eye(4), payload_mass=10.0, payload_com=[0, 0, 0.1])
    robot = robot.with_model("DH,s,e,h")
    released = ["theta2", "d3", "alpha1", "sx2", "sy3", "kz2", "ky3", "lm2", "lv5", "tool.tx", "tool.rz"]
    q = RNG.uniform(-1, 1, (n_configs, 6))
    model = BatchKinematics(
        robot,
        robot.parameter_vector({"kz2": 6e-7, "ky3": 4e-7, "lm1": 3e-4}),
        released,
        q,
        "tool",
        features(q, MotionHistory(q - RNG.uniform(-0.3, 0.3, q.shape), np.ones(n_configs))),
    )
    scale = np.array([1e-8 if name[0] == "k" else 1e-3 for name in released])  # rad/(N m), else m or rad
    values.insert(P_KEY, model.base[model.index] + RNG.normal(0, 1.0, len(released)) * scale)
    return model


def _in_front(model: BatchKinematics, values: gtsam.Values, j: int) -> gtsam.Pose3:
    """An object 0.5 m in front of configuration j's camera, so that its points project."""
    camera = gtsam.Pose3(model.poses(values.atVector(P_KEY))[j])
    return camera.compose(gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)), np.array([0.02, -0.03, 0.5])))


def _measurement_sets():
    """(measurement set, values) for every measurement kind, with and without P and the
    optional variables, with and without a robust loss (at residuals beyond its threshold)."""
    sets = []
    for released, robust in ((True, None), (False, None), (True, RobustLoss("huber", 1.0))):
        values = gtsam.Values()
        model = _kinematics(values)
        key = P_KEY if released else None
        values.insert(3, gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)))
        groups = [
            (np.array([0, 0, 0, 1, 1, 1]), RNG.normal(0, 0.3, (6, 3)), RNG.normal(0, 0.5, (6, 3))),
            (np.array([2, 2, 1]), RNG.normal(0, 0.3, (3, 3)), RNG.normal(0, 0.5, (3, 3))),
        ]
        sets.append((PointPairs(model, key, groups, 1e-3, fixture_key=3, robust=robust), values))
        if released:  # with nothing released and the fixture known, there is nothing to estimate
            sets.append((PointPairs(model, key, groups, 1e-3, fixture_rotation=gtsam.Rot3.Rz(0.3).matrix()), values))

        values = gtsam.Values()
        model = _kinematics(values)
        values.insert(2, _in_front(model, values, 1))
        intrinsics = np.array([1500.0, 1450.0, 640.0, 480.0, -0.2, 0.15, 1e-3, -2e-3, -0.05])
        values.insert(3, intrinsics)
        configs = np.array([1, 1, 1, 1])
        points = RNG.normal(0, 0.05, (4, 3))
        pixels = RNG.uniform(300, 900, (4, 2))
        sets.append((Projections(model, key, 2, configs, points, pixels, 0.5, intrinsics_key=3, robust=robust), values))
        sets.append((Projections(model, key, 2, configs, points, pixels, 0.5, intrinsics=intrinsics), values))
        # Eye-to-hand: a camera 0.5 m in front of configuration 1's board, the board on the flange.
        board = gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)), RNG.normal(0, 0.1, 3))
        values.insert(4, board)
        offset = gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)), np.array([0.02, -0.03, 0.5]))
        values.insert(5, offset.compose(gtsam.Pose3(model.poses(values.atVector(P_KEY))[1]).compose(board).inverse()))
        configs = np.array([1, 1, 1, 1, 1, 1])
        points = RNG.normal(0, 0.05, (6, 3))
        pixels = RNG.uniform(300, 900, (6, 2))
        static = StaticProjections(model, key, 5, 4, configs, points, pixels, 0.5, intrinsics_key=3, robust=robust)
        sets.append((static, values))
        sets.append((StaticProjections(model, key, 5, 4, configs, points, pixels, 0.5, intrinsics=intrinsics), values))

        # Self-observation: two cameras on the link of configurations 0 and 1 (rows 0, 1), each
        # 0.5 m from a board on row 2's frame, whose points they see.
        values = gtsam.Values()
        model = _kinematics(values)
        poses = model.poses(values.atVector(P_KEY))
        values.insert(20, gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.3, 3)), RNG.normal(0, 0.05, 3)))  # board
        board_W = gtsam.Pose3(poses[2]).compose(values.atPose3(20))
        for mount, row in ((21, 0), (22, 1)):
            camera_W = board_W.compose(gtsam.Pose3(gtsam.Rot3.Expmap(RNG.normal(0, 0.2, 3)), [0.02, -0.03, -0.5]))
            values.insert(mount, gtsam.Pose3(poses[row]).inverse().compose(camera_W))
        intrinsics = np.array([[1500.0, 1450.0, 640.0, 480.0, -0.2, 0.15, 1e-3, -2e-3, -0.05],
                               [1200.0, 1210.0, 600.0, 500.0, 0.1, -0.05, 0.0, 1e-3, 0.0]])  # fmt: skip
        link = LinkProjections(model, key, [21, 22], [20], np.array([0, 0, 1, 1]), np.array([2, 2, 2, 2]),
                               np.array([0, 0, 1, 1]), np.zeros(4, dtype=int), RNG.normal(0, 0.03, (4, 3)),
                               RNG.uniform(300, 900, (4, 2)), 0.5, intrinsics, robust=robust)  # fmt: skip
        sets.append((link, values))

        values = gtsam.Values()
        model = _kinematics(values)
        values.insert(1, _pose())
        values.insert(4, _pose())
        values.insert(5, RNG.normal(0, 1.0, 3))
        values.insert(6, RNG.normal(0, 0.2, 3))
        values.insert(7, RNG.normal(0, 0.2, 6))
        sets.append(
            (
                TrackerPoints(
                    model,
                    key,
                    1,
                    7,
                    2,
                    np.array([0, 0, 2]),
                    np.array([0, 1, 1]),
                    RNG.normal(0, 1, (3, 3)),
                    1e-3,
                    robust=robust,
                ),
                values,
            )
        )
        # The scored-point model of the truth scores: the instrument or the points constant.
        sets.append(
            (
                TrackerPoints(model, key, None, 7, 2, np.array([0, 2]), np.array([1, 0]), np.zeros((2, 3)), 1.0,
                              tracker=_pose().matrix()),
                values,
            )
        )  # fmt: skip
        sets.append(
            (
                TrackerPoints(model, key, 1, None, 2, np.array([1, 2]), np.array([1, 0]), np.zeros((2, 3)), 1.0,
                              points=RNG.normal(0, 0.2, (2, 3))),
                values,
            )
        )  # fmt: skip
        measured = [_pose().matrix(), _pose().matrix()]
        sets.append((Poses(model, key, 1, 4, np.array([2, 0]), measured, 1e-3, 1e-2, robust=robust), values))
        values.insert(8, RNG.normal(0, 1.0, 9))
        distances = Distances(
            model, key, 6, 8, 3, np.array([0, 2, 1]), np.array([2, 0, 2]), np.array([1.7, 2.1, 0.9]), 1e-3, robust
        )
        sets.append((distances, values))
        # Readings to pivots and between configurations (a two-ball bar), and the latter alone.
        mixed = Distances(
            model, key, 6, 8, 3, np.array([0, 2, 1]), np.array([2, -1, -1]), np.array([1.7, 2.1, 0.9]), 1e-3, robust,
            others=np.array([-1, 0, 2]),
        )  # fmt: skip
        sets.append((mixed, values))
        between = Distances(
            model, key, 6, None, 0, np.array([0, 2]), np.array([-1, -1]), np.array([2.1, 0.9]), 1e-3, robust,
            others=np.array([1, 0]),
        )  # fmt: skip
        sets.append((between, values))
        touches = TouchPoints(model, key, 6, 8, 3, np.array([0, 1, 2, 2]), np.array([0, 2, 2, 1]), 1e-3, robust)
        sets.append((touches, values))
        if released:  # the spacings have no P: once is enough
            sets.append((SocketSpacings(8, 3, np.array([[0, 1], [2, 0]]), np.array([0.4, 0.7]), 1e-4, robust), values))
        # Self-contact (balls on two tips touching) and contacts with planes, radii estimated or known.
        values.insert(9, RNG.normal(0, 0.1, 9))  # three balls' centres on their tips
        values.insert(10, RNG.uniform(0.01, 0.03, 3))  # their radii
        values.insert(11, np.r_[RNG.normal(0, 0.1, 2), 0.4, RNG.normal(0, 0.1, 2), -0.3])  # two planes (a1, a2, d)
        rows_a, rows_b = np.array([0, 1, 2, 2]), np.array([1, 2, 0, 1])
        elements_a, elements_b = np.array([0, 1, 2, 0]), np.array([1, 2, 0, 2])
        sets.append((SelfContacts(model, key, 9, 10, 3, rows_a, rows_b, elements_a, elements_b, 1e-4, robust), values))
        sets.append((SelfContacts(model, key, 9, None, 3, rows_a, rows_b, elements_a, elements_b, 1e-4, robust,
                                  radii=np.array([0.02, 0.025, 0.015])), values))  # fmt: skip
        readings = np.array([0.3, 0.28, 0.31, 0.29])
        sets.append((TipDistances(model, key, 9, 3, rows_a, rows_b, elements_a, elements_b, readings, 1e-6, robust),
                     values))  # fmt: skip
        normals = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])
        rows, elements, planes = np.array([0, 1, 2, 2]), np.array([0, 1, 2, 0]), np.array([0, 1, 1, 0])
        sets.append((PlaneContacts(model, key, 9, 10, 11, 3, normals, rows, elements, planes, 1e-4, robust), values))
        sets.append((PlaneContacts(model, key, 9, None, 11, 3, normals, rows, elements, planes, 1e-4, robust,
                                   radii=np.array([0.02, 0.025, 0.015])), values))  # fmt: skip
    return sets


def _cases():
    """(factor, values) for every factor type: each factor of every measurement set, and the priors."""
    cases = [(measurements.factor(), values) for measurements, values in SETS]
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


SETS = _measurement_sets()
CASES = _cases()


def _subclasses(cls):
    return {c for s in cls.__subclasses__() for c in (s, *_subclasses(s))}


def test_every_factor_type_is_covered():
    shipped = {c for c in _subclasses(CheckedFactor) if c.__module__.startswith("fgcal.factors")}
    assert {type(f) for f, _ in CASES} == shipped
    kinds = {c for c in _subclasses(MeasurementSet) if c.__module__.startswith("fgcal.factors")}
    assert {type(m) for m, _ in SETS} == kinds


def _label(factor) -> str:
    if isinstance(factor, MeasurementFactor):
        m = factor.measurements
        return f"{type(m).__name__}-{len(m.variables)}vars-{'robust' if m.robust else 'plain'}"
    return type(factor).__name__


@pytest.mark.parametrize(("factor", "values"), CASES, ids=[_label(f) for f, _ in CASES])
def test_linearize_matches_central_differences(factor, values):
    linear = factor.factor.linearize(values)  # through GTSAM: a wrong Jacobian would crash here
    A, b = linear.jacobian()
    whiten = 1.0 / factor.sigmas
    np.testing.assert_allclose(-b, whiten * factor.factor.unwhitenedError(values), rtol=1e-12, atol=1e-12)
    column = 0
    for key, kind, dim in factor.variables:
        numeric = np.zeros((factor.dim, dim))
        analytic = A[:, column : column + dim] / whiten[:, None]
        for i in range(dim):
            # A step that moves the residual by about 1e-3 at most: a compliance (1e-7 rad/(N m))
            # moves it by 1e6 per unit, and a 1e-6 step there would measure curvature.
            h = 1e-6 * min(1.0, 1e3 / max(np.abs(analytic[:, i]).max(), 1e-300))
            step = np.zeros(dim)
            step[i] = h
            plus = factor.factor.unwhitenedError(_retract(values, key, kind, step))
            minus = factor.factor.unwhitenedError(_retract(values, key, kind, -step))
            numeric[:, i] = (plus - minus) / (2 * h)
        scale = max(np.linalg.norm(numeric), 1e-9)
        assert np.linalg.norm(analytic - numeric) / scale < 1e-6, f"{_label(factor)} key {key} ({kind})"
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
    model = _kinematics(values)
    poses = model.poses(values.atVector(P_KEY))
    c = RNG.normal(0, 0.3, (2, 3))
    p_F = RNG.normal(0, 0.5, (2, 3))
    factor = PointPairs(model, P_KEY, [(np.array([0, 2]), c, p_F)], 1.0).factor()
    seed_pair = transform(poses[0], c[0]) - transform(poses[2], c[1]) + (p_F[1] - p_F[0])
    np.testing.assert_allclose(factor.factor.unwhitenedError(values), seed_pair / np.sqrt(2), atol=1e-12)


def test_contrasts_are_the_block_diagonal_helmert_contrasts():
    """Applied in O(O c), they equal the block-diagonal product, far from the origin too."""
    import scipy.linalg

    from fgcal.factors.point_pair import Contrasts, helmert

    sizes = [2, 5, 2, 40, 3, 300]
    x = RNG.normal(0, 1.0, (sum(sizes), 4)) + 1e3
    expected = scipy.linalg.block_diag(*[helmert(n) for n in sizes]) @ x
    assert Contrasts(sizes).shape == expected.shape[:1] + x.shape[:1]
    np.testing.assert_allclose(Contrasts(sizes) @ x, expected, rtol=0, atol=1e-9)
    # A group of micrometre differences after 200000 groups of centimetre ones: its rows keep
    # their precision (running sums over the whole set would carry the others' rounding, 1e-10
    # to 5e-10 relative; group by group they are exact to 1e-16).
    x = np.vstack([1.0 + RNG.normal(0.01, 0.01, (600000, 3)), 1.0 + RNG.normal(0, 1e-6, (3, 3))])
    last = helmert(3) @ (x[-3:] - x[-3])
    relative = np.abs((Contrasts([3] * 200001) @ x)[-2:] - last).max() / np.abs(last).max()
    assert relative < 1e-12


def test_point_pair_jacobian_is_the_same_chunk_by_chunk(monkeypatch):
    """The Jacobian is assembled a few whole groups at a time; the chunks change nothing."""
    import fgcal.factors.point_pair as point_pair

    values = gtsam.Values()
    model = _kinematics(values, n_configs=6)
    groups = [(RNG.integers(0, 6, n), RNG.normal(0, 0.3, (n, 3)), RNG.normal(0, 0.5, (n, 3))) for n in (3, 2, 7, 4, 2)]
    whole = PointPairs(model, P_KEY, groups, 1e-3).compute([values.atVector(P_KEY)], True)
    monkeypatch.setattr(point_pair, "BLOCK_OBSERVATIONS", 5)
    chunked = PointPairs(model, P_KEY, groups, 1e-3)
    assert len(chunked.contrasts.blocks) > 2
    evaluation = chunked.compute([values.atVector(P_KEY)], True)
    np.testing.assert_allclose(evaluation.residual, whole.residual, rtol=0, atol=1e-15)
    np.testing.assert_allclose(evaluation.blocks[0], whole.blocks[0], rtol=1e-13, atol=1e-15)


def transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return T[:3, :3] @ p + T[:3, 3]


def test_robust_loss_is_the_robust_cost_and_its_gradient():
    """|r'|^2/2 = rho(|r|) per unit, and J'^T r' = w J^T r (the M-estimator's gradient)."""
    rng = np.random.default_rng(3)
    residual = rng.normal(0, 3, 12)
    jacobian = rng.normal(0, 1, (12, 5))
    starts = np.array([0, 3, 6, 9])
    for loss in (RobustLoss("huber", 1.5), RobustLoss("cauchy", 2.0)):
        out, J = loss.apply(residual, jacobian, starts)
        for a in starts:
            r, Jr = residual[a : a + 3], jacobian[a : a + 3]
            s = np.linalg.norm(r)
            if loss.kind == "huber":
                rho = 0.5 * s * s if s <= loss.k else loss.k * s - 0.5 * loss.k**2
                weight = 1.0 if s <= loss.k else loss.k / s
            else:
                rho = 0.5 * loss.k**2 * np.log1p((s / loss.k) ** 2)
                weight = 1.0 / (1.0 + (s / loss.k) ** 2)
            assert 0.5 * np.sum(out[a : a + 3] ** 2) == pytest.approx(rho, rel=1e-12)
            np.testing.assert_allclose(J[a : a + 3].T @ out[a : a + 3], weight * Jr.T @ r, rtol=1e-10, atol=1e-12)


def test_projection_matches_opencv():
    import cv2

    from fgcal.factors import project

    intrinsics = np.array([1500.0, 1450.0, 640.0, 480.0, -0.2, 0.15, 1e-3, -2e-3, -0.05])
    points = RNG.normal(0, 0.1, (20, 3)) + np.array([0.0, 0.0, 0.6])
    K = np.array([[1500.0, 0, 640.0], [0, 1450.0, 480.0], [0, 0, 1]])
    expected, _ = cv2.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, intrinsics[4:])
    np.testing.assert_allclose(project(intrinsics, points), expected.reshape(-1, 2), rtol=0, atol=1e-9)
    np.testing.assert_allclose(project(intrinsics, points[0]), expected.reshape(-1, 2)[0], rtol=0, atol=1e-9)


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


def test_chi_median_matches_scipy():
    from scipy.special import gammaincinv

    from fgcal.calibration.goodness import chi_median

    k = np.arange(1, 60)
    np.testing.assert_allclose(chi_median(k), np.sqrt(2.0 * gammaincinv(k / 2.0, 0.5)), rtol=2e-4)


def test_a_trial_step_behind_the_camera_costs_so_much_it_is_rejected():
    """Where a measurement model breaks down (a point behind the camera), costing a trial step
    gives BREAKDOWN_RESIDUAL per row, which the optimiser rejects; linearising there is an
    error (BehindCameraError), never a crash or a silently used Jacobian."""
    from fgcal.factors import BehindCameraError
    from fgcal.factors.base import BREAKDOWN_RESIDUAL

    values = gtsam.Values()
    model = _kinematics(values)
    camera = gtsam.Pose3(model.poses(values.atVector(P_KEY))[1])
    values.insert(2, camera.compose(gtsam.Pose3(gtsam.Rot3(), np.array([0.0, 0.0, -0.5]))))  # behind it
    intrinsics = np.array([1500.0, 1450.0, 640.0, 480.0, -0.2, 0.15, 1e-3, -2e-3, -0.05])
    factor = Projections(
        model, P_KEY, 2, np.array([1, 1]), RNG.normal(0, 0.05, (2, 3)), np.full((2, 2), 500.0), 0.5, intrinsics
    ).factor()
    np.testing.assert_array_equal(factor.factor.unwhitenedError(values), np.full(4, BREAKDOWN_RESIDUAL))
    with pytest.raises(BehindCameraError):
        factor.factor.linearize(values)
