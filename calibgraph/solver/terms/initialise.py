"""Initial guesses that never fall into the planar-pose ambiguity.

A small planar board seen from far has two near-equal PnP poses (IPPE returns both), and single-view
PnP often picks the mirrored one. Every closed-form AX = ZB method fed with those
poses inherits the error. Here each view keeps *both* IPPE candidates and the choice is made by
consensus across views:

1. Per camera, RANSAC over minimal sets of 3 views and candidate choices solves the rotation part
   ``R_Z B_k = A_k R_Y`` linearly (18 unknowns, null space) and counts the views whose best
   candidate agrees within a few degrees.
2. The board mount rotation comes from the camera(s) with the strongest consensus (all agreeing
   cameras re-solved jointly in 'joint' mode); translations follow from the linear system
   ``t_Z + R_Z t_Bk = R_Ak t_Y + t_Ak``, solved robustly.
3. Every camera pose is then re-derived from the shared mount: each view proposes
   ``Z = A_k Y B_k^-1`` for each candidate; the largest agreeing cluster wins.

Notation of the AX = ZB literature, in the solver's frames (``ref`` is the robot base in
eye-to-hand and the flange in eye-in-hand, ``mount`` the other one): Z = T_ref_cam, Y =
T_mount_board, A_k = T_ref_mount of capture k (the robot pose), B_k = T_cam_board from PnP.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import ObservabilityError
from calibgraph.core.transforms import log_so3, make_T, project_to_so3

ROT_INLIER_DEG = 5.0
MAX_MOUNT_SEEDS = 5


@dataclass(frozen=True)
class ViewCandidates:
    """PnP candidates of T_cam_board for one view: rotations (m, 3, 3), translations (m, 3), rms (m,)."""

    camera: str
    capture: int
    T_ref_mount: np.ndarray  # (4, 4) robot pose of the capture (A_k)
    R: np.ndarray
    t: np.ndarray
    rms_px: np.ndarray


def pnp_candidates(p_board_m: np.ndarray, uv_px: np.ndarray, intr: Intrinsics, max_rms_px: float = 20.0):
    """Both IPPE solutions of a planar view (fewer when degenerate). Returns (R (m,3,3), t (m,3), rms (m,))."""
    if len(uv_px) < 4:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0)
    obj = np.ascontiguousarray(p_board_m[:, :3], dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
    try:
        n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, intr.K, intr.dist, flags=cv2.SOLVEPNP_IPPE)
    except cv2.error:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0)
    Rs, ts, rms = [], [], []
    for i in range(n):
        R, _ = cv2.Rodrigues(rvecs[i])
        t = np.asarray(tvecs[i], float).reshape(3)
        e = float(np.asarray(errs).reshape(-1)[i]) if errs is not None else 0.0
        if t[2] <= 0 or not np.isfinite(e) or e > max_rms_px:
            continue
        Rs.append(R)
        ts.append(t)
        rms.append(e)
    return np.array(Rs).reshape(-1, 3, 3), np.array(ts).reshape(-1, 3), np.array(rms)


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angle between rotations, batched over leading dims."""
    c = (np.einsum("...ij,...ij->...", Ra, Rb) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _pairwise_cos(R: np.ndarray) -> np.ndarray:
    """(M, M) cosine of the angle between every pair of the rotations ``R`` (M, 3, 3), clipped to
    [-1, 1] (:func:`_angle_deg` is its arccos): the traces tr(Ra^T Rb) as one matrix product of the
    flattened rotations, and no arccos (an angle limit is a cosine limit)."""
    F = R.reshape(len(R), 9)
    return np.clip((F @ F.T - 1.0) / 2.0, -1.0, 1.0)


def _solve_rotations(rows_by_cam: dict, n_cams: int):
    """Linear least squares for R_Z (one per camera slot) and shared R_Y.

    rows_by_cam: slot -> list of (A_rot, B_rot). Equation R_Z B - A R_Y = 0, row-major vec.
    """
    nu = 9 * (n_cams + 1)
    I3 = np.eye(3)
    N = np.zeros((nu, nu))
    Y = slice(9 * n_cams, nu)
    for slot, pairs in rows_by_cam.items():
        if not pairs:
            continue
        A = np.array([a for a, _ in pairs])
        Bm = np.array([b for _, b in pairs])
        n = len(pairs)
        # kron(I, B^T)[(i,j),(k,l)] = d_ik B[l,j];  kron(A, I)[(i,j),(k,l)] = A[i,k] d_jl
        Mz = np.einsum("ik,nlj->nijkl", I3, Bm).reshape(9 * n, 9)
        My = -np.einsum("nik,jl->nijkl", A, I3).reshape(9 * n, 9)
        Z = slice(9 * slot, 9 * slot + 9)
        N[Z, Z] += Mz.T @ Mz
        N[Z, Y] += Mz.T @ My
        N[Y, Z] += My.T @ Mz
        N[Y, Y] += My.T @ My
    # Normal equations, formed block by block (each view touches its camera's block and R_Y only),
    # keep this O(rows) for thousands of views; the null vector is the eigenvector of the smallest
    # eigenvalue.
    evals, evecs = np.linalg.eigh(N)
    v = evecs[:, 0]
    s = np.sqrt(np.clip(evals[::-1], 0, None))
    # The null vector is [R_Z..., R_Y] times an unknown scale s; every block's determinant has the
    # sign of s^3. Decide the sign on all blocks together: with noisy views one block alone (R_Y, say)
    # can come out with the wrong determinant sign, and projecting it onto SO(3) then gives a
    # rotation ~180 deg away.
    blocks_raw = [v[9 * i: 9 * i + 9].reshape(3, 3) for i in range(n_cams + 1)]
    dets = np.array([np.linalg.det(b) for b in blocks_raw])
    sign = 1.0 if dets.sum() >= 0 else -1.0
    scale = sign * np.cbrt(max(abs(dets.sum()) / len(dets), 1e-300))
    RY = project_to_so3(blocks_raw[-1] / scale)
    RZ = [project_to_so3(b / scale) for b in blocks_raw[:-1]]
    cond = s[-2] / max(s[0], 1e-300) if len(s) > 1 else 0.0
    return RZ, RY, cond


def _stack(views):
    """Flatten all candidates: (R (M,3,3), A_rot (M,3,3), owner view (M,), index within view (M,))."""
    R = np.concatenate([v.R for v in views]) if views else np.zeros((0, 3, 3))
    A = np.concatenate([np.broadcast_to(v.T_ref_mount[:3, :3], (len(v.R), 3, 3)) for v in views]) if views else R
    owner = np.concatenate([np.full(len(v.R), i) for i, v in enumerate(views)]).astype(int) if views else np.zeros(0, int)
    j = np.concatenate([np.arange(len(v.R)) for v in views]).astype(int) if views else np.zeros(0, int)
    return R, A, owner, j


def _best_candidate_errors(RZ, RY, views, stacked=None):
    """For each view: (best angle error deg, index of best candidate); vectorised over candidates."""
    R, A, owner, j = stacked if stacked is not None else _stack(views)
    a = _angle_deg(RZ @ R, A @ RY)
    errs = np.full(len(views), np.inf)
    idx = np.full(len(views), -1)
    order = np.argsort(-a)  # write larger errors first so the smallest per view wins
    errs[owner[order]] = a[order]
    idx[owner[order]] = j[order]
    return errs, idx


def ransac_camera(views: list, rng: np.random.Generator, iterations: int = 300, max_hypotheses: int = 3):
    """RANSAC rotation consensus for one camera.

    Returns up to ``max_hypotheses`` distinct hypotheses (mount rotations more than 10 deg apart),
    best first, each (RZ, RY, inlier mask, chosen candidate idx); [] when none. With noisy far views
    a wrong, self-consistent hypothesis can collect as many inliers as the right one, so the caller
    decides between them by reprojection error.
    """
    usable = [i for i, v in enumerate(views) if len(v.R) > 0]
    if len(usable) < 3:
        return []
    found = []  # (score, RZ, RY, inl, idx)
    stacked = _stack(views)
    needed, it = 30, 0
    while it < max(needed, 30) and it < iterations:
        it += 1
        pick = rng.choice(usable, size=3, replace=False)
        A_rots = [views[i].T_ref_mount[:3, :3] for i in pick]
        # skip samples with (nearly) no relative robot rotation: the system is then degenerate
        if max(_angle_deg(A_rots[0], A_rots[1]), _angle_deg(A_rots[0], A_rots[2])) < 3.0:
            continue
        # IPPE ranks its two solutions by reprojection error; the better one is right most of the time
        choice = [0 if (len(views[i].R) == 1 or rng.uniform() < 0.75) else 1 for i in pick]
        rows = {0: [(views[i].T_ref_mount[:3, :3], views[i].R[c]) for i, c in zip(pick, choice)]}
        RZ, RY, _ = _solve_rotations(rows, 1)
        errs, idx = _best_candidate_errors(RZ[0], RY, views, stacked)
        inl = errs < ROT_INLIER_DEG
        score = (inl.sum(), -np.sum(np.minimum(errs, ROT_INLIER_DEG)))
        if inl.sum() < 3:
            continue  # not even its own sample agrees: noise, not a hypothesis
        same = [j for j, f in enumerate(found) if _angle_deg(f[2], RY) < 10.0]
        if same:
            j = same[0]
            if score > found[j][0]:
                found[j] = (score, RZ[0], RY, inl, idx)
        else:
            found.append((score, RZ[0], RY, inl, idx))
        best = max(f[0][0] for f in found)
        # adaptive stopping: P(all 3 picks inliers with the right candidates) >= (eps * 0.5)^3
        p = (best / len(usable) * 0.5) ** 3
        needed = int(np.ceil(np.log(1e-3) / np.log(max(1 - p, 1e-12)))) if p > 0 else iterations
    found.sort(key=lambda f: f[0], reverse=True)
    out = []
    for _, RZ, RY, inl, idx in found[:max_hypotheses]:
        # refit on all inliers, then re-select
        for _ in range(2):
            if inl.sum() < 3:
                break
            rows = {0: [(views[i].T_ref_mount[:3, :3], views[i].R[idx[i]]) for i in np.flatnonzero(inl)]}
            RZ1, RY1, _ = _solve_rotations(rows, 1)
            errs, idx = _best_candidate_errors(RZ1[0], RY1, views, stacked)
            inl = errs < ROT_INLIER_DEG
            RZ, RY = RZ1[0], RY1
        if inl.sum() >= 3:
            out.append((RZ, RY, inl, idx))
    return out


def _solve_translations(entries: list, n_cams: int, RZ: list):
    """Least squares for t_Z (per slot) and shared t_Y from (slot, A, R_B, t_B) entries: the
    minimum-norm solution, from normal equations formed block by block (each entry's rows touch its
    camera's t_Z, as the identity, and t_Y)."""
    nu = 3 * (n_cams + 1)
    slots = np.array([e[0] for e in entries])
    A = np.array([e[1] for e in entries])
    M_Y = -A[:, :3, :3]
    b = A[:, :3, 3] - np.einsum("nij,nj->ni", np.array(RZ)[slots], np.array([e[3] for e in entries]))
    N, r = np.zeros((nu, nu)), np.zeros(nu)
    Y = slice(3 * n_cams, nu)
    for slot in np.unique(slots):
        on = slots == slot
        Z = slice(3 * slot, 3 * slot + 3)
        N[Z, Z] = on.sum() * np.eye(3)
        N[Z, Y] = M_Y[on].sum(axis=0)
        N[Y, Z] = N[Z, Y].T
        r[Z] = b[on].sum(axis=0)
    N[Y, Y] = len(entries) * np.eye(3)  # M_Y^T M_Y = I for a rotation
    r[Y] = np.einsum("nji,nj->i", M_Y, b)
    x, *_ = np.linalg.lstsq(N, r, rcond=None)
    return [x[3 * i: 3 * i + 3] for i in range(n_cams)], x[3 * n_cams:]


def _robust_translations(entries, n_cams, RZ):
    tZ, tY = _solve_translations(entries, n_cams, RZ)
    for _ in range(3):
        slots = np.array([e[0] for e in entries])
        A = np.array([e[1] for e in entries])
        tB = np.array([e[3] for e in entries])
        res = np.linalg.norm(np.array(tZ)[slots] + np.einsum("nij,nj->ni", np.array(RZ)[slots], tB)
                             - A[:, :3, :3] @ tY - A[:, :3, 3], axis=1)
        thr = max(3.0 * np.median(res), 0.01)
        keep = [e for e, r in zip(entries, res) if r <= thr]
        if len(keep) == len(entries) or len(keep) < 3:
            break
        entries = keep
        tZ, tY = _solve_translations(entries, n_cams, RZ)
    return tZ, tY


def camera_from_mount(views: list, T_mount_board: np.ndarray):
    """T_ref_cam by consensus over views given the board mount. Returns (T, n_agree)."""
    views = [v for v in views if len(v.R)]
    if not views:
        return None, 0
    A = np.concatenate([np.broadcast_to(v.T_ref_mount, (len(v.R), 4, 4)) for v in views])
    R_cb = np.concatenate([v.R for v in views])
    t_cb = np.concatenate([v.t for v in views])
    T_board_cam = np.zeros((len(R_cb), 4, 4))
    T_board_cam[:, :3, :3] = R_cb.transpose(0, 2, 1)
    T_board_cam[:, :3, 3] = -np.einsum("nji,nj->ni", R_cb, t_cb)
    T_board_cam[:, 3, 3] = 1.0
    props = A @ T_mount_board @ T_board_cam
    Rs = props[:, :3, :3]
    close = _pairwise_cos(Rs) > np.cos(np.radians(ROT_INLIER_DEG))  # angle below ROT_INLIER_DEG
    counts = close.sum(axis=1)
    best = int(np.argmax(counts))
    members = close[best]
    R = project_to_so3(Rs[members].sum(axis=0))
    t = np.median(props[members, :3, 3], axis=0)
    return make_T(R, t), int(counts[best])


def initialise(cameras: list, views_by_cam: dict, joint: bool, seed: int = 0) -> list:
    """Candidate initial guesses, to be ranked by the caller (by reprojection error).

    Args:
        cameras: camera names in slot order.
        views_by_cam: name -> list of ViewCandidates.
        joint: one shared mount (True) or one mount per camera (False).
    Returns:
        A list of (T_ref_cam dict, mounts dict) with mounts keyed 0 in joint mode or by camera name in
        single mode. In single mode each entry holds one hypothesis per camera (entry i uses each
        camera's i-th hypothesis, or its best when it has fewer).
    Raises:
        ObservabilityError when no camera has a consistent set of views.
    """
    rng = np.random.default_rng(seed)
    per_cam = {}
    for name in cameras:
        hyps = ransac_camera(views_by_cam.get(name, []), rng)
        if hyps:
            per_cam[name] = hyps
    if not per_cam:
        raise ObservabilityError(
            "no camera has 3 or more mutually consistent views with different board orientations; "
            "add robot poses that tilt the board (rotations of 15-40 deg about different axes)."
        )
    out = []
    if not joint:
        n_alt = max(len(h) for h in per_cam.values())
        for a in range(n_alt):
            T_ref_cam, mounts = {}, {}
            for name, hyps in per_cam.items():
                RZ, RY, inl, idx = hyps[min(a, len(hyps) - 1)]
                vs = views_by_cam[name]
                entries = [(0, vs[i].T_ref_mount, vs[i].R[idx[i]], vs[i].t[idx[i]]) for i in np.flatnonzero(inl)]
                tZ, tY = _robust_translations(entries, 1, [RZ])
                mounts[name] = make_T(RY, tY)
                T, _ = camera_from_mount(vs, mounts[name])
                T_ref_cam[name] = T if T is not None else make_T(RZ, tZ[0])
            out.append((T_ref_cam, mounts))
        return out
    # joint: every distinct hypothesis of every camera seeds the shared mount; cameras whose own
    # hypotheses agree with the seed join the linear solve
    seeds = []
    for name in sorted(per_cam, key=lambda n: -per_cam[n][0][2].mean()):
        for h in per_cam[name]:
            if all(_angle_deg(h[1], s[1]) > 10.0 for s in seeds):
                seeds.append(h)
    # Distinct mount hypotheses are few in practice (the right one and a flipped one or two); cap the
    # list so that large cells do not pay for every camera's alternatives.
    seeds = seeds[:MAX_MOUNT_SEEDS]
    for RY_seed_h in seeds:
        RY_seed = RY_seed_h[1]
        rows, entries, agreeing = {}, [], []
        for name, hyps in per_cam.items():
            match = [h for h in hyps if _angle_deg(h[1], RY_seed) < 2 * ROT_INLIER_DEG]
            if match:
                agreeing.append((name, match[0]))
        for slot, (name, (RZ, RY, inl, idx)) in enumerate(agreeing):
            vs = views_by_cam[name]
            rows[slot] = [(vs[i].T_ref_mount[:3, :3], vs[i].R[idx[i]]) for i in np.flatnonzero(inl)]
            entries += [(slot, vs[i].T_ref_mount, vs[i].R[idx[i]], vs[i].t[idx[i]]) for i in np.flatnonzero(inl)]
        RZs, RY, _ = _solve_rotations(rows, len(agreeing))
        tZs, tY = _robust_translations(entries, len(agreeing), RZs)
        T_mount_board = make_T(RY, tY)
        T_ref_cam = {}
        for name in cameras:
            T, n_agree = camera_from_mount(views_by_cam.get(name, []), T_mount_board)
            if T is not None:
                T_ref_cam[name] = T
        out.append((T_ref_cam, {0: T_mount_board}))
    return out


def rotation_spread_deg(A_list) -> tuple[float, float]:
    """(largest, second-largest) principal spread of the robot rotations, degrees.

    The rotation vectors of ``A_0^T A_k`` are stacked; their singular values measure how much the
    motion rotates about the dominant and the second axis. Used by the observability check.
    """
    if len(A_list) < 2:
        return 0.0, 0.0
    R0 = A_list[0][:3, :3]
    W = np.array([log_so3(R0.T @ A[:3, :3]) for A in A_list[1:]])
    s = np.linalg.svd(W, compute_uv=False) / np.sqrt(len(W))
    s = np.concatenate([s, [0.0, 0.0]])
    return float(np.degrees(s[0])), float(np.degrees(s[1]))


def refine_translations(views_by_cam: dict, intr_by_cam: dict, T_ref_cam: dict, T_mount_board: np.ndarray,
                        p_board_by_view: dict, uv_by_view: dict):
    """Translations of all cameras and of the mount from every corner, given the rotations.

    With rotations fixed, ``p_cam = q + M_Y t_Y + M_Z t_Z`` is linear in the translations and each
    corner gives two linear equations ``x_n z - x = 0``, ``y_n z - y = 0`` (normalised, undistorted
    image coordinates). Far better conditioned than averaging per-view PnP depths. Views whose
    rotation disagrees with the consensus are left out; the worst views are trimmed once.
    Returns new (T_ref_cam, T_mount_board).
    """
    names = [n for n in T_ref_cam if n in views_by_cam]
    slot = {n: i for i, n in enumerate(names)}
    nu = 3 * (len(names) + 1)
    RY = T_mount_board[:3, :3]
    # per camera, its views whose rotation agrees with the consensus, all their corners at once:
    # each corner's two rows on [t_Z of its camera, t_Y] and right-hand sides, and its view
    G_parts, b_parts, own_parts, AtA_parts, Atb_parts, slot_parts = [], [], [], [], [], []
    nb = 0
    for n in names:
        RZ = T_ref_cam[n][:3, :3]
        intr = intr_by_cam[n]
        vs = [v for v in views_by_cam[n] if len(v.R)]
        if not vs:
            continue
        R, A, cand_view, _ = _stack(vs)
        err = np.full(len(vs), np.inf)
        np.minimum.at(err, cand_view, _angle_deg(RZ @ R, A @ RY))
        vs = [v for v, e in zip(vs, err) if not e > ROT_INLIER_DEG]
        if not vs:
            continue
        pb = np.concatenate([p_board_by_view[(n, v.capture)] for v in vs])
        uv = np.concatenate([uv_by_view[(n, v.capture)] for v in vs])
        counts = np.array([len(p_board_by_view[(n, v.capture)]) for v in vs])
        w = np.repeat(np.arange(len(vs)), counts)  # each corner's view
        xy = cv2.undistortPoints(uv.reshape(-1, 1, 2).astype(np.float64), intr.K, intr.dist).reshape(-1, 2)
        RA = np.array([v.T_ref_mount[:3, :3] for v in vs])
        tA = np.array([v.T_ref_mount[:3, 3] for v in vs])
        q = (np.einsum("nij,nj->ni", (RA @ RY)[w], pb) + tA[w]) @ RZ  # R_Z^T (R_A R_Y p + t_A)
        MY = (RZ.T @ RA)[w]  # (N, 3, 3)
        MZ = -RZ.T
        Gc, bc = [], []
        for c in (0, 1):
            # (xn e3 - e_c)^T p_cam = 0; a view's rows touch its camera's t_Z and t_Y only
            xn = xy[:, c]
            Gc.append(np.hstack([xn[:, None] * MZ[2] - MZ[c], xn[:, None] * MY[:, 2] - MY[:, c]]))
            bc.append(-(xn * q[:, 2] - q[:, c]))
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        AtA_parts.append(np.add.reduceat(np.einsum("ni,nj->nij", Gc[0], Gc[0]) + np.einsum("ni,nj->nij", Gc[1], Gc[1]),
                                         starts))
        Atb_parts.append(np.add.reduceat(Gc[0] * bc[0][:, None] + Gc[1] * bc[1][:, None], starts))
        G_parts += Gc
        b_parts += bc
        own_parts += [w + nb, w + nb]
        slot_parts.append(np.full(len(vs), slot[n]))
        nb += len(vs)
    if nb < 3:
        return T_ref_cam, T_mount_board
    ns = len(names)
    slots = np.concatenate(slot_parts)
    AtA, Atb = np.concatenate(AtA_parts), np.concatenate(Atb_parts)
    G_all, b_all, owner = np.concatenate(G_parts), np.concatenate(b_parts), np.concatenate(own_parts)
    use = np.ones(nb, bool)
    # A weak pull towards the current translations keeps directions the kept views do not determine
    # (a camera whose views all fell out, a mount seen edge-on) where they were instead of singular.
    x0 = np.concatenate([T_ref_cam[n][:3, 3] for n in names] + [T_mount_board[:3, 3]])
    Y = slice(3 * ns, nu)
    for _ in range(2):
        N_zz, N_zy = np.zeros((ns, 3, 3)), np.zeros((ns, 3, 3))
        r_z = np.zeros((ns, 3))
        np.add.at(N_zz, slots[use], AtA[use, :3, :3])
        np.add.at(N_zy, slots[use], AtA[use, :3, 3:])
        np.add.at(r_z, slots[use], Atb[use, :3])
        N, r = np.zeros((nu, nu)), np.zeros(nu)
        for i in range(ns):
            Z = slice(3 * i, 3 * i + 3)
            N[Z, Z], N[Z, Y], N[Y, Z], r[Z] = N_zz[i], N_zy[i], N_zy[i].T, r_z[i]
        N[Y, Y], r[Y] = AtA[use, 3:, 3:].sum(axis=0), Atb[use, 3:].sum(axis=0)
        lam = 1e-9 * max(np.trace(N) / len(N), 1e-12)
        x = np.linalg.solve(N + lam * np.eye(len(N)), r + lam * x0)
        xb = np.hstack([x[:3 * ns].reshape(ns, 3)[slots], np.broadcast_to(x[Y], (nb, 3))])  # each view's unknowns
        e = np.einsum("rj,rj->r", G_all, xb[owner]) - b_all
        res = np.sqrt(np.bincount(owner, e * e, nb) / np.bincount(owner, minlength=nb))
        keep = res <= 4.0 * np.median(res) + 1e-9
        if np.array_equal(keep, use) or keep.sum() < 3:
            break
        use = keep
    out = {n: make_T(T_ref_cam[n][:3, :3], x[3 * slot[n]: 3 * slot[n] + 3]) if n in slot else T_ref_cam[n] for n in T_ref_cam}
    return out, make_T(RY, x[3 * len(names):])
