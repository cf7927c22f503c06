"""The views linearised at an estimate: what the FK check and the corner-noise model both read.

For every active view: its whitened residual and its Jacobian on the capture's robot pose F(k);
for every capture: the FK prior's information and the information its views carry on F(k).
Computed once and shared (:mod:`calibgraph.solver.robot.fk_check`, :mod:`calibgraph.solver.terms.noise_model`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.solver.terms.factors import fk_noise, pad_views, padded_view_residuals, whitened
from calibgraph.solver.terms.views import robot_keys


@dataclass(frozen=True)
class Linearised:
    """``views``: [(view, kept-corner mask, e (2n,), H_F (2n, 6))] of the active views;
    ``captures``: robot pose (the capture whose F a configuration's captures share,
    :func:`~calibgraph.solver.fit.graph.robot_keys`) -> (FK prior information (6, 6), the views' information
    on it (6, 6), the prior's square-root information R (6, 6)); each view's ``H_F`` is on that pose."""

    views: list
    captures: dict
    robot_of: dict  # capture -> its robot pose's key in ``captures`` (itself, or its configuration's first capture)

    def robot_pose_covariances(self) -> dict:
        """capture -> covariance of F(k) given the rest of the graph, ``(prior + views)^-1``."""
        if not self.captures:
            return {}
        inv = np.linalg.pinv(np.array([prior + info for prior, info, _ in self.captures.values()]))
        return dict(zip(self.captures, inv))


def revisit_whitening(problem: Problem, views, est, sigma_px: float, jacobians: dict | None = None) -> dict:
    """id(view) -> (U, c), the whitening (:func:`~calibgraph.solver.terms.factors.whitened`) of each active view
    whose capture shares its robot pose with another active capture (a revisit of a configuration,
    :func:`~calibgraph.solver.terms.views.robot_keys`): the shared pose carries the configuration's error, and
    each visit's own, the arm's repeatability (``fk_repeat_*``, the stated FK sigmas by default), moves
    the view's board image as a robot pose does: its residual's covariance is ``I + H_F S H_F^T`` (``H_F``
    the view's whitened Jacobian on its robot pose at ``est``, ``S`` the repeatability's covariance).
    ``jacobians``: id(view) -> that Jacobian, where the caller has it already (:func:`linearise`); else
    it is computed here, every view of one camera in one vectorised pass."""
    keys = robot_keys(problem, views)
    shared = {}
    for k, (r, _) in keys.items():
        shared[r] = shared.get(r, 0) + 1
    mine = [v for v in views if v.active and v.kept.any() and v.camera in est.T_ref_cam
            and shared.get(keys[v.capture][0], 0) > 1]
    if not mine:
        return {}
    o = problem.options
    rep = replace(o, fk_sigma_translation_m=o.fk_repeat_translation_m or o.fk_sigma_translation_m,
                  fk_sigma_rotation_rad=o.fk_repeat_rotation_rad or o.fk_sigma_rotation_rad)
    H = jacobians if jacobians is not None else {k: J for k, (_, J) in _view_rows(problem, mine, est, sigma_px).items()}
    out = {}
    for v in mine:
        L = np.linalg.inv(np.asarray(fk_noise(rep, problem.mode, est.T_ref_mount.get(v.capture, v.T_ref_mount)).R()))
        A = H[id(v)] @ L
        if not np.all(np.isfinite(A)):
            continue
        U, sv, _ = np.linalg.svd(A, full_matrices=False)
        out[id(v)] = (U, 1.0 - 1.0 / np.sqrt(1.0 + sv * sv))
    return out


def _view_rows(problem: Problem, views: list, est, sigma_px: float) -> dict:
    """id(view) -> (whitened residual, whitened Jacobian on its robot pose) of ``views`` at ``est``, every
    view of one camera in one vectorised pass."""
    rows = {}
    for name in dict.fromkeys(v.camera for v in views):
        mine = [v for v in views if v.camera == name]
        P, UV, valid, W = pad_views(mine, est.board_scale, kept_only=True)
        T_F = np.array([est.T_ref_mount.get(v.capture, v.T_ref_mount) for v in mine])
        e, _, J_f = padded_view_residuals(est.T_ref_cam[name], T_F, est.T_mount_board, P, UV,
                                          est.camera_model(name, problem.cameras), np.sqrt(W) / sigma_px)
        for i, v in enumerate(mine):
            n2 = 2 * int(valid[i].sum())
            rows[id(v)] = (e[i, :n2], J_f[i, :n2])
    return rows


def linearise(problem: Problem, views, est, sigma_px: float) -> Linearised:
    """Whitened residuals and robot-pose Jacobians of the active views at ``est`` (an Estimate),
    every view of one camera in one vectorised pass."""
    active = [v for v in views if v.active and v.kept.any()]
    rows = _view_rows(problem, active, est, sigma_px)
    out, info = [], {}
    repeat = revisit_whitening(problem, views, est, sigma_px, jacobians={k: J for k, (_, J) in rows.items()})
    keys = robot_keys(problem, views)  # a revisit's views bear on its configuration's shared robot pose
    T_fk = {v.capture: v.T_ref_mount for v in views}
    for v in active:  # in the order given
        e, H_f = rows[id(v)]
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(H_f))):
            continue
        if id(v) in repeat:  # a revisit: its residual whitened for its own repeatability error
            U, c = repeat[id(v)]
            e, H_f = whitened(e, c, U), whitened(H_f, c, U)
        r, D = keys[v.capture]
        if D is not None:
            H_f = H_f @ gtsam.Pose3(np.linalg.inv(D)).AdjointMap()
        if r not in info:
            R = np.asarray(fk_noise(problem.options, problem.mode, T_fk[r]).R())
            info[r] = (R.T @ R, np.zeros((6, 6)), R)
        prior, views_info, R = info[r]
        info[r] = (prior, views_info + H_f.T @ H_f, R)
        out.append((v, v.kept, e, H_f))
    return Linearised(out, info, {k: r for k, (r, _) in keys.items()})
