"""Write a rendered simulated dataset: run the real acquisition state machine on the simulated cell.

:func:`simulate_dataset` builds the world, wraps it in :class:`SimRobot`/:class:`SimCamera`, and
hands them to :func:`calibgraph.acquire.run.run_acquisition` — the same capture pipeline that runs
on hardware (detection on the spot, atomic capture files, journal). It then writes
``ground_truth.json`` beside the data::

    {"format": "calibgraph-ground-truth/1",
     "frame_convention": "...",
     "mode": "eye_to_hand",
     "T_flange_board": 4x4,
     "cameras": {"cam0": {"T_base_cam": 4x4, "intrinsics_true": {K, dist, width_px, height_px},
                          "intrinsics_reported": {K, dist, width_px, height_px, source},
                          "intrinsics": (= intrinsics_true), "preset": "l515"}},
     "captures": {"0": {"T_base_flange_true": 4x4, "T_base_flange_reported": 4x4, "q_rad": [...],
                        "q_rad_true": [...]}},
     "robot": {"fk_sigma_translation_m": ..., "fk_sigma_rotation_deg": ..., "joint_offsets_rad": [7 values]},
     "realism": {...}, "workcell": {...explicit workcell mapping...}}

``T_base_flange_true`` is the noise-free flange pose at the true joint angles (``q_rad_true`` =
reported ``q_rad`` + ``robot.joint_offsets_rad``); the capture files hold the reported one. Likewise
the images are rendered with ``intrinsics_true`` while ``dataset.yaml`` holds what the cameras
report (``intrinsics_reported``: factory-class errors, ``source: factory``, unless the workcell's
``realism.reported_intrinsics`` is ``exact``).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calibgraph.acquire.run import run_acquisition
from calibgraph.detect.corners import detect_image
from calibgraph.io.files import read_input_bytes
from calibgraph.io.ground_truth import write_ground_truth_file
from calibgraph.plan.trajectory import load_trajectory
from calibgraph.sim.devices import board_plainly_hidden, make_devices
from calibgraph.sim.render import SimWorld
from calibgraph.sim.workcell import Workcell, realism_to_dict, workcell_to_dict


def write_ground_truth(out_dir, cell: Workcell, world=None) -> Path:
    """Write ``ground_truth.json`` for the captures already in ``out_dir``.

    True flange poses come from the joint angles stored in each capture file plus the cell's joint
    offsets (exact in the simulation) through the MuJoCo model's kinematics.
    """
    out = Path(out_dir)
    if world is None:
        world = SimWorld(cell)
    caps = {}
    offsets = np.asarray(cell.joint_offsets_rad, float)
    for f in sorted((out / "captures").glob("*.json")):
        d = json.loads(read_input_bytes(f, "capture file"))
        q = d.get("q_rad")
        if q is None:
            continue
        q0 = world.q()
        q_true = np.asarray(q, float) + offsets
        world.set_q(q_true)
        caps[str(d["index"])] = {"T_base_flange_true": world.T_base_flange().tolist(),
                                 "T_base_flange_reported": d["T_base_flange"], "q_rad": q, "q_rad_true": q_true.tolist()}
        world.set_q(q0)
    gt = {
        "mode": "eye_to_hand",
        "T_flange_board": np.asarray(cell.T_flange_board).tolist(),
        "cameras": {c.name: {"T_base_cam": np.asarray(c.T_base_cam).tolist(), "intrinsics_true": _true(c.intrinsics),
                             "intrinsics_reported": cell.reported_intrinsics(c.name).to_dict(),
                             "intrinsics": _true(c.intrinsics), "preset": c.preset} for c in cell.cameras},
        "captures": caps,
        "robot": {"model": "franka_fr3 (franky-sim MJCF)", "fk_sigma_translation_m": cell.fk_sigma_translation_m,
                  "fk_sigma_rotation_deg": cell.fk_sigma_rotation_deg, "joint_offsets_rad": offsets.tolist()},
        "realism": realism_to_dict(cell.realism),
        "workcell": workcell_to_dict(cell),
    }
    return write_ground_truth_file(out, gt)


def _true(intr) -> dict:
    """K, dist and image size of true intrinsics (no source: they are what the renderer used)."""
    d = intr.to_dict()
    d.pop("source", None)
    return d


class VisibilityGatedDetector:
    """Detector for simulated captures that skips frames in which the board is plainly not in view.

    A failed search on a full frame costs seconds (the detector up-scales regions looking for a
    far board), and most frames of a cell with cameras around the robot show the board's back or
    nothing. This gate asks the simulation's ground truth, with looser limits than the planner
    (board inside the image, facing the camera within 80 degrees, squares >= 3 px, no occlusion
    test), and runs the real detector on every frame that passes, so marginal views are still
    decided by the detector. Frames it skips are reported as "board not in view (simulation
    shortcut)". ``simulate_dataset(..., gate=False)`` runs the detector on every frame.
    """

    def __init__(self, world, detector=None):
        self.world = world
        self.detector = detector
        self.skipped = 0

    def __call__(self, image, target, intrinsics=None):
        cam = self.world.last_frame_camera.pop(id(image), None)
        if cam is not None and board_plainly_hidden(self.world, cam):
            self.skipped += 1
            return None
        det = self.detector or detect_image
        return det(image, target, intrinsics)


def simulate_dataset(cell: Workcell, trajectory, out_dir, world=None, progress=True, detector=None,
                     resume: bool = False, gate: bool = True):
    """Capture a simulated dataset of ``cell`` along ``trajectory`` into ``out_dir``.

    Args:
        cell: the workcell.
        trajectory: a :class:`calibgraph.plan.trajectory.Trajectory` (what
            :func:`calibgraph.plan.planner.plan_trajectory` returns) or a path to a trajectory YAML.
        out_dir: new dataset folder.
        world: an existing :class:`SimWorld` of ``cell`` (saves compiling the model again).
        progress: True (lines on stderr), False, or a callable receiving progress lines.
        detector: passed to the acquisition (default :func:`calibgraph.detect.corners.detect_image`).
        gate: wrap the detector in :class:`VisibilityGatedDetector` (skip frames whose board is
            plainly out of view, for speed) and let cameras skip rendering those frames.
    Returns:
        the acquisition's :class:`calibgraph.acquire.run.AcquisitionReport`.
    """

    if isinstance(trajectory, (str, Path)):
        trajectory = load_trajectory(trajectory)
    world = world or SimWorld(cell)
    robot, cams = make_devices(world, cell.fk_sigma_translation_m, np.radians(cell.fk_sigma_rotation_deg), cell.seed)

    if gate:
        detector = VisibilityGatedDetector(world, detector)
    world.skip_hidden_renders = bool(gate)
    report = run_acquisition(robot, cams, trajectory, out_dir, cell.target, detector=detector, resume=resume,
                             progress=progress)
    write_ground_truth(out_dir, cell, world)
    return report
