"""Kinematics of any serial chain: forward kinematics, Jacobian, closed-form and numeric inverse
kinematics. SI units throughout (m, rad). ``python -m robot_server.kinematics`` is the command."""

from __future__ import annotations

from numpy.typing import ArrayLike

from ..model import RobotModel
from ._chain import PoseBlock, PoseJacobian
from ._ops import Ops
from .fk import (
    ChainFunctions,
    chain_functions,
    fk,
    fk_batch,
    jacobian,
    jacobian_batch,
    link_frames,
    manipulability,
    singularity_measure,
    singularity_measure_batch,
)
from .ik import BatchSolutions, Branch, ClosedFormIK, IKSolution, NotApplicable, Singularity, closed_form
from .numeric import NumericIKResult, ik_numeric, rotation_error
from .rotations import quaternion_angle, quaternion_of, quaternion_to_rotation, rotation_to_quaternion, slerp

__all__ = [
    "Ops",
    "PoseBlock",
    "PoseJacobian",
    "ChainFunctions",
    "chain_functions",
    "fk",
    "fk_batch",
    "jacobian",
    "jacobian_batch",
    "link_frames",
    "manipulability",
    "singularity_measure",
    "singularity_measure_batch",
    "ClosedFormIK",
    "IKSolution",
    "Branch",
    "BatchSolutions",
    "NotApplicable",
    "Singularity",
    "closed_form",
    "NumericIKResult",
    "ik_numeric",
    "rotation_error",
    "quaternion_angle",
    "quaternion_of",
    "quaternion_to_rotation",
    "rotation_to_quaternion",
    "slerp",
    "ik",
    "IKFailed",
]


class IKFailed(ValueError):
    """No configuration within the joint limits reaches the pose (to the tolerances)."""


def ik(model: RobotModel, pose: ArrayLike, seed: ArrayLike | None = None, *, all: bool = False) -> list[IKSolution]:
    """Inverse kinematics by the best method the model admits: closed form (every solution, or the
    one nearest ``seed``) when the model has a spherical wrist, else numeric (one solution, from
    ``seed``). Raises :class:`IKFailed` when there is none."""
    solver = closed_form(model)
    if solver is not None:
        solutions = solver.solve_all(pose, seed)
        if not solutions:
            raise IKFailed(f"{model.name}: the pose is out of reach within the joint limits")
        if all or seed is None:
            return solutions if all else solutions[:1]
        nearest = solver.solve(pose, seed)
        assert nearest is not None
        return [nearest]
    result = ik_numeric(model, pose, seed)
    if not result.success:
        raise IKFailed(
            f"{model.name}: no solution found (best residual {result.position_error:.3g} m, "
            f"{result.orientation_error:.3g} rad after {result.iterations} iterations)"
        )
    return [IKSolution(result.q)]
