"""calibgraph: multi-camera hand-eye calibration of robotic workcells on a GTSAM factor graph.

Frame convention: ``T_a_b`` maps points from frame b to frame a (``p_a = T_a_b @ p_b``).

The engine is pure: importing it never imports a camera/robot SDK, MuJoCo or rerun.

    >>> from calibgraph import solve
    >>> result = solve(problem)          # Problem in, Result out
"""

__version__ = "0.1.0"

from .camera import Intrinsics, preset  # noqa: E402
from .errors import CalibgraphError, DetectionError, InputError, ObservabilityError, SolverError  # noqa: E402
from .problem import Capture, Detection, Problem, SolverOptions  # noqa: E402
from .result import CameraResult, PairResult, Result  # noqa: E402
from .targets import Target, load_target  # noqa: E402


def solve(problem):
    """Calibrate every camera of ``problem``; see :func:`calibgraph.solve.solve`."""
    from .solver import solve as _solve

    return _solve(problem)


__all__ = [
    "CalibgraphError", "Capture", "CameraResult", "Detection", "DetectionError", "InputError", "Intrinsics",
    "ObservabilityError", "PairResult", "Problem", "Result", "SolverError", "SolverOptions", "Target",
    "load_target", "preset", "solve",
]
