"""The robot model: parameters by name and kind, the elementary transform chain and its compiled
kernel, joints, the motion history, the constant Robot and its per-evaluation kinematics, robot
files and URDF (read and written), inverse kinematics, cameras and boards.
"""
