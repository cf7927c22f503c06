"""Which of the robot's two error components to widen, chosen by what a user meets: held-out poses
predicted from the *reported* forward kinematics.

When the fitted flange poses depart from FK further than stated in both rotation and translation
(:mod:`calibgraph.solver.robot.fk_check` widens both), the two explanations are nearly confounded in the
images: a small flange rotation moves a board's image much as a flange translation does. Helmert's
steps then split the excess by the stated ratio, and a real arm's error, which repeats from pose to
pose rather than being independent, need not follow that split. The split changes the calibration a
user applies with the reported poses (RWHE-Calib's KUKA sets: both widened, 0.21-0.43 mm and about
0.04 deg, predicted held-out poses 2-29 % worse than with the rotation kept at its stated accuracy;
scripts/results/bench_heldout.md).

So the candidates -- both components widened (Helmert's answer), only the translation, only the
rotation -- are cross-validated: the captures are dealt into :data:`FOLDS` folds; for each fold the
graph of the other captures is solved (from the current estimate) and the fold's kept corners are
predicted from the fold's reported FK (:meth:`Estimate.residuals` with no fitted robot poses), as the
calibration is applied. The candidate with the smallest held-out RMS is used unless it is within
:data:`TIE` of Helmert's (with the FK errors independent from pose to pose, as the model assumes, the
candidates tie and Helmert's split stands). Skipped (Helmert's answer kept) with too few captures
to hold any out, or when a fold would leave a camera with too few views.

The same folds say how far the 1-sigma can be trusted: :func:`jackknife_factor` compares the
scatter of the chosen candidate's fold solves with the graph's covariance, and the final graph's
noises take the variance factor the model lacks (``optimise.final_graph``). Where the robot departed
from its FK but no split was cross-validated (one component widened, or the corners' correlated noise
explained the departure and the robot was kept at its stated accuracy), :func:`jackknife_folds` solves
the folds of the final graph for the jackknife alone. The simulator's joint
zero offsets, an error that repeats from pose to pose and is not modelled without
``--estimate-kinematics``: camera error / 1-sigma RMS 2.3-3.7 -> 1.3-2.7 (3 seeds, 30 and 60
captures, eye-to-hand).
"""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np

from calibgraph.core.errors import ObservabilityError
from calibgraph.core.problem import configuration_folds
from calibgraph.solver.robot.fk_check import widened
from calibgraph.solver.terms.noise_model import APPLY_Z, log_ratio_z

FOLDS = 5
# within this fraction of Helmert's held-out RMS the candidates predict alike and Helmert's split stands
# (robots whose errors are independent from pose to pose: 0.01-0.3 % apart in the simulator; the KUKA
# sets' repeating errors: 2-23 %)
TIE = 0.005
# each fold must leave every camera at least this many views (and the solver's own minimum)
MIN_VIEWS_LEFT = 3
# the jackknife of a set of fewer than 2 FOLDS configurations holds out one at a time, from this many on
MIN_LEAVE_ONE_OUT = 6


def _folds(problem, views: list, min_views: int, small: bool = False) -> list | None:
    """FOLDS sets of capture indices (the configurations dealt in capture order, a revisit in its
    configuration's fold: :func:`~calibgraph.core.problem.configuration_folds`), or None when holding
    one out would leave a camera below ``min_views`` active views or a fold empty. With ``small``, a set of
    fewer than 2 FOLDS configurations (but at least :data:`MIN_LEAVE_ONE_OUT`) is held out one
    configuration at a time (the jackknife of 8 ViSP poses)."""
    active = {v.capture for v in views if v.active}
    config = problem.configurations
    n_conf = len({config.get(k, k) for k in active})
    if n_conf < 2 * FOLDS and not (small and n_conf >= MIN_LEAVE_ONE_OUT):
        return None
    n_folds = FOLDS if n_conf >= 2 * FOLDS else n_conf
    folds = [f & active for f in configuration_folds([problem.capture_by_index[c] for c in active], n_folds)]
    cams = {v.camera for v in views if v.active}
    for fold in folds:
        for cam in cams:
            if sum(1 for v in views if v.active and v.camera == cam and v.capture not in fold) < min_views:
                return None
    return folds


def _min_views(problem) -> int:
    return max(MIN_VIEWS_LEFT, int(problem.options.min_views_per_camera))


def _held_out(views: list, fold: set) -> list:
    return [replace(v, active=False, reason="held out (FK split cross-validation)") if v.capture in fold and v.active
            else v for v in views]


def cross_validated_split(problem, stated_opts, ratio, views: list, est, resolve) -> tuple:
    """(the FkRatio to use, the chosen candidate's fold estimates (one :class:`Estimate` per fold) or
    None). When the folds ran, the ratio's ``cross_validation`` holds their record; otherwise it is
    ``ratio`` itself.

    ``problem``: the problem at the widened FK sigmas; ``stated_opts``: the options with the stated
    ones; ``ratio``: Helmert's :class:`~calibgraph.solver.robot.fk_check.FkRatio`; ``est``: the estimate
    at ``ratio``; ``resolve(problem, views, est) -> Estimate`` solves a graph from ``est``."""
    if not (ratio.rotation.applied > 1.0 and ratio.translation.applied > 1.0):
        return ratio, None
    folds = _folds(problem, views, _min_views(problem))
    if folds is None:
        return ratio, None
    candidates = {
        "both": ratio,
        "translation": replace(ratio, rotation=replace(ratio.rotation, applied=1.0)),
        "rotation": replace(ratio, translation=replace(ratio.translation, applied=1.0)),
    }
    rms, fold_est, per_capture = {}, {}, {}
    for name, cand in candidates.items():
        p = problem.with_(options=widened(stated_opts, cand))
        sse, n = {}, 0
        fold_est[name] = []
        try:
            for fold in folds:
                e = resolve(p, _held_out(views, fold), est)
                fold_est[name].append(e)
                test = [v for v in views if v.active and v.capture in fold]
                for v, r in zip(test, replace(e, T_ref_mount={}).residuals(test, problem.cameras)):
                    k = v.kept
                    sse[v.capture] = sse.get(v.capture, 0.0) + float(np.sum(r[k] ** 2))
                    n += int(k.sum())
        except (ObservabilityError, RuntimeError, np.linalg.LinAlgError):
            return ratio, None
        per_capture[name] = sse
        rms[name] = float(np.sqrt(sum(sse.values()) / max(n, 1)))
    # how clearly the captures prefer each candidate to Helmert's split (reported, not a gate: a gate at
    # 2 standard errors let some train sets of one arm switch and others not, which scattered the
    # calibration across sets more than either split did; the captures' misses are heavy-tailed)
    caps = sorted(per_capture["both"])
    t_stat = {}
    for name in ("translation", "rotation"):
        d = np.array([per_capture[name][k] - per_capture["both"][k] for k in caps])
        se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
        t_stat[name] = float(np.mean(d) / se) if se > 0 else 0.0
    best = min(rms, key=rms.get)
    chosen = best if rms[best] < (1.0 - TIE) * rms["both"] else "both"
    record = {"folds": FOLDS, "rms_px": rms, "t_vs_both": t_stat, "chosen": chosen}
    return replace(candidates[chosen], cross_validation=record), fold_est[chosen]


def jackknife_folds(problem, views: list, est, resolve) -> list | None:
    """The fold solves of the jackknife alone (one :class:`Estimate` per fold), for a graph whose robot
    departed from its stated FK but whose split was not cross-validated (only one component widened,
    or the robot judged as stated once the corners' correlated noise was weighted): the per-pose
    model's covariance is then as much in question as when both widen. None when the folds cannot
    be made or a fold cannot be solved."""
    folds = _folds(problem, views, _min_views(problem), small=True)
    if folds is None:
        return None
    try:
        return [resolve(problem, _held_out(views, fold), est) for fold in folds]
    except (ObservabilityError, RuntimeError, np.linalg.LinAlgError):
        return None


def jackknife_applied(factor: float, folds: int, robot_widened: bool) -> float:
    """The variance factor the 1-sigma takes. With the robot's FK prior widened (the FK check found its
    errors beyond the per-pose model's), the model is known to be wrong and the folds' ``factor`` (at
    least 1) is the best measure of how far. With the robot kept at its stated accuracy, only when the
    folds' scatter exceeds the graph's covariance beyond chance (the FK check's one-sided test on its
    log, with one camera's 6 (K-1) degrees of freedom: cameras share the robot, so their factors are not
    independent), else 1: with the model right a camera's factor is 0.4-1.7 (correlated corner noise,
    three cameras, three seeds), and a 1-sigma widened by chance would be blamed on the robot."""
    if robot_widened:
        return max(1.0, float(factor))
    return float(factor) if log_ratio_z(factor, 6.0 * (folds - 1)) > APPLY_Z else 1.0


def jackknife_factor(est, fold_est: list, cov_of) -> tuple:
    """(factor, per camera): how far the fold solves' camera poses scatter beyond the graph's covariance.

    Each fold's solve leaves out 1/FOLDS of the captures: the delete-group jackknife variance of a
    camera pose is ``(K-1)/K sum_k d_k d_k^T`` (``d_k``: fold k's pose against the full solve's,
    in its body frame, about the folds' mean), which under the model's independent FK errors matches the graph's marginal
    ``cov_of(camera)`` (GTSAM's, the same frame): ``tr(cov^-1 V_J) / 6`` is about 1. A robot error that repeats
    from pose to pose makes the estimate move more from one set of captures to another than the
    per-pose FK prior implies; the factor (the mean over cameras, at least 1) is then the variance
    the 1-sigma lacks."""
    K = len(fold_est)
    per = {}
    for name, T in est.T_ref_cam.items():
        d = np.array([gtsam.Pose3(T).localCoordinates(gtsam.Pose3(e.T_ref_cam[name])) for e in fold_est
                      if name in e.T_ref_cam])
        if len(d) != K:
            continue
        d = d - d.mean(axis=0)  # about the folds' mean: the full solve's small offset from them is not scatter
        V = (K - 1) / K * d.T @ d
        try:
            per[name] = float(np.trace(np.linalg.solve(cov_of(name), V)) / 6.0)
        except np.linalg.LinAlgError:
            continue
    if not per:
        return 1.0, per
    return max(1.0, float(np.mean(list(per.values())))), per
