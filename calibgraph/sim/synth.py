"""The import path outside scripts use for synthetic scenes: ``calibgraph.sim.synth.make_scene``
and ``ring_cameras`` (with the scene types beside them).

The code lives in :mod:`calibgraph.sim.synthetic_corners`; this module only re-exports it so that
those scripts keep working.
"""

from calibgraph.sim.synthetic_corners import (
    DEFAULT_T_FLANGE_BOARD,
    WORKSPACE_CENTRE_M,
    Scene,
    Truth,
    bump_camera,
    correlate_corner_noise,
    make_scene,
    random_board_facing,
    reported_cameras,
    ring_cameras,
)

__all__ = ["DEFAULT_T_FLANGE_BOARD", "WORKSPACE_CENTRE_M", "Scene", "Truth", "bump_camera", "correlate_corner_noise", "make_scene",
           "random_board_facing", "reported_cameras", "ring_cameras"]
