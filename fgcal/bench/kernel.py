"""``fgcal bench``'s kinematics figures: what one evaluation of the chain costs, the yardstick
for a compiled kernel (issue 26), and issue 37's targets against Pinocchio.

On the IRB 120 (6 axes, model DH,s,e, random compliances so that the gravity terms are
exercised), CPU microseconds per configuration of

- fgcal's FK plus the Jacobian with respect to every parameter (what calibration needs), and
  plus the Jacobian with respect to the joints (what IK needs), batched over ``n`` configurations
  (``forward`` and ``jacobian``) and for a single one at a time (``forward_jacobian`` into a
  ``Workspace`` made once, as Pinocchio's Data is);
- the same FK plus joint Jacobian on the rigid model DH,s, which is what Pinocchio is given, and
  for a single configuration through ``forward`` and ``jacobian`` too (a fresh evaluation per call);
- Pinocchio's FK plus the joint Jacobian (``computeJointJacobians``) of that rigid model
  exported as URDF, one configuration per call, when Pinocchio is installed (``pip install
  '.[interop]'``). It has no derivatives with respect to the kinematic parameters or the
  compliances, and no gravity terms: a yardstick, not a drop-in.

The first call of each case (which compiles or loads fgcal's kernel) is not timed. The cases
run in interleaved rounds (at least :data:`ROUNDS`: each takes milliseconds); each case's best
is kept, and a ratio to Pinocchio is the median of the rounds' ratios (a round's cases share
the machine's load). Issue 37's targets (:data:`TARGETS`) are stated met or not; those against
Pinocchio are skipped without it.
"""

from __future__ import annotations

import importlib.util
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ..model import kinematics
from ..model.robot_io import load_robot

ROUNDS = 15
# Issue 37's speed targets: (key, what, the case, its limit, against): a ratio to Pinocchio's
# time at most the limit, or CPU us per configuration under it.
TARGETS = (
    ("rigid_batched", "rigid DH,s FK + joint Jacobian, batched", "rigid_joint_batched", 1.0, "pinocchio"),
    ("rigid_single", "rigid DH,s FK + joint Jacobian, a single configuration", "rigid_joint_single", 3.0,
     "pinocchio"),
    ("param_single", "DH,s,e FK + all-parameter Jacobian, a single configuration", "param_single", 15.0, "us"),
)  # fmt: skip


def kernel_bench(repeats: int, say: Callable[[str], None], n: int = 1000) -> dict:
    compliant = load_robot("abb_irb120")
    rng = np.random.default_rng(0)
    params = compliant.parameter_vector({f"k{a}{j}": float(rng.uniform(1e-5, 5e-5)) for a in "xyz" for j in (1, 2, 3)})
    rigid = compliant.with_model("DH,s")  # the model Pinocchio is given
    rigid_params = rigid.parameter_vector({})
    q = rng.uniform(compliant.limits[:, 0], compliant.limits[:, 1], (n, compliant.n_joints))
    rows = q[:, None]  # (n, 1, 6): each a single configuration, a view as Pinocchio's q[i] is
    joints = [f"q{i + 1}" for i in range(compliant.n_joints)]

    def batched(robot, values: np.ndarray, names: list[str]) -> float:
        started = time.process_time()
        data = kinematics.forward(robot, values, q)
        kinematics.jacobian(robot, data, names)
        return (time.process_time() - started) / n * 1e6

    def single(robot, values: np.ndarray, names: list[str]) -> float:
        work = kinematics.Workspace(robot, names)
        started = time.process_time()
        for row in rows:
            kinematics.forward_jacobian(work, values, row)
        return (time.process_time() - started) / n * 1e6

    def single_calls(robot, values: np.ndarray, names: list[str]) -> float:
        started = time.process_time()
        for row in rows:
            kinematics.jacobian(robot, kinematics.forward(robot, values, row), names)
        return (time.process_time() - started) / n * 1e6

    cases = {
        "param_batched": lambda: batched(compliant, params, compliant.parameter_names),
        "param_single": lambda: single(compliant, params, compliant.parameter_names),
        "joint_batched": lambda: batched(compliant, params, joints),
        "joint_single": lambda: single(compliant, params, joints),
        "rigid_joint_batched": lambda: batched(rigid, rigid_params, joints),
        "rigid_joint_single": lambda: single(rigid, rigid_params, joints),
        "rigid_joint_single_calls": lambda: single_calls(rigid, rigid_params, joints),
    }
    pinocchio = _pinocchio(rigid)
    if pinocchio is not None:
        cases["pinocchio"] = lambda: pinocchio(q)
    for case in cases.values():  # the first call compiles or loads the kernel: not timed
        case()
    times: dict[str, list[float]] = {key: [] for key in cases}
    for _ in range(max(repeats, ROUNDS)):
        for key, case in cases.items():
            times[key].append(case())
    best = {key: min(values) for key, values in times.items()}
    ratio = {
        key: float(np.median(np.array(times[key]) / np.array(times["pinocchio"]))) if pinocchio else None
        for key in cases
        if key != "pinocchio"
    }
    result = {
        "kernel_robot": compliant.name,
        "kernel_n_configurations": n,
        "kernel_rounds": len(times["param_batched"]),
        "kernel_fk_param_jacobian_batched_us": best["param_batched"],
        "kernel_fk_param_jacobian_single_us": best["param_single"],
        "kernel_fk_joint_jacobian_batched_us": best["joint_batched"],
        "kernel_fk_joint_jacobian_single_us": best["joint_single"],
        "kernel_rigid_fk_joint_jacobian_batched_us": best["rigid_joint_batched"],
        "kernel_rigid_fk_joint_jacobian_single_us": best["rigid_joint_single"],
        "kernel_rigid_fk_joint_jacobian_single_calls_us": best["rigid_joint_single_calls"],
        "pinocchio_fk_joint_jacobian_us": best.get("pinocchio"),
        "kernel_to_pinocchio": ratio if pinocchio else None,
        "kernel_targets": {},
    }
    say(
        f"  kinematics of the {compliant.name}, CPU us per configuration, best of {result['kernel_rounds']} rounds, "
        f"batched ({n}) / single (forward_jacobian into a Workspace): model DH,s,e with compliances "
        f"({len(compliant.parameter_names)} parameters): FK + parameter Jacobian {best['param_batched']:.1f} / "
        f"{best['param_single']:.1f}, FK + joint Jacobian {best['joint_batched']:.2f} / {best['joint_single']:.2f}; "
        f"rigid DH,s: FK + joint Jacobian {best['rigid_joint_batched']:.2f} / {best['rigid_joint_single']:.2f} "
        f"(single through forward and jacobian: {best['rigid_joint_single_calls']:.2f})"
    )
    if pinocchio is None:
        say("  Pinocchio: skipped, pinocchio not installed (pip install '.[interop]')")
    else:
        say(
            f"  Pinocchio FK + joint Jacobian of the rigid DH,s model {best['pinocchio']:.2f} us per configuration "
            f"(one per call); fgcal's on the same model, median ratio of the rounds: "
            f"{ratio['rigid_joint_batched']:.2f}x batched, {ratio['rigid_joint_single']:.2f}x single "
            f"({ratio['rigid_joint_single_calls']:.2f}x through forward and jacobian); with the compliances, "
            f"{ratio['joint_batched']:.2f}x batched, {ratio['joint_single']:.2f}x single"
        )
    say("  issue 37's targets:")
    for key, what, case, limit, against in TARGETS:
        if against == "us":
            value, stated = best[case], f"under {limit:g} us"
            shown = f"{value:.2f} us"
        else:
            value, stated = (None if ratio[case] is None else ratio[case]), f"within {limit:g}x Pinocchio"
            shown = "skipped: pinocchio not installed" if value is None else f"{value:.2f}x"
        met = None if value is None else bool(value <= limit if against != "us" else value < limit)
        result["kernel_targets"][key] = {"what": what, "target": stated, "value": value, "met": met}
        verdict = "" if met is None else (": met" if met else ": NOT met")
        say(f"    {what}, {stated}: {shown}{verdict}")
    return result


def _pinocchio(robot) -> Callable[[np.ndarray], float] | None:
    """Pinocchio's FK + joint Jacobians of ``robot`` (its rigid model, as URDF), timed: CPU us
    per configuration; None when Pinocchio is not installed."""
    if importlib.util.find_spec("pinocchio") is None:
        return None
    import pinocchio

    from ..model.urdf_export import urdf_document

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "robot.urdf"
        path.write_text(urdf_document(robot))
        model = pinocchio.buildModelFromUrdf(str(path))
    data = model.createData()
    last = model.njoints - 1

    def timed(q: np.ndarray) -> float:
        started = time.process_time()
        for row in q:
            pinocchio.computeJointJacobians(model, data, row)
            pinocchio.getJointJacobian(model, data, last, pinocchio.ReferenceFrame.LOCAL)
        return (time.process_time() - started) / len(q) * 1e6

    return timed
