"""Choosing N of M candidates: greedy selection, then Fedorov exchange passes.

The information matrix of a design is ``M = prior + sum_c J_c^T J_c`` over its candidates
(J_c: r whitened rows). Adding or removing a candidate is a rank-r change, so the effect of
every candidate on the criterion comes from ``M^-1`` without a refit (A = J_c M^-1,
S = I + A J_c^T):

- ``d-optimal``: maximise ``log det`` of the parameters' information with the auxiliary
  unknowns eliminated (D_s-optimality): gain ``log det S - log det S_aux``;
- ``position``: minimise the mean predicted variance of the scored point over the region,
  ``trace(W M^-1)``: gain ``trace(S^-1 A W A^T)``;
- ``o1``..``o5``: the observability indices (fgcal.planning.indices), computed exactly for
  the candidates with the largest D-gain (a short list: an index needs an eigen-decomposition).

Exchange: each design point in turn is removed and the best candidate (possibly the same)
put in its place, until a pass changes nothing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .indices import observability
from .information import Information

CRITERIA = ("d-optimal", "position", "o1", "o2", "o3", "o4", "o5")
SHORT_LIST = 24


@dataclass
class DesignState:
    """Information matrix of a design and its inverse, kept in step by rank-r updates."""

    info: Information
    M: np.ndarray
    M_inv: np.ndarray
    chosen: list[int]

    @classmethod
    def empty(cls, info: Information) -> DesignState:
        M = info.prior_matrix
        return cls(info, M, np.linalg.inv(M), [])

    def add(self, c: int) -> None:
        J = self.info.rows[c]
        A = J @ self.M_inv
        self.M += J.T @ J
        self._update(-A, np.eye(len(J)) + A @ J.T, A)
        self.chosen.append(c)

    def remove(self, c: int) -> None:
        J = self.info.rows[c]
        A = J @ self.M_inv
        self.M -= J.T @ J
        self._update(A, np.eye(len(J)) - A @ J.T, A)
        self.chosen.remove(c)

    def _update(self, left: np.ndarray, S: np.ndarray, A: np.ndarray) -> None:
        """M_inv += left^T S^-1 A; where rounding leaves S singular (information that weak
        priors and strong rows make ill-conditioned), the inverse is recomputed from M."""
        try:
            self.M_inv += left.T @ np.linalg.solve(S, A)
        except np.linalg.LinAlgError:
            self.refresh()

    def refresh(self) -> None:
        """Recompute the inverse (rank updates accumulate rounding)."""
        self.M_inv = np.linalg.inv(self.M)


def _logdet_spd(S: np.ndarray) -> np.ndarray:
    """log det of a stack of symmetric positive definite matrices: by Cholesky (half an LU's
    work), or by LU where rounding left one not quite positive definite (weak priors)."""
    try:
        return 2.0 * np.log(np.diagonal(np.linalg.cholesky(S), axis1=1, axis2=2)).sum(axis=1)
    except np.linalg.LinAlgError:
        return np.linalg.slogdet(S)[1]


def _d_gains(state: DesignState, rows: np.ndarray, aux_gram: np.ndarray | None = None) -> np.ndarray:
    """``log det S - log det S_aux`` per candidate. ``aux_gram``: the candidates' ``a^T a`` of
    their auxiliary columns a, when there are fewer of those than rows; Sylvester's identity
    ``det(I_r + a K a^T) = det(I_k + K a^T a)`` then gives the aux term from k x k matrices."""
    m = state.info.n_params
    n_candidates, r, p = rows.shape
    # One matrix product for all candidates, not one per candidate.
    A = (rows.reshape(-1, p) @ state.M_inv).reshape(n_candidates, r, p)
    S = A @ np.swapaxes(rows, 1, 2)
    S[:, np.arange(r), np.arange(r)] += 1.0
    gain = _logdet_spd(S)
    aux = rows[:, :, m:]
    if aux.shape[2]:
        M_aux_inv = np.linalg.inv(state.M[m:, m:])
        if aux_gram is not None:
            gain -= np.linalg.slogdet(np.eye(aux.shape[2]) + M_aux_inv @ aux_gram)[1]
        else:
            S_aux = aux @ M_aux_inv @ np.swapaxes(aux, 1, 2)
            S_aux[:, np.arange(r), np.arange(r)] += 1.0
            gain -= _logdet_spd(S_aux)
    return gain


def _position_gains(state: DesignState, rows: np.ndarray, W: np.ndarray) -> np.ndarray:
    A = rows @ state.M_inv
    S = np.eye(rows.shape[1]) + A @ np.swapaxes(rows, 1, 2)
    B = A @ W @ np.swapaxes(A, 1, 2)
    return np.trace(np.linalg.solve(S, B), axis1=1, axis2=2)


def _gain_function(criterion: str, info: Information) -> Callable[[DesignState, np.ndarray], np.ndarray]:
    aux = info.rows[:, :, info.n_params :]
    aux_gram = np.swapaxes(aux, 1, 2) @ aux if 0 < aux.shape[2] < aux.shape[1] else None
    if criterion == "d-optimal":
        return lambda state, idx: _d_gains(state, info.rows[idx], None if aux_gram is None else aux_gram[idx])
    if criterion == "position":
        W = info.region.T @ info.region
        return lambda state, idx: _position_gains(state, info.rows[idx], W)
    index = criterion.upper()

    def short_list(state: DesignState, idx: np.ndarray) -> np.ndarray:
        d = _d_gains(state, info.rows[idx], None if aux_gram is None else aux_gram[idx])
        gains = np.full(len(idx), -np.inf)
        for k in np.argsort(-d)[:SHORT_LIST]:
            J = info.rows[idx[k]]
            rows = len(state.chosen) + 1
            gains[k] = observability(state.M + J.T @ J, info, rows * info.rows.shape[1])[index]
        return gains

    return short_list


def plan_design(
    info: Information,
    n: int,
    criterion: str,
    max_passes: int = 4,
    progress: Callable[[str], None] | None = None,
    greedy_order: list[int] | None = None,
    start: list[int] | None = None,
) -> tuple[list[int], list[int]]:
    """The chosen candidate indices (n), and the greedy order (the prefix of any length is
    the greedy design of that length). ``greedy_order``: a longer greedy order of the same
    criterion, whose prefix is then the start (the same additions, not recomputed). ``start``:
    a design of n to exchange from instead of the greedy one (the greedy order returned is then
    that design)."""
    if criterion not in CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}; expected one of {CRITERIA}")
    gains = _gain_function(criterion, info)
    all_idx = np.arange(len(info.rows))
    state = DesignState.empty(info)
    for k in range(n):
        if start is not None:
            state.add(start[k])
            continue
        if greedy_order is not None and k < len(greedy_order):
            state.add(greedy_order[k])
            continue
        g = gains(state, all_idx)
        g[state.chosen] = -np.inf
        state.add(int(np.argmax(g)))
    greedy = list(state.chosen)
    for pass_ in range(max_passes):
        state.refresh()
        swaps = 0
        for slot in range(n):
            current = state.chosen[slot]
            state.remove(current)
            g = gains(state, all_idx)
            g[state.chosen] = -np.inf
            best = int(np.argmax(g))
            # Evaluated on its own: a short-list criterion may not have looked at it.
            stay = float(gains(state, np.array([current]))[0])
            if best != current and g[best] > stay + 1e-9 * max(1.0, abs(stay)):
                swaps += 1
            else:
                best = current
            state.add(best)
            # add() appends: keep the slot order so the loop visits every design point once.
            state.chosen.insert(slot, state.chosen.pop())
        if progress:
            progress(f"  exchange pass {pass_ + 1}: {swaps} swaps")
        if swaps == 0:
            break
    return list(state.chosen), greedy


def information_of(info: Information, chosen: list[int] | np.ndarray) -> np.ndarray:
    rows = info.rows[np.asarray(chosen, dtype=int)].reshape(-1, info.rows.shape[2])
    return info.prior_matrix + rows.T @ rows


def predicted_sigma(info: Information, M: np.ndarray) -> float:
    """RMS (m) over the region of the scored point's predicted error norm (gauge removed)."""
    covariance = np.linalg.inv(M)
    return float(np.sqrt(np.einsum("ij,jk,ik->", info.region, covariance, info.region) / info.n_region))


def criterion_value(info: Information, chosen: list[int], criterion: str) -> float:
    """The criterion of a design, larger is better: log det of the parameters' information with
    the auxiliary unknowns eliminated (d-optimal), minus the mean predicted variance over the
    region (position), or the index (o1..o5)."""
    M = information_of(info, chosen)
    m = info.n_params
    if criterion == "d-optimal":
        return float(np.linalg.slogdet(M)[1] - np.linalg.slogdet(M[m:, m:])[1])
    if criterion == "position":
        return -float(np.trace(info.region.T @ info.region @ np.linalg.inv(M)))
    return observability(M, info, len(chosen) * info.rows.shape[1])[criterion.upper()]


def with_repeats(info: Information, chosen: list[int], labels: list[str], minimum: int, criterion: str) -> list[int]:
    """The design with every label (a point touched) chosen ``minimum`` times or not at all:
    the configurations of a label chosen fewer times are replaced, one by one, by the best
    candidates of labels already chosen often enough."""
    counts: dict[str, int] = {}
    for c in chosen:
        counts[labels[c]] = counts.get(labels[c], 0) + 1
    short = {label for label, k in counts.items() if k < minimum}
    if not short:
        return chosen
    gains = _gain_function(criterion, info)
    state = DesignState.empty(info)
    for c in chosen:
        if labels[c] not in short:
            state.add(c)
    allowed = np.array([i for i in range(len(labels)) if labels[i] in counts and labels[i] not in short])
    while len(state.chosen) < len(chosen):
        g = gains(state, allowed)
        g[np.isin(allowed, state.chosen)] = -np.inf
        state.add(int(allowed[int(np.argmax(g))]))
    return list(state.chosen)
