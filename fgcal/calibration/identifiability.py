"""Which parameters the data determine, found numerically before solving.

From the whitened measurement Jacobian at the initial estimate (auxiliary unknowns such as
the tracker pose projected out), columns scaled by each parameter's plausible deviation are selected greedily
(Gram-Schmidt with pivoting) in priority order: DH (theta, d, a, alpha), then axis
distortions, compliances, the motion history's terms, tool, base. A column whose information, after projecting out the
columns already selected, is below ``min_information`` (1 = its standard deviation would
exceed its plausible deviation) is unidentifiable: it is fixed at its current value and
reported with the selected parameters it is (nearly) a combination of.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from ..model.parameters import (
    COMPLIANCE_KINDS,
    MASS_KIND,
    MOTION_KINDS,
    is_mass,
    is_motion,
    kind_label,
    moment_column,
    split_name,
)
from .graph import StageGraph
from .priors import Priors

# A fixed frame's perturbation comes first: where it duplicates the row after it (theta, d, sx,
# sy of a DH row), the frame, the mount a robot file names as uncertain, keeps the deviation.
GROUPS = (
    ("frame",),
    ("theta", "d", "a", "alpha", "tx", "ty", "tz", "rx", "ry", "rz"),
    ("sx", "sy"),
    ("kx", "ky", "kz", "kc"),
    (MASS_KIND,),
    ("lm", "lv"),
    ("tool",),
    ("base",),
)
# Plausible deviations: m, rad; a joint's lost motion is hundredths of a degree.
SCALE = {"length": 1e-2, "angle": 1e-2, "motion": 1e-3, "mass": 0.1}


@dataclass
class Identifiability:
    identifiable: list[str]
    unidentifiable: dict[str, str]  # name -> reason
    singular_values: np.ndarray  # of the scaled, whitened Jacobian of the identifiable set
    condition_number: float
    n_rows: int
    # Fixed parameter -> the identifiable ones it is (mostly) a combination of: their estimates
    # absorb its deviation, so they are effective values.
    absorbed_by: dict[str, list[str]] = field(default_factory=dict)


def parameter_scale(name: str, moments_rms: np.ndarray) -> float:
    """Plausible deviation of a parameter: 1 cm for lengths, 10 mrad for angles and, for a
    compliance, the value that deflects its joint by 10 mrad at the RMS gravity moment of
    its component over the data (so the scale suits a 3 kg arm and a 125 kg arm alike)."""
    kind, _ = split_name(name)
    if kind in COMPLIANCE_KINDS:
        moment = moments_rms[moment_column(name)]
        return SCALE["angle"] / max(float(moment), 1e-9)
    if kind in ("d", "a", "tx", "ty", "tz"):
        return SCALE["length"]
    if kind in MOTION_KINDS:
        return SCALE["motion"]
    if kind == MASS_KIND:
        return SCALE["mass"]
    return SCALE["angle"]


def group_of(name: str) -> int:
    label = kind_label(name)
    return next(i for i, group in enumerate(GROUPS) if label in group)


def aux_blocks(stage: StageGraph) -> dict[str, slice]:
    """Each auxiliary unknown's columns in reduced_jacobian's (rows x n_aux) block, by name."""
    blocks, offset = {}, 0
    for name, (_, dim) in stage.dims.items():
        if name != "P":
            blocks[name] = slice(offset, offset + dim)
            offset += dim
    return blocks


def reduced_jacobian(stage: StageGraph) -> tuple[np.ndarray, np.ndarray]:
    """Whitened Jacobians of the measurement residuals (no robust loss) w.r.t. the released
    parameters and the auxiliary unknowns, at the stage's values: (rows x m), (rows x n_aux)."""
    J_p, J_aux, _ = whitened_system(stage, robust=False)
    return J_p, J_aux


def whitened_system(stage: StageGraph, robust: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stage's whitened measurement rows at its values (through the robust loss if
    ``robust``): the Jacobians w.r.t. the released parameters (rows x m) and the auxiliary
    unknowns (rows x n_aux, in aux_blocks' order), and the residuals (rows,)."""
    blocks = aux_blocks(stage)
    columns = {stage.dims[name][0]: block for name, block in blocks.items()}
    # Filled in place: the stacked Jacobian is the largest array of the analysis.
    n_rows = sum(measurements.n_rows for measurements in stage.measurements)
    J_p = np.zeros((n_rows, stage.kinematics.n_released))
    J_aux = np.zeros((n_rows, sum(block.stop - block.start for block in blocks.values())))
    b = np.zeros(n_rows)
    first = 0
    for measurements in stage.measurements:
        evaluation = measurements.whitened(measurements.read(stage.values), True, robust=robust)
        rows = slice(first, first + measurements.n_rows)
        b[rows] = evaluation.residual
        for block, (key, _, _) in zip(evaluation.blocks, measurements.variables, strict=True):
            if key == stage.keys.params:
                J_p[rows] += block
            else:
                J_aux[rows, columns[key]] += block
        first = rows.stop
    return J_p, J_aux, b


def analyse(stage: StageGraph, min_information: float = 1.0, priors: Priors | None = None) -> Identifiability:
    """The selection on the stage's released parameters. The priors a config states are
    information as the measurements are (a whitened row 1/sigma on its parameter's column), so a
    direction the data leave weak can be determined by a stated prior, as a ridge term does."""
    J_p, J_aux = reduced_jacobian(stage)
    kinematics = stage.kinematics
    moments = kinematics.data(kinematics.base[kinematics.index]).moments
    _mass_columns_with_compliance(stage, J_p, moments)
    # What select needs is in hand: the evaluations cached for the graph (tens of MB at
    # thousands of configurations) need not outlive it through select's own arrays.
    stage.forget()
    stated = {} if priors is None else {i: priors.stated(n) for i, n in enumerate(stage.released)}
    stated = {i: sigma for i, sigma in stated.items() if sigma is not None}
    if stated:
        rows = np.zeros((len(stated), J_p.shape[1]))
        rows[np.arange(len(stated)), list(stated)] = 1.0 / np.array(list(stated.values()))
        J_p = np.vstack([J_p, rows])
        J_aux = np.vstack([J_aux, np.zeros((len(stated), J_aux.shape[1]))])
    return select(J_p, J_aux, stage.released, moments, min_information, aux_blocks(stage))


def _mass_columns_with_compliance(stage: StageGraph, J_p: np.ndarray, moments: np.ndarray) -> None:
    """A mass scale moves the robot only through the compliances: at zero compliance (the
    nominal start) its column is zero whatever the data. Its columns and the compliances' are
    taken where each released compliance still at zero has its plausible value instead (a 10
    mrad deflection): at one point, so that a mass scale of every body is exactly the
    combination of the compliances it is (k mu t is one product); the geometry's columns stay
    at the start."""
    released = stage.released
    masses = [i for i, name in enumerate(released) if is_mass(name)]
    if not masses or stage.keys.params is None:
        return
    values = np.array(stage.values.atVector(stage.keys.params), dtype=float)
    moments_rms = np.sqrt(np.mean(moments**2, axis=0))
    compliances = [i for i, name in enumerate(released) if split_name(name)[0] in COMPLIANCE_KINDS]
    for i in compliances:
        if values[i] == 0.0:
            values[i] = parameter_scale(released[i], moments_rms)
    trial = gtsam.Values(stage.values)
    trial.update(stage.keys.params, values)
    J_trial, _ = reduced_jacobian(replace(stage, values=trial))
    J_p[:, masses + compliances] = J_trial[:, masses + compliances]


def select(
    J_p: np.ndarray,
    J_aux: np.ndarray,
    names: list[str],
    moments: np.ndarray,
    min_information: float,
    aux: dict[str, slice] | None = None,
) -> Identifiability:
    """The pivoted Gram-Schmidt selection on whitened Jacobians (rows x m) and (rows x n_aux),
    the auxiliary unknowns projected out; ``moments`` (N, 3n) are the gravity moments over
    the data, for the compliances' plausible deviations; ``aux`` names the auxiliary unknowns'
    columns (a parameter they absorb is reported as absorbed by them, not as without effect)."""
    moments_rms = np.sqrt(np.mean(moments**2, axis=0))
    scales = np.array([parameter_scale(n, moments_rms) for n in names])
    before_aux = np.linalg.norm(J_p, axis=0) * scales  # each column's information on its own
    absorbing = _absorbing(J_p * scales[None, :], J_aux, aux or {}, before_aux, min_information)
    if J_aux.shape[1]:
        Q, R = np.linalg.qr(J_aux)
        keep = np.abs(np.diag(R)) > 1e-9 * max(1.0, np.abs(np.diag(R)).max())
        Q = Q[:, keep]
        J_p = J_p - Q @ (Q.T @ J_p)
    scaled = J_p * scales[None, :]
    columns = np.zeros((scaled.shape[0], scaled.shape[1]))  # the basis, filled column by column
    selected: list[int] = []
    rejected: list[int] = []
    for group in range(len(GROUPS)):
        members = [i for i, n in enumerate(names) if group_of(n) == group]
        while members:
            basis = columns[:, : len(selected)]
            residual = scaled[:, members] - basis @ (basis.T @ scaled[:, members])
            norms = np.linalg.norm(residual, axis=0)
            # Ties (equivalent columns, such as a link length before and after a coupled joint)
            # go to the first in priority order, so that rounding at 1e-16 cannot flip the choice.
            best = int(np.flatnonzero(norms >= (1.0 - 1e-9) * norms.max())[0])
            if norms[best] < min_information:
                rejected += members
                break
            columns[:, len(selected)] = residual[:, best] / norms[best]
            selected.append(members.pop(best))
    # Each column may be determined alone and a direction of several still not: the common scale
    # of all lengths and touched points when nothing measures a length. A direction is weak, not
    # a parameter: while the weakest direction of the selected set is below min_information, the
    # parameter among those spanning it (weighing at least half the most) that the other selected
    # columns explain best (least information of its own left) is fixed; ties go to the lowest in
    # priority. After each such change the parameters rejected so far are reconsidered, in
    # priority order: one that no longer makes any direction weak is selected again.
    def weakest(indices: list[int]) -> tuple[float, np.ndarray]:
        # The singular values and right vectors of A are those of its R (A = QR): no rows x k U.
        _, singular, Vt = np.linalg.svd(np.linalg.qr(scaled[:, indices], mode="r"), full_matrices=False)
        return float(singular[-1]), np.abs(Vt[-1])

    while selected:
        smallest, weights = weakest(selected)
        if smallest >= min_information:
            break
        spanning = [k for k in range(len(selected)) if weights[k] >= 0.5 * weights.max()]
        left = []
        for k in spanning:
            others = scaled[:, [s for j, s in enumerate(selected) if j != k]]
            column = scaled[:, selected[k]]
            if others.shape[1]:
                coefficients = np.linalg.lstsq(others, column, rcond=None)[0]
                column = column - others @ coefficients
            left.append(float(np.linalg.norm(column)))
        best = min(left)
        drop = [k for k, value in zip(spanning, left, strict=True) if value <= best * (1.0 + 1e-9)][-1]
        rejected.append(selected.pop(drop))
        for i in sorted(rejected, key=lambda i: (group_of(names[i]), i)):
            if i == rejected[-1] or np.linalg.norm(scaled[:, i]) < min_information:
                continue
            if weakest([*selected, i])[0] >= min_information:
                selected.append(i)
                rejected.remove(i)
    unidentifiable: dict[str, str] = {}
    absorbed_by: dict[str, list[str]] = {}
    kept = scaled[:, selected]
    for i in rejected:
        column = scaled[:, i]
        information = float(np.linalg.norm(column))
        if information < min_information and i in absorbing:
            unidentifiable[names[i]] = (
                f"absorbed by {absorbing[i]} (information {before_aux[i]:.2g} alone, {information:.2g} beside it)"
            )
            continue
        if information < min_information:
            unidentifiable[names[i]] = f"no effect on the measurements (information {information:.2g})"
            continue
        coefficients = np.linalg.lstsq(kept, column, rcond=None)[0] if selected else np.zeros(0)
        partners = sorted(zip(coefficients, [names[s] for s in selected], strict=True), key=lambda c: -abs(c[0]))
        described = ", ".join(f"{c:+.3g} {n}" for c, n in partners[:3] if abs(c) > 0.05)
        absorbed_by[names[i]] = [n for c, n in partners[:3] if abs(c) > 0.05]
        rest = float(np.linalg.norm(column - kept @ coefficients)) if selected else information
        unidentifiable[names[i]] = (
            f"a combination of other parameters ({described or 'several'}); information left {rest:.2g}"
        )
    if selected:
        singular = np.linalg.svd(np.linalg.qr(scaled[:, selected], mode="r"), compute_uv=False)
        condition = float(singular[0] / singular[-1])
    else:
        singular, condition = np.zeros(0), float("inf")
    order = [names[i] for i in sorted(selected)]
    return Identifiability(order, unidentifiable, singular, condition, scaled.shape[0], absorbed_by)


def _absorbing(
    scaled: np.ndarray, J_aux: np.ndarray, aux: dict[str, slice], alone: np.ndarray, min_information: float
) -> dict[int, str]:
    """Columns that carry information alone but (nearly) none once the auxiliary unknowns are
    projected out -> the unknowns that take them (each explaining at least half the column; else
    all of them together): a tracker's pose takes the base, reflector positions the tool."""
    out = {}
    if not aux:
        return out
    bases = {}
    for name, columns in aux.items():
        Q, R = np.linalg.qr(J_aux[:, columns])
        diagonal = np.abs(np.diag(R))
        bases[name] = Q[:, diagonal > 1e-9 * max(1.0, diagonal.max())] if diagonal.size else Q
    for i in np.flatnonzero(alone >= min_information):
        column = scaled[:, i]
        takers = [
            name for name, Q in bases.items() if np.linalg.norm(Q.T @ column) >= 0.5 * alone[i]
        ]
        out[int(i)] = ", ".join(takers) if takers else "the auxiliary unknowns together"
    return out


def motion_warning(identifiability: Identifiability) -> str | None:
    """What a design that cannot separate the motion history's terms from the joint offsets
    must be told (fgcal.model.motion): every configuration was reached the same way."""
    hidden = [n for n in identifiability.unidentifiable if is_motion(n)]
    if not hidden:
        return None
    # A term whose joint the data barely see (its offset fixed too, or no effect of its own) is
    # not hidden by how the robot moved: more motion would not show it, more of that joint would.
    unseen_joints = {split_name(n)[1] for n in identifiability.unidentifiable if split_name(n)[0] == "theta"}
    unseen = [
        n for n in hidden
        if split_name(n)[1] in unseen_joints or not identifiability.unidentifiable[n].startswith("a combination")
    ]  # fmt: skip
    same_way = [n for n in hidden if n not in unseen]
    parts = []
    if same_way:
        absorbing = sorted({p for n in same_way for p in identifiability.absorbed_by.get(n, [])})
        into = f" (their effect is absorbed by {', '.join(absorbing)})" if absorbing else ""
        parts.append(
            f"the motion-history terms {', '.join(same_way)} cannot be told apart from the joint offsets{into}: the "
            "configurations were reached the same way (approached from one side, at one speed). They stay at zero, "
            "and the calibration holds only for moves made the same way; to identify them, reach configurations "
            "from both sides and at different speeds (docs/calibration.md, Motion history)"
        )
    if unseen:
        joints = sorted({int(split_name(n)[1]) for n in unseen})
        parts.append(
            f"the motion-history terms {', '.join(unseen)} stay at zero because the data barely see joint"
            f"{'s' if len(joints) > 1 else ''} {', '.join(map(str, joints))} at all (its own parameters are fixed "
            "too): measure points farther from its axis, not other approaches"
        )
    return "; ".join(parts)


# A parameter fixed as unidentifiable that a fit releasing it would move by more than this many
# sigmas is fixed against the data's evidence: the headline says so.
EVIDENCE_SIGMAS = 10.0


def evidence_against_fixing(
    stage: StageGraph, fixed: list[str], variance_factor: float, min_information: float
) -> dict[str, float]:
    """For each parameter of ``fixed`` (released in ``stage`` beside the estimated ones, at the
    solution), how many sigmas a fit that also released it would move it: one Gauss-Newton step
    of the whitened (robust) residuals b on its column a, the auxiliary unknowns and the other
    released parameters projected out (P): z = |r.b| / |r| / sqrt(variance_factor), r = (I - P) a.
    The variance factor is the fit's (chi2/dof where the declared noise does not fit the
    residuals, either way), as the report's sigmas are: an over-declared noise hides no evidence.
    Only a parameter the fit would determine is judged: its information at the fit's noise level,
    |r| times its plausible deviation over sqrt(variance_factor), at least ``min_information``. A
    direction the others (nearly) reproduce, such as a base tilt the tracker's pose takes but for
    the gravity it turns, has no evidence either way (omitted): z of a vanishing |r| is noise."""
    J_p, J_aux, b = whitened_system(stage, robust=True)
    n_rows = len(b)
    kinematics = stage.kinematics
    moments = kinematics.data(kinematics.base[kinematics.index]).moments
    moments_rms = np.sqrt(np.mean(moments**2, axis=0))
    stage.forget()
    index = {name: i for i, name in enumerate(stage.released)}
    others = np.hstack([J_aux, J_p[:, [index[n] for n in stage.released if n not in fixed]]])
    Q = np.zeros((n_rows, 0))
    if others.shape[1]:  # an orthonormal basis of what the others span (dependent columns dropped)
        Q, R = np.linalg.qr(others)
        diagonal = np.abs(np.diag(R))
        Q = Q[:, diagonal > 1e-9 * max(1.0, diagonal.max())]
    out = {}
    for name in fixed:
        column = J_p[:, index[name]]
        r = column - Q @ (Q.T @ column)
        size = float(np.linalg.norm(r))
        if size * parameter_scale(name, moments_rms) / np.sqrt(variance_factor) < min_information:
            continue
        out[name] = abs(float(r @ b)) / size / np.sqrt(variance_factor)
    return out
