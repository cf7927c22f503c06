"""The robot's forward kinematics against its stated accuracy, judged from the fit.

A robot less accurate than stated pulls the cameras without showing in the corners' scatter. Each
capture's estimated robot pose F(k) departs from its FK prior by ``d_k`` (whitened by the prior);
under the stated FK sigmas ``sum |d_k|^2`` is about the prior's redundancy
``sum 6 - tr(Lambda_p Sigma_k)``, with ``Sigma_k = (Lambda_p + J_k)^-1`` the covariance of F(k)
given the rest (J_k: the information of capture k's views). Their ratio says by how much the
stated accuracy is off.

A robot's translation and rotation accuracy are two things (a KUKA's 0.4 mm with 0.01 deg; a
joint offset that turns the flange 0.05 deg), so they are two variance components (Helmert's
estimator): the rotation rows of ``d_k`` against their share of the redundancy
``3 - tr((R Sigma_k R^T)_rot)``, the translation rows against theirs (R the prior's square-root
information). A component is widened when its ratio is above 1 at the 0.05 level (the test is against
the stated sigmas); the widened factors are then stepped again at the widened sigmas (at most
FK_COMPONENT_STEPS times) until the fit agrees with them, since the redundancy shares of the first
step assume the stated sigmas (a translation error partly absorbed by the fitted flange rotations
raises the rotation's first ratio too). The final graph uses the FK sigmas the fit implies and a note
says so. One factor on
both put a translation error on the rotation too: on a real KUKA set (issue 38) a 4x translation
variance widened the rotation 2x beyond what the arm's rotations showed, and its predictions of
held-out poses from the reported FK were the worst of the methods compared.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.solver.robot import kinematics as kin
from calibgraph.solver.terms.keys import F
from calibgraph.solver.terms.linearise import Linearised, linearise
from calibgraph.solver.terms.reduced import linearise_graph
from calibgraph.solver.terms.noise_model import APPLY_Z, MODE_MIN_CORNERS, NOTE_Z, log_ratio_z, view_mode_basis

# A component with less redundancy than this takes the pooled factor; Helmert steps after the first.
MIN_COMPONENT_DOF = 2.0
FK_COMPONENT_STEPS = 3


@dataclass(frozen=True)
class FkComponent:
    """One variance component of the FK prior (rotation or translation): ``ratio`` ~1 when the stated
    sigma holds; ``applied``: the factor on its variance the final graph uses (the ratio when above 1
    at the 0.05 level, else 1); ``dof``: its share of the prior residuals' redundancy;
    ``significant``: p < 0.001."""

    ratio: float
    applied: float
    dof: float
    significant: bool

    @classmethod
    def of(cls, energy: float, red: float) -> "FkComponent":
        ratio = energy / red
        z = log_ratio_z(ratio, red)
        return cls(float(ratio), float(ratio) if z > APPLY_Z else 1.0, float(red), bool(z > NOTE_Z))

    def to_dict(self) -> dict:
        return {"variance_ratio": self.ratio, "applied": self.applied, "dof": self.dof, "significant": self.significant}


@dataclass(frozen=True)
class FkRatio:
    """The FK prior against the fit: ``rotation`` and ``translation`` :class:`FkComponent` (each
    widened on its own); ``ratio`` / ``dof``: both pooled (what one factor on both would say);
    ``significant``: the pooled ratio or either component's is above 1 at the 0.001 level."""

    ratio: float
    dof: float
    significant: bool
    rotation: FkComponent
    translation: FkComponent
    # which components the held-out captures chose to widen (fk_select.cross_validated_split), when it ran
    cross_validation: dict | None = None

    @property
    def applied(self) -> float:
        """The largest factor applied to either component's variance (1: the stated prior stands)."""
        return max(self.rotation.applied, self.translation.applied)

    @property
    def widens(self) -> bool:
        return self.applied > 1.0

    def to_dict(self, opts) -> dict:
        t, r = float(opts.fk_sigma_translation_m), float(opts.fk_sigma_rotation_rad)
        out = {"variance_ratio": self.ratio, "applied": self.applied, "dof": self.dof, "significant": self.significant,
               "rotation": self.rotation.to_dict(), "translation": self.translation.to_dict(),
               "stated_sigma_translation_m": t, "stated_sigma_rotation_rad": r,
               "used_sigma_translation_m": t * float(np.sqrt(self.translation.applied)),
               "used_sigma_rotation_rad": r * float(np.sqrt(self.rotation.applied))}
        if self.cross_validation is not None:
            out["cross_validation"] = dict(self.cross_validation)
            # the FK error a new pose has: a component kept at its stated sigma by the folds departs as the fit says
            def judged(c):
                return c.applied if c.applied > 1.0 else max(1.0, c.ratio)

            out["prediction_sigma_translation_m"] = t * float(np.sqrt(judged(self.translation)))
            out["prediction_sigma_rotation_rad"] = r * float(np.sqrt(judged(self.rotation)))
        return out


def _mode_weighted_information(lin: Linearised, mode_factors: dict) -> dict:
    """capture -> the information its views carry on F(k) when each view's low-order image modes
    have ``mode_factors[camera]`` times the variance of the rest (as the graph weights them)."""
    info = {k: np.zeros((6, 6)) for k in lin.captures}
    for v, keep, _e, H_f in lin.views:
        f = mode_factors.get(v.camera, 1.0)
        r = lin.robot_of[v.capture]
        if f > 1.0 and keep.sum() >= MODE_MIN_CORNERS:
            G = view_mode_basis(v.uv_px[keep]).T @ H_f
            info[r] += H_f.T @ H_f - (1.0 - 1.0 / f) * (G.T @ G)
        else:
            info[r] += H_f.T @ H_f
    return info


def fk_variance_ratio(problem: Problem, views, est, sigma_px: float, lin: Linearised | None = None,
                      mode_factors: dict | None = None, marginal: dict | None = None) -> FkRatio | None:
    """The :class:`FkRatio` of the fit at ``est`` (None when there is too little to tell). With
    kinematics='joint-offsets' the poses' departures are from FK(q + offsets), the prior the kinematic factor sets. ``lin``: :func:`linearise`
    of the same arguments, when already computed; ``mode_factors``: camera -> variance factor of its
    views' low-order image modes in the graph ``est`` was fitted on (the views then pin F(k) less);
    ``marginal``: capture -> the marginal covariance of F(k) in that graph (:func:`robot_pose_marginals`).
    Without it the redundancy takes F(k)'s covariance given the rest, which is smaller than its
    marginal (the cameras, mount and intrinsics come from the same views): the redundancy comes out
    too large and the ratio too small (about 0.8 on synthetic cells where the stated accuracy holds)."""
    lin = lin or linearise(problem, views, est, sigma_px)
    prior_at = {v.capture: v.T_ref_mount for v in views}
    if problem.options.kinematics == "joint-offsets":
        # the poses follow the joint angles through the arm with the offsets: what departs from that is the
        # arm's error the offsets do not explain (the rest of its kinematics), judged as the per-pose FK error is
        ks = kin.setup(problem)
        o = ks.full(est.joint_offsets)
        prior_at = {k: ks.chain.fk(np.asarray(ks.q_rad[k], float) + o) for k in lin.captures}
        if problem.mode == "eye_in_hand":  # F(k) is T_flange_base
            prior_at = {k: np.linalg.inv(T) for k, T in prior_at.items()}
        # F(k)'s marginal carries the offsets' uncertainty, which moves F(k) and its prior's centre together:
        # the departure's own covariance is F(k)'s given the rest (the offsets held)
        marginal = None
    weighted = _mode_weighted_information(lin, mode_factors) if mode_factors else None
    energy, red = np.zeros(2), np.zeros(2)  # [rotation, translation]
    for k, (prior, views_info, R) in lin.captures.items():
        if weighted is not None:
            views_info = weighted[k]
        T_est = est.T_ref_mount.get(k)
        if T_est is None:
            continue
        xi = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(prior_at[k]).between(gtsam.Pose3(T_est))))
        d2 = (R @ xi) ** 2  # whitened: rows 0-2 rotation, 3-5 translation (at the flange, either mode)
        cov_k = marginal[k] if marginal is not None and k in marginal else np.linalg.pinv(prior + views_info)
        w = np.diag(R @ cov_k @ R.T)  # tr(prior cov_k) split by rows: tr(R cov_k R^T)
        energy += [d2[:3].sum(), d2[3:].sum()]
        red += [3.0 - w[:3].sum(), 3.0 - w[3:].sum()]
    if red.sum() < 5.0 or energy.sum() <= 0:
        return None
    pooled = FkComponent.of(float(energy.sum()), float(red.sum()))
    # a component the views pin almost completely leaves too little to judge it by: it takes the pooled factor
    rot, trans = (FkComponent.of(float(energy[g]), float(red[g])) if red[g] >= MIN_COMPONENT_DOF and energy[g] > 0
                  else pooled for g in (0, 1))
    return FkRatio(pooled.ratio, pooled.dof, pooled.significant or rot.significant or trans.significant, rot, trans)


# the robust rounds are run again at the arm's accuracy its free robot poses imply when their pixel sigma is
# more than this many times the corners' own scatter (the whole-board misfit taken for pixel noise: a Franka's
# 12 poses 13x; correlated corner noise of 5x the variance in a 54-corner board's six modes: 1.1x) and the free
# poses depart this many times the stated variance (a robot error a few times the stated one the FK check sizes
# on its own)
RERUN_SIGMA = 2.0
RERUN_RATIO = 9.0


def high_order_level(lin: Linearised) -> float:
    """The corners' own variance, in the whitened units of ``lin``'s residuals: their mean square outside each
    view's six whole-board image modes (which a robot or camera pose error, or the corners' correlated noise,
    moves; nothing else does); 1 where the pixel sigma ``lin`` was made at is the corners' own."""
    hi, dof = 0.0, 0
    for v, keep, e, _ in lin.views:
        n = int(keep.sum())
        if n >= MODE_MIN_CORNERS + 2:
            q = view_mode_basis(v.uv_px[keep]).T @ e
            hi += float(e @ e - q @ q)
            dof += 2 * n - 6
    return hi / dof if dof >= 10 else 1.0


def free_robot_ratio(problem: Problem, views, est, sigma_px: float) -> np.ndarray:
    """How far, in variance, the arm departs from its stated FK accuracy judged with every robot pose
    refitted to its views alone (one Gauss-Newton step each, the cameras and the mount held), the
    corners' noise taken at its own level: the scatter of each view's corners outside its six whole-board
    image modes, which no pose error touches: [rotation, translation] (each at least 1, 1 where nothing departs).

    Robust rounds run at a Panda-class stated accuracy treat an arm millimetres off as pixel noise:
    the pixel sigma swells to the whole-board misfit (a Franka's 12 poses: 1.9 px against the 0.14 px its
    corners scatter), the FK check then finds the poses within their prior, and the misfit is blamed on
    the corners. The departures of the freely refitted poses against their FK prior, less what the
    corners' own noise puts in them, are the robot's error however large (a moment estimate: the FK check
    sizes it again, precisely, on the rounds run at it)."""
    lin = linearise(problem, views, est, sigma_px)
    H, g = {}, {}
    for v, keep, e, H_f in lin.views:
        r = lin.robot_of[v.capture]
        H[r] = H.get(r, 0.0) + H_f.T @ H_f
        g[r] = g.get(r, 0.0) + H_f.T @ e
    if not H:
        return np.ones(2)
    level = high_order_level(lin)  # the corners' own variance in the whitened units of e
    energy, noise, n_poses = np.zeros(2), np.zeros(2), 0
    for r, (prior, _, R) in lin.captures.items():
        if r not in H:
            continue
        C = np.linalg.pinv(H[r], rcond=1e-10)
        T_prior = next(v.T_ref_mount for v, *_ in lin.views if lin.robot_of[v.capture] == r)
        rho = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(T_prior).between(gtsam.Pose3(est.T_ref_mount.get(r, T_prior)))))
        d2 = (R @ (rho - C @ g[r])) ** 2
        w = level * np.diag(R @ C @ R.T)
        energy += [d2[:3].sum(), d2[3:].sum()]
        noise += [w[:3].sum(), w[3:].sum()]
        n_poses += 1
    if n_poses < 3:
        return np.ones(2)
    return np.maximum(1.0, (energy - noise) / (3.0 * n_poses))


def robot_pose_marginals(graph, values) -> dict | None:
    """capture -> marginal covariance (6, 6) of its robot pose F(k) in a solved view graph (from the
    Schur-reduced linearisation of :mod:`calibgraph.solver.terms.reduced`); None when it cannot be formed."""
    try:
        L = linearise_graph(graph, values)
        m = L.marginals(list(L.locals_))
    except np.linalg.LinAlgError:
        return None
    f = chr(gtsam.Symbol(F(0)).chr())
    return {int(gtsam.Symbol(key).index()): m.marginalCovariance(key) for key in L.locals_
            if chr(gtsam.Symbol(key).chr()) == f}


def settled_components(again: FkRatio) -> bool:
    """True when, judged again at the widened sigmas, neither component is off by more than its
    sampling scatter (|log ratio| below the 0.05 level) or 10 %."""
    return all(abs(np.log(max(c.ratio, 1e-12))) < max(APPLY_Z * np.sqrt(2.0 / c.dof), np.log(1.1))
               for c in (again.rotation, again.translation))


def rescaled(ratio: FkRatio, again: FkRatio) -> FkRatio:
    """``ratio`` (judged at the stated sigmas) with each widened component's factor times what the
    fit says at the widened sigmas (``again``): one more Helmert step, which may only narrow a
    component the first step over-widened, down to its stated sigma at most. Never wider than the
    first step: with few captures the views leave parts of each flange pose free, so a wider prior
    lets the poses depart further and the steps grow without end (industrial_calibration's 15-pose
    10x10 set: 1700x after 3 steps)."""
    def step(c: FkComponent, a: FkComponent) -> FkComponent:
        return c if c.applied <= 1.0 else replace(c, applied=float(np.clip(c.applied * a.ratio, 1.0, c.applied)))

    return replace(ratio, rotation=step(ratio.rotation, again.rotation),
                   translation=step(ratio.translation, again.translation))


def widened(options, ratio: FkRatio):
    """``options`` with the FK sigmas the fit implies (each component's ``applied`` times its variance)."""
    return replace(options, fk_sigma_translation_m=options.fk_sigma_translation_m * float(np.sqrt(ratio.translation.applied)),
                   fk_sigma_rotation_rad=options.fk_sigma_rotation_rad * float(np.sqrt(ratio.rotation.applied)))


def _remedy(options, joint_angles: bool) -> str:
    """What a user can do about an arm less accurate than stated: state its accuracy, and for joint
    zero offsets estimate them where the captures record joint angles (or say they must)."""
    if options.kinematics == "joint-offsets":
        offsets = "joint zero offsets are estimated already: the rest is not one the arm's zero offsets explain"
    elif joint_angles and options.kinematics == "auto":
        offsets = "joint zero offsets: see the note on them below"
    elif joint_angles:
        offsets = "joint zero offsets: --estimate-kinematics joint-offsets"
    else:
        offsets = ("joint zero offsets: --estimate-kinematics joint-offsets, which needs the joint angles "
                   "(q_rad) recorded with each capture; these captures have none")
    return f"state the arm's accuracy with --fk-sigma-mm/--fk-sigma-deg; {offsets}"


def fk_note(options, ratio: FkRatio | None, jackknife: dict | None = None, joint_angles: bool = True) -> list:
    """One line when the robot poses disagree with the stated FK accuracy and the prior was widened,
    or the folds' jackknife (``jackknife``: ``Estimate.jackknife``) widened the 1-sigma.
    ``joint_angles``: every capture records its joint angles (the joint-offset remedy is open)."""
    cv = ratio.cross_validation if ratio is not None else None
    f = float((jackknife or {}).get("jackknife_applied", 1.0))
    scatter = (f"the folds' camera poses scatter {f:.1f}x the variance the per-pose FK model gives (the arm's "
               f"error repeats from pose to pose): the pixel and FK noises x{np.sqrt(f):.2f}, each 1-sigma up to that")
    if ratio is None or not ratio.widens:
        if f <= 1.0:
            return []
        return [f"robot: the arm's error repeats from pose to pose, so every camera's 1-sigma is widened for it (by up "
                f"to {np.sqrt(f):.2f}x). Detail: the fitted flange poses departed from forward kinematics until the "
                f"corners' correlated "
                f"noise was weighted, and the robot is kept at its stated accuracy; but {scatter} "
                f"({_remedy(options, joint_angles)})"]
    o = options
    parts = []
    for c, what, stated, unit in ((ratio.translation, "translation", 1e3 * o.fk_sigma_translation_m, "mm"),
                                  (ratio.rotation, "rotation", np.degrees(o.fk_sigma_rotation_rad), "deg")):
        s = float(np.sqrt(c.ratio))
        fmt = ".2f" if unit == "mm" else ".3f"
        if c.applied > 1.0:
            test = "" if c.significant else ", p < 0.05 but not < 0.001"
            parts.append(f"{what} {s:.1f}x the stated {stated:{fmt}} {unit}{test}: solved with "
                         f"{stated * float(np.sqrt(c.applied)):{fmt}} {unit}")
        elif cv is not None and cv.get("chosen") is not None and c.ratio > 1.0:
            parts.append(f"{what} {s:.1f}x the stated {stated:{fmt}} {unit} by the fit, kept at it: held-out "
                         f"captures predicted from the reported FK better so")
        else:
            parts.append(f"{what} within the stated {stated:{fmt}} {unit} ({s:.1f}x): kept")
    if cv is not None and cv.get("chosen") is not None:
        rms = cv["rms_px"]
        parts.append(f"{cv['folds']}-fold held-out RMS {rms[cv['chosen']]:.2f} px"
                     + ("" if cv["chosen"] == "both" else f" against {rms['both']:.2f} px with both widened"))
    if f > 1.0:
        parts.append(scatter)
    return [f"robot: the arm is less accurate than stated, so every camera's 1-sigma is widened for it. Detail: "
            f"the fitted flange poses depart from forward kinematics further than the stated FK accuracy "
            f"allows ({'; '.join(parts)}); the 1-sigma is widened for it ({_remedy(options, joint_angles)})"]


def fk_record(options, ratio: FkRatio | None, jackknife: dict | None) -> dict | None:
    """result.json's ``fk_noise``: the FK check (:meth:`FkRatio.to_dict`); with the robot kept at its
    stated accuracy and no ratio measurable (the corners' correlated noise weighted), the stated
    sigmas and the folds' jackknife alone; None when neither ran."""
    if ratio is not None:
        return ratio.to_dict(options)
    if jackknife is None:
        return None
    t, r = float(options.fk_sigma_translation_m), float(options.fk_sigma_rotation_rad)
    return {"stated_sigma_translation_m": t, "stated_sigma_rotation_rad": r, "used_sigma_translation_m": t,
            "used_sigma_rotation_rad": r, "cross_validation": {"chosen": None, **jackknife}}
