"""``fgcal bench``'s kinematics figures: what one evaluation of the chain costs, the yardstick
for a compiled kernel (issue 26).

On the IRB 120 (6 axes, model DH,s,e, random compliances so that the gravity terms are
exercised), CPU microseconds per configuration of

- fgcal's FK plus the Jacobian with respect to every parameter (what calibration needs), and
  plus the Jacobian with respect to the joints (what IK needs), batched over ``n`` configurations
  and for a single one;
- Pinocchio's FK plus the joint Jacobian (``computeJointJacobians``) of the same robot exported
  as URDF, one configuration per call, when Pinocchio is installed (``pip install
  '.[interop]'``). It has no derivatives with respect to the kinematic parameters or the
  compliances: a yardstick, not a drop-in.

Interleaved rounds, the best of each kept, as the rest of the bench.
"""

from __future__ import annotations

import importlib.util
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from . import kinematics
from .robot_io import load_robot


def kernel_bench(repeats: int, say: Callable[[str], None], n: int = 1000, singles: int = 200) -> dict:
    robot = load_robot("abb_irb120")
    rng = np.random.default_rng(0)
    params = robot.parameter_vector({f"k{a}{j}": float(rng.uniform(1e-5, 5e-5)) for a in "xyz" for j in (1, 2, 3)})
    q = rng.uniform(robot.limits[:, 0], robot.limits[:, 1], (n, robot.n_joints))
    everything = robot.parameter_names
    joints = [f"q{i + 1}" for i in range(robot.n_joints)]

    def fgcal_batched(names: list[str]) -> float:
        started = time.process_time()
        data = kinematics.forward(robot, params, q)
        kinematics.jacobian(robot, data, names)
        return (time.process_time() - started) / n * 1e6

    def fgcal_single(names: list[str]) -> float:
        started = time.process_time()
        for row in q[:singles]:
            data = kinematics.forward(robot, params, row[None])
            kinematics.jacobian(robot, data, names)
        return (time.process_time() - started) / singles * 1e6

    pinocchio = _pinocchio(robot)
    keys = ("param_batched", "param_single", "joint_batched", "joint_single", "pinocchio")
    best = dict.fromkeys(keys, np.inf)
    for _ in range(repeats):
        best["param_batched"] = min(best["param_batched"], fgcal_batched(everything))
        best["param_single"] = min(best["param_single"], fgcal_single(everything))
        best["joint_batched"] = min(best["joint_batched"], fgcal_batched(joints))
        best["joint_single"] = min(best["joint_single"], fgcal_single(joints))
        if pinocchio is not None:
            best["pinocchio"] = min(best["pinocchio"], pinocchio(q))
    result = {
        "kernel_robot": robot.name,
        "kernel_n_configurations": n,
        "kernel_fk_param_jacobian_batched_us": best["param_batched"],
        "kernel_fk_param_jacobian_single_us": best["param_single"],
        "kernel_fk_joint_jacobian_batched_us": best["joint_batched"],
        "kernel_fk_joint_jacobian_single_us": best["joint_single"],
        "pinocchio_fk_joint_jacobian_us": None if pinocchio is None else best["pinocchio"],
    }
    say(
        f"  kinematics of the {robot.name} ({len(everything)} parameters), CPU us per configuration: FK + parameter "
        f"Jacobian {best['param_batched']:.1f} batched ({n}), {best['param_single']:.0f} single; FK + joint Jacobian "
        f"{best['joint_batched']:.1f} batched, {best['joint_single']:.0f} single"
    )
    if pinocchio is None:
        say("  Pinocchio is not installed (pip install '.[interop]'): no yardstick")
    else:
        say(
            f"  Pinocchio FK + joint Jacobian {best['pinocchio']:.2f} us per configuration (one per call): fgcal's "
            f"batched joint Jacobian is {best['joint_batched'] / best['pinocchio']:.1f}x, its single "
            f"{best['joint_single'] / best['pinocchio']:.0f}x"
        )
    return result


def _pinocchio(robot) -> Callable[[np.ndarray], float] | None:
    """Pinocchio's FK + joint Jacobians of ``robot`` (its rigid model, as URDF), timed: CPU us
    per configuration; None when Pinocchio is not installed."""
    if importlib.util.find_spec("pinocchio") is None:
        return None
    import pinocchio

    from .urdf_export import urdf_document

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "robot.urdf"
        path.write_text(urdf_document(robot.with_model("DH,s")))
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
