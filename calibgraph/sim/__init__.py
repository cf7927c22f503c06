"""The simulated workcell: a MuJoCo FR3 arm presenting a board to fixed cameras.

Submodules (MuJoCo is imported only when a world is built):

- :mod:`.workcell` — the cell as data (cameras, board mount, image realism), YAML loader;
- :mod:`.scene` — the MuJoCo model (franky-sim's FR3, board texture, stands, cameras);
- :mod:`.render` — :class:`SimWorld` (model, state, renderer) and sensor degradations;
- :mod:`.ik` — damped-least-squares IK and collision checks;
- :mod:`.devices` — :class:`SimRobot` and :class:`SimCamera`, implementations of
  :mod:`calibgraph.acquire.interfaces`;
- :mod:`.simulate` — write a simulated dataset with its ground truth.
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
