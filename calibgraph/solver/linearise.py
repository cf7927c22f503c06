"""The views linearised at an estimate: what the FK check and the corner-noise model both read.

For every active view: its whitened residual and its Jacobian on the capture's robot pose F(k);
for every capture: the FK prior's information and the information its views carry on F(k).
Computed once and shared (:mod:`calibgraph.solver.fk_check`, :mod:`calibgraph.solver.noise_model`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.solver.factors import fk_noise, view_residual


@dataclass(frozen=True)
class Linearised:
    """``views``: [(view, kept-corner mask, e (2n,), H_F (2n, 6))] of the active views;
    ``captures``: capture -> (FK prior information (6, 6), the views' information on F(k) (6, 6),
    the prior's square-root information R (6, 6))."""

    views: list
    captures: dict

    def robot_pose_covariances(self) -> dict:
        """capture -> covariance of F(k) given the rest of the graph, ``(prior + views)^-1``."""
        return {k: np.linalg.pinv(prior + info) for k, (prior, info, _) in self.captures.items()}


def linearise(problem: Problem, views, est, sigma_px: float) -> Linearised:
    """Whitened residuals and robot-pose Jacobians of the active views at ``est`` (an Estimate)."""
    out, info = [], {}
    for v in views:
        if not v.active:
            continue
        keep = v.kept
        if not keep.any():
            continue
        e, J = view_residual(est.T_ref_cam[v.camera], est.T_ref_mount.get(v.capture, v.T_ref_mount), est.T_mount_board,
                             est.board_scale * v.p_board_m[keep], v.uv_px[keep],
                             est.camera_model(v.camera, problem.cameras), np.sqrt(v.w[keep]) / sigma_px)
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(J[1]))):
            continue
        H_f = J[1]
        if v.capture not in info:
            R = np.asarray(fk_noise(problem.options, problem.mode, v.T_ref_mount).R())
            info[v.capture] = (R.T @ R, np.zeros((6, 6)), R)
        prior, views_info, R = info[v.capture]
        info[v.capture] = (prior, views_info + H_f.T @ H_f, R)
        out.append((v, keep, e, H_f))
    return Linearised(out, info)
