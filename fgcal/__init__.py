"""fgcal: calibration of industrial robot arms with factor graphs.

Public API: :func:`load_robot` returns a :class:`Robot`; :func:`calibrate` a calibration with
named estimates, sigmas and held-out figures; :func:`compensate` corrected commands. See
docs/api.md.
"""

import os
import pkgutil

# Run from a source checkout's root, this folder comes first on sys.path and hides the installed
# package, whose fgcal.factors and fgcal.datasets are the top-level factors/ and datasets/
# folders mapped in at install (pyproject.toml): look for the subpackages there too.
__path__ = pkgutil.extend_path(__path__, __name__)

# fgcal's dense algebra is small (tens of columns), where BLAS threads cost more than they
# give. OpenBLAS reads this once, when NumPy, SciPy or OpenCV load it, and only that stops
# its idle threads from spinning (threadpoolctl's limit, applied by the CLI too, does not);
# a value the user has set is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from .core.errors import FgcalError, InputError
from .model.robot import Robot
from .model.robot_io import load_robot, save_robot

__all__ = ["FgcalError", "InputError", "Robot", "calibrate", "compensate", "load_robot", "save_robot"]
__version__ = "0.2.0"


def calibrate(dataset, **settings):
    """Calibrate a dataset with a calibration config's settings (fgcal.api.calibrate)."""
    # Loaded when first used (GTSAM, SciPy): import fgcal stays as light as the model.
    from .api import calibrate as run

    return run(dataset, **settings)


def compensate(robot, targets, hints=None, nominal=None, tcp=None, approach="previous"):
    """Corrected commands for a controller running its nominal model (fgcal.api.compensate)."""
    from .api import compensate as run

    return run(robot, targets, hints, nominal, tcp, approach)
