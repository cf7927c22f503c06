"""calibgraph: multi-camera hand-eye calibration of robotic workcells on a GTSAM factor graph.

Frame convention: ``T_a_b`` maps points from frame b to frame a (``p_a = T_a_b @ p_b``).

The package is layered in data-flow order — :mod:`~calibgraph.core` → :mod:`~calibgraph.io` →
:mod:`~calibgraph.detect` → :mod:`~calibgraph.solver` → :mod:`~calibgraph.plan` →
:mod:`~calibgraph.acquire` → :mod:`~calibgraph.report`, with :mod:`~calibgraph.sim` and
:mod:`~calibgraph.cli` at the edge — and this module re-exports what a script needs::

    import calibgraph as cg

    dataset = cg.load_dataset("my_dataset")          # any supported layout
    problem, _ = cg.build_problem(dataset)            # detects views without stored corners
    result = cg.solve(problem)                        # Problem in, Result out
    print(result.cameras["cam0"].T_base_cam, result.cameras["cam0"].sigma_translation_mm)
    result.save("result.json")
    same = cg.load_result("result.json")               # equal to result, every number

Importing it never imports a camera/robot SDK, MuJoCo or rerun (see ``scripts/examples/``).
"""

import os as _os

# calibgraph's dense linear algebra is small (6x6 blocks, a few hundred unknowns at most), and the
# detection runs its own worker threads: OpenBLAS's threads only spin on such matrices, and on a
# shared machine they burn several times the work's CPU (issue 36, at load ~15 on 2 cores: an 8-camera
# solve 4.7 -> 3.8 CPU-s, its error budget 0.52 -> 0.12; scoring 160 candidates of a 16-camera cell
# 1.2-2.5 -> 0.2-0.3). One thread unless the user set it; read when numpy first loads.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from calibgraph.core.camera import Intrinsics, preset
from calibgraph.core.errors import (
    CalibgraphError,
    DetectionError,
    InputError,
    ObservabilityError,
    SolverError,
)
from calibgraph.core.problem import Capture, Detection, Problem, SolverOptions
from calibgraph.core.targets import Target, a4_board_54, thesis_board
from calibgraph.core.version import __version__
from calibgraph.detect.corners import ImageDetection, dataset_detector, detect_image
from calibgraph.io.dataset import Dataset
from calibgraph.io.layouts import load_dataset
from calibgraph.io.specs import load_target
from calibgraph.plan.planner import plan_trajectory
from calibgraph.plan.trajectory import Trajectory, TrajectoryPose, load_trajectory
from calibgraph.plan.visibility import board_visibility
from calibgraph.solver.solve.batch import solve
from calibgraph.solver.solve.build import build_problem
from calibgraph.solver.solve.incremental import IncrementalSolver
from calibgraph.solver.output.result import CameraResult, PairResult, Result, load_result, load_result_dict

__all__ = [
    "CalibgraphError", "CameraResult", "Capture", "Dataset", "Detection", "DetectionError", "ImageDetection",
    "IncrementalSolver", "InputError", "Intrinsics", "ObservabilityError", "PairResult", "Problem", "Result",
    "SolverError", "SolverOptions", "Target", "Trajectory", "TrajectoryPose", "__version__", "a4_board_54",
    "board_visibility", "build_problem", "dataset_detector", "detect_image", "load_dataset", "load_result",
    "load_result_dict", "load_target", "load_trajectory", "plan_trajectory", "preset", "solve", "thesis_board",
]
