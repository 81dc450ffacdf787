"""Factors of a robot measuring itself by contact: balls on the tips of a tree (the contact
elements: a centre on its tip and a radius) touch each other (self-contact) or unknown planes
of the cell (a table, a wall). No instrument reads anything: a contact says that a distance
is zero. The chain closes through the tree (two arms meeting in the torso) or through the
planes every contact shares."""

from __future__ import annotations

import numpy as np

from .base import Evaluation, MeasurementSet, RobustLoss, point_jacobian
from .kinematics import Kinematics, params_variable


def _element_blocks(
    n_rows: int, elements: np.ndarray, per_row: np.ndarray, n_elements: int, width: int = 3
) -> np.ndarray:
    """(rows, width * n_elements): row o gets ``per_row[o]`` (width,) at element ``elements[o]``."""
    block = np.zeros((n_rows, width * n_elements))
    rows = np.arange(n_rows)
    for axis in range(width):
        np.add.at(block, (rows, width * elements + axis), per_row[:, axis])
    return block


def plane_normals(planes: np.ndarray, nominal: np.ndarray, bases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals n_k = (n0_k + B_k a_k) / |n0_k + B_k a_k| of planes (K, 3) = (a1, a2, d) rows,
    and dn_k/da_k (K, 3, 2). ``nominal`` (K, 3) unit normals, ``bases`` (K, 3, 2) orthonormal
    bases of their orthogonal complements: a chart without singularity near the nominal."""
    m = nominal + np.einsum("kij,kj->ki", bases, planes[:, :2])
    length = np.linalg.norm(m, axis=1)
    n = m / length[:, None]
    projector = np.eye(3) - n[:, :, None] * n[:, None, :]
    return n, np.einsum("kij,kjl->kil", projector / length[:, None, None], bases)


def complement_basis(normal: np.ndarray) -> np.ndarray:
    """(3, 2) orthonormal basis of the plane orthogonal to the unit ``normal``."""
    normal = np.asarray(normal, dtype=float)
    helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1)
    return np.column_stack([e1, np.cross(normal, e1)])


class SelfContacts(MeasurementSet):
    """``r_o = |X_a(P, q_j) c_ea - X_b(P, q_j) c_eb| - (rho_ea + rho_eb)``  (m), per contact o.

    At configuration j ball ea (centre c_ea on its tip a, radius rho_ea) touches ball eb on tip b;
    X_a, X_b are the tips' poses in W from the kinematics (rows ``rows_a``, ``rows_b`` of its
    frame-major poses). The centres are one vector variable C = (c_0, c_1, ...), the radii one
    vector variable (or constants, ``radii``). The robust unit is one contact.
    """

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        centres_key: int,
        radii_key: int | None,
        n_elements: int,
        rows_a: np.ndarray,
        rows_b: np.ndarray,
        elements_a: np.ndarray,
        elements_b: np.ndarray,
        sigma_m: float,
        robust: RobustLoss | None = None,
        radii: np.ndarray | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.rows_a, self.rows_b = np.asarray(rows_a, dtype=int), np.asarray(rows_b, dtype=int)
        self.elements_a, self.elements_b = np.asarray(elements_a, dtype=int), np.asarray(elements_b, dtype=int)
        if not len(self.rows_a) or len({len(self.rows_a), len(self.rows_b), len(self.elements_a),
                                        len(self.elements_b)}) != 1:  # fmt: skip
            raise ValueError("two tips' rows and two elements per contact, at least one contact")
        if np.any(self.elements_a == self.elements_b):
            raise ValueError("a contact joins two different elements")
        if (radii_key is None) == (radii is None):
            raise ValueError("the radii are a variable or constants, one of the two")
        self.n_elements = int(n_elements)
        self.radii_key = radii_key
        self.radii = None if radii is None else np.asarray(radii, dtype=float)
        self.variables = [*params_variable(params_key, kinematics), (centres_key, "vector", 3 * self.n_elements)]
        if radii_key is not None:
            self.variables.append((radii_key, "vector", self.n_elements))
        self.sigma = np.full(len(self.rows_a), float(sigma_m))
        self.unit_starts = np.arange(len(self.rows_a))
        self.readings = np.zeros(len(self.rows_a))  # a gauge's (TipDistances)
        # The configuration of each contact (scores), when the rows are frame-major.
        self.configs = self.rows_a % len(kinematics.q) if hasattr(kinematics, "q") else self.rows_a
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        params = inputs[0] if self.params_key is not None else None
        at = 1 if self.params_key is not None else 0
        centres = np.asarray(inputs[at], dtype=float).reshape(-1, 3)
        radii = np.asarray(inputs[at + 1], dtype=float) if self.radii_key is not None else self.radii
        poses = self.kinematics.poses(params)
        T_a, T_b = poses[self.rows_a], poses[self.rows_b]
        c_a, c_b = centres[self.elements_a], centres[self.elements_b]
        p_a = np.einsum("oij,oj->oi", T_a[:, :3, :3], c_a) + T_a[:, :3, 3]
        p_b = np.einsum("oij,oj->oi", T_b[:, :3, :3], c_b) + T_b[:, :3, 3]
        delta = p_a - p_b
        length = np.linalg.norm(delta, axis=1)
        residual = length - radii[self.elements_a] - radii[self.elements_b] - self.readings
        if not jacobians:
            return Evaluation(residual, [])
        u = delta / np.maximum(length, 1e-300)[:, None]
        blocks = []
        if params is not None:
            J = self.kinematics.jacobians(params)
            d_a = np.matmul(point_jacobian(T_a[:, :3, :3], c_a), J[self.rows_a])
            d_b = np.matmul(point_jacobian(T_b[:, :3, :3], c_b), J[self.rows_b])
            blocks.append(np.einsum("oi,oij->oj", u, d_a - d_b))
        n = len(residual)
        blocks.append(
            _element_blocks(n, self.elements_a, np.einsum("oi,oij->oj", u, T_a[:, :3, :3]), self.n_elements)
            - _element_blocks(n, self.elements_b, np.einsum("oi,oij->oj", u, T_b[:, :3, :3]), self.n_elements)
        )
        if self.radii_key is not None:
            ones = -np.ones((n, 1))
            blocks.append(
                _element_blocks(n, self.elements_a, ones, self.n_elements, 1)
                + _element_blocks(n, self.elements_b, ones, self.n_elements, 1)
            )
        return Evaluation(residual, blocks)


class TipDistances(SelfContacts):
    """``r_o = |X_a(P, q_j) c_ea - X_b(P, q_j) c_eb| - L_o``  (m), per reading o.

    A gauge between two tips (a ballbar whose cups sit on ball ea of tip a and ball eb of tip b,
    or a known distance) reads L_o at configuration j: the centres, tips and rows as in
    :class:`SelfContacts` (the balls' radii do not enter). What gives a self-contained
    calibration its scale. The robust unit is one reading.
    """

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        centres_key: int,
        n_elements: int,
        rows_a: np.ndarray,
        rows_b: np.ndarray,
        elements_a: np.ndarray,
        elements_b: np.ndarray,
        readings_m: np.ndarray,
        sigma_m: float,
        robust: RobustLoss | None = None,
    ) -> None:
        readings = np.asarray(readings_m, dtype=float).reshape(-1)
        if len(readings) != len(np.atleast_1d(rows_a)):
            raise ValueError("one reading per pair of rows")
        super().__init__(kinematics, params_key, centres_key, None, n_elements, rows_a, rows_b, elements_a,
                         elements_b, sigma_m, robust, radii=np.zeros(int(n_elements)))  # fmt: skip
        self.readings = readings


class PlaneContacts(MeasurementSet):
    """``r_o = n_k . X_a(P, q_j) c_e - d_k - rho_e``  (m), per contact o.

    At configuration j ball e (centre c_e on its tip a, radius rho_e) touches plane k
    ``{x : n_k . x = d_k}`` of W from the side its normal points to. A plane is the vector
    (a1, a2, d_k), its normal ``n_k = (n0_k + B_k a) / |n0_k + B_k a|`` in the chart around its
    nominal n0_k (B_k an orthonormal basis orthogonal to it); all planes are one vector variable.
    The centres and radii as in :class:`SelfContacts`. The robust unit is one contact.
    """

    def __init__(
        self,
        kinematics: Kinematics,
        params_key: int | None,
        centres_key: int,
        radii_key: int | None,
        planes_key: int,
        n_elements: int,
        nominal_normals: np.ndarray,
        rows: np.ndarray,
        elements: np.ndarray,
        planes: np.ndarray,
        sigma_m: float,
        robust: RobustLoss | None = None,
        radii: np.ndarray | None = None,
    ) -> None:
        self.kinematics = kinematics
        self.params_key = params_key
        self.rows = np.asarray(rows, dtype=int)
        self.elements = np.asarray(elements, dtype=int)
        self.planes = np.asarray(planes, dtype=int)
        if not len(self.rows) or len({len(self.rows), len(self.elements), len(self.planes)}) != 1:
            raise ValueError("a tip's row, an element and a plane per contact, at least one contact")
        if (radii_key is None) == (radii is None):
            raise ValueError("the radii are a variable or constants, one of the two")
        self.nominal = np.asarray(nominal_normals, dtype=float).reshape(-1, 3)
        self.bases = np.array([complement_basis(n) for n in self.nominal]).reshape(-1, 3, 2)
        self.n_elements, self.n_planes = int(n_elements), len(self.nominal)
        self.radii_key = radii_key
        self.radii = None if radii is None else np.asarray(radii, dtype=float)
        self.variables = [*params_variable(params_key, kinematics), (centres_key, "vector", 3 * self.n_elements)]
        if radii_key is not None:
            self.variables.append((radii_key, "vector", self.n_elements))
        self.variables.append((planes_key, "vector", 3 * self.n_planes))
        self.sigma = np.full(len(self.rows), float(sigma_m))
        self.unit_starts = np.arange(len(self.rows))
        self.configs = self.rows % len(kinematics.q) if hasattr(kinematics, "q") else self.rows
        super().__init__(robust)

    def compute(self, inputs: list, jacobians: bool) -> Evaluation:
        params = inputs[0] if self.params_key is not None else None
        at = 1 if self.params_key is not None else 0
        centres = np.asarray(inputs[at], dtype=float).reshape(-1, 3)
        radii = np.asarray(inputs[at + 1], dtype=float) if self.radii_key is not None else self.radii
        planes = np.asarray(inputs[-1], dtype=float).reshape(-1, 3)
        normals, d_normals = plane_normals(planes, self.nominal, self.bases)
        T = self.kinematics.poses(params)[self.rows]
        c = centres[self.elements]
        p = np.einsum("oij,oj->oi", T[:, :3, :3], c) + T[:, :3, 3]
        n = normals[self.planes]
        residual = np.sum(n * p, axis=1) - planes[self.planes, 2] - radii[self.elements]
        if not jacobians:
            return Evaluation(residual, [])
        blocks = []
        rows = len(residual)
        if params is not None:
            J = self.kinematics.jacobians(params)[self.rows]
            blocks.append(np.einsum("oi,oij->oj", n, np.matmul(point_jacobian(T[:, :3, :3], c), J)))
        blocks.append(_element_blocks(rows, self.elements, np.einsum("oi,oij->oj", n, T[:, :3, :3]), self.n_elements))
        if self.radii_key is not None:
            blocks.append(_element_blocks(rows, self.elements, -np.ones((rows, 1)), self.n_elements, 1))
        per_plane = np.column_stack([np.einsum("oi,oij->oj", p, d_normals[self.planes]), -np.ones(rows)])
        blocks.append(_element_blocks(rows, self.planes, per_plane, self.n_planes))
        return Evaluation(residual, blocks)
