"""The views linearised at an estimate: what the FK check and the corner-noise model both read.

For every active view: its whitened residual and its Jacobian on the capture's robot pose F(k);
for every capture: the FK prior's information and the information its views carry on F(k).
Computed once and shared (:mod:`calibgraph.solver.fk_check`, :mod:`calibgraph.solver.noise_model`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.solver.factors import fk_noise, pad_views, padded_view_residuals


@dataclass(frozen=True)
class Linearised:
    """``views``: [(view, kept-corner mask, e (2n,), H_F (2n, 6))] of the active views;
    ``captures``: capture -> (FK prior information (6, 6), the views' information on F(k) (6, 6),
    the prior's square-root information R (6, 6))."""

    views: list
    captures: dict

    def robot_pose_covariances(self) -> dict:
        """capture -> covariance of F(k) given the rest of the graph, ``(prior + views)^-1``."""
        if not self.captures:
            return {}
        inv = np.linalg.pinv(np.array([prior + info for prior, info, _ in self.captures.values()]))
        return dict(zip(self.captures, inv))


def linearise(problem: Problem, views, est, sigma_px: float) -> Linearised:
    """Whitened residuals and robot-pose Jacobians of the active views at ``est`` (an Estimate),
    every view of one camera in one vectorised pass."""
    active = [v for v in views if v.active and v.kept.any()]
    rows = {}
    for name in dict.fromkeys(v.camera for v in active):
        mine = [v for v in active if v.camera == name]
        P, UV, valid, W = pad_views(mine, est.board_scale, kept_only=True)
        T_F = np.array([est.T_ref_mount.get(v.capture, v.T_ref_mount) for v in mine])
        e, _, J_f = padded_view_residuals(est.T_ref_cam[name], T_F, est.T_mount_board, P, UV,
                                          est.camera_model(name, problem.cameras), np.sqrt(W) / sigma_px)
        for i, v in enumerate(mine):
            n2 = 2 * int(valid[i].sum())
            rows[id(v)] = (e[i, :n2], J_f[i, :n2])
    out, info = [], {}
    for v in active:  # in the order given
        e, H_f = rows[id(v)]
        if not (np.all(np.isfinite(e)) and np.all(np.isfinite(H_f))):
            continue
        if v.capture not in info:
            R = np.asarray(fk_noise(problem.options, problem.mode, v.T_ref_mount).R())
            info[v.capture] = (R.T @ R, np.zeros((6, 6)), R)
        prior, views_info, R = info[v.capture]
        info[v.capture] = (prior, views_info + H_f.T @ H_f, R)
        out.append((v, v.kept, e, H_f))
    return Linearised(out, info)
