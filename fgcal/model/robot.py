"""The robot description: a constant model (geometry, masses, base and tool poses) and
the elementary transform chain built from it (SPEC section 2).

Per-evaluation quantities live in :mod:`fgcal.model.kinematics`; this module holds nothing that
changes between evaluations. A robot's chain and its compiled model (fgcal.model.chain_model:
every constant table the evaluations read) are built once per robot, at its first evaluation.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from ..core.errors import InputError
from . import chain_model, kinematics
from .chain_model import ChainModel
from .ets import ET, Chain
from .ik import IKResult, inverse_kinematics
from .joints import DHJoint, Joint, perturbation_elements, pose_elements
from .parameters import COUPLED_COMPLIANCE, FRAME, FRAME_LABEL, MASS_KIND, parameter_names

# Each model adds terms to the one before: axis distortions (s), gravity compliances (e) and
# the motion history's joint offsets (h: lost motion and the speed term, fgcal.model.motion).
MODELS = ("DH", "DH,s", "DH,s,e", "DH,s,e,h")
# A calibration moves the flange by millimetres: two models whose flanges are farther apart
# than this (Robot.flange_gap_m) are two robots.
SAME_ROBOT_M = 0.05


FK_CHUNK = 4096  # configurations per forward pass of Robot.fk (a pass keeps every link's frames)


@dataclass(frozen=True)
class Robot:
    """Constant description of a serial robot (SI units).

    ``joints`` are the joint geometries (fgcal.model.joints: DH rows or URDF-style origins and
    axes), base to flange; ``coms`` the centres of mass of the links in their own frames
    (m: the frame after joint i's link); ``base_pose`` the nominal ``T_W_0``,
    ``flange_pose`` the flange in the last link's frame (identity for DH; the tip link of a
    URDF) and ``tool_pose`` the nominal ``T_n_C`` (flange to tool or camera). ``urdf``: the
    URDF file and tip link of a robot that came from one (fgcal export writes that document
    back with the calibrated joint origins). ``region``: configurations of a calibrated robot's
    fitting data, where its model is known best (program filtering and rigid fits use them).
    """

    name: str
    joints: tuple[Joint, ...]
    directions: np.ndarray
    limits: np.ndarray
    masses: np.ndarray
    coms: np.ndarray
    payload_mass: float = 0.0
    payload_com: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gravity: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, -9.81]))
    base_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    tool_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    flange_pose: np.ndarray = field(default_factory=lambda: np.eye(4))
    overrides: Mapping[str, float] = field(default_factory=dict)
    source: str = ""
    model: str = "DH,s,e"
    urdf: tuple[str, str] | None = None  # the URDF (file, tip link) the description came from
    region: np.ndarray | None = None  # (K, n) configurations a calibration was fitted on (rad, m)
    # A tree (fgcal.model.ets): the joint whose link each joint hangs from (-1: the base; None: a
    # serial chain, each from the one before), the joint the flange hangs from (None: the
    # last), and further named frames: (name, joint it hangs from or -1, pose in that link).
    parents: tuple[int, ...] | None = None
    flange_joint: int | None = None
    tips: tuple[tuple[str, int, np.ndarray], ...] = ()
    flange_name: str = "flange"  # the flange's name among the tips (a URDF's tip link)
    # Coupled joints, which the controller does not move on their own (a parallelogram, a
    # torso's last joint): (joint, ((joint it follows, coefficient), ...), offset rad or m), so
    # that q_k = sum_i c_i q_i + c_0. ``joints``, ``masses`` and ``coms`` count them;
    # ``directions``, ``limits`` and joint values do not.
    coupled: tuple[tuple[int, tuple[tuple[int, float], ...], float], ...] = ()
    # Body groups whose masses are scaled by a parameter mass.{name}: (name, joints whose
    # links are the group's bodies).
    mass_groups: tuple[tuple[str, tuple[int, ...]], ...] = ()
    # The controller's joints' speed and effort limits, (moved, 2): rad/s (m/s) and N m (N), NaN
    # where the robot file states none (None: none stated). Written to URDF, not used in fitting.
    ratings: np.ndarray | None = None
    # Fixed frames (issue 40): (name, joint, pose) a constant transform T (4x4, m) between joint's
    # parent link and its row, with the six parameters frame.{name}.*; ``calibrated_tips`` the tips
    # whose poses have them too (frame.{tip}.*).
    fixed_frames: tuple[tuple[str, int, np.ndarray], ...] = ()
    calibrated_tips: tuple[str, ...] = ()
    # Compliances: the joints whose deflection turns about their parent's axes, at the frame their
    # row starts from (DLR's model), instead of about the bending frame after their motion; and
    # coupled compliances (joint, joint whose z moment drives it, both 0-based): parameter kc{joint}.
    parent_axis: tuple[int, ...] = ()
    compliance_coupling: tuple[tuple[int, int], ...] = ()
    # Loads beyond the flange's payload: (tip, mass kg, centre of mass in the tip's frame, m) and
    # fixed bodies (name, joint whose link carries it or -1 the base, mass kg, centre of mass in
    # that link's frame, m).
    tip_payloads: tuple[tuple[str, float, np.ndarray], ...] = ()
    fixed_bodies: tuple[tuple[str, int, float, np.ndarray], ...] = ()

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"unknown model {self.model!r}; expected one of {MODELS}")
        n = len(self.joints)
        if n == 0:
            raise ValueError("a robot needs at least one joint")
        followers = [k for k, _, _ in self.coupled]
        for k, sources, _ in self.coupled:
            if not 0 <= k < n or not sources or any(s in followers or not 0 <= s < n for s, _ in sources):
                raise ValueError(f"coupled joint {k + 1}: it follows joints the controller moves, of the robot's {n}")
        if len(set(followers)) != len(followers) or len(followers) >= n:
            raise ValueError("each joint is coupled once, and at least one joint is not")
        for group, members in self.mass_groups:
            if not members or any(not 0 <= b < n for b in members):
                raise ValueError(f"mass group {group!r}: the joints of its bodies, of the robot's {n}")
        moved = n - len(followers)
        for name, arr, shape in (
            ("directions", self.directions, (moved,)),
            ("limits", self.limits, (moved, 2)),
            ("masses", self.masses, (n,)),
            ("coms", self.coms, (n, 3)),
            *((("ratings", self.ratings, (moved, 2)),) if self.ratings is not None else ()),
        ):
            if np.shape(arr) != shape:
                raise ValueError(f"{name} has shape {np.shape(arr)}, expected {shape}")
        unknown = set(self.overrides) - set(self.parameter_names)
        if unknown:
            raise ValueError(f"unknown parameter names: {sorted(unknown)}")
        parents = self.parents
        if parents is not None and (len(parents) != n or any(not -1 <= p < i for i, p in enumerate(parents))):
            raise ValueError("each joint hangs from an earlier joint (or -1, the base)")
        hangs = [j for _, j, _ in self.tips] + ([] if self.flange_joint is None else [self.flange_joint])
        if any(not -1 <= j < n for j in hangs):
            raise ValueError(f"a tip hangs from a joint the robot does not have (0 to {n - 1}, or -1)")
        names = [name for name, _, _ in self.tips] + [self.flange_name]
        if len(set(names)) != len(names):
            raise ValueError(f"tip names must differ: {names}")
        frames = self.frame_names
        if len(set(frames)) != len(frames) or any(not FRAME_LABEL.match(f) for f in frames):
            raise ValueError(f"fixed frames need distinct names of letters, digits and _: {frames}")
        if any(not 0 <= j < n for _, j, _ in self.fixed_frames) or any(t not in names for t in self.calibrated_tips):
            raise ValueError("a fixed frame stands before a joint of the robot, or is one of its tips")
        if any(not 0 <= j < n for j in self.parent_axis):
            raise ValueError(f"parent_axis: joints of the robot's {n}")
        if any(not (0 <= j < n and 0 <= i < n and i != j) for j, i in self.compliance_coupling) or len(
            {j for j, _ in self.compliance_coupling}
        ) != len(self.compliance_coupling):
            raise ValueError("a coupled compliance: a joint, once, driven by another joint of the robot")
        if any(t not in names or not m >= 0 for t, m, _ in self.tip_payloads):
            raise ValueError("a tip payload: a tip of the robot, a mass >= 0")
        if any(not -1 <= j < n or not m >= 0 for _, j, m, _ in self.fixed_bodies):
            raise ValueError("a fixed body: on a joint's link (or -1, the base), a mass >= 0")

    def __repr__(self) -> str:
        kinds = "prismatic and revolute" if self.prismatic.any() else "revolute"
        calibrated = f", {len(self.overrides)} parameters set" if self.overrides else ""
        payload = f", payload {self.payload_mass:g} kg" if self.payload_mass else ""
        tree = f", a tree with tips {', '.join(self.tip_names)}" if self.parents is not None or self.tips else ""
        coupled = f" ({len(self.coupled)} more coupled)" if self.coupled else ""
        return (
            f"<Robot {self.name!r}: {self.n_joints} {kinds} joints{coupled}{tree}, model {self.model}"
            f"{calibrated}{payload}>"
        )

    # -- description -------------------------------------------------------------------
    @property
    def compliant(self) -> bool:
        """The model bends the joints under gravity (models DH,s,e and DH,s,e,h)."""
        return "e" in self.model.split(",")

    @property
    def history(self) -> bool:
        """The model offsets the joints by how they were reached (model DH,s,e,h)."""
        return "h" in self.model.split(",")

    @property
    def n_joints(self) -> int:
        """The joints the controller moves: the width of joint values (coupled joints follow)."""
        return len(self.joints) - len(self.coupled)

    @property
    def n_links(self) -> int:
        """Every joint of the geometry, coupled ones included (what parameters are numbered by)."""
        return len(self.joints)

    def geometry_values(self, q: np.ndarray) -> np.ndarray:
        """(N, L) the value of every joint of the geometry at joint values ``q`` (N, n): a joint
        the controller moves, its own (rad or m); a coupled one, ``sum c_i q_i + c_0``."""
        q2 = self.check_q(q)
        out = np.empty((len(q2), self.n_links))
        coupled = {k for k, _, _ in self.coupled}
        for k, (sources, offset) in enumerate(self.drives):
            if k in coupled:
                out[:, k] = sum(c * q2[:, column] for column, c in sources) + offset
            else:
                out[:, k] = q2[:, sources[0][0]]
        return out

    @cached_property
    def drives(self) -> tuple[tuple[tuple[tuple[int, float], ...], float], ...]:
        """Per joint of the geometry, how the joint values move it: ((column of q, coefficient),
        ...) and a constant offset (rad or m); a joint the controller moves is its own column
        times its direction."""
        coupled = {k: (sources, offset) for k, sources, offset in self.coupled}
        column = {}
        for k in range(self.n_links):
            if k not in coupled:
                column[k] = len(column)
        out = []
        for k in range(self.n_links):
            if k in coupled:
                sources, offset = coupled[k]
                out.append((tuple((column[s], float(c)) for s, c in sources), float(offset)))
            else:
                out.append((((column[k], float(self.directions[column[k]])),), 0.0))
        return tuple(out)

    @property
    def dh(self) -> np.ndarray:
        """Nominal ``(theta, d, a, alpha)`` rows (rad, m) of a robot whose joints are all DH."""
        if not all(isinstance(j, DHJoint) for j in self.joints):
            raise ValueError(f"{self.name} is not described by DH parameters")
        return np.array([[j.theta, j.d, j.a, j.alpha] for j in self.joints])

    @property
    def prismatic(self) -> np.ndarray:
        """(n,) True for each prismatic joint the controller moves (its values are m, not rad)."""
        followers = {k for k, _, _ in self.coupled}
        return np.array([j.prismatic for k, j in enumerate(self.joints) if k not in followers], dtype=bool)

    @property
    def frame_names(self) -> list[str]:
        """The fixed frames with parameters frame.{name}.*: those before rows, then the calibrated tips."""
        return [name for name, _, _ in self.fixed_frames] + list(self.calibrated_tips)

    @property
    def framed_parameters(self) -> list[str]:
        """The row parameters fixed frames duplicate exactly: those of the row right after a frame (a
        DH row's theta, d, sx, sy), and, on a link from which every joint leaves through a frame and
        no tip hangs, its motion's offset and what follows it (a DH row's theta, d, a, alpha). A
        frame's perturbation and these are one deviation (identifiability keeps the frame's)."""
        names = [f"{kind}{j + 1}" for _, j, _ in self.fixed_frames for kind in self.joints[j].framed]
        parents = self.parents if self.parents is not None else tuple(range(-1, self.n_links - 1))
        framed = {j for _, j, _ in self.fixed_frames}
        hanging = {j for _, j, _ in self.tips} | {self.n_links - 1 if self.flange_joint is None else self.flange_joint}
        for link in range(self.n_links):
            children = [j for j, p in enumerate(parents) if p == link]
            if children and all(j in framed for j in children) and link not in hanging:
                names += [f"{kind}{link + 1}" for kind in self.joints[link].carrying]
        return list(dict.fromkeys(names))

    @cached_property
    def parameter_names(self) -> list[str]:
        coupled = {j for j, _ in self.compliance_coupling}
        kinds = [(*j.kinds, *((COUPLED_COMPLIANCE,) if i in coupled else ())) for i, j in enumerate(self.joints)]
        return parameter_names(kinds, self.n_joints, [name for name, _ in self.mass_groups], self.frame_names)

    def nominal_parameters(self) -> dict[str, float]:
        """Every SPEC parameter name with its nominal value (SI): the manufacturer's DH,
        zero distortions and compliances, zero base/tool perturbations, then any values
        the robot file sets (a calibrated robot file sets its estimates)."""
        values = dict.fromkeys(self.parameter_names, 0.0)
        values.update({f"{MASS_KIND}.{name}": 1.0 for name, _ in self.mass_groups})
        for i, joint in enumerate(self.joints, start=1):
            values.update({f"{kind}{i}": float(v) for kind, v in joint.nominal().items()})
        values.update({k: float(v) for k, v in self.overrides.items()})
        return values

    def parameter_vector(self, params: Mapping[str, float] | None = None) -> np.ndarray:
        """Full parameter vector (SI) from a full or partial dict; missing names are nominal."""
        values = self.nominal_parameters()
        if params:
            unknown = [name for name in params if name not in values]
            if unknown:
                raise InputError(None, unknown[0], f"unknown parameter name for {self.name} ({self.n_joints} joints)")
            for name, value in params.items():
                if not np.isfinite(value):
                    raise InputError(None, name, f"parameter value must be finite, got {value!r}")
                values[name] = float(value)
        return np.array([values[name] for name in self.parameter_names])

    def parameter_dict(self, vector: np.ndarray) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.parameter_names, vector, strict=True)}

    def with_model(self, model: str) -> Robot:
        """The same robot with another of MODELS (which terms enter the chain)."""
        return replace(self, model=model)

    def with_tool(
        self, tool_pose: np.ndarray, payload_mass: float | None = None, payload_com: np.ndarray | None = None
    ) -> Robot:
        """The same robot carrying another tool (nominal ``T_n_C``) and payload."""
        return replace(
            self,
            tool_pose=np.asarray(tool_pose, float),
            payload_mass=self.payload_mass if payload_mass is None else float(payload_mass),
            payload_com=self.payload_com if payload_com is None else np.asarray(payload_com, float),
        )

    @cached_property
    def chain(self) -> Chain:
        """The elementary transform chain of this robot (built once per instance)."""
        return build_chain(self)

    @cached_property
    def compiled(self) -> ChainModel:
        """The compiled model of the chain (fgcal.model.chain_model): its tables, bodies, paths
        and names as the kernels read them, built once per instance, at its first evaluation."""
        return chain_model.build(self)

    # -- evaluation (thin wrappers over fgcal.model.kinematics) --------------------------------
    def check_q(self, q: np.ndarray) -> np.ndarray:
        """Joint angles as an (N, n) float array (rad); wrong sizes or NaN raise InputError."""
        q = np.asarray(q, dtype=float)
        q2 = np.atleast_2d(q)
        if q2.ndim != 2 or q2.shape[1] != self.n_joints:
            raise InputError(None, "q", f"{self.name} has {self.n_joints} joints; got joint angles of shape {q.shape}")
        if not np.all(np.isfinite(q2)):
            raise InputError(None, "q", "joint angles must be finite")
        return q2

    def fk(
        self,
        q: np.ndarray,
        params: Mapping[str, float] | None = None,
        motion: np.ndarray | None = None,
        tip: str | None = None,
    ) -> np.ndarray:
        """Flange pose ``T_W_n`` (4x4, m) in the world frame, base pose applied; with ``tip``,
        the pose of that named frame of a tree (:attr:`tip_names`).

        ``q`` is (n,) or (N, n) in rad; ``params`` a full or partial dict of parameter
        names (missing names are nominal); ``motion`` the motion-history features (N, 2n) of
        the configurations (fgcal.model.motion.features; model DH,s,e,h). Returns (4, 4) or (N, 4, 4).
        """
        return self._frame(q, params, "flange" if tip is None else tip, motion)

    @property
    def tip_names(self) -> list[str]:
        """The named frames: the flange's name, then the tree's other tips."""
        return [self.flange_name, *(name for name, _, _ in self.tips)]

    def tip_error(self, tip: str) -> str | None:
        """What is wrong with ``tip`` as a tip of this robot (None: one of :attr:`tip_names`, or
        ``flange``, which always names the flange)."""
        if tip in self.tip_names or tip == "flange":
            return None
        return f"{self.name} has no tip {tip!r} (its tips: {', '.join(self.tip_names)})"

    def fk_tool(
        self, q: np.ndarray, params: Mapping[str, float] | None = None, motion: np.ndarray | None = None
    ) -> np.ndarray:
        """Tool (or camera) pose ``T_W_C`` = ``T_W_n T_n_C``, like :meth:`fk`."""
        return self._frame(q, params, "tool", motion)

    def flange_gap_m(self, other: Robot, count: int = 32) -> float:
        """The largest flange-position difference (m) between this robot and ``other`` over
        ``count`` seeded configurations within both ranges: a calibration moves the flange by
        millimetres, another robot by a metre (a check that two models are one robot)."""
        if other.n_joints != self.n_joints:
            return float("inf")
        low = np.maximum(np.maximum(self.limits[:, 0], other.limits[:, 0]), -np.pi)
        high = np.minimum(np.minimum(self.limits[:, 1], other.limits[:, 1]), np.pi)
        q = np.random.default_rng(0).uniform(low, np.maximum(low, high), (count, self.n_joints))
        return float(np.linalg.norm(self.fk(q)[:, :3, 3] - other.fk(q)[:, :3, 3], axis=1).max())

    def reach_m(self, params: np.ndarray | None = None, tip: str = "flange") -> tuple[np.ndarray, float]:
        """The base origin in W (m) and a sure bound on how far the flange (or a tree's ``tip``) gets from it (m):
        the sum of the chain's largest translations over the joint ranges (rotations keep
        lengths). A point farther than this plus the tool's length is out of reach.
        ``params``: the full parameter vector (default nominal)."""
        chain = self.chain
        p = self.parameter_vector() if params is None else np.asarray(params, dtype=float)
        data = kinematics.forward(self, p, np.zeros((1, self.n_joints)))
        base_origin = kinematics.frame_pose(self, data, "base")[0, :3, 3]
        total = 0.0
        path = self.compiled.ancestry[self.compiled.frame_index(tip)]
        for k, element in enumerate(chain.elements):
            if not path[k] or k < chain.base_end:
                continue
            if element.is_rotation or element.axis == "Rvec":
                continue
            value = element.const + (p[element.param] if element.param is not None else 0.0)
            if element.joint is None:
                total += abs(value)
            else:
                low, high = self.limits[element.joint]
                total += max(abs(value + element.sign * low), abs(value + element.sign * high))
        return base_origin, total

    def jacobian(
        self,
        q: np.ndarray,
        wrt: Sequence[str],
        params: Mapping[str, float] | None = None,
        frame: str = "flange",
        point: np.ndarray | None = None,
        motion: np.ndarray | None = None,
    ) -> np.ndarray:
        """Analytic Jacobian with respect to the names in ``wrt`` (parameter names or
        joints ``q1``..``qn``), at configurations reached as ``motion`` says (see :meth:`fk`).

        Without ``point``: (N, 6, len(wrt)) body-frame twist Jacobian of the frame's pose,
        rows ``[omega, v]`` (GTSAM's Pose3 retraction order). With ``point`` (3,), a point
        fixed in that frame: (N, 3, len(wrt)) derivative of its world position (m per unit).
        """
        q2 = self.check_q(q)
        data = kinematics.forward(self, self.parameter_vector(params), q2, _motion(motion, q2))
        return kinematics.jacobian(self, data, wrt, frame=frame, point=point)

    def ik(
        self,
        targets: np.ndarray,
        q_hint: np.ndarray,
        params: Mapping[str, float] | None = None,
        frame: str = "tool",
        tcp: np.ndarray | None = None,
        **options,
    ) -> IKResult:
        """Joint angles putting the TCP (``tcp``, m, in ``frame``) on ``targets``: positions
        (N, 3) or poses (N, 4, 4) in W, from the hints ``q_hint`` (N, n), on the full model at
        this robot's payload (fgcal.model.ik: status, residuals, smallest change for positions)."""
        targets = np.asarray(targets, dtype=float)
        single = targets.ndim == (2 if targets.shape[-2:] == (4, 4) else 1)
        hints = self.check_q(q_hint)
        batch = targets[None] if single else targets
        if batch.shape[1:] not in ((3,), (4, 4)) or not np.all(np.isfinite(batch)):
            raise InputError(None, "targets", f"finite positions (N, 3) or poses (N, 4, 4), got shape {targets.shape}")
        if len(hints) != len(batch):
            raise InputError(None, "q_hint", f"one hint per target: {len(hints)} hints for {len(batch)} targets")
        return inverse_kinematics(self, self.parameter_vector(params), batch, hints, frame, tcp, **options)

    def _frame(
        self, q: np.ndarray, params: Mapping[str, float] | None, frame: str, motion: np.ndarray | None = None
    ) -> np.ndarray:
        q2 = self.check_q(q)
        vector, features = self.parameter_vector(params), _motion(motion, q2)
        # In chunks: a forward pass keeps every link's frames (about 13 kB a configuration), so
        # 60,000 program targets at once took 800 MB for a (60000, 4, 4) answer.
        out = np.empty((len(q2), 4, 4))
        for start in range(0, len(q2), FK_CHUNK):
            rows = slice(start, start + FK_CHUNK)
            data = kinematics.forward(self, vector, q2[rows], None if features is None else features[rows])
            out[rows] = kinematics.frame_pose(self, data, frame)
        return out[0] if np.ndim(q) == 1 else out


def _motion(motion: np.ndarray | None, q: np.ndarray) -> np.ndarray | None:
    """Motion features as (N, 2n) rows for the (N, n) joint values (one row for one)."""
    if motion is None:
        return None
    rows = np.atleast_2d(np.asarray(motion, dtype=float))
    if rows.shape != (q.shape[0], 2 * q.shape[1]) or not np.all(np.isfinite(rows)):
        raise InputError(
            None, "motion", f"finite motion features of shape {(q.shape[0], 2 * q.shape[1])}, got {rows.shape}"
        )
    return rows


def build_chain(robot: Robot) -> Chain:
    """The chain ``T_W_0 * prod_i T_{i-1,i}(q_i) * T_last_flange * T_n_C`` of SPEC section 2.

    Each joint contributes its elements up to its bending frame, the gravity deflection
    ``Rz(gz) Ry(gy) Rx(gx)`` (model 'DH,s,e' only) and the rest of its link (fgcal.model.joints).
    A DH link is ``Rx(sx) Ry(sy) Rz(s q + theta) Rz(gz) Ry(gy) Rx(gx) Tz(d) Tx(a) Rx(alpha)``;
    model 'DH' drops sx, sy and g, 'DH,s' drops g. Base and tool are their nominal poses
    followed by a 6-parameter perturbation.
    """
    names = robot.parameter_names
    index = {name: k for k, name in enumerate(names)}
    elements: list[ET] = [*pose_elements(robot.base_pose), *perturbation_elements(index["base.tx"])]
    base_end = len(elements)
    bend, link_end = [], []

    def hung(new: list[ET], start: int) -> list[ET]:
        """Elements that start from frame ``start`` (a tree's branch point), wherever they go."""
        if new and start != len(elements):
            new[0] = replace(new[0], parent=start)
        return new

    def frame_of(joint: int) -> int:
        return base_end if joint < 0 else link_end[joint]

    before = {joint: (name, pose) for name, joint, pose in robot.fixed_frames}
    coupling = dict(robot.compliance_coupling)
    parent_axis = set(robot.parent_axis)
    carrier = []
    for i, joint in enumerate(robot.joints):

        def param(kind: str, number: int = i + 1) -> int:
            return index[f"{kind}{number}"]

        start = frame_of(robot.parents[i]) if robot.parents is not None else len(elements)
        new: list[ET] = []
        if i in before:  # a fixed frame on the parent link: its nominal pose, then its perturbation
            name, pose = before[i]
            new += [*pose_elements(pose), *perturbation_elements(index[f"{FRAME}.{name}.tx"])]
        deflection = []
        if robot.compliant:
            deflection = [
                ET("Rz", param=param("kz"), moment=3 * i + 2),
                ET("Ry", param=param("ky"), moment=3 * i + 1),
                ET("Rx", param=param("kx"), moment=3 * i),
            ]
            if i in coupling:  # about the same z, driven by the other joint's z moment
                deflection.insert(1, ET("Rz", param=param(COUPLED_COMPLIANCE), moment=3 * coupling[i] + 2))
        if i in parent_axis:  # bent about the parent's axes, at the frame the row starts from
            bend.append(len(elements) + len(new) if new else start)  # (a branch's first: where it leaves)
            new += deflection
        (first, *more), offset = robot.drives[i]
        new += joint.before_bend(param, first[0], first[1], robot.model != "DH")
        if more or offset:
            # A coupled joint: one motion per joint it follows, about the same axis (they commute).
            motion = new[-1]
            new[-1] = replace(motion, const=motion.const + offset)
            new += [ET(motion.axis, joint=column, sign=c) for column, c in more]
        carrier.append(len(elements) + len(new) - 1)  # the last motion: it moves what the joint carries
        if i not in parent_axis:
            bend.append(len(elements) + len(new))
            new += deflection
        elements += hung(new, start)
        elements += joint.after_bend(param)
        link_end.append(len(elements))
    flange = frame_of(robot.n_links - 1 if robot.flange_joint is None else robot.flange_joint)
    to_flange = pose_elements(robot.flange_pose)
    if to_flange:
        elements += hung(to_flange, flange)
        flange = len(elements)
    elements += hung([*pose_elements(robot.tool_pose), *perturbation_elements(index["tool.tx"])], flange)
    tool = len(elements)
    tips = [(robot.flange_name, flange)]
    calibrated = set(robot.calibrated_tips)
    for name, joint_index, pose in robot.tips:
        frame = frame_of(joint_index)
        to_tip = pose_elements(pose)
        if name in calibrated:
            to_tip += perturbation_elements(index[f"{FRAME}.{name}.tx"])
        if to_tip:
            elements += hung(to_tip, frame)
            frame = len(elements)
        tips.append((name, frame))
    if robot.flange_name in calibrated:
        raise ValueError(f"the flange {robot.flange_name!r} has the tool's parameters (tool.*), not a frame's")
    return Chain(tuple(elements), base_end, tuple(bend), tuple(link_end), flange, tool, tuple(tips), tuple(carrier))
