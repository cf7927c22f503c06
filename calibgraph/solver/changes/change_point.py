"""Did a camera move during capture? A change point in time of the pose its views imply.

Each view of a camera, with every other parameter held, implies a pose of that camera. The test is
built so that nothing the camera shares with the others can hide or fake a move:

- the robot pose of each capture is taken from its forward-kinematics prior and the *other*
  cameras' views of that capture (the tested camera's own pull on it is removed, linearly, from
  the estimate it was solved in), with that uncertainty propagated into the view's pose;
- the estimate comes from the robust rounds, before the FK prior, the corner-noise model, the
  board scale's note or a claimed camera model could be widened to explain one camera's misfit;
- each view's corners are re-weighted against the view's own best fit, not against the joint
  one, so the views after a knock are not down-weighted for disagreeing with the views before it.

Linearised at one pose ``T_lin`` of the camera, view ``v`` implies a tangent ``zeta_v`` with
information ``Lambda_v`` (corners and the robot pose's uncertainty). For every split of the views
in capture order, two means against one give the likelihood-ratio statistic ``glr``; judged as an F
statistic against the scatter the two means leave, ``F = (glr / 6) / (rss_two / (6 n - 12))``,
which is what keeps the test honest under correlated corner noise and FK noise: both scale the
views' scatter about their mean exactly as they scale the split (a view's six pose directions are
its six low-order image modes). The split is a move when ``F`` passes ``F_LIMIT``, each side is
consistent on its own (no side a mixture of its own) and the two poses leave the camera's corners at
about the solve's pixel noise (a model error that is not a move is not explained by a cut in time).
Two more shapes of a move are tested beside the single cut:

- a move just before the camera's *last* view (``min_after=1``, what the solve asks): one view
  after a cut cannot be told from one bad view, but answering it with the old pose would report
  where the camera no longer stands; the solve then reports the camera not calibrated, asking
  "moved after capture k?" (:mod:`calibgraph.solver.changes.moved`);
- a camera moved and **moved back** (knocked and sprung back, or taken off and put back): the
  views of a span ``[i, j)`` against the views before and after it together. The span has one more
  cut than a single split, so it is taken only when that second cut is itself significant
  (``(glr_span - glr_cut) / 6`` over the span model's scatter passes ``F_LIMIT``) and the split it
  gives passes the same tests as a cut.

Linear algebra on 6x6 blocks with prefix sums: all splits of all cameras cost about one
linearisation of the views, not a solve per camera.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np

from calibgraph.core.transforms import pose_error
from calibgraph.solver.robot import kinematics as kin
from calibgraph.solver.terms.factors import fk_noise, pad_views, padded_view_residuals
from calibgraph.solver.terms.noise_model import shrunk_level
from calibgraph.solver.fit.robust import loss_weights
from calibgraph.solver.terms.views import robot_keys

MIN_GROUP_VIEWS = 2     # a side of a split needs this many views (one view is a single outlier, not a pose)
F_LIMIT = 12.0          # two poses must explain the views this much better than one (F, 6 and 6n-12 dof:
                        # p < 1e-7 for pure noise at 10 views; a still cell whose robot is 10x less accurate
                        # than stated, judged at the stated accuracy, reached F ~ 9; judged at the accuracy the
                        # split implies (camera_splits' robot scales) a 5 mm knock under 5x correlated corner
                        # noise is F 13.9, and no still cell of bench_claims' repeating-error arms passes 12)
SELF_CONSISTENT = 2.0   # each side's scatter within this factor (RMS) of the pooled scatter of the split
AT_NOISE = 2.0          # the two poses leave the camera's corners within this factor (RMS) of the solve's
                        # pixel sigma: a camera whose views do not fit even on their own (a wrong lens model,
                        # another target) has an error no cut in time explains
VIEW_LEVEL_PASSES = 4   # fixed-point passes for a noisy view's own level (its corner sigma about its own pose)
VIEW_LEVEL_Z = 3.0      # a view is noisy when its own fit's chi-square per dof is this many standard errors above 1
LINEARISE_AGAIN = 1e-3  # re-linearise a camera when the views' mean is this far (rad, m) from T_lin


@dataclass(frozen=True)
class ViewPoses:
    """One camera's views in capture order, each as the pose of the camera it implies: the tangent
    ``zeta`` (n, 6) at ``T_lin`` (GTSAM order, rotation first, right perturbation) and its
    information ``info`` (n, 6, 6)."""

    camera: str
    captures: np.ndarray
    zeta: np.ndarray
    info: np.ndarray
    T_lin: np.ndarray
    own_rss: np.ndarray  # (n,) each view's weighted squared residual (in sigmas) at its own best pose
    n_obs: np.ndarray  # (n,) its residual count (2 per kept corner)


@dataclass(frozen=True)
class Split:
    """The best split of one camera's views: ``k`` views before the change, the F statistic, the
    two poses (``T_before`` / ``T_after``, ref frame) with their covariances (6x6, GTSAM tangent at
    each pose), and the camera-centre displacement between them."""

    camera: str
    k: int
    captures_before: tuple
    captures_after: tuple
    f_stat: float
    glr: float
    scatter: tuple  # per-dof scatter of (one pose, before, after, the two pooled)
    T_before: np.ndarray
    T_after: np.ndarray
    cov_before: np.ndarray
    cov_after: np.ndarray
    displacement_mm: float
    rotation_deg: float
    sigma_displacement_mm: float
    rms_two_sigma: float  # RMS of the camera's corner residuals with the two poses, in pixel sigmas
    captures_back: tuple = ()  # moved and moved back: the captures after the span (``T_before`` again)
    # the views' implied poses about the two means: Gaussian log-likelihood (up to a constant), the
    # log-determinant of their information included (how :func:`camera_splits` weighs robot scales)
    log_likelihood: float = float("nan")

    @property
    def consistent(self) -> bool:
        """Each side on its own is about as consistent as the two pooled."""
        _, a, b, pooled = self.scatter
        return max(a, b) <= SELF_CONSISTENT ** 2 * max(pooled, 1e-12)

    @property
    def is_move(self) -> bool:
        return self.f_stat >= F_LIMIT and self.consistent and self.rms_two_sigma <= AT_NOISE

    @property
    def dragged(self) -> bool:
        """A move by the F test and each side's consistency whose two poses still leave the corners
        above the noise: the estimate it was judged at may be the one the mixture dragged."""
        return self.f_stat >= F_LIMIT and self.consistent and self.rms_two_sigma > AT_NOISE


def _pose(T) -> gtsam.Pose3:
    return gtsam.Pose3(np.asarray(T, float))


def _prior_centres(problem, est, captures) -> tuple[dict, object]:
    """(capture -> where the FK prior puts the robot pose, the prior's noise model builder)."""
    ks = kin.setup(problem)
    caps = problem.capture_by_index
    if ks is None:
        ref = {k: (caps[k].T_base_flange if problem.mode == "eye_to_hand" else np.linalg.inv(caps[k].T_base_flange))
               for k in captures}
        return ref, lambda T: fk_noise(problem.options, problem.mode, T)
    o = ks.full(est.joint_offsets if est.joint_offsets is not None else np.zeros(len(ks.free)))
    fk = {k: ks.chain.fk(np.asarray(ks.q_rad[k], float) + o) for k in captures}
    if problem.mode == "eye_in_hand":  # F(k) is T_flange_base: the kinematic factor's information on it
        return {k: np.linalg.inv(T) for k, T in fk.items()}, lambda T: fk_noise(problem.options, problem.mode, T)
    return fk, lambda T: fk_noise(problem.options)


def _robot_pose_terms(problem, views, est, sigma_px: float) -> tuple[dict, dict, dict]:
    """The linearised information on every robot pose F of the graph (one a configuration: a revisit
    shares its first visit's, :func:`~calibgraph.solver.terms.views.robot_keys`), at ``est``:
    (robot pose -> [prior information + views' information (6, 6), gradient (6,)],
     (camera, capture) -> (that view's information (6, 6), its gradient (6,)) on its robot pose,
     capture -> (its robot pose, the offset D of its own pose from it or None)) for the active views."""
    keys = robot_keys(problem, views)
    captures = sorted({r for r, _ in keys.values()})
    centre, noise = _prior_centres(problem, est, captures)
    per_capture, per_view = {}, {}
    for k in captures:
        T_est = est.T_ref_mount.get(k, centre[k])
        R = np.asarray(noise(centre[k]).R())
        rho = np.asarray(gtsam.Pose3.Logmap(_pose(centre[k]).between(_pose(T_est))))
        per_capture[k] = [R.T @ R, R.T @ R @ rho]
    active = [v for v in views if v.active and v.camera in est.T_ref_cam]
    for name in dict.fromkeys(v.camera for v in active):  # one camera's views at once
        mine = [v for v in active if v.camera == name]
        P, UV, _, W = pad_views(mine, est.board_scale, kept_only=True)
        sw = np.sqrt(W) / sigma_px
        T_F = np.array([est.T_ref_mount.get(v.capture, v.T_ref_mount) for v in mine])
        e, _, J_f = padded_view_residuals(est.T_ref_cam[name], T_F, est.T_mount_board, P, UV,
                                          est.camera_model(name, problem.cameras), sw)
        finite = np.isfinite(e).all(axis=1) & np.isfinite(J_f).all(axis=(1, 2))
        for i, v in enumerate(mine):  # a revisit's Jacobian on its shared robot pose: F D Exp(x) = F Exp(Ad(D) x) D
            D = keys[v.capture][1]
            if D is not None and finite[i]:
                J_f[i] = J_f[i] @ gtsam.Pose3(np.linalg.inv(D)).AdjointMap()
        H, g = J_f.transpose(0, 2, 1) @ J_f, np.einsum("vji,vj->vi", J_f, e)
        for i in np.flatnonzero(finite):
            v = mine[i]
            r = keys[v.capture][0]
            per_capture[r][0] = per_capture[r][0] + H[i]
            per_capture[r][1] = per_capture[r][1] + g[i]
            per_view[(v.camera, v.capture)] = (H[i], g[i])
    return per_capture, per_view, keys


def _view_tangents(padded: tuple, T_lin, T_F, est, intr, sigma_px, A, d, opts, passes: int = 3, T_cam=None):
    """(``sigma_px``: the views' corner sigma, a number or (V,).) Every view of one camera at once (``padded``: (points, pixels, valid) of :func:`pad_views`; ``T_F`` (V, 4, 4), ``A`` (V, 6, 6),
    ``d`` (V, 6)): (ok (V,) bool, zeta (V, 6), information (V, 6, 6), weighted squared residual in sigmas
    (V,), residual count (V,)) of the camera pose each view implies at ``T_lin``, the robot pose at
    ``T_F`` + ``d`` with information ``A`` (prior and the other cameras), each view's corners
    re-weighted against its own best fit (until its weights settle, at most ``passes`` times); ``ok``
    is False for a degenerate view."""
    P, UV, valid = padded
    V, N = valid.shape
    w = valid.astype(float)
    ok, done = np.ones(V, bool), np.zeros(V, bool)
    zeta, info, rss, n_obs = np.zeros((V, 6)), np.zeros((V, 6, 6)), np.zeros(V), np.zeros(V, int)
    for _ in range(passes):
        keep = w > 0
        ok &= done | (keep.sum(axis=1) >= 4)
        act = np.flatnonzero(ok & ~done)
        if not len(act):
            break
        sw = np.sqrt(w[act]) / np.broadcast_to(sigma_px, (V,))[act, None]
        if T_cam is None:  # the camera's pose each view implies
            e, J_c, J_f = padded_view_residuals(T_lin, T_F[act], est.T_mount_board, P[act], UV[act], intr, sw)
        else:  # the board mount's, the camera at ``T_cam``
            e, J_c, J_f = padded_view_residuals(T_cam, T_F[act], T_lin, P[act], UV[act], intr, sw, mount=True)
        finite = (np.isfinite(e).all(axis=1) & np.isfinite(J_c).all(axis=(1, 2)) & np.isfinite(J_f).all(axis=(1, 2)))
        ok[act[~finite]] = False
        act, sw, e, J_c, J_f = act[finite], sw[finite], e[finite], J_c[finite], J_f[finite]
        if not len(act):
            break
        e = e + np.einsum("vij,vj->vi", J_f, d[act])
        Ft = J_f.transpose(0, 2, 1)
        Ct = J_c.transpose(0, 2, 1)
        M = Ft @ J_f + A[act]
        Mi_FtC = np.linalg.solve(M, Ft @ J_c)
        Mi_Fte = np.linalg.solve(M, np.einsum("vji,vj->vi", J_f, e)[..., None])[..., 0]
        CtF = Ct @ J_f
        inf = Ct @ J_c - CtF @ Mi_FtC
        grad = np.einsum("vji,vj->vi", J_c, e) - np.einsum("vij,vj->vi", CtF, Mi_Fte)
        z = -np.linalg.solve(inf, grad[..., None])[..., 0]
        eps = -(Mi_Fte + np.einsum("vij,vj->vi", Mi_FtC, z))
        r = (e + np.einsum("vij,vj->vi", J_c, z) + np.einsum("vij,vj->vi", J_f, eps)).reshape(len(act), N, 2)
        k, wa = keep[act], w[act]
        norms = np.where(k, np.linalg.norm(r, axis=2) / (np.sqrt(wa) + 1e-12), 0.0)  # in sigmas, unweighted
        w_new = np.where(k, loss_weights(norms, opts.loss, opts.loss_scale), 0.0)
        w_new[norms > opts.outlier_sigmas] = 0.0
        settled = np.all(np.abs(w_new - wa) <= 0.05 + 1e-5 * np.abs(wa), axis=1)
        zeta[act], info[act], rss[act], n_obs[act] = z, inf, np.sum(r * r, axis=(1, 2)), 2 * k.sum(axis=1)
        done[act[settled]] = True
        w[act[~settled]] = w_new[~settled]
    ok &= np.isfinite(zeta).all(axis=1) & np.isfinite(info).all(axis=(1, 2))
    return ok, zeta, 0.5 * (info + info.transpose(0, 2, 1)), rss, n_obs


def view_poses(problem, name: str, views: list, est, T_lin, sigma_px: float, per_capture: dict,
               per_view: dict, keys: dict | None = None, mount: bool = False) -> ViewPoses | None:
    """Camera ``name``'s ``views`` (all of them, whatever the robust rounds made of them) as the poses
    they imply, each against the robot pose its capture gets from the FK prior and the other
    cameras' views (``per_capture`` less this camera's own terms in ``per_view``: on a configuration
    visited more than once, all of this camera's views of it). ``keys``: capture -> (its robot pose,
    offset) as :func:`_robot_pose_terms` returns them (None: every capture its own). With ``mount``, the
    poses of the board's mount the views imply (``T_lin`` then the mount's pose), the camera held at its
    estimate: a board that moved on its mount (or on the table) moves every camera's views at once."""
    intr = est.camera_model(name, problem.cameras)
    centre, noise = _prior_centres(problem, est, sorted({v.capture for v in views}))
    mine = sorted(views, key=lambda v: v.capture)
    T_F = np.array([est.T_ref_mount.get(v.capture, centre[v.capture]) for v in mine])
    A, g = np.empty((len(mine), 6, 6)), np.empty((len(mine), 6))
    keys = keys or {}
    own = {}  # robot pose -> this camera's terms on it
    for (cam, k), (H_c, g_c) in per_view.items():
        if cam == name:
            r = keys.get(k, (k, None))[0]
            a, b = own.get(r, (0.0, 0.0))
            own[r] = (a + H_c, b + g_c)
    for i, v in enumerate(mine):
        r, D = keys.get(v.capture, (v.capture, None))
        if r in per_capture:
            A_k, g_k = per_capture[r]
            H_c, g_c = own.get(r, (0.0, 0.0))
            A[i], g[i] = A_k - H_c, g_k - g_c
            if D is not None:  # on the view's own robot pose F D
                Ad = gtsam.Pose3(D).AdjointMap()
                A[i], g[i] = Ad.T @ A[i] @ Ad, Ad.T @ g[i]
        else:  # a capture no active view is in: the FK prior alone
            R = np.asarray(noise(centre[v.capture]).R())
            rho = np.asarray(gtsam.Pose3.Logmap(_pose(centre[v.capture]).between(_pose(T_F[i]))))
            A[i], g[i] = R.T @ R, R.T @ R @ rho
    d = -np.linalg.solve(A, g[..., None])[..., 0]
    shared = {}
    for k, (r, _) in keys.items():
        shared[r] = shared.get(r, 0) + 1
    rep = None
    for i, v in enumerate(mine):  # a revisit's own pose is its configuration's shared one give or take the repeatability
        if shared.get(keys.get(v.capture, (v.capture, None))[0], 0) > 1:
            if rep is None:
                o = problem.options
                rep = replace(o, fk_sigma_translation_m=o.fk_repeat_translation_m or o.fk_sigma_translation_m,
                              fk_sigma_rotation_rad=o.fk_repeat_rotation_rad or o.fk_sigma_rotation_rad)
            R = np.asarray(fk_noise(rep, problem.mode, T_F[i]).R())
            A[i] = np.linalg.inv(np.linalg.inv(A[i]) + np.linalg.inv(R.T @ R))
    padded = pad_views(mine, est.board_scale)[:3]
    sigma_v = sigma_px * np.array([v.sigma_scale for v in mine])  # each view's own corner sigma
    for _ in range(3):
        T_at = T_lin
        T_cam = est.T_ref_cam[name] if mount else None
        ok, Z, IN, rss, n_obs = _view_tangents(padded, T_lin, T_F, est, intr, sigma_v, A, d, problem.options,
                                               T_cam=T_cam)
        if ok.sum() < MIN_GROUP_VIEWS + 1:  # too few for any split
            return None
        zeta, info = Z[ok], IN[ok]
        mean = np.linalg.solve(info.sum(axis=0), np.einsum("nij,nj->i", info, zeta))
        if np.max(np.abs(mean)) < LINEARISE_AGAIN:
            break
        T_lin = (_pose(T_lin) * gtsam.Pose3.Expmap(mean)).matrix()  # the views' mean: linearise there
    # A view whose corners scatter about its own best pose beyond chance at its camera's sigma (a blurred,
    # edge-on or badly fitted board) is weighed at its own level: it says that much less on where the
    # camera stands, however far off it is. A knock's pose error is fitted away in that own fit, so a
    # knocked camera's views keep their weight. The level is shrunk towards the camera's as the final
    # graph's view_noise is, and found as a fixed point (the corners are re-weighted against the view's
    # own fit at the sigma tried); only those views are solved again.
    t = np.ones(len(mine))
    for _ in range(VIEW_LEVEL_PASSES):
        red = np.maximum(n_obs - 6.0, 1.0)
        level = shrunk_level(rss, red)
        beyond = rss / red > 1.0 + VIEW_LEVEL_Z * np.sqrt(2.0 / red)
        sel = ok & np.where(t > 1.0, np.abs(level - 1.0) > 0.05, beyond)
        if not sel.any():
            break
        t[sel] = np.maximum(t[sel] * np.sqrt(level[sel]), 1.0)
        i = np.flatnonzero(sel)
        ok_i, Z[i], IN[i], rss[i], n_obs[i] = _view_tangents(tuple(a[i] for a in padded), T_at, T_F[i], est, intr,
                                                             sigma_v[i] * t[i], A[i], d[i], problem.options,
                                                             T_cam=T_cam)
        ok[i] &= ok_i
    if ok.sum() < MIN_GROUP_VIEWS + 1:
        return None
    caps = np.array([v.capture for v in mine])[ok]
    return ViewPoses(name, caps, Z[ok], IN[ok], np.asarray(T_at), rss[ok].astype(float), n_obs[ok].astype(float))


def _fits(L: np.ndarray, e: np.ndarray, sq: np.ndarray) -> tuple:
    """(means (..., 6), residual sums (...)) of groups of views given by their summed information
    ``L`` (..., 6, 6), information-weighted tangents ``e`` (..., 6) and weighted squares ``sq`` (...)."""
    m = np.linalg.solve(L, e[..., None])[..., 0]
    return m, sq - np.einsum("...i,...i->...", e, m)


def best_split(vp: ViewPoses, min_side: int = MIN_GROUP_VIEWS, min_after: int | None = None,
               span: bool = True, at_capture: int | None = None) -> Split | None:
    """The split of ``vp``'s views in capture order that two poses explain best (None when there
    are too few views for two sides): one cut (``min_side`` views before it, ``min_after`` after
    it, default ``min_side``), or, with ``span``, a span of views that moved and moved back (at least
    ``min_side`` views in it and one on each side) when its second cut is significant on its own."""
    n = len(vp.captures)
    min_after = min_side if min_after is None else min_after
    if n < min_side + min_after:
        return None
    L, z = vp.info, vp.zeta
    eta = np.einsum("nij,nj->ni", L, z)
    s = np.einsum("ni,ni->n", z, eta)
    cL = np.concatenate([np.zeros((1, 6, 6)), np.cumsum(L, axis=0)])
    ce = np.concatenate([np.zeros((1, 6)), np.cumsum(eta, axis=0)])
    cs = np.concatenate([np.zeros(1), np.cumsum(s)])
    _, rss_one = _fits(cL[-1], ce[-1], cs[-1])
    dof_two = 6 * n - 12
    # one cut at k: views [0, k) and [k, n)
    ks = np.arange(min_side, n - min_after + 1)
    if at_capture is not None:  # the cut before that capture only
        ks = ks[ks == int(np.searchsorted(vp.captures, at_capture))]
        if not len(ks):
            return None
    _, ra = _fits(cL[ks], ce[ks], cs[ks])
    _, rb = _fits(cL[-1] - cL[ks], ce[-1] - ce[ks], cs[-1] - cs[ks])
    glr = rss_one - ra - rb
    best = int(np.argmax(glr))
    k, cut_glr = int(ks[best]), float(glr[best])
    inner = (k, n)  # the views of the second pose: [i, j)
    if span and n >= min_side + 2:
        i, j = np.triu_indices(n + 1, k=min_side)
        keep = (i >= 1) & (j <= n - 1)
        i, j = i[keep], j[keep]
        if len(i):
            L_in, e_in, s_in = cL[j] - cL[i], ce[j] - ce[i], cs[j] - cs[i]
            _, r_in = _fits(L_in, e_in, s_in)
            _, r_out = _fits(cL[-1] - L_in, ce[-1] - e_in, cs[-1] - s_in)
            g = rss_one - r_in - r_out
            b = int(np.argmax(g))
            second = (g[b] - cut_glr) / 6.0 / max((r_in[b] + r_out[b]) / dof_two, 1e-300)
            if second >= F_LIMIT:
                inner = (int(i[b]), int(j[b]))
    a, b = inner
    idx_in = np.arange(a, b)
    idx_out = np.r_[0:a, b:n]
    L_out, e_out, s_out = cL[-1] - (cL[b] - cL[a]), ce[-1] - (ce[b] - ce[a]), cs[-1] - (cs[b] - cs[a])
    ma, ra = _fits(L_out, e_out, s_out)
    mb, rb = _fits(cL[b] - cL[a], ce[b] - ce[a], cs[b] - cs[a])
    glr = float(rss_one - ra - rb)
    pooled = (ra + rb) / dof_two
    f = (glr / 6.0) / max(pooled, 1e-300)
    cov_a, cov_b = np.linalg.inv(L_out), np.linalg.inv(cL[b] - cL[a])
    T_a = (_pose(vp.T_lin) * gtsam.Pose3.Expmap(ma)).matrix()
    T_b = (_pose(vp.T_lin) * gtsam.Pose3.Expmap(mb)).matrix()
    d_m, d_deg = pose_error(T_a, T_b)
    # the camera centre's displacement and its 1-sigma along it (tangent translation is in camera axes)
    R = vp.T_lin[:3, :3]
    c_ab = R @ (mb[3:] - ma[3:])
    u = c_ab / max(np.linalg.norm(c_ab), 1e-12)
    var = float(u @ R @ (cov_a[3:, 3:] + cov_b[3:, 3:]) @ R.T @ u) * max(pooled, 1.0)
    n_out, n_in = len(idx_out), len(idx_in)
    caps = [int(c) for c in vp.captures]
    return Split(vp.camera, a, tuple(caps[:a]), tuple(caps[a:b]), float(f), glr,
                 (rss_one / (6 * n - 6), ra / max(6 * n_out - 6, 1), rb / max(6 * n_in - 6, 1), pooled),
                 T_a, T_b, cov_a, cov_b, 1e3 * d_m, d_deg, 1e3 * np.sqrt(max(var, 0.0)),
                 float(np.sqrt((vp.own_rss.sum() + ra + rb) / max(vp.n_obs.sum(), 1))), tuple(caps[b:]),
                 float(-0.5 * (ra + rb) + 0.5 * np.sum(np.linalg.slogdet(vp.info)[1])))


def camera_splits(problem, views: list, est, sigma_px: float, names, start: dict | None = None,
                  min_after: int = MIN_GROUP_VIEWS, robot_scales=(1.0,)) -> dict:
    """camera -> its best :class:`Split` for every camera of ``names`` with enough views.

    ``views``: every view of the solve (active or not; the active ones of the other cameras hold
    the robot poses); ``est``: the estimate to judge against (the robust rounds'), ``start``:
    camera -> pose to linearise a camera at that ``est`` lacks (one left out of the graph);
    ``min_after``: views after a cut (1: a move before the last view is tested too).

    ``robot_scales``: factors on the stated FK sigmas to weigh each view's robot pose with. With more
    than one, each camera is tested at the factor under which its views, split in two, are likeliest
    (their implied poses' Gaussian likelihood about the two means, the log-determinant of their
    information included): the robot's accuracy as the split itself implies it, so that neither a
    robot error is read as a move (judged at the stated accuracy) nor a move hidden in a robot error
    it inflated (judged at the accuracy the unsplit fit implies)."""
    terms = {}
    for f in robot_scales:
        scaled = problem if f == 1.0 else problem.with_(options=replace(
            problem.options, fk_sigma_translation_m=problem.options.fk_sigma_translation_m * f,
            fk_sigma_rotation_rad=problem.options.fk_sigma_rotation_rad * f))
        terms[f] = (scaled, _robot_pose_terms(scaled, views, est, sigma_px))
    out = {}
    for name in names:
        T_lin = est.T_ref_cam.get(name, (start or {}).get(name))
        mine = [v for v in views if v.camera == name]
        if T_lin is None or len(mine) < MIN_GROUP_VIEWS + min_after:
            continue
        best, best_ll = None, -np.inf
        for f, (scaled, (per_capture, per_view, keys)) in terms.items():
            split = _camera_split(scaled, name, mine, est, T_lin, sigma_px, per_capture, per_view, min_after, keys)
            if split is not None and split.dragged and name in est.intrinsics:
                # the two poses fit only at the intrinsics the solve pulled to the mixture of them: judged
                # again at the camera's given intrinsics (a wrong lens model fits no better there)
                given = replace(est, intrinsics={n: i for n, i in est.intrinsics.items() if n != name})
                again = _camera_split(scaled, name, mine, given, T_lin, sigma_px, per_capture, per_view, min_after,
                                      keys)
                split = again if again is not None and again.is_move else split
            if split is not None and (len(terms) == 1 or split.log_likelihood > best_ll):
                best, best_ll = split, split.log_likelihood
        if best is not None:
            out[name] = best
    return out


def board_split(problem, views: list, est, sigma_px: float, name: str, robot_scale: float = 1.0,
                at_capture: int | None = None) -> Split | None:
    """The best split in capture order of the board-mount poses camera ``name``'s views imply (its own pose
    held): a board moved on its mount (eye-to-hand) or on the table (eye-in-hand) at that cut. A moved
    camera's views imply one pose of it before and one after; a moved board's imply a pose of the camera
    that changes with the robot pose, and one pose of the board before and one after. ``robot_scale``: the
    factor on the stated FK sigmas, as the camera's split was judged at; ``at_capture``: only the cut before
    that capture."""
    mine = [v for v in views if v.camera == name]
    if name not in est.T_ref_cam or len(mine) < 2 * MIN_GROUP_VIEWS:
        return None
    scaled = problem if robot_scale == 1.0 else problem.with_(options=replace(
        problem.options, fk_sigma_translation_m=problem.options.fk_sigma_translation_m * robot_scale,
        fk_sigma_rotation_rad=problem.options.fk_sigma_rotation_rad * robot_scale))
    per_capture, per_view, keys = _robot_pose_terms(scaled, views, est, sigma_px)
    try:
        with np.errstate(all="ignore"):
            vp = view_poses(scaled, name, mine, est, est.T_mount_board, sigma_px, per_capture, per_view, keys,
                            mount=True)
            split = best_split(vp, span=False, at_capture=at_capture) if vp is not None else None
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        return None
    return split if split is not None and np.isfinite(split.f_stat) else None


def _camera_split(problem, name, mine, est, T_lin, sigma_px, per_capture, per_view, min_after, keys=None) -> Split | None:
    """Camera ``name``'s best split at ``est`` (see :func:`camera_splits`); None when there is none."""
    try:
        with np.errstate(all="ignore"):
            vp = view_poses(problem, name, mine, est, T_lin, sigma_px, per_capture, per_view, keys)
            split = best_split(vp, min_after=min_after) if vp is not None else None
    except (np.linalg.LinAlgError, ValueError, FloatingPointError):
        return None  # a degenerate camera (absurd intrinsics, views behind it): nothing to say about a move
    return split if split is not None and np.isfinite(split.f_stat) else None
