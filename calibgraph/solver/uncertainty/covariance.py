"""Covariances in the frames a user reads them in, and the bound they are measured against.

GTSAM's marginals are in the body frame of each pose (right perturbation ``T @ Exp(xi)``);
result.json states them in the axes of the reference frame (base or flange), rotation first.
"""

from __future__ import annotations

import gtsam
import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.core.transforms import inv, log_so3
from calibgraph.solver.fit.graph import Estimate, Marginals, build_graph, ordering
from calibgraph.solver.terms.keys import C
from calibgraph.solver.terms.views import prepare_views


def to_ref_axes(T: np.ndarray, cov_body: np.ndarray) -> np.ndarray:
    """GTSAM right-perturbation covariance -> rotation/position errors in the reference frame axes."""
    G = np.zeros((6, 6))
    G[:3, :3] = G[3:, 3:] = T[:3, :3]
    return G @ cov_body @ G.T


def from_ref_axes(T: np.ndarray, cov_ref: np.ndarray) -> np.ndarray:
    """Reference-axes pose covariance -> GTSAM's body frame (the inverse of :func:`to_ref_axes`)."""
    G = np.zeros((6, 6))
    G[:3, :3] = G[3:, 3:] = T[:3, :3].T
    return G @ cov_ref @ G.T


def pair_covariance(T_a: np.ndarray, T_b: np.ndarray, cov_joint_body: np.ndarray) -> np.ndarray:
    """Covariance of T_a_b = T_a^-1 T_b in a's axes from the joint (12x12) body-frame marginal."""
    T0 = inv(T_a) @ T_b

    def f(xa, xb):
        Ta = gtsam.Pose3(T_a).retract(xa).matrix()
        Tb = gtsam.Pose3(T_b).retract(xb).matrix()
        T = inv(Ta) @ Tb
        return np.concatenate([log_so3(T[:3, :3] @ T0[:3, :3].T), T[:3, 3] - T0[:3, 3]])

    J = np.zeros((6, 12))
    eps = 1e-6
    for i in range(12):
        d = np.zeros(12)
        d[i] = eps
        J[:, i] = (f(d[:6], d[6:]) - f(-d[:6], -d[6:])) / (2 * eps)
    # f's rotation vector (left error of R_a_b) and translation (t_a_b) are both in a's axes already
    return J @ cov_joint_body @ J.T


def crlb(problem: Problem, T_ref_cam: dict, T_mount_board, pixel_sigma_px: float, T_base_flange_true: dict | None = None,
         mounts_single: dict | None = None) -> dict:
    """Cramer-Rao bound of every camera pose: the inverse Fisher information from the Jacobian at the
    true values, with the true pixel sigma and the problem's FK prior sigmas.

    Returns name -> 6x6 covariance (rotation first, reference-frame axes, as in the results).
    In 'single' mode pass ``mounts_single`` (name -> true mount) or the shared true mount is used for each.
    """
    views, _ = prepare_views(problem)
    T_ref_mount_true = {}
    if T_base_flange_true:
        T_ref_mount_true = {k: (T if problem.mode == "eye_to_hand" else inv(T)) for k, T in T_base_flange_true.items()}
    groups = [list(problem.cameras)] if problem.method == "joint" else [[n] for n in problem.cameras]
    out = {}
    for names in groups:
        vs = [v for v in views if v.camera in names]
        mount = T_mount_board if problem.method == "joint" or not mounts_single else mounts_single[names[0]]
        est = Estimate(T_ref_cam={n: T_ref_cam[n] for n in names}, T_mount_board=mount, T_ref_mount=dict(T_ref_mount_true))
        slots = {n: i for i, n in enumerate(names)}
        graph, values = build_graph(vs, slots, problem, est, pixel_sigma_px)
        marg = Marginals(graph, values, ordering(values))
        for n in names:
            out[n] = to_ref_axes(T_ref_cam[n], marg.marginalCovariance(C(slots[n])))
    return out
