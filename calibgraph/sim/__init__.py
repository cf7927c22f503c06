"""The simulated workcell: a MuJoCo FR3 arm presenting a board to fixed cameras.

Submodules (MuJoCo is imported only when a world is built):

- :mod:`.workcell` — the cell as data (cameras, board mount, image realism), YAML loader;
- :mod:`.scene` — the MuJoCo model (franky-sim's FR3, board texture, stands, cameras);
- :mod:`.render` — :class:`SimWorld` (model, state, renderer) and sensor degradations;
- :mod:`.ik` — damped-least-squares IK and collision checks;
- :mod:`.reported_intrinsics` — the intrinsics a simulated camera reports (factory-class errors
  around the true ones it renders with, or exactly those: an oracle);
- :mod:`.devices` — :class:`SimRobot` and :class:`SimCamera`, implementations of
  :mod:`calibgraph.acquire.interfaces`;
- :mod:`.rendered_dataset` — write a rendered dataset (the real acquisition on the simulated cell)
  with its ground truth;
- :mod:`.planning_world` — the robot and static geometry of a cell without its cameras, for the
  autonomous loop to plan in;
- :mod:`.synthetic_corners` — seeded scenes of projected corners (no rendering) with their truth,
  for tests and benchmarks (:mod:`.synth` keeps the ``calibgraph.sim.synth.make_scene`` path);
- :mod:`.kinematic_scene` — such scenes of an arm with joint zero offsets;
- :mod:`.corner_devices` — cameras of a simulated world that deliver projected corners;
- :mod:`.fakes` — an in-process fake robot and cameras for fast acquisition tests;
- :mod:`.board_image` — images of a board with exact ground-truth pixels, without MuJoCo.
"""

from calibgraph.sim.workcell import (
    Realism,
    SimCameraSpec,
    Workcell,
    board_by_name,
    load_workcell,
    ring_workcell,
)

__all__ = ["Realism", "SimCameraSpec", "Workcell", "board_by_name", "load_workcell", "ring_workcell"]
