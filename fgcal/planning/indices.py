"""Observability indices of a design, from the singular values s_1 >= .. >= s_m of the
parameters' whitened Jacobian, each column scaled by its parameter's plausible deviation and
the auxiliary unknowns eliminated (the singular values are the square roots of the
eigenvalues of that Schur complement). L is the number of measurement rows.

- O1 (Borm and Menq): ``(s_1 s_2 .. s_m)^(1/m) / sqrt(L)``: the volume of the error ellipsoid;
- O2 (Driels and Pathre): ``s_m / s_1``: the inverse condition number;
- O3 (Nahvi and Hollerbach): ``s_m``: the worst-determined direction;
- O4 (Nahvi and Hollerbach): ``s_m^2 / s_1``: the noise amplification index;
- O5 (Sun and Hollerbach): ``1 / sum 1/s_i``: A-optimality on the singular values.
"""

from __future__ import annotations

import numpy as np

from .information import Information


def observability(M: np.ndarray, info: Information, n_rows: int, with_prior: bool = True) -> dict[str, float]:
    """Indices O1..O5 and the condition number of information ``M`` (prior included in M;
    ``with_prior=False`` takes the parameters' prior out again, so that the indices
    describe the measurements alone)."""
    m = info.n_params
    schur = M[:m, :m] - M[:m, m:] @ np.linalg.solve(M[m:, m:], M[m:, :m])
    if not with_prior:
        schur = schur - np.diag(info.prior[:m])
    scaled = schur * np.outer(info.scale, info.scale)
    eigen = np.clip(np.linalg.eigvalsh(scaled), 0.0, None)
    s = np.sqrt(eigen[::-1])
    s_min, s_max = float(s[-1]), float(s[0])
    with np.errstate(divide="ignore"):
        return {
            "O1": float(np.exp(np.mean(np.log(np.maximum(s, 1e-300)))) / np.sqrt(max(n_rows, 1))),
            "O2": s_min / s_max if s_max > 0 else 0.0,
            "O3": s_min,
            "O4": s_min**2 / s_max if s_max > 0 else 0.0,
            "O5": float(1.0 / np.sum(1.0 / np.maximum(s, 1e-300))),
            "condition_number": s_max / s_min if s_min > 0 else float("inf"),
        }
