"""fgcal bench: the solve against its yardsticks (suite) and the kinematics kernel against
Pinocchio (kernel).
"""
