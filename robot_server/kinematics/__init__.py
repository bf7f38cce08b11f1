"""Kinematics of any serial chain: forward kinematics, Jacobian, closed-form and numeric inverse
kinematics. SI units throughout (m, rad). ``python -m robot_server.kinematics`` is the command."""

from .fk import chain_functions, fk, fk_batch, jacobian, link_frames, manipulability, singularity_measure

__all__ = [
    "chain_functions",
    "fk",
    "fk_batch",
    "jacobian",
    "link_frames",
    "manipulability",
    "singularity_measure",
]
