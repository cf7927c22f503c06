"""The robot's forward kinematics against its stated accuracy, judged from the fit.

A robot less accurate than stated pulls the cameras without showing in the corners' scatter. Each
capture's estimated robot pose F(k) departs from its FK prior by ``d_k`` (whitened by the prior);
under the stated FK sigmas ``sum |d_k|^2`` is about the prior's redundancy
``sum 6 - tr(Lambda_p Sigma_k)``, with ``Sigma_k = (Lambda_p + J_k)^-1`` the covariance of F(k)
given the rest (J_k: the information of capture k's views). Their ratio says by how much the
stated accuracy is off; when it is above 1 at the 0.05 level, the final graph uses the FK sigmas
the fit implies and a note says so.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import gtsam
import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.solver.keys import F
from calibgraph.solver.linearise import Linearised, linearise
from calibgraph.solver.reduced import linearise_graph
from calibgraph.solver.noise_model import APPLY_Z, MODE_MIN_CORNERS, NOTE_Z, view_mode_basis


@dataclass(frozen=True)
class FkRatio:
    """``ratio`` ~1 when the stated FK accuracy holds; ``applied``: the factor on the FK prior's
    variance the final graph uses (the ratio when above 1 at the 0.05 level, else 1); ``dof``: the
    prior residuals' redundancy; ``significant``: p < 0.001."""

    ratio: float
    applied: float
    dof: float
    significant: bool

    def to_dict(self, opts) -> dict:
        s = float(np.sqrt(self.applied))
        t, r = float(opts.fk_sigma_translation_m), float(opts.fk_sigma_rotation_rad)
        return {"variance_ratio": self.ratio, "applied": self.applied, "dof": self.dof, "significant": self.significant,
                "stated_sigma_translation_m": t, "stated_sigma_rotation_rad": r,
                "used_sigma_translation_m": t * s, "used_sigma_rotation_rad": r * s}


def _mode_weighted_information(lin: Linearised, mode_factors: dict) -> dict:
    """capture -> the information its views carry on F(k) when each view's low-order image modes
    have ``mode_factors[camera]`` times the variance of the rest (as the graph weights them)."""
    info = {k: np.zeros((6, 6)) for k in lin.captures}
    for v, keep, _e, H_f in lin.views:
        f = mode_factors.get(v.camera, 1.0)
        if f > 1.0 and keep.sum() >= MODE_MIN_CORNERS:
            G = view_mode_basis(v.uv_px[keep]).T @ H_f
            info[v.capture] += H_f.T @ H_f - (1.0 - 1.0 / f) * (G.T @ G)
        else:
            info[v.capture] += H_f.T @ H_f
    return info


def fk_variance_ratio(problem: Problem, views, est, sigma_px: float, lin: Linearised | None = None,
                      mode_factors: dict | None = None, marginal: dict | None = None) -> FkRatio | None:
    """The :class:`FkRatio` of the fit at ``est`` (None when there is too little to tell, or with
    kinematics='joint-offsets', whose poses follow the joint angles). ``lin``: :func:`linearise`
    of the same arguments, when already computed; ``mode_factors``: camera -> variance factor of its
    views' low-order image modes in the graph ``est`` was fitted on (the views then pin F(k) less);
    ``marginal``: capture -> the marginal covariance of F(k) in that graph (:func:`robot_pose_marginals`).
    Without it the redundancy takes F(k)'s covariance given the rest, which is smaller than its
    marginal (the cameras, mount and intrinsics come from the same views): the redundancy comes out
    too large and the ratio too small (about 0.8 on synthetic cells where the stated accuracy holds)."""
    if problem.options.kinematics != "none":
        return None
    lin = lin or linearise(problem, views, est, sigma_px)
    prior_at = {v.capture: v.T_ref_mount for v in views}
    weighted = _mode_weighted_information(lin, mode_factors) if mode_factors else None
    energy = red = 0.0
    for k, (prior, views_info, R) in lin.captures.items():
        if weighted is not None:
            views_info = weighted[k]
        T_est = est.T_ref_mount.get(k)
        if T_est is None:
            continue
        xi = np.asarray(gtsam.Pose3.Logmap(gtsam.Pose3(prior_at[k]).between(gtsam.Pose3(T_est))))
        d = R @ xi
        energy += float(d @ d)
        cov_k = marginal[k] if marginal is not None and k in marginal else np.linalg.pinv(prior + views_info)
        red += 6.0 - float(np.trace(prior @ cov_k))
    if red < 5.0 or energy <= 0:
        return None
    ratio = energy / red
    z = np.log(ratio) / np.sqrt(2.0 / red)
    return FkRatio(float(ratio), float(ratio) if z > APPLY_Z else 1.0, float(red), bool(z > NOTE_Z))


def robot_pose_marginals(graph, values) -> dict | None:
    """capture -> marginal covariance (6, 6) of its robot pose F(k) in a solved view graph (from the
    Schur-reduced linearisation of :mod:`calibgraph.solver.reduced`); None when it cannot be formed."""
    try:
        L = linearise_graph(graph, values)
        m = L.marginals(list(L.locals_))
    except np.linalg.LinAlgError:
        return None
    f = chr(gtsam.Symbol(F(0)).chr())
    return {int(gtsam.Symbol(key).index()): m.marginalCovariance(key) for key in L.locals_
            if chr(gtsam.Symbol(key).chr()) == f}


def widened(options, ratio: FkRatio):
    """``options`` with the FK sigmas the fit implies (``ratio.applied`` times the variance)."""
    s = float(np.sqrt(ratio.applied))
    return replace(options, fk_sigma_translation_m=options.fk_sigma_translation_m * s,
                   fk_sigma_rotation_rad=options.fk_sigma_rotation_rad * s)


def fk_note(options, ratio: FkRatio | None) -> list:
    """One line when the robot poses disagree with the stated FK accuracy and the prior was widened."""
    if ratio is None or ratio.applied <= 1.0:
        return []
    o, s = options, float(np.sqrt(ratio.applied))
    test = "" if ratio.significant else ", p < 0.05 but not < 0.001"
    return [f"robot: the fitted flange poses depart from forward kinematics {s:.1f}x as far as the stated FK "
            f"accuracy ({1e3 * o.fk_sigma_translation_m:.2f} mm, {np.degrees(o.fk_sigma_rotation_rad):.3f} deg) "
            f"allows{test}; solved with {1e3 * o.fk_sigma_translation_m * s:.2f} mm, "
            f"{np.degrees(o.fk_sigma_rotation_rad) * s:.3f} deg and the 1-sigma widened for it (state the arm's "
            f"accuracy with --fk-sigma-mm/--fk-sigma-deg; joint zero offsets: --estimate-kinematics joint-offsets)"]
