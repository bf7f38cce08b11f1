"""The controller layer of the paper: the robot controller emulator.

Robot models and kinematics, interpolation, motor models, the control loop and the emulator process
land here issue by issue (see README.md). It may import :mod:`simple_message`, numpy and ruckig,
never :mod:`client`.
"""
