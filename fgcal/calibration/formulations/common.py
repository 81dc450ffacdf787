"""What several formulations share: pixel observations and the camera's intrinsics (projection,
static camera), and the start of an instrument's pose from measured poses (6D poses, static
camera)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.errors import InputError
from ...data.dataset import Dataset
from ...factors import MeasurementSet
from ...model.camera import solve_pnp
from ..problem import HeldOut, Observations, Problem, rows_of, subset_of, take
from ..settings import MeasurementSettings
from ..state import Auxiliary, State

INTRINSICS = ("fx_px", "fy_px", "cx_px", "cy_px", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class PixelObservations(Observations):
    configs: np.ndarray  # (O,) per pixel: index into config_ids
    points: np.ndarray  # (O, 3) the point in its drawing's frame (fixture or board), m
    pixels: np.ndarray  # (O, 2) px
    names: np.ndarray  # (O,) point names

    @property
    def n_residuals(self) -> int:
        return 2 * len(self.configs)

    def unit_label(self, unit: int) -> tuple[str, str]:
        return str(self.config_ids[self.configs[unit]]), str(self.names[unit])

    def select(self, keep: np.ndarray) -> PixelObservations:
        return PixelObservations(self.config_ids, self.q, **take(self, keep, ("configs", "points", "pixels", "names")))


def require_pixels(dataset: Dataset, who: str) -> None:
    if "pixels" not in dataset.tables or dataset.camera is None:
        raise InputError(
            dataset.path / "dataset.yaml", "measured", f"{who} the pixels table and the camera intrinsics (camera:)"
        )


def pixel_observations(dataset: Dataset, subset: np.ndarray) -> PixelObservations:
    """The pixels of the images of ``subset`` with their points' drawing coordinates."""
    points = dataset.tables["points"]
    where = {name: i for i, name in enumerate(points.ids["point"])}
    rows = list(rows_of(dataset, dataset.tables["pixels"], "point", subset))
    return PixelObservations(
        **subset_of(dataset, subset),
        configs=np.array([r[0] for r in rows], dtype=int),
        points=points.values[[where[r[1]] for r in rows]].reshape(-1, 3),
        pixels=np.array([r[2] for r in rows], dtype=float).reshape(-1, 2),
        names=np.array([r[1] for r in rows], dtype=object),
    )


def fit_pixels(dataset: Dataset, fit: np.ndarray, formulation: str) -> PixelObservations:
    require_pixels(dataset, f"the {formulation} formulation needs")
    observations = pixel_observations(dataset, fit)
    if len(np.unique(observations.configs)) < 3:
        raise InputError(dataset.path / "pixels.csv", None, "too few fitting images with pixels")
    return observations


def dataset_intrinsics(dataset: Dataset) -> np.ndarray:
    camera = dataset.camera
    return np.array([camera.fx, camera.fy, camera.cx, camera.cy, *camera.distortion])


def intrinsics_unknowns(dataset: Dataset, settings: MeasurementSettings) -> dict[str, Auxiliary]:
    """The intrinsics as an unknown with a prior around the dataset's values (from the earlier
    intrinsic calibration), when the config estimates them; else none (held at the dataset's)."""
    if settings.intrinsics_prior_sigmas is None:
        return {}
    values = dataset_intrinsics(dataset)
    return {
        "intrinsics": Auxiliary(
            "vector",
            values.copy(),
            INTRINSICS,
            prior_mean=values,
            prior_sigmas=np.array(settings.intrinsics_prior_sigmas),
        )
    }


def constant_intrinsics(dataset: Dataset, state: State) -> np.ndarray | None:
    """The intrinsics a pixel set holds constant, or None when they are an unknown."""
    return None if "intrinsics" in state.aux else dataset_intrinsics(dataset)


def pixel_errors(problem: Problem, main: MeasurementSet, inputs: list, state: State) -> dict[str, HeldOut]:
    """The reprojection error in px of each held-out pixel (besides the metric one)."""
    pixels = np.linalg.norm(main.compute(inputs, False).residual.reshape(-1, 2), axis=1)
    return {"reprojection_px": HeldOut(pixels, np.asarray(main.configs))}


def depth_over_focal(problem: Problem, main: MeasurementSet, inputs: list, state: State) -> np.ndarray:
    """Per pixel, its point's depth over the mean focal length: what turns a pixel error at
    that depth into metres, in the plane of the point."""
    intrinsics = state.get("intrinsics")
    if intrinsics is None:
        intrinsics = dataset_intrinsics(problem.dataset)
    return main.camera_points(inputs)[3][:, 2] / (0.5 * float(intrinsics[0] + intrinsics[1]))


def pnp_per_image(dataset: Dataset, observations: PixelObservations) -> dict[int, np.ndarray]:
    """T_C_F (or T_C_B) of every image with at least four points, from OpenCV's solvePnP (IPPE)."""
    spread = np.linalg.svd(observations.points - observations.points.mean(axis=0), compute_uv=False)
    if len(spread) < 2 or spread[1] <= 1e-6 * max(spread[0], 1e-300):
        raise InputError(
            dataset.path / "points.csv", None, "the points seen in the images lie on one line (or one point): a "
            "camera's pose needs points spanning a plane",
        )  # fmt: skip
    poses = {}
    for j in np.unique(observations.configs):
        rows = observations.configs == j
        if rows.sum() >= 4:
            T = solve_pnp(observations.points[rows], observations.pixels[rows], dataset.camera)
            if T is not None and np.all(np.isfinite(T)):
                poses[int(j)] = T
    if len(poses) < 3:
        raise InputError(
            dataset.path / "pixels.csv",
            None,
            f"solvePnP succeeded on {len(poses)} images: at least 3 with 4 points are needed",
        )
    return poses


def initial_pose_chain(flange: np.ndarray, measured: np.ndarray, rounds: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """L (the instrument's T_I_W) and E (the measured frame on the flange, T_n_E) from
    measured poses ``Z_j = L X_j E`` (N, 4, 4) and the flange poses X_j of the current model:
    OpenCV's calibrateHandEye (Park) in its eye-to-hand use (the flange poses inverted gives
    ``Y = L^-1`` and the constant E), then alternating averages of L and E (chordal mean of
    the rotations, mean of the translations), which settle the noise of the hand-eye step."""
    import cv2  # loaded when used: commands without images or cameras skip it

    inverse_flange = np.linalg.inv(flange)
    R, t = cv2.calibrateHandEye(
        list(inverse_flange[:, :3, :3]),
        list(inverse_flange[:, :3, 3]),
        list(measured[:, :3, :3]),
        list(measured[:, :3, 3]),
        method=cv2.CALIB_HAND_EYE_PARK,
    )
    W_from_instrument = np.eye(4)
    W_from_instrument[:3, :3], W_from_instrument[:3, 3] = R, np.ravel(t)
    L = np.linalg.inv(W_from_instrument)
    for _ in range(rounds):
        E = mean_pose(inverse_flange @ np.linalg.inv(L) @ measured)
        L = mean_pose(measured @ np.linalg.inv(flange @ E))
    return L, mean_pose(inverse_flange @ np.linalg.inv(L) @ measured)


def mean_pose(poses: np.ndarray) -> np.ndarray:
    """Chordal mean of the rotations and mean of the translations of poses (N, 4, 4)."""
    U, _, Vt = np.linalg.svd(poses[:, :3, :3].sum(axis=0))
    T = np.eye(4)
    T[:3, :3] = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    T[:3, 3] = poses[:, :3, 3].mean(axis=0)
    return T
