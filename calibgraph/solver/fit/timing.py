"""Wall time per solver stage, for ``solve(problem, timings={})`` and the benchmarks."""

from __future__ import annotations

import time
from contextlib import contextmanager

# PnP candidates, the initialiser's consensus and its translation solve, graph building, LM runs,
# elimination for the marginals, and the robot error model's cross-validation (kinematics_select; it
# times its solves as a whole)
STAGES = ("candidates", "initialise", "refine_translations", "build_graph", "lm", "marginals", "kinematics_select")


@contextmanager
def timed(timings: dict | None, stage: str):
    """Add the wall time of the block to ``timings[stage]`` (nothing when ``timings`` is None)."""
    if timings is None:
        yield
        return
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - t0
