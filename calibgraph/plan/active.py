"""Active refinement: the next robot pose by expected information gain per second of motion.

After the survey every camera that saw the board has a pose ``T_base_cam`` and a 6x6 marginal
covariance (rotation first, base axes: the left rotation vector and the camera-centre offset):
the batch solve of every capture so far (:mod:`calibgraph.acquire.auto`), marginal over the mount,
the board scale, the FK and every camera model, the numbers the stop rule and ``result.json`` use.
A candidate flange pose is scored on the *linearised calibration graph*
(:mod:`calibgraph.plan.information`): the parameters are every placed camera, the board mount, the
board scale and the camera model [fx, fy, cx, cy, k1, k2] of every camera whose intrinsics the
solver estimates, under the prior of their source (factory values: focal length to 2 %); each
capture's flange is marginalised under the FK prior, so the cameras that see one capture share it:

    Sigma = (priors + sum over the captures so far of I_k)^-1,  Sigma' = (Sigma^-1 + I_candidate)^-1

This is the solver's graph at the current estimate (``tests/test_auto.py`` checks it against
:func:`calibgraph.solver.uncertainty.covariance.crlb` with exact, factory and calibrated intrinsics); what it
leaves out (robust weights, the corner-noise modes) is carried by applying its *ratio* to the batch
1-sigma: predicted sigma_c = batch sigma_c x model sigma'_c / model sigma_c. With the camera models
among the parameters, a camera whose model is weak gains most from the views that pin it: the board
near and far along its line of sight and tilted (its focal length against its depth, which with
factory intrinsics makes most of a far camera's 1-sigma), towards the edges of its image
(principal point and distortion against its rotation), and views it shares with a camera that
pins the capture's flange better than the robot's FK does.

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
used once. A camera whose 1-sigma the captures left cannot bring within tolerance, even with the
pool's candidates weighted at will (:meth:`ActivePlanner.reach`), is given up by the loop and said
so early. Choosing costs well under a second on two cores (``scripts/bench_choose.py``): the
whole pool is scored in one vectorised pass (:func:`~calibgraph.plan.visibility.boards_visible`,
:func:`joint_information` on a stack of poses), ray casts and path checks only for the best dozen.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibgraph.core.transforms import inv
from calibgraph.plan.information import (
    block_sigmas,
    block_sigmas_added,
    design_bound,
    inv_scaled,
    joint_information,
    prior_information,
    shortfall,
    sigma_norms,
    view_information,
)
from calibgraph.plan.planner import free_motion
from calibgraph.plan.survey import board_pose_facing, reach_pose, seeds_at
from calibgraph.plan.visibility import board_visible, boards_visible, occlusion_probes, square_px
from calibgraph.solver.camera.session_plan import SESSION_PIXEL_SIGMA_PX, predict_session_covariance

__all__ = ["CameraBelief", "Candidate", "Choice", "ActivePlanner", "view_information", "joint_information",
           "sigma_norms", "shortfall", "motion_time_s", "keepout_violation", "explain_shortfall"]

SETTLE_S = 0.5  # what every motion costs on top of the joint-space time (the simulated robot's model too)
STAND_RADIUS_M = 0.25  # keep-out radius round an estimated camera stand, before its uncertainty
# What a capture costs beyond its motion (grabbing every camera, detection, the solve): in the score's
# per-second denominator it keeps a short motion to a nearly useless pose from beating a longer one to
# a useful pose (bench cells, 6 runs: 59 captures at 2 s against 65 at 0 s; 59 at 6 s, with more robot time).
CAPTURE_S = 2.0
# Board poses drawn per IK tried (the best by expected gain go to the IK). 10 gave no fewer captures
# than 4 on the irregular cell (42 against 41 on average over seeds 0-5, with less spread), at more
# choose time.
OVERSAMPLE = 4
# Smallest board square (px) the planner counts on a camera detecting: calibgraph's detector (up-scaling,
# photometric board fit) finds 96 % of boards with 5 px squares at 0.01 px per corner
# (scripts/results/bench_detect_bias.md); a D455 sees the A4 board's 25 mm squares that small from 3 m.
MIN_SQUARE_PX = 5.0
SESSION_VIEWS = 25  # images of the close-range intrinsics session a camera out of reach is advised (Reach.with_session)
REACH_SAMPLE = 240  # board poses drawn per camera to bound what the captures left can give it (ActivePlanner.reach)


@dataclass(frozen=True)
class CameraBelief:
    """What the loop knows about a camera: intrinsics, estimated ``T_base_cam`` (4, 4) and its
    6x6 covariance (rotation first, base axes; None while only a single-view guess exists);
    ``intrinsics_prior``: the (6, 6) covariance of the prior the solver puts on its [fx, fy, cx,
    cy, k1, k2] (:func:`~calibgraph.plan.information.intrinsics_prior`), None when it holds them
    known: the planner's model then leaves the camera model out."""

    name: str
    intrinsics: object
    T_base_cam: np.ndarray
    covariance: np.ndarray | None = None
    views: int = 0
    intrinsics_prior: np.ndarray | None = field(default=None, repr=False)


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


@dataclass(frozen=True)
class Reach:
    """How far ``budget`` more captures could take a camera (:meth:`ActivePlanner.reach`).

    Attributes:
        camera: its name.
        budget: the captures counted.
        candidates: pool candidates that show it the board.
        lower: (mm, deg) no ``budget`` captures from the pool give a smaller 1-sigma (0: not bounded).
        design: (mm, deg) the 1-sigma of the best weights found (an estimate of what planning reaches).
        with_session: (mm, deg) the same design's 1-sigma after a close-range intrinsics session of
            ``SESSION_VIEWS`` images (its predicted covariance of [fx, fy, cx, cy, k1, k2] added to the
            camera's prior); given only for a camera out of reach whose model the solver estimates.
    """

    camera: str
    budget: int
    candidates: int
    lower: tuple
    design: tuple
    with_session: tuple = ()

    def out_of_reach(self, tol_mm: float, tol_deg: float) -> bool:
        return self.lower[0] > tol_mm or self.lower[1] > tol_deg


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
        self.reach_rng = np.random.default_rng([seed, 1])  # its own stream: bounding never changes the choices
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
        samples = []  # (T_base_board, IK seeds, aimed): all drawn first, in the sampler's fixed order
        lo, hi = self.world.q_lo[0] + 0.1, self.world.q_hi[0] - 0.1
        T_all, a_all, aimed_all = self._draw(beliefs, names, w, self.rng,
                                             n_new * (max(int(oversample), 1) if prescore is not None else 1))
        for T_bb, a, aimed in zip(T_all, a_all, aimed_all):
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
                seen |= boards_visible(b.intrinsics, b.T_base_cam, self.cell.target, T_all, margin_px=0.0,
                                       min_square_px=MIN_SQUARE_PX)
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

    def _draw(self, beliefs: dict, names: list, w: np.ndarray, rng, n: int):
        """``n`` board poses aimed at cameras of ``names`` (drawn with probabilities ``w``), a third of
        them at the bisector of the camera and a neighbour within 120 deg: (T_base_board (n, 4, 4),
        azimuth of each centre (n,), cameras each is aimed at)."""
        all_names = list(beliefs)
        eyes = np.array([beliefs[x].T_base_cam[:3, 3] for x in all_names])
        az = np.arctan2(eyes[:, 1], eyes[:, 0])
        cam = np.array([all_names.index(x) for x in names])[rng.choice(len(names), p=w, size=n)]
        pair = rng.uniform(size=n) < 0.33
        other = np.full(n, -1)
        for c in np.unique(cam):
            near = [o for o in range(len(all_names)) if o != c and abs(np.angle(np.exp(1j * (az[o] - az[c])))) < np.radians(120)]
            sel = np.flatnonzero((cam == c) & pair)
            if near and len(sel):
                other[sel] = np.array(near)[rng.integers(len(near), size=len(sel))]
        pair = other >= 0
        a = np.where(pair, np.angle(np.exp(1j * az[cam]) + np.exp(1j * az[np.maximum(other, 0)])), az[cam])
        tilt = self.tilt * np.where(pair, rng.uniform(0, 0.4, n), rng.uniform(0.2, 1.0, n))
        anywhere = rng.uniform(size=n) < 0.5  # anywhere round the base: across and along the camera's line of sight
        a = np.where(anywhere, rng.uniform(-np.pi, np.pi, n), a + rng.uniform(-1, 1, n) * np.radians(75))
        r = rng.uniform(*self.radius_m, n)
        centre = np.column_stack([r * np.cos(a), r * np.sin(a), rng.uniform(*self.height_m, n)])
        # face the camera, or the bisector of the directions to the two (equal angles to both)
        to_eye = eyes[cam] - centre
        to_eye /= np.maximum(np.linalg.norm(to_eye, axis=1, keepdims=True), 1e-9)
        to_other = eyes[np.maximum(other, 0)] - centre
        to_other /= np.maximum(np.linalg.norm(to_other, axis=1, keepdims=True), 1e-9)
        facing = to_eye + np.where(pair[:, None], to_other, 0.0)
        t_axis = rng.uniform(0, 2 * np.pi, n)
        tilt_vec = tilt[:, None] * np.column_stack([np.cos(t_axis), np.sin(t_axis), np.zeros(n)])
        roll = self.roll * rng.uniform(-1, 1, n)
        T_bb = boards_facing(facing, centre, tilt_vec, roll, self._points_b.mean(axis=0))
        aimed = [(all_names[c],) if o < 0 else (all_names[c], all_names[o]) for c, o in zip(cam, other)]
        return T_bb, a, aimed

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
                                 min_square_px=MIN_SQUARE_PX,
                                 occluded=self.world.occluded if occlusion else None):
                continue
            out[n] = view_information(b.intrinsics, b.T_base_cam, T_bb, self._points_b, pixel_sigma_px,
                                      T_flange_board, *self.fk_sigmas)
        return out

    @staticmethod
    def free_intrinsics(scored: dict, names) -> list:
        """Which of the cameras ``names`` have their camera model among the model's parameters."""
        return [scored[n].intrinsics_prior is not None for n in names]

    def graph_information(self, scored: dict, history, T_flange_board, pixel_sigma_px):
        """The linearised graph of the captures so far: (names, [(intrinsics, T_base_cam)], information
        (P, P)) over the ``scored`` cameras, the mount, the board scale and the camera models the
        solver estimates (see :func:`joint_information`; :meth:`free_intrinsics`), with the solver's
        weak priors (1 rad / 10 m on cameras and mount), the board-scale prior and each camera
        model's prior."""
        names = list(scored)
        cams = [(scored[n].intrinsics, scored[n].T_base_cam) for n in names]
        free = self.free_intrinsics(scored, names)
        K = len(names)
        J = prior_information(K, [scored[n].intrinsics_prior for n, f in zip(names, free) if f])
        hist = [(np.asarray(T, float), tuple(c)) for T, c in (history or ()) if any(n in c for n in names)]
        if hist:
            seen = np.array([[n in c for n in names] for _, c in hist])
            J = J + joint_information(cams, seen, np.array([T for T, _ in hist]), T_flange_board, self._points_b,
                                      pixel_sigma_px, *self.fk_sigmas, free_intrinsics=free).sum(axis=0)
        return names, cams, J

    def _predictor(self, scored: dict, rho: dict, short: dict, T_flange_board, pixel_sigma_px, tol_mm, tol_deg,
                   history=None):
        """(names, visible(T_base_board (M, 4, 4)) -> (M, K), predict(visible (M, K), T_base_flange (M, 4, 4)) ->
        (gain (M,), predicted 1-sigma (M, K, 2))) for the ``scored`` cameras.

        The prediction is the joint model's ratio (:meth:`graph_information`, the candidate's
        information added) applied to each camera's reference 1-sigma (the batch solve's): the model
        leaves out the robust weights and the corner-noise modes, the ratio carries what it does
        capture (shared flange, mount, board scale, camera models). gain = sum over the cameras short
        of tolerance of max(rho, 1)^2 - max(rho', 1)^2."""
        names, cams, J0 = self.graph_information(scored, history, T_flange_board, pixel_sigma_px)
        free = self.free_intrinsics(scored, names)
        K = len(names)
        cov0 = inv_scaled(J0)
        sig0 = block_sigmas(cov0, K)  # (K, 2) model 1-sigma now
        ref = np.array([sigma_norms(scored[n].covariance) for n in names])  # (K, 2) reference 1-sigma now
        rho_now = np.array([max(rho[n], 1.0) for n in names])
        is_short = np.array([n in short for n in names])
        visible = self._visibility(scored, names)

        def predict(rows, T_bf):
            rows = np.asarray(rows, bool).reshape(-1, K)
            gain, sig = np.zeros(len(rows)), np.full((len(rows), K, 2), np.nan)
            m = rows.any(axis=1)
            if m.any():
                I = joint_information(cams, rows[m], T_bf[m], T_flange_board, self._points_b, pixel_sigma_px,
                                      *self.fk_sigmas, free_intrinsics=free)
                # each candidate's covariance from today's (Woodbury on the columns it informs)
                sig[m] = ref * block_sigmas_added(J0, I, K, cov0) / np.maximum(sig0, 1e-12)
                rho_new = np.maximum(np.maximum(sig[m][..., 0] / tol_mm, sig[m][..., 1] / tol_deg), 1.0)
                gain[m] = np.sum(np.where(is_short, rho_now ** 2 - rho_new ** 2, 0.0), axis=-1)
            return gain, sig

        return names, visible, predict

    def _visibility(self, scored: dict, names: list):
        """visible(T_base_board (M, 4, 4)) -> (M, K): which of the cameras ``names`` see the whole
        board from their estimated poses (image margin grown by their uncertainty; no occlusion test)."""

        def visible(T_bb):
            vis = np.zeros((len(T_bb), len(names)), bool)
            for k, n in enumerate(names):
                b = scored[n]
                d = np.linalg.norm(T_bb[:, :3, 3] - b.T_base_cam[:3, 3], axis=1)
                vis[:, k] = boards_visible(b.intrinsics, b.T_base_cam, self.cell.target, T_bb,
                                           margin_px=_pixel_margin(b, d), min_square_px=MIN_SQUARE_PX)
            return vis

        return visible

    def reach(self, beliefs: dict, T_flange_board, pixel_sigma_px: float, budget: int, names, history=None,
              tol_mm: float = np.inf, tol_deg: float = np.inf, n_sample: int = REACH_SAMPLE) -> dict:
        """camera -> :class:`Reach`: how far ``budget`` more captures could take each camera of
        ``names`` (see :func:`~calibgraph.plan.information.design_bound`).

        The candidates are ``n_sample`` board poses drawn as the pool's are but aimed at the camera
        alone, with the pool's candidates: those the camera sees whole from its estimate. The bound
        is optimistic on purpose, so that a camera said to be out of reach is: no IK or keep-out
        test and no occlusion (a drawn pose need not be reachable), the convex relaxation's weights
        (any non-negative weights summing to ``budget``, repeats allowed, every capture spent on this
        camera), and the other cameras' poses and models held known in the new captures (their views
        of a capture then pin its flange, the mount and the scale for free); what the captures so
        far tell is the camera's marginal (the others marginalised, not held), so that a budget of
        none gives today's 1-sigma. The model's 1-sigma is scaled to the
        batch solve's as in the choice. Only the norms short of ``tol_mm`` / ``tol_deg`` are bounded
        (the other is given as 0)."""
        scored = {n: b for n, b in beliefs.items() if b.covariance is not None}
        all_names, cams, J0 = self.graph_information(scored, history, T_flange_board, pixel_sigma_px)
        free = self.free_intrinsics(scored, all_names)
        K, P0 = len(all_names), 6 * len(all_names) + 7
        ratio = (np.array([sigma_norms(scored[n].covariance) for n in all_names])
                 / np.maximum(block_sigmas(inv_scaled(J0), K), 1e-12))
        visible = self._visibility(scored, all_names)
        T_fb_inv = inv(T_flange_board)
        model_cols, j = {}, 0
        for k, f in enumerate(free):
            if f:
                model_cols[k] = np.arange(P0 + 6 * j, P0 + 6 * j + 6)
                j += 1
        out = {}
        for n in names:
            if n not in scored:
                continue
            k = all_names.index(n)
            T_bb = self._draw(scored, [n], np.ones(1), self.reach_rng, n_sample)[0]
            T_bb = np.concatenate([T_bb, np.array([c.T_base_flange for c in self.pool]).reshape(-1, 4, 4) @ T_flange_board])
            T_bb = T_bb[self._visibility(scored, [n])(T_bb)[:, 0]]  # this camera's first: the others see a few
            vis, T_bf = visible(T_bb), T_bb @ T_fb_inv
            own = np.r_[6 * k:6 * k + 6, 6 * K:6 * K + 7, model_cols.get(k, np.zeros(0, int))]
            infos = joint_information(cams, vis, T_bf, T_flange_board, self._points_b, pixel_sigma_px, *self.fk_sigmas,
                                      free_intrinsics=free)[:, own][:, :, own] if len(T_bf) else np.zeros((0, 0, 0))
            # what the captures so far tell of its own columns: the others marginalised (Schur
            # complement), so that no captures give exactly today's 1-sigma
            oth = np.setdiff1d(np.arange(len(J0)), own)
            Jk = J0[np.ix_(own, own)] - J0[np.ix_(own, oth)] @ inv_scaled(J0[np.ix_(oth, oth)]) @ J0[np.ix_(oth, own)]
            Jk = 0.5 * (Jk + Jk.T)
            t_now, r_now = sigma_norms(scored[n].covariance)
            lower, design = [0.0, 0.0], [t_now, r_now]
            for i, (rows, now, tol, unit) in enumerate((([3, 4, 5], t_now, tol_mm, 1e3),
                                                        ([0, 1, 2], r_now, tol_deg, np.degrees(1.0)))):
                if now > tol:
                    lb, v = design_bound(Jk, infos, budget if len(T_bf) else 0, rows)
                    lower[i], design[i] = (float(ratio[k, i] * unit * np.sqrt(x)) for x in (lb, v))
            session = ()
            if (lower[0] > tol_mm or lower[1] > tol_deg) and k in model_cols and len(T_bf):
                m = np.arange(len(own) - 6, len(own))  # the camera model's columns of ``own``
                Js = Jk.copy()
                # the session's corners as good as this camera's hand-eye ones, at most a hand-held session's
                Js[np.ix_(m, m)] += np.linalg.inv(predict_session_covariance(
                    scored[n].intrinsics, self.cell.target, SESSION_VIEWS,
                    pixel_sigma_px=min(float(pixel_sigma_px), SESSION_PIXEL_SIGMA_PX)))
                session = tuple(float(ratio[k, i] * unit * np.sqrt(design_bound(Js, infos, budget, rows)[1]))
                                for i, (rows, unit) in enumerate((([3, 4, 5], 1e3), ([0, 1, 2], np.degrees(1.0)))))
            out[n] = Reach(n, int(budget), int(len(T_bf)), tuple(lower), tuple(design), session)
        return out

    def _score_pool(self, predictor, T_flange_board):
        """Every pool candidate at once, geometry only: (visible (M, K), gain (M,), predicted 1-sigma (M, K, 2))."""
        _, visible, predict = predictor
        T_bf = np.array([c.T_base_flange for c in self.pool])
        vis = visible(T_bf @ T_flange_board)
        gain, sig = predict(vis, T_bf)
        return vis, gain, sig

    def choose(self, beliefs: dict, T_flange_board, pixel_sigma_px: float, tol_mm: float, tol_deg: float, q_now,
               n_top_up: int = 20, max_step_rad: float = 0.03, max_pool: int = 160, history=None,
               skip=()) -> Choice | None:
        """The best candidate (highest gain per second) with a collision-free motion from ``q_now``,
        or None when no candidate shows the board to a camera short of tolerance. Only cameras
        with a covariance are scored; ``beliefs`` without one still shape the keep-outs.

        Scoring runs without the occlusion test (pure geometry, vectorised over the pool); the
        best dozen are then checked for occlusion by the arm (ray casts at the candidate's
        configuration) and re-scored with the cameras it hides removed, and for a free motion
        from ``q_now``. Cameras in ``skip`` (out of reach) are not pursued."""
        scored = {n: b for n, b in beliefs.items() if b.covariance is not None}
        rho = {n: shortfall(b.covariance, tol_mm, tol_deg) for n, b in scored.items()}
        short = {n: r for n, r in rho.items() if r > 1.0 and n not in skip}
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


def boards_facing(facing: np.ndarray, centre_m: np.ndarray, tilt_rotvec: np.ndarray, roll_rad: np.ndarray,
                  pattern_centre_b: np.ndarray) -> np.ndarray:
    """(n, 4, 4) ``T_base_board`` of boards whose pattern centre is at ``centre_m`` (n, 3) and whose
    printed face (-z) looks along ``facing`` (n, 3), tilted and rolled as
    :func:`calibgraph.core.transforms.board_facing` does it, for many at once."""
    z = -facing / np.linalg.norm(facing, axis=1, keepdims=True)
    x = np.cross(z, [0.0, 0.0, 1.0])
    flat = np.linalg.norm(x, axis=1) < 1e-9
    x[flat] = np.cross(z[flat], [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(z, x)
    R = np.stack([x, y, z], axis=2) @ _exp_so3_rows(tilt_rotvec) @ _exp_so3_rows(np.outer(roll_rad, [0.0, 0.0, 1.0]))
    T = np.tile(np.eye(4), (len(R), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = centre_m - R @ pattern_centre_b
    return T


def _exp_so3_rows(w: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations of the rotation vectors ``w`` (n, 3) (Rodrigues)."""
    th = np.linalg.norm(w, axis=1)
    k = w / np.maximum(th, 1e-12)[:, None]
    K = np.zeros((len(w), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
    K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
    s, c = np.sin(th)[:, None, None], (1 - np.cos(th))[:, None, None]
    return np.eye(3) + s * K + c * (K @ K)
