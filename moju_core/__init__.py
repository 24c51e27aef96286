"""moju_core: dense non-rigid structure from motion by MoJu (Kumar, CVPR 2019).

The functional entry point is :func:`reconstruct`; parameters are :class:`SolverParams`, the
answer is a :class:`Result` (its by-products in :class:`Diagnostics`). :class:`MoJu` is the
same solver as a scikit-learn estimator.
"""

from moju_core.errors import Cancelled, MeasurementError
from moju_core.params import SolverParams
from moju_core.result import Diagnostics, Progress, Result, Stage, StopReason

__version__ = "0.1.0"

__all__ = [
    "Cancelled",
    "Diagnostics",
    "MeasurementError",
    "MoJu",
    "Progress",
    "Result",
    "SolverParams",
    "Stage",
    "StopReason",
    "__version__",
    "reconstruct",
]


def __getattr__(name: str):
    # The solver pulls in scikit-learn; load it only when it is asked for.
    if name == "reconstruct":
        from moju_core.solver import reconstruct

        return reconstruct
    if name == "MoJu":
        from moju_core.estimator import MoJu

        return MoJu
    raise AttributeError(name)
