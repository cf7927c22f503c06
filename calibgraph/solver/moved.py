"""A camera bumped during capture: found, named, and calibrated from where it ended up.

A fixed camera that is knocked between two captures has two poses in one dataset. A solver that
assumes one pose averages them (the estimate lands between the two, with a 1σ that believes it)
or rejects the views of the minority pose as outliers and reports the old pose. Neither is a
calibration of the camera as it now stands.

The test, per camera of an eye-to-hand result: with the board mount, the board scale and the
recorded flange poses of the solve, every corner the camera saw is a known point in the base
frame, so the camera's pose is a PnP fit over all its views. For every split of its views in
capture order (each side at least ``MIN_GROUP_VIEWS`` views) the two sides are fitted apart; the
split is kept when two poses explain the corners far better than one (an F test on the residual
sums, 6 against 12 pose parameters), when the split explains most of what one pose leaves above the
cell's noise level (the solve's pixel sigma) and the two poses leave about that level, and when each
side is consistent on its own. The camera is then calibrated from the side that matches the end of the
capture (the views before the move are set aside, listed as rejected with the reason), the
problem is solved again, and a note says which camera moved, between which captures and by how
much (mm, deg). The two poses are never averaged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError, ObservabilityError
from calibgraph.core.transforms import inv, pose_error
from calibgraph.solver.result import RejectedView

MIN_GROUP_VIEWS = 2     # a side of a split needs this many views (one view is a single outlier, not a pose)
F_LIMIT = 20.0          # two poses must explain the corners this much better than one (F, 6 and N-12 dof;
                        # p < 1e-20 for pure noise at the corner counts of a calibration)
EXPLAINED = 0.7         # ... the split explains this share of the residual above the cell's noise level
AT_NOISE = 1.5          # ... and the two poses leave an RMS within this factor of the cell's pixel sigma
SELF_CONSISTENT = 2.0   # each side's RMS within this factor of the pooled RMS of the split
MAX_MOVED = 3           # cameras handled in one solve
LINEAR_F_SKIP = 0.25     # skip the exact fits when the best linearised F is below this share of F_LIMIT
EXACT_SPLITS = 3        # the best linearised splits whose neighbourhoods are refitted exactly


@dataclass(frozen=True)
class Move:
    """A camera whose views split into two self-consistent groups."""

    camera: str
    last_before: int        # last capture index before the move
    first_after: int        # first capture index after it
    captures_before: tuple  # capture indices of the views before the move (set aside)
    captures_after: tuple   # those after (used)
    displacement_mm: float
    rotation_deg: float
    f_stat: float
    rms_one_px: float
    rms_two_px: float

    def note(self) -> str:
        return (f"camera {self.camera} moved during capture, between captures {self.last_before} and {self.first_after}, "
                f"by {self.displacement_mm:.1f} mm and {self.rotation_deg:.2f} deg: its views split into two "
                f"self-consistent groups ({len(self.captures_before)} views before, {len(self.captures_after)} after; "
                f"one pose leaves {self.rms_one_px:.2f} px RMS, two leave {self.rms_two_px:.2f} px). Calibrated from "
                f"the {len(self.captures_after)} views after the move (the camera as it stood at the end of the "
                f"capture); the {len(self.captures_before)} earlier views were set aside, not averaged in. Fix the "
                "camera's mount and re-capture for more views in its final pose.")


def _intrinsics(problem, result, name) -> Intrinsics:
    if name not in result.cameras:
        return problem.cameras[name]
    d = result.cameras[name].intrinsics
    return Intrinsics.from_dict(d) if d else problem.cameras[name]


def _base_points(problem, result, views) -> tuple:
    """(points in the base frame (N, 3), pixels (N, 2), view number of each point)."""
    caps = {c.index: c.T_base_flange for c in problem.captures}
    caps.update(result.T_base_flange_est or {})  # the solve's flange poses (FK noise taken out) where it has them
    T_fb = result.T_mount_board
    p_board = problem.points_board_m * float(result.board_scale or 1.0)
    P, uv, which = [], [], []
    for k, d in enumerate(views):
        pb = p_board[d.ids]
        T = caps[d.capture] @ T_fb
        P.append(pb @ T[:3, :3].T + T[:3, 3])
        uv.append(np.asarray(d.uv_px, float))
        which.append(np.full(len(d.ids), k))
    return np.concatenate(P), np.concatenate(uv), np.concatenate(which)


def _fit(P, uv, intr: Intrinsics, T_cam_base0):
    """PnP over many views: (T_cam_base, residual sum of squares, N points)."""
    import cv2

    rvec0, _ = cv2.Rodrigues(T_cam_base0[:3, :3])
    tvec0 = T_cam_base0[:3, 3].reshape(3, 1).copy()
    ok, rvec, tvec = cv2.solvePnP(P, uv, intr.K, intr.dist8, rvec0.copy(), tvec0, useExtrinsicGuess=True,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok:
        rvec, tvec = rvec0, tvec0
    rvec, tvec = cv2.solvePnPRefineLM(P, uv, intr.K, intr.dist8, rvec, tvec)
    proj, _ = cv2.projectPoints(P, rvec, tvec, intr.K, intr.dist8)
    r = proj.reshape(-1, 2) - uv
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(rvec)[0]
    T[:3, 3] = tvec.ravel()
    return T, float(np.sum(r ** 2)), len(P)


def _linear_split_scores(P, uv, which, n_views: int, intr: Intrinsics, T_cam_base) -> np.ndarray:
    """Residual sum of squares of the best two-pose fit for every split ``k`` (views ``< k`` | ``>= k``),
    linearised at the one-pose fit ``T_cam_base``: a group's best pose lowers its residual sum by
    ``g^T H^-1 g`` (Gauss-Newton, ``H``, ``g`` summed over the group's views). Prefix sums make every
    split O(1), so scanning all of them costs one projection instead of two PnP fits per split.
    Returns (n_views + 1,) with inf where a side has fewer than ``MIN_GROUP_VIEWS`` views."""
    import cv2

    rvec, _ = cv2.Rodrigues(T_cam_base[:3, :3])
    proj, jac = cv2.projectPoints(P, rvec, T_cam_base[:3, 3].reshape(3, 1), intr.K, intr.dist8)
    r = (proj.reshape(-1, 2) - uv).reshape(-1)
    J = jac[:, :6]
    rows = np.repeat(which, 2)
    H = np.zeros((n_views, 6, 6))
    g = np.zeros((n_views, 6))
    s = np.zeros(n_views)
    np.add.at(H, rows, J[:, :, None] * J[:, None, :])
    np.add.at(g, rows, J * r[:, None])
    np.add.at(s, rows, r * r)
    zero = (np.zeros((1, 6, 6)), np.zeros((1, 6)), np.zeros(1))
    cH, cg, cs = (np.concatenate([z, np.cumsum(a, axis=0)]) for z, a in zip(zero, (H, g, s)))

    def reduced(Hk, gk, sk):
        return sk - gk @ np.linalg.lstsq(Hk, gk, rcond=None)[0]

    out = np.full(n_views + 1, np.inf)
    for k in range(MIN_GROUP_VIEWS, n_views - MIN_GROUP_VIEWS + 1):
        out[k] = reduced(cH[k], cg[k], cs[k]) + reduced(cH[-1] - cH[k], cg[-1] - cg[k], cs[-1] - cs[k])
    return out


def _global_pnp(P, uv, intr: Intrinsics) -> np.ndarray:
    """T_cam_base from all points without a starting guess (SQPnP: the points span the workspace, so
    there is no planar ambiguity)."""
    import cv2

    ok, rvec, tvec = cv2.solvePnP(P, uv, intr.K, intr.dist8, flags=cv2.SOLVEPNP_SQPNP)
    T = np.eye(4)
    if ok:
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
    return T


def find_move(problem, result, name: str) -> Move | None:
    """The best split of camera ``name``'s views into two poses, when it passes the tests; else None.

    Every split is scored by its linearised two-pose residual (:func:`_linear_split_scores`); the
    few best are fitted exactly (two PnP fits each) and the tests run on the exact fits."""
    views = sorted((d for d in problem.detections if d.camera == name and len(d.ids) >= 4), key=lambda d: d.capture)
    if len(views) < 2 * MIN_GROUP_VIEWS or result.T_mount_board is None:
        return None
    intr = _intrinsics(problem, result, name)
    P, uv, which = _base_points(problem, result, views)
    known = name in result.cameras and result.cameras[name].calibrated
    T0 = inv(result.cameras[name].T_ref_cam) if known else _global_pnp(P, uv, intr)
    T_one, rss_one, n = _fit(P, uv, intr, T0)
    if n <= 12:
        return None
    approx = _linear_split_scores(P, uv, which, len(views), intr, T_one)
    order = [int(k) for k in np.argsort(approx) if np.isfinite(approx[k])]
    if not order:
        return None
    f_lin = ((rss_one - approx[order[0]]) / 6.0) / (max(approx[order[0]], 1e-12) / (n - 12))
    if f_lin < LINEAR_F_SKIP * F_LIMIT:  # no split comes near the test even linearised: one pose it is
        return None
    # the linearisation ranks splits well near the best one; refit its neighbourhood exactly
    candidates = sorted({j for k in order[:EXACT_SPLITS] for j in (k - 1, k, k + 1)
                         if MIN_GROUP_VIEWS <= j <= len(views) - MIN_GROUP_VIEWS})
    best = None
    for k in candidates:
        a, b = which < k, which >= k
        Ta, rss_a, na = _fit(P[a], uv[a], intr, T_one)
        Tb, rss_b, nb = _fit(P[b], uv[b], intr, T_one)
        rss_two = rss_a + rss_b
        if rss_two <= 0:
            continue
        f = ((rss_one - rss_two) / 6.0) / (rss_two / (n - 12))
        if best is None or f > best[0]:
            best = (f, k, Ta, Tb, rss_a / max(na - 6, 1), rss_b / max(nb - 6, 1), rss_two)
    if best is None:
        return None
    f, k, Ta, Tb, var_a, var_b, rss_two = best
    rms_one, rms_two = np.sqrt(rss_one / n), np.sqrt(rss_two / n)
    pooled = rss_two / (n - 12)
    if f < F_LIMIT:
        return None
    # Effect size: the split must explain most of what one pose leaves above the cell's noise level
    # (the solve's pixel sigma over all cameras), and the two poses must leave about that level. A
    # model error that is not a move (lens, kinematics) is not explained by one cut in time.
    sigma2 = float(result.pixel_sigma_px or 0.0) ** 2
    noise_one, noise_two = (2 * n - 6) * sigma2, (2 * n - 12) * sigma2
    excess = rss_one - noise_one
    if excess <= 0 or (rss_one - rss_two) < EXPLAINED * excess or rss_two > AT_NOISE ** 2 * noise_two:
        return None
    if max(var_a, var_b) > SELF_CONSISTENT ** 2 * pooled:  # one side is itself a mixture: not one clean move
        return None
    d_m, d_deg = pose_error(inv(Ta), inv(Tb))
    return Move(name, views[k - 1].capture, views[k].capture, tuple(d.capture for d in views[:k]),
                tuple(d.capture for d in views[k:]), 1e3 * d_m, d_deg, float(f), float(rms_one), float(rms_two))


def find_moves(problem, result, skip=()) -> list:
    """Every eye-to-hand camera of ``result`` whose views split into two poses, strongest first."""
    if problem.mode != "eye_to_hand" or result.T_mount_board is None:
        return []
    moves = [m for n in result.cameras if n not in skip for m in [find_move(problem, result, n)] if m is not None]
    return sorted(moves, key=lambda m: -m.f_stat)


def _drop_before(problem, m: Move):
    drop = {(m.camera, c) for c in m.captures_before}
    return problem.with_(detections=tuple(d for d in problem.detections if (d.camera, d.capture) not in drop))


def _without_before(problem, m: Move, resolve):
    """(problem without ``m``'s views from before the move, its solution); too few views left is an
    error that names the move."""
    problem = _drop_before(problem, m)
    try:
        return problem, resolve(problem)
    except ObservabilityError as e:
        raise _too_few_after(m, e) from None


def _too_few_after(m: Move, e: Exception) -> ObservabilityError:
    return ObservabilityError(
        f"camera {m.camera} moved during capture, between captures {m.last_before} and {m.first_after}, by about "
        f"{m.displacement_mm:.0f} mm and {m.rotation_deg:.1f} deg (its views split into two self-consistent "
        f"groups); the {len(m.captures_after)} views after the move are too few to calibrate it as it now "
        f"stands ({e}) and the earlier ones describe a pose it no longer has: fix its mount and capture more "
        "views of it.", camera=m.camera)


def _move_behind_rejection(problem, error: ObservabilityError, resolve) -> Move | None:
    """When the solve rejected every view of one camera, was it because the camera moved? The other
    cameras are solved without it (mount, scale and flange poses from them), then its views are
    tested for a split as in :func:`find_move`."""
    name = getattr(error, "camera", None)
    if name is None or problem.mode != "eye_to_hand" or len(problem.cameras) < 2:
        return None
    others = problem.with_(cameras={n: c for n, c in problem.cameras.items() if n != name},
                           detections=tuple(d for d in problem.detections if d.camera != name))
    try:
        rest = resolve(others)
    except CalibgraphError:
        return None
    return find_move(problem, rest, name)


def solve_minding_moves(problem, resolve) -> object:
    """``resolve(problem)``, or, when a camera moved during capture, the result of ``problem``
    without that camera's views from before the move, with a note and the set-aside views listed
    as rejected. Cameras are handled one at a time, strongest split first, and the others tested
    again on the new solution. A camera whose views were all rejected is tested too: a move explains
    that better than "inconsistent views"."""
    moves, handled, original = [], set(), problem
    try:
        result = resolve(problem)
    except ObservabilityError as e:
        m = _move_behind_rejection(problem, e, resolve)
        if m is None:
            raise
        problem, result = _without_before(problem, m, resolve)
        handled.add(m.camera)
        moves.append(m)
    while len(moves) < MAX_MOVED:
        found = find_moves(problem, result, skip=handled)
        if not found:
            break
        m = found[0]
        problem, result = _without_before(problem, m, resolve)
        handled.add(m.camera)
        moves.append(m)
    if not moves:
        return result
    moves = [_measured_again(original, result, m) for m in moves]  # the mount is no longer dragged
    cams = dict(result.cameras)
    for m in moves:
        if not cams[m.camera].calibrated:
            continue
        reason = (f"camera moved between captures {m.last_before} and {m.first_after}: this view is from before the move "
                  "and was set aside")
        rv = tuple(RejectedView(m.camera, c, reason) for c in m.captures_before)
        cams[m.camera] = replace(cams[m.camera], views_rejected=tuple(cams[m.camera].views_rejected) + rv)
    return replace(result, cameras=cams, rejected_views=tuple(rv for c in cams.values() for rv in c.views_rejected),
                   notes=tuple(result.notes) + tuple(m.note() for m in moves))


def _measured_again(problem, result, m: Move) -> Move:
    """``m`` with the displacement between the camera's pose before the move (a PnP fit of the
    set-aside views on ``result``'s mount) and its calibrated pose after it."""
    before = set(m.captures_before)
    views = [d for d in problem.detections if d.camera == m.camera and d.capture in before and len(d.ids) >= 4]
    if not views:
        return m
    if not views or not result.cameras[m.camera].calibrated:
        return m
    P, uv, _ = _base_points(problem, result, views)
    T_after = result.cameras[m.camera].T_ref_cam
    T_cb, _, _ = _fit(P, uv, _intrinsics(problem, result, m.camera), inv(T_after))
    d_m, d_deg = pose_error(inv(T_cb), T_after)
    return replace(m, displacement_mm=1e3 * d_m, rotation_deg=d_deg)
