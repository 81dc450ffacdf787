"""The pair groups of a planned design (pairs formulation, ``pairs.groups``).

The pairs formulation fits its images in groups; within a group every point pair is used
through orthonormal contrasts, which cancel the group's common position (the base, unknown).
A group g of images j, each with points o measured in its camera frame with whitened rows
J_o (information.GroupRows: before any grouping), so carries

    I_g = sum_j J_j^T J_j - U_g^T U_g / n_g,   U_g = sum_j R_W_C,j sum_{o in j} J_o,

with n_g the group's points: the contrasts are ``H = helmert(n_g)`` on each coordinate of the
points' positions in W (``R_W_C,j c_o + t_j - R_W_F p_o``), whose rows span every direction but
the points' common translation, ``H^T H = I - 1 1^T / n_g``; a point's W row is its camera row
turned by R_W_C,j (the noise is isotropic, the whitening unchanged).

Left to chance (the calibration's seeded draw), the groups of one design differ by up to 10 %
in the predicted error; the planner models them in expectation while choosing configurations
(plan_model._grouped), then chooses the groups of the chosen ones: the partition into groups of
``pairs.group_images`` that minimises the predicted error (the mean predicted variance of the
scored point over the region, exactly as ``predicted_sigma``), by pairwise swaps of images
between groups from a few random partitions, each swap the best of all, until none improves.
A swap changes two groups' U: all swaps are evaluated in one batch of small solves.
"""

from __future__ import annotations

import numpy as np

from .exchange import predicted_sigma
from .information import GroupRows, Information

STARTS = 4  # random partitions the swaps start from; the best result kept
RANDOM_DRAWS = 8  # random partitions the prediction without the plan's groups averages
MAX_SWAPS = 2000  # a bound, never reached on the seed cell (36 images: some 20 swaps)


def image_terms(grouping: GroupRows, chosen: list[int] | np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Of the chosen candidates: ``sum_j J_j^T J_j`` (p, p), each image's ``u_j = R_W_C,j
    sum_o J_o`` (n, 3, p), and the points per image."""
    rows = grouping.rows[np.asarray(chosen, dtype=int)]  # (n, r, p)
    n, r, p = rows.shape
    gram = np.einsum("nrp,nrq->pq", rows, rows)
    u = grouping.turn[np.asarray(chosen, dtype=int)] @ rows.reshape(n, r // 3, 3, p).sum(axis=1)
    return gram, u, r // 3


def group_information(info: Information, chosen: list[int] | np.ndarray, groups: list[list[int]]) -> np.ndarray:
    """The information (p, p) of the chosen candidates fitted in ``groups`` (positions in
    ``chosen``), with the priors and fixed rows."""
    gram, u, points = image_terms(info.grouping, chosen)
    M = info.prior_matrix + gram
    for group in groups:
        U = u[group].sum(axis=0)
        M -= U.T @ U / (points * len(group))
    return M


def variance(info: Information, M: np.ndarray) -> float:
    """The mean predicted variance of the scored point over the region (m^2): predicted_sigma^2."""
    return predicted_sigma(info, M) ** 2


def random_groups(n: int, size: int, rng: np.random.Generator) -> list[list[int]]:
    """n images in groups of ``size`` at random, the last one smaller where n is not a multiple
    (as the calibration draws them)."""
    order = [int(j) for j in rng.permutation(n)]
    return [order[k : k + size] for k in range(0, n, size)]


def improve_groups(info: Information, chosen: list[int] | np.ndarray, groups: list[list[int]]) -> list[list[int]]:
    """``groups`` improved by pairwise swaps of images between groups, each the swap that
    lowers the predicted variance most, until none lowers it: never worse than the start."""
    gram, u, points = image_terms(info.grouping, chosen)
    base = info.prior_matrix + gram
    W = info.region.T @ info.region
    groups = [list(g) for g in groups]
    owner = np.empty(len(u), dtype=int)
    for g, group in enumerate(groups):
        owner[group] = g
    weight = np.array([1.0 / (points * len(g)) for g in groups])
    every_i, every_k = np.triu_indices(len(u), 1)
    for _ in range(MAX_SWAPS):
        apart = owner[every_i] != owner[every_k]  # the swaps: two images of different groups
        i, k = every_i[apart], every_k[apart]
        if not len(i):  # one group: nothing to swap
            break
        U = np.stack([u[g].sum(axis=0) for g in groups])  # (G, 3, p)
        loss = np.einsum("gxp,gxq,g->pq", U, U, weight)
        current = float(np.trace(W @ np.linalg.inv(base - loss)))
        a, b = owner[i], owner[k]
        delta = u[k] - u[i]  # group a trades image i for k; group b the other way
        Ua, Ub = U[a] + delta, U[b] - delta
        change = (np.swapaxes(Ua, 1, 2) @ Ua - np.swapaxes(U[a], 1, 2) @ U[a]) * weight[a, None, None]
        change += (np.swapaxes(Ub, 1, 2) @ Ub - np.swapaxes(U[b], 1, 2) @ U[b]) * weight[b, None, None]
        trial = np.trace(np.linalg.solve((base - loss)[None] - change, np.broadcast_to(W, change.shape)),
                         axis1=1, axis2=2)  # fmt: skip
        best = int(np.argmin(trial))
        if not trial[best] < current * (1.0 - 1e-12):
            break
        gi, gk = int(i[best]), int(k[best])
        ga, gb = owner[gi], owner[gk]
        groups[ga][groups[ga].index(gi)], groups[gb][groups[gb].index(gk)] = gk, gi
        owner[gi], owner[gk] = gb, ga
    return groups


def random_groups_sigma(info: Information, chosen: list[int], seed: int, draws: int = RANDOM_DRAWS) -> float:
    """The predicted RMS error (m) of the chosen candidates fitted in random groups, as the
    calibration draws them without a groups file: the root of the mean variance over ``draws``
    random partitions (seeded)."""
    rng = np.random.default_rng(seed)
    values = [
        variance(info, group_information(info, chosen, random_groups(len(chosen), info.grouping.size, rng)))
        for _ in range(draws)
    ]
    return float(np.sqrt(np.mean(values)))


def plan_groups(info: Information, chosen: list[int], seed: int, starts: int = STARTS) -> list[list[int]]:
    """The pair groups of the chosen candidates (positions in ``chosen``) with the least
    predicted error: swaps from ``starts`` random partitions (seeded), the best kept."""
    rng = np.random.default_rng(seed)
    best, best_value = None, np.inf
    for _ in range(starts):
        groups = improve_groups(info, chosen, random_groups(len(chosen), info.grouping.size, rng))
        value = variance(info, group_information(info, chosen, groups))
        if value < best_value:
            best, best_value = groups, value
    return [sorted(g) for g in best]
