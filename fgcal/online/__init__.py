"""Online recalibration with iSAM2 (issue: online recalibration; issue 41: any formulation)."""

from .calibrator import OnlineCalibrator, OnlineSettings, OnlineUpdate
from .protocol import FormulationCalibrator, Reading

__all__ = ["FormulationCalibrator", "OnlineCalibrator", "OnlineSettings", "OnlineUpdate", "Reading"]
