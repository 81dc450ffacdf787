"""fgcal: calibration of industrial robot arms with factor graphs.

Public API: :func:`load_robot` returns a :class:`Robot`; see docs/api.md.
"""

from .errors import FgcalError, InputError
from .robot import Robot
from .robot_io import load_robot, save_robot

__all__ = ["FgcalError", "InputError", "Robot", "load_robot", "save_robot"]
__version__ = "0.1.0"
