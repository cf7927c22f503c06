"""Seeded synthetic workcells of projected corners with exact ground truth, for tests and benchmarks.

No rendering: corners are projected through the true chain and perturbed with Gaussian pixel
noise; forward-kinematics poses can be perturbed too. The geometry follows the thesis: cameras
on a ring around the robot at a given distance and height, looking at the workspace where the
board is presented with varied tilts, some poses visible from several cameras at once.

The corners come from the cameras' true intrinsics; the problem hands the solver the intrinsics
the cameras *report* (``reported_intrinsics``): by default drawn with factory-class errors
(:mod:`calibgraph.sim.reported_intrinsics`), or ``'exact'``, the true ones (an oracle's problem).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.core.camera import preset
from calibgraph.core.problem import Capture, Detection, Problem, SolverOptions
from calibgraph.core.targets import Target, a4_board_54
from calibgraph.core.transforms import board_facing, exp_so3, inv, look_at, make_T
from calibgraph.solver.terms.noise_model import view_mode_basis
from calibgraph.sim.reported_intrinsics import FACTORY, parse_reported, reported_intrinsics


@dataclass(frozen=True)
class Truth:
    """Ground truth of a synthetic scene.

    ``T_ref_cam[c]`` is ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand);
    ``T_mount_board`` is ``T_flange_board`` (eye-to-hand) or ``T_base_board`` (eye-in-hand).
    ``T_base_flange_true`` are the noise-free flange poses. ``intrinsics`` (name -> Intrinsics) are
    the cameras' true intrinsics, the ones the corners were projected with (``problem.cameras``
    holds what the cameras report); None when a Truth is made without them.
    """

    T_ref_cam: dict
    T_mount_board: np.ndarray
    T_base_flange_true: dict
    intrinsics: dict | None = None


@dataclass(frozen=True)
class Scene:
    """A synthetic :class:`Problem` and the :class:`Truth` it was made from."""

    problem: Problem
    truth: Truth


def reported_cameras(cameras: dict, reported) -> dict:
    """name -> the Intrinsics the solver is given for ``cameras`` (name -> (T, true Intrinsics)):
    the true ones unchanged under ``'exact'``, else drawn (:func:`reported_intrinsics`, seeded by
    the block's seed and the name: a camera reports the same values in every scene, as a real one
    does; Monte Carlo trials that want other cameras vary the block's seed)."""
    reported = parse_reported(reported)
    if reported == "exact":
        return {n: c[1] for n, c in cameras.items()}
    return {n: reported_intrinsics(c[1], n, reported) for n, c in cameras.items()}


# Typical mount: board 12 cm out from the flange, facing along the flange z axis.
# Board front (-z_board) faces along the flange z axis; 12 cm out, slightly off-centre.
DEFAULT_T_FLANGE_BOARD = make_T(exp_so3([0.0, np.pi, 0.0]), [0.03, -0.05, 0.12])

WORKSPACE_CENTRE_M = np.array([0.45, 0.0, 0.55])


def ring_cameras(distances_m, height_m: float = 1.6, presets=("l515",), spread_deg: float = 360.0,
                 centre_m=WORKSPACE_CENTRE_M, start_deg: float = 0.0, rng=None) -> dict:
    """Cameras on a ring around ``centre_m`` at horizontal ``distances_m``, looking at it.

    Returns name -> (T_base_cam, Intrinsics).
    """
    n = len(distances_m)
    cams = {}
    for i, d in enumerate(distances_m):
        ang = np.radians(start_deg + (spread_deg * i / n if spread_deg >= 360 else
                                      (-spread_deg / 2 + spread_deg * i / max(n - 1, 1))))
        eye = centre_m + np.array([d * np.cos(ang), d * np.sin(ang), 0.0])
        eye[2] = height_m
        T = look_at(eye, centre_m + np.array([0, 0, 0.05]))
        intr = replace(preset(presets[i % len(presets)]), source="exact")  # a simulation's own cameras
        cams[f"cam{i}"] = (T, intr)
    return cams


def random_board_facing(T_base_cam: np.ndarray, centre_m: np.ndarray, tilt_deg: float, rng) -> np.ndarray:
    """T_base_board (origin at ``centre_m``) with the board's -z looking at the camera, tilted about a
    random axis by 0.3-1.0 x ``tilt_deg`` and rolled by up to ±36 degrees.

    The unperturbed board is :func:`board_facing`'s turned by 180 degrees about its z (x = up × z), the
    orientation these seeded scenes are defined with; the tilt axis and roll are mapped through that turn."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    tilt = axis * np.radians(tilt_deg) * rng.uniform(0.3, 1.0)
    roll = rng.uniform(-np.pi / 5, np.pi / 5)
    return board_facing(T_base_cam[:3, 3], centre_m, tilt * np.array([-1.0, -1.0, 1.0]), roll + np.pi)


def make_scene(
    cameras: dict | None = None,
    target: Target | None = None,
    n_poses: int = 40,
    pixel_sigma_px: float = 0.3,
    fk_sigma_translation_m: float = 0.0,
    fk_sigma_rotation_rad: float = 0.0,
    T_flange_board: np.ndarray | None = None,
    tilt_deg: float = 35.0,
    workspace_half_extent_m=(0.15, 0.15, 0.15),
    max_view_angle_deg: float = 70.0,
    shared_fraction: float = 0.3,
    mode: str = "eye_to_hand",
    method: str = "joint",
    options: SolverOptions | None = None,
    seed: int = 0,
    reported_intrinsics=FACTORY,
    eye_in_hand_distance_m=(0.3, 0.6),
) -> Scene:
    """A seeded synthetic workcell.

    Args:
        cameras: name -> (T_base_cam, Intrinsics); default three L515-like cameras at 1.5/3/5 m.
        n_poses: robot poses; each presents the board to one camera (round robin), a fraction
            ``shared_fraction`` is aimed between two cameras so both see it.
        pixel_sigma_px: Gaussian corner noise.
        fk_sigma_*: noise added to the reported flange poses (the solver sees the noisy ones).
        mode: 'eye_to_hand' or 'eye_in_hand' (then ``cameras`` are T_flange_cam and the board is
            fixed in the cell).
        reported_intrinsics: what the solver is told about the cameras: a
            :class:`~calibgraph.sim.reported_intrinsics.ReportedIntrinsics` (default: factory-class
            errors, drawn per camera name and the block's seed) or a mapping of its fields, or ``'exact'`` (the
            true intrinsics, as given in ``cameras``: an oracle's scene).
        eye_in_hand_distance_m: (near, far) camera-to-board distance of the eye-in-hand poses.
    """
    rng = np.random.default_rng(seed)
    target = target or a4_board_54()
    pts = target.points_board_m
    # centre the board frame's points for presentation purposes
    board_centre_b = pts.mean(axis=0)
    if mode == "eye_in_hand":
        return _make_eye_in_hand(cameras, target, n_poses, pixel_sigma_px, fk_sigma_translation_m,
                                 fk_sigma_rotation_rad, T_flange_board, tilt_deg, method, options, rng,
                                 reported_intrinsics, eye_in_hand_distance_m)
    if cameras is None:
        cameras = ring_cameras([1.5, 3.0, 5.0])
    T_fb = DEFAULT_T_FLANGE_BOARD if T_flange_board is None else T_flange_board
    names = list(cameras)
    captures, dets, flange_true = [], [], {}
    half = np.asarray(workspace_half_extent_m)
    k = 0
    attempts = 0
    while k < n_poses and attempts < 50 * n_poses:
        attempts += 1
        centre = WORKSPACE_CENTRE_M + rng.uniform(-half, half)
        c0 = names[k % len(names)]
        T_bc0 = cameras[c0][0]
        if len(names) > 1 and rng.uniform() < shared_fraction:
            c1 = names[(k + 1) % len(names)]
            mid = cameras[c0][0].copy()
            # aim at the bisector of the two cameras
            d0 = cameras[c0][0][:3, 3] - centre
            d1 = cameras[c1][0][:3, 3] - centre
            eye = centre + (d0 / np.linalg.norm(d0) + d1 / np.linalg.norm(d1))
            mid[:3, 3] = eye
            T_bc0 = mid
        T_base_board_ctr = random_board_facing(T_bc0, centre, tilt_deg, rng)
        # place so that the board centre (not its first corner) is at `centre`
        T_base_board = T_base_board_ctr @ make_T(np.eye(3), -board_centre_b)
        T_bf = T_base_board @ inv(T_fb)
        views = []
        for name in names:
            T_bc, intr = cameras[name]
            T_cb = inv(T_bc) @ T_base_board
            p_cam = pts @ T_cb[:3, :3].T + T_cb[:3, 3]
            normal_cam = T_cb[:3, 2]
            view_dir = (T_cb[:3, :3] @ board_centre_b + T_cb[:3, 3])
            cosang = normal_cam @ view_dir / np.linalg.norm(view_dir)
            if cosang < np.cos(np.radians(max_view_angle_deg)) or np.any(p_cam[:, 2] < 0.1):
                continue
            uv = intr.project(p_cam)
            if not np.all(intr.in_image(uv, margin_px=5)):
                continue
            views.append((name, uv + rng.normal(scale=pixel_sigma_px, size=uv.shape) if pixel_sigma_px > 0 else uv))
        if not views:
            continue
        T_bf_meas = T_bf @ make_T(exp_so3(rng.normal(scale=fk_sigma_rotation_rad, size=3)) if fk_sigma_rotation_rad > 0 else np.eye(3),
                                  rng.normal(scale=fk_sigma_translation_m, size=3) if fk_sigma_translation_m > 0 else np.zeros(3))
        captures.append(Capture(index=k, T_base_flange=T_bf_meas))
        flange_true[k] = T_bf
        for name, uv in views:
            dets.append(Detection(camera=name, capture=k, ids=np.arange(len(pts)), uv_px=uv))
        k += 1
    opts = options or SolverOptions(
        fk_sigma_translation_m=max(fk_sigma_translation_m, 1e-6),
        fk_sigma_rotation_rad=max(fk_sigma_rotation_rad, 1e-8),
    )
    prob = Problem(points_board_m=pts, cameras=reported_cameras(cameras, reported_intrinsics),
                   captures=tuple(captures), detections=tuple(dets), mode="eye_to_hand", method=method, options=opts,
                   target=target)
    truth = Truth(T_ref_cam={n: cameras[n][0] for n in names}, T_mount_board=T_fb, T_base_flange_true=flange_true,
                  intrinsics={n: cameras[n][1] for n in names})
    return Scene(prob, truth)


def _make_eye_in_hand(cameras, target, n_poses, pixel_sigma_px, fk_t, fk_r, T_base_board, tilt_deg, method,
                      options, rng, reported, distance_m=(0.3, 0.6)) -> Scene:
    pts = target.points_board_m
    board_centre_b = pts.mean(axis=0)
    if cameras is None:
        # one camera on the flange, looking along flange z, offset 6 cm
        cameras = {"wrist": (make_T(exp_so3([0, 0, np.pi / 2]), [0.06, 0.0, 0.04]), replace(preset("d455"), source="exact"))}
    if T_base_board is None:
        # board lying on the table in front of the robot, facing up (board z down into the table)
        T_base_board = make_T(exp_so3([np.pi, 0, 0]), [0.55, -0.1, 0.02])
    names = list(cameras)
    centre_base = (T_base_board @ np.append(board_centre_b, 1))[:3]
    captures, dets, flange_true = [], [], {}
    k = attempts = 0
    while k < n_poses and attempts < 50 * n_poses:
        attempts += 1
        name0 = names[k % len(names)]
        T_fc = cameras[name0][0]
        dist = rng.uniform(*distance_m)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        dirn = exp_so3(axis * np.radians(tilt_deg) * rng.uniform(0.3, 1.0)) @ np.array([0, 0, 1.0])
        eye = centre_base + dist * dirn
        T_base_cam = look_at(eye, centre_base + rng.normal(scale=0.03, size=3), up=(1.0, 0.0, 0.0))
        T_base_cam = T_base_cam @ make_T(exp_so3([0, 0, rng.uniform(-0.5, 0.5)]), np.zeros(3))
        T_bf = T_base_cam @ inv(T_fc)
        views = []
        for name in names:
            T_fc_n, intr = cameras[name]
            T_cb = inv(T_bf @ T_fc_n) @ T_base_board
            p_cam = pts @ T_cb[:3, :3].T + T_cb[:3, 3]
            if np.any(p_cam[:, 2] < 0.05):
                continue
            uv = intr.project(p_cam)
            if not np.all(intr.in_image(uv, margin_px=5)):
                continue
            views.append((name, uv + rng.normal(scale=pixel_sigma_px, size=uv.shape)))
        if not views:
            continue
        T_bf_meas = T_bf @ make_T(exp_so3(rng.normal(scale=fk_r, size=3)), rng.normal(scale=fk_t, size=3))
        captures.append(Capture(index=k, T_base_flange=T_bf_meas))
        flange_true[k] = T_bf
        for name, uv in views:
            dets.append(Detection(camera=name, capture=k, ids=np.arange(len(pts)), uv_px=uv))
        k += 1
    opts = options or SolverOptions(fk_sigma_translation_m=max(fk_t, 1e-6), fk_sigma_rotation_rad=max(fk_r, 1e-8))
    prob = Problem(points_board_m=pts, cameras=reported_cameras(cameras, reported), captures=tuple(captures),
                   detections=tuple(dets), mode="eye_in_hand", method=method, options=opts, target=target)
    truth = Truth(T_ref_cam={n: cameras[n][0] for n in names}, T_mount_board=T_base_board, T_base_flange_true=flange_true,
                  intrinsics={n: cameras[n][1] for n in names})
    return Scene(prob, truth)


def bump_camera(scene, camera: str, at_capture: int, shift_m: float, rot_deg: float = 0.0, seed: int = 0,
                pixel_sigma_px: float = 0.3, back_at_capture: int | None = None):
    """A synthetic scene whose camera ``camera`` was knocked before capture ``at_capture``: its views
    from then on (until ``back_at_capture``, when it is put back where it was) are projected from a
    pose whose centre moved by ``shift_m`` (random direction) and which turned by ``rot_deg`` about
    its centre (random axis), with fresh pixel noise. Returns (problem, T_base_cam after the move)."""
    rng = np.random.default_rng(seed)
    prob, truth = scene.problem, scene.truth
    u, w = rng.normal(size=3), rng.normal(size=3)
    T_after = truth.T_ref_cam[camera].copy()
    T_after[:3, :3] = exp_so3(w / np.linalg.norm(w) * np.radians(rot_deg)) @ T_after[:3, :3]
    T_after[:3, 3] += u / np.linalg.norm(u) * shift_m
    intr = (truth.intrinsics or prob.cameras)[camera]
    dets = []
    for d in prob.detections:
        if d.camera == camera and d.capture >= at_capture and (back_at_capture is None or d.capture < back_at_capture):
            T_cb = inv(T_after) @ truth.T_base_flange_true[d.capture] @ truth.T_mount_board
            p = prob.points_board_m[d.ids]
            uv = intr.project(p @ T_cb[:3, :3].T + T_cb[:3, 3])
            d = Detection(d.camera, d.capture, d.ids, uv + rng.normal(scale=pixel_sigma_px, size=uv.shape))
        dets.append(d)
    return prob.with_(detections=tuple(dets)), T_after


def correlate_corner_noise(problem, factor: float, seed: int = 0, pixel_sigma_px: float = 0.3):
    """``problem`` with each view's board image also shifted, turned, scaled and sheared at random:
    ``factor - 1`` times the corner variance (``pixel_sigma_px``^2) in each of the view's 6 low-order
    image modes, as overlapping corner windows on small squares produce (``factor`` 1: unchanged)."""
    if factor <= 1.0:
        return problem
    rng = np.random.default_rng(seed)
    dets = []
    for d in problem.detections:
        Q = view_mode_basis(d.uv_px)
        extra = Q @ rng.normal(0.0, pixel_sigma_px * np.sqrt(factor - 1.0), Q.shape[1])
        dets.append(replace(d, uv_px=d.uv_px + extra.reshape(d.uv_px.shape)))
    return problem.with_(detections=tuple(dets))
