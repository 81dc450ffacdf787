"""Online recalibration with iSAM2 (issue: online recalibration)."""

from .calibrator import OnlineCalibrator, OnlineSettings, OnlineUpdate

__all__ = ["OnlineCalibrator", "OnlineSettings", "OnlineUpdate"]
