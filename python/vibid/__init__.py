"""vibid: identification of mechanical vibration systems (masses, damping, stiffness,
natural frequencies, damping ratios) by least squares, over the C library libvibid.

    import vibid
    stand = vibid.Stand.load("examples/stands/paper_example1.cfg")
    result = vibid.identify(stand, "capture.csv")     # or .mf4 (MDF4), .tdms (TDMS)
    result.parameters, result.modes, result.covariance, result.tracks

Documentation: docs/python.md in the repository.
"""

from ._core import VibidError
from ._core import version as _lib_version
from ._captures import CaptureError, read_capture
from ._identify import METHODS, Result, identify
from ._many import identify_many
from ._stand import Stand

__version__ = _lib_version()
__all__ = ["Stand", "identify", "identify_many", "read_capture", "Result", "VibidError", "CaptureError", "METHODS",
           "__version__"]

# The estimators as classes (issue 13; docs/python.md "Estimator classes").
from ._estimators import EKF, IV, KFRLS, RLS, Estimate, LeastSquares, RecursiveIV  # noqa: E402

__all__ += ["LeastSquares", "RLS", "IV", "RecursiveIV", "KFRLS", "EKF", "Estimate"]

# vibidd's pipeline in-process (issue 13; docs/python.md "vibid.replay").
from ._drivers import replay  # noqa: E402
from ._monitor import Monitoring, monitor  # noqa: E402
# Output-only modal analysis (issue 34; docs/python.md "Output-only modal analysis").
from ._oma import OmaResult, oma  # noqa: E402

__all__ += ["replay", "monitor", "Monitoring"]
__all__ += ["oma", "OmaResult"]
