"""The PC side of the paper: robot driver, planning, the ``robot-client`` command.

It may import :mod:`simple_message` and :mod:`robot_server`'s models and kinematics as a library.
"""
