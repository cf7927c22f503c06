"""What a held-out test would say, without test data: the expected error of a new pose's corners
predicted from the robot's *reported* forward kinematics.

A user applies the calibration with the poses the robot reports, so a new capture's board corners
are predicted as ``pi(K, inv(T_ref_cam) T_ref_mount(FK) T_mount_board p)`` and miss the detected
ones by (to first order) the sum of independent parts, per corner:

* robot: the FK error of the new pose, at the accuracy the solve used (the stated FK sigmas, or
  those the fit implied when the check widened them: ``fk_noise.used_sigma_*``; when the held-out
  captures kept a component at its stated sigma, the size the fit judged it: ``prediction_sigma_*``), rotation and
  translation perturbing ``T_base_flange`` at the flange, as the FK prior does;
* calibration: the joint covariance of the camera pose, the board mount, the camera's estimated
  intrinsics and the board scale (their correlations included where the solve has them: the view formulation's joint
  graph; elsewhere the pose's and the mount's covariances are summed);
* corners: the detected corners' own noise, 2 sigma_px^2 (the camera's a posteriori pixel sigma),
  and the extra variance of each view's 6 whole-board image modes the solve found (``corner_noise``'s
  ``applied`` factor): whether shared pixels or an unmodelled robot error moved whole boards in the
  calibration's views, it moves a new view's board too.

Each part's 2-D mean square is averaged over the corners of the camera's used views (the poses of
this calibration stand for the new ones), by the projection's Jacobians (analytic; central
differences of the projection are the reference the tests compare them with). ``mm`` converts
each corner's miss with its depth over the focal length (the miss at the board's distance, across
the line of sight). The figure assumes what the solve assumes: the FK error of a new pose is
independent of the calibration poses' (a kinematic error that repeats from pose to pose predicts
better; one that grows outside the calibrated workspace worse).

With joint zero offsets estimated (``kinematics='joint-offsets'``) a new pose's flange pose is
``FK(q + o)`` of its reported joint angles through the arm model with the estimated offsets (what
``calibgraph export --format robot`` gives the user), and the offsets join the calibration part's
joint covariance, entering through each pose's flange Jacobian on them.
"""

from __future__ import annotations

import gtsam
import numpy as np

from calibgraph.core.camera import project_points
from calibgraph.core.transforms import exp_so3, inv
from calibgraph.solver.terms.factors import cross_rows, distortion_columns
from calibgraph.solver.terms.noise_model import N_MODES

EPS = 1e-6


def _left(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """``T`` perturbed as the result's covariances are: rotation vector ``xi[:3]`` on the left, in the
    frame ``T`` is expressed in, and ``xi[3:]`` added to its translation."""
    out = T.copy()
    out[:3, :3] = exp_so3(xi[:3]) @ T[:3, :3]
    out[:3, 3] = T[:3, 3] + xi[3:]
    return out


def _jacobian(f, n: int = 6) -> np.ndarray:
    """(2N, n) central-difference Jacobian of ``f`` (R^n -> (N, 2) pixels)."""
    cols = []
    for i in range(n):
        e = np.zeros(n)
        e[i] = EPS
        cols.append(((f(e) - f(-e)) / (2 * EPS)).reshape(-1))
    return np.column_stack(cols)


def predicted_uv(T_ref_cam: np.ndarray, T_base_flange: np.ndarray, T_mount_board: np.ndarray, mode: str, intr,
                 p_board_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(pixels (N, 2), camera-frame points (N, 3)) of board points ``p_board_m`` at a capture whose
    robot pose is ``T_base_flange``, as a user applies a calibration: ``T_ref_cam`` is
    ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand), ``T_mount_board`` the board's
    pose in its mount (``T_flange_board`` or ``T_base_board``)."""
    p = np.asarray(p_board_m, float)
    return _project_views(T_ref_cam, np.asarray(T_base_flange, float)[None], T_mount_board, mode, intr, p,
                          np.zeros(len(p), int))


def _project_views(T_ref_cam, T_base_flange, T_mount_board, mode: str, intr, p_board_m, which):
    """:func:`predicted_uv` for several captures at once: ``T_base_flange`` (n, 4, 4), each board
    point ``p_board_m[i]`` seen at capture ``which[i]``."""
    T_ref_mount = _inv_stack(T_base_flange) if mode == "eye_in_hand" else T_base_flange
    T = inv(T_ref_cam) @ T_ref_mount @ T_mount_board
    p_cam = np.einsum("nij,nj->ni", T[which, :3, :3], p_board_m) + T[which, :3, 3]
    return intr.project(p_cam), p_cam


def expected_prediction(problem, result, fk_sigma_translation_m: float, fk_sigma_rotation_rad: float,
                        pose_mount_cov: dict | None = None, per_view: bool = False, numeric: bool = False,
                        corrected: dict | None = None) -> dict:
    """camera -> {expected_rms_px, expected_rms_mm, parts_px: {robot, calibration, corners}, ...}
    for the calibrated cameras (module docstring); the FK sigmas are those the solve used.
    ``pose_mount_cov``: camera -> (the joint covariance of its pose and the board mount in GTSAM's
    body frame (right perturbations), then, when they were estimated, its intrinsics (``K(c)``'s
    entries: fx fy cx cy k1 k2 [p1 p2 [k3]]) and the board scale; the intrinsics' count; whether the
    scale is in), when the solve has it: their correlations (the board seen by the camera pins them
    together) then enter the calibration part; without it the pose's and the mount's covariances are
    added as if independent, which overstates it.

    The Jacobians are taken for all of a camera's views at once (each perturbation projects every
    view; a view's corners depend on its own robot pose only); ``per_view=True`` takes them view by
    view, the slow path the test compares with (same numbers to rounding; 16 cameras x 480 poses:
    5.4 s view by view). The Jacobians are analytic (the chain rule through the same projection,
    :func:`_analytic_jacobians`); ``numeric=True`` takes them by central differences of
    :func:`_project_views`, the slower reference the test compares with (16 x 480: 0.55 s).

    ``corrected`` (joint offsets estimated): capture -> (FK(q + offsets), its flange-frame Jacobian on
    the free offsets): a new pose's flange pose comes from its reported joint angles through the
    corrected arm, and the offsets' uncertainty (their rows of the joint covariance, which must then be
    given) enters the calibration part through that Jacobian."""
    fk_cov = np.diag([fk_sigma_rotation_rad ** 2] * 3 + [fk_sigma_translation_m ** 2] * 3)
    caps = {c.index: c for c in problem.captures}
    out = {}
    for name, cam in result.calibrated.items():
        intr = cam.solved_intrinsics or problem.cameras[name]
        M = cam.T_mount_board if cam.T_mount_board is not None else result.T_mount_board
        M_cov = result.mount_covariance if cam.T_mount_board is None else None
        if M is None or intr is None or not np.all(np.isfinite(intr.K)):
            continue
        views = []
        for k, rec in cam.residuals_px.items():
            if rec["rejected"] or k not in caps or (corrected is not None and k not in corrected):
                continue
            ids = rec["ids"][rec["weight"] > 0]
            if len(ids):
                T_bf, J_o = corrected[k] if corrected is not None else (caps[k].T_base_flange, None)
                views.append((T_bf, problem.points_board_m[ids] * result.board_scale, J_o))
        if not views:
            continue
        joint, n_k, has_scale, n_o = (pose_mount_cov or {}).get(name) or (None, 0, False, 0)
        if joint is None or cam.T_mount_board is not None:
            joint = None
        if corrected is not None and (joint is None or n_o != views[0][2].shape[1]):
            continue  # the offsets' uncertainty is not known here: no figure rather than an understated one
        stack = [[v] for v in views] if per_view else [views]
        parts = [_camera_parts(problem.mode, intr, cam.T_ref_cam, cam.covariance, M, M_cov, joint, n_k, has_scale,
                               result.board_scale, vs, fk_cov, numeric) for vs in stack]
        robot, calib = (np.concatenate([p[i] for p in parts]) for i in (0, 1))
        depth2 = np.concatenate([p[2] for p in parts])  # per view: sum over its corners of (1e3 depth / fx)^2
        n_view = np.array([len(v[1]) for v in views], float)
        mode_factor = max(float((cam.corner_noise or {}).get("applied", 1.0)), 1.0)
        # the corners' own noise, with the whole-board part the solve found in its views (6 image modes
        # at ``mode_factor`` times the corners' variance: shared pixels, or a robot or camera error)
        corners = (2.0 * n_view + N_MODES * (mode_factor - 1.0)) * (cam.pixel_sigma_px or result.pixel_sigma_px) ** 2
        sums = np.array([robot.sum(), calib.sum(), corners.sum()])
        mm2 = float(np.sum((robot + calib + corners) / n_view * depth2))
        n = int(n_view.sum())
        parts = np.sqrt(sums / n)
        out[name] = {"expected_rms_px": float(np.sqrt(sums.sum() / n)), "expected_rms_mm": float(np.sqrt(mm2 / n)),
                     "parts_px": {"robot": float(parts[0]), "calibration": float(parts[1]), "corners": float(parts[2])},
                     "fk_sigma_translation_m": float(fk_sigma_translation_m),
                     "fk_sigma_rotation_rad": float(fk_sigma_rotation_rad), "corners": n,
                     "predicted_from": "joint angles" if corrected is not None else "flange poses"}
    return out


def _camera_parts(mode, intr, X, X_cov, M, M_cov, joint, n_k, has_scale, board_scale, views, fk_cov, numeric=False):
    """For ``views`` ([(T_base_flange, board points, the flange pose's Jacobian on the joint offsets or
    None)]) of one camera: per view, the robot and the calibration parts' 2-D mean square summed over
    its corners, and its corners' (1e3 depth / fx)^2 summed; every view at once."""
    T_bf = np.stack([v[0] for v in views])
    P = np.concatenate([v[1] for v in views])
    which = np.repeat(np.arange(len(views)), [len(v[1]) for v in views])
    n_views = len(views)
    J_o = np.stack([v[2] for v in views]) if views[0][2] is not None else None
    jacobians = _numeric_jacobians if numeric else _analytic_jacobians
    J_robot, J_cal, J_X, J_M, depth = jacobians(mode, intr, X, M, n_k, has_scale, board_scale, T_bf, P, which,
                                                joint is not None, M_cov is not None, J_o)
    robot = _per_view(J_robot, fk_cov, which, n_views)
    if joint is not None:
        calib = _per_view(J_cal, joint, which, n_views)
    else:
        calib = _per_view(J_X, X_cov, which, n_views)
        if M_cov is not None:
            calib = calib + _per_view(J_M, M_cov, which, n_views)
    depth2 = np.bincount(which, (1e3 * depth / intr.K[0, 0]) ** 2, minlength=n_views)
    return robot, calib, depth2


def _numeric_jacobians(mode, intr, X, M, n_k, has_scale, board_scale, T_bf, P, which, joint: bool, mount: bool,
                       J_o: np.ndarray | None = None):
    """:func:`_analytic_jacobians` by central differences of :func:`_project_views` (every view
    projected at once per perturbation): the slow reference."""
    def project(X_=X, T_bf_=T_bf, M_=M, intr_=intr, P_=P):
        return _project_views(X_, T_bf_, M_, mode, intr_, P_, which)

    J_robot = _jacobian(lambda e: project(T_bf_=T_bf @ _flange_step(e))[0])
    J_cal = J_X = J_M = None
    if joint:
        Xp, Mp = gtsam.Pose3(X), gtsam.Pose3(M)
        k0 = np.concatenate([[intr.K[0, 0], intr.K[1, 1], intr.K[0, 2], intr.K[1, 2]], intr.dist8[:max(n_k - 4, 0)]])
        n_o = 0 if J_o is None else J_o.shape[2]
        n_s = 12 + n_k + int(has_scale)

        def joint_project(e):
            intr_ = intr.with_pinhole(k0 + e[12:12 + n_k]) if n_k else intr
            P_ = P * (1.0 + e[12 + n_k] / board_scale) if has_scale else P
            # the offsets move each flange pose by Exp(J_o d) at the flange (FK(q + o + d) = FK(q + o) Exp(J d))
            T_ = T_bf if not n_o else np.stack([T @ gtsam.Pose3.Expmap(J @ e[n_s:]).matrix()
                                                 for T, J in zip(T_bf, J_o)])
            return project(Xp.retract(e[:6]).matrix(), T_, Mp.retract(e[6:12]).matrix(), intr_, P_)[0]

        J_cal = _jacobian(joint_project, n_s + n_o)
    else:
        J_X = _jacobian(lambda e: project(X_=_left(X, e))[0])
        J_M = _jacobian(lambda e: project(M_=_left(M, e))[0]) if mount else None
    return J_robot, J_cal, J_X, J_M, project()[1][:, 2]


def _analytic_jacobians(mode, intr, X, M, n_k, has_scale, board_scale, T_bf, P, which, joint: bool, mount: bool = True,
                        J_o: np.ndarray | None = None):
    """The Jacobians :func:`_camera_parts` takes numerically, by the chain rule (each (2N, n), rows u,
    v of each corner): on the robot pose of each corner's own capture (the FK prior's perturbation at
    the flange, :func:`_flange_step`), on [camera pose, mount (GTSAM's right perturbations), the
    intrinsics' ``n_k`` entries, the board scale] when ``joint`` (else None), on the camera pose
    and on the mount perturbed as their covariances are (:func:`_left`) otherwise; and the corners'
    depths. (``mount``: the numeric reference's switch; the mount's Jacobian costs nothing extra here.)
    ``J_o`` (views, 6, n_o): each view's flange pose on the joint offsets; with ``joint`` their columns
    close the calibration Jacobian (the robot's, through that chain)."""
    T_rm = _inv_stack(T_bf) if mode == "eye_in_hand" else T_bf
    R_c, t_c = X[:3, :3], X[:3, 3]
    R_b, t_b = M[:3, :3], M[:3, 3]
    R_w = T_rm[which, :3, :3]
    p_m = P @ R_b.T + t_b
    q = np.einsum("nij,nj->ni", R_w, p_m) + T_rm[which, :3, 3]  # the corners in the reference frame
    p_c = (q - t_c) @ R_c
    K = intr.K
    uv, Jp, aux = project_points(p_c, K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1], intr.dist8, True)
    N = len(P)
    JR = Jp @ R_c.T  # d uv / d q
    JF = np.einsum("nij,njk->nik", JR, R_w)  # d uv / d p_m
    JB = JF @ R_b  # d uv / d P

    def rows(*blocks):
        return np.concatenate(blocks, axis=2).reshape(2 * N, -1)

    if mode == "eye_in_hand":  # T_ref_mount = (T_bf D(e))^-1: d q = [q]x w - v
        J_robot = rows(cross_rows(JR, q), -JR)
    else:  # T_ref_mount = T_bf D(e): d q = R_rm (-[p_m]x w + v)
        J_robot = rows(-cross_rows(JF, p_m), JF)
    J_cal = J_X = J_M = None
    if joint:
        blocks = [cross_rows(Jp, p_c), -Jp, -cross_rows(JB, P), JB]
        if n_k:
            x, y, xd, yd = aux[:4]
            Jk = np.zeros((N, 2, n_k))
            Jk[:, 0, 0], Jk[:, 0, 2], Jk[:, 1, 1], Jk[:, 1, 3] = xd, 1.0, yd, 1.0
            Jk[:, :, 4:] = distortion_columns(x, y, intr.dist8, K[0, 0], K[1, 1], K[0, 1], n_k)
            blocks.append(Jk)
        if has_scale:
            blocks.append(np.einsum("nij,nj->ni", JB, P)[:, :, None] / board_scale)
        if J_o is not None:
            blocks.append(J_robot.reshape(N, 2, 6) @ J_o[which])
        J_cal = rows(*blocks)
    else:
        J_X = rows(cross_rows(JR, q - t_c), -JR)  # X = (exp(w) R_c, t_c + v)
        J_M = rows(-cross_rows(JF, p_m - t_b), JF)  # M = (exp(w) R_b, t_b + v)
    return J_robot, J_cal, J_X, J_M, p_c[:, 2]


def _flange_step(xi: np.ndarray) -> np.ndarray:
    """The perturbation of ``T_base_flange`` at the flange (the FK prior's convention), as a 4x4."""
    d = np.eye(4)
    d[:3, :3] = exp_so3(xi[:3])
    d[:3, 3] = xi[3:]
    return d


def _inv_stack(T: np.ndarray) -> np.ndarray:
    """Inverses of a stack of rigid transforms (n, 4, 4)."""
    out = np.zeros_like(T)
    Rt = np.transpose(T[:, :3, :3], (0, 2, 1))
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def _per_view(J: np.ndarray, cov: np.ndarray, which: np.ndarray, n_views: int) -> np.ndarray:
    """Per view, the sum over its corners of the 2-D mean square ``tr(J cov J^T)`` (``J``: (2N, n),
    rows u, v of each corner in turn)."""
    per_row = np.sum((J @ cov) * J, axis=1)
    return np.bincount(np.repeat(which, 2), per_row, minlength=n_views)


def prediction_notes(prediction: dict) -> list:
    """One line per camera: what a held-out test would say."""
    how = {"joint angles": "from its reported joint angles through the arm model with the estimated offsets",
           "flange poses": "from its reported FK"}
    return [f"camera {name}: at a new robot pose, this calibration should place the board's corners in its image "
            f"within {p['expected_rms_px']:.2f} px RMS of where it sees them ({p['expected_rms_mm']:.2f} mm at the "
            f"board), most of it from the {_largest(p['parts_px'])}. Detail: a new robot pose's corners, predicted "
            f"{how[p.get('predicted_from', 'flange poses')]}, are expected to miss by "
            f"{p['expected_rms_px']:.2f} px RMS: robot "
            f"{p['parts_px']['robot']:.2f} px, calibration {p['parts_px']['calibration']:.2f} px, corner noise "
            f"{p['parts_px']['corners']:.2f} px" for name, p in prediction.items()]


def _largest(parts_px: dict) -> str:
    """The part of a prediction's miss that is largest, in words."""
    words = {"robot": "robot's own error", "calibration": "calibration's 1-sigma", "corners": "corners' noise"}
    k = max(("robot", "calibration", "corners"), key=lambda s: float(parts_px.get(s, 0.0)))
    return words[k]
