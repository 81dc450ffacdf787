"""Batch calibration on a GTSAM factor graph: problem assembly, identifiability, staged
solving, covariances, validation and reports."""
