"""From solved graphs to the :class:`~calibgraph.solver.output.result.Result`: per-camera poses with their
covariance in reference axes, residuals, camera pairs, the board mount, the robot section."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibgraph.core.errors import CalibgraphError, ObservabilityError
from calibgraph.core.problem import Problem, uses_file_covariance
from calibgraph.core.transforms import inv
from calibgraph.solver.robot import kinematics as kin
from calibgraph.solver.uncertainty.budget import advice, budgets, doubled_information
from calibgraph.solver.terms.reduced import Linear
from calibgraph.solver.camera.session_plan import SESSION_PIXEL_SIGMA_PX, predict_session_covariance
from calibgraph.solver.solve.camera_model import intrinsics_record
from calibgraph.solver.uncertainty.covariance import pair_covariance, to_ref_axes
from calibgraph.solver.fit.graph import Estimate, intrinsics_size
from calibgraph.solver.terms.keys import B, C, K, O, S
from calibgraph.solver.uncertainty.observability import check_after_solve
from calibgraph.solver.solve.optimise import Group
from calibgraph.solver.output.result import CameraResult, PairResult, RejectedView
from calibgraph.solver.terms.views import reprojections


def view_residuals(name: str, est: Estimate, views: list, cameras: dict) -> tuple[dict, np.ndarray, list]:
    """Residuals (reprojected - detected, px) of one camera's views at the estimate: (capture ->
    record for the result, kept corners' residuals of the active views (M, 2), rejected corners as
    (camera, capture, corner id, residual px))."""
    intr = est.camera_model(name, cameras)
    residuals, kept, rejected_corners = {}, [], []
    uv_hats = reprojections(views, est.T_ref_cam, est.T_mount_board, est.T_ref_mount, {name: intr}, est.board_scale)
    for v, uv_hat in zip(views, uv_hats):
        d = uv_hat - v.uv_px
        residuals[v.capture] = {"ids": v.ids, "uv_detected_px": v.uv_px, "residual_px": d,
                                "weight": v.w.copy(), "rejected": not v.active}
        if v.active:
            keep = v.kept
            kept.append(d[keep])
            for cid, rr in zip(v.ids[~keep], np.linalg.norm(d[~keep], axis=1)):
                rejected_corners.append((name, v.capture, int(cid), float(rr)))
    return residuals, np.concatenate(kept) if kept else np.zeros((0, 2)), rejected_corners


def camera_pixel_sigma(group: Group, name: str) -> float:
    """The a posteriori sigma of camera ``name``'s corners (px per axis): the solve's reference
    sigma times the camera's noise scale (that of its active views)."""
    scale = next((v.noise_scale for v in group.views if v.camera == name and v.active), 1.0)
    return group.est.sigma_px * scale


def error_budgets(problem: Problem, group: Group, lin: Linear) -> dict:
    """name -> ``CameraResult.error_budget`` of the group's cameras (see :mod:`calibgraph.solver.uncertainty.budget`)."""
    est = group.est
    keys = {n: (C(est.slots[n]), K(est.slots[n]) if est.values.exists(K(est.slots[n])) else None) for n in group.names}
    out, doubled = {}, doubled_information(lin)
    doubled_cov = np.linalg.inv(doubled)  # one inverse for every camera's "twice the poses"
    for n, b in budgets(lin, keys).items():
        b = replace(b, cov_by_noise={src: to_ref_axes(est.T_ref_cam[n], c) for src, c in b.cov_by_noise.items()})
        sigma_n = camera_pixel_sigma(group, n)
        size = intrinsics_size(problem, n, est) if keys[n][1] is not None else 6
        session = _session_information(problem, est, n, sigma_n, size)
        filed = keys[n][1] is not None and uses_file_covariance(
            problem.cameras[n], problem.options, wide=n in est.wide_intrinsics or n in est.free_intrinsics)
        out[n] = b.to_dict(advice(n, b, lin, *keys[n], session_info=session, has_session=filed,
                                  doubled=doubled, doubled_cov=doubled_cov))
    return out


def _session_information(problem: Problem, est: Estimate, name: str, sigma_px: float | None = None, size: int = 6):
    """A callable giving the (size, size) information on the intrinsics vector (``size``: that of
    its graph, 6, 8 or 9) a close-range session of 25 images with the problem's board would give
    camera ``name`` at its estimated intrinsics (None: board unknown).
    Its corners are taken as good as this camera's own in the hand-eye views (``sigma_px``: same
    camera and detector, the board nearer and larger), at most SESSION_PIXEL_SIGMA_PX (a hand-held
    session's printed board and exposure): with the fixed 0.1 px the advice for a rendered 5 m D455
    (corners at 0.015 px) predicted 5.9 mm where its session reached 1.2 mm."""
    sigma = SESSION_PIXEL_SIGMA_PX if not sigma_px or sigma_px <= 0 else min(float(sigma_px), SESSION_PIXEL_SIGMA_PX)
    if problem.target is None:
        return None

    def info():
        try:
            cov = predict_session_covariance(est.camera_model(name, problem.cameras), problem.target,
                                             pixel_sigma_px=sigma, size=size)
        except (CalibgraphError, np.linalg.LinAlgError):  # a board or camera no session plan fits
            return None
        return np.linalg.inv(cov)
    return info


def camera_result(problem: Problem, name: str, group: Group, rejected: list, budget: dict | None = None
                  ) -> tuple[CameraResult, list]:
    """(CameraResult of one camera, its rejected corners): pose, covariance in reference axes, residuals.
    ``rejected``: views refused before the solve (RejectedView); ``budget``: its error budget."""
    est, joint = group.est, problem.method == "joint"
    cov = to_ref_axes(est.T_ref_cam[name], est.marginals.marginalCovariance(C(est.slots[name])))
    try:
        check_after_solve(name, cov)
    except ObservabilityError as e:  # a pose the data do not determine is no calibration
        return not_calibrated(problem, name, str(e).replace(f"camera {name!r} is ", "", 1), rejected), []
    mine = [v for v in group.views if v.camera == name]
    used = [v for v in mine if v.active]
    residuals, kept_px, rejected_corners = view_residuals(name, est, mine, problem.cameras)
    rn = np.linalg.norm(kept_px, axis=1)
    views_rejected = tuple(RejectedView(name, v.capture, v.reason) for v in mine if not v.active)
    views_rejected += tuple(r for r in rejected if r.camera == name)
    result = CameraResult(
        name=name, ref_frame="base" if problem.mode == "eye_to_hand" else "flange", T_ref_cam=est.T_ref_cam[name],
        covariance=cov,
        reprojection_rms_px=float(np.sqrt(np.mean(rn ** 2))) if rn.size else float("nan"),
        reprojection_max_px=float(rn.max()) if rn.size else float("nan"),
        views_used=len(used), views_rejected=views_rejected,
        corners_used=int(sum(v.kept.sum() for v in used)),
        corners_rejected=int(sum((~v.kept).sum() for v in used)),
        T_mount_board=None if joint else est.T_mount_board,
        residuals_px=residuals,
        intrinsics=intrinsics_record(problem, name, est),
        corner_noise=est.mode_ratios[name].to_dict() if name in est.mode_ratios else None,
        pixel_sigma_px=camera_pixel_sigma(group, name),
        error_budget=budget,
    )
    return result, rejected_corners


def not_calibrated(problem: Problem, name: str, why: str, rejected: list) -> CameraResult:
    """The CameraResult of a camera too few of whose views survived: no pose, no covariance, why."""
    mine = sorted(d.capture for d in problem.detections if d.camera == name)
    refused = {r.capture: r for r in rejected if r.camera == name}
    views_rejected = tuple(refused.get(k, RejectedView(name, k, f"camera not calibrated: {why}")) for k in mine)
    return CameraResult(name=name, ref_frame="base" if problem.mode == "eye_to_hand" else "flange", T_ref_cam=None,
                        covariance=None, reprojection_rms_px=float("nan"), reprojection_max_px=float("nan"),
                        views_used=0, views_rejected=views_rejected, calibrated=False, why=why)


def pair_results(names: list, cameras: dict, groups: list, joint: bool) -> dict:
    """(a, b) -> PairResult for every camera pair; in 'joint' from one joint marginal of all cameras
    (pairwise calls would be O(n^2) solves), in 'single' from independent per-camera marginals."""
    joint_cov = None
    if joint and len(names) > 1:
        est = groups[0].est
        joint_cov = est.marginals.joint([C(est.slots[n]) for n in names])
    body = {n: g.est.marginals.marginalCovariance(C(g.est.slots[n])) for g in groups for n in g.names}
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
                cov_ab[:6, :6], cov_ab[6:, 6:] = body[a], body[b]
            pairs[(a, b)] = PairResult(a=a, b=b, T_a_b=inv(T_ref_a) @ T_ref_b,
                                       covariance=pair_covariance(T_ref_a, T_ref_b, cov_ab))
    return pairs


def mount_and_robot_poses(problem: Problem, groups: list):
    """(T_mount_board, its covariance in reference axes, capture -> estimated T_base_flange) of the
    joint graph; (None, None, {}) in 'single' mode."""
    if problem.method != "joint":
        return None, None, {}
    est = groups[0].est
    T_base_flange = est.T_ref_mount
    if problem.mode == "eye_in_hand":
        T_base_flange = {k: inv(T) for k, T in T_base_flange.items()}
    return est.T_mount_board, to_ref_axes(est.T_mount_board, est.mount_cov_body), T_base_flange


def robot_result(problem: Problem, ks, group: Group) -> tuple[dict, list]:
    """(``Result.robot``, notes): the joint offsets with their marginal covariance joint with the
    camera poses, the mount and the board scale (for the correlations); refuses offsets the data do
    not determine."""
    est, names = group.est, group.names
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
    o = problem.options
    captures = sorted({v.capture for v in group.views if v.active})
    kin.check_after_solve(ks, np.sqrt(np.clip(np.diag(cov)[:nf], 0, None)), o.joint_offset_prior_rad, captures)
    out = kin.robot_result(ks, est.joint_offsets, cov, labels, o.joint_offset_prior_rad, o.kinematics_staging)
    out["model_source"] = o.kinematics_model
    off, s = np.asarray(out["joint_offsets_rad"]), out["joint_offsets_sigma_rad"]
    big = [f"joint {i + 1} {1e3 * off[i]:+.2f} ± {1e3 * s[i]:.2f} mrad" for i in ks.free if abs(off[i]) > 3 * s[i]]
    notes = []
    if big:
        notes.append("the robot's joint zero offsets differ from zero: " + ", ".join(big) +
                     " (calibgraph export writes a corrected URDF)")
    return out, notes
