"""The view factor: every detected corner of one view is a reprojection residual.

Model (generic over modes: ``ref`` is the robot base in eye-to-hand and the flange in eye-in-hand,
``mount`` the other one, the frame the board is fixed to; ``T_ref_mount[k]`` is the robot pose of
capture k, T_base_flange in eye-to-hand and T_flange_base in eye-in-hand):

    p_cam = T_ref_cam^-1 @ T_ref_mount[k] @ T_mount_board @ p_board   (project_chain)
    r_i   = sqrt(w_i) / sigma_px * (project(p_cam_i) - uv_i)       (2 rows per corner)

One ``gtsam.CustomFactor`` per view with vectorised numpy keeps the corner as the unit of
observation (each corner has its own robust weight ``w_i`` and its own two rows) without the cost of
one Python call per corner per linearisation. Jacobians are analytic, in GTSAM's Pose3 tangent
(right perturbation ``T @ Exp(xi)``, ``xi = [omega, v]``).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from calibgraph.core.camera import Intrinsics, distortion_partials, project_points

_MIN_DEPTH_M = 1e-3
CHUNK_CORNERS = 4096  # corners per numpy pass of :func:`make_view_factors` (its arrays stay in cache)


def project_chain(T_ref_cam: np.ndarray, T_ref_mount: np.ndarray, T_mount_board: np.ndarray, p_board_m: np.ndarray,
                  intr: Intrinsics) -> np.ndarray:
    """Pure model: board points (N, 3) -> pixels (N, 2) through the kinematic chain."""
    T_cam_board = np.linalg.inv(T_ref_cam) @ T_ref_mount @ T_mount_board
    p_cam = p_board_m @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    return intr.project(p_cam)


def fk_noise(opts, mode: str = "eye_to_hand", T_ref_mount: np.ndarray | None = None):
    """Noise model of the forward-kinematics prior on F(k) = ``T_ref_mount``.

    The sigmas describe T_base_flange (perturbed at the flange); in eye-in-hand the variable is its
    inverse T_flange_base, whose right perturbation is -Ad(T_base_flange) xi, so the square-root
    information becomes diag(1/sigma) Ad(T_flange_base)."""
    s = np.array([opts.fk_sigma_rotation_rad] * 3 + [opts.fk_sigma_translation_m] * 3)
    if mode == "eye_to_hand" or T_ref_mount is None:
        return gtsam.noiseModel.Diagonal.Sigmas(s)
    return gtsam.noiseModel.Gaussian.SqrtInformation(np.diag(1.0 / s) @ gtsam.Pose3(T_ref_mount).AdjointMap(), False)


def cross_rows(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """cross(a[n, r], p[n]) for a (N, 2, 3) and p (N, 3), without np.cross's axis shuffling."""
    px, py, pz = p[:, None, 0], p[:, None, 1], p[:, None, 2]
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    return np.stack([ay * pz - az * py, az * px - ax * pz, ax * py - ay * px], axis=-1)


def _cross_into(out: np.ndarray, a: np.ndarray, p: np.ndarray, negate: bool = False) -> None:
    """``out`` (N, 2, 3) = cross(a[n, r], p[n]) (or its negative) for a (N, 2, 3), p (N, 3), in place."""
    px, py, pz = p[:, None, 0], p[:, None, 1], p[:, None, 2]
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    for i, (u, q, v, r) in enumerate(((ay, pz, az, py), (az, px, ax, pz), (ax, py, ay, px))):
        np.multiply(u, q, out=out[..., i])
        out[..., i] -= v * r
        if negate:
            np.negative(out[..., i], out=out[..., i])


def view_residual(T_ref_cam, T_ref_mount, T_mount_board, p_board_m, uv_px, intr: Intrinsics, sqrt_w,
                  want_jacobians=True):
    """Residual (2N,) and Jacobians (2N, 6) w.r.t. camera, robot pose and mount.

    ``sqrt_w`` (N,) already includes 1 / sigma_px.
    """
    R_rc, t_rc = T_ref_cam[:3, :3], T_ref_cam[:3, 3]
    R_rm, t_rm = T_ref_mount[:3, :3], T_ref_mount[:3, 3]
    R_mb, t_mb = T_mount_board[:3, :3], T_mount_board[:3, 3]
    p_m = p_board_m @ R_mb.T + t_mb  # corners in the mount frame
    p_r = p_m @ R_rm.T + t_rm  # ... in the reference frame
    p_c = (p_r - t_rc) @ R_rc  # R_rc^T (p_r - t_rc), row-wise: in the camera frame
    # Keep the residual finite when a corner falls behind the camera during iterations.
    p_c_safe = p_c.copy()
    p_c_safe[:, 2] = np.maximum(p_c_safe[:, 2], _MIN_DEPTH_M)
    if not want_jacobians:
        uv = intr.project(p_c_safe)
        return ((uv - uv_px) * sqrt_w[:, None]).reshape(-1), None
    uv, Jp = intr.project(p_c_safe, with_jacobian=True)  # (N,2), (N,2,3)
    e = ((uv - uv_px) * sqrt_w[:, None]).reshape(-1)
    Jp = Jp * sqrt_w[:, None, None]
    n = p_board_m.shape[0]
    # Row vector a^T [p]x equals cross(a, p), so every "J @ skew(p)" below is a batched cross product.
    # camera (right perturbation of T_ref_cam): d p_c = [p_c]x omega - v
    H_c = np.concatenate([cross_rows(Jp, p_c), -Jp], axis=2)
    # robot pose: d p_r = R_rm(-[p_m]x omega + v), d p_c = R_rc^T d p_r
    R_cm = R_rc.T @ R_rm
    JF = Jp @ R_cm
    H_f = np.concatenate([-cross_rows(JF, p_m), JF], axis=2)
    # mount: d p_m = R_mb(-[p_b]x omega + v)
    JB = JF @ R_mb
    H_b = np.concatenate([-cross_rows(JB, p_board_m), JB], axis=2)
    H_c, H_f, H_b = (H.reshape(2 * n, 6) for H in (H_c, H_f, H_b))
    return e, (H_c, H_f, H_b)


def _cross_last(a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """cross(a[..., r, :], p[...]) for a (..., 2, 3) and p (..., 3)."""
    px, py, pz = p[..., None, 0], p[..., None, 1], p[..., None, 2]
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    return np.stack([ay * pz - az * py, az * px - ax * pz, ax * py - ay * px], axis=-1)


def pad_views(views: list, scale: float = 1.0, kept_only: bool = False) -> tuple:
    """Views' corners padded to the largest view, for :func:`padded_view_residuals`: (points
    ``scale * p_board_m`` (V, N, 3), pixels (V, N, 2), valid (V, N), the corners' weights (V, N) (``View.weight``),
    0 on padding). ``kept_only``: each view's kept corners only (non-zero weight), in order. A
    padding slot repeats the view's first corner (finite)."""
    sel = [v.kept if kept_only else np.ones(len(v.ids), bool) for v in views]
    N = max([1] + [int(m.sum()) for m in sel])
    V = len(views)
    P, UV, valid, W = np.zeros((V, N, 3)), np.zeros((V, N, 2)), np.zeros((V, N), bool), np.zeros((V, N))
    for i, (v, m) in enumerate(zip(views, sel)):
        n = int(m.sum())
        P[i, :n], UV[i, :n], valid[i, :n], W[i, :n] = scale * v.p_board_m[m], v.uv_px[m], True, v.weight[m]
        if n:
            P[i, n:], UV[i, n:] = P[i, 0], UV[i, 0]
    return P, UV, valid, W


def padded_view_residuals(T_ref_cam, T_ref_mount, T_mount_board, p_board_m, uv_px, intr: Intrinsics, sqrt_w,
                          mount: bool = False):
    """:func:`view_residual` of V views of one camera at once, their corners padded to N.

    ``T_ref_cam`` (4, 4) or (V, 4, 4), ``T_ref_mount`` (V, 4, 4), ``p_board_m`` (V, N, 3), ``uv_px``
    (V, N, 2), ``sqrt_w`` (V, N) including 1 / sigma_px, 0 on padding (whose points must be finite
    ones of the view). Returns e (V, 2N) and the Jacobians on the camera and the robot pose
    (V, 2N, 6), rows ordered as :func:`view_residual` orders them; with ``mount``, the Jacobian on the
    board mount (its right perturbation) instead of the camera's."""
    V, N = sqrt_w.shape
    T_rc = np.broadcast_to(T_ref_cam, (V, 4, 4))
    R_rc, t_rc = T_rc[:, :3, :3], T_rc[:, :3, 3]
    R_rm, t_rm = T_ref_mount[:, :3, :3], T_ref_mount[:, :3, 3]
    p_m = p_board_m @ T_mount_board[:3, :3].T + T_mount_board[:3, 3]
    p_r = p_m @ R_rm.transpose(0, 2, 1) + t_rm[:, None]
    p_c = (p_r - t_rc[:, None]) @ R_rc
    p_c_safe = p_c.copy()
    p_c_safe[..., 2] = np.maximum(p_c_safe[..., 2], _MIN_DEPTH_M)
    uv, Jp = intr.project(p_c_safe.reshape(-1, 3), with_jacobian=True)
    e = ((uv.reshape(V, N, 2) - uv_px) * sqrt_w[..., None]).reshape(V, 2 * N)
    Jp = Jp.reshape(V, N, 2, 3) * sqrt_w[..., None, None]
    H_c = np.concatenate([_cross_last(Jp, p_c), -Jp], axis=-1)
    JF = Jp @ (R_rc.transpose(0, 2, 1) @ R_rm)[:, None]
    H_f = np.concatenate([-_cross_last(JF, p_m), JF], axis=-1)
    if mount:  # T_mount_board Exp(x): p_m moves by R_mb (x_r cross p_b + x_t)
        JB = JF @ T_mount_board[:3, :3]
        H_c = np.concatenate([-_cross_last(JB, p_board_m), JB], axis=-1)
    return e, H_c.reshape(V, 2 * N, 6), H_f.reshape(V, 2 * N, 6)


def make_view_factor(key_cam, key_robot, key_mount, p_board_m: np.ndarray, uv_px: np.ndarray, intr: Intrinsics,
                     sqrt_w: np.ndarray, noise=None) -> gtsam.CustomFactor:
    """A CustomFactor for one view (keys: camera pose, robot pose, board mount). ``noise``: the
    view's noise model on the weighted residuals (default unit: independent corners)."""
    p_board_m = np.ascontiguousarray(p_board_m, float)
    uv_px = np.ascontiguousarray(uv_px, float)
    sqrt_w = np.ascontiguousarray(sqrt_w, float)
    model = noise or gtsam.noiseModel.Unit.Create(2 * p_board_m.shape[0])

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H):
        T_ref_cam = values.atPose3(key_cam).matrix()
        T_ref_mount = values.atPose3(key_robot).matrix()
        T_mount_board = values.atPose3(key_mount).matrix()
        e, J = view_residual(T_ref_cam, T_ref_mount, T_mount_board, p_board_m, uv_px, intr, sqrt_w, want_jacobians=H is not None)
        if H is not None:
            H[0], H[1], H[2] = J
        return e

    return gtsam.CustomFactor(model, [key_cam, key_robot, key_mount], error_func)


def with_pinhole(intr: Intrinsics, k6: np.ndarray) -> Intrinsics:
    """Copy of ``intr`` with [fx, fy, cx, cy] and, when given, [k1, k2] replaced (validated: for
    values that leave the solver; the factors use :meth:`Intrinsics.with_pinhole`)."""
    fast = intr.with_pinhole(k6)
    return Intrinsics(K=fast.K, dist=fast.dist, width_px=intr.width_px, height_px=intr.height_px, source=intr.source)


def intrinsics_vector(intr: Intrinsics, n: int = 6) -> np.ndarray:
    """[fx, fy, cx, cy, k1, k2] (``n`` 6), then [p1, p2] (8) and k3 (9): the refined subset of the
    intrinsics (``INTRINSICS_FULL``'s first ``n``; its distortion part is OpenCV's first ``n - 4``)."""
    return np.concatenate([[intr.K[0, 0], intr.K[1, 1], intr.K[0, 2], intr.K[1, 2]], intr.dist8[:n - 4]])


def distortion_columns(x, y, dist8, fx, fy, s, n: int) -> np.ndarray:
    """(N, 2, n - 4) d(u, v) / d(k1, k2[, p1, p2[, k3]]) at undistorted normalised points (x, y)
    (u = fx x_d + s y_d + cx, v = fy y_d + cy; ``dist8`` (8,) or (8, N), skew ``s``)."""
    dx, dy = distortion_partials(x, y, dist8, n - 4)
    return np.stack([fx * dx.T + s * dy.T, fy * dy.T], axis=0).transpose(2, 0, 1)


def _intrinsics_jacobian(T_ref_cam, T_ref_mount, T_mount_board, p_board_m, uv_px, cur: Intrinsics, k6, e, sqrt_w):
    """Weighted d residual / d [fx, fy, cx, cy, k1, k2 (, p1, p2 (, k3))] (2N, len(k6)) at the
    current intrinsics ``cur``.

    With x_d, y_d the distorted normalised coordinates: d u / d(fx, cx) = (x_d, 1), d v / d(fy, cy)
    = (y_d, 1); the distortion columns are :func:`calibgraph.core.camera.distortion_partials`.
    """
    n = p_board_m.shape[0]
    T_cam_board = np.linalg.inv(T_ref_cam) @ T_ref_mount @ T_mount_board
    p_c = p_board_m @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    z = np.maximum(p_c[:, 2], _MIN_DEPTH_M)
    x, y = p_c[:, 0] / z, p_c[:, 1] / z
    uv = e.reshape(n, 2) / sqrt_w[:, None] + uv_px
    yd = (uv[:, 1] - k6[3]) / k6[1]
    xd = (uv[:, 0] - k6[2] - cur.K[0, 1] * yd) / k6[0]
    fx, s, fy = cur.K[0, 0], cur.K[0, 1], cur.K[1, 1]
    m = len(k6)
    Jk = np.zeros((n, 2, m))
    Jk[:, 0, 0] = xd
    Jk[:, 0, 2] = 1.0
    Jk[:, 1, 1] = yd
    Jk[:, 1, 3] = 1.0
    Jk[:, :, 4:] = distortion_columns(x, y, cur.dist8, fx, fy, s, m)
    return (Jk * sqrt_w[:, None, None]).reshape(2 * n, m)


def make_calibration_factor(key_cam, key_robot, key_mount, p_board_m, uv_px, intr: Intrinsics, sqrt_w,
                            key_intr=None, key_scale=None, noise=None) -> gtsam.CustomFactor:
    """View factor with, optionally, the camera's intrinsics ``key_intr`` ([fx, fy, cx, cy, k1, k2]
    and, when its prior covers them, [p1, p2 (, k3)]: a Vector variable) and the board's scale factor
    ``key_scale`` (a Vector1 variable ``s``: the printed board's points are ``s * p_board_m``) as
    variables too.

    The scale's Jacobian is the chain through the mount: d p_cam / d s = R_cam_board p_board.
    """
    p_board_m = np.ascontiguousarray(p_board_m, float)
    uv_px = np.ascontiguousarray(uv_px, float)
    sqrt_w = np.ascontiguousarray(sqrt_w, float)
    n = p_board_m.shape[0]
    model = noise or gtsam.noiseModel.Unit.Create(2 * n)
    keys = [key_cam, key_robot, key_mount] + [k for k in (key_intr, key_scale) if k is not None]

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H):
        T_ref_cam = values.atPose3(key_cam).matrix()
        T_ref_mount = values.atPose3(key_robot).matrix()
        T_mount_board = values.atPose3(key_mount).matrix()
        scale = float(values.atVector(key_scale)[0]) if key_scale is not None else 1.0
        p_b = p_board_m * scale
        k6 = values.atVector(key_intr) if key_intr is not None else None
        cur = intr.with_pinhole(k6) if k6 is not None else intr
        e, J = view_residual(T_ref_cam, T_ref_mount, T_mount_board, p_b, uv_px, cur, sqrt_w,
                             want_jacobians=H is not None)
        if H is not None:
            H[0], H[1], H[2] = J
            idx = 3
            if key_intr is not None:
                H[idx] = _intrinsics_jacobian(T_ref_cam, T_ref_mount, T_mount_board, p_b, uv_px, cur, k6, e, sqrt_w)
                idx += 1
            if key_scale is not None:
                # the mount Jacobian's translation block is d residual / d p_mount rotated into the
                # board axes (d p_m = R_mb v): so d residual / d s = H_b[:, 3:] @ p_board
                H_b = J[2].reshape(n, 2, 6)
                H[idx] = np.einsum("nij,nj->ni", H_b[:, :, 3:], p_board_m).reshape(2 * n, 1)
        return e

    return gtsam.CustomFactor(model, keys, error_func)


@dataclass(frozen=True)
class ViewTerm:
    """One view of a capture (:func:`make_view_factors`): its camera's keys and model,
    its kept corners and their weights (``sqrt_w`` (n,) already includes 1 / sigma_px), and
    ``whiten`` (2n, 6) Q scaled so that ``e - whiten @ (Q^T e)`` whitens correlated low-order modes
    (None: independent corners)."""

    key_cam: int
    key_intr: int | None
    intr: Intrinsics
    p_board_m: np.ndarray
    uv_px: np.ndarray
    sqrt_w: np.ndarray
    modes: np.ndarray | None = None  # (2n, 6) orthonormal basis Q of the view's low-order modes
    mode_factor: float = 1.0  # their variance factor
    n_intr: int = 6  # the size of the camera's intrinsics vector when estimated (6, 8 or 9)
    # a revisit's own robot error about its configuration's shared pose (the arm's repeatability), as the
    # whitening (U (2n, k), c (k,)) of its residual: e -> e - U (c * (U^T e)) (linearise.revisit_whitening)
    repeat: tuple | None = None


def whitened(x: np.ndarray, c: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``x - Q diag(c) Q^T x`` (``x`` (2n,) or (2n, m), ``Q`` (2n, k) orthonormal, ``c`` (k,)): the
    whitening of a residual whose covariance is I + Q diag(s^2) Q^T, with c = 1 - (1 + s^2)^-1/2."""
    y = Q.T @ x
    return x - Q @ (c[:, None] * y if y.ndim == 2 else c * y)


def make_capture_factors(key_robot, key_mount, key_scale, terms: list) -> list:
    """One CustomFactor per view of one capture (``terms``: :class:`ViewTerm` s): the views share
    the robot pose ``key_robot`` (F(k)), the mount and the board scale (``key_scale`` or None), and
    each brings its camera pose and, when estimated, its intrinsics (:func:`make_view_factors` for
    one capture)."""
    return make_view_factors(key_mount, key_scale, [(key_robot, terms)])


def make_view_factors(key_mount, key_scale, captures: list) -> list:
    """One CustomFactor per view of every capture in ``captures`` ((robot pose key F(k), its views'
    :class:`ViewTerm` s[, the fixed offset D (4, 4) of the capture's robot pose from the key's: a capture
    revisiting a configuration shares the key of its first visit, T_ref_mount = F D]) tuples), in that order: a view's factor has the keys of its capture's robot
    pose, the mount, the board scale (``key_scale`` or None), its camera pose and, when estimated,
    its intrinsics. Each view's residual has its low-order modes whitened by its variance factor
    (covariance I + (f - 1) Q Q^T, whose inverse square root is I - (1 - f^-1/2) Q Q^T), so its
    noise model is unit.

    The same model as :func:`make_calibration_factor`; all the views' corners are projected in one
    vectorised pass with per-corner camera and robot-pose parameters (one numpy pass for the whole
    graph, not one per view or per capture), and each view's factor takes its rows of it. A
    factor's Jacobian is then its own view's rows on its own keys, so the linear system keeps the
    graph's sparsity. The pass is redone, at the values asked for, whenever a view finds the
    values of its keys differ from those of the last pass: a graph's error or linearisation at new
    values makes one pass, whichever factor asks first."""
    terms = [t for _, ts, *_ in captures for t in ts]
    n_views = len(terms)
    robot_keys = [k for k, *_ in captures]
    # a capture that revisits a configuration shares its robot pose key: its own pose is the key's times
    # the fixed offset between their reported poses (a third entry; identity when absent)
    deltas = [np.asarray(c[2], float) if len(c) > 2 and c[2] is not None else None for c in captures]
    Delta = np.array([np.eye(4) if D is None else D for D in deltas])
    shifted = np.array([D is not None for D in deltas])
    Ad_inv = np.array([gtsam.Pose3(np.linalg.inv(D)).AdjointMap() if D is not None else np.eye(6) for D in deltas])
    cap = np.repeat(np.arange(len(captures)), [len(c[1]) for c in captures]).astype(int)  # capture of each view
    cam_slot = {k: i for i, k in enumerate(dict.fromkeys(t.key_cam for t in terms))}
    cam_keys = list(cam_slot)
    cam = np.array([cam_slot[t.key_cam] for t in terms], int)  # camera pose of each view
    intr_slot = {k: i for i, k in enumerate(dict.fromkeys(t.key_intr for t in terms if t.key_intr is not None))}
    intr_keys = list(intr_slot)
    intr_of = [intr_slot[t.key_intr] if t.key_intr is not None else -1 for t in terms]
    rows, whiten = [], {}
    start = 0
    for v, t in enumerate(terms):
        n = t.p_board_m.shape[0]
        rows.append(slice(start, start + 2 * n))
        steps = [] if t.repeat is None else [(t.repeat[1], t.repeat[0])]
        if t.modes is not None and t.mode_factor > 1.0:
            steps.append((np.full(t.modes.shape[1], 1.0 - 1.0 / np.sqrt(t.mode_factor)), t.modes))
        if steps:
            whiten[v] = steps
        start += 2 * n
    total = start
    if not n_views:
        return []
    P_b = np.ascontiguousarray(np.concatenate([t.p_board_m for t in terms]), float)
    UV = np.concatenate([t.uv_px for t in terms])
    SW = np.concatenate([t.sqrt_w for t in terms])
    counts = [t.p_board_m.shape[0] for t in terms]
    vi = np.repeat(np.arange(n_views), counts)  # view of each corner
    models = {}  # each camera model's row (views share their camera's Intrinsics)
    model_of = np.array([models.setdefault(id(t.intr), (len(models), t.intr))[0] for t in terms], int)
    by_model = [m for _, m in models.values()]
    static = np.array([[m.K[0, 1], *m.dist8] for m in by_model])[model_of]  # skew, k1..k6 as given
    pinhole = np.array([[m.K[0, 0], m.K[1, 1], m.K[0, 2], m.K[1, 2]] for m in by_model])[model_of]
    estimated = np.array([t.key_intr is not None for t in terms])
    n_intr = np.array([t.n_intr for t in terms])  # each estimated camera's intrinsics vector size
    views_of_intr = [np.flatnonzero(np.array(intr_of) == j) for j in range(len(intr_keys))]
    # the last pass: the values it was made at (the robot poses', cameras' and mount's Pose3, the
    # intrinsics' and the scale's bytes), its residuals and Jacobians (row blocks over all the views' rows)
    cache = {"robot": None, "cam": None, "intr": None, "mount": None, "scale": None, "e": None, "H": None, "white": {}}

    def scale_bytes(values) -> bytes:
        return values.atVector(key_scale).tobytes() if key_scale is not None else b""

    n_pose = 3 + (key_scale is not None)  # Jacobian blocks before the intrinsics': robot pose, mount, (scale,) camera

    def view_blocks(blocks, v: int) -> list:
        """View ``v``'s Jacobian blocks, on its keys in order, from a pass's row blocks."""
        rs = rows[v]
        return [A[rs] for A in blocks[:n_pose]] + ([blocks[n_pose][rs, :n_intr[v]]] if estimated[v] else [])

    m_intr = int(n_intr[estimated].max()) if estimated.any() else 0
    ends = np.cumsum(counts)  # chunks of whole views, about CHUNK_CORNERS corners each (in cache)
    cuts = sorted({0, *(int(ends[i]) for i in np.searchsorted(ends, np.arange(CHUNK_CORNERS, ends[-1], CHUNK_CORNERS))),
                   int(ends[-1])})
    chunks = [slice(lo, hi) for lo, hi in zip(cuts[:-1], cuts[1:])]

    def compute(values):
        mount = values.atPose3(key_mount)
        T_mb = mount.matrix()
        scale = float(values.atVector(key_scale)[0]) if key_scale is not None else 1.0
        robots = [values.atPose3(k) for k in robot_keys]
        cams = [values.atPose3(k) for k in cam_keys]
        T_rm = np.array([p.matrix() for p in robots])
        if shifted.any():
            T_rm = T_rm @ Delta
        T_rc = np.array([p.matrix() for p in cams])
        k6s = [np.asarray(values.atVector(k), float) for k in intr_keys]
        par = pinhole.copy()  # fx, fy, cx, cy
        dist = static[:, 1:].copy()
        for j, k6 in enumerate(k6s):
            vs = views_of_intr[j]
            par[vs] = k6[:4]
            dist[vs, :len(k6) - 4] = k6[4:]
        R_mb, t_mb = T_mb[:3, :3], T_mb[:3, 3]
        # each view's chain from the mount frame to its camera: p_c = M p_m + d, M = R_rc^T R_rm
        R_rcT = T_rc[cam, :3, :3].transpose(0, 2, 1)
        M = R_rcT @ T_rm[cap, :3, :3]
        d = np.einsum("vij,vj->vi", R_rcT, T_rm[cap, :3, 3] - T_rc[cam, :3, 3])
        n_c = len(vi)
        e = np.empty((n_c, 2))
        H_f, H_b, H_c = np.empty((n_c, 2, 6)), np.empty((n_c, 2, 6)), np.empty((n_c, 2, 6))
        H_s = np.empty((n_c, 2)) if key_scale is not None else None
        Jk = np.zeros((n_c, 2, m_intr)) if m_intr else None
        for ch in chunks:
            w = vi[ch]
            sw = SW[ch]
            p_b = P_b[ch] * scale
            p_m = p_b @ R_mb.T + t_mb
            Mv = M[w]
            p_c = np.einsum("nij,nj->ni", Mv, p_m) + d[w]
            p_c[:, 2] = np.maximum(p_c[:, 2], _MIN_DEPTH_M)  # finite residuals for a corner behind the camera
            fx, fy, cx, cy = par[w].T
            skew, dist_c = static[w, 0], dist[w].T
            uv, Jp, aux = project_points(p_c, fx, fy, cx, cy, skew, dist_c, True)
            e[ch] = (uv - UV[ch]) * sw[:, None]
            Jp *= sw[:, None, None]
            _cross_into(H_c[ch, :, :3], Jp, p_c)
            np.negative(Jp, out=H_c[ch, :, 3:])
            JF = H_f[ch, :, 3:]  # Jp M, written in place
            for k in range(3):
                np.multiply(Jp[:, :, 0], Mv[:, None, 0, k], out=JF[:, :, k])
                JF[:, :, k] += Jp[:, :, 1] * Mv[:, None, 1, k]
                JF[:, :, k] += Jp[:, :, 2] * Mv[:, None, 2, k]
            _cross_into(H_f[ch, :, :3], JF, p_m, negate=True)
            JB = H_b[ch, :, 3:]
            JB[...] = (JF.reshape(-1, 3) @ R_mb).reshape(JF.shape)
            _cross_into(H_b[ch, :, :3], JB, p_b, negate=True)
            if H_s is not None:
                H_s[ch] = np.einsum("nij,nj->ni", JB, P_b[ch])
            if Jk is not None:
                x, y, xd, yd = aux[:4]
                J = Jk[ch]
                J[:, 0, 0], J[:, 0, 2], J[:, 1, 1], J[:, 1, 3] = xd, 1.0, yd, 1.0
                J[:, :, 4:] = distortion_columns(x, y, dist_c, fx, fy, skew, m_intr)
                J *= sw[:, None, None]
        if shifted.any():  # on the shared key F: F Exp(xi) D = F D Exp(Ad(D^-1) xi)
            at = shifted[cap[vi]]
            H_f[at] = H_f[at] @ Ad_inv[cap[vi][at]]
        e = e.reshape(-1)
        blocks = [H_f.reshape(-1, 6), H_b.reshape(-1, 6)]
        if H_s is not None:
            blocks.append(H_s.reshape(-1, 1))
        blocks.append(H_c.reshape(-1, 6))
        if Jk is not None:
            blocks.append(Jk.reshape(-1, m_intr))
        white = {}
        for v, steps in whiten.items():  # a whitened view's rows, replaced
            ev, Hv = e[rows[v]], view_blocks(blocks, v)
            for c, Q in steps:
                ev, Hv = whitened(ev, c, Q), [whitened(A, c, Q) for A in Hv]
            white[v] = (ev, Hv)
        cache.update(robot=robots, cam=cams, intr=[k.tobytes() for k in k6s], mount=mount, scale=scale_bytes(values),
                     e=e, H=blocks, white=white)

    def factor(v: int, t) -> gtsam.CustomFactor:
        key_robot = robot_keys[cap[v]]
        keys = [key_robot, key_mount] + ([key_scale] if key_scale is not None else []) + [t.key_cam]
        keys += [t.key_intr] if t.key_intr is not None else []
        c, j, k_i = cap[v], cam[v], intr_of[v]

        def stale(values) -> bool:
            # exact: Pose3.equals at tolerance 0 is equality of every entry (cheaper than their bytes)
            return (cache["e"] is None or not cache["robot"][c].equals(values.atPose3(key_robot), 0.0)
                    or not cache["cam"][j].equals(values.atPose3(t.key_cam), 0.0)
                    or not cache["mount"].equals(values.atPose3(key_mount), 0.0)
                    or (key_scale is not None and cache["scale"] != scale_bytes(values))
                    or (k_i >= 0 and cache["intr"][k_i] != np.asarray(values.atVector(t.key_intr), float).tobytes()))

        def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H):
            if stale(values):
                # with the Jacobians even for the error alone: LM linearises next where it accepted a
                # step, at values whose error it has just asked for
                compute(values)
            if v in cache["white"]:
                e, Hv = cache["white"][v]
                if H is not None:
                    for i, A in enumerate(Hv):
                        H[i] = A
                return e
            if H is not None:
                for i, A in enumerate(view_blocks(cache["H"], v)):
                    H[i] = A
            return cache["e"][rows[v]]

        n_rows = 2 * t.p_board_m.shape[0]
        if n_rows not in units:
            units[n_rows] = gtsam.noiseModel.Unit.Create(n_rows)
        return gtsam.CustomFactor(units[n_rows], keys, error_func)

    units = {}  # one unit noise model per row count
    return [factor(v, t) for v, t in enumerate(terms)]
