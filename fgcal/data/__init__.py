"""Files: datasets, image detection, a simulation's truth, instrument exports (FARO, any CSV),
targets and their compensation, robot programs (RAPID, KRL), controller files (UR kinematics).
"""
