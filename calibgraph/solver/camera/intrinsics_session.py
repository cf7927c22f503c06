"""Close-range intrinsics calibration of one camera from hand-held views of a board (no robot).

The stage reads top to bottom (:func:`calibrate_views`):

1. views with too few corners are set aside; initial intrinsics come from the board homographies
   (Zhang's method, OpenCV's ``calibrateCamera``), first with k1, k2 only, then the full model;
2. a view whose board pose is ambiguous (the planar pose's mirror solution, another pose more than
   ``MIRROR_APART_DEG`` away, fits its corners nearly as well: a tilted board seen from afar) is
   rejected with the reason; a board square to the camera, whose mirror solution is nearly the same
   pose, is not;
3. Levenberg-Marquardt refines every view's pose and the intrinsics (fx, fy, cx, cy and the
   model's distortion coefficients) with the view poses eliminated at each step (their Schur
   complement); a view whose residuals are far beyond the others' (RMS above
   ``REJECT_RMS_RATIO`` times the median view's) is rejected, the worst first, and the fit redone;
4. the corner noise: neighbouring corners share pixels, so each view's low-order image modes
   (shift, rotation, scale, shears) may vary more than the rest of its residuals; their variance
   factor is estimated against the rest (as the joint graph does,
   :mod:`calibgraph.solver.terms.noise_model`) and, where above 1, the views are whitened with it;
5. the a posteriori pixel sigma scales the full covariance of the intrinsics: the inverse of their
   information with the view poses eliminated;
6. coverage: where the corners fell in a grid of image cells, with one line when the board never
   reached the image corners (distortion weakly known) or was never tilted (focal length weakly known).

Every projection and Jacobian is :mod:`calibgraph.solver.camera.intrinsics_model`'s, the same model as the
joint graph (:meth:`calibgraph.core.camera.Intrinsics.project`, OpenCV's).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from calibgraph.core.camera import DIST_NAMES, Intrinsics
from calibgraph.core.errors import DetectionError, InputError, ObservabilityError
from calibgraph.core.targets import Target
from calibgraph.core.transforms import exp_so3, make_T
from calibgraph.core.version import __version__
from calibgraph.detect.dataset import dataset_detector
from calibgraph.io.files import image_size
from calibgraph.io.dataset import Dataset, View
from calibgraph.solver.camera.intrinsics_model import (
    DEFAULT_MODEL,
    intrinsics_block,
    model_parameters,
    parameter_vector,
    stored_coefficients,
    view_jacobians,
    with_parameters,
)
from calibgraph.solver.terms.noise_model import APPLY_Z, MODE_MIN_CORNERS, N_MODES, view_mode_basis

MIN_CORNERS = 6  # a view's pose takes 6 of its residuals; fewer corners leave it nothing to say
MIN_VIEWS = 6  # Zhang's method needs 3 views of a plane; a full distortion model wants more
REJECT_RMS_RATIO = 3.0  # a view whose RMS is this many times the median view's is rejected
AMBIGUITY_RATIO = 4.0  # a view whose mirror pose fits within this many times the typical RMS is ambiguous
MIRROR_APART_DEG = 5.0  # ... when that mirror is another pose: a board square to the camera has its mirror
                         # within twice its tilt (the two merge face-on), the same pose for the fit, not a trap
MIN_RMS_PX = 0.02  # floor of the typical view RMS in the tests above (perfect synthetic corners)
WEAK_TILT_DEG = 15.0  # no view tilted more than this: the focal length is weakly known
GRID_COLS = 8  # coverage cells across the image width (rows follow its aspect)
CAMERA_FILE_FORMAT = "calibgraph-camera/1"


@dataclass(frozen=True)
class SessionView:
    """One image's detected corners: ``name`` (its file), ``ids`` (n,) target point ids, ``uv_px`` (n, 2)."""

    name: str
    ids: np.ndarray
    uv_px: np.ndarray

    def __post_init__(self):
        ids = np.asarray(self.ids, int).reshape(-1)
        uv = np.asarray(self.uv_px, float).reshape(-1, 2)
        if ids.size != len(uv):
            raise InputError(f"view {self.name}: {ids.size} ids but {len(uv)} corners.")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "uv_px", uv)


@dataclass(frozen=True)
class Coverage:
    """Where the used views' corners fell.

    ``cells_fraction``: share of a ``GRID_COLS``-wide grid of image cells holding a corner;
    ``corners_reached``: which of the four corner cells ('top-left', ...) did; ``radius_fraction``:
    the largest distance of a corner from the principal point over the half diagonal;
    ``max_tilt_deg``: the largest angle between a board's normal and the optical axis (its tilt
    against the image plane, which is what tells the focal length);
    ``warnings``: one line for each weakness.
    """

    cells_fraction: float
    corners_reached: tuple
    radius_fraction: float
    max_tilt_deg: float
    warnings: tuple = ()

    def to_dict(self) -> dict:
        return {"cells_fraction": round(self.cells_fraction, 3), "image_corners_reached": list(self.corners_reached),
                "radius_fraction": round(self.radius_fraction, 3), "max_tilt_deg": round(self.max_tilt_deg, 1)}


@dataclass(frozen=True)
class SessionResult:
    """A calibrated camera.

    Attributes:
        intrinsics: the camera (``source='calibration'``) with the covariance its joint-graph prior
            uses: of [fx, fy, cx, cy, k1, k2] and the model's p1, p2 and k3 (those it estimates).
        model: the distortion model (``intrinsics_model.DISTORTION_MODELS``).
        parameter_names: the estimated parameters, rows of ``covariance``.
        covariance: their full covariance (px, unitless).
        pixel_sigma_px: a posteriori corner noise (per axis, whitened residuals).
        rms_px: RMS reprojection error of the used corners.
        views_used: names of the views in the fit.
        rejected: (name, reason) of the views left out.
        T_cam_board: name -> (4, 4) pose of each used view.
        view_rms_px: name -> RMS of each used view.
        coverage: :class:`Coverage`.
        mode_variance_ratio: the low-order corner-noise factor applied (1 = independent corners).
        iterations: Levenberg-Marquardt iterations of the final fit.
    """

    intrinsics: Intrinsics
    model: str
    parameter_names: tuple
    covariance: np.ndarray
    pixel_sigma_px: float
    rms_px: float
    views_used: tuple
    rejected: tuple
    T_cam_board: dict = field(repr=False)
    view_rms_px: dict = field(repr=False)
    coverage: Coverage = None
    mode_variance_ratio: float = 1.0
    iterations: int = 0

    @property
    def values(self) -> dict:
        """name -> value of every estimated parameter."""
        return dict(zip(self.parameter_names, parameter_vector(self.intrinsics, self.parameter_names).tolist()))

    @property
    def sigma(self) -> dict:
        """name -> 1-sigma of every estimated parameter (px, unitless)."""
        return dict(zip(self.parameter_names, np.sqrt(np.diag(self.covariance)).tolist()))

    @property
    def warnings(self) -> tuple:
        return self.coverage.warnings if self.coverage is not None else ()

    def to_dict(self, target: Target | None = None) -> dict:
        """The camera file's content (``calibgraph.io.camera_file``): what ``Intrinsics.from_dict``
        reads (image size, K, distortion, covariance with its row names, source) and the record of
        how it was found."""
        intr = self.intrinsics
        held = [n for n in DIST_NAMES[: intr.dist.size] if n not in self.parameter_names]
        d = {
            "format": CAMERA_FILE_FORMAT,
            "source": "calibration",
            "width_px": intr.width_px,
            "height_px": intr.height_px,
            "K": intr.K.tolist(),
            "distortion": {"model": self.model, "coefficients": intr.dist.tolist(),
                           "names": list(DIST_NAMES[: intr.dist.size])},
            "sigma": {n: float(v) for n, v in self.sigma.items()},
            "covariance_order": list(self.parameter_names),
            "covariance": self.covariance.tolist(),
            "rms_px": round(self.rms_px, 5),
            "pixel_sigma_px": round(self.pixel_sigma_px, 5),
            "views_used": len(self.views_used),
            "views": {"used": list(self.views_used), "rejected": {n: why for n, why in self.rejected}},
        }
        if held:
            d["distortion"]["held_at_zero"] = held
        if self.mode_variance_ratio != 1.0:
            d["corner_noise_low_order_factor"] = round(self.mode_variance_ratio, 3)
        if self.coverage is not None:
            d["coverage"] = self.coverage.to_dict()
        d["warnings"] = list(self.warnings)
        if target is not None:
            d["target"] = target.to_dict()
        d["calibgraph_version"] = __version__
        return d


# ---------------------------------------------------------------------------------------------
# initial values
# ---------------------------------------------------------------------------------------------
def _opencv_flags(model: str):
    import cv2

    return {"k1k2": cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3, "k1k2p1p2": cv2.CALIB_FIX_K3,
            "k1k2p1p2k3": 0, "rational": cv2.CALIB_RATIONAL_MODEL}[model]


def initial_intrinsics(views: list, target: Target, width_px: int, height_px: int, model: str):
    """(Intrinsics, [T_cam_board]) from Zhang's method on the views (OpenCV), k1 k2 first, then the model."""
    import cv2

    pts = target.points_board_m
    obj = [pts[v.ids].astype(np.float32) for v in views]
    img = [v.uv_px.astype(np.float32) for v in views]
    size = (int(width_px), int(height_px))
    try:
        _, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, None, None,
                                               flags=cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3)
        if model != "k1k2":
            d0 = np.zeros(8 if model == "rational" else 5)
            d0[:5] = np.asarray(dist, float).reshape(-1)[:5]
            _, K, dist, _, _ = cv2.calibrateCamera(obj, img, size, K, d0,
                                                   flags=_opencv_flags(model) | cv2.CALIB_USE_INTRINSIC_GUESS)
    except cv2.error as e:
        raise ObservabilityError(f"the views do not determine the intrinsics ({str(e).strip().splitlines()[-1][:100]}); "
                                 "tilt the board by 20-45 degrees in different directions between images.") from None
    if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0 and np.all(np.isfinite(dist))):
        raise ObservabilityError("the views do not determine the intrinsics; tilt the board by 20-45 degrees in "
                                 "different directions between images.")
    K = np.array(K, float)
    K[0, 1] = 0.0
    d = np.zeros(stored_coefficients(model))
    d[: min(d.size, np.size(dist))] = np.asarray(dist, float).reshape(-1)[: d.size]
    intr = Intrinsics(K=K, dist=d, width_px=width_px, height_px=height_px)
    poses = [_pnp(intr, pts[v.ids], v.uv_px)[0] for v in views]
    return intr, poses


def _pnp(intr: Intrinsics, p_board_m: np.ndarray, uv_px: np.ndarray):
    """(best T_cam_board, best RMS px, mirror solution's RMS px, angle between the two solutions'
    rotations in degrees) of a planar view (IPPE, both solutions)."""
    import cv2

    ok, rvecs, tvecs, _ = cv2.solvePnPGeneric(p_board_m.astype(np.float64), uv_px.astype(np.float64), intr.K,
                                                 intr.dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok or len(rvecs) == 0:
        return None, np.inf, np.inf, 0.0
    rms = []
    Ts = []
    for r, t in zip(rvecs, tvecs):
        T = make_T(exp_so3(np.asarray(r, float).reshape(3)), np.asarray(t, float).reshape(3))
        uv = intr.project(p_board_m @ T[:3, :3].T + T[:3, 3])
        rms.append(float(np.sqrt(np.nanmean(np.sum((uv - uv_px) ** 2, axis=1)))) if np.all(np.isfinite(uv)) else np.inf)
        Ts.append(T)
    order = np.argsort(rms)
    if len(rms) < 2:
        return Ts[order[0]], rms[order[0]], np.inf, 0.0
    a, b = Ts[order[0]], Ts[order[1]]
    cos = np.clip((np.trace(a[:3, :3].T @ b[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return a, rms[order[0]], rms[order[1]], float(np.degrees(np.arccos(cos)))


# ---------------------------------------------------------------------------------------------
# the fit
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Fit:
    intr: Intrinsics
    poses: list
    cost: float  # sum of whitened squared residuals (px^2)
    info: np.ndarray  # information of the intrinsics, view poses eliminated (whitened, 1/px^2 units)
    residuals: list  # (2n,) raw residual per view
    iterations: int


def _whitener(uv_px: np.ndarray, factor: float) -> np.ndarray | None:
    """W with W^T W = (I + (factor - 1) Q Q^T)^-1 for a view's low-order modes Q; None when factor is 1."""
    if factor == 1.0:
        return None
    Q = view_mode_basis(uv_px)
    return np.eye(len(Q)) + (1.0 / np.sqrt(factor) - 1.0) * (Q @ Q.T)


def _linearise(intr, names, views, poses, pts, factor):
    out = []
    cost = 0.0
    for v, T in zip(views, poses):
        uv, A, B = view_jacobians(intr, names, pts[v.ids], T)
        r = (uv - v.uv_px).reshape(-1)
        W = _whitener(v.uv_px, factor)
        rw, Aw, Bw = (r, A, B) if W is None else (W @ r, W @ A, W @ B)
        cost += float(rw @ rw)
        out.append((r, rw, Aw, Bw))
    return out, cost


def _apply(intr, names, poses, dx_i, dx_p, n_coeff):
    x = parameter_vector(intr, names) + dx_i
    new_poses = []
    for T, d in zip(poses, dx_p):
        R = exp_so3(d[:3]) @ T[:3, :3]
        new_poses.append(make_T(R, T[:3, 3] + d[3:]))
    return with_parameters(intr, names, x, n_coeff), new_poses


def refine(intr: Intrinsics, poses: list, views: list, target: Target, model: str, factor: float = 1.0,
           max_iterations: int = 100) -> _Fit:
    """Levenberg-Marquardt on every view's pose and the model's intrinsics; each step solves the
    intrinsics from the reduced system (view poses eliminated) and back-substitutes the poses."""
    names = model_parameters(model)
    pts = target.points_board_m
    n_coeff = stored_coefficients(model)
    lam = 1e-3
    lin, cost = _linearise(intr, names, views, poses, pts, factor)
    it = 0
    for it in range(1, max_iterations + 1):
        m = len(names)
        S = np.zeros((m, m))
        g = np.zeros(m)
        d_ii = np.zeros(m)
        blocks = []
        for _, rw, A, B in lin:
            d_ii += np.sum(B * B, axis=0)
            Hpp, Hpi, gp = A.T @ A, A.T @ B, A.T @ rw
            Hpp_d = Hpp + lam * np.diag(np.diag(Hpp))
            Ki = np.linalg.solve(Hpp_d, np.column_stack([Hpi, gp]))
            S += B.T @ B - Hpi.T @ Ki[:, :m]
            g += B.T @ rw - Hpi.T @ Ki[:, m]
            blocks.append(Ki)
        try:
            dx_i = -np.linalg.solve(S + lam * np.diag(d_ii), g)
        except np.linalg.LinAlgError:
            lam *= 10.0
            continue
        dx_p = [-(Ki[:, m] + Ki[:, :m] @ dx_i) for Ki in blocks]
        try:
            cand_intr, cand_poses = _apply(intr, names, poses, dx_i, dx_p, n_coeff)
            cand_lin, cand_cost = _linearise(cand_intr, names, views, cand_poses, pts, factor)
        except InputError:
            cand_cost = np.inf
        if np.isfinite(cand_cost) and cand_cost < cost:
            done = (cost - cand_cost) < 1e-12 * max(cost, 1e-30) + 1e-20
            intr, poses, lin, cost = cand_intr, cand_poses, cand_lin, cand_cost
            lam = max(lam / 10.0, 1e-9)
            if done:
                break
        else:
            lam *= 10.0
            if lam > 1e8:
                break
    info = _reduced(lin, len(names))
    return _Fit(intr, poses, cost, info, [r for r, *_ in lin], it)


def _reduced(lin, m: int) -> np.ndarray:
    S = np.zeros((m, m))
    for _, _, A, B in lin:
        Hpi = A.T @ B
        S += B.T @ B - Hpi.T @ np.linalg.solve(A.T @ A, Hpi)
    return 0.5 * (S + S.T)


def _view_rms(fit: _Fit) -> np.ndarray:
    return np.array([float(np.sqrt(np.mean(r.reshape(-1, 2) ** 2) * 2)) for r in fit.residuals])


def mode_variance_ratio(fit: _Fit, views: list, target: Target, model: str) -> tuple:
    """(ratio, z): the variance of each view's low-order image modes (shift, rotation, scale,
    shears of its corners, ``noise_model.view_mode_basis``) over that of independent corner noise,
    and the test statistic of the extra variance.

    The corner errors are modelled as ``s1 I + s2 Q Q^T`` per view. The residuals are ``r = P e``,
    P the projector off the whole fit's Jacobian; each view's pose absorbs most of its modes and the
    shared intrinsics most of what is left (the modes a pose cannot make are what the intrinsics are
    estimated from), so P is taken whole: ``I - blockdiag(M_v) - Bt S^-1 Bt^T`` with M_v the hat
    matrix of view v's pose, Bt the intrinsics' Jacobian projected off the poses and S = Bt^T Bt.
    Helmert's estimator equates ``r^T r`` and ``sum_v |Q_v^T r_v|^2`` to their expectations
    (``tr(P) s1 + tr(P QQ) s2`` and ``tr(P QQ) s1 + tr(P QQ P QQ) s2``, QQ = blockdiag(Q_v Q_v^T))
    and solves for s1, s2; ``z`` is s2 over its standard deviation when s2 = 0. ratio = 1 + s2 / s1."""
    names = model_parameters(model)
    pts = target.points_board_m
    m = len(names)
    n_res = 0.0
    q = np.zeros(2)  # the observed quadratic forms
    per_view = []
    for v, T, r in zip(views, fit.poses, fit.residuals):
        _, A, B = view_jacobians(fit.intr, names, pts[v.ids], T)
        U = np.linalg.qr(A)[0]
        Bt = B - U @ (U.T @ B)
        n_res += len(r) - 6.0
        if len(v.ids) < MODE_MIN_CORNERS:
            per_view.append((None, Bt, None))
            continue
        Q = view_mode_basis(v.uv_px)
        QU = Q.T @ U
        per_view.append((np.eye(N_MODES) - QU @ QU.T, Bt, Q.T @ Bt))
        qr_ = Q.T @ r
        q += [float(r @ r), float(qr_ @ qr_)]
    S = sum(Bt.T @ Bt for _, Bt, _ in per_view)
    try:
        Si = np.linalg.inv(S)
    except np.linalg.LinAlgError:
        return 1.0, 0.0
    t_pqq = f_pqq = 0.0
    Y = np.zeros((m, m))
    for QPQ_a, _, X in per_view:
        if X is None:
            continue
        XSX = X @ Si @ X.T
        QPQ = QPQ_a - XSX
        t_pqq += float(np.trace(QPQ))
        f_pqq += float(np.sum(QPQ * QPQ)) - float(np.sum(XSX * XSX))
        Y += X.T @ X
    f_pqq += float(np.trace(Si @ Y @ Si @ Y))  # the views' modes seen through the shared intrinsics
    N = np.array([[n_res - m, t_pqq], [t_pqq, f_pqq]])
    if f_pqq < 0.5 or np.linalg.cond(N) > 1e8:
        return 1.0, 0.0
    s1, s2 = np.linalg.solve(N, q)
    if s1 <= 0:
        return 1.0, 0.0
    # the estimator of s2 is c . q; with s2 = 0 its variance is 2 s1^2 c^T N c
    c = np.linalg.solve(N, [0.0, 1.0])
    var = 2.0 * s1 ** 2 * float(c @ N @ c)
    z = float(s2 / np.sqrt(var)) if var > 0 else 0.0
    return float(1.0 + max(s2, 0.0) / s1), z


# ---------------------------------------------------------------------------------------------
# coverage
# ---------------------------------------------------------------------------------------------
def coverage(views: list, poses: list, intr: Intrinsics, target: Target) -> Coverage:
    """Where the corners of ``views`` fell in the image, how far out and how tilted the boards were."""
    W, H = intr.width_px, intr.height_px
    cols = GRID_COLS
    rows = max(2, int(round(cols * H / W)))
    uv = np.vstack([v.uv_px for v in views])
    ci = np.clip((uv[:, 0] + 0.5) * cols / W, 0, cols - 1e-9).astype(int)
    ri = np.clip((uv[:, 1] + 0.5) * rows / H, 0, rows - 1e-9).astype(int)
    hit = np.zeros((rows, cols), bool)
    hit[ri, ci] = True
    names = {"top-left": (0, 0), "top-right": (0, cols - 1), "bottom-left": (rows - 1, 0),
             "bottom-right": (rows - 1, cols - 1)}
    reached = tuple(n for n, (r, c) in names.items() if hit[r, c])
    half_diag = 0.5 * np.hypot(W, H)
    radius = float(np.max(np.hypot(uv[:, 0] - intr.K[0, 2], uv[:, 1] - intr.K[1, 2])) / half_diag)
    # tilt against the image plane (the board's normal against the optical axis): a board square to the
    # image plane gives a homography of scale and shift wherever it is, which says nothing of the focal
    # length; against the line of sight, such a board at the image's edge read 25-40 degrees "tilted"
    tilts = [np.degrees(np.arccos(np.clip(abs(T[2, 2]), 0.0, 1.0))) for T in poses]
    max_tilt = float(max(tilts)) if tilts else 0.0
    warn = []
    if not reached:
        warn.append("the board never reached the image corners: distortion is weakly known")
    elif len(reached) < 4:
        missed = ", ".join(n for n in names if n not in reached)
        warn.append(f"the board never reached the {missed} image corner{'s' if len(reached) < 3 else ''}: "
                    "distortion there is weakly known")
    frac = float(hit.mean())
    if frac < 0.6:
        warn.append(f"the board's corners covered only {100 * frac:.0f} % of the image (cells of {W // cols}x{H // rows} px): "
                    "move it over the whole frame")
    if max_tilt < WEAK_TILT_DEG:
        warn.append(f"the board was never tilted more than {max_tilt:.0f} degrees from square to the image plane: the focal "
                    "length is weakly known; tilt it by 30-45 degrees in some images")
    return Coverage(frac, reached, radius, max_tilt, tuple(warn))


# ---------------------------------------------------------------------------------------------
# the stage
# ---------------------------------------------------------------------------------------------
def calibrate_views(views: list, target: Target, width_px: int, height_px: int, model: str = DEFAULT_MODEL,
                    min_views: int = MIN_VIEWS, rejected_before=()) -> SessionResult:
    """Calibrate one camera from its views of ``target`` (module docstring).

    Args:
        views: :class:`SessionView` per image (detected corners).
        target: the board.
        width_px, height_px: image size.
        model: distortion model (``intrinsics_model.DISTORTION_MODELS``; default k1 k2 p1 p2 k3).
        min_views: fewer usable views than this is refused.
        rejected_before: (name, reason) of images already set aside (unreadable, no board), reported
            with the views this stage rejects.
    Returns:
        :class:`SessionResult`.
    Raises:
        ObservabilityError: too few usable views, or views that do not determine the intrinsics.
    """
    names = model_parameters(model)
    rejected = list(rejected_before)
    usable = []
    for v in views:
        if len(v.ids) < MIN_CORNERS:
            rejected.append((v.name, f"only {len(v.ids)} corners (at least {MIN_CORNERS} needed)"))
        else:
            usable.append(v)
    _enough(usable, rejected, min_views)
    intr, poses = initial_intrinsics(usable, target, width_px, height_px, model)

    # ambiguous planar poses, judged at the initial intrinsics against the typical view's fit
    pnp = [_pnp(intr, target.points_board_m[v.ids], v.uv_px) for v in usable]
    typical = max(float(np.median([p[1] for p in pnp])), MIN_RMS_PX)
    keep = []
    for v, (T, rms, rms_alt, apart_deg) in zip(usable, pnp):
        if T is None:
            rejected.append((v.name, "no board pose fits its corners"))
        elif rms_alt < AMBIGUITY_RATIO * typical and apart_deg > MIRROR_APART_DEG:
            rejected.append((v.name, f"board pose ambiguous: its mirror pose fits within {rms_alt:.2f} px "
                                     f"(typical view {typical:.2f} px); tilt the board more or bring it closer"))
        else:
            keep.append((v, T))
    usable = [v for v, _ in keep]
    poses = [T for _, T in keep]
    _enough(usable, rejected, min_views)

    # fit, rejecting the worst view while one is far beyond the others
    fit = refine(intr, poses, usable, target, model)
    while True:
        rms = _view_rms(fit)
        med = max(float(np.median(rms)), MIN_RMS_PX)
        worst = int(np.argmax(rms))
        if rms[worst] <= REJECT_RMS_RATIO * med or len(usable) <= min_views:
            break
        rejected.append((usable[worst].name, f"residuals far beyond the other views' (RMS {rms[worst]:.2f} px, "
                                              f"median view {med:.2f} px)"))
        usable = usable[:worst] + usable[worst + 1:]
        fit = refine(fit.intr, fit.poses[:worst] + fit.poses[worst + 1:], usable, target, model)

    # correlated corner noise, then the a posteriori sigma and the covariance
    ratio, z = mode_variance_ratio(fit, usable, target, model)
    factor = ratio if (z > APPLY_Z and ratio > 1.0) else 1.0
    if factor != 1.0:
        fit = refine(fit.intr, fit.poses, usable, target, model, factor=factor)
    n_obs = 2 * sum(len(v.ids) for v in usable)
    dof = n_obs - 6 * len(usable) - len(names)
    if dof <= 0:
        raise ObservabilityError(f"{len(usable)} views of {target.n_points} corners leave no redundancy for the "
                                 f"{len(names)} intrinsics; add views.")
    sigma_px = float(np.sqrt(fit.cost / dof))
    try:
        cov = np.linalg.inv(fit.info) * sigma_px ** 2
    except np.linalg.LinAlgError:
        raise ObservabilityError("the views do not determine the intrinsics (singular information); tilt the board "
                                 "by 20-45 degrees in different directions and move it over the whole image.") from None
    cov = 0.5 * (cov + cov.T)
    if np.linalg.eigvalsh(cov).min() <= 0 or not np.all(np.isfinite(cov)):
        raise ObservabilityError("the views do not determine the intrinsics; tilt the board by 20-45 degrees in "
                                 "different directions and move it over the whole image.")
    intr = replace(fit.intr, source="calibration", covariance=intrinsics_block(cov, names))
    all_r = np.concatenate(fit.residuals)
    rms_px = float(np.sqrt(np.mean(all_r ** 2) * 2))
    view_rms = dict(zip((v.name for v in usable), _view_rms(fit).tolist()))
    return SessionResult(intrinsics=intr, model=model, parameter_names=names, covariance=cov, pixel_sigma_px=sigma_px,
                         rms_px=rms_px, views_used=tuple(v.name for v in usable), rejected=tuple(rejected),
                         T_cam_board={v.name: T for v, T in zip(usable, fit.poses)}, view_rms_px=view_rms,
                         coverage=coverage(usable, fit.poses, fit.intr, target), mode_variance_ratio=factor,
                         iterations=fit.iterations)


def _enough(usable: list, rejected: list, min_views: int) -> None:
    if len(usable) >= min_views:
        return
    why = ""
    if rejected:
        first = rejected[0]
        why = f"; {len(rejected)} rejected (e.g. {first[0]}: {first[1]})"
    raise ObservabilityError(f"only {len(usable)} usable view(s) of the board, at least {min_views} are needed{why}; "
                             f"take {max(min_views, 20)}-25 images with the board tilted and spread over the image.")



# ---------------------------------------------------------------------------------------------
# from image files
# ---------------------------------------------------------------------------------------------
def calibrate_images(paths: list, target: Target, model: str = DEFAULT_MODEL, min_views: int = MIN_VIEWS,
                     progress: bool = False, where: str = "the target file", workers: int = 2) -> SessionResult:
    """Detect ``target`` in every image (calibgraph's detector, sub-pixel board fit) and calibrate
    the camera from them (:func:`calibrate_views`). Images that cannot be read, show no board or
    differ in size from the first are rejected with the reason. The images are detected as a
    dataset's are (:func:`~calibgraph.detect.dataset.dataset_detector`: ``workers`` threads, a
    progress bar with ``progress``, no cache), with the same early stop on a wrong board spec
    (:mod:`calibgraph.detect.spec_check`); ``where`` names the file that declares the target.

    Raises:
        InputError: no images, none readable, or a wrong board spec (the grid the images show named).
        ObservabilityError: the board found in too few of them.
    """
    import os

    if not paths:
        raise InputError("no images given.")
    model_parameters(model)  # an unknown model is refused before any work
    paths = [Path(p) for p in paths]
    root = Path(os.path.commonpath([str(p.resolve().parent) for p in paths]))
    ds = Dataset(root=root, target=target, cameras={"camera": None}, captures=(),
                 views=tuple(View("camera", k, os.path.relpath(p.resolve(), root)) for k, p in enumerate(paths)))
    results = dataset_detector(ds, workers=workers, progress=progress, cache=False, fail_fast=True, where=where).run()
    views, rejected = [], []
    size = None
    for k, p in enumerate(paths):
        name = p.name
        det = results[("camera", k)]
        wh = None if det.unreadable else image_size(p)
        if wh is None:
            rejected.append((name, det.reason if det.unreadable else f"{p}: cannot read the image size"))
            continue
        if size is None:
            size = wh
        if wh != size:
            rejected.append((name, f"image size {wh[0]}x{wh[1]} differs from the first image's {size[0]}x{size[1]}"))
            continue
        if det.ok:
            views.append(SessionView(name, det.ids, det.uv_px))
        else:
            rejected.append((name, det.reason or "board not found"))
    if size is None:
        raise InputError(f"none of the {len(paths)} images could be read (e.g. {rejected[0][1]}).")
    if not views:
        raise ObservabilityError(f"the board was found in none of the {len(paths)} images (e.g. {rejected[0][0]}: "
                                 f"{rejected[0][1]}); check the target file (rows and cols count inner corners).")
    result = calibrate_views(views, target, size[0], size[1], model, min_views, rejected_before=rejected)
    return result
