"""Active refinement: the next robot pose by expected information gain per second of motion.

After the survey every camera that saw the board has a pose ``T_base_cam`` and a 6x6 marginal
covariance (rotation first, base axes: the left rotation vector and the camera-centre offset):
the batch solve of every capture so far (:mod:`calibgraph.acquire.auto`), the numbers the stop
rule and ``result.json`` use. A candidate flange pose is scored on the *linearised calibration
graph* (:func:`joint_information`): the parameters are every placed camera, the board mount and
the board scale; each capture's flange is marginalised under the FK prior, so the cameras that
see one capture share it:

    J_k   = d uv / d(cameras, mount, scale, flange_k)   (2 rows per corner seen, 6K + 13 columns)
    I_k   = Schur complement of flange_k in  J_k^T J_k / sigma_px^2 + FK prior
    Sigma = (priors + sum over the captures so far of I_k)^-1,  Sigma' = (Sigma^-1 + I_candidate)^-1

This is the solver's graph at the current estimate (``tests/test_auto.py`` checks it against
:func:`calibgraph.solver.covariance.crlb`); what it leaves out (intrinsics, robust weights) is carried
by applying its *ratio* to the batch 1-sigma: predicted sigma_c = batch sigma_c x model sigma'_c /
model sigma_c. It matters for far cameras: their depth is tied to the board scale and their
lateral position to their rotation, and only views at several depths and sides, or other
cameras' views, untie them; a one-camera model with the mount and scale held known predicted
1.7 mm -> 0.77 mm for a view that gave 1.18 mm (top-down cell), now 1.185 for 1.183.

A camera counts as seeing a candidate when the whole board is in view from its *estimated* pose
(:func:`calibgraph.plan.visibility.board_visible`, with an image margin grown by the pixel shift
the pose's 3-sigma would cause). A camera's shortfall is ``rho_c = max(|sigma_t| / tol_mm,
|sigma_r| / tol_deg)`` (norms of the per-axis 1-sigma); the score is

    gain = sum_c max(rho_c, 1)^2 - max(rho'_c, 1)^2        (cameras already within tolerance add 0)

per second (joint-space motion time at the speed scale, plus settling, plus :data:`CAPTURE_S`
for the capture itself), so the worst camera counts most, a pose that helps two cameras at once
wins over one that helps one, and a view that pins the shared mount or scale helps cameras that
do not see it.

Candidates come from a pool of reachable, collision-free configurations (IK within the joint
limits on the planning world, keep-out volumes round the estimated cameras checked), topped up
every step: board poses facing a camera short of tolerance (or the bisector of two), their
centres half the time near the camera's azimuth and half anywhere round the base (a far camera
learns most from board positions spread across and along its line of sight), :data:`OVERSAMPLE`
times more drawn than the IK is given, ranked by the model's expected gain first; a candidate is
used once. Choosing costs well under a second on two cores (``scripts/bench_choose.py``): the
whole pool is scored in one vectorised pass (:func:`~calibgraph.plan.visibility.boards_visible`,
:func:`joint_information` on a stack of poses), ray casts and path checks only for the best dozen.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibgraph.core.transforms import inv
from calibgraph.plan.planner import free_motion
from calibgraph.plan.survey import board_pose_facing, reach_pose, seeds_at
from calibgraph.plan.visibility import board_visible, boards_visible, occlusion_probes, square_px

__all__ = ["CameraBelief", "Candidate", "Choice", "ActivePlanner", "view_information", "sigma_norms", "shortfall",
           "motion_time_s", "keepout_violation", "explain_shortfall"]

SETTLE_S = 0.5  # what every motion costs on top of the joint-space time (the simulated robot's model too)
STAND_RADIUS_M = 0.25  # keep-out radius round an estimated camera stand, before its uncertainty
BOARD_SCALE_SIGMA = 0.02  # the solver's default prior on the printed board's scale (SolverOptions.board_scale_sigma)
# What a capture costs beyond its motion (grabbing every camera, detection, the solve): in the score's
# per-second denominator it keeps a short motion to a nearly useless pose from beating a longer one to
# a useful pose (bench cells, 6 runs: 59 captures at 2 s against 65 at 0 s; 59 at 6 s, with more robot time).
CAPTURE_S = 2.0
# Board poses drawn per IK tried (the best by expected gain go to the IK). 10 gave no fewer captures
# than 4 on the irregular cell (42 against 41 on average over seeds 0-5, with less spread), at more
# choose time.
OVERSAMPLE = 4


@dataclass(frozen=True)
class CameraBelief:
    """What the loop knows about a camera: intrinsics, estimated ``T_base_cam`` (4, 4) and its
    6x6 covariance (rotation first, base axes; None while only a single-view guess exists)."""

    name: str
    intrinsics: object
    T_base_cam: np.ndarray
    covariance: np.ndarray | None = None
    views: int = 0


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


def view_information(intrinsics, T_base_cam: np.ndarray, T_base_board: np.ndarray, points_board_m: np.ndarray,
                     pixel_sigma_px: float, T_flange_board: np.ndarray | None = None,
                     fk_sigma_translation_m: float = 0.0, fk_sigma_rotation_rad: float = 0.0) -> np.ndarray:
    """Fisher information (6x6, rotation first, base axes) on ``T_base_cam`` of one view of the
    board points; for ``T_base_board`` (M, 4, 4) the M views' informations (M, 6, 6) at once.

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
    p = np.einsum("nj,mij->mni", points_board_m, T_bb[:, :3, :3]) + T_bb[:, None, :3, 3]  # (M, N, 3) base
    p_cam = (p - c) @ R
    _, Jp = intrinsics.project(p_cam.reshape(-1, 3), with_jacobian=True)  # (M N, 2, 3)
    Jp = np.where(np.all(np.isfinite(Jp), axis=(1, 2))[:, None, None], Jp, 0.0)  # behind the camera: no information
    JpR = Jp @ R.T  # d uv / d p (base axes)
    # d p_cam / d(dr, dt) = R^T [[p - c]x, -I]  =>  d uv / d(dr) = JpR [p - c]x, d uv / d(dt) = -JpR
    Jc = np.empty((M * N, 2, 6))
    Jc[:, :, :3] = np.einsum("nij,njk->nik", JpR, _skew_rows((p - c).reshape(-1, 3)))
    Jc[:, :, 3:] = -JpR
    Jc = Jc.reshape(M, 2 * N, 6)
    w = 1.0 / pixel_sigma_px ** 2
    I_cc = w * np.einsum("mki,mkj->mij", Jc, Jc)
    if T_flange_board is None or not (fk_sigma_translation_m > 0 and fk_sigma_rotation_rad > 0):
        return I_cc[0] if single else I_cc
    # flange right-perturbation xi = [w, v]: p = T_bf exp(xi) p_f moves by R_bf ([-p_f]x w + v)
    T_bf = T_bb @ np.linalg.inv(T_flange_board)
    R_bf = T_bf[:, :3, :3]
    p_f = np.einsum("mni,mij->mnj", p - T_bf[:, None, :3, 3], R_bf)  # flange axes
    JpRf = np.einsum("mnij,mjk->mnik", JpR.reshape(M, N, 2, 3), R_bf)  # d uv / d p (flange axes)
    Jf = np.empty((M, N, 2, 6))
    Jf[..., :3] = -np.einsum("mnij,mnjk->mnik", JpRf, _skew_rows(p_f.reshape(-1, 3)).reshape(M, N, 3, 3))
    Jf[..., 3:] = JpRf
    Jf = Jf.reshape(M, 2 * N, 6)
    prior = np.diag(1.0 / np.array([fk_sigma_rotation_rad] * 3 + [fk_sigma_translation_m] * 3) ** 2)
    I_cf = w * np.einsum("mki,mkj->mij", Jc, Jf)
    I_ff = w * np.einsum("mki,mkj->mij", Jf, Jf) + prior
    out = I_cc - I_cf @ np.linalg.solve(I_ff, np.swapaxes(I_cf, 1, 2))
    return out[0] if single else out


def view_jacobians(intrinsics, T_base_cam: np.ndarray, T_base_flange: np.ndarray, T_flange_board: np.ndarray,
                   points_board_m: np.ndarray) -> np.ndarray:
    """d uv / d(camera, flange, mount, board scale) of the board points seen by one camera from
    the flange poses ``T_base_flange`` (M, 4, 4): (M, 2N, 19), columns [camera 6 (base axes, as in
    :func:`view_information`), flange 6 (right perturbation), mount 6 (right perturbation of
    ``T_flange_board``), board scale 1 (the points scaled about the board origin, as the solver does)].
    Points behind the camera give zero rows."""
    T_bf = np.asarray(T_base_flange, float).reshape(-1, 4, 4)
    M, N = len(T_bf), len(points_board_m)
    T_bb = T_bf @ T_flange_board
    R_bb = T_bb[:, :3, :3]
    R, c = T_base_cam[:3, :3], T_base_cam[:3, 3]
    p = np.einsum("nj,mij->mni", points_board_m, R_bb) + T_bb[:, None, :3, 3]  # (M, N, 3) base
    _, Jp = intrinsics.project(((p - c) @ R).reshape(-1, 3), with_jacobian=True)
    Jp = np.where(np.all(np.isfinite(Jp), axis=(1, 2))[:, None, None], Jp, 0.0)
    JpR = (Jp @ R.T).reshape(M, N, 2, 3)  # d uv / d p (base axes)
    J = np.empty((M, N, 2, 19))
    J[..., :3] = np.einsum("mnij,mnjk->mnik", JpR, _skew_rows((p - c).reshape(-1, 3)).reshape(M, N, 3, 3))
    J[..., 3:6] = -JpR
    R_bf = T_bf[:, :3, :3]
    p_f = np.einsum("mni,mij->mnj", p - T_bf[:, None, :3, 3], R_bf)  # flange axes
    JpRf = np.einsum("mnij,mjk->mnik", JpR, R_bf)
    J[..., 6:9] = -np.einsum("mnij,mnjk->mnik", JpRf, _skew_rows(p_f.reshape(-1, 3)).reshape(M, N, 3, 3))
    J[..., 9:12] = JpRf
    JpRb = np.einsum("mnij,mjk->mnik", JpR, R_bb)
    J[..., 12:15] = -np.einsum("mnij,njk->mnik", JpRb, _skew_rows(np.asarray(points_board_m, float)))
    J[..., 15:18] = JpRb
    J[..., 18] = np.einsum("mnij,nj->mni", JpRb, np.asarray(points_board_m, float))
    return J.reshape(M, 2 * N, 19)


def joint_information(cams: list, seen: np.ndarray, T_base_flange: np.ndarray, T_flange_board: np.ndarray,
                      points_board_m: np.ndarray, pixel_sigma_px: float, fk_sigma_translation_m: float,
                      fk_sigma_rotation_rad: float) -> np.ndarray:
    """Fisher information of M captures on the parameters shared across views, each capture's
    flange marginalised under the FK prior: (M, P, P) with P = 6K + 7, the order [camera 1 ... camera
    K (6 each, rotation first, base axes), mount 6, board scale 1]. ``cams``: K (intrinsics,
    T_base_cam); ``seen``: (M, K) which cameras see each capture.

    This is the linearised calibration graph one capture at a time: unlike :func:`view_information`
    (one camera, mount and scale held known) the cameras of a capture share its flange, and every
    view informs the mount and the board scale that all cameras depend on. A far camera's depth is
    tied to the board scale (a 1e-4 scale error is 0.45 mm at 4.5 m), which only views at several
    depths, or other cameras, pin down."""
    T_bf = np.asarray(T_base_flange, float).reshape(-1, 4, 4)
    seen = np.asarray(seen, bool).reshape(len(T_bf), len(cams))
    M, K = len(T_bf), len(cams)
    P = 6 * K + 7
    w = 1.0 / pixel_sigma_px ** 2
    L = np.zeros((M, P + 6, P + 6))
    for k, (intr, T_bc) in enumerate(cams):
        m = seen[:, k]
        if not m.any():
            continue
        J = view_jacobians(intr, T_bc, T_bf[m], T_flange_board, points_board_m)
        idx = np.r_[6 * k:6 * k + 6, P:P + 6, 6 * K:6 * K + 7]  # camera, flange, mount + scale
        L[np.ix_(np.flatnonzero(m), idx, idx)] += w * np.einsum("mki,mkj->mij", J, J)
    L[:, P:, P:] += np.diag(1.0 / np.array([fk_sigma_rotation_rad] * 3 + [fk_sigma_translation_m] * 3) ** 2)
    I_pf = L[:, :P, P:]
    return L[:, :P, :P] - I_pf @ np.linalg.solve(L[:, P:, P:], np.swapaxes(I_pf, 1, 2))


def _block_sigmas(cov: np.ndarray, K: int) -> np.ndarray:
    """(..., K, 2) translation-norm (mm) and rotation-norm (deg) 1-sigma of each camera block of a
    joint covariance (..., P, P)."""
    d = np.sqrt(np.clip(np.diagonal(cov, axis1=-2, axis2=-1)[..., :6 * K], 0, None))
    d = d.reshape(*d.shape[:-1], K, 6)
    return np.stack([np.linalg.norm(d[..., 3:], axis=-1) * 1e3, np.degrees(np.linalg.norm(d[..., :3], axis=-1))], -1)


def _skew_rows(v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) skew matrices of the rows of ``v`` (N, 3)."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2] = -v[:, 2], v[:, 1]
    S[:, 1, 0], S[:, 1, 2] = v[:, 2], -v[:, 0]
    S[:, 2, 0], S[:, 2, 1] = -v[:, 1], v[:, 0]
    return S


def motion_time_s(q0, q1, dq_max_rad_s, speed_scale: float) -> float:
    """Time of a straight joint-space motion at ``speed_scale`` of the joint velocity limits, plus settling."""
    dq = np.abs(np.asarray(q1, float) - np.asarray(q0, float))
    return float(np.max(dq / (np.asarray(dq_max_rad_s, float) * speed_scale))) + SETTLE_S


def _pixel_margin(b: CameraBelief, distance_m):
    """Image margin (px) covering the 3-sigma pixel shift of the board under the pose's uncertainty
    (``distance_m`` a scalar or an array: the margins of many board poses)."""
    d = np.asarray(distance_m, float)
    if b.covariance is None:
        return np.full(d.shape, 150.0) if d.ndim else 150.0
    f = float(b.intrinsics.K[0, 0])
    s_rot = np.sqrt(max(np.max(np.linalg.eigvalsh(b.covariance[:3, :3])), 0.0))
    s_t = np.sqrt(max(np.max(np.linalg.eigvalsh(b.covariance[3:, 3:])), 0.0))
    m = np.minimum(12.0 + 3.0 * f * (s_rot + s_t / np.maximum(d, 0.3)), 200.0)
    return m if d.ndim else float(m)


def keepout_violation(points_m: np.ndarray, beliefs: dict, floor_z_m: float) -> str | None:
    """Name of the estimated camera whose stand volume (a vertical cylinder from the floor to 0.15 m
    above the camera, radius 0.25 m + 3 sigma of its horizontal position) holds one of ``points_m``."""
    P = np.asarray(points_m, float).reshape(-1, 3)
    for b in beliefs.values():
        c = b.T_base_cam[:3, 3]
        s_xy = 0.5 if b.covariance is None else float(np.sqrt(max(np.max(np.linalg.eigvalsh(b.covariance[3:5, 3:5])), 0)))
        r = STAND_RADIUS_M + 3.0 * min(s_xy, 0.5)
        inside = (np.hypot(P[:, 0] - c[0], P[:, 1] - c[1]) < r) & (P[:, 2] < c[2] + 0.15) & (P[:, 2] > floor_z_m)
        if np.any(inside):
            return b.name
    return None


@dataclass(eq=False)
class Candidate:
    """A reachable, collision-free configuration and the flange pose it gives; ``aimed``: the
    cameras its board pose was sampled for."""

    q_rad: np.ndarray
    T_base_flange: np.ndarray
    aimed: tuple
    probe_m: np.ndarray = field(repr=False, default=None)  # flange + board outline, base frame
    last_gain: float = 0.0


@dataclass(frozen=True)
class Choice:
    """The pose chosen, its expected effect and the motion to it.

    Attributes:
        candidate: the :class:`Candidate`.
        motion: joint targets ``[via..., goal]`` (straight joint motions, collision-free).
        time_s: predicted motion time (vias included).
        gain: score numerator (sum of squared shortfall reductions).
        sees: cameras expected to see the whole board.
        predicted: camera -> (1-sigma mm, 1-sigma deg) expected after the capture.
        why: one line for the plan log.
        candidates: the best candidates of this choice (at most ``ActivePlanner.n_logged``), best
            first: dicts ``board_centre_m`` [x, y, z] (base frame, estimated mount), ``score`` (gain
            per second, geometric visibility) and ``gain``; for the plan log and the rerun recording.
        board_centre_m: board centre of the chosen candidate (base frame, estimated mount).
        chosen_index: its place in ``candidates`` (the occlusion check re-ranks the best dozen, so
            it need not be 0).
    """

    candidate: Candidate
    motion: list
    time_s: float
    gain: float
    sees: tuple
    predicted: dict
    why: str
    candidates: tuple = ()
    board_centre_m: tuple = ()
    chosen_index: int = -1


class ActivePlanner:
    """Candidate pool + scoring (see the module docstring).

    Args:
        world: the planning :class:`~calibgraph.plan.planner.RobotWorld` (robot and declared
            geometry only).
        cell: the :class:`~calibgraph.plan.cell.CellDescription`.
        dq_max_rad_s: (7,) joint velocity limits for the motion-time model.
        speed_scale: fraction of them the robot moves at.
        seed: sampling seed.
        fk_sigma_translation_m, fk_sigma_rotation_rad: the solver's FK prior (its defaults), marginalised
            out of each view's information.
    """

    def __init__(self, world, cell, dq_max_rad_s, speed_scale: float = 0.2, seed: int = 0, tilt_deg: float = 50.0,
                 roll_deg: float = 30.0, radius_m=(0.30, 0.75), height_m=(0.15, 0.95),
                 fk_sigma_translation_m: float = 1e-4, fk_sigma_rotation_rad: float = float(np.radians(0.01))):
        self.world, self.cell = world, cell
        self.fk_sigmas = (float(fk_sigma_translation_m), float(fk_sigma_rotation_rad))
        self.dq_max = np.asarray(dq_max_rad_s, float)
        self.speed_scale = float(speed_scale)
        self.rng = np.random.default_rng(seed)
        self.tilt, self.roll = np.radians(tilt_deg), np.radians(roll_deg)
        self.radius_m = radius_m
        self.height_m = height_m
        self.pool: list = []
        self.n_logged = 20  # candidates per choice kept for the plan log (Choice.candidates)
        self.oversample = OVERSAMPLE
        self.pruned = 0  # samples dropped before the IK (keep-out, or seen by no camera that can gain)
        self.ik_tries = 0  # samples given to the IK
        self._points_b = cell.target.points_board_m
        tgt = cell.target
        corners = [0, tgt.cols - 1, (tgt.rows - 1) * tgt.cols, tgt.n_points - 1]
        self._outline_b = tgt.points_board_m[corners]

    # -- pool ----------------------------------------------------------------------------------------
    def _probe(self, T_bf, T_fb):
        T_bb = T_bf @ T_fb
        return np.vstack([T_bf[:3, 3], self._outline_b @ T_bb[:3, :3].T + T_bb[:3, 3]])

    def top_up(self, beliefs: dict, weights: dict, n_new: int, q_now, T_flange_board, useful=None, prescore=None,
               oversample: int = 1) -> int:
        """Sample ``n_new`` board poses aimed at the cameras (chosen with probability ~ ``weights``,
        a third of them between two cameras) and add the reachable, collision-free ones to the
        pool. Returns how many were added.

        Cheap tests run before the IK (the costly part): a pose inside a keep-out, or (with
        ``useful``, the cameras that can gain) one that none of them sees from its estimated pose
        even with no image margin, could never be chosen and is dropped unsolved. With
        ``prescore`` (T_base_board (M, 4, 4) -> expected gain (M,)) ``oversample`` x ``n_new``
        poses are drawn and only the ``n_new`` of highest expected gain go to the IK: the model
        costs far less than the IK, so the IK is spent where the information is."""
        names = [n for n in beliefs if weights.get(n, 0) > 0] or list(beliefs)
        if not names:
            return 0
        w = np.array([max(float(weights.get(n, 0.0)), 1e-6) for n in names])
        w /= w.sum()
        eyes = {n: beliefs[n].T_base_cam[:3, 3] for n in beliefs}
        az = {n: float(np.arctan2(e[1], e[0])) for n, e in eyes.items()}
        samples = []  # (T_base_board, IK seeds, aimed): all drawn first, in the sampler's fixed order
        for _ in range(n_new * (max(int(oversample), 1) if prescore is not None else 1)):
            cam = names[self.rng.choice(len(names), p=w)]
            others = [o for o in beliefs if o != cam and abs(np.angle(np.exp(1j * (az[o] - az[cam])))) < np.radians(120)]
            if others and self.rng.uniform() < 0.33:
                o = others[self.rng.integers(len(others))]
                a = float(np.angle(np.exp(1j * az[cam]) + np.exp(1j * az[o])))
                aimed, tilt = (cam, o), self.tilt * self.rng.uniform(0, 0.4)
            else:
                a, aimed, tilt = az[cam], (cam,), self.tilt * self.rng.uniform(0.2, 1.0)
            if self.rng.uniform() < 0.5:  # anywhere round the base: across and along the camera's line of sight
                a = self.rng.uniform(-np.pi, np.pi)
            else:  # on the camera's side
                a += self.rng.uniform(-1, 1) * np.radians(75)
            r = self.rng.uniform(*self.radius_m)
            centre = np.array([r * np.cos(a), r * np.sin(a), self.rng.uniform(*self.height_m)])
            # face the camera, or the bisector of the directions to the two (equal angles to both)
            eye = centre + sum((eyes[n] - centre) / max(np.linalg.norm(eyes[n] - centre), 1e-9) for n in aimed)
            t_axis = self.rng.uniform(0, 2 * np.pi)
            T_bb = board_pose_facing(eye, centre, self.cell.target, tilt * np.array([np.cos(t_axis), np.sin(t_axis), 0]),
                                     self.roll * self.rng.uniform(-1, 1))
            lo, hi = self.world.q_lo[0] + 0.1, self.world.q_hi[0] - 0.1
            near = q_now is not None and abs(np.angle(np.exp(1j * (q_now[0] - a)))) < 0.6
            samples.append((T_bb, seeds_at(float(np.clip(a, lo, hi)), q_now if near else None, 2, self.rng), aimed))
        if not samples:
            return 0
        keep = np.ones(len(samples), bool)
        if useful:
            T_all = np.array([t for t, _, _ in samples])
            seen = np.zeros(len(samples), bool)
            for n in useful:
                b = beliefs[n]
                seen |= boards_visible(b.intrinsics, b.T_base_cam, self.cell.target, T_all, margin_px=0.0)
            keep &= seen
        T_fb_inv = inv(T_flange_board)
        for i, (T_bb, _, _) in enumerate(samples):
            if keep[i] and keepout_violation(self._probe(T_bb @ T_fb_inv, T_flange_board), beliefs, self.cell.floor_z_m):
                keep[i] = False
        if prescore is not None and keep.sum() > n_new:
            idx = np.flatnonzero(keep)
            g = prescore(np.array([samples[i][0] for i in idx]))
            keep[:] = False
            keep[idx[np.argsort(-g, kind="stable")[:n_new]]] = True
        self.pruned += int(np.sum(~keep))
        q_saved = self.world.q()
        added = 0
        try:
            for (T_bb, seeds, aimed), k in zip(samples, keep):
                if not k:
                    continue
                self.ik_tries += 1
                got = reach_pose(self.world, T_bb, T_flange_board, seeds)
                if got is None:
                    continue
                q, T_bf = got
                probe = self._probe(T_bf, T_flange_board)
                if keepout_violation(probe, beliefs, self.cell.floor_z_m):
                    continue
                self.pool.append(Candidate(q, T_bf, aimed, probe))
                added += 1
        finally:
            self.world.set_q(q_saved)
        return added

    # -- scoring ---------------------------------------------------------------------------------------
    def predict(self, cand: Candidate, beliefs: dict, T_flange_board, pixel_sigma_px: float, occlusion: bool = True):
        """camera -> Fisher information (6x6) of the view ``cand`` would give, for every camera that
        sees the whole board from its estimated pose. Leaves the world at the candidate."""
        T_bb = cand.T_base_flange @ T_flange_board
        out = {}
        if occlusion:
            self.world.set_q(cand.q_rad)
        for n, b in beliefs.items():
            d = float(np.linalg.norm(T_bb[:3, 3] - b.T_base_cam[:3, 3]))
            if not board_visible(b.intrinsics, b.T_base_cam, self.cell.target, T_bb, margin_px=_pixel_margin(b, d),
                                 occluded=self.world.occluded if occlusion else None):
                continue
            out[n] = view_information(b.intrinsics, b.T_base_cam, T_bb, self._points_b, pixel_sigma_px,
                                      T_flange_board, *self.fk_sigmas)
        return out

    def graph_information(self, scored: dict, history, T_flange_board, pixel_sigma_px):
        """The linearised graph of the captures so far: (names, [(intrinsics, T_base_cam)], information
        (P, P)) over the ``scored`` cameras, the mount and the board scale (see :func:`joint_information`),
        with the solver's weak priors (1 rad / 10 m on cameras and mount) and the board-scale prior."""
        names = list(scored)
        cams = [(scored[n].intrinsics, scored[n].T_base_cam) for n in names]
        K = len(names)
        P = 6 * K + 7
        J = np.diag(np.r_[np.tile([1.0] * 3 + [0.01] * 3, K + 1), 1.0 / BOARD_SCALE_SIGMA ** 2])
        hist = [(np.asarray(T, float), tuple(c)) for T, c in (history or ()) if any(n in c for n in names)]
        if hist:
            seen = np.array([[n in c for n in names] for _, c in hist])
            J = J + joint_information(cams, seen, np.array([T for T, _ in hist]), T_flange_board, self._points_b,
                                      pixel_sigma_px, *self.fk_sigmas).sum(axis=0)
        assert J.shape == (P, P)
        return names, cams, J

    def _predictor(self, scored: dict, rho: dict, short: dict, T_flange_board, pixel_sigma_px, tol_mm, tol_deg,
                   history=None):
        """(names, visible(T_base_board (M, 4, 4)) -> (M, K), predict(visible (M, K), T_base_flange (M, 4, 4)) ->
        (gain (M,), predicted 1-sigma (M, K, 2))) for the ``scored`` cameras.

        The prediction is the joint model's ratio (:meth:`_model`, the candidate's information added)
        applied to each camera's reference 1-sigma (the batch solve's): the model leaves out the
        intrinsics and the robust weights, the ratio carries what it does capture (shared flange,
        mount, board scale). gain = sum over the cameras short of tolerance of
        max(rho, 1)^2 - max(rho', 1)^2."""
        names, cams, J0 = self.graph_information(scored, history, T_flange_board, pixel_sigma_px)
        K = len(names)
        sig0 = _block_sigmas(np.linalg.inv(J0), K)  # (K, 2) model 1-sigma now
        ref = np.array([sigma_norms(scored[n].covariance) for n in names])  # (K, 2) reference 1-sigma now
        rho_now = np.array([max(rho[n], 1.0) for n in names])
        is_short = np.array([n in short for n in names])

        def visible(T_bb):
            vis = np.zeros((len(T_bb), K), bool)
            for k, n in enumerate(names):
                b = scored[n]
                d = np.linalg.norm(T_bb[:, :3, 3] - b.T_base_cam[:3, 3], axis=1)
                vis[:, k] = boards_visible(b.intrinsics, b.T_base_cam, self.cell.target, T_bb,
                                           margin_px=_pixel_margin(b, d))
            return vis

        def predict(rows, T_bf):
            rows = np.asarray(rows, bool).reshape(-1, K)
            gain, sig = np.zeros(len(rows)), np.full((len(rows), K, 2), np.nan)
            m = rows.any(axis=1)
            if m.any():
                I = joint_information(cams, rows[m], T_bf[m], T_flange_board, self._points_b, pixel_sigma_px,
                                      *self.fk_sigmas)
                sig[m] = ref * _block_sigmas(np.linalg.inv(J0 + I), K) / np.maximum(sig0, 1e-12)
                rho_new = np.maximum(np.maximum(sig[m][..., 0] / tol_mm, sig[m][..., 1] / tol_deg), 1.0)
                gain[m] = np.sum(np.where(is_short, rho_now ** 2 - rho_new ** 2, 0.0), axis=-1)
            return gain, sig

        return names, visible, predict

    def _score_pool(self, predictor, T_flange_board):
        """Every pool candidate at once, geometry only: (visible (M, K), gain (M,), predicted 1-sigma (M, K, 2))."""
        _, visible, predict = predictor
        T_bf = np.array([c.T_base_flange for c in self.pool])
        vis = visible(T_bf @ T_flange_board)
        gain, sig = predict(vis, T_bf)
        return vis, gain, sig

    def choose(self, beliefs: dict, T_flange_board, pixel_sigma_px: float, tol_mm: float, tol_deg: float, q_now,
               n_top_up: int = 20, max_step_rad: float = 0.03, max_pool: int = 160, history=None) -> Choice | None:
        """The best candidate (highest gain per second) with a collision-free motion from ``q_now``,
        or None when no candidate shows the board to a camera short of tolerance. Only cameras
        with a covariance are scored; ``beliefs`` without one still shape the keep-outs.

        Scoring runs without the occlusion test (pure geometry, vectorised over the pool); the
        best dozen are then checked for occlusion by the arm (ray casts at the candidate's
        configuration) and re-scored with the cameras it hides removed, and for a free motion
        from ``q_now``."""
        scored = {n: b for n, b in beliefs.items() if b.covariance is not None}
        rho = {n: shortfall(b.covariance, tol_mm, tol_deg) for n, b in scored.items()}
        short = {n: r for n, r in rho.items() if r > 1.0}
        if not short:
            return None
        predictor = self._predictor(scored, rho, short, T_flange_board, pixel_sigma_px, tol_mm, tol_deg, history)
        names, visible, predict = predictor
        T_fb_inv = inv(T_flange_board)

        def prescore(T_bb):
            return predict(visible(T_bb), T_bb @ T_fb_inv)[0]

        self.top_up(beliefs, {n: r ** 2 for n, r in short.items()}, n_top_up, q_now, T_flange_board, useful=set(short),
                    prescore=prescore, oversample=self.oversample)
        # drop candidates that an updated keep-out now forbids
        self.pool = [c for c in self.pool if not keepout_violation(c.probe_m, beliefs, self.cell.floor_z_m)]
        if not self.pool:
            return None
        centre_b = self._points_b.mean(axis=0)
        vis, gain, sig = self._score_pool(predictor, T_flange_board)
        Q = np.array([c.q_rad for c in self.pool])
        t = np.max(np.abs(Q - np.asarray(q_now, float)) / (self.dq_max * self.speed_scale), axis=1) + SETTLE_S
        t = t + CAPTURE_S
        for c, g in zip(self.pool, gain):
            c.last_gain = float(g)
        index = {id(c): i for i, c in enumerate(self.pool)}
        ranked = [(float(g / tt), c) for c, g, tt in zip(self.pool, gain, t) if g > 1e-9]
        if len(self.pool) > max_pool:  # keep the pool (and the scoring time) bounded: forget the least useful
            keep = set(np.argsort([-c.last_gain for c in self.pool], kind="stable")[:max_pool].tolist())
            self.pool = [c for i, c in enumerate(self.pool) if i in keep]
        ranked.sort(key=lambda r: -r[0])
        q_saved = self.world.q()
        try:
            rescored = []
            for _, cand in ranked[:12]:  # occlusion by the arm: drop the cameras whose rays it blocks
                i = index[id(cand)]
                self.world.set_q(cand.q_rad)
                T_bb = cand.T_base_flange @ T_flange_board
                probes = occlusion_probes(self.cell.target, T_bb)
                row = np.array([bool(vis[i, k]) and not self.world.occluded(scored[n].T_base_cam[:3, 3], probes)
                                for k, n in enumerate(names)])
                sees = tuple(sorted(n for k, n in enumerate(names) if row[k]))
                if np.array_equal(row, vis[i]):
                    g, s_ = float(gain[i]), sig[i]
                else:
                    g1, s1 = predict(row[None], cand.T_base_flange[None])
                    g, s_ = float(g1[0]), s1[0]
                if g > 1e-9:
                    pred = {n: (float(s_[k, 0]), float(s_[k, 1])) for k, n in enumerate(names)}
                    rescored.append((g / t[i], g, cand, sees, pred))
            rescored.sort(key=lambda r: -r[0])
            for rate, g, cand, sees, pred in rescored:
                motion = free_motion(self.world, q_now, cand.q_rad, max_step_rad)
                if cand in self.pool:
                    self.pool.remove(cand)
                if motion is None:
                    continue
                T, q = 0.0, np.asarray(q_now, float)
                for qq in motion:
                    T += motion_time_s(q, qq, self.dq_max, self.speed_scale)
                    q = qq
                worst = max(short, key=short.get)
                top = tuple({"board_centre_m": _centre(c, T_flange_board, centre_b), "score": _sig3(r),
                             "gain": _sig3(c.last_gain)} for r, c in ranked[: self.n_logged])
                why = (f"best of {len(ranked)} candidates that help ({len(self.pool) + 1} in the pool): seen by "
                       f"{', '.join(sees)}; worst camera {worst} at {short[worst]:.2f}x tolerance; gain {g:.3g} "
                       f"in {T:.1f} s" + (f" ({len(motion) - 1} via poses)" if len(motion) > 1 else ""))
                idx = next((i for i, (_, c) in enumerate(ranked[: self.n_logged]) if c is cand), -1)
                return Choice(cand, motion, T, g, sees, pred, why, top, tuple(_centre(cand, T_flange_board, centre_b)),
                              idx)
        finally:
            self.world.set_q(q_saved)
        return None


def _centre(cand: Candidate, T_flange_board, centre_b) -> list:
    """Board centre (base frame, m, rounded to 0.1 mm) of a candidate."""
    T = cand.T_base_flange @ T_flange_board
    return [round(float(v), 4) for v in T[:3, :3] @ centre_b + T[:3, 3]]


def _sig3(x: float) -> float:
    return float(f"{float(x):.4g}")


def explain_shortfall(name: str, belief: CameraBelief, views: list, target, tol_mm: float, tol_deg: float) -> str:
    """Why camera ``name`` is short of tolerance and what would help, from its estimate and the
    board poses it saw (``views``: list of T_base_board)."""
    if belief is None or belief.covariance is None:
        return f"{name}: no pose estimate (fewer than 3 consistent views); show it the board from several tilts"
    t, r = sigma_norms(belief.covariance)
    parts = [f"{name}: 1σ {t:.2f} mm / {r:.3f}° against {tol_mm:g} mm / {tol_deg:g}° after {len(views)} views"]
    if not views:
        return parts[0]
    dists = [float(np.linalg.norm(T[:3, 3] - belief.T_base_cam[:3, 3])) for T in views]
    sq = []
    for T in views:
        T_cb = inv(belief.T_base_cam) @ T
        p = target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3]
        sq.append(square_px(belief.intrinsics.project(p), target))
    normals = np.array([inv(belief.T_base_cam)[:3, :3] @ T[:3, 2] for T in views])
    spread = float(np.degrees(np.arccos(np.clip(np.min(normals @ normals.mean(axis=0) / np.linalg.norm(normals.mean(axis=0))),
                                                -1, 1)))) if len(views) > 1 else 0.0
    reasons, helps = [], []
    if np.median(dists) > 2.5:
        reasons.append(f"far ({np.median(dists):.1f} m)")
        helps.append("move it closer or use a larger board")
    if np.median(sq) < 12:
        reasons.append(f"board small in its image (squares {np.median(sq):.0f} px)")
        helps.append("a larger board, or a lens with a longer focal length")
    if spread < 20:
        reasons.append(f"few viewing angles (board tilts within {spread:.0f}°)")
        helps.append("reachable poses that tilt the board more towards it (it may sit outside the arm's good reach)")
    if len(views) < 8:
        reasons.append(f"only {len(views)} views")
        helps.append("a larger --max-poses budget")
    if not reasons:
        reasons.append("the budget ran out")
        helps.append("a larger --max-poses budget")
    return f"{parts[0]}: {', '.join(reasons)}; would help: {'; '.join(dict.fromkeys(helps))}"
