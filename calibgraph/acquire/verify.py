"""A verify capture: a handful of poses most sensitive to every camera's motion, captured, tested.

    plan (from the stored result alone) -> capture (the acquisition state machine, its safety) -> verify

1. **Candidates**: board poses aimed at each camera of the stored result, and between pairs of
   neighbouring cameras, at the *stored* ``T_base_cam`` (no placements needed from the cell), made
   reachable and collision-free on the planning world (IK within the joint limits; keep-out volumes
   round the stored camera stands) by :class:`calibgraph.plan.active.ActivePlanner`.
2. **Choice**: :func:`calibgraph.plan.verify.choose_verify_poses` picks ``n_poses`` of them
   greedily by the non-centrality of the worst-placed 2 mm / 0.2 deg bump of every camera (the
   visibility test includes occlusion by the arm at the candidate's joints).
3. **Motion**: the chosen poses are visited in order of base rotation; a motion that collides gets
   via poses (:func:`calibgraph.plan.planner.free_motion`), a pose no via reaches is replaced by
   the next best candidate.
4. **Capture**: :func:`calibgraph.acquire.run.run_acquisition` with the given safety limits
   (joint limits, workspace box along every motion, speed cap) writes an ordinary dataset, with
   the trajectory as ``trajectory.yaml`` (so ``--resume`` works as for any capture).
5. **Verify**: :func:`calibgraph.solver.changes.verify.verify` on the dataset; the verdict is written to
   ``verify.json`` in the dataset.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibgraph.acquire.run import run_acquisition
from calibgraph.acquire.safety import FRANKA_LIMITS
from calibgraph.core.errors import InputError
from calibgraph.io.files import atomic_write_text
from calibgraph.io.layouts import load_dataset
from calibgraph.plan.active import ActivePlanner, CameraBelief
from calibgraph.plan.planner import free_motion
from calibgraph.plan.trajectory import Trajectory, TrajectoryPose
from calibgraph.plan.verify import choose_verify_poses
from calibgraph.plan.visibility import board_visible
from calibgraph.solver.solve.build import build_problem
from calibgraph.solver.changes.verify import DEFAULT_ALPHA, stored_model, verify

__all__ = ["plan_verify_trajectory", "run_verify_capture", "VerifyCaptureReport", "VERIFY_NAME"]

VERIFY_NAME = "verify.json"


def _beliefs(model, names) -> dict:
    return {n: CameraBelief(n, model.intrinsics[n], model.T_base_cam[n], model.covariance[n], 1) for n in names}


def plan_verify_trajectory(result: dict, cell, world, n_poses: int = 5, n_candidates: int = 60, q_start=None,
                           seed: int = 0, max_step_rad: float = 0.03, where: str = "result") -> Trajectory:
    """A :class:`Trajectory` of ``n_poses`` capture poses (plus via poses) chosen from the stored
    ``result`` (a result dict) for the cameras it shares with ``cell`` (module docstring). The
    planning ``world`` is a :class:`~calibgraph.plan.planner.RobotWorld` of the cell without cameras;
    its state is restored."""
    if int(n_poses) < 1:
        raise InputError(f"verify: --verify-poses must be >= 1, got {n_poses}.")
    model = stored_model(result, where)
    names = [n for n in cell.camera_names if n in model.T_base_cam]
    if not names:
        raise InputError(f"{where}: none of the cell's cameras ({', '.join(cell.camera_names)}) is in the stored result "
                         f"({', '.join(model.T_base_cam)}).")
    beliefs = _beliefs(model, names)
    T_fb = model.T_flange_board
    q_saved = world.q()
    try:
        q0 = world.start_configuration() if q_start is None else np.asarray(q_start, float).reshape(-1)
        planner = ActivePlanner(world, cell, FRANKA_LIMITS["fr3"]["dq_max_rad_s"], seed=seed)
        # every camera gets candidates aimed at it (and between it and a neighbour)
        for n in names:
            planner.top_up({k: beliefs[k] for k in names}, {k: 1.0 if k == n else 0.0 for k in names},
                           max(4, n_candidates // len(names)), q0, T_fb)
        pool = list(planner.pool)
        if not pool:
            raise InputError("verify: no reachable, collision-free board pose in view of a stored camera; "
                             "check the cell's obstacles and that the result belongs to this cell.")

        def visible(i, name):
            world.set_q(pool[i].q_rad)
            return board_visible(model.intrinsics[name], model.T_base_cam[name], cell.target,
                                 pool[i].T_base_flange @ T_fb, occluded=world.occluded)

        cams = {n: (model.intrinsics[n], model.T_base_cam[n], model.covariance[n]) for n in names}
        order, _ = choose_verify_poses([c.T_base_flange for c in pool], cams, T_fb, cell.target, len(pool),
                                       model.pixel_sigma_px, visible=visible)
        seen = {i: tuple(n for n in names if visible(i, n)) for i in order}
        chosen = []
        for i in order:  # best first; a pose that no free motion reaches is replaced by the next
            if len(chosen) == n_poses:
                break
            if seen[i]:
                chosen.append(i)
        chosen.sort(key=lambda i: float(pool[i].q_rad[0]))
        seq, q, spare = [], q0, [i for i in order if i not in chosen and seen[i]]
        todo = list(chosen)
        while todo:
            i = todo.pop(0)
            motion = free_motion(world, q, pool[i].q_rad, max_step_rad)
            if motion is None:
                if spare:
                    todo.append(spare.pop(0))
                continue
            for v in motion[:-1]:
                world.set_q(v)
                seq.append(TrajectoryPose(q_rad=v, T_base_flange=world.T_base_flange(), capture=False))
            seq.append(TrajectoryPose(q_rad=pool[i].q_rad, T_base_flange=pool[i].T_base_flange, cameras=seen[i]))
            q = pool[i].q_rad
        if not any(p.capture for p in seq):
            raise InputError("verify: no verify pose could be reached by a collision-free motion.")
    finally:
        world.set_q(q_saved)
    n_cap = sum(p.capture for p in seq)
    notes = [f"verify poses: {n_cap} of {len(pool)} candidates, chosen from {where} for the worst-placed "
             f"2 mm / 0.2 deg bump of {', '.join(names)}"]
    return Trajectory(poses=tuple(seq), workcell=cell.name, seed=seed, notes=tuple(notes))


@dataclass(frozen=True)
class VerifyCaptureReport:
    """The acquisition's report and the verify verdict (None after a dry run or a stopped capture)."""

    acquisition: object
    verify: object
    verdict_path: Path | None


def run_verify_capture(robot, cameras, result: dict, cell, world, out_dir, detector=None, safety=None, n_poses: int = 5,
                       alpha: float = DEFAULT_ALPHA, resume: bool = False, dry_run: bool = False, seed: int = 0,
                       settle_dwell_s: float = 0.0, progress=True, where: str = "result") -> VerifyCaptureReport:
    """Plan a verify trajectory from ``result``, capture it with ``robot`` and ``cameras`` into
    ``out_dir`` and run the verify (module docstring). With ``resume`` the dataset's
    ``trajectory.yaml`` is continued instead of planning anew."""
    out_dir = Path(out_dir)
    say = progress if callable(progress) else (lambda s: print(s, file=sys.stderr, flush=True)) if progress else None
    if resume and (out_dir / "trajectory.yaml").is_file():
        traj = Trajectory.load(out_dir / "trajectory.yaml")
    else:
        q0 = None
        if robot is not None:
            try:
                q0 = np.asarray(robot.joint_positions(), float)
            except Exception:  # a robot that cannot report its joints: plan from the world's start
                q0 = None
        traj = plan_verify_trajectory(result, cell, world, n_poses=n_poses, q_start=q0, seed=seed, where=where)
    if say:
        say(f"verify trajectory: {traj.n_capture} poses (+{traj.n_via} via), expected views {traj.views_per_camera()}")
    names = set(stored_model(result, where).T_base_cam)
    cams = {n: c for n, c in (cameras.items() if isinstance(cameras, dict) else ((c.name, c) for c in cameras))
            if n in names}
    if not cams and not dry_run:
        raise InputError(f"verify: no camera of the stored result is connected (result: {', '.join(sorted(names))}).")
    rep = run_acquisition(robot, cams, traj, out_dir, cell.target, detector=detector, resume=resume, safety=safety,
                          progress=progress, dry_run=dry_run, settle_dwell_s=settle_dwell_s)
    if dry_run or rep.stopped_reason:
        return VerifyCaptureReport(rep, None, None)
    problem, _ = build_problem(load_dataset(out_dir), progress=False)
    vr = verify(problem, result, alpha=alpha, where=where)
    d = vr.to_dict()
    d.update({"result": where, "dataset": str(out_dir)})
    path = atomic_write_text(out_dir / VERIFY_NAME, json.dumps(d, indent=2))
    return VerifyCaptureReport(rep, vr, path)
