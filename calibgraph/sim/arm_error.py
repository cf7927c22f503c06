"""Synthetic-corner scenes of an arm whose absolute error repeats with its configuration.

A real arm's forward kinematics is off by millimetres (a Franka's absolute accuracy), and the error
is not random from capture to capture: it is a function of the joint angles (the link lengths and
twists, the joint zero offsets of the arm as built differ from its model), so a capture that
revisits a joint target has exactly the error it had the first time, and captures at nearby
targets have nearly the same one. Per-pose FK noise, as :mod:`calibgraph.sim.synthetic_corners`
draws it, is the wrong model of such an arm; this module draws the right one:

- the **true arm** is the built-in FR3 chain with every joint origin but the first turned and
  shifted by a small random amount (``link_sigma_m``, ``link_sigma_rad``) and joints 2-6 off their
  zero by ``offset_sigma_rad``. The base-to-joint-1 origin, joint 1's zero (a turn of the whole arm)
  and joint 7's zero and the flange (a roll or shift of the last link) are left exact: they are
  gauges a calibration absorbs into the cameras or the mount, and leaving them out keeps the
  simulated truth of the cameras the one the data can reach;
- each **configuration** (a flange pose from the scene geometry of ``make_scene``, eye-to-hand or
  eye-in-hand, solved for the FR3's joint angles within its limits) is captured ``sessions`` times
  (session after session in the same order, as a calibration re-run with the same joint targets);
  the robot reports the joint angles ``q`` and the nominal FK of them, the flange is where the true
  arm puts it for ``q`` times a small repeatability error (``repeat_sigma_m``, fresh per capture),
  and the corners are projected from there with the true intrinsics and fresh Gaussian pixel noise;
- optionally a camera is **moved** (``move``: capture index, shift m, turn deg) and the board
  **printed off scale** (``board_scale``): the claims the solver must still make.

The problem states the FK accuracy the solver is told (``stated_fk_sigma_*``, Panda class by default),
not the true one: the arm departs from it, as a real one does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.acquire.safety import FRANKA_LIMITS
from calibgraph.core.camera import preset
from calibgraph.core.kinematics import SerialChain, franka_chain
from calibgraph.core.problem import Capture, Detection, Problem, SolverOptions
from calibgraph.core.targets import Target, a4_board_54
from calibgraph.core.transforms import exp_so3, inv, make_T
from calibgraph.sim.kinematic_scene import READY_Q_RAD, ik
from calibgraph.sim.reported_intrinsics import FACTORY
from calibgraph.sim.synthetic_corners import Scene, Truth, make_scene, reported_cameras, ring_cameras

# the default arm: link origins off by 0.5 mm / 0.5 mrad, zero offsets 1 mrad (about 1.5-3 mm of absolute
# error at the flange over the workspace, a Franka's order)
LINK_SIGMA_M = 5e-4
LINK_SIGMA_RAD = 5e-4
OFFSET_SIGMA_RAD = 1e-3
OFFSET_JOINTS = (1, 2, 3, 4, 5)  # joints 2-6 (0-based): joint 1 and joint 7 are gauges


@dataclass(frozen=True)
class ArmTruth:
    """The true arm and what it did: ``chain`` (the arm as built), ``offsets_rad`` (7,) (physical =
    reported + offset), per capture the configuration it revisits (``configuration``), the flange
    error of the true arm against the nominal FK (``flange_error_m``: position error at the flange,
    m, per configuration), and the claims made true (``moved``: camera, first capture after, the
    pose after; ``board_scale``)."""

    chain: SerialChain
    offsets_rad: np.ndarray
    configuration: dict
    flange_error_m: np.ndarray
    moved: tuple | None = None
    board_scale: float = 1.0
    test: Problem | None = None  # held-out configurations (``test_configs``), captured once each

    @property
    def rms_error_mm(self) -> float:
        return float(1e3 * np.sqrt(np.mean(self.flange_error_m ** 2)))


def perturbed_arm(chain: SerialChain, rng, link_sigma_m: float = LINK_SIGMA_M, link_sigma_rad: float = LINK_SIGMA_RAD,
                  offset_sigma_rad: float = OFFSET_SIGMA_RAD) -> tuple[SerialChain, np.ndarray]:
    """(the arm as built, its joint zero offsets (n,)): ``chain`` with the origins of joints 2..n turned
    and shifted at random (right perturbation of each origin) and joints 2-6 off their zero."""
    T = chain.T_prev_origin.copy()
    for i in range(1, chain.n_joints):
        T[i] = T[i] @ make_T(exp_so3(rng.normal(scale=link_sigma_rad, size=3)), rng.normal(scale=link_sigma_m, size=3))
    o = np.zeros(chain.n_joints)
    idx = [j for j in OFFSET_JOINTS if j < chain.n_joints]
    o[idx] = rng.normal(scale=offset_sigma_rad, size=len(idx))
    return SerialChain(chain.name + " as built", chain.joint_names, T, chain.axes, chain.T_last_flange,
                       chain.link_names, chain.flange_link, None), o


def _configurations(mode: str, cameras, target, n_configs: int, seed: int, chain, **scene_kw) -> list:
    """[(q (7,), T_base_flange nominal, cameras that see the board)] for ``n_configs`` reachable poses."""
    lim = FRANKA_LIMITS["fr3"]
    q_lo, q_hi = np.array(lim["q_min_rad"]) + 0.05, np.array(lim["q_max_rad"]) - 0.05
    base = make_scene(cameras=cameras, target=target, n_poses=4 * n_configs, pixel_sigma_px=0.0, mode=mode,
                      seed=seed, reported_intrinsics="exact", **scene_kw)
    seen = {}
    for d in base.problem.detections:
        seen.setdefault(d.capture, []).append(d.camera)
    out = []
    for c in base.problem.captures:
        if len(out) >= n_configs:
            break
        T_bf = base.truth.T_base_flange_true[c.index]
        yaw = np.arctan2(T_bf[1, 3], T_bf[0, 3])
        starts = [READY_Q_RAD + np.r_[yaw, np.zeros(6)], READY_Q_RAD + np.r_[yaw, 0, 0, 0, 0, 0, np.pi / 2],
                  READY_Q_RAD + np.r_[yaw, 0, 0, 0, 0, 0, -np.pi / 2],
                  READY_Q_RAD + np.r_[yaw, 0.3, 0, 0.5, 0, -0.5, -1.5]]
        q = ik(chain, T_bf, q_lo, q_hi, starts)
        if q is not None:
            out.append((q, T_bf, seen[c.index]))
    return out, base


def arm_error_scene(mode: str = "eye_to_hand", n_configs: int = 12, sessions: int = 1, cameras: dict | None = None,
                    target: Target | None = None, pixel_sigma_px: float = 0.2, arm_scale: float = 1.0,
                    repeat_sigma_m: float = 2e-5, record_joint_angles: bool = True,
                    stated_fk_sigma_translation_m: float = 1e-4,
                    stated_fk_sigma_rotation_rad: float = float(np.radians(0.01)),
                    move: tuple | None = None, board_scale: float = 1.0, reported_intrinsics=FACTORY,
                    options: SolverOptions | None = None, test_configs: int = 0, seed: int = 0,
                    **scene_kw) -> tuple[Scene, ArmTruth]:
    """A seeded scene of an arm whose error repeats with its configuration (module docstring).

    Args:
        mode: 'eye_to_hand' (``cameras`` name -> (T_base_cam, Intrinsics); default one L515 at 1.5 m and
            one at 2.5 m) or 'eye_in_hand' (``cameras`` name -> (T_flange_cam, Intrinsics); default one D455
            on the flange, the board on the table, 0.3-0.6 m away).
        n_configs: distinct joint targets; ``sessions``: how many times each is captured (in order).
        arm_scale: the true arm's link and zero errors in units of the defaults (0: an exact arm).
        record_joint_angles: the captures carry ``q_rad`` (else only ``T_base_flange``).
        move: (capture index, shift m, turn deg[, camera]): the camera (default the first) is knocked
            before that capture (a random direction and axis), its later views projected from there.
        board_scale: the printed board's true size over the declared one (the problem states the declared).
        reported_intrinsics: what the solver is told (factory-class by default; 'exact' for an oracle).
        test_configs: that many more configurations, each captured once after the sessions, held out of
            the problem: ``ArmTruth.test`` holds them (a problem of their captures, same cameras), to score
            predictions of new poses from their reported FK.
        scene_kw: passed to ``make_scene`` for the geometry (``tilt_deg``, ``eye_in_hand_distance_m``, ...).
    Returns:
        (Scene with the problem and the truth (``T_base_flange_true``: the true flange pose per capture),
        ArmTruth).
    """
    rng = np.random.default_rng(seed + 15485863)
    target = target or a4_board_54()
    nominal = franka_chain()
    if cameras is None:
        if mode == "eye_in_hand":
            cameras = {"wrist": (make_T(exp_so3([0, 0, np.pi / 2]), [0.06, 0.0, 0.04]),
                                 replace(preset("d455"), source="exact"))}
        else:
            cameras = ring_cameras([1.5, 2.5], spread_deg=90.0, start_deg=-45.0)
    configs, base = _configurations(mode, cameras, target, n_configs + test_configs, seed, nominal, **scene_kw)
    if not configs:
        raise ValueError("no reachable configuration for this geometry")
    true_arm, o = perturbed_arm(nominal, rng, LINK_SIGMA_M * arm_scale, LINK_SIGMA_RAD * arm_scale,
                                OFFSET_SIGMA_RAD * arm_scale)
    pts = base.problem.points_board_m
    pts_true = pts * board_scale
    T_mount_board = base.truth.T_mount_board
    T_ref_cam = {n: c[0] for n, c in cameras.items()}
    intr_true = {n: c[1] for n, c in cameras.items()}
    moved_cam = move[3] if move is not None and len(move) > 3 else next(iter(cameras))
    T_after = None
    if move is not None:
        u, w = rng.normal(size=3), rng.normal(size=3)
        T_after = T_ref_cam[moved_cam].copy()
        T_after[:3, :3] = exp_so3(w / np.linalg.norm(w) * np.radians(move[2])) @ T_after[:3, :3]
        T_after[:3, 3] += u / np.linalg.norm(u) * move[1]
    configs, tests = configs[:n_configs], configs[n_configs:]
    captures, dets, flange_true, configuration = [], [], {}, {}
    err = []
    for q, _, _ in configs:
        err.append(true_arm.fk(q + o)[:3, 3] - nominal.fk(q)[:3, 3])
    plan = [(j, c) for _ in range(sessions) for j, c in enumerate(configs)]
    plan += [(n_configs + j, c) for j, c in enumerate(tests)]
    n_train = None
    for i, (j, (q, T_bf_nom, seen)) in enumerate(plan):
        if i == sessions * len(configs):
            n_train = len(captures)
        k = len(captures)
        T_true = true_arm.fk(q + o) @ make_T(np.eye(3), rng.normal(scale=repeat_sigma_m, size=3))
        views = []
        for name in seen:
            T_cam = T_after if (move is not None and name == moved_cam and k >= move[0]) else T_ref_cam[name]
            if mode == "eye_to_hand":
                T_cb = inv(T_cam) @ T_true @ T_mount_board
            else:
                T_cb = inv(T_true @ T_cam) @ T_mount_board
            p_cam = pts_true @ T_cb[:3, :3].T + T_cb[:3, 3]
            if np.any(p_cam[:, 2] < 0.05):
                continue
            uv = intr_true[name].project(p_cam)
            if not np.all(intr_true[name].in_image(uv, margin_px=2)):
                continue
            views.append(Detection(camera=name, capture=k, ids=np.arange(len(pts)),
                                   uv_px=uv + rng.normal(scale=pixel_sigma_px, size=uv.shape)))
        if not views:
            continue
        captures.append(Capture(index=k, T_base_flange=T_bf_nom, q_rad=q if record_joint_angles else None))
        dets += views
        flange_true[k], configuration[k] = T_true, j
    opts = options or SolverOptions(fk_sigma_translation_m=stated_fk_sigma_translation_m,
                                    fk_sigma_rotation_rad=stated_fk_sigma_rotation_rad)
    n_train = len(captures) if n_train is None else n_train

    def part(keep):
        return Problem(points_board_m=pts, cameras=reported_cameras(cameras, reported_intrinsics),
                       captures=tuple(c for c in captures if keep(c.index)),
                       detections=tuple(d for d in dets if keep(d.capture)), mode=mode, method="joint", options=opts,
                       target=target)

    problem = part(lambda k: k < n_train)
    test = part(lambda k: k >= n_train) if tests else None
    truth_cams = dict(T_ref_cam)
    if move is not None:
        truth_cams[moved_cam] = T_after  # where it stands now
    truth = Truth(truth_cams, T_mount_board, flange_true, intr_true)
    arm = ArmTruth(true_arm, o, configuration, np.array(err),
                   (moved_cam, move[0], T_after) if move is not None else None, board_scale, test)
    return Scene(problem, truth), arm
