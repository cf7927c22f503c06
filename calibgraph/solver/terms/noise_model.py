"""Corner noise: within-view correlated errors, and the pixel sigma the covariances are scaled with.

A corner's sub-pixel position is fitted to the pixels around it, and on small squares neighbouring
corners share most of those pixels (and the blur, lighting and print between them), so their errors
are positively correlated. The correlated part moves the whole board's image (a shift, rotation,
scale or shear), exactly the modes a camera's pose is estimated from, while the point-to-point
scatter, which sets the a posteriori pixel sigma, is smaller. Treating the corners as independent
then makes a far camera's 1-sigma too small.

Per camera, the variance of each view's low-order image modes is estimated against the rest of the
residuals (two variance components, Helmert's estimator in its simplest form) and, where larger,
the views are weighted and their covariance propagated accordingly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.solver.terms.linearise import Linearised, linearise

# Views with fewer kept corners leave too few residuals beside the 6 modes to compare them with.
MODE_MIN_CORNERS = 6
N_MODES = 6
# One-sided test levels on log(ratio) (its sd is sqrt(2 / dof_a + 2 / dof_b)): a variance factor is
# applied above z = 1.645 (p < 0.05) and called significant above z = 3.09 (p < 0.001).
APPLY_Z = 1.645
NOTE_Z = 3.09
# the modes' redundancy left with the robot poses free must be at least this (4 views' six modes) for the
# corners' correlated noise to be told from the robot's error (a far camera's single views leave a few
# near-degenerate directions, whose ratio is no evidence: 24x from 3 dof at 5 m with independent corners)
MIN_SEPARABLE_DOF = 24


def log_ratio_z(ratio: float, *dofs: float) -> float:
    """The one-sided test statistic of a variance ratio: log(ratio) over its sd, sqrt(sum 2 / dof) for
    the degrees of freedom of the variances compared (one when the other is the model's own)."""
    return float(np.log(max(ratio, 1e-12)) / np.sqrt(sum(2.0 / d for d in dofs)))


@dataclass(frozen=True)
class ModeRatio:
    """Low-order to remaining residual variance of one camera's views.

    ``ratio``: the estimate; ``applied``: what the final graph uses (the ratio when it is above 1 at
    the 0.05 level, else 1); ``dof_modes`` / ``dof_rest``: the residual counts behind it;
    ``significant``: above 1 at the 0.001 level; ``energy_modes_px2``: weighted squared residuals
    in the modes, summed over the views.
    """

    ratio: float
    applied: float
    dof_modes: int
    dof_rest: int
    significant: bool
    energy_modes_px2: float = 0.0
    # told apart from the robot's error (:func:`separated`): None where not judged (the robot poses held);
    # False: the excess is one the robot's own error explains as well, nothing is applied for it
    separable: bool | None = None
    with_robot_ratio: float | None = None  # the ratio with the robot poses at their FK prior, where separable is judged
    taken_as: str | None = None  # not separable: 'robot' or 'corner noise', the explanation the 1-sigma took

    def to_dict(self) -> dict:
        out = {"low_order_variance_ratio": self.ratio, "applied": self.applied, "dof_modes": self.dof_modes,
               "dof_rest": self.dof_rest, "significant": self.significant}
        if self.separable is not None:
            out["separable_from_robot"] = self.separable
            out["ratio_with_robot_poses_at_fk"] = self.with_robot_ratio
        if self.taken_as is not None:
            out["taken_as"] = self.taken_as
        return out


def separated(at_fk: dict, robot_free: dict) -> dict:
    """camera -> the corner-noise :class:`ModeRatio` the final graph applies: of the excess the modes show
    with the robot poses at their FK prior (``at_fk``), the part the robot's own error cannot explain
    (``robot_free``: :func:`mode_variance_ratios` with ``robot_free``). A camera whose excess vanishes once
    its robot poses are free (its captures each seen once, by it alone) gets nothing applied and
    ``separable`` False: the data do not tell correlated corner noise from the robot's error there, and
    the robot's error, which the FK check sizes, carries it."""
    out = {}
    for cam, m in at_fk.items():
        f = robot_free.get(cam)
        if m.applied <= 1.0:
            out[cam] = m
        elif f is not None and f.applied > 1.0 and f.dof_modes >= MIN_SEPARABLE_DOF:
            # freeing the robot poses can only take misfit away: the corners' part is at most the excess at FK
            r = min(f.ratio, m.ratio)
            out[cam] = ModeRatio(r, r, f.dof_modes, f.dof_rest, f.significant, f.energy_modes_px2, True, m.ratio)
        else:
            out[cam] = ModeRatio(m.ratio, 1.0, m.dof_modes, m.dof_rest, False, m.energy_modes_px2, False, m.ratio)
    return out


def view_mode_basis(uv_px: np.ndarray) -> np.ndarray:
    """(2n, 6) orthonormal basis of one view's low-order image modes at its corners ``uv_px`` (n, 2):
    a shift in u and v and the four linear maps about the corners' centroid (rotation, scale, the
    two shears), i.e. an affine change of the board's image; rows interleave u, v per corner as the
    view factor's residual does."""
    return view_mode_bases(np.asarray(uv_px, float)[None])[0]


def view_mode_bases(uv_px: np.ndarray) -> np.ndarray:
    """:func:`view_mode_basis` of V views of n corners each at once: ``uv_px`` (V, n, 2) -> (V, 2n, 6)."""
    c = uv_px - uv_px.mean(axis=1, keepdims=True)
    c = c / np.maximum(np.sqrt(np.mean(np.sum(c * c, axis=2), axis=1)), 1e-9)[:, None, None]
    V, n = uv_px.shape[:2]
    A = np.zeros((V, 2 * n, N_MODES))
    A[:, 0::2, 0] = 1.0
    A[:, 1::2, 1] = 1.0
    A[:, 0::2, 2], A[:, 0::2, 3] = c[..., 0], c[..., 1]
    A[:, 1::2, 4], A[:, 1::2, 5] = c[..., 0], c[..., 1]
    return np.linalg.qr(A)[0]


def mode_variance_ratios(problem: Problem, views, est, sigma_px: float, lin: Linearised | None = None,
                         robot_free: bool = False) -> dict:
    """camera -> :class:`ModeRatio`: how much more the residuals vary in each view's low-order image
    modes than in the rest.

    The estimator: the mean squared residual in the modes over their redundancy, divided by the same
    for the rest. The redundancy of a view is what the fit leaves of it: the view's robot pose F(k)
    is fitted to the views of capture k within its FK prior and absorbs much of the shift, so each
    view's share is ``tr(Q^T (I - M) Q)`` with ``M = J_F Sigma_k J_F^T`` (J_F the view's whitened
    Jacobian on F(k), Sigma_k the covariance of F(k) given the rest of the graph); the camera pose,
    mount, scale and intrinsics are shared by many views and absorb a negligible share of each.
    ~1 with independent corners (F-distributed). ``lin``: :func:`linearise` of the same arguments.

    ``robot_free``: the same with every robot pose refitted to its views alone, no FK prior (one
    Gauss-Newton step each, the rest held): what is left in the modes then is what no robot error, of
    any size, explains -- the part of the corners' correlated noise that the data tell apart from the
    robot's own error. A view whose capture no other view shares (no other camera, no revisit of its
    configuration) leaves nothing of its modes (its robot pose takes them all), so only captures seen
    more than once tell the two apart.
    """
    lin = lin or linearise(problem, views, est, sigma_px)
    per_view = [(v, keep, e, H_f) for v, keep, e, H_f in lin.views if keep.sum() >= MODE_MIN_CORNERS]
    if robot_free:
        per_view, cov = _robot_refitted(lin, per_view)
    else:
        cov = lin.robot_pose_covariances()
    terms = _mode_terms(per_view, {k: cov[r] for k, r in lin.robot_of.items() if r in cov})
    acc = {}
    for (v, _, e, _), (low, total, t_low, t_all) in zip(per_view, terms.tolist()):
        a = acc.setdefault(v.camera, np.zeros(5))
        a += [low, max(total - low, 0.0), N_MODES - t_low, len(e) - N_MODES - (t_all - t_low), low * sigma_px ** 2]
    out = {}
    for cam, (low, rest, r_low, r_rest, low_px2) in acc.items():
        n_views = sum(1 for v, *_ in per_view if v.camera == cam)
        if n_views < 5 or rest <= 0 or r_low < 1.0 or r_rest < 1.0:
            continue  # fewer than 5 views: too little to estimate a variance factor from
        ratio = (low / r_low) / (rest / r_rest)
        z = log_ratio_z(ratio, r_low, r_rest)
        out[cam] = ModeRatio(float(ratio), float(ratio) if z > APPLY_Z else 1.0, int(round(r_low)),
                             int(round(r_rest)), bool(z > NOTE_Z), float(low_px2))
    return out


def _robot_refitted(lin: Linearised, per_view: list) -> tuple[list, dict]:
    """(``per_view`` with each view's residual after its robot pose's free refit, robot pose -> the
    covariance of that refit, the pseudo-inverse of its views' information): for
    :func:`mode_variance_ratios` with ``robot_free``. Uses every view of ``lin`` on a robot pose, also
    the few left out of ``per_view``."""
    H, g = {}, {}
    for v, _, e, H_f in lin.views:
        r = lin.robot_of[v.capture]
        H[r] = H.get(r, 0.0) + H_f.T @ H_f
        g[r] = g.get(r, 0.0) + H_f.T @ e
    cov = {r: np.linalg.pinv(Hr, rcond=1e-10) for r, Hr in H.items()}
    step = {r: -cov[r] @ g[r] for r in H}
    out = [(v, keep, e + H_f @ step[lin.robot_of[v.capture]], H_f) for v, keep, e, H_f in per_view]
    return out, cov


def _mode_terms(per_view: list, cov: dict) -> np.ndarray:
    """(V, 4) per view of ``per_view`` ([(view, kept mask, e (2n,), H_f (2n, 6))]): the squared
    residual in its 6 modes ``|Q^T e|^2``, the total ``e^T e``, and the traces of M = H_f Sigma_k
    H_f^T without forming it (2n x 2n): ``tr(Q^T M Q) = <Sigma_k, G G^T>`` with ``G = H_f^T Q``, and
    ``tr(M) = <Sigma_k, H_f^T H_f>`` (``cov``: capture -> Sigma_k). Views of equal corner counts
    are taken together."""
    out = np.zeros((len(per_view), 4))
    groups = {}
    for i, (_, keep, e, _) in enumerate(per_view):
        groups.setdefault(len(e), []).append(i)
    for idx in groups.values():
        E = np.array([per_view[i][2] for i in idx])
        H = np.array([per_view[i][3] for i in idx])
        Q = view_mode_bases(np.array([per_view[i][0].uv_px[per_view[i][1]] for i in idx]))
        Sk = np.array([cov[per_view[i][0].capture] for i in idx])
        G = np.einsum("grj,gri->gji", H, Q)
        qe = np.einsum("gri,gr->gi", Q, E)
        out[idx, 0] = np.sum(qe * qe, axis=1)
        out[idx, 1] = np.sum(E * E, axis=1)
        out[idx, 2] = np.sum(Sk * np.einsum("gik,gjk->gij", G, G), axis=(1, 2))
        out[idx, 3] = np.sum(Sk * np.einsum("gri,grj->gij", H, H), axis=(1, 2))
    return out


def robust_pixel_sigma(views: list, norms: list) -> float:
    """A robust pixel sigma from the kept corners' residual norms (``norms``: (N,) per view): the
    median of a 2-D Gaussian residual norm is sqrt(2 ln 2) = 1.1774 per-axis sigmas."""
    kept = np.concatenate([r[v.kept] / v.sigma_scale for v, r in zip(views, norms)])
    return max(float(np.median(kept)) / 1.1774, 1e-3)


# A camera needs this many kept corners for its own noise level; with fewer it keeps the others'.
CAMERA_SIGMA_MIN_CORNERS = 40
# A view's own noise level is shrunk towards its camera's as if that had this many residuals, and
# kept within this range of it (beyond, the robust weights and view rejection take over).
VIEW_PRIOR_DOF = 20
VIEW_NOISE_RANGE = (1 / 3, 3.0)


def shrunk_level(sum_sq, dof):
    """A view's variance level from ``sum_sq`` (its squared residuals in units of its camera's level)
    over ``dof`` residuals, shrunk towards 1 as if the camera's level had VIEW_PRIOR_DOF of its own
    (numbers or arrays)."""
    return (VIEW_PRIOR_DOF + sum_sq) / (VIEW_PRIOR_DOF + dof)


def _high_order(v, r) -> tuple[float, int]:
    """(squared residual of view ``v``'s kept corners outside its 6 low-order image modes, its count):
    the corners' own scatter, which a pose error of the view (a knocked camera, a robot pose off)
    leaves alone, since that moves the whole board's image."""
    keep = v.kept
    n = int(keep.sum())
    if not v.active or n < MODE_MIN_CORNERS + 2:
        return 0.0, 0
    e = np.asarray(r, float)[keep].reshape(-1)
    if not np.all(np.isfinite(e)) or np.max(np.abs(e)) >= 1e5:
        return 0.0, 0
    return max(float(e @ e) - _mode_energy(v.uv_px[keep], e), 0.0), 2 * n - N_MODES


def _mode_energy(uv_px: np.ndarray, e: np.ndarray) -> float:
    """``|Q^T e|^2`` for Q = :func:`view_mode_basis` ``(uv_px)`` without forming Q: the u and the v
    residuals each projected on {1, x, y} of the centred corners (1 is orthogonal to x and y there),
    a 2x2 solve instead of a QR of (2n, 6). A view whose corners lie on a line takes the QR."""
    c = uv_px - uv_px.mean(axis=0)
    G = c.T @ c
    det = G[0, 0] * G[1, 1] - G[0, 1] * G[1, 0]
    if not det > 1e-9 * max(float(np.trace(G)), 1e-300) ** 2:
        Q = view_mode_basis(uv_px)
        q = Q.T @ e
        return float(q @ q)
    E = e.reshape(-1, 2)  # rows: (u, v) residual of each corner
    s = E.sum(axis=0)
    B = c.T @ E  # (2, 2): columns u, v
    return float(s @ s) / len(E) + float(np.sum(B * np.linalg.solve(G, B)))


def _high_order_all(views: list, residuals: list) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_high_order` of every view at once: (squared residuals outside the 6 modes (V,), their
    counts (V,)). The per-view sums (centroid, the 2x2 Gram matrix of the centred corners, the
    residuals' sums and moments) are segment sums over all the views' corners; a view whose corners
    lie on a line takes :func:`_high_order`'s QR."""
    V = len(views)
    pe, pn = np.zeros(V), np.zeros(V, int)
    idx, uv, es = [], [], []
    for i, (v, r) in enumerate(zip(views, residuals)):
        if not v.active:
            continue
        keep = v.kept
        n = int(keep.sum())
        if n < MODE_MIN_CORNERS + 2:
            continue
        idx.append(i)
        uv.append(v.uv_px[keep])
        es.append(np.asarray(r, float)[keep])
    if not idx:
        return pe, pn
    counts = np.array([len(u) for u in uv])
    w = np.repeat(np.arange(len(idx)), counts)
    E = np.concatenate(es)
    # a view with a non-finite or absurd residual (>= 1e5 px) is left out
    bad = np.bincount(w, ~(np.abs(E) < 1e5).all(axis=1), minlength=len(idx)) > 0
    if bad.any():
        good = np.flatnonzero(~bad)
        idx, uv, es = [idx[j] for j in good], [uv[j] for j in good], [es[j] for j in good]
        if not idx:
            return pe, pn
        counts = counts[good]
        w = np.repeat(np.arange(len(idx)), counts)
        E = np.concatenate(es)
    idx = np.array(idx)
    UV = np.concatenate(uv)
    m = len(idx)

    def seg(x):
        return np.bincount(w, x, minlength=m)

    c = UV - np.column_stack([seg(UV[:, 0]), seg(UV[:, 1])])[w] / counts[w, None]
    G = np.empty((m, 2, 2))
    G[:, 0, 0], G[:, 1, 1] = seg(c[:, 0] * c[:, 0]), seg(c[:, 1] * c[:, 1])
    G[:, 0, 1] = G[:, 1, 0] = seg(c[:, 0] * c[:, 1])
    B = np.empty((m, 2, 2))  # c^T E: rows x, y of the corners; columns the u, v residuals
    for a in range(2):
        for b in range(2):
            B[:, a, b] = seg(c[:, a] * E[:, b])
    s = np.column_stack([seg(E[:, 0]), seg(E[:, 1])])
    det = G[:, 0, 0] * G[:, 1, 1] - G[:, 0, 1] * G[:, 1, 0]
    ok = det > 1e-9 * np.maximum(G[:, 0, 0] + G[:, 1, 1], 1e-300) ** 2
    modes = np.zeros(m)
    if ok.any():
        X = np.linalg.solve(G[ok], B[ok])
        modes[ok] = np.sum(s[ok] * s[ok], axis=1) / counts[ok] + np.sum(B[ok] * X, axis=(1, 2))
    for j in np.flatnonzero(~ok):  # corners on a line: the basis by QR
        q = view_mode_basis(uv[j]).T @ es[j].reshape(-1)
        modes[j] = float(q @ q)
    pe[idx] = np.maximum(seg(np.sum(E * E, axis=1)) - modes, 0.0)
    pn[idx] = 2 * counts - N_MODES
    return pe, pn


def camera_noise_scales(views: list, residuals: list, per_view: bool = True) -> tuple[list, float, float]:
    """(views with each camera's ``noise_scale`` and each view's ``view_noise`` set, the largest
    relative change of a camera's scale, the largest of a view's level). ``residuals``: (N, 2)
    reprojected - detected per view.

    Cameras differ in corner noise (sensor, lens, distance, blur: a Kinect's corners scatter several
    times a close L515's); one pixel sigma for all would call the noisy camera's corners outliers
    and make its 1-sigma too small, and the quiet cameras' too wide. A camera's level is the mean
    square of its kept corners' residuals outside each view's low-order image modes (shift,
    rotation, scale, shear: what a pose error does to a small board's image), so that a camera
    whose views misfit as a whole — knocked during capture, or a robot pose off — does not pass for
    a noisy one and keep its misfitting views; its scale is that level over all cameras' pooled
    (square root). A camera with fewer than CAMERA_SIGMA_MIN_CORNERS kept corners keeps scale 1.

    Within a camera the views differ too (a far or tilted board's small squares, blur): with
    ``per_view``, each active view's level over its camera's, shrunk towards 1 as if the camera's
    level had VIEW_PRIOR_DOF residuals of its own (a view of 20 corners moves about two thirds of
    the way), and kept within VIEW_NOISE_RANGE, is its ``view_noise``. Views out of the graph keep
    1, so that a rejected view cannot earn its way back by looking noisy."""
    pe_all, pn_all = _high_order_all(views, residuals)
    tot_e = float(sum(pe_all.tolist()))  # in view order, as the per-camera sums below
    tot_n = int(pn_all.sum())
    if tot_n == 0 or tot_e <= 0:
        return views, 0.0, 0.0
    ref = tot_e / tot_n
    slot = {c: i for i, c in enumerate(dict.fromkeys(v.camera for v in views))}
    cams = list(slot)
    ci = np.array([slot[v.camera] for v in views], int)
    e_cam, n_cam = np.bincount(ci, pe_all, len(cams)), np.bincount(ci, pn_all, len(cams))
    scales, level = {}, {}
    for cam, e, n in zip(cams, e_cam, n_cam):
        level[cam] = e / n if n > 0 else 0.0
        scales[cam] = max(float(np.sqrt(level[cam] / ref)), 1e-3) if n >= CAMERA_SIGMA_MIN_CORNERS and e > 0 else 1.0
    out, change, change_view = [], 0.0, 0.0
    for v, pe, pn in zip(views, pe_all.tolist(), pn_all.tolist()):
        t = 1.0
        if per_view and pn > 0 and level[v.camera] > 0:
            ratio = pe / pn / level[v.camera]
            t = min(max(math.sqrt(shrunk_level(pn * ratio, pn)), VIEW_NOISE_RANGE[0]), VIEW_NOISE_RANGE[1])
        change = max(change, abs(scales[v.camera] / v.noise_scale - 1.0))
        change_view = max(change_view, abs(t / v.view_noise - 1.0))
        out.append(v if (v.noise_scale, v.view_noise) == (scales[v.camera], t)
                   else v.evolve(noise_scale=scales[v.camera], view_noise=t))
    return out, change, change_view


def a_posteriori_sigma(views: list, norms: list, n_parameters: int, mode_ratios: dict) -> float:
    """The a posteriori pixel sigma: weighted squared residuals over the redundancy, a view's
    low-order modes counted at 1 / their variance factor (the whitened residual). ``views``: the
    active views, ``norms`` their residual norms (px); ``n_parameters``: the graph's unknowns."""
    n_obs = 2 * sum(int(v.kept.sum()) for v in views)
    wr2 = sum(float(np.sum(v.weight * r ** 2)) for v, r in zip(views, norms))
    wr2 -= sum(m.energy_modes_px2 * (1.0 - 1.0 / m.applied) for m in mode_ratios.values())
    return max(float(np.sqrt(max(wr2, 0.0) / max(n_obs - n_parameters, 1))), 1e-4)


def corner_noise_notes(mode_ratios: dict) -> list:
    """One line per camera whose views' low-order modes were found to vary more than the rest."""
    out = []
    for name, m in mode_ratios.items():
        if m.separable is False:
            if m.taken_as is None:
                continue
            how = ("its views are weighted for correlated corner noise" if m.taken_as == "corner noise" else
                   "it is taken as the robot's error (the robot note says how large)")
            out.append(f"camera {name}: its views' images move as whole boards more than its corners scatter "
                       f"({m.with_robot_ratio:.1f}x in each view's shift, rotation, scale and shear), and these captures "
                       "cannot tell whether the robot's own error or correlated corner noise does it (each is seen once, "
                       f"by it alone, and a robot pose off moves a board's image just so): {how}, the explanation with "
                       "the larger 1-sigma; captures that revisit the same joint targets, or that a second camera sees, "
                       "would tell the two apart")
            continue
        if m.applied > 1.0:
            test = "" if m.significant else ", p < 0.05 but not < 0.001"
            out.append(f"camera {name}: its corners err together, whole boards at a time, so each of its views counts "
                       f"for less and its 1-sigma is widened for it. Detail: its residuals move whole boards (each "
                       f"view's shift, rotation, scale and shear in the image vary {m.ratio:.2f}x what the other "
                       f"residuals imply{test}: corners of small squares share pixels, or an unmodelled camera or "
                       f"robot error)")
    return out
