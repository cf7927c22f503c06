"""Synthetic-corner scenes of an arm with joint zero offsets, for tests and the kinematics benchmark.

:func:`make_kinematic_scene` takes the geometry of :func:`calibgraph.sim.synthetic_corners.make_scene` (cameras on
a ring, the board presented with varied tilts), solves the arm's inverse kinematics for each flange
pose (the built-in Franka FR3 chain within the FR3's joint limits; poses it cannot reach are
dropped), and then makes the data a real arm gives: the robot reports ``q_rad`` = true angles -
offsets and ``T_base_flange`` = nominal FK of the reported angles; the true flange pose is
``FK(q_true)`` times a small per-pose error (repeatability, the FK sigmas), and the corners are
projected from it (with the true intrinsics) with Gaussian pixel noise. The problem holds the
intrinsics the cameras report (``reported_intrinsics``, as in ``make_scene``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.acquire.safety import FRANKA_LIMITS
from calibgraph.core.kinematics import franka_chain
from calibgraph.core.problem import Capture, Detection, Problem, SolverOptions
from calibgraph.core.transforms import exp_so3, inv, make_T
from calibgraph.sim.synthetic_corners import Scene, Truth, make_scene

# a comfortable FR3 configuration ("ready" pose) and the IK's other starts around it
READY_Q_RAD = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])


def ik(chain, T_goal: np.ndarray, q_lo: np.ndarray, q_hi: np.ndarray, starts, iterations: int = 100):
    """Joint angles reaching ``T_goal`` within the limits (damped least squares from each start), or None."""
    import gtsam

    for q0 in starts:
        q = np.clip(np.asarray(q0, float), q_lo, q_hi)
        for _ in range(iterations):
            T, J = chain.fk_jacobian(q)
            e = gtsam.Pose3(T).localCoordinates(gtsam.Pose3(T_goal))
            if np.abs(e).max() < 1e-11:
                return q
            dq = np.linalg.solve(J.T @ J + 1e-6 * np.eye(len(q)), J.T @ e)
            q = np.clip(q + dq, q_lo, q_hi)
        T = chain.fk(q)
        if np.abs(gtsam.Pose3(T).localCoordinates(gtsam.Pose3(T_goal))).max() < 1e-9:
            return q
    return None


@dataclass(frozen=True)
class KinematicTruth:
    """The true joint offsets (rad, physical = reported + offset) and true joint angles per capture."""

    joint_offsets_rad: np.ndarray
    q_true_rad: dict


def make_kinematic_scene(joint_offsets_rad=None, n_poses: int = 60, pixel_sigma_px: float = 0.3,
                         fk_sigma_translation_m: float = 1e-4, fk_sigma_rotation_rad: float = float(np.radians(0.01)),
                         cameras: dict | None = None, options: SolverOptions | None = None, seed: int = 0,
                         **scene_kw) -> tuple[Scene, KinematicTruth]:
    """A seeded eye-to-hand scene whose captures carry joint angles of an FR3 with ``joint_offsets_rad``
    (7,) (default none). ``options`` default to the FK sigmas given; ``scene_kw`` go to ``make_scene``
    (``reported_intrinsics`` among them). Returns (Scene, KinematicTruth)."""
    rng = np.random.default_rng(seed + 7919)
    o = np.zeros(7) if joint_offsets_rad is None else np.asarray(joint_offsets_rad, float).reshape(7)
    chain = franka_chain()
    lim = FRANKA_LIMITS["fr3"]
    q_lo, q_hi = np.array(lim["q_min_rad"]) + 0.05, np.array(lim["q_max_rad"]) - 0.05
    base = make_scene(cameras=cameras, n_poses=3 * n_poses, pixel_sigma_px=0.0, seed=seed, **scene_kw)
    prob, truth = base.problem, base.truth
    T_fb = truth.T_mount_board
    pts = prob.points_board_m
    by_cap = {}
    for d in prob.detections:
        by_cap.setdefault(d.capture, []).append(d.camera)
    captures, dets, flange_true, q_true = [], [], {}, {}
    for c in prob.captures:
        if len(captures) >= n_poses:
            break
        T_bf = truth.T_base_flange_true[c.index]
        yaw = np.arctan2(T_bf[1, 3], T_bf[0, 3])
        starts = [READY_Q_RAD + np.r_[yaw, np.zeros(6)], READY_Q_RAD + np.r_[yaw, 0, 0, 0, 0, 0, np.pi / 2],
                  READY_Q_RAD + np.r_[yaw, 0, 0, 0, 0, 0, -np.pi / 2], READY_Q_RAD + np.r_[yaw, 0.3, 0, 0.5, 0, -0.5, -1.5]]
        q = ik(chain, T_bf, q_lo, q_hi, starts)
        if q is None:
            continue
        k = len(captures)
        q_rep = q - o
        T_true = chain.fk(q) @ make_T(exp_so3(rng.normal(scale=fk_sigma_rotation_rad, size=3)),
                                      rng.normal(scale=fk_sigma_translation_m, size=3))
        captures.append(Capture(index=k, T_base_flange=chain.fk(q_rep), q_rad=q_rep))
        flange_true[k], q_true[k] = T_true, q
        for name in by_cap[c.index]:
            T_cb = inv(truth.T_ref_cam[name]) @ T_true @ T_fb
            uv = truth.intrinsics[name].project(pts @ T_cb[:3, :3].T + T_cb[:3, 3])
            dets.append(Detection(camera=name, capture=k, ids=np.arange(len(pts)),
                                  uv_px=uv + rng.normal(scale=pixel_sigma_px, size=uv.shape)))
    opts = options or SolverOptions(fk_sigma_translation_m=fk_sigma_translation_m,
                                    fk_sigma_rotation_rad=fk_sigma_rotation_rad)
    problem = replace(prob, captures=tuple(captures), detections=tuple(dets), options=opts)
    return (Scene(problem, Truth(truth.T_ref_cam, T_fb, flange_true, truth.intrinsics)),
            KinematicTruth(o, q_true))


def kinematic_scene_from_trajectory(cell, trajectory, joint_offsets_rad=None, pixel_sigma_px: float = 0.3,
                                    options: SolverOptions | None = None, seed: int = 0) -> tuple[Scene, KinematicTruth]:
    """Synthetic corners (not rendered) of a simulated workcell along a planned trajectory.

    ``cell``: a :class:`calibgraph.sim.workcell.Workcell` (cameras, board, mount, FK sigmas);
    ``trajectory``: a :class:`calibgraph.plan.trajectory.Trajectory` planned for it (its capture
    poses' ``q_rad`` are taken as the robot's commanded = reported angles, and ``cameras`` as the
    cameras that see the board). As :class:`calibgraph.sim.devices.SimRobot` does, the arm turns to
    ``q_rad + offsets``, reports ``q_rad`` and the nominal FK of it; the true flange pose carries the
    cell's per-pose repeatability error; every board point is projected through the true chain
    and the true intrinsics, with Gaussian pixel noise (views leaving the image are dropped); the
    problem holds the intrinsics the cell's cameras report (its ``realism.reported_intrinsics``).
    ``options`` default to the cell's FK sigmas.
    """
    rng = np.random.default_rng(seed + 104729)
    o = np.zeros(7) if joint_offsets_rad is None else np.asarray(joint_offsets_rad, float).reshape(7)
    chain = franka_chain()
    fk_t, fk_r = cell.fk_sigma_translation_m, float(np.radians(cell.fk_sigma_rotation_deg))
    pts = cell.target.points_board_m
    cams = {c.name: c for c in cell.cameras}
    captures, dets, flange_true, q_true = [], [], {}, {}
    for p in trajectory.poses:
        if not p.capture or not p.cameras:
            continue
        q_rep = np.asarray(p.q_rad, float)
        q = q_rep + o
        T_true = chain.fk(q) @ make_T(exp_so3(rng.normal(scale=fk_r, size=3)), rng.normal(scale=fk_t, size=3))
        views = []
        for name in p.cameras:
            spec = cams[name]
            T_cb = inv(spec.T_base_cam) @ T_true @ cell.T_flange_board
            pc = pts @ T_cb[:3, :3].T + T_cb[:3, 3]
            uv = spec.intrinsics.project(pc) + rng.normal(scale=pixel_sigma_px, size=(len(pts), 2))
            w, h = spec.intrinsics.width_px, spec.intrinsics.height_px
            if np.all(pc[:, 2] > 0.2) and np.all((uv >= 0) & (uv < [w, h])):
                views.append(Detection(camera=name, capture=len(captures), ids=np.arange(len(pts)), uv_px=uv))
        if not views:
            continue
        k = len(captures)
        captures.append(Capture(index=k, T_base_flange=chain.fk(q_rep), q_rad=q_rep))
        dets += views
        flange_true[k], q_true[k] = T_true, q
    opts = options or SolverOptions(fk_sigma_translation_m=fk_t, fk_sigma_rotation_rad=fk_r)
    problem = Problem(points_board_m=pts, cameras=cell.intrinsics(), captures=tuple(captures),
                      detections=tuple(dets), options=opts)
    truth = Truth({n: c.T_base_cam for n, c in cams.items()}, np.asarray(cell.T_flange_board), flange_true,
                  cell.true_intrinsics())
    return Scene(problem, truth), KinematicTruth(o, q_true)
