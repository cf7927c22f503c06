"""Has a camera moved since it was calibrated? A chi-square test against the stored covariance.

Given a stored calibration (a :class:`~calibgraph.solver.output.result.Result`, ``calibgraph.load_result``)
and a short fresh capture of the same cameras and target, every camera that sees the
board is re-estimated from the new views alone, with everything else held at the stored estimate:
the board mount ``T_flange_board``, the camera's intrinsics and the board scale. The robot poses
``F(k)`` keep their forward-kinematics prior (they are variables, as in the calibration)::

    C(c)  T_base_cam of camera c, new estimate      -- starts at the stored pose, no prior
    F(k)  T_base_flange of capture k                -- FK prior (SolverOptions fk sigmas)

    corner residual  = project(T_base_cam^-1 . T_base_flange[k] . T_flange_board . s p_board) - uv,
                       weighted by the stored pixel sigma (the detector noise of the calibration)

The difference of the new and the stored pose, in base axes as the stored covariance is,

    d = [log(R_new R_stored^T), t_new - t_stored]            (6,: rad, m)
    m2 = d^T (Sigma_stored + Sigma_new)^-1 d                 ~ chi-square, 6 dof, when nothing moved

and the camera is called *moved* when ``P(chi2_6 > m2) < alpha`` (default 0.001 per camera).
Treating the two estimates as independent ignores that the new one reuses the stored mount and
intrinsics, whose errors are correlated with the stored camera pose; the test is then
conservative (false alarms below ``alpha``). ``scripts/bench_verify.py`` measures the rate.

When every camera seen (two or more) is found moved, the common explanation is tested: the board
mount is re-estimated with every camera held at its stored pose, and if the cameras then all pass
the test again, the verdict is that the board mount (or the robot's kinematics) changed, not the
cameras.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import gtsam
import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.problem import Problem
from calibgraph.core.targets import Target
from calibgraph.core.transforms import log_so3
from calibgraph.solver.uncertainty.covariance import to_ref_axes
from calibgraph.solver.terms.factors import fk_noise
from calibgraph.solver.terms.views import MIN_CORNERS_PER_VIEW
from calibgraph.solver.terms.factors import make_calibration_factor, view_residual
from calibgraph.solver.terms.keys import B, C, F, S
from calibgraph.solver.robot.kinematics import stored_arm
from calibgraph.solver.output.result import Result, as_result, solved_target, target_differences

__all__ = ["CameraCheck", "VerifyResult", "verify", "chi2_sf_6", "chi2_isf_6", "stored_model", "StoredModel",
           "check_fresh_data"]

DEFAULT_ALPHA = 1e-3
OUTLIER_SIGMAS = 5.0
VERDICTS = ("unchanged", "cameras_moved", "mount_or_robot_moved")


def chi2_sf_6(x: float) -> float:
    """P(chi-square with 6 dof > x), closed form: exp(-x/2) (1 + x/2 + x^2/8)."""
    h = max(float(x), 0.0) / 2.0
    return float(np.exp(-h) * (1.0 + h + h * h / 2.0))


def chi2_isf_6(p: float) -> float:
    """x with P(chi2_6 > x) = p (bisection on :func:`chi2_sf_6`)."""
    lo, hi = 0.0, 200.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if chi2_sf_6(mid) > p else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class StoredModel:
    """What a stored result says about the cell (eye-to-hand, joint): per camera ``T_base_cam``
    (4, 4), ``covariance`` (6, 6, rotation first, base axes) and ``intrinsics`` (the estimate);
    the board mount, the board scale and the pixel sigma of the calibration."""

    T_base_cam: dict
    covariance: dict
    intrinsics: dict
    T_flange_board: np.ndarray
    board_scale: float
    pixel_sigma_px: float
    mount_covariance: np.ndarray  # (6, 6), rotation first, flange axes
    board_scale_sigma: float


def stored_model(result: Result, where: str = "result") -> StoredModel:
    """:class:`StoredModel` of a stored :class:`~calibgraph.solver.output.result.Result` (a result dict is
    converted)."""
    result = as_result(result, where)
    if result.mode != "eye_to_hand" or result.T_mount_board is None:
        raise InputError(f"{where}: verify needs an eye-to-hand result with one board mount (method 'joint'); "
                         f"this one is mode={result.mode!r}, method={result.method!r}.")
    intr = {}
    for name, c in result.calibrated.items():
        intr[name] = c.solved_intrinsics
        if intr[name] is None:
            raise InputError(f"{where}: camera {name!r} has no intrinsics (a result written by an older calibgraph); "
                             "solve the calibration again with this calibgraph.")
    if not result.pixel_sigma_px > 0:
        raise InputError(f"{where}: no pixel sigma in 'solver'; re-solve the calibration with this calibgraph.")
    mount_cov = result.mount_covariance if result.mount_covariance is not None else np.diag([1e-16] * 6)
    return StoredModel({n: c.T_ref_cam for n, c in result.calibrated.items()},
                       {n: c.covariance for n, c in result.calibrated.items()}, intr, result.T_mount_board,
                       result.board_scale, result.pixel_sigma_px, mount_cov, result.board_scale_sigma or 0.0)


def check_fresh_data(result: Result, cameras, target: Target | None = None, where: str = "result") -> list:
    """Refuse fresh data that does not belong to the stored ``result``: a camera it does not know
    (a renamed one would otherwise be ignored and the rest called unchanged) or a target spec
    other than the one the result was solved with (which would make every camera look moved).
    Returns notes on what could not be checked."""
    result = as_result(result, where)
    stored, fresh = set(result.cameras), set(cameras)
    unknown, absent = sorted(fresh - stored), sorted(stored - fresh)
    if unknown:
        raise InputError(f"verify: camera(s) {', '.join(unknown)} of the fresh data are not in the stored result {where} "
                         f"(its cameras: {', '.join(sorted(stored))})"
                         + (f"; {', '.join(absent)} of the result are not in the fresh data: was a camera renamed?"
                            if absent else "")
                         + " Use the camera names of the calibration (or remove the new camera from dataset.yaml).")
    notes = [f"{n} was not calibrated in the stored result ({result.cameras[n].why}): not verified"
             for n in sorted(fresh & set(result.not_calibrated))]
    if target is None:
        return notes
    solved = solved_target(result)
    if solved is None:
        return notes + ["the target the result was solved with is unknown (it does not record it and its dataset is "
                        "gone): make sure the fresh data declares the same board"]
    differ = target_differences(solved, target)
    if differ:
        raise InputError(f"verify: the fresh data's target differs from the one {where} was solved with: "
                         f"{'; '.join(differ)}. Declare the calibration's target (a different board makes every camera "
                         "look moved), or calibrate again with the new one.")
    return notes


@dataclass(frozen=True)
class CameraCheck:
    """The test of one camera.

    ``status``: 'moved', 'unchanged' or 'not_seen'. ``d`` (6,): new minus stored, rotation vector
    (rad) then translation (m), base axes; ``covariance`` (6, 6): Sigma_stored + Sigma_new;
    ``mahalanobis2`` and ``p_value`` of the chi-square test; ``displacement_mm`` / ``rotation_deg``
    with their 1-sigma along the displacement (or rotation) direction."""

    name: str
    status: str
    views: int = 0
    corners: int = 0
    d: np.ndarray | None = None
    covariance: np.ndarray | None = None
    mahalanobis2: float = float("nan")
    p_value: float = float("nan")
    displacement_mm: float = float("nan")
    sigma_displacement_mm: float = float("nan")
    rotation_deg: float = float("nan")
    sigma_rotation_deg: float = float("nan")
    rms_px: float = float("nan")
    T_base_cam_new: np.ndarray | None = None

    def to_dict(self) -> dict:
        out = {"status": self.status, "views": self.views, "corners": self.corners}
        if self.d is not None:
            out.update({
                "displacement_mm": self.displacement_mm, "sigma_displacement_mm": self.sigma_displacement_mm,
                "rotation_deg": self.rotation_deg, "sigma_rotation_deg": self.sigma_rotation_deg,
                "translation_mm_xyz": (self.d[3:] * 1e3).tolist(),
                "rotation_deg_xyz": np.degrees(self.d[:3]).tolist(),
                "mahalanobis2": self.mahalanobis2, "p_value": self.p_value, "rms_px": self.rms_px,
                "T_base_cam_new": self.T_base_cam_new.tolist(),
            })
        return out


@dataclass(frozen=True)
class VerifyResult:
    """Per-camera checks and the cell's verdict ('unchanged', 'cameras_moved' or
    'mount_or_robot_moved'), with the test's settings and notes."""

    cameras: dict
    verdict: str
    alpha: float
    pixel_sigma_px: float
    notes: tuple = ()
    mount_change: np.ndarray | None = field(default=None, repr=False)  # (6,) when the mount was re-fitted

    @property
    def moved(self) -> list:
        return [n for n, c in self.cameras.items() if c.status == "moved"]

    @property
    def anything_moved(self) -> bool:
        return self.verdict != "unchanged"

    def to_dict(self) -> dict:
        d = {"format": "calibgraph-verify/1", "verdict": self.verdict, "alpha_per_camera": self.alpha,
             "threshold_mahalanobis2": chi2_isf_6(self.alpha), "pixel_sigma_px": self.pixel_sigma_px,
             "moved": self.moved, "cameras": {n: c.to_dict() for n, c in self.cameras.items()},
             "notes": list(self.notes)}
        if self.mount_change is not None:
            d["mount_change"] = {"rotation_deg_xyz": np.degrees(self.mount_change[:3]).tolist(),
                                 "translation_mm_xyz": (self.mount_change[3:] * 1e3).tolist()}
        return d


@dataclass
class _View:
    camera: str
    capture: int
    p_board_m: np.ndarray  # (N, 3), as declared (the board scale is a variable)
    uv_px: np.ndarray  # (N, 2)
    keep: np.ndarray  # (N,) bool


def _body_cov(T: np.ndarray, cov_ref: np.ndarray) -> np.ndarray:
    """Reference-axes pose covariance -> GTSAM's body frame (inverse of batch.to_ref_axes)."""
    G = np.zeros((6, 6))
    G[:3, :3] = G[3:, 3:] = T[:3, :3]
    return G.T @ cov_ref @ G


def _pose_prior(key, T, cov_ref):
    cov = 0.5 * (cov_ref + cov_ref.T) + np.eye(6) * 1e-18
    return gtsam.PriorFactorPose3(key, gtsam.Pose3(T), gtsam.noiseModel.Gaussian.Covariance(_body_cov(T, cov)))


def _fit(views: list, problem: Problem, model: StoredModel, which: str, T_fb: np.ndarray):
    """LM on the small graph; returns (values, marginals or None, slots).

    which='camera': the cameras seen are free, the mount and the board scale have priors at their
    stored estimates and covariances (so the new camera covariance carries their uncertainty);
    which='mount': the mount is free, every camera has its stored pose and covariance as a prior."""
    names = sorted({v.camera for v in views})
    slots = {n: i for i, n in enumerate(names)}
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    poses = {c.index: c.T_base_flange for c in problem.captures}
    for k in sorted({v.capture for v in views}):
        graph.add(gtsam.PriorFactorPose3(F(k), gtsam.Pose3(poses[k]), fk_noise(problem.options)))
        values.insert(F(k), gtsam.Pose3(poses[k]))
    for n, i in slots.items():
        values.insert(C(i), gtsam.Pose3(model.T_base_cam[n]))
        if which == "mount":
            graph.add(_pose_prior(C(i), model.T_base_cam[n], model.covariance[n]))
    values.insert(B(0), gtsam.Pose3(T_fb))
    if which == "camera":
        graph.add(_pose_prior(B(0), T_fb, model.mount_covariance))
    values.insert(S(0), np.array([model.board_scale]))
    graph.add(gtsam.PriorFactorVector(S(0), np.array([model.board_scale]),
                                      gtsam.noiseModel.Isotropic.Sigma(1, max(model.board_scale_sigma, 1e-9))))
    for v in views:
        if v.keep.sum() < MIN_CORNERS_PER_VIEW:
            continue
        graph.add(make_calibration_factor(C(slots[v.camera]), F(v.capture), B(0), v.p_board_m[v.keep], v.uv_px[v.keep],
                                          model.intrinsics[v.camera], np.full(int(v.keep.sum()), 1.0 / model.pixel_sigma_px),
                                          key_scale=S(0)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-10)
    params.setAbsoluteErrorTol(1e-12)
    out = values
    try:
        out = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        marg = gtsam.Marginals(graph, out)
    except RuntimeError:
        return out, None, slots
    return out, marg, slots


def _residual_sigmas(v: _View, T_cam, T_f, T_fb, intr, sigma_px, scale) -> np.ndarray:
    e, _ = view_residual(T_cam, T_f, T_fb, v.p_board_m * scale, v.uv_px, intr, np.full(len(v.uv_px), 1.0 / sigma_px),
                         want_jacobians=False)
    return np.linalg.norm(e.reshape(-1, 2), axis=1)


def _camera_fit(views, problem, model, T_fb):
    """Re-estimate the cameras seen (mount held); one round of corner outlier rejection."""
    for _ in range(2):
        vals, marg, slots = _fit(views, problem, model, "camera", T_fb)
        changed = False
        for v in views:
            r = _residual_sigmas(v, vals.atPose3(C(slots[v.camera])).matrix(), vals.atPose3(F(v.capture)).matrix(),
                                 vals.atPose3(B(0)).matrix(), model.intrinsics[v.camera], model.pixel_sigma_px,
                                 float(vals.atVector(S(0))[0]))
            keep = r < OUTLIER_SIGMAS
            if keep.sum() >= MIN_CORNERS_PER_VIEW and np.any(keep != v.keep):
                v.keep, changed = keep, True
        if not changed:
            break
    return vals, marg, slots


def _check(name, views, vals, marg, slots, model, T_fb, alpha) -> CameraCheck:
    mine = [v for v in views if v.camera == name]
    T_new = vals.atPose3(C(slots[name])).matrix()
    T_old = model.T_base_cam[name]
    d = np.concatenate([log_so3(T_new[:3, :3] @ T_old[:3, :3].T), T_new[:3, 3] - T_old[:3, 3]])
    cov_new = to_ref_axes(T_new, marg.marginalCovariance(C(slots[name])))
    cov_d = model.covariance[name] + cov_new
    m2 = float(d @ np.linalg.solve(cov_d, d))
    p = chi2_sf_6(m2)

    def along(block, x):
        n = np.linalg.norm(x)
        u = x / n if n > 0 else np.ones(3) / np.sqrt(3)
        return float(np.sqrt(max(u @ block @ u, 0.0)))

    r = np.concatenate([_residual_sigmas(v, T_new, vals.atPose3(F(v.capture)).matrix(), vals.atPose3(B(0)).matrix(),
                                         model.intrinsics[name], 1.0, float(vals.atVector(S(0))[0]))[v.keep]
                        for v in mine])
    return CameraCheck(
        name=name, status="moved" if p < alpha else "unchanged", views=len(mine), corners=int(r.size), d=d,
        covariance=cov_d, mahalanobis2=m2, p_value=p,
        displacement_mm=float(np.linalg.norm(d[3:]) * 1e3), sigma_displacement_mm=along(cov_d[3:, 3:], d[3:]) * 1e3,
        rotation_deg=float(np.degrees(np.linalg.norm(d[:3]))), sigma_rotation_deg=float(np.degrees(along(cov_d[:3, :3], d[:3]))),
        rms_px=float(np.sqrt(np.mean(r ** 2))) if r.size else float("nan"), T_base_cam_new=T_new)


def applied_flange_poses(problem: Problem, result: Result) -> tuple:
    """(``problem`` with each capture's flange pose as the stored calibration applies it, notes). A
    calibration that estimated the arm's joint zero offsets (``result.robot``) was solved with the
    flange at FK(q + offsets): the fresh captures' reported joint angles are put through the same arm
    model with those offsets. Without joint angles the reported poses are kept, with a note: their
    error includes the offsets', which a camera's test may then read as a move."""
    rb = result.robot or {}
    if rb.get("joint_offsets_rad") is None or not problem.captures:
        return problem, []
    o = np.asarray(rb["joint_offsets_rad"], float)
    if any(c.q_rad is None or c.q_rad.size != o.size for c in problem.captures):
        return problem, [f"the stored calibration estimated the arm's joint zero offsets, but these captures do not all "
                         f"record {o.size} joint angles (q_rad): their reported flange poses carry the offsets' error, "
                         "which the test may read as a camera or mount move; record the joint angles (calibgraph "
                         "capture does)"]
    chain = stored_arm(result, "verify")[0]
    T = chain.fk(np.array([c.q_rad for c in problem.captures]) + o)
    captures = tuple(replace(c, T_base_flange=T[i]) for i, c in enumerate(problem.captures))
    return problem.with_(captures=captures), [
        "flange poses from the reported joint angles through the arm model with the stored calibration's joint "
        "zero offsets, as it was solved"]


def verify(problem: Problem, result: Result, alpha: float = DEFAULT_ALPHA, where: str = "result",
           target: Target | None = None) -> VerifyResult:
    """Test every camera of the stored ``result`` against the views of ``problem`` (the fresh
    capture). Cameras of the result that the capture does not show are 'not_seen'; a camera of the
    capture that the result does not know, or a ``target`` (the fresh data's declared board) other
    than the result's, is refused (:func:`check_fresh_data`)."""
    if not 0 < alpha < 1:
        raise InputError(f"alpha must be in (0, 1), got {alpha}.")
    result = as_result(result, where)
    model = stored_model(result, where)
    notes = check_fresh_data(result, problem.cameras, target, where)
    problem, applied = applied_flange_poses(problem, result)
    notes += applied
    views = []
    for det in problem.detections:
        if det.camera in model.T_base_cam and len(det.ids) >= MIN_CORNERS_PER_VIEW:
            views.append(_View(det.camera, det.capture, problem.points_board_m[det.ids],
                               np.asarray(det.uv_px, float), np.ones(len(det.ids), bool)))
    seen = sorted({v.camera for v in views})
    checks = {n: CameraCheck(n, "not_seen") for n in model.T_base_cam}
    if not seen:
        return VerifyResult(checks, "unchanged", alpha, model.pixel_sigma_px,
                            tuple(notes + ["no camera of the stored result saw the board in this capture"]))
    vals, marg, slots = _camera_fit(views, problem, model, model.T_flange_board)
    if marg is None:
        raise InputError("the verify capture does not determine the cameras' poses (singular graph); "
                         "capture poses with the whole board in view of each camera.")
    for n in seen:
        checks[n] = _check(n, views, vals, marg, slots, model, model.T_flange_board, alpha)
    moved = [n for n in seen if checks[n].status == "moved"]
    verdict, mount_change = ("cameras_moved" if moved else "unchanged"), None
    if len(seen) >= 2 and len(moved) == len(seen):
        mvals, mmarg, _ = _fit(views, problem, model, "mount", model.T_flange_board)
        if mmarg is not None:
            T_fb_new = mvals.atPose3(B(0)).matrix()
            vals2, marg2, slots2 = _camera_fit(views, problem, model, T_fb_new)
            if marg2 is not None and all(_check(n, views, vals2, marg2, slots2, model, T_fb_new, alpha).status == "unchanged"
                                         for n in seen):
                T0 = model.T_flange_board
                mount_change = np.concatenate([log_so3(T_fb_new[:3, :3] @ T0[:3, :3].T), T_fb_new[:3, 3] - T0[:3, 3]])
                verdict = "mount_or_robot_moved"
                notes.append(
                    f"all {len(seen)} cameras disagree in the same way: one change of the board mount "
                    f"({np.linalg.norm(mount_change[3:]) * 1e3:.2f} mm, {np.degrees(np.linalg.norm(mount_change[:3])):.3f} deg) "
                    "explains every view, so the board mount or the robot moved, not the cameras")
        if verdict != "mount_or_robot_moved":
            notes.append("every camera seen moved, and no single change of the board mount explains it")
    return VerifyResult(checks, verdict, alpha, model.pixel_sigma_px, tuple(notes), mount_change)
