"""04 — Plan a calibration trajectory for a cell and check it with a dry run: nothing moves.

    MUJOCO_GL=egl python scripts/examples/04_plan_and_capture_dry_run.py [--poses 8] [--out traj.yaml]

The planner needs a model of the arm (IK, collisions, occlusion): here the simulator's MuJoCo FR3
(``pip install -e ".[sim]"``). The dry run checks every pose and every motion against the safety
limits, as ``calibgraph capture --dry-run`` does before a real robot is allowed to move.
"""

import argparse
import sys
import tempfile
from pathlib import Path

import calibgraph as cg
from calibgraph.acquire.run import run_acquisition
from calibgraph.acquire.safety import SafetyLimits
from calibgraph.sim.render import SimWorld
from calibgraph.sim.workcell import ring_workcell


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=8)
    ap.add_argument("--out", type=Path, default=None, help="trajectory file to write")
    args = ap.parse_args(argv)

    cell = ring_workcell(n_cameras=3, distance_m=3.0, preset_name="l515")
    world = SimWorld(cell)
    try:
        trajectory = cg.plan_trajectory(world, n_poses=args.poses, seed=0)
    finally:
        world.close()
    print(f"planned {trajectory.n_capture} capture poses (+{trajectory.n_via} via poses); "
          f"views per camera {trajectory.views_per_camera()}")
    if args.out:
        trajectory.save(args.out)
        print(f"wrote {args.out}")
    with tempfile.TemporaryDirectory() as tmp:
        report = run_acquisition(None, {}, trajectory, Path(tmp) / "dataset", cell.target,
                                 safety=SafetyLimits.from_dict({"robot_model": "fr3"}), dry_run=True, progress=False)
    print(report.summary())
    return 0 if report.complete else 1


if __name__ == "__main__":
    try:
        sys.exit(main())
    except cg.CalibgraphError as e:
        sys.exit(f"error: {e}")
