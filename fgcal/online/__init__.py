"""Online recalibration with iSAM2 (issue: online recalibration)."""

from .calibrator import OnlineCalibrator, OnlineEstimate

__all__ = ["OnlineCalibrator", "OnlineEstimate"]
