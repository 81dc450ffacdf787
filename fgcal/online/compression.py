"""Marginal factors compressed: the linear factors iSAM2 keeps for what left the window, on the
same variables, merged into one QR-compressed factor (both online calibrators)."""

from __future__ import annotations

import gtsam
import numpy as np


def copy_value(out: gtsam.Values, values: gtsam.Values, key: int) -> int:
    """One value of ``values`` into ``out``, whatever its type (a Pose3, a Rot3 or a vector);
    returns its tangent dimension."""
    for read, dim in ((values.atPose3, 6), (values.atRot3, 3), (values.atVector, None)):
        try:
            value = read(key)
        except Exception:  # GTSAM's wrong-type error
            continue
        out.insert(key, value)
        return dim if dim is not None else len(value)
    raise TypeError(f"unsupported value type at key {gtsam.DefaultKeyFormatter(key)}")


def merged_factor(keys: tuple[int, ...], marginals: list, point: gtsam.Values):
    """One QR-compressed linear factor for linear factors on ``keys`` (at ``point``)."""
    subset = gtsam.Values()
    dims = {key: copy_value(subset, point, key) for key in keys}
    offsets = dict(zip(keys, np.cumsum([0, *[dims[k] for k in keys]])[:-1].tolist(), strict=True))
    width = sum(dims.values())
    blocks = []
    for marginal in marginals:
        linear = marginal.linearize(subset)
        A, b = linear.jacobian()
        stacked = np.zeros((A.shape[0], width + 1))
        column = 0
        for key in linear.keys():  # noqa: SIM118 (a GaussianFactor, not a dict)
            stacked[:, offsets[key] : offsets[key] + dims[key]] = A[:, column : column + dims[key]]
            column += dims[key]
        stacked[:, width] = b
        blocks.append(stacked)
    R = np.linalg.qr(np.vstack(blocks), mode="r")
    arguments = []
    for key in keys:
        arguments += [key, R[:, offsets[key] : offsets[key] + dims[key]]]
    unit = gtsam.noiseModel.Unit.Create(R.shape[0])
    return gtsam.LinearContainerFactor(gtsam.JacobianFactor(*arguments, R[:, width], unit), subset)


MERGE_MARGINALS_ABOVE = 4  # marginal factors kept apart up to this many


def merge_marginals(smoother, marginals: list[int], scanned: int) -> tuple[list[int], int]:
    """Merge the marginal factors of what left a fixed-lag window; returns the slots of those
    kept apart and the smoother's factor slots scanned so far.

    Each marginalisation leaves a LinearContainerFactor; left alone they pile up, and every
    update would eliminate them all again. Re-expressed at the current linearisation point
    (which leaves each quadratic as it was), the ones on the same variables are stacked and
    compressed by QR into one Jacobian factor (a Hessian would do too, but QR elimination needs
    a Jacobian and a merged marginal may be rank deficient)."""
    factors = smoother.getFactors()
    for i in range(scanned, factors.size()):
        if isinstance(factors.at(i), gtsam.LinearContainerFactor):
            marginals.append(i)
    scanned = factors.size()
    # A marginal factor goes away itself when one of its variables is marginalised.
    marginals = [i for i in marginals if factors.at(i) is not None]
    if len(marginals) <= MERGE_MARGINALS_ABOVE:
        return marginals, scanned
    by_keys: dict[tuple[int, ...], list[int]] = {}
    for i in marginals:
        by_keys.setdefault(tuple(sorted(factors.at(i).keys())), []).append(i)
    point = smoother.getLinearizationPoint()
    merged, removed, kept = gtsam.NonlinearFactorGraph(), [], []
    for keys, slots in by_keys.items():
        if len(slots) < 2 or len(keys) > 3:  # GTSAM's Python JacobianFactor takes up to 3 keys
            kept += slots
            continue
        merged.add(merged_factor(keys, [factors.at(i) for i in slots], point))
        removed += slots
    if removed:
        smoother.update(merged, gtsam.Values(), {}, removed)
    return kept, scanned
