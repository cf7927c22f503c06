"""Batch solver: robust initialisation -> IRLS Levenberg-Marquardt -> outlier rejection -> marginals.

The graph (keys in :mod:`calibgraph.solver.keys`; ``ref`` is the robot base in eye-to-hand and the
flange in eye-in-hand, ``mount`` the other one, the frame the board is fixed to)::

    C(c)  T_ref_cam of camera c         -- unknown, no prior
    B(0)  T_mount_board, the board mount -- unknown, no prior ('single': one graph per camera)
    F(k)  T_ref_mount of capture k      -- prior from forward kinematics (fk sigmas, :func:`fk_noise`)
    K(c)  [fx, fy, cx, cy, k1, k2]      -- unless intrinsics='fixed': prior around the given values,
                                           as wide as their source says (SolverOptions.intrinsics)
    S(0)  board scale factor s          -- unless board_scale=False: prior N(1, board_scale_sigma)
    O(0)  free joint zero offsets       -- only with kinematics='joint-offsets': F(k) then has a factor
                                           to O(0) through FK(q_k + o) instead of its fixed prior
                                           (:mod:`calibgraph.solver.kinematics`, always 'view')

and the detected corners, each a reprojection residual through
:func:`~calibgraph.solver.factors.project_chain`, in one of two formulations of the same model:

    'view'    one CustomFactor per view (C(c), F(k), B(0)[, K(c)]) with a residual pair per corner
              (:mod:`calibgraph.solver.factors`); any OpenCV distortion model;
    'corner'  one C++ projection factor per corner (:mod:`calibgraph.solver.factors_ppp`, which holds
              F(k) and B(0) in another parametrisation); Cal3DS2 distortion (k1 k2 p1 p2) only.

``SolverOptions.formulation`` chooses (:func:`_formulation`): 'view' or 'corner' as asked ('corner'
with a k3..k6 camera is refused), and 'auto' (the default) takes 'corner' when every camera of the
graph fits Cal3DS2 and the graph has at least CORNER_FORMULATION_MIN_VIEWS (1000) views with a PnP
solution, 'view' otherwise. A graph that estimates intrinsics or the board scale (the defaults) is
always 'view': the corner factors hold both fixed.
When the corner graph fails numerically under 'auto', that graph is solved again with 'view'.

Robustness is at corner level: iteratively re-weighted least squares with Huber (or Cauchy)
weights on each corner's residual norm, each LM run holding the weights fixed, so the cost LM
sees is consistent; corners beyond ``outlier_sigmas`` are rejected and listed, views that lose
most of their corners are rejected with a reason. Covariances are the marginals of the final
weighted graph (eliminated in the solver's ordering, :class:`_Marginals`) with the pixel sigma
estimated from the residuals (a posteriori variance factor) unless it is given.

Internal API. Besides :func:`solve` and :func:`crlb`, the steps of a solve are public names here for
the iSAM2 path (:mod:`calibgraph.solver.incremental`), ``scripts/bench_solver.py`` and the tests;
calibgraph does not re-export them, and they change with the solver:

    View, Estimate           a view in the graph (with its robust weights); the graph's variables
    prepare_views            the problem's detections as Views (too few corners: rejected)
    view_candidates          both IPPE poses of every view (the initialiser's input)
    best_initial_guess       the initialiser's hypotheses ranked by reprojection error
    solve_from_start         IRLS + outlier handling + marginals for one graph from a given start
    build_graph              factor graph and initial values of an Estimate
    levenberg_marquardt      one LM run on a graph
    fk_noise                 noise model of the forward-kinematics prior on F(k)
    to_ref_axes              GTSAM body-frame pose covariance -> reference-frame axes

``solve(problem, timings={})`` adds the wall time (s) spent in each of ``STAGES`` to the dict.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from calibgraph.core.errors import InputError, ObservabilityError
from calibgraph.core.problem import Problem, intrinsics_estimated, intrinsics_prior_sigmas, intrinsics_source
from calibgraph.core.transforms import inv, log_so3
from calibgraph.solver import factors_ppp
from calibgraph.solver import kinematics as kin
from calibgraph.solver.factors import (
    intrinsics_vector,
    make_calibration_factor,
    make_view_factor,
    project_chain,
    view_residual,
    with_pinhole,
)
from calibgraph.solver.initialise import (
    ViewCandidates,
    initialise,
    pnp_candidates,
    refine_translations,
)
from calibgraph.solver.keys import B, C, F, K, O, S
from calibgraph.solver.moved import solve_minding_moves
from calibgraph.solver.observability import check_after_solve, check_before_solve
from calibgraph.solver.result import CameraResult, PairResult, RejectedView, Result

MIN_CORNERS_PER_VIEW = 4
INTRINSICS_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2")
# what solve(..., timings=...) times: PnP candidates, the initialiser's consensus and its translation
# solve (inside best_initial_guess), graph building, LM runs, elimination for the marginals
STAGES = ("candidates", "initialise", "refine_translations", "build_graph", "lm", "marginals")


@dataclass
class View:
    """One camera's detections in one capture, as the solver uses them (mutable: the solve sets the
    robust weights and whether the view is active)."""

    camera: str
    capture: int
    ids: np.ndarray  # (N,) corner ids
    p_board_m: np.ndarray  # (N, 3) corners in the board frame
    uv_px: np.ndarray  # (N, 2) detected corners
    T_ref_mount: np.ndarray  # (4, 4) robot pose of the capture from forward kinematics (the prior)
    w: np.ndarray = None  # (N,) robust weights in [0, 1]; 0 = rejected corner
    active: bool = True
    reason: str = ""  # why the view is not active


@dataclass
class Estimate:
    """Values of the graph's variables; after :func:`solve_from_start` also the solve's outcome."""

    T_ref_cam: dict  # camera -> (4, 4)
    T_mount_board: np.ndarray  # (4, 4)
    T_ref_mount: dict  # capture -> (4, 4) estimated robot pose; a capture missing here starts at its FK pose
    iterations: int = 0
    cost: float = np.inf
    sigma_px: float = 1.0
    intrinsics: dict = field(default_factory=dict)  # camera -> estimated Intrinsics (unless intrinsics='fixed')
    board_scale: float = 1.0  # estimated scale of the printed board (1 when board_scale=False)
    wide_intrinsics: frozenset = frozenset()  # cameras whose intrinsics get the wide prior (found inadequate)
    slots: dict = field(default_factory=dict)  # camera -> index of its C (and K) key
    formulation: str = ""  # 'view' or 'corner'
    marginals: _Marginals | None = None  # of the final graph
    mount_cov_body: np.ndarray | None = None  # (6, 6) covariance of T_mount_board, GTSAM body frame
    joint_offsets: np.ndarray | None = None  # free joint offsets (rad) with kinematics='joint-offsets'
    # camera -> ModeRatio of the final graph (view_noise_modes); its ``applied`` weights the views
    mode_ratios: dict = field(default_factory=dict)
    fk_ratio: FkRatio | None = None  # the FK prior against the fit (fk_variance); ``applied`` widens it


@contextmanager
def _timed(timings: dict | None, stage: str):
    """Add the wall time of the block to ``timings[stage]`` (nothing when ``timings`` is None)."""
    if timings is None:
        yield
        return
    t0 = time.perf_counter()
    try:
        yield
    finally:
        timings[stage] = timings.get(stage, 0.0) + time.perf_counter() - t0


def _robot_prior_poses(problem: Problem) -> dict:
    """capture -> T_ref_mount as forward kinematics reports it (the prior of F(k))."""
    if problem.mode == "eye_to_hand":
        return {c.index: c.T_base_flange for c in problem.captures}
    return {c.index: inv(c.T_base_flange) for c in problem.captures}


def fk_noise(opts, mode: str = "eye_to_hand", T_ref_mount: np.ndarray | None = None):
    """Noise model of the forward-kinematics prior on F(k) = ``T_ref_mount``.

    The sigmas describe T_base_flange (perturbed at the flange); in eye-in-hand the variable is its
    inverse T_flange_base, whose right perturbation is -Ad(T_base_flange) xi, so the square-root
    information becomes diag(1/sigma) Ad(T_flange_base)."""
    s = np.array([opts.fk_sigma_rotation_rad] * 3 + [opts.fk_sigma_translation_m] * 3)
    if mode == "eye_to_hand" or T_ref_mount is None:
        return gtsam.noiseModel.Diagonal.Sigmas(s)
    return gtsam.noiseModel.Gaussian.SqrtInformation(np.diag(1.0 / s) @ gtsam.Pose3(T_ref_mount).AdjointMap(), False)


def _loss_weights(r_sigma: np.ndarray, loss: str, scale: float) -> np.ndarray:
    """IRLS weights for residual norms expressed in sigmas."""
    if loss == "none":
        return np.ones_like(r_sigma)
    if loss == "huber":
        return np.where(r_sigma <= scale, 1.0, scale / np.maximum(r_sigma, 1e-12))
    return 1.0 / (1.0 + (r_sigma / scale) ** 2)


def _all_residuals(views, est: Estimate, cameras: dict) -> list:
    """Residual norms (px) of every view, batched per camera: one projection call per camera
    instead of one per view (the per-view numpy overhead dominated large cells)."""
    out = [None] * len(views)
    by_cam = {}
    for i, v in enumerate(views):
        by_cam.setdefault(v.camera, []).append(i)
    for cam, idx in by_cam.items():
        T_cs = inv(est.T_ref_cam[cam])
        pts, uvs, counts = [], [], []
        for i in idx:
            v = views[i]
            T = T_cs @ est.T_ref_mount.get(v.capture, v.T_ref_mount) @ est.T_mount_board
            pts.append((est.board_scale * v.p_board_m) @ T[:3, :3].T + T[:3, 3])
            uvs.append(v.uv_px)
            counts.append(len(v.ids))
        uv_hat = est.intrinsics.get(cam, cameras[cam]).project(np.concatenate(pts))
        r = np.linalg.norm(uv_hat - np.concatenate(uvs), axis=1)
        r = np.where(np.isfinite(r), r, 1e6)
        for i, part in zip(idx, np.split(r, np.cumsum(counts)[:-1])):
            out[i] = part
    return out


# Views with fewer kept corners leave too few residuals beside the 6 modes to compare them with.
MODE_MIN_CORNERS = 6
N_MODES = 6
# One-sided test levels on log(ratio) (its sd is sqrt(2 / dof_modes + 2 / dof_rest)): the factor is
# applied above z = 1.645 (p < 0.05; below that, independent corners explain the residuals) and
# called significant above z = 3.09 (p < 0.001).
MODE_APPLY_Z = 1.645
MODE_NOTE_Z = 3.09


@dataclass(frozen=True)
class ModeRatio:
    """Low-order to remaining residual variance of one camera's views (see :func:`mode_variance_ratios`).

    ``ratio``: the estimate; ``applied``: what the final graph uses (the ratio when it is above 1 at
    the 0.05 level, else 1); ``dof_modes`` / ``dof_rest``: the residual counts behind it;
    ``significant``: above 1 at the 0.001 level.
    """

    ratio: float
    applied: float
    dof_modes: int
    dof_rest: int
    significant: bool
    energy_modes_px2: float = 0.0  # weighted squared residuals in the modes, summed over the views

    def to_dict(self) -> dict:
        return {"low_order_variance_ratio": self.ratio, "applied": self.applied, "dof_modes": self.dof_modes,
                "dof_rest": self.dof_rest, "significant": self.significant}


def view_mode_basis(uv_px: np.ndarray) -> np.ndarray:
    """(2n, 6) orthonormal basis of one view's low-order image modes at its corners ``uv_px`` (n, 2):
    a shift in u and v and the four linear maps about the corners' centroid (rotation, scale, the
    two shears), i.e. an affine change of the board's image; rows interleave u, v per corner as the
    view factor's residual does."""
    c = uv_px - uv_px.mean(axis=0)
    c = c / max(float(np.sqrt(np.mean(np.sum(c * c, axis=1)))), 1e-9)
    n = len(uv_px)
    A = np.zeros((2 * n, N_MODES))
    A[0::2, 0] = 1.0
    A[1::2, 1] = 1.0
    A[0::2, 2], A[0::2, 3] = c[:, 0], c[:, 1]
    A[1::2, 4], A[1::2, 5] = c[:, 0], c[:, 1]
    return np.linalg.qr(A)[0]


def _view_jacobians(problem: Problem, views, est: Estimate, sigma_px: float):
    """Whitened residuals and robot-pose Jacobians of the active views at ``est``:
    ([(view, kept-corner mask, e (2n,), H_F (2n, 6))], capture -> (FK prior information (6, 6),
    the views' information on F(k) (6, 6), the prior's square-root information R (6, 6)))."""
    out, info = [], {}
    for v in views:
        if not v.active:
            continue
        keep = v.w > 0
        if not keep.any():
            continue
        intr = est.intrinsics.get(v.camera, problem.cameras[v.camera])
        e, J = view_residual(est.T_ref_cam[v.camera], est.T_ref_mount.get(v.capture, v.T_ref_mount), est.T_mount_board,
                             est.board_scale * v.p_board_m[keep], v.uv_px[keep], intr, np.sqrt(v.w[keep]) / sigma_px)
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(J[1]))):
            continue
        H_f = J[1]
        if v.capture not in info:
            R = np.asarray(fk_noise(problem.options, problem.mode, v.T_ref_mount).R())
            info[v.capture] = (R.T @ R, np.zeros((6, 6)), R)
        prior, views_info, R = info[v.capture]
        info[v.capture] = (prior, views_info + H_f.T @ H_f, R)
        out.append((v, keep, e, H_f))
    return out, info


@dataclass(frozen=True)
class FkRatio:
    """How far the estimated robot poses sit from forward kinematics, against the stated FK sigmas
    (see :func:`fk_variance_ratio`): ``ratio`` ~1 when the statement holds; ``applied``: the
    factor on the FK prior's variance the final graph uses (the ratio when above 1 at the 0.05
    level, else 1); ``dof``: the prior residuals' redundancy; ``significant``: p < 0.001."""

    ratio: float
    applied: float
    dof: float
    significant: bool

    def to_dict(self, opts) -> dict:
        s = float(np.sqrt(self.applied))
        t, r = float(opts.fk_sigma_translation_m), float(opts.fk_sigma_rotation_rad)
        return {"variance_ratio": self.ratio, "applied": self.applied, "dof": self.dof, "significant": self.significant,
                "stated_sigma_translation_m": t, "stated_sigma_rotation_rad": r,
                "used_sigma_translation_m": t * s, "used_sigma_rotation_rad": r * s}


def fk_variance_ratio(problem: Problem, views, est: Estimate, sigma_px: float, linearised=None) -> FkRatio | None:
    """The robot's forward kinematics against its stated accuracy, from the fit (None when there
    is too little to tell, or with kinematics='joint-offsets', whose poses follow the joint angles).

    Each capture's estimated robot pose F(k) departs from its FK prior by ``d_k`` (whitened by the
    prior); under the stated FK sigmas ``sum |d_k|^2`` is about the prior's redundancy
    ``sum 6 - tr(Lambda_p Sigma_k)``, with ``Sigma_k = (Lambda_p + J_k)^-1`` the covariance of F(k)
    given the rest (J_k: the information of capture k's views). A robot less accurate than stated
    pulls the cameras without showing in the corners' scatter; the ratio says by how much.
    ``linearised``: :func:`_view_jacobians` of the same arguments, when already computed.
    """
    if problem.options.kinematics != "none":
        return None
    _, info = linearised or _view_jacobians(problem, views, est, sigma_px)
    prior_at = {v.capture: v.T_ref_mount for v in views}
    energy = red = 0.0
    for k, (prior, views_info, R) in info.items():
        T_est = est.T_ref_mount.get(k)
        if T_est is None:
            continue
        xi = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(prior_at[k]).between(gtsam.Pose3(T_est))))
        d = R @ xi
        energy += float(d @ d)
        red += 6.0 - float(np.trace(prior @ np.linalg.pinv(prior + views_info)))
    if red < 5.0 or energy <= 0:
        return None
    ratio = energy / red
    z = np.log(ratio) / np.sqrt(2.0 / red)
    return FkRatio(float(ratio), float(ratio) if z > MODE_APPLY_Z else 1.0, float(red), bool(z > MODE_NOTE_Z))


def mode_variance_ratios(problem: Problem, views, est: Estimate, sigma_px: float, linearised=None) -> dict:
    """Per camera: how much more the residuals vary in each view's low-order image modes than in
    the rest (camera -> :class:`ModeRatio`).

    Why: a corner's sub-pixel position is fitted to the pixels around it, and on small squares
    neighbouring corners share most of those pixels (and the blur, lighting and print between
    them), so their errors are positively correlated. The correlated part moves the whole board's
    image (a shift, rotation, scale or shear), exactly the modes a camera's pose is estimated from,
    while the point-to-point scatter, which sets the a posteriori pixel sigma, is smaller. Treating
    the corners as independent then makes a far camera's 1-sigma too small (rendered D455 at 5 m,
    thesis board, 6 px squares: the modes vary 1.5-2.5x, errors up to 3.9 sigma).

    Estimator (two variance components, Helmert's in its simplest form): the mean squared residual
    in the modes over their redundancy, divided by the same for the rest. The redundancy of a view
    is what the fit leaves of it: the view's robot pose F(k) is fitted to the views of capture k
    within its FK prior and absorbs much of the shift, so each view's share is ``tr(Q^T (I - M) Q)``
    with ``M = J_F Sigma_k J_F^T`` (J_F the view's whitened Jacobian on F(k), Sigma_k the covariance
    of F(k) given the rest of the graph); the camera pose, mount, scale and intrinsics are shared by
    many views and absorb a negligible share of each. ~1 with independent corners (F-distributed).
    ``linearised``: :func:`_view_jacobians` of the same arguments, when already computed.
    """
    jac, info = linearised or _view_jacobians(problem, views, est, sigma_px)
    per_view = [(v, e, H_f, view_mode_basis(v.uv_px[keep])) for v, keep, e, H_f in jac
                 if keep.sum() >= MODE_MIN_CORNERS]
    cov = {k: np.linalg.pinv(prior + views_info) for k, (prior, views_info, _) in info.items()}
    acc = {}
    for v, e, H_f, Q in per_view:
        M = H_f @ cov[v.capture] @ H_f.T
        qe = Q.T @ e
        low, total = float(qe @ qe), float(e @ e)
        t_low = float(np.trace(Q.T @ M @ Q))
        a = acc.setdefault(v.camera, np.zeros(5))
        a += [low, max(total - low, 0.0), N_MODES - t_low, len(e) - N_MODES - (float(np.trace(M)) - t_low),
              low * sigma_px ** 2]
    out = {}
    for cam, (low, rest, r_low, r_rest, low_px2) in acc.items():
        n_views = sum(1 for v, *_ in per_view if v.camera == cam)
        if n_views < 5 or rest <= 0 or r_low < 1.0 or r_rest < 1.0:
            continue  # fewer than 5 views: too little to estimate a variance factor from
        ratio = (low / r_low) / (rest / r_rest)
        z = np.log(max(ratio, 1e-12)) / np.sqrt(2.0 / r_low + 2.0 / r_rest)
        out[cam] = ModeRatio(float(ratio), float(ratio) if z > MODE_APPLY_Z else 1.0, int(round(r_low)),
                             int(round(r_rest)), bool(z > MODE_NOTE_Z), float(low_px2))
    return out


def _view_noise(uv_px: np.ndarray, factor: float):
    """Noise model of one view whose low-order modes have ``factor`` times the variance of the rest
    (unit otherwise): covariance I + (factor - 1) Q Q^T on the weighted residuals."""
    Q = view_mode_basis(uv_px)
    return gtsam.noiseModel.Gaussian.Covariance(np.eye(len(Q)) + (factor - 1.0) * (Q @ Q.T))


CORNER_FORMULATION_MIN_VIEWS = 1000


def _formulation(problem: Problem, names, n_views: int) -> str:
    """Which graph to build: 'view' (per-view CustomFactor) or 'corner' (C++ factor per corner)."""
    f = problem.options.formulation
    if problem.options.kinematics != "none":
        if f == "corner":
            raise InputError("solver: formulation 'corner' has no kinematic factors; use 'view' or 'auto' with "
                             "--estimate-kinematics.")
        return "view"
    if any(intrinsics_estimated(problem.cameras[n], problem.options) for n in names) or problem.options.board_scale:
        if f == "corner":
            raise InputError("solver: formulation 'corner' holds the intrinsics and the board's size fixed; with it, "
                             "set intrinsics='fixed' and board_scale=False (--fixed-intrinsics --fixed-board-scale).")
        return "view"  # the corner factors hold intrinsics and the board's size fixed
    fits = all(factors_ppp.supports(problem.cameras[n]) for n in names)
    if f == "corner" and not fits:
        raise InputError("solver: formulation 'corner' needs Cal3DS2 distortion (k1 k2 p1 p2 only); "
                         "use formulation 'view' for cameras with k3..k6.")
    if f == "auto":
        # Measured by scripts/bench_solver.py (16 cameras x 1000 poses, 6761 views): corner 42.6 s CPU,
        # view 62.2 s (LM alone 8.6 s vs 41 s); at 3 cameras x 110 poses the two are on par. The corner
        # graph is numerically touchier (see factors_ppp), so it is used where it pays off, with the
        # per-view graph as the fallback.
        return "corner" if fits and n_views >= CORNER_FORMULATION_MIN_VIEWS else "view"
    return f


def _check_cameras_keep_views(views, slots):
    """Every camera in the graph needs an active view; otherwise its variable would be unconstrained."""
    for name in slots:
        mine = [v for v in views if v.camera == name]
        if mine and not any(v.active for v in mine):
            reasons = sorted({v.reason for v in mine if v.reason})[:3]
            raise ObservabilityError(
                f"camera {name!r}: all {len(mine)} of its views were rejected as inconsistent with the rest "
                f"({'; '.join(reasons)}); check its intrinsics, that it saw the same target, and add views of it.",
                camera=name,
            )


def build_graph(views, slots, problem, est: Estimate, sigma_px: float, form: str = "view",
                mode_factors: dict | None = None):
    """(graph, initial values) of the active views' kept corners at the values of ``est``.

    ``slots``: camera -> index of its C (and K) key; ``sigma_px``: pixel sigma of a full-weight corner;
    ``form``: 'view' or 'corner' (see the module docstring); ``mode_factors``: camera -> variance
    factor of its views' low-order modes (:func:`mode_variance_ratios`; view form only).
    """
    _check_cameras_keep_views(views, slots)
    if form == "corner":
        o = problem.options
        fk = np.array([o.fk_sigma_rotation_rad] * 3 + [o.fk_sigma_translation_m] * 3)
        return factors_ppp.build(views, slots, problem, est, sigma_px, fk)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    used_caps = sorted({v.capture for v in views if v.active})
    T_ref_mount_fk = {v.capture: v.T_ref_mount for v in views}
    ks = kin.setup(problem)
    for k in used_caps:
        if ks is None:
            graph.add(gtsam.PriorFactorPose3(F(k), gtsam.Pose3(T_ref_mount_fk[k]),
                                             fk_noise(problem.options, problem.mode, T_ref_mount_fk[k])))
        else:
            graph.add(kin.make_kinematic_factor(F(k), O(0), ks.q_rad[k], ks, fk_noise(problem.options)))
        values.insert(F(k), gtsam.Pose3(est.T_ref_mount.get(k, T_ref_mount_fk[k])))
    if ks is not None:
        nf = len(ks.free)
        graph.add(gtsam.PriorFactorVector(O(0), np.zeros(nf),
                                          gtsam.noiseModel.Isotropic.Sigma(nf, problem.options.joint_offset_prior_rad)))
        values.insert(O(0), est.joint_offsets if est.joint_offsets is not None else np.zeros(nf))
    for name, i in slots.items():
        values.insert(C(i), gtsam.Pose3(est.T_ref_cam[name]))
    values.insert(B(0), gtsam.Pose3(est.T_mount_board))
    o = problem.options
    refine = {name for name in slots if intrinsics_estimated(problem.cameras[name], o)}
    if refine:
        for name, i in slots.items():
            if name not in refine:
                continue
            given = problem.cameras[name]
            sig = intrinsics_prior_sigmas(given, o, wide=name in est.wide_intrinsics)
            graph.add(gtsam.PriorFactorVector(K(i), intrinsics_vector(given), gtsam.noiseModel.Diagonal.Sigmas(sig)))
            values.insert(K(i), intrinsics_vector(est.intrinsics.get(name, given)))
    if o.board_scale:
        graph.add(gtsam.PriorFactorVector(S(0), np.array([1.0]), gtsam.noiseModel.Isotropic.Sigma(1, o.board_scale_sigma)))
        values.insert(S(0), np.array([est.board_scale]))
    for v in views:
        if not v.active:
            continue
        keep = v.w > 0
        sw = np.sqrt(v.w[keep]) / sigma_px
        f = (mode_factors or {}).get(v.camera, 1.0)
        noise = _view_noise(v.uv_px[keep], f) if f > 1.0 and keep.sum() >= MODE_MIN_CORNERS else None
        if refine or o.board_scale:
            graph.add(make_calibration_factor(C(slots[v.camera]), F(v.capture), B(0), v.p_board_m[keep],
                                              v.uv_px[keep], problem.cameras[v.camera], sw,
                                              key_intr=K(slots[v.camera]) if v.camera in refine else None,
                                              key_scale=S(0) if o.board_scale else None, noise=noise))
        else:
            graph.add(make_view_factor(C(slots[v.camera]), F(v.capture), B(0), v.p_board_m[keep], v.uv_px[keep],
                                       problem.cameras[v.camera], sw, noise=noise))
    return graph, values


def _ordering(values) -> gtsam.Ordering:
    """Robot poses first, then cameras and mounts: eliminating each F(k) only couples the few
    camera poses that saw capture k, so the reduced system stays small (COLAMD may otherwise pick
    an order that makes the thousands of robot poses a dense block)."""
    first, last = [], []
    for key in values.keys():
        (first if chr(gtsam.Symbol(key).chr()) == "f" else last).append(key)
    order = gtsam.Ordering()
    for key in first + last:
        order.push_back(key)
    return order


class _Marginals:
    """Marginal covariances from a Bayes tree eliminated with the solver's ordering.

    gtsam.Marginals picks its own (COLAMD) ordering, which fails on the corner graph when the FK
    priors are very tight; the ordering used by LM is well conditioned for both formulations.
    """

    def __init__(self, graph, values, ordering):
        self._bt = graph.linearize(values).eliminateMultifrontal(ordering)
        self._keys = set(values.keys())

    def marginalCovariance(self, key) -> np.ndarray:  # noqa: N802 - mirrors gtsam.Marginals
        return self._bt.marginalCovariance(key)

    def has(self, key) -> bool:
        """True when ``key`` is a variable of the eliminated graph."""
        return self._keys is None or key in self._keys

    def joint(self, keys) -> np.ndarray:
        """Joint covariance of the variables ``keys`` (Pose3: 6 rows/cols, vectors: their size), in the order given."""
        jm = self._bt.jointMarginalCovariance(list(keys))
        return np.block([[np.asarray(jm.at(a, b)) for b in keys] for a in keys])


def _order_for(values, form):
    return factors_ppp.ordering(values) if form == "corner" else _ordering(values)


def levenberg_marquardt(graph, values, max_iterations, form: str = "view"):
    """One LM run with the solver's elimination ordering: (values, iterations, final error).
    A singular system raises ObservabilityError."""
    params = gtsam.LevenbergMarquardtParams()
    params.setOrdering(_order_for(values, form))
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-9)
    params.setAbsoluteErrorTol(1e-12)
    opt = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    try:
        out = opt.optimize()
    except RuntimeError as e:  # gtsam's IndeterminantLinearSystemException surfaces as RuntimeError
        raise ObservabilityError(
            f"the calibration graph is singular ({str(e).splitlines()[0][:120]}); some parameter is not "
            "determined by the views: add poses with the board tilted about different axes."
        ) from None
    return out, opt.iterations(), graph.error(out)


def _extract(values, slots, views, est: Estimate, cameras: dict, form: str = "view") -> Estimate:
    """The Estimate held by optimised ``values`` (robot poses of captures not in the graph kept)."""
    if form == "corner":
        T_ref_cam, T_mount_board, T_ref_mount_new = factors_ppp.extract(values, slots, views)
        T_ref_mount = dict(est.T_ref_mount)
        T_ref_mount.update(T_ref_mount_new)
        return Estimate(T_ref_cam=T_ref_cam, T_mount_board=T_mount_board, T_ref_mount=T_ref_mount)
    T_ref_cam = {name: values.atPose3(C(i)).matrix() for name, i in slots.items()}
    T_ref_mount = dict(est.T_ref_mount)
    for k in {v.capture for v in views if v.active}:
        T_ref_mount[k] = values.atPose3(F(k)).matrix()
    intr = dict(est.intrinsics)
    for name, i in slots.items():
        if values.exists(K(i)):
            base = est.intrinsics.get(name) or cameras[name]
            intr[name] = with_pinhole(base, values.atVector(K(i)))
    scale = float(values.atVector(S(0))[0]) if values.exists(S(0)) else est.board_scale
    offsets = np.asarray(values.atVector(O(0))) if values.exists(O(0)) else est.joint_offsets
    return Estimate(T_ref_cam=T_ref_cam, T_mount_board=values.atPose3(B(0)).matrix(), T_ref_mount=T_ref_mount,
                    intrinsics=intr, board_scale=scale, wide_intrinsics=est.wide_intrinsics, joint_offsets=offsets)


def solve_from_start(problem: Problem, names: list, views: list, T_ref_cam0: dict, T_mount_board0: np.ndarray,
                     timings: dict | None = None, wide_intrinsics: frozenset = frozenset(),
                     joint_offsets0: np.ndarray | None = None) -> Estimate:
    """IRLS + outlier handling + marginals for one graph (all cameras in 'joint', one camera in
    'single') from the start ``T_ref_cam0`` (camera -> 4x4), ``T_mount_board0``; no initialiser.

    Sets the views' weights, ``active`` and ``reason``. The Estimate carries the final cost, pixel
    sigma, marginals, ``slots`` and the formulation used. ``wide_intrinsics``: cameras whose
    intrinsics get the wide prior (found inadequate by a first solve); ``joint_offsets0``: the free
    joint offsets to start from (kinematics='joint-offsets'; default zero).
    """
    form = _formulation(problem, names, len(views))
    try:
        return _solve_with_formulation(problem, names, views, T_ref_cam0, T_mount_board0, form, timings,
                                       wide_intrinsics, joint_offsets0)
    except ObservabilityError:
        if form != "corner" or problem.options.formulation == "corner":
            raise
        # numerical failure of the corner graph: the per-view graph is the reference
        return _solve_with_formulation(problem, names, views, T_ref_cam0, T_mount_board0, "view", timings,
                                       wide_intrinsics)


def _solve_with_formulation(problem: Problem, names: list, views: list, T_ref_cam0: dict, T_mount_board0: np.ndarray,
                            form: str, timings: dict | None, wide_intrinsics: frozenset = frozenset(),
                            joint_offsets0: np.ndarray | None = None) -> Estimate:
    """:func:`solve_from_start` in one formulation: screening, robust rounds, final graph and marginals."""
    slots = {n: i for i, n in enumerate(names)}
    est = Estimate(T_ref_cam=dict(T_ref_cam0), T_mount_board=T_mount_board0, T_ref_mount={},
                   wide_intrinsics=frozenset(wide_intrinsics), joint_offsets=joint_offsets0)
    sigma = _screen_views_at_start(problem, views, est)
    iterations = 0
    for _ in range(4):
        est, sigma, it, res = _reweighted_solves(problem, views, slots, est, sigma, form, timings)
        iterations += it
        if not _readmit_or_reject_views(views, res, sigma, problem.options):
            break
    return _final_solve_and_marginals(problem, names, views, slots, est, sigma, iterations, form, timings)


def _screen_views_at_start(problem: Problem, views: list, est: Estimate) -> float:
    """Activate every view at full weight, set aside the views grossly off at the start (so that a
    few corrupted views cannot drag the first solve); returns the starting pixel sigma."""
    for v in views:
        v.w = np.ones(len(v.ids))
        v.active = True
        v.reason = ""
    init_rms = np.array([np.sqrt(np.mean(r ** 2)) for r in _all_residuals(views, est, problem.cameras)])
    thr0 = max(10.0 * np.median(init_rms), 15.0)
    for v, r in zip(views, init_rms):
        if r > thr0:
            v.active = False
            v.reason = f"inconsistent with the other views at initialisation (rms {r:.1f} px)"
    return problem.options.pixel_sigma_px or max(float(np.median(init_rms[init_rms <= thr0])), 0.5)


def _reweighted_solves(problem: Problem, views: list, slots: dict, est: Estimate, sigma: float, form: str,
                       timings: dict | None):
    """LM runs with fixed corner weights, re-weighted in between, until the weights and the pixel
    sigma settle (at most 6 runs): (estimate, pixel sigma, LM iterations, residual norms by id(view))."""
    opts = problem.options
    iterations = 0
    for _ in range(6):
        with _timed(timings, "build_graph"):
            graph, values = build_graph(views, slots, problem, est, sigma, form)
        with _timed(timings, "lm"):
            values, it, _ = levenberg_marquardt(graph, values, opts.max_iterations, form)
        iterations += it
        est = _extract(values, slots, views, est, problem.cameras, form)
        res = {id(v): r for v, r in zip(views, _all_residuals(views, est, problem.cameras))}
        active = [v for v in views if v.active]
        sigma_new = _pixel_sigma(active, res, opts.pixel_sigma_px)
        change = _reweight(active, res, sigma_new, opts)
        converged = abs(sigma_new - sigma) < 0.02 * sigma and change < 0.05
        sigma = sigma_new
        if converged:
            break
    return est, sigma, iterations, res


def _pixel_sigma(active: list, res: dict, fixed_sigma_px: float | None) -> float:
    """The given pixel sigma, else a robust estimate from the kept corners' residual norms."""
    norms = np.concatenate([res[id(v)][v.w > 0] for v in active])
    # median of a 2-D Gaussian residual norm is sqrt(2 ln 2) = 1.1774 per-axis sigmas
    return fixed_sigma_px or max(float(np.median(norms)) / 1.1774, 1e-3)


def _reweight(active: list, res: dict, sigma_px: float, opts) -> float:
    """New robust weights of the active views' corners (0 beyond outlier_sigmas); the largest change."""
    change = 0.0
    for v in active:
        r = res[id(v)] / sigma_px
        w_new = _loss_weights(r, opts.loss, opts.loss_scale)
        w_new[r > opts.outlier_sigmas] = 0.0
        change = max(change, float(np.abs(w_new - v.w).max()))
        v.w = w_new
    return change


def _readmit_or_reject_views(views: list, res: dict, sigma_px: float, opts) -> bool:
    """View level: reject active views that lost most of their corners, re-admit set-aside views that
    fit now; True when any view changed."""
    changed = False
    for v in views:
        r = res[id(v)] / sigma_px
        kept = r <= opts.outlier_sigmas
        ok = kept.mean() >= 0.5 and kept.sum() >= MIN_CORNERS_PER_VIEW
        if v.active and not ok:
            v.active = False
            v.reason = (f"{(~kept).sum()} of {len(kept)} corners beyond {opts.outlier_sigmas:g} sigma "
                        f"(median residual {np.median(res[id(v)]):.2f} px)")
            changed = True
        elif not v.active and ok:
            v.active = True
            v.reason = ""
            v.w = np.where(kept, _loss_weights(r, opts.loss, opts.loss_scale), 0.0)
            changed = True
    return changed


def _a_posteriori_sigma(problem: Problem, names: list, views: list, est: Estimate) -> float:
    """The given pixel sigma, else the a posteriori one: weighted residuals over the redundancy
    (a view's low-order modes divided by their variance factor, :attr:`Estimate.mode_ratios`)."""
    opts = problem.options
    if opts.pixel_sigma_px:
        return opts.pixel_sigma_px
    active = [v for v in views if v.active]
    n_obs = 2 * sum(int((v.w > 0).sum()) for v in active)
    n_intr = sum(intrinsics_estimated(problem.cameras[n], opts) for n in names)
    n_par = 6 * (len(names) + 1) + 6 * n_intr + int(opts.board_scale)
    n_par += 0 if est.joint_offsets is None else len(est.joint_offsets)
    wr2 = sum(float(np.sum(v.w * r ** 2)) for v, r in zip(active, _all_residuals(active, est, problem.cameras)))
    # a view's modes count 1 / factor of their squared residuals (the whitened residual)
    wr2 -= sum(m.energy_modes_px2 * (1.0 - 1.0 / m.applied) for m in est.mode_ratios.values())
    return max(float(np.sqrt(max(wr2, 0.0) / max(n_obs - n_par, 1))), 1e-4)


def _final_solve_and_marginals(problem: Problem, names: list, views: list, slots: dict, est: Estimate, sigma: float,
                               iterations: int, form: str, timings: dict | None) -> Estimate:
    """The final weighted graph at the a posteriori pixel sigma (re-solved when that sigma moved the
    pixel/FK balance by more than 5%), its cost and its marginals."""
    opts = problem.options
    check_modes = form == "view" and opts.view_noise_modes and not opts.pixel_sigma_px
    # residuals and robot-pose Jacobians at the estimate, shared by the two checks below
    linearised = _view_jacobians(problem, views, est, sigma) if opts.fk_variance or check_modes else None
    est.fk_ratio = fk_variance_ratio(problem, views, est, sigma, linearised) if opts.fk_variance else None
    widen = est.fk_ratio is not None and est.fk_ratio.applied > 1.0
    if widen:
        # the robot is less accurate than stated: the final graph uses the FK sigmas the fit implies
        s = float(np.sqrt(est.fk_ratio.applied))
        problem = problem.with_(options=replace(opts, fk_sigma_translation_m=opts.fk_sigma_translation_m * s,
                                                fk_sigma_rotation_rad=opts.fk_sigma_rotation_rad * s))
        # ... and the residuals the corner-noise modes are judged on are those of that graph
        with _timed(timings, "lm"):
            graph, values = build_graph(views, slots, problem, est, sigma, form)
            values, it, _ = levenberg_marquardt(graph, values, opts.max_iterations, form)
        iterations += it
        est = replace(_extract(values, slots, views, est, problem.cameras, form), fk_ratio=est.fk_ratio)
        linearised = None  # another estimate and another FK prior
    est.mode_ratios = mode_variance_ratios(problem, views, est, sigma, linearised) if check_modes else {}
    factors = {c: m.applied for c, m in est.mode_ratios.items() if m.applied > 1.0}
    sigma_post = _a_posteriori_sigma(problem, names, views, est)
    with _timed(timings, "build_graph"):
        graph, values = build_graph(views, slots, problem, est, sigma_post, form, factors)
    if abs(sigma_post - sigma) > 0.05 * sigma or any(f > 1.05 for f in factors.values()):
        # the pixel/FK balance moved enough to shift the optimum: re-solve before the marginals
        with _timed(timings, "lm"):
            values, it, _ = levenberg_marquardt(graph, values, opts.max_iterations, form)
        iterations += it
        est = replace(_extract(values, slots, views, est, problem.cameras, form), mode_ratios=est.mode_ratios,
                      fk_ratio=est.fk_ratio)
    est.iterations, est.cost, est.sigma_px = iterations, graph.error(values), sigma_post
    est.marginals = _marginals(graph, values, form, timings)
    est.slots, est.formulation = slots, form
    est.mount_cov_body = (factors_ppp.mount_cov_body(est.marginals, values) if form == "corner"
                          else est.marginals.marginalCovariance(B(0)))
    return est


def _marginals(graph, values, form: str, timings: dict | None) -> _Marginals:
    """Marginals of the final graph; a singular one raises ObservabilityError with advice."""
    try:
        with _timed(timings, "marginals"):
            return _Marginals(graph, values, _order_for(values, form))
    except RuntimeError as e:
        raise ObservabilityError(
            f"covariance could not be computed ({str(e).splitlines()[0][:120]}): the views leave a parameter "
            "undetermined; add poses with the board tilted about different axes."
        ) from None


def to_ref_axes(T: np.ndarray, cov_body: np.ndarray) -> np.ndarray:
    """GTSAM right-perturbation covariance -> rotation/position errors in the reference frame axes."""
    R = T[:3, :3]
    G = np.zeros((6, 6))
    G[:3, :3] = R
    G[3:, 3:] = R
    return G @ cov_body @ G.T


def _pair_covariance(T_a: np.ndarray, T_b: np.ndarray, cov_joint_body: np.ndarray) -> np.ndarray:
    """Covariance of T_a_b = T_a^-1 T_b in a's axes from the joint (12x12) body-frame marginal."""
    T0 = inv(T_a) @ T_b

    def f(xa, xb):
        Ta = gtsam.Pose3(T_a).retract(xa).matrix()
        Tb = gtsam.Pose3(T_b).retract(xb).matrix()
        T = inv(Ta) @ Tb
        return np.concatenate([log_so3(T[:3, :3] @ T0[:3, :3].T), T[:3, 3] - T0[:3, 3]])

    J = np.zeros((6, 12))
    eps = 1e-6
    for i in range(12):
        d = np.zeros(12)
        d[i] = eps
        J[:, i] = (f(d[:6], d[6:]) - f(-d[:6], -d[6:])) / (2 * eps)
    # f's rotation vector (left error of R_a_b) and translation (t_a_b) are both in a's axes already
    return J @ cov_joint_body @ J.T


def prepare_views(problem: Problem) -> tuple[list, list]:
    """(views, rejected): the problem's detections as :class:`View` s, and those with fewer than
    MIN_CORNERS_PER_VIEW corners as :class:`RejectedView` s."""
    robot_poses = _robot_prior_poses(problem)
    views, rejected = [], []
    for d in problem.detections:
        if len(d.ids) < MIN_CORNERS_PER_VIEW:
            rejected.append(RejectedView(d.camera, d.capture, f"only {len(d.ids)} corners (need {MIN_CORNERS_PER_VIEW})"))
            continue
        views.append(View(camera=d.camera, capture=d.capture, ids=d.ids, p_board_m=problem.points_board_m[d.ids],
                          uv_px=d.uv_px, T_ref_mount=robot_poses[d.capture]))
    return views, rejected


def view_candidates(problem: Problem, views: list) -> tuple[dict, list]:
    """(camera -> [ViewCandidates], views without a valid PnP solution): both IPPE poses of every view."""
    out = {}
    bad = []
    for v in views:
        R, t, rms = pnp_candidates(v.p_board_m, v.uv_px, problem.cameras[v.camera])
        if len(R) == 0:
            bad.append(v)
            continue
        out.setdefault(v.camera, []).append(ViewCandidates(v.camera, v.capture, v.T_ref_mount, R, t, rms))
    return out, bad


def _init_score(cameras: dict, views, T_ref_cam, T_mount_board) -> float:
    """Median per-view RMS reprojection error (px) of an initial guess over the views it covers."""
    vs = [v for v in views if v.camera in T_ref_cam]
    if not vs:
        return np.inf
    est = Estimate(T_ref_cam=T_ref_cam, T_mount_board=T_mount_board, T_ref_mount={})
    rms = [np.sqrt(np.mean(r ** 2)) for r in _all_residuals(vs, est, cameras)]
    return float(np.median(rms))


INIT_SCORE_MAX_VIEWS = 300


def _subsample(cands: dict, views: list, max_views: int, seed: int):
    """At most ~max_views views, spread over cameras in proportion (at least 5 each when available)."""
    total = sum(len(v) for v in cands.values())
    if total <= max_views:
        return cands, views
    rng = np.random.default_rng(seed)
    out = {}
    for name, vs in cands.items():
        k = min(len(vs), max(5, int(np.ceil(len(vs) * max_views / total))))
        out[name] = [vs[i] for i in sorted(rng.choice(len(vs), size=k, replace=False))]
    keep = {(v.camera, v.capture) for vs in out.values() for v in vs}
    return out, [v for v in views if (v.camera, v.capture) in keep]


def best_initial_guess(cameras: dict, views: list, cands: dict, joint: bool, seed: int = 0,
                       timings: dict | None = None) -> tuple[dict, dict]:
    """Rank the initialiser's hypotheses by reprojection error after the linear translation solve.

    ``cameras``: name -> Intrinsics, in slot order; ``cands``: from :func:`view_candidates`.
    Returns (camera -> T_ref_cam, mounts) with mounts {0: T_mount_board} when ``joint``, else
    camera -> its own mount; a camera that could not be initialised is missing.

    Per-view PnP rotations of a small far board can be tens of degrees off, and a wrong hypothesis
    can be as self-consistent in rotation as the right one; it cannot explain the corners.
    """
    p_by_view = {(v.camera, v.capture): v.p_board_m for v in views}
    uv_by_view = {(v.camera, v.capture): v.uv_px for v in views}
    with _timed(timings, "initialise"):
        hyps = initialise(list(cameras), cands, joint=joint, seed=seed)

    def translations(*args):
        with _timed(timings, "refine_translations"):
            return refine_translations(*args)

    if joint:
        # Rank on a subsample (large cells have thousands of views), refine the winner on all.
        s_cands, s_views = _subsample(cands, views, INIT_SCORE_MAX_VIEWS, seed)
        best = None
        for T0, mounts in hyps:
            if len(hyps) > 1:
                T1, m1 = translations(s_cands, cameras, T0, mounts[0], p_by_view, uv_by_view)
                score = (-len(T1), _init_score(cameras, s_views, T1, m1))
            else:
                score = (0, 0.0)
            if best is None or score < best[0]:
                best = (score, T0, mounts[0])
        T0, m0 = translations(cands, cameras, best[1], best[2], p_by_view, uv_by_view)
        return T0, {0: m0}
    T_best, m_best, s_best = {}, {}, {}
    for T0, mounts in hyps:
        for n in mounts:
            Tn, mn = translations({n: cands.get(n, [])}, cameras, {n: T0[n]}, mounts[n], p_by_view, uv_by_view)
            sc = _init_score(cameras, [v for v in views if v.camera == n], {n: Tn[n]}, mn)
            if n not in s_best or sc < s_best[n]:
                T_best[n], m_best[n], s_best[n] = Tn[n], mn, sc
    return T_best, m_best


def solve(problem: Problem, initial: dict | None = None, seed: int = 0, timings: dict | None = None) -> Result:
    """Calibrate all cameras of ``problem``.

    A camera moved during capture (its views split into two self-consistent groups) is calibrated
    from the views after the move, with a note naming it, the captures and the displacement
    (:mod:`calibgraph.solver.moved`).

    Args:
        problem: a validated :class:`Problem`.
        initial: optional initial guess ``{"T_ref_cam": {name: 4x4}, "T_mount_board": 4x4}``; the
            robust initialiser runs anyway and the start that ends with the lower cost wins.
        seed: RANSAC seed (results are deterministic for a given seed).
        timings: when a dict, the wall time (s) of each stage in ``STAGES`` is added to it.
    Returns:
        :class:`Result`.
    Raises:
        ObservabilityError: a camera has too few views or the motion leaves a parameter undetermined.
        InputError: formulation 'corner' was asked for a camera with k3..k6 distortion.
    """
    t0 = time.perf_counter()
    result = solve_minding_moves(problem, lambda p: _solve_once(p, initial, seed, timings))
    return replace(result, solve_time_s=time.perf_counter() - t0)


def _solve_once(problem: Problem, initial: dict | None = None, seed: int = 0, timings: dict | None = None) -> Result:
    """One solve of ``problem`` (see :func:`solve`)."""
    t0 = time.perf_counter()
    views, cands, rejected = _usable_views(problem, timings)
    check_before_solve(problem, _captures_by_camera(views))
    names = list(problem.cameras)
    joint = problem.method == "joint"
    T_ref_cam0, mounts0 = _initial_guess(problem, views, cands, joint, seed, timings)
    notes = []
    ks = kin.setup(problem)
    if ks is not None:
        kin.check_motion(ks, sorted({v.capture for v in views}))
    if joint:
        offsets0 = None
        if ks is not None and problem.options.kinematics_staging == "staged":
            T_ref_cam0, mounts0, offsets0 = _kinematics_stages(problem, names, views, T_ref_cam0, mounts0, initial,
                                                               ks, timings)
        group = _solve_joint(problem, names, views, T_ref_cam0, mounts0[0], initial, timings, offsets0)
        if problem.options.intrinsics == "auto":
            group = _widen_inadequate_intrinsics(problem, names, group, notes, timings)
        groups = [group]
    else:
        groups = [_solve_single(problem, n, views, T_ref_cam0[n], mounts0[n], timings) for n in names]
    cov_body = {n: g.est.marginals.marginalCovariance(C(g.est.slots[n])) for g in groups for n in g.names}
    cameras, rejected_corners = {}, []
    for g in groups:
        for n in g.names:
            cameras[n], corners = _camera_result(problem, n, g.est, g.views, cov_body[n], rejected, joint)
            rejected_corners += corners
    T_mount_board, mount_cov, T_base_flange_est = _mount_and_robot_poses(problem, groups, joint)
    scale, scale_sigma = _board_scale(problem, groups, notes)
    notes += _intrinsics_notes(cameras)
    notes += _corner_noise_notes(groups)
    notes += _fk_notes(problem, groups)
    settings = {k: getattr(problem.options, k) for k in problem.options.__dataclass_fields__}
    settings["formulation_used"] = groups[0].est.formulation
    robot = _robot_result(problem, ks, names, groups[0], notes) if ks is not None else None
    return Result(
        mode=problem.mode, method=problem.method, cameras=cameras, T_mount_board=T_mount_board,
        mount_covariance=mount_cov, pairs=_pair_results(names, cameras, cov_body, groups, joint), converged=True,
        iterations=sum(g.est.iterations for g in groups), final_cost=sum(g.est.cost for g in groups),
        pixel_sigma_px=float(np.mean([g.est.sigma_px for g in groups])), solve_time_s=time.perf_counter() - t0,
        rejected_views=tuple(rv for c in cameras.values() for rv in c.views_rejected),
        rejected_corners=tuple(rejected_corners), T_base_flange_est=T_base_flange_est, settings=settings,
        board_scale=scale, board_scale_sigma=scale_sigma, notes=tuple(notes), robot=robot,
        fk_noise=(groups[0].est.fk_ratio.to_dict(problem.options)
                  if len(groups) == 1 and groups[0].est.fk_ratio is not None else None),
    )


def _kinematics_stages(problem: Problem, names: list, views: list, T_ref_cam0: dict, mounts0: dict,
                       initial: dict | None, ks, timings: dict | None):
    """Stages 1 and 2 of kinematics_staging='staged': the cameras with the FK prior inflated (and no
    offsets), then the offsets that best explain the flange poses that solve found. Returns the start
    of the joint solve: (T_ref_cam, {0: T_mount_board}, free offsets)."""
    o = problem.options
    loose = replace(o, kinematics="none", fk_sigma_rotation_rad=o.fk_sigma_rotation_rad * kin.STAGE1_FK_INFLATION,
                    fk_sigma_translation_m=o.fk_sigma_translation_m * kin.STAGE1_FK_INFLATION)
    g1 = _solve_joint(problem.with_(options=loose), names, views, T_ref_cam0, mounts0[0], initial, timings)
    fk_sigmas = np.array([o.fk_sigma_rotation_rad] * 3 + [o.fk_sigma_translation_m] * 3)
    offsets = kin.offsets_from_poses(ks, g1.est.T_ref_mount, o.joint_offset_prior_rad, fk_sigmas)
    return g1.est.T_ref_cam, {0: g1.est.T_mount_board}, offsets


def _robot_result(problem: Problem, ks, names: list, group: _Group, notes: list) -> dict:
    """``Result.robot``: the offsets with their marginal covariance joint with the camera poses, the mount
    and the board scale (for the correlations); refuses offsets the data do not determine."""
    est = group.est
    keys, labels = [O(0)], []
    for n in names:
        keys.append(C(est.slots[n]))
        labels += [f"{n} {a}" for a in ("rx", "ry", "rz", "x", "y", "z")]
    keys.append(B(0))
    labels += [f"mount {a}" for a in ("rx", "ry", "rz", "x", "y", "z")]
    if est.marginals.has(S(0)):
        keys.append(S(0))
        labels.append("board scale")
    cov = est.marginals.joint(keys)
    nf = len(ks.free)
    captures = sorted({v.capture for v in group.views if v.active})
    kin.check_after_solve(ks, np.sqrt(np.clip(np.diag(cov)[:nf], 0, None)), problem.options.joint_offset_prior_rad,
                          captures)
    out = kin.robot_result(ks, est.joint_offsets, cov, labels, problem.options.joint_offset_prior_rad,
                           problem.options.kinematics_staging)
    out["model_source"] = problem.options.kinematics_model
    o, s = np.asarray(out["joint_offsets_rad"]), out["joint_offsets_sigma_rad"]
    big = [f"joint {i + 1} {1e3 * o[i]:+.2f} ± {1e3 * s[i]:.2f} mrad" for i in ks.free if abs(o[i]) > 3 * s[i]]
    if big:
        notes.append("the robot's joint zero offsets differ from zero: " + ", ".join(big) +
                     " (calibgraph export writes a corrected URDF)")
    return out


# A camera whose kept corners miss by more than this (px RMS), mostly along the radial direction,
# has intrinsics the prior of their source cannot fix (e.g. a file without the lens's distortion):
# sub-pixel detectors on sharp boards leave 0.05-0.3 px.
INADEQUATE_RMS_PX = 0.5
INADEQUATE_RADIAL_FRACTION = 0.25


def _radial_structure(est: Estimate, views: list, name: str, intr) -> tuple[float, float]:
    """(RMS px of the kept corners' residuals, fraction of their energy along a radial
    distortion pattern about the principal point) of camera ``name``."""
    d_all, b_all = [], []
    for v in views:
        if v.camera != name or not v.active:
            continue
        keep = v.w > 0
        uv_hat = project_chain(est.T_ref_cam[name], est.T_ref_mount.get(v.capture, v.T_ref_mount), est.T_mount_board,
                               est.board_scale * v.p_board_m[keep], intr)
        d_all.append(uv_hat - v.uv_px[keep])
        x = (v.uv_px[keep] - intr.K[:2, 2]) / np.array([intr.K[0, 0], intr.K[1, 1]])
        b_all.append(x * np.sum(x * x, axis=1, keepdims=True) * np.array([intr.K[0, 0], intr.K[1, 1]]))
    if not d_all:
        return 0.0, 0.0
    d, b = np.concatenate(d_all), np.concatenate(b_all)
    e_d = float(np.sum(d * d))
    if e_d <= 0 or float(np.sum(b * b)) <= 0:
        return 0.0, 0.0
    alpha = float(np.sum(d * b) / np.sum(b * b))
    return float(np.sqrt(e_d / len(d))), alpha ** 2 * float(np.sum(b * b)) / e_d


CHI2_6_999 = 22.46  # chi-square, 6 dof, 0.999 quantile


def _intrinsics_disagreement(problem: Problem, est: Estimate, name: str) -> float:
    """Squared Mahalanobis distance (6 dof) between the estimated and the given intrinsics of a
    camera, against the covariance of that difference (prior minus posterior): large when the data
    disagree with the given values more than their source's prior allows."""
    if est.marginals is None or not intrinsics_estimated(problem.cameras[name], problem.options):
        return 0.0
    given = problem.cameras[name]
    delta = intrinsics_vector(est.intrinsics.get(name, given)) - intrinsics_vector(given)
    P_prior = np.diag(intrinsics_prior_sigmas(given, problem.options, wide=name in est.wide_intrinsics) ** 2)
    P_post = est.marginals.marginalCovariance(K(est.slots[name]))
    w, V = np.linalg.eigh(0.5 * (P_prior - P_post + (P_prior - P_post).T))
    keep = w > 1e-9 * max(float(w.max()), 1e-30)
    z = V[:, keep].T @ delta
    return float(np.sum(z * z / w[keep]))


def _widen_inadequate_intrinsics(problem: Problem, names: list, group: _Group, notes: list,
                                 timings: dict | None) -> _Group:
    """Re-solve with a wide intrinsics prior for the cameras whose data reject their given
    intrinsics (the estimate moved further than the source's prior allows: chi-square, 6 dof,
    p < 0.001; or residuals still large and radial); keep it when it fits, and say so in ``notes``."""
    est, views = group.est, group.views
    bad = {}
    for n in names:
        if not intrinsics_estimated(problem.cameras[n], problem.options):
            continue
        d2 = _intrinsics_disagreement(problem, est, n)
        rms, radial = _radial_structure(est, views, n, est.intrinsics.get(n, problem.cameras[n]))
        if d2 > CHI2_6_999 or (rms > INADEQUATE_RMS_PX and radial > INADEQUATE_RADIAL_FRACTION):
            bad[n] = (d2, rms)
    if not bad:
        return group
    state = [(v.active, v.reason, v.w.copy()) for v in views]
    try:
        est2 = solve_from_start(problem, names, views, est.T_ref_cam, est.T_mount_board, timings,
                                wide_intrinsics=frozenset(bad), joint_offsets0=est.joint_offsets)
    except ObservabilityError:
        for v, (active, reason, w) in zip(views, state):
            v.active, v.reason, v.w = active, reason, w
        notes += [f"camera {n}: the data disagree with its given intrinsics (chi-square {d2:.0f} on 6 dof), and "
                  "they cannot be estimated from these views; check the intrinsics" for n, (d2, _) in bad.items()]
        return group
    for n, (d2, rms) in bad.items():
        given = intrinsics_vector(problem.cameras[n])
        new = intrinsics_vector(est2.intrinsics.get(n, problem.cameras[n]))
        rms2 = _radial_structure(est2, views, n, est2.intrinsics.get(n, problem.cameras[n]))[0]
        src = intrinsics_source(problem.cameras[n], problem.options)
        notes.append(f"camera {n}: the data disagree with its given ({src}) intrinsics (chi-square {d2:.0f} on 6 dof; "
                     f"residual {rms:.2f} -> {rms2:.2f} px): estimated with a wide prior, fx {100 * (new[0] / given[0] - 1):+.2f} %, "
                     f"fy {100 * (new[1] / given[1] - 1):+.2f} %, cx {new[2] - given[2]:+.1f} px, cy {new[3] - given[3]:+.1f} px, "
                     f"k1 {new[4] - given[4]:+.3f}, k2 {new[5] - given[5]:+.3f} (1-sigma in the result; "
                     "--fixed-intrinsics keeps the given ones)")
    return _Group(group.names, est2, views)


def _board_scale(problem: Problem, groups: list, notes: list) -> tuple[float, float | None]:
    """(estimated board scale, its 1-sigma) of the joint graph — (1, None) when not estimated — and a
    note when the board's printed size differs from the declared one by more than 3 sigma."""
    est = groups[0].est
    if not problem.options.board_scale or len(groups) != 1 or est.marginals is None or not est.marginals.has(S(0)):
        return 1.0, None
    s = est.board_scale
    sigma = float(np.sqrt(max(est.marginals.marginalCovariance(S(0))[0, 0], 0.0)))
    if abs(s - 1.0) > 3 * sigma:
        pts = problem.points_board_m
        d = np.linalg.norm(pts[1:] - pts[:1], axis=1)
        pitch = float(d[d > 1e-9].min()) if np.any(d > 1e-9) else 0.0
        notes.append(f"the board is {100 * (s - 1):+.2f} % (± {100 * sigma:.2f} %) the size the target spec declares: "
                     f"printed at {100 * s:.1f} %" + (f" (pitch {1e3 * pitch * s:.2f} mm, not {1e3 * pitch:.2f} mm)" if pitch
                                                     else "")
                     + "; the calibration accounts for it — check the print with a ruler and fix the target spec")
    return s, sigma


def _corner_noise_notes(groups: list) -> list:
    """One line per camera whose views' low-order modes were found to vary more than the rest."""
    out = []
    for g in groups:
        for name, m in g.est.mode_ratios.items():
            if m.applied > 1.0:
                test = "" if m.significant else ", p < 0.05 but not < 0.001"
                out.append(f"camera {name}: its residuals move whole boards (each view's shift, rotation, scale and "
                           f"shear in the image vary {m.ratio:.2f}x what the other residuals imply{test}: corners of "
                           f"small squares share pixels, or an unmodelled camera or robot error); its views are "
                           f"weighted and its 1-sigma widened for it")
    return out


def _fk_notes(problem: Problem, groups: list) -> list:
    """One line when the robot poses disagree with the stated FK accuracy and the prior was widened."""
    out = []
    for g in groups:
        r = g.est.fk_ratio
        if r is None or r.applied <= 1.0:
            continue
        o, s = problem.options, float(np.sqrt(r.applied))
        test = "" if r.significant else ", p < 0.05 but not < 0.001"
        out.append(f"robot: the fitted flange poses depart from forward kinematics {s:.1f}x as far as the stated FK "
                   f"accuracy ({1e3 * o.fk_sigma_translation_m:.2f} mm, {np.degrees(o.fk_sigma_rotation_rad):.3f} deg) "
                   f"allows{test}; solved with {1e3 * o.fk_sigma_translation_m * s:.2f} mm, "
                   f"{np.degrees(o.fk_sigma_rotation_rad) * s:.3f} deg and the 1-sigma widened for it (state the arm's "
                   f"accuracy with --fk-sigma-mm/--fk-sigma-deg; joint zero offsets: --estimate-kinematics joint-offsets)")
        break
    return out


def _intrinsics_notes(cameras: dict) -> list:
    """A note per camera whose estimated focal length or principal point is more than 3 sigma and
    0.2 % (focal) / 2 px (principal point) away from the given values."""
    out = []
    for n, c in cameras.items():
        d = c.intrinsics or {}
        if not d.get("estimated") or d.get("prior") == "wide":
            continue
        given, sig = d["given"], d["sigma"]
        K = np.asarray(d["K"], float)
        est = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
        f_rel = [(est[k] - given[k]) / given[k] for k in ("fx", "fy")]
        f_sig = [sig[k] / given[k] for k in ("fx", "fy")]
        if all(abs(r) > max(3 * s, 0.002) for r, s in zip(f_rel, f_sig)):
            out.append(f"camera {n}: focal length estimated {100 * np.mean(f_rel):+.2f} % (± {100 * np.mean(f_sig):.2f} %) "
                       "from the given intrinsics; the poses and 1-sigma account for it")
        for k in ("cx", "cy"):
            if abs(est[k] - given[k]) > max(3 * sig[k], 2.0):
                out.append(f"camera {n}: principal point {k} estimated {est[k] - given[k]:+.1f} px (± {sig[k]:.1f}) "
                           "from the given value")
    return out


@dataclass(frozen=True)
class _Group:
    """One solved graph: its cameras, its estimate and its views (one group in 'joint', one per camera in 'single')."""

    names: list
    est: Estimate
    views: list


def _usable_views(problem: Problem, timings: dict | None) -> tuple[list, dict, list]:
    """(views, their PnP candidates by camera, refused views): views need enough corners and a PnP solution."""
    views, rejected = prepare_views(problem)
    with _timed(timings, "candidates"):
        cands, bad = view_candidates(problem, views)
    for v in bad:
        rejected.append(RejectedView(v.camera, v.capture, "no valid PnP solution (corners degenerate or ids wrong)"))
    bad_ids = {id(v) for v in bad}
    return [v for v in views if id(v) not in bad_ids], cands, rejected


def _captures_by_camera(views: list) -> dict:
    """camera -> captures of its views (what the observability check counts)."""
    out = {}
    for v in views:
        out.setdefault(v.camera, []).append(v.capture)
    return out


def _initial_guess(problem: Problem, views: list, cands: dict, joint: bool, seed: int, timings: dict | None):
    """:func:`best_initial_guess`, refusing with advice when a camera could not be initialised."""
    T_ref_cam0, mounts0 = best_initial_guess(problem.cameras, views, cands, joint, seed, timings)
    missing = [n for n in problem.cameras if n not in T_ref_cam0]
    if missing:
        raise ObservabilityError(
            f"camera(s) {missing} could not be initialised: no consistent set of views (each view's PnP disagrees "
            "with the board mount found from the other cameras); check their intrinsics and the target spec."
        )
    return T_ref_cam0, mounts0


def _solve_joint(problem: Problem, names: list, views: list, T_ref_cam0: dict, T_mount_board0: np.ndarray,
                 initial: dict | None, timings: dict | None, joint_offsets0: np.ndarray | None = None) -> _Group:
    """All cameras in one graph, from the initialiser's start and the user's (when given): the lower cost wins."""
    starts = [(T_ref_cam0, T_mount_board0)]
    if initial:
        starts.append((dict(initial["T_ref_cam"]), np.asarray(initial["T_mount_board"])))
    best, error = None, None
    for T_ref_cam, T_mount_board in starts:
        try:
            est = solve_from_start(problem, names, views, T_ref_cam, T_mount_board, timings,
                                   joint_offsets0=joint_offsets0)
        except ObservabilityError as e:
            error = e
            continue
        if best is None or est.cost < best[0].cost:
            best = (est, [(v.active, v.reason, v.w.copy()) for v in views])
    if best is None:
        raise error
    est, view_state = best
    for v, (active, reason, w) in zip(views, view_state):  # the views as the winning start left them
        v.active, v.reason, v.w = active, reason, w
    return _Group(names, est, views)


def _solve_single(problem: Problem, name: str, views: list, T_ref_cam0: np.ndarray, T_mount_board0: np.ndarray,
                  timings: dict | None) -> _Group:
    """One camera in its own graph, with its own board mount."""
    mine = [v for v in views if v.camera == name]
    return _Group([name], solve_from_start(problem, [name], mine, {name: T_ref_cam0}, T_mount_board0, timings), mine)


def _camera_result(problem: Problem, name: str, est: Estimate, views: list, cov_body: np.ndarray, rejected: list,
                   joint: bool) -> tuple[CameraResult, list]:
    """(CameraResult of one camera, its rejected corners): pose, covariance in reference axes, residuals."""
    cov = to_ref_axes(est.T_ref_cam[name], cov_body)
    check_after_solve(name, cov)
    mine = [v for v in views if v.camera == name]
    used = [v for v in mine if v.active]
    intr = est.intrinsics.get(name, problem.cameras[name])
    residuals, kept_px, rejected_corners = _view_residuals(name, est, mine, intr)
    rn = np.linalg.norm(kept_px, axis=1)
    views_rejected = tuple(RejectedView(name, v.capture, v.reason) for v in mine if not v.active)
    views_rejected += tuple(r for r in rejected if r.camera == name)
    intr_dict = intr.to_dict()
    if est.marginals is not None and intrinsics_estimated(problem.cameras[name], problem.options):
        sig = np.sqrt(np.clip(np.diag(est.marginals.marginalCovariance(K(est.slots[name]))), 0, None))
        given = intrinsics_vector(problem.cameras[name])
        intr_dict["estimated"] = True
        intr_dict["prior"] = "wide" if name in est.wide_intrinsics else intrinsics_source(problem.cameras[name], problem.options)
        intr_dict["sigma"] = dict(zip(INTRINSICS_NAMES, sig.tolist()))
        intr_dict["given"] = dict(zip(INTRINSICS_NAMES, given.tolist()))
    result = CameraResult(
        name=name, ref_frame="base" if problem.mode == "eye_to_hand" else "flange", T_ref_cam=est.T_ref_cam[name],
        covariance=cov,
        reprojection_rms_px=float(np.sqrt(np.mean(rn ** 2))) if rn.size else float("nan"),
        reprojection_max_px=float(rn.max()) if rn.size else float("nan"),
        views_used=len(used), views_rejected=views_rejected,
        corners_used=int(sum((v.w > 0).sum() for v in used)),
        corners_rejected=int(sum((v.w == 0).sum() for v in used)),
        T_mount_board=None if joint else est.T_mount_board,
        residuals_px=residuals,
        intrinsics=intr_dict,
        corner_noise=est.mode_ratios[name].to_dict() if name in est.mode_ratios else None,
    )
    return result, rejected_corners


def _view_residuals(name: str, est: Estimate, views: list, intr) -> tuple[dict, np.ndarray, list]:
    """Residuals (reprojected - detected, px) of one camera's views at the estimate: (capture ->
    record for the result, kept corners' residuals of the active views (M, 2), rejected corners as
    (camera, capture, corner id, residual px))."""
    residuals, kept, rejected_corners = {}, [], []
    for v in views:
        uv_hat = project_chain(est.T_ref_cam[name], est.T_ref_mount.get(v.capture, v.T_ref_mount), est.T_mount_board,
                               est.board_scale * v.p_board_m, intr)
        d = uv_hat - v.uv_px
        residuals[v.capture] = {"ids": v.ids, "uv_detected_px": v.uv_px, "residual_px": d,
                                "weight": v.w.copy(), "rejected": not v.active}
        if v.active:
            keep = v.w > 0
            kept.append(d[keep])
            for cid, rr in zip(v.ids[~keep], np.linalg.norm(d[~keep], axis=1)):
                rejected_corners.append((name, v.capture, int(cid), float(rr)))
    return residuals, np.concatenate(kept) if kept else np.zeros((0, 2)), rejected_corners


def _pair_results(names: list, cameras: dict, cov_body: dict, groups: list, joint: bool) -> dict:
    """(a, b) -> PairResult for every camera pair; in 'joint' from one joint marginal of all cameras
    (pairwise calls would be O(n^2) solves), in 'single' from independent per-camera marginals."""
    joint_cov = None
    if joint and len(names) > 1:
        est = groups[0].est
        joint_cov = est.marginals.joint([C(est.slots[n]) for n in names])
    pairs = {}
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            T_ref_a, T_ref_b = cameras[a].T_ref_cam, cameras[b].T_ref_cam
            if joint:
                ia, ib = names.index(a), names.index(b)
                sel = np.r_[6 * ia: 6 * ia + 6, 6 * ib: 6 * ib + 6]
                cov_ab = joint_cov[np.ix_(sel, sel)]
            else:
                cov_ab = np.zeros((12, 12))
                cov_ab[:6, :6], cov_ab[6:, 6:] = cov_body[a], cov_body[b]
            pairs[(a, b)] = PairResult(a=a, b=b, T_a_b=inv(T_ref_a) @ T_ref_b,
                                       covariance=_pair_covariance(T_ref_a, T_ref_b, cov_ab))
    return pairs


def _mount_and_robot_poses(problem: Problem, groups: list, joint: bool):
    """(T_mount_board, its covariance in reference axes, capture -> estimated T_base_flange) of the
    joint graph; (None, None, {}) in 'single' mode."""
    if not joint:
        return None, None, {}
    est = groups[0].est
    T_base_flange = est.T_ref_mount
    if problem.mode == "eye_in_hand":
        T_base_flange = {k: inv(T) for k, T in T_base_flange.items()}
    return est.T_mount_board, to_ref_axes(est.T_mount_board, est.mount_cov_body), T_base_flange


def crlb(problem: Problem, T_ref_cam: dict, T_mount_board, pixel_sigma_px: float, T_base_flange_true: dict | None = None,
         mounts_single: dict | None = None) -> dict:
    """Cramer-Rao bound of every camera pose: the inverse Fisher information from the Jacobian at the
    true values, with the true pixel sigma and the problem's FK prior sigmas.

    Returns name -> 6x6 covariance (rotation first, reference-frame axes, as in the results).
    In 'single' mode pass ``mounts_single`` (name -> true mount) or the shared true mount is used for each.
    """
    views, _ = prepare_views(problem)
    for v in views:
        v.w = np.ones(len(v.ids))
    T_ref_mount_true = {}
    if T_base_flange_true:
        T_ref_mount_true = {k: (T if problem.mode == "eye_to_hand" else inv(T)) for k, T in T_base_flange_true.items()}
    groups = [list(problem.cameras)] if problem.method == "joint" else [[n] for n in problem.cameras]
    out = {}
    for names in groups:
        vs = [v for v in views if v.camera in names]
        mount = T_mount_board if problem.method == "joint" or not mounts_single else mounts_single[names[0]]
        est = Estimate(T_ref_cam={n: T_ref_cam[n] for n in names}, T_mount_board=mount, T_ref_mount=dict(T_ref_mount_true))
        slots = {n: i for i, n in enumerate(names)}
        graph, values = build_graph(vs, slots, problem, est, pixel_sigma_px)
        marg = _Marginals(graph, values, _ordering(values))
        for n in names:
            out[n] = to_ref_axes(T_ref_cam[n], marg.marginalCovariance(C(slots[n])))
    return out
