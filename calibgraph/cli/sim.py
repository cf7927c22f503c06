"""``calibgraph sim``: write a simulated dataset (images, captures, ground truth) without solving.

    calibgraph sim --workcell datasets/workcells/default.yaml --out DATASET [--trajectory traj.yaml]

Without ``--trajectory`` a trajectory of ``--poses`` poses is planned for the cell and saved as
``DATASET/planned_trajectory.yaml`` (reusable with ``--trajectory``). The dataset records that
``calibgraph sim`` made it, from which workcell and trajectory (:mod:`calibgraph.acquire.claim`):
``--resume`` continues only such a run with the same inputs.
"""

from __future__ import annotations

import sys
from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("sim", help="simulate a workcell and write a dataset with ground truth",
                       description="Render a MuJoCo workcell (FR3 arm, board on the flange, fixed cameras), run the "
                                   "acquisition state machine on it and write a calibgraph dataset plus "
                                   "ground_truth.json. Needs the 'sim' extra (mujoco, franky-sim).")
    p.add_argument("--workcell", type=Path, default=None,
                   help="workcell YAML (default: 3 L515 cameras around the robot at 3 m)")
    p.add_argument("--trajectory", type=Path, default=None, help="trajectory YAML (default: plan one)")
    p.add_argument("--out", type=Path, required=True, help="new dataset folder")
    p.add_argument("--poses", type=int, default=40, help="poses to plan when no trajectory is given (default 40)")
    p.add_argument("--seed", type=int, default=0, help="seed of the planner")
    p.add_argument("--plan", choices=("information", "random"), default="information",
                   help="how the planner picks the poses: 'information' (default) chooses them from a sampled pool by "
                        "what they pin (far cameras' focal length against depth, the mount, the board scale); 'random' "
                        "takes the first visible ones, as before")
    p.add_argument("--resume", action="store_true", help="continue an interrupted simulated capture")
    p.add_argument("--reported-intrinsics", choices=("factory", "exact"), default=None,
                   help="what the cameras report, overriding the workcell's realism.reported_intrinsics: factory "
                        "(factory-class errors around the true intrinsics, the default) or exact (the true ones: an oracle)")
    p.add_argument("--full-detection", action="store_true",
                   help="run the detector on every frame (default: skip frames whose board is plainly out of view)")
    p.add_argument("--intrinsics-session", type=int, default=None, metavar="N",
                   help="instead of a dataset, write a close-range intrinsics session to --out: N hand-held images "
                        "per camera of the board at 0.3-0.8 m (OUT/<camera>/*.png, OUT/target.yaml, "
                        "OUT/ground_truth.json) for calibgraph intrinsics; no robot, no OpenGL")
    p.add_argument("--quiet", action="store_true", help="no progress lines (warnings and errors still print)")
    return p


def _intrinsics_session(args, cell) -> int:
    from calibgraph.io.output_guard import check_output_folder
    from calibgraph.sim.session import simulate_intrinsics_session

    check_output_folder(args.out, "session folder", empty=True)
    say = None if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    simulate_intrinsics_session(args.out, {c.name: c.intrinsics for c in cell.cameras}, cell.target,
                                args.intrinsics_session, realism=cell.realism, seed=args.seed, progress=say)
    if not args.quiet:
        print(f"wrote {args.out}: {args.intrinsics_session} images per camera of {len(cell.cameras)} cameras; "
              f"calibrate one with: calibgraph intrinsics {args.out / cell.cameras[0].name} --out CAM.yaml")
    return 0


def run(args) -> int:
    from calibgraph.acquire.claim import claim_dataset, content_sha256
    from calibgraph.acquire.workcell import read_workcell
    from calibgraph.core.errors import InputError
    from calibgraph.io.files import output_folder
    from calibgraph.io.output_guard import check_output_folder
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.plan.trajectory import load_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import simulate_dataset
    from calibgraph.sim.workcell import ring_workcell, workcell_from_dict, workcell_to_dict

    check_output_folder(args.out, "dataset folder", claimed=True)  # never inside a dataset; --resume decides on one
    if args.workcell:  # read once: a pipe is refused, degenerate camera geometry too
        cell = workcell_from_dict(read_workcell(args.workcell, "workcell file", hardware=False).data, str(args.workcell))
    else:
        cell = ring_workcell(spread_deg=200.0, name="default")
    if args.reported_intrinsics:
        cell = cell.with_reported_intrinsics(args.reported_intrinsics)
    if args.intrinsics_session is not None:
        if args.intrinsics_session < 1:
            raise InputError("--intrinsics-session must be >= 1 images.")
        return _intrinsics_session(args, cell)
    if not args.trajectory and args.poses < 1:
        raise InputError("--poses must be >= 1.")
    traj = load_trajectory(args.trajectory) if args.trajectory else None
    inputs = {"workcell_sha256": content_sha256(workcell_to_dict(cell)),
              "trajectory_sha256": None if traj is None else traj.sha256()}
    say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    # the dataset is claimed before anything is built: a dataset of another run is refused untouched,
    # a file or a read-only folder is said now, not after simulating
    with claim_dataset(args.out, "sim", inputs, args.resume, say, files={"workcell_file": args.workcell}) as claim:
        output_folder(args.out, "dataset folder")
        say(f"building the simulated workcell {cell.name!r}: {len(cell.cameras)} cameras, board "
            f"{cell.target.rows}x{cell.target.cols} points of {cell.target.pitch_m * 1e3:g} mm, "
            + ("cameras report their true intrinsics (oracle)" if cell.oracle_intrinsics else
               "cameras report factory-class intrinsics"))
        world = SimWorld(cell)
        world.check_rendering()  # no OpenGL: one clear error now, not after planning
        if traj is None:
            traj = plan_trajectory(world, args.poses, seed=args.seed, select=args.plan)
            claim.require({"trajectory_sha256": traj.sha256()})  # a resume with other --poses/--seed: refused here
            traj.save(args.out / "planned_trajectory.yaml")
            via = f" + {traj.n_via} via poses for collision-free motion" if traj.n_via else ""
            say(f"planned {traj.n_capture} poses{via} (expected views per camera: {traj.views_per_camera()}); "
                f"saved {args.out / 'planned_trajectory.yaml'}")
            for note in traj.notes:
                say(f"  plan: {note}")
        report = simulate_dataset(cell, traj, args.out, world=world, progress=False if args.quiet else True,
                                  resume=args.resume, gate=not args.full_detection)
    if not args.quiet:
        print(report.summary())
        print(f"wrote {args.out} (ground truth in {args.out / 'ground_truth.json'})")
    return 0
