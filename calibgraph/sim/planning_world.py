"""The planning world of a cell whose camera placements are unknown: the simulator's FR3 model
and the cell's declared geometry (floor, pedestal, obstacles, keep-out boxes), no camera.

The autonomous loop (:mod:`calibgraph.acquire.auto`) plans in it (IK, collisions, occlusion by the
arm) whether the robot is simulated or real; the simulated cell that renders the images is a
separate world, so the planner never sees the true placements.
"""

from __future__ import annotations

from calibgraph.plan.cell import CellDescription
from calibgraph.sim.render import SimWorld
from calibgraph.sim.workcell import Workcell


def planning_world(cell: CellDescription) -> SimWorld:
    """A :class:`SimWorld` (a :class:`calibgraph.plan.planner.RobotWorld`) of ``cell`` without cameras."""
    wc = Workcell(name=f"{cell.name}_planning", target=cell.target, T_flange_board=cell.T_flange_board, cameras=(),
                  floor_z_m=cell.floor_z_m, obstacles=cell.obstacles, planning_only=True)
    return SimWorld(wc)
