"""Planning the measurement configurations of a calibration (``fgcal plan``, docs/planning.md).

candidates (what the cell can measure, drawn by the formulation's ``planning``,
fgcal.calibration.plan_model) -> information (whitened Jacobian rows of each candidate on the
identifiable parameters and the auxiliary unknowns, the formulation's own) -> exchange (the
design: greedy then Fedorov exchange with rank-r updates) -> indices (observability
indices O1..O5) -> plan (the command: files, report, plot).
"""

# Candidates fgcal plan considers at most: their information rows take about 10 kB each, and a
# camera cell's candidates cost an inverse kinematics each.
MAX_CANDIDATES = 50000
