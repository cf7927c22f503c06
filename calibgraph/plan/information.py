"""The planner's information model: the linearised calibration graph, camera models included.

The parameters are every placed camera's pose (6 each: rotation first, base axes, as the results
express a covariance), the board mount (6) and the board scale (1), and, for each camera whose
intrinsics the solver estimates, its camera model [fx, fy, cx, cy, k1, k2] (6) under the prior of
their source (:func:`calibgraph.core.problem.intrinsics_prior_covariance`: factory values are
trusted to 2 % in focal length, a calibration file to its own covariance). Each capture's flange
is marginalised under the FK prior, so the cameras that see one capture share it:

    J_k   = d uv / d(cameras, mount, scale, camera models, flange_k)   (2 rows per corner seen)
    I_k   = Schur complement of flange_k in  J_k^T J_k / sigma_px^2 + FK prior
    Sigma = (priors + sum over the captures of I_k)^-1

A camera's pose 1-sigma is its block of ``Sigma``: marginal over the mount, the scale, the FK and
every camera model, as the batch solver reports it. With the camera models among the parameters a
view is worth what it tells about them too: a board close to a camera and far from it (focal
length against depth), tilted (focal length against the board's scale), near the image's corners
and edges (principal point and distortion against the rotation) — the views a camera whose model
is weak needs before its pose can be pinned.

:func:`design_bound` answers the stop rule's other question: how far can a camera's 1-sigma go
with ``B`` more captures drawn from a set of reachable candidates? It is the optimum of the convex
relaxation (any non-negative weights summing to ``B``), bounded from below by Frank-Wolfe's
duality gap, so a camera said to be out of reach is out of reach of every choice of ``B``
candidates from the set.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.problem import SolverOptions, intrinsics_estimated, intrinsics_prior_covariance

__all__ = ["sigma_norms", "shortfall", "view_information", "view_jacobians", "intrinsics_jacobian",
           "joint_information", "block_sigmas", "block_sigmas_added", "inv_scaled", "intrinsics_prior",
           "prior_information", "design_bound", "BOARD_SCALE_SIGMA"]

N_INTR = 6  # [fx, fy, cx, cy, k1, k2]: the solver's intrinsics vector
BOARD_SCALE_SIGMA = 0.02  # the solver's default prior on the printed board's scale (SolverOptions.board_scale_sigma)


def sigma_norms(cov: np.ndarray) -> tuple:
    """(translation 1-sigma norm in mm, rotation 1-sigma norm in deg) of a rotation-first 6x6."""
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    return float(np.linalg.norm(d[3:]) * 1e3), float(np.degrees(np.linalg.norm(d[:3])))


def shortfall(cov, tol_mm: float, tol_deg: float) -> float:
    """max(|sigma_t| / tol_mm, |sigma_r| / tol_deg): <= 1 within tolerance (inf when unknown)."""
    if cov is None:
        return float("inf")
    t, r = sigma_norms(cov)
    return max(t / tol_mm, r / tol_deg)


def intrinsics_prior(intrinsics, options: SolverOptions | None = None, wide: bool = False) -> np.ndarray | None:
    """(6, 6) covariance of the prior the batch solver puts on a camera's [fx, fy, cx, cy, k1, k2]
    (``wide``: the wide prior it falls back on when the data reject the given values), or None
    when it holds them fixed (``source: exact``, ``--fixed-intrinsics``); of a calibration file whose
    covariance also covers p1, p2 (, k3), their marginal block (the planning model holds those)."""
    o = options or SolverOptions()
    if not intrinsics_estimated(intrinsics, o):
        return None
    return intrinsics_prior_covariance(intrinsics, o, wide=wide)[:6, :6]


def prior_information(n_cameras: int, intrinsics_priors=()) -> np.ndarray:
    """The priors of the graph :func:`joint_information` linearises, as an information matrix in its
    parameter order: the solver's weak priors on every camera and the mount (1 rad / 10 m), the
    board-scale prior (:data:`BOARD_SCALE_SIGMA`), then the inverse of each camera model's prior
    covariance in ``intrinsics_priors`` (one (6, 6) per camera whose model is estimated, in camera
    order; None entries are skipped)."""
    blocks = [np.diag(np.r_[np.tile([1.0] * 3 + [0.01] * 3, n_cameras + 1), 1.0 / BOARD_SCALE_SIGMA ** 2])]
    blocks += [np.linalg.inv(c) for c in intrinsics_priors if c is not None]
    n = sum(len(b) for b in blocks)
    out, i = np.zeros((n, n)), 0
    for b in blocks:
        out[i:i + len(b), i:i + len(b)] = b
        i += len(b)
    return out


def view_information(intrinsics, T_base_cam: np.ndarray, T_base_board: np.ndarray, points_board_m: np.ndarray,
                     pixel_sigma_px: float, T_flange_board: np.ndarray | None = None,
                     fk_sigma_translation_m: float = 0.0, fk_sigma_rotation_rad: float = 0.0) -> np.ndarray:
    """Fisher information (6x6, rotation first, base axes) on ``T_base_cam`` of one view of the
    board points, the camera model held known; for ``T_base_board`` (M, 4, 4) the M views'
    informations (M, 6, 6) at once.

    Perturbing the camera by ``R <- exp(dr) R, c <- c + dt`` moves a point seen at
    ``p_cam = R^T (p - c)`` by ``R^T [p - c]x dr - R^T dt``. With an FK prior (the flange pose of
    the view is itself uncertain, 1-sigma ``fk_sigma_*``, perturbed at the flange as the solver
    does) the flange is marginalised out: the Schur complement of the 12x12 information of
    (camera, flange) with the prior on the flange block. Without it a far camera's gain is
    overstated several times: at 0.05 px corner noise the robot's 0.1 mm / 0.01 deg dominates.
    """
    T_bb = np.asarray(T_base_board, float)
    single = T_bb.ndim == 2
    T_bb = T_bb.reshape(-1, 4, 4)
    M, N = len(T_bb), len(points_board_m)
    R, c = T_base_cam[:3, :3], T_base_cam[:3, 3]
    p = np.asarray(points_board_m, float) @ np.swapaxes(T_bb[:, :3, :3], 1, 2) + T_bb[:, None, :3, 3]  # (M, N, 3) base
    p_cam = (p - c) @ R
    _, Jp = intrinsics.project(p_cam.reshape(-1, 3), with_jacobian=True)  # (M N, 2, 3)
    Jp = np.where(np.all(np.isfinite(Jp), axis=(1, 2))[:, None, None], Jp, 0.0)  # behind the camera: no information
    JpR = Jp @ R.T  # d uv / d p (base axes)
    # d p_cam / d(dr, dt) = R^T [[p - c]x, -I]  =>  d uv / d(dr) = JpR [p - c]x, d uv / d(dt) = -JpR
    Jc = np.empty((M * N, 2, 6))
    Jc[:, :, :3] = JpR @ _skew_rows((p - c).reshape(-1, 3))
    Jc[:, :, 3:] = -JpR
    Jc = Jc.reshape(M, 2 * N, 6)
    w = 1.0 / pixel_sigma_px ** 2
    I_cc = w * (np.swapaxes(Jc, 1, 2) @ Jc)
    if T_flange_board is None or not (fk_sigma_translation_m > 0 and fk_sigma_rotation_rad > 0):
        return I_cc[0] if single else I_cc
    # flange right-perturbation xi = [w, v]: p = T_bf exp(xi) p_f moves by R_bf ([-p_f]x w + v)
    T_bf = T_bb @ np.linalg.inv(T_flange_board)
    R_bf = T_bf[:, :3, :3]
    p_f = (p - T_bf[:, None, :3, 3]) @ R_bf  # flange axes
    JpRf = JpR.reshape(M, N, 2, 3) @ R_bf[:, None]  # d uv / d p (flange axes)
    Jf = np.empty((M, N, 2, 6))
    Jf[..., :3] = -(JpRf @ _skew_rows(p_f.reshape(-1, 3)).reshape(M, N, 3, 3))
    Jf[..., 3:] = JpRf
    Jf = Jf.reshape(M, 2 * N, 6)
    prior = np.diag(1.0 / np.array([fk_sigma_rotation_rad] * 3 + [fk_sigma_translation_m] * 3) ** 2)
    I_cf = w * (np.swapaxes(Jc, 1, 2) @ Jf)
    I_ff = w * (np.swapaxes(Jf, 1, 2) @ Jf) + prior
    out = I_cc - I_cf @ np.linalg.solve(I_ff, np.swapaxes(I_cf, 1, 2))
    return out[0] if single else out


def intrinsics_jacobian(intrinsics, p_cam_m: np.ndarray) -> np.ndarray:
    """d uv / d[fx, fy, cx, cy, k1, k2] (N, 2, 6) of camera-frame points ``p_cam_m`` (N, 3), in the
    solver's parameterisation (the other distortion coefficients and the skew held); points
    behind the camera give zero rows."""
    P = np.asarray(p_cam_m, float).reshape(-1, 3)
    valid = P[:, 2] > 1e-9
    Z = np.where(valid, P[:, 2], 1.0)
    x, y = P[:, 0] / Z, P[:, 1] / Z
    k1, k2, p1, p2, k3, k4, k5, k6 = intrinsics.dist8
    r2 = x * x + y * y
    a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    xd = x * a / b + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * a / b + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    fx, s = intrinsics.K[0, 0], intrinsics.K[0, 1]
    fy = intrinsics.K[1, 1]
    J = np.zeros((len(P), 2, N_INTR))
    J[:, 0, 0], J[:, 1, 1] = xd, yd
    J[:, 0, 2], J[:, 1, 3] = 1.0, 1.0
    for j, dr in ((4, r2 / b), (5, r2 * r2 / b)):  # d rad / d k1, d k2
        J[:, 0, j] = (fx * x + s * y) * dr
        J[:, 1, j] = fy * y * dr
    J[~valid] = 0.0
    return J


def view_jacobians(intrinsics, T_base_cam: np.ndarray, T_base_flange: np.ndarray, T_flange_board: np.ndarray,
                   points_board_m: np.ndarray, with_intrinsics: bool = False) -> np.ndarray:
    """d uv / d(camera, flange, mount, board scale[, camera model]) of the board points seen by one
    camera from the flange poses ``T_base_flange`` (M, 4, 4): (M, 2N, 19), or (M, 2N, 25) with
    ``with_intrinsics``; columns [camera 6 (base axes, as in :func:`view_information`), flange 6
    (right perturbation), mount 6 (right perturbation of ``T_flange_board``), board scale 1 (the
    points scaled about the board origin, as the solver does), then fx, fy, cx, cy, k1, k2].
    Points behind the camera give zero rows."""
    T_bf = np.asarray(T_base_flange, float).reshape(-1, 4, 4)
    M, N = len(T_bf), len(points_board_m)
    T_bb = T_bf @ T_flange_board
    R_bb = T_bb[:, :3, :3]
    R, c = T_base_cam[:3, :3], T_base_cam[:3, 3]
    p = np.asarray(points_board_m, float) @ np.swapaxes(R_bb, 1, 2) + T_bb[:, None, :3, 3]  # (M, N, 3) base
    p_cam = ((p - c) @ R).reshape(-1, 3)
    _, Jp = intrinsics.project(p_cam, with_jacobian=True)
    Jp = np.where(np.all(np.isfinite(Jp), axis=(1, 2))[:, None, None], Jp, 0.0)
    JpR = (Jp @ R.T).reshape(M, N, 2, 3)  # d uv / d p (base axes)
    J = np.empty((M, N, 2, 19 + (N_INTR if with_intrinsics else 0)))
    J[..., :3] = JpR @ _skew_rows((p - c).reshape(-1, 3)).reshape(M, N, 3, 3)
    J[..., 3:6] = -JpR
    R_bf = T_bf[:, :3, :3]
    p_f = (p - T_bf[:, None, :3, 3]) @ R_bf  # flange axes
    JpRf = JpR @ R_bf[:, None]
    J[..., 6:9] = -(JpRf @ _skew_rows(p_f.reshape(-1, 3)).reshape(M, N, 3, 3))
    J[..., 9:12] = JpRf
    JpRb = JpR @ R_bb[:, None]
    J[..., 12:15] = -(JpRb @ _skew_rows(np.asarray(points_board_m, float))[None])
    J[..., 15:18] = JpRb
    J[..., 18] = (JpRb @ np.asarray(points_board_m, float)[None, :, :, None])[..., 0]
    if with_intrinsics:
        J[..., 19:] = intrinsics_jacobian(intrinsics, p_cam).reshape(M, N, 2, N_INTR)
    return J.reshape(M, 2 * N, J.shape[-1])


def joint_information(cams: list, seen: np.ndarray, T_base_flange: np.ndarray, T_flange_board: np.ndarray,
                      points_board_m: np.ndarray, pixel_sigma_px: float, fk_sigma_translation_m: float,
                      fk_sigma_rotation_rad: float, free_intrinsics=None) -> np.ndarray:
    """Fisher information of M captures on the parameters shared across views, each capture's
    flange marginalised under the FK prior: (M, P, P) in the order [camera 1 ... camera K (6 each,
    rotation first, base axes), mount 6, board scale 1, then the camera model (fx, fy, cx, cy, k1,
    k2) of each camera flagged in ``free_intrinsics`` (K booleans; None: none), in camera order].
    ``cams``: K (intrinsics, T_base_cam); ``seen``: (M, K) which cameras see each capture, or the
    probability that each sees it (floats in [0, 1]: a view's corner information is weighted by it, its
    expected information).

    This is the linearised calibration graph one capture at a time: unlike :func:`view_information`
    (one camera, mount and scale held known) the cameras of a capture share its flange, and every
    view informs the mount and the board scale that all cameras depend on. A far camera's depth is
    tied to the board scale (a 1e-4 scale error is 0.45 mm at 4.5 m) and to its focal length,
    which only views at several depths and tilts, or other cameras, pin down."""
    T_bf = np.asarray(T_base_flange, float).reshape(-1, 4, 4)
    seen = np.asarray(seen).reshape(len(T_bf), len(cams))
    seen = seen if seen.dtype == bool else np.clip(seen.astype(float), 0.0, 1.0)
    M, K = len(T_bf), len(cams)
    free = [False] * K if free_intrinsics is None else [bool(f) for f in free_intrinsics]
    P0 = 6 * K + 7
    P = P0 + N_INTR * sum(free)
    w = 1.0 / pixel_sigma_px ** 2
    L = np.zeros((M, P + 6, P + 6))
    j = 0
    for k, (intr, T_bc) in enumerate(cams):
        cols = [np.r_[6 * k:6 * k + 6, P:P + 6, 6 * K:6 * K + 7]]  # camera, flange, mount + scale
        if free[k]:
            cols.append(np.arange(P0 + N_INTR * j, P0 + N_INTR * (j + 1)))
            j += 1
        m = seen[:, k] > 0
        if not m.any():
            continue
        idx = np.concatenate(cols)
        J = view_jacobians(intr, T_bc, T_bf[m], T_flange_board, points_board_m, with_intrinsics=free[k])
        wk = w * np.asarray(seen[m, k], float)[:, None, None]
        L[np.ix_(np.flatnonzero(m), idx, idx)] += wk * (np.swapaxes(J, 1, 2) @ J)
    L[:, P:, P:] += np.diag(1.0 / np.array([fk_sigma_rotation_rad] * 3 + [fk_sigma_translation_m] * 3) ** 2)
    I_pf = L[:, :P, P:]
    return L[:, :P, :P] - I_pf @ np.linalg.solve(L[:, P:, P:], np.swapaxes(I_pf, 1, 2))


def inv_scaled(J: np.ndarray) -> np.ndarray:
    """Inverse of the symmetric positive definite information ``J`` (..., P, P), through its
    diagonal scaling (radians, metres, pixels and distortion coefficients differ by many orders of
    magnitude; the scaled matrix has a unit diagonal)."""
    d = 1.0 / np.sqrt(np.maximum(np.diagonal(J, axis1=-2, axis2=-1), 1e-300))
    S = J * d[..., :, None] * d[..., None, :]
    return np.linalg.inv(S) * d[..., :, None] * d[..., None, :]


def block_sigmas_added(J0: np.ndarray, infos: np.ndarray, K: int, cov0: np.ndarray | None = None) -> np.ndarray:
    """``block_sigmas(inv_scaled(J0 + infos), K)`` (M, K, 2) without inverting a (P, P) matrix per
    candidate: a capture informs only the cameras that see it (and their models), the mount and the
    scale, so each candidate's information lives on a few columns ``s`` and the covariance follows
    from today's by the Woodbury identity, ``Sigma' = Sigma - Sigma_:s I_ss (1 + Sigma_ss I_ss)^-1
    Sigma_s:``, of which only the camera blocks' diagonals are formed. Candidates that inform the same
    columns are done together. ``cov0``: ``inv_scaled(J0)`` when the caller has it. Works in the
    diagonal scaling of ``J0`` (as :func:`inv_scaled`)."""
    infos = np.asarray(infos, float).reshape(-1, *J0.shape)
    M = len(infos)
    d = 1.0 / np.sqrt(np.maximum(np.diag(J0), 1e-300))
    C = (inv_scaled(J0) if cov0 is None else cov0) / d[:, None] / d[None, :]  # the scaled J0's inverse
    n = 6 * K
    out = np.empty((M, n))
    support = np.any(infos != 0.0, axis=1)  # (M, P): the columns each candidate informs
    patterns, which = np.unique(support, axis=0, return_inverse=True)
    which = np.asarray(which).reshape(-1)
    for g, pat in enumerate(patterns):
        m = np.flatnonzero(which == g)
        sidx = np.flatnonzero(pat)
        if not len(sidx):
            out[m] = np.diag(C)[:n]
            continue
        Is = infos[np.ix_(m, sidx, sidx)] * d[sidx][None, :, None] * d[sidx][None, None, :]
        A = C[:n, sidx]  # (n, s)
        W = Is @ np.linalg.inv(np.eye(len(sidx)) + C[np.ix_(sidx, sidx)][None] @ Is)  # (m, s, s)
        out[m] = np.diag(C)[:n] - np.sum((A @ W) * A, axis=-1)
    cov_diag = np.clip(out, 0, None) * (d[:n] ** 2)[None, :]
    v = np.sqrt(cov_diag).reshape(M, K, 6)
    return np.stack([np.linalg.norm(v[..., 3:], axis=-1) * 1e3, np.degrees(np.linalg.norm(v[..., :3], axis=-1))], -1)


def block_sigmas(cov: np.ndarray, K: int) -> np.ndarray:
    """(..., K, 2) translation-norm (mm) and rotation-norm (deg) 1-sigma of each camera block of a
    joint covariance (..., P, P)."""
    d = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1)[..., :6 * K], 0, None))
    d = d.reshape(*d.shape[:-1], K, 6)
    return np.stack([np.linalg.norm(d[..., 3:], axis=-1) * 1e3, np.degrees(np.linalg.norm(d[..., :3], axis=-1))], -1)


def design_bound(J0: np.ndarray, infos: np.ndarray, budget: float, rows, iterations: int = 200,
                 rel_gap: float = 0.02) -> tuple:
    """How small ``trace(Sigma[rows, rows])`` can get with ``budget`` more captures from the
    candidates whose informations are ``infos`` (M, P, P), on top of the information ``J0`` (P, P).

    The captures' informations add, so the best choice of ``budget`` candidates (repeats allowed)
    is bounded below by the best non-negative weights ``w`` summing to ``budget`` — a convex
    problem (the trace of an inverse is convex in the information). The weights are found by the
    multiplicative algorithm of A-optimal design (``w_i <- w_i sqrt(phi_i)``, renormalised, with
    ``phi_i = trace(E' Sigma I_i Sigma E)`` the rate at which candidate ``i`` lowers the trace),
    and the convexity gives a lower bound at every iterate, ``f(w) - budget max(phi) + w . phi``
    (the two meet at the optimum: the equivalence theorem). Returns (lower bound, value of the
    design found): no ``budget`` captures from these candidates get the trace below the first; the
    second is reached by weights summing to ``budget``."""
    rows = np.asarray(rows)
    M = len(infos)
    d = 1.0 / np.sqrt(np.maximum(np.diag(J0) + budget * np.max(np.diagonal(infos, axis1=1, axis2=2), axis=0)
                                 if M else np.diag(J0), 1e-300))
    E = np.zeros((len(J0), len(rows)))
    E[rows, np.arange(len(rows))] = d[rows]
    J0s = J0 * d[:, None] * d[None, :]
    if M == 0 or budget <= 0:
        v = float(np.trace(E.T @ np.linalg.solve(J0s, E)))
        return v, v
    Is = infos * d[None, :, None] * d[None, None, :]
    w = np.full(M, budget / M)
    lower, f = 0.0, np.inf
    for _ in range(iterations):
        A = np.linalg.solve(J0s + np.tensordot(w, Is, 1), E)
        f = float(np.trace(E.T @ A))
        phi = np.maximum(((Is @ A) * A).sum(axis=(1, 2)), 0.0)
        lower = max(lower, f - budget * float(phi.max()) + float(w @ phi))
        if f - lower <= rel_gap * f:
            break
        w = w * np.sqrt(phi)
        w *= budget / max(w.sum(), 1e-300)
    return max(lower, 0.0), f


def _skew_rows(v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) skew matrices of the rows of ``v`` (N, 3)."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S
