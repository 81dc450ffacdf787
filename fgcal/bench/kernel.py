"""``fgcal bench``'s kinematics figures: what one evaluation of the chain costs, the yardstick
for a compiled kernel (issue 26).

On the IRB 120 (6 axes, model DH,s,e, random compliances so that the gravity terms are
exercised), CPU microseconds per configuration of

- fgcal's FK plus the Jacobian with respect to every parameter (what calibration needs), and
  plus the Jacobian with respect to the joints (what IK needs), batched over ``n`` configurations
  and for a single one;
- the same FK plus joint Jacobian on the rigid model DH,s, which is what Pinocchio is given;
- Pinocchio's FK plus the joint Jacobian (``computeJointJacobians``) of that rigid model
  exported as URDF, one configuration per call, when Pinocchio is installed (``pip install
  '.[interop]'``). It has no derivatives with respect to the kinematic parameters or the
  compliances, and no gravity terms: a yardstick, not a drop-in.

The first call of each case (which compiles or loads fgcal's kernel) is not timed.

Interleaved rounds, the best of each kept, as the rest of the bench.
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


def kernel_bench(repeats: int, say: Callable[[str], None], n: int = 1000, singles: int = 200) -> dict:
    compliant = load_robot("abb_irb120")
    rng = np.random.default_rng(0)
    params = compliant.parameter_vector({f"k{a}{j}": float(rng.uniform(1e-5, 5e-5)) for a in "xyz" for j in (1, 2, 3)})
    rigid = compliant.with_model("DH,s")  # the model Pinocchio is given
    rigid_params = rigid.parameter_vector({})
    q = rng.uniform(compliant.limits[:, 0], compliant.limits[:, 1], (n, compliant.n_joints))
    joints = [f"q{i + 1}" for i in range(compliant.n_joints)]

    def batched(robot, values: np.ndarray, names: list[str]) -> float:
        started = time.process_time()
        data = kinematics.forward(robot, values, q)
        kinematics.jacobian(robot, data, names)
        return (time.process_time() - started) / n * 1e6

    def single(robot, values: np.ndarray, names: list[str]) -> float:
        started = time.process_time()
        for row in q[:singles]:
            data = kinematics.forward(robot, values, row[None])
            kinematics.jacobian(robot, data, names)
        return (time.process_time() - started) / singles * 1e6

    cases = {
        "param_batched": lambda: batched(compliant, params, compliant.parameter_names),
        "param_single": lambda: single(compliant, params, compliant.parameter_names),
        "joint_batched": lambda: batched(compliant, params, joints),
        "joint_single": lambda: single(compliant, params, joints),
        "rigid_joint_batched": lambda: batched(rigid, rigid_params, joints),
        "rigid_joint_single": lambda: single(rigid, rigid_params, joints),
    }
    pinocchio = _pinocchio(rigid)
    if pinocchio is not None:
        cases["pinocchio"] = lambda: pinocchio(q)
    for case in cases.values():  # the first call compiles or loads the kernel: not timed
        case()
    best = dict.fromkeys(cases, np.inf)
    for _ in range(repeats):
        for key, case in cases.items():
            best[key] = min(best[key], case())
    result = {
        "kernel_robot": compliant.name,
        "kernel_n_configurations": n,
        "kernel_fk_param_jacobian_batched_us": best["param_batched"],
        "kernel_fk_param_jacobian_single_us": best["param_single"],
        "kernel_fk_joint_jacobian_batched_us": best["joint_batched"],
        "kernel_fk_joint_jacobian_single_us": best["joint_single"],
        "kernel_rigid_fk_joint_jacobian_batched_us": best["rigid_joint_batched"],
        "kernel_rigid_fk_joint_jacobian_single_us": best["rigid_joint_single"],
        "pinocchio_fk_joint_jacobian_us": best.get("pinocchio"),
    }
    say(
        f"  kinematics of the {compliant.name}, CPU us per configuration, batched ({n}) / single: model DH,s,e with "
        f"compliances ({len(compliant.parameter_names)} parameters): FK + parameter Jacobian "
        f"{best['param_batched']:.1f} / {best['param_single']:.1f}, FK + joint Jacobian {best['joint_batched']:.2f} / "
        f"{best['joint_single']:.1f}; rigid DH,s: FK + joint Jacobian {best['rigid_joint_batched']:.2f} / "
        f"{best['rigid_joint_single']:.1f}"
    )
    if pinocchio is None:
        say("  Pinocchio is not installed (pip install '.[interop]'): no yardstick")
    else:
        say(
            f"  Pinocchio FK + joint Jacobian of the rigid DH,s model {best['pinocchio']:.2f} us per configuration "
            f"(one per call): fgcal's on the same model is {best['rigid_joint_batched'] / best['pinocchio']:.1f}x "
            f"batched, {best['rigid_joint_single'] / best['pinocchio']:.0f}x single; with the compliances, "
            f"{best['joint_batched'] / best['pinocchio']:.1f}x batched"
        )
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
