"""fgcal: calibration of industrial robot arms with factor graphs.

Public API: :func:`load_robot` returns a :class:`Robot`; see docs/api.md.
"""

import os

# fgcal's dense algebra is small (tens of columns), where BLAS threads cost more than they
# give. OpenBLAS reads this once, when NumPy, SciPy or OpenCV load it, and only that stops
# its idle threads from spinning (threadpoolctl's limit, applied by the CLI too, does not);
# a value the user has set is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from .errors import FgcalError, InputError
from .robot import Robot
from .robot_io import load_robot, save_robot

__all__ = ["FgcalError", "InputError", "Robot", "load_robot", "save_robot"]
__version__ = "0.1.0"
