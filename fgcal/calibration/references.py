"""The tracker's stability over the session, from reflectors fixed in the cell
(``tracker_references``): how far each drifted, how noisy its readings are, and which readings
are gross misreads. The calibration assumes one tracker pose for the whole session; a drift of
the references is a drift of that pose, and it cannot be told apart from the robot's errors."""

from __future__ import annotations

import numpy as np

from ..data.dataset import Dataset
from .goodness import chi_median

WINDOW = 11  # readings in the running median that the misreads are measured from
MISREAD_SIGMA = 5.0  # a reading this many sigmas from the running median is a misread
END_FRACTION = 0.1  # drift: the median of the last tenth of the readings minus that of the first
CHI3_MEDIAN = float(chi_median(np.array([3]))[0])  # median norm of a 3-D standard normal vector


def reference_check(dataset: Dataset, declared_sigma_m: float) -> dict | None:
    """Per reference reflector, in reading order (the configurations' order): readings, robust
    noise sigma per coordinate (m), drift over the session (m, as a vector and its norm) and the
    configurations of its misreads (farther from the running median than MISREAD_SIGMA times
    the larger of the robust and the declared sigma, as a 3-D norm); and the drift common to all
    references (the tracker's)."""
    table = dataset.tables.get("tracker_references")
    if table is None or not len(table):
        return None
    order = {c: i for i, c in enumerate(dataset.configs)}
    targets: dict[str, dict] = {}
    drifts = []
    for name in sorted(set(table.ids["target"])):
        rows = np.flatnonzero(table.ids["target"] == name)
        rows = rows[np.argsort([order[c] for c in table.ids["config"][rows]], kind="stable")]
        xyz = table.values[rows]
        if len(xyz) < WINDOW:
            targets[str(name)] = {"readings": len(xyz), "note": f"fewer than {WINDOW} readings: not assessed"}
            continue
        deviation = np.linalg.norm(xyz - running_median(xyz, WINDOW), axis=1)
        sigma = float(np.median(deviation)) / CHI3_MEDIAN
        threshold = MISREAD_SIGMA * max(sigma, declared_sigma_m) * CHI3_MEDIAN
        misread = deviation > threshold
        clean = xyz[~misread]
        ends = max(1, round(END_FRACTION * len(clean)))
        drift = np.median(clean[-ends:], axis=0) - np.median(clean[:ends], axis=0)
        drifts.append(drift)
        targets[str(name)] = {
            "readings": len(xyz),
            "noise_sigma_m": sigma,
            "drift_m": [float(v) for v in drift],
            "drift_norm_m": float(np.linalg.norm(drift)),
            "misreads": [str(c) for c in table.ids["config"][rows][misread]],
            "largest_misread_m": float(deviation[misread].max()) if misread.any() else None,
        }
    common = np.mean(drifts, axis=0) if drifts else np.zeros(3)
    return {
        "targets": targets,
        "common_drift_m": [float(v) for v in common],
        "common_drift_norm_m": float(np.linalg.norm(common)),
        "declared_sigma_m": declared_sigma_m,
        "method": f"misreads: beyond {MISREAD_SIGMA:g} sigmas (the larger of the robust and the declared one; 3-D "
        f"norm) from a running median of {WINDOW} readings; drift: median of the last {END_FRACTION:.0%} of the "
        "clean readings minus the first's",
    }


def running_median(points: np.ndarray, window: int) -> np.ndarray:
    """Median of each coordinate over ``window`` readings centred on each one (shrunk at the ends)."""
    half = window // 2
    n = len(points)
    return np.array([np.median(points[max(0, i - half) : min(n, i + half + 1)], axis=0) for i in range(n)])
