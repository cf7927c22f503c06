"""The factor graph of a calibration: its variables, factors, one LM run, and its marginals.

Keys (:mod:`calibgraph.solver.terms.keys`; ``ref`` is the robot base in eye-to-hand and the flange in
eye-in-hand, ``mount`` the other one, the frame the board is fixed to)::

    C(c)  T_ref_cam of camera c         -- unknown, no prior
    B(0)  T_mount_board, the board mount -- unknown, no prior ('single': one graph per camera)
    F(k)  T_ref_mount of capture k      -- prior from forward kinematics (:func:`fk_noise`)
    K(c)  [fx, fy, cx, cy, k1, k2]      -- unless the intrinsics are held: prior around the given
                                           values, as wide as their source says; a calibration
                                           file's covariance over [p1, p2 (, k3)] too adds them
    S(0)  board scale factor s          -- unless board_scale=False: prior N(1, board_scale_sigma)
    O(0)  free joint zero offsets       -- only with kinematics='joint-offsets': F(k) then has a
                                           factor to O(0) through FK(q_k + o) instead of its prior

Each view's corners are reprojection residuals through
:func:`~calibgraph.solver.terms.factors.project_chain`, in one of two formulations of the same model:
'view' (one vectorised CustomFactor per view, any OpenCV distortion) or 'corner' (one C++
projection factor per corner, :mod:`calibgraph.solver.terms.factors_ppp`, Cal3DS2 distortion only, with
the intrinsics and the board scale held). :func:`formulation` chooses.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError, ObservabilityError
from calibgraph.core.problem import Problem, intrinsics_estimated, intrinsics_prior_covariance
from calibgraph.solver.terms import factors_ppp
from calibgraph.solver.robot import kinematics as kin
from calibgraph.solver.terms.factors import ViewTerm, fk_noise, intrinsics_vector, make_view_factors, with_pinhole
from calibgraph.solver.terms.keys import B, C, F, K, O, S
from calibgraph.solver.terms.linearise import revisit_whitening
from calibgraph.solver.terms.noise_model import MODE_MIN_CORNERS, view_mode_basis
from calibgraph.solver.terms.reduced import linearise_graph
from calibgraph.solver.fit.timing import timed
from calibgraph.solver.terms.views import norms_of, reprojections, robot_keys

# The corner formulation pays off on large graphs only (see scripts/results/bench_solver.md); the
# per-view graph is the reference and the fallback.
CORNER_FORMULATION_MIN_VIEWS = 1000


@dataclass(frozen=True)
class Estimate:
    """Values of the graph's variables and, once a graph is solved, its outcome."""

    T_ref_cam: dict  # camera -> (4, 4)
    T_mount_board: np.ndarray  # (4, 4)
    T_ref_mount: dict  # capture -> (4, 4) estimated robot pose; a capture missing here starts at its FK pose
    intrinsics: dict = field(default_factory=dict)  # camera -> estimated Intrinsics (when estimated)
    board_scale: float = 1.0  # estimated scale of the printed board (1 when board_scale=False)
    joint_offsets: np.ndarray | None = None  # free joint offsets (rad) with kinematics='joint-offsets'
    wide_intrinsics: frozenset = frozenset()  # cameras whose intrinsics get the wide prior
    free_intrinsics: frozenset = frozenset()  # cameras whose given intrinsics were claimed exact but are estimated
    # outcome of a solved graph
    iterations: int = 0
    converged: bool = False  # every LM run of the final graph ended on its tolerance, the robust rounds settled
    cost: float = np.inf
    sigma_px: float = 1.0
    slots: dict = field(default_factory=dict)  # camera -> index of its C (and K) key
    formulation: str = ""  # 'view' or 'corner'
    marginals: "Marginals | None" = None  # of the final graph
    mount_cov_body: np.ndarray | None = None  # (6, 6) covariance of T_mount_board, GTSAM body frame
    mode_ratios: dict = field(default_factory=dict)  # camera -> noise_model.ModeRatio of the final graph
    fk_ratio: object | None = None  # fk_check.FkRatio of the final graph
    # the folds' jackknife of the camera poses (fk_select), when the robot departed from its stated FK:
    # {folds, jackknife_variance_factor, jackknife_per_camera}
    jackknife: dict | None = None
    graph: object | None = field(default=None, repr=False)  # the final graph and its values (error budget)
    values: object | None = field(default=None, repr=False)
    linear: object | None = field(default=None, repr=False)  # reduced.Linear of the final graph, when formed
    # (scale, 1-sigma) the board's scale was estimated at before it was held at its declared value
    # (camera_model.hold_unseparable_scale), when it was
    held_scale: tuple | None = None

    def camera_model(self, name: str, cameras: dict) -> Intrinsics:
        """The intrinsics camera ``name`` is projected with: estimated, else given (``cameras``)."""
        return self.intrinsics.get(name) or cameras[name]

    def residuals(self, views: list, cameras: dict) -> list:
        """Residuals (reprojected - detected, px, (N, 2) per view) of ``views`` at this estimate."""
        models = {v.camera: self.camera_model(v.camera, cameras) for v in views}
        uv_hats = reprojections(views, self.T_ref_cam, self.T_mount_board, self.T_ref_mount, models, self.board_scale)
        return [uv_hat - v.uv_px for v, uv_hat in zip(views, uv_hats)]

    def residual_norms(self, views: list, cameras: dict) -> list:
        """Residual norms (px) of ``views`` at this estimate (see :func:`views.residual_norms`)."""
        return norms_of(self.residuals(views, cameras))


def estimates_intrinsics(problem: Problem, name: str, est: Estimate) -> bool:
    """True when camera ``name``'s intrinsics are variables of the graph."""
    return name in est.free_intrinsics or intrinsics_estimated(problem.cameras[name], problem.options)


def intrinsics_prior(problem: Problem, name: str, est: Estimate) -> np.ndarray:
    """Covariance of the prior on camera ``name``'s intrinsics vector in this graph: over [fx, fy,
    cx, cy, k1, k2] and, for a calibration file whose covariance covers them, [p1, p2 (, k3)]."""
    wide = name in est.wide_intrinsics or name in est.free_intrinsics
    return intrinsics_prior_covariance(problem.cameras[name], problem.options, wide=wide)


def intrinsics_prior_mean(intr: Intrinsics, n: int) -> np.ndarray:
    """The mean of the prior on a camera's intrinsics vector (size ``n``): its given values; for a
    camera of unknown intrinsics, whose values were found from the same views the graph holds, only
    their focal lengths (the one scale there is, under a 10 % prior), with the principal point at the
    image centre and no distortion. Centring the prior on values found from the views would count
    those views twice, and from a few views of a small board Zhang's k1 and k2 can be wild (k2 = 97
    for a lens without distortion): a prior of 0.5 around them held k2 there, and the pose's
    Mahalanobis^2 reached 73 (scripts/results/bench_unknown_few_views_findings.md)."""
    x = intrinsics_vector(intr, n)
    if intr.known:
        return x
    x[2:4] = [(intr.width_px - 1) / 2.0, (intr.height_px - 1) / 2.0]
    x[4:] = 0.0
    return x


def intrinsics_size(problem: Problem, name: str, est: Estimate) -> int:
    """The size of camera ``name``'s intrinsics vector in this graph (6, 8 or 9; see
    :func:`intrinsics_prior`)."""
    return intrinsics_prior(problem, name, est).shape[0]


def _prior_noise(cov: np.ndarray):
    """A diagonal covariance as sigmas (as before calibration files carried correlations), else full."""
    if np.count_nonzero(cov - np.diag(np.diag(cov))) == 0:
        return gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(np.diag(cov)))
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def formulation(problem: Problem, names, n_views: int, est: Estimate | None = None) -> str:
    """Which graph to build: 'view' (per-view CustomFactor) or 'corner' (C++ factor per corner).

    'view' or 'corner' as asked ('corner' with a k3..k6 camera, estimated intrinsics, board scale or
    joint offsets is refused); 'auto' takes 'corner' when every camera fits Cal3DS2, nothing but
    poses is estimated and the graph has at least CORNER_FORMULATION_MIN_VIEWS views."""
    f = problem.options.formulation
    if problem.options.kinematics == "joint-offsets":
        if f == "corner":
            raise InputError("solver: formulation 'corner' has no kinematic factors; use 'view' or 'auto' with "
                             "--estimate-kinematics.")
        return "view"
    free = est.free_intrinsics if est is not None else frozenset()
    if any(n in free or intrinsics_estimated(problem.cameras[n], problem.options) for n in names) \
            or problem.options.board_scale:
        if f == "corner":
            raise InputError("solver: formulation 'corner' holds the intrinsics and the board's size fixed; with it, "
                             "set intrinsics='fixed' and board_scale=False (--fixed-intrinsics --fixed-board-scale).")
        return "view"
    fits = all(factors_ppp.supports(problem.cameras[n]) for n in names)
    if f == "corner" and not fits:
        raise InputError("solver: formulation 'corner' needs Cal3DS2 distortion (k1 k2 p1 p2 only); "
                         "use formulation 'view' for cameras with k3..k6.")
    if f == "auto":  # (the corner graph gives every capture its own robot pose: revisits share theirs in 'view')
        return "corner" if fits and n_views >= CORNER_FORMULATION_MIN_VIEWS and not problem.revisits else "view"
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
    ``form``: 'view' or 'corner'; ``mode_factors``: camera -> variance factor of its views' low-order
    modes (:func:`calibgraph.solver.terms.noise_model.mode_variance_ratios`; view form only).
    """
    _check_cameras_keep_views(views, slots)
    o = problem.options
    if form == "corner":
        fk = np.array([o.fk_sigma_rotation_rad] * 3 + [o.fk_sigma_translation_m] * 3)
        return factors_ppp.build(views, slots, problem, est, sigma_px, fk)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    T_ref_mount_fk = {v.capture: v.T_ref_mount for v in views}
    ks = kin.setup(problem)
    keys = robot_keys(problem, views)
    for k in sorted({r for r, _ in keys.values()}):  # one robot pose a configuration: its FK error is shared
        if ks is None:
            graph.add(gtsam.PriorFactorPose3(F(k), gtsam.Pose3(T_ref_mount_fk[k]),
                                             fk_noise(o, problem.mode, T_ref_mount_fk[k])))
        else:
            graph.add(kin.make_kinematic_factor(F(k), O(0), ks.q_rad[k], ks, fk_noise(o), problem.mode))
        values.insert(F(k), gtsam.Pose3(est.T_ref_mount.get(k, T_ref_mount_fk[k])))
    if ks is not None:
        nf = len(ks.free)
        graph.add(gtsam.PriorFactorVector(O(0), np.zeros(nf), gtsam.noiseModel.Isotropic.Sigma(nf, o.joint_offset_prior_rad)))
        values.insert(O(0), est.joint_offsets if est.joint_offsets is not None else np.zeros(nf))
    for name, i in slots.items():
        values.insert(C(i), gtsam.Pose3(est.T_ref_cam[name]))
    values.insert(B(0), gtsam.Pose3(est.T_mount_board))
    refine = {name for name in slots if estimates_intrinsics(problem, name, est)}
    n_intr = {}
    for name in refine:
        i, given = slots[name], problem.cameras[name]
        prior = intrinsics_prior(problem, name, est)
        n_intr[name] = prior.shape[0]
        graph.add(gtsam.PriorFactorVector(K(i), intrinsics_prior_mean(given, n_intr[name]), _prior_noise(prior)))
        values.insert(K(i), intrinsics_vector(est.camera_model(name, problem.cameras), n_intr[name]))
    if o.board_scale:
        graph.add(gtsam.PriorFactorVector(S(0), np.array([1.0]), gtsam.noiseModel.Isotropic.Sigma(1, o.board_scale_sigma)))
        values.insert(S(0), np.array([est.board_scale]))
    by_capture = {}
    for v in views:
        if v.active:
            by_capture.setdefault(v.capture, []).append(v)
    repeat = revisit_whitening(problem, views, est, sigma_px)
    captures = []
    for k, vs in by_capture.items():
        terms = []
        for v in vs:
            keep = v.kept
            f = (mode_factors or {}).get(v.camera, 1.0)
            modes = view_mode_basis(v.uv_px[keep]) if f > 1.0 and keep.sum() >= MODE_MIN_CORNERS else None
            terms.append(ViewTerm(C(slots[v.camera]), K(slots[v.camera]) if v.camera in refine else None,
                                  problem.cameras[v.camera], v.p_board_m[keep], v.uv_px[keep],
                                  np.sqrt(v.weight[keep]) / sigma_px, modes, f, n_intr.get(v.camera, 6),
                                  repeat.get(id(v))))
        r, D = keys[k]
        captures.append((F(r), terms, D))
    for f in make_view_factors(B(0), S(0) if o.board_scale else None, captures):
        graph.add(f)
    return graph, values


def ordering(values, form: str = "view") -> gtsam.Ordering:
    """The elimination ordering: robot poses first, then cameras, mounts and the rest. Eliminating
    each F(k) only couples the few camera poses that saw capture k, so the reduced system stays
    small (COLAMD may otherwise make the thousands of robot poses a dense block)."""
    if form == "corner":
        return factors_ppp.ordering(values)
    first, last = [], []
    for key in values.keys():
        (first if chr(gtsam.Symbol(key).chr()) == "f" else last).append(key)
    order = gtsam.Ordering()
    for key in first + last:
        order.push_back(key)
    return order


class Marginals:
    """Marginal covariances from a Bayes tree eliminated with the solver's ordering.

    gtsam.Marginals picks its own (COLAMD) ordering, which fails on the corner graph when the FK
    priors are very tight; the ordering used by LM is well conditioned for both formulations.
    """

    def __init__(self, graph, values, order):
        self._bt = graph.linearize(values).eliminateMultifrontal(order)
        self._keys = set(values.keys())

    def marginalCovariance(self, key) -> np.ndarray:  # noqa: N802 - mirrors gtsam.Marginals
        return self._bt.marginalCovariance(key)

    def has(self, key) -> bool:
        """True when ``key`` is a variable of the eliminated graph."""
        return key in self._keys

    def joint(self, keys) -> np.ndarray:
        """Joint covariance of the variables ``keys`` (Pose3: 6 rows/cols, vectors: their size), in the order given."""
        jm = self._bt.jointMarginalCovariance(list(keys))
        return np.block([[np.asarray(jm.at(a, b)) for b in keys] for a in keys])


def marginals(graph, values, form: str, timings: dict | None = None) -> Marginals:
    """Marginals of a solved graph; a singular one raises ObservabilityError with advice."""
    try:
        with timed(timings, "marginals"):
            return Marginals(graph, values, ordering(values, form))
    except RuntimeError as e:
        raise ObservabilityError(
            f"covariance could not be computed ({str(e).splitlines()[0][:120]}): the views leave a parameter "
            "undetermined; add poses with the board tilted about different axes."
        ) from None


def reduced_marginals(graph, values, timings: dict | None = None):
    """(the Schur-reduced linearisation of a solved view graph (:mod:`calibgraph.solver.terms.reduced`,
    which the error budget reads too), its marginals): one linearisation, and only the few global
    variables' covariance formed. A graph whose reduced information is not positive definite goes
    to :func:`marginals` (which refuses a singular one with advice): (None, its marginals)."""
    with timed(timings, "marginals"):
        try:
            L = linearise_graph(graph, values)
            return L, L.marginals(values.keys())
        except np.linalg.LinAlgError:
            pass
    return None, marginals(graph, values, "view", timings)


@dataclass(frozen=True)
class LMRun:
    """The outcome of one Levenberg-Marquardt run."""

    values: gtsam.Values
    iterations: int
    error: float
    converged: bool  # ended on its error tolerance, not on the iteration limit


# LM stops once the decrease the next iteration would bring, predicted from the last two
# (``d_k^2 / d_(k-1)`` while they shrink at least tenfold), is below this (GTSAM's error, 0.5 chi^2):
# the estimate is then within sqrt(2 * 1e-4) ~ 0.014 sigma (Mahalanobis, all variables together) of
# the optimum, and the iteration that would only confirm it is not run.
PREDICTED_DECREASE_TOL = 1e-4
# ... or once an undamped step (lambda at most GN_LAMBDA) decreased the error as its linearisation
# predicted to within PREDICTED_DECREASE_TOL: the quadratic model holds there, and its minimum, where
# the step went, is the optimum's to that accuracy.
GN_LAMBDA = 1e-4
# GTSAM's LevenbergMarquardtParams defaults, which the loop below follows
LAMBDA_INITIAL, LAMBDA_FACTOR, LAMBDA_MAX, MIN_MODEL_FIDELITY = 1e-5, 10.0, 1e5, 1e-3
REL_ERROR_TOL, ABS_ERROR_TOL = 1e-9, 1e-12


def _damping(values, lam: float) -> gtsam.GaussianFactorGraph:
    """LM's damping: a prior sqrt(lambda) I on every variable's tangent (GTSAM's, without diagonal damping)."""
    out = gtsam.GaussianFactorGraph()
    zero = values.zeroVectors()
    for k in values.keys():
        d = zero.at(k).shape[0]
        out.push_back(gtsam.JacobianFactor(k, np.eye(d), np.zeros(d), gtsam.noiseModel.Isotropic.Sigma(d, 1.0 / np.sqrt(lam))))
    return out


def levenberg_marquardt(graph, values, max_iterations, form: str = "view") -> LMRun:
    """One LM run with the solver's elimination ordering: GTSAM's Levenberg-Marquardt (its lambda
    policy, model-fidelity test and error tolerances), stopped too on :data:`PREDICTED_DECREASE_TOL`.

    The loop is run here, on GTSAM's linearisation and linear solver, rather than by
    ``gtsam.LevenbergMarquardtOptimizer``: inside that optimizer every Python factor's call receives a
    copy of all the values, which on a large cell costs more than the solve. A singular system
    raises ObservabilityError."""
    order = ordering(values, form)
    error, lam, iterations, last, stop = graph.error(values), LAMBDA_INITIAL, 0, None, False
    while iterations < max_iterations and not stop and np.isfinite(error):
        lin = graph.linearize(values)
        accepted, solved = None, False
        while accepted is None and lam < LAMBDA_MAX:
            damped = gtsam.GaussianFactorGraph()
            damped.push_back(lin)
            damped.push_back(_damping(values, lam))
            try:
                delta = damped.optimize(order)
                solved = True
            except RuntimeError:  # indeterminant even with this damping: damp more
                lam *= LAMBDA_FACTOR
                continue
            lin_drop = error - lin.error(delta)
            if lin_drop >= 0:
                new_values = values.retract(delta)
                new_error = graph.error(new_values)
                if lin_drop <= np.finfo(float).eps * error or (error - new_error) / lin_drop > MIN_MODEL_FIDELITY:
                    accepted = (new_values, new_error, lin_drop, lam)
                    lam = lam / LAMBDA_FACTOR
                    break
            lam *= LAMBDA_FACTOR
        iterations += 1
        if accepted is None:  # no lambda decreases the error: at the optimum (or the system is singular)
            if not solved:
                raise ObservabilityError(
                    "the calibration graph is singular: some parameter is not determined by the views: add poses "
                    "with the board tilted about different axes.")
            break
        values, new_error, lin_drop, lam_used = accepted
        drop = error - new_error
        error = new_error
        stop = drop <= ABS_ERROR_TOL or drop <= REL_ERROR_TOL * (error + drop) or (
            last is not None and drop < 0.1 * last and drop * drop / last < PREDICTED_DECREASE_TOL) or (
            lam_used <= GN_LAMBDA and abs(drop - lin_drop) < PREDICTED_DECREASE_TOL)
        last = drop
    return LMRun(values, iterations, error, bool(np.isfinite(error) and iterations < max_iterations))


def extract(values, slots, views, est: Estimate, cameras: dict, form: str = "view", problem: Problem | None = None) -> Estimate:
    """The variables held by optimised ``values`` as a new Estimate (robot poses of captures not in
    the graph kept; the solve's outcome fields are left to the caller). ``problem``: the graph's problem,
    whose revisits share a robot pose (:func:`robot_keys`); None: every capture its own."""
    if form == "corner":
        T_ref_cam, T_mount_board, T_ref_mount_new = factors_ppp.extract(values, slots, views)
        T_ref_mount = dict(est.T_ref_mount)
        T_ref_mount.update(T_ref_mount_new)
        return Estimate(T_ref_cam=T_ref_cam, T_mount_board=T_mount_board, T_ref_mount=T_ref_mount,
                        wide_intrinsics=est.wide_intrinsics, free_intrinsics=est.free_intrinsics)
    T_ref_cam = {name: values.atPose3(C(i)).matrix() for name, i in slots.items()}
    T_ref_mount = dict(est.T_ref_mount)
    keys = robot_keys(problem, views) if problem is not None else {v.capture: (v.capture, None) for v in views if v.active}
    for k, (r, D) in keys.items():
        T_ref_mount[k] = values.atPose3(F(r)).matrix() if D is None else values.atPose3(F(r)).matrix() @ D
    intr = dict(est.intrinsics)
    for name, i in slots.items():
        if values.exists(K(i)):
            intr[name] = with_pinhole(est.camera_model(name, cameras), values.atVector(K(i)))
    scale = float(values.atVector(S(0))[0]) if values.exists(S(0)) else est.board_scale
    offsets = np.asarray(values.atVector(O(0))) if values.exists(O(0)) else est.joint_offsets
    return Estimate(T_ref_cam=T_ref_cam, T_mount_board=values.atPose3(B(0)).matrix(), T_ref_mount=T_ref_mount,
                    intrinsics=intr, board_scale=scale, joint_offsets=offsets, wide_intrinsics=est.wide_intrinsics,
                    free_intrinsics=est.free_intrinsics)
