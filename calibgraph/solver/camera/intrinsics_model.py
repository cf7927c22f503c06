"""One camera seen in many views of a planar board: the intrinsics parameter vector of a distortion
model, the projection Jacobians, and the information matrix of the intrinsics with the view poses
eliminated (their Schur complement).

Shared by the close-range calibration (:mod:`calibgraph.solver.camera.intrinsics_session`) and its
prediction for a planned session (:mod:`calibgraph.solver.camera.session_plan`), so that what is predicted
is computed exactly as what is measured.

A view's pose ``T_cam_board`` is perturbed on the left in the camera frame, tangent
``[rotation (3), translation (3)]`` (GTSAM's order): ``R <- exp(w) R``, ``t <- t + dt``. Residual rows
interleave u and v per corner, as the joint graph's view factor does.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.camera import DIST_NAMES, INTRINSICS_FULL, Intrinsics, covered_size, distortion_partials
from calibgraph.core.errors import InputError

# distortion model -> the coefficients it estimates (the others are held at zero)
DISTORTION_MODELS = {
    "k1k2": ("k1", "k2"),
    "k1k2p1p2": ("k1", "k2", "p1", "p2"),
    "k1k2p1p2k3": ("k1", "k2", "p1", "p2", "k3"),
    "rational": DIST_NAMES,
}
DEFAULT_MODEL = "k1k2p1p2k3"


def model_parameters(model: str) -> tuple:
    """The intrinsics a model estimates: ``('fx', 'fy', 'cx', 'cy', *its distortion coefficients)``."""
    if model not in DISTORTION_MODELS:
        raise InputError(f"distortion model {model!r} is unknown; choose one of {', '.join(DISTORTION_MODELS)}.")
    return ("fx", "fy", "cx", "cy", *DISTORTION_MODELS[model])


def stored_coefficients(model: str) -> int:
    """How many OpenCV coefficients an :class:`Intrinsics` of this model carries (5, or 8 for 'rational')."""
    return 8 if model == "rational" else 5


def parameter_vector(intr: Intrinsics, names: tuple) -> np.ndarray:
    """The values of ``names`` (fx, fy, cx, cy and distortion coefficient names) in ``intr``."""
    d = dict(fx=intr.K[0, 0], fy=intr.K[1, 1], cx=intr.K[0, 2], cy=intr.K[1, 2], **dict(zip(DIST_NAMES, intr.dist8)))
    return np.array([d[n] for n in names], float)


def with_parameters(intr: Intrinsics, names: tuple, x: np.ndarray, n_coefficients: int | None = None) -> Intrinsics:
    """``intr`` with the parameters ``names`` set to ``x`` (no skew; distortion padded to
    ``n_coefficients``, default ``intr``'s own count, at least 5)."""
    K = np.array(intr.K, float)
    dist = intr.dist8.copy()
    for n, v in zip(names, x):
        if n in ("fx", "fy", "cx", "cy"):
            K[{"fx": 0, "fy": 1, "cx": 0, "cy": 1}[n], {"fx": 0, "fy": 1, "cx": 2, "cy": 2}[n]] = v
        else:
            dist[DIST_NAMES.index(n)] = v
    n = n_coefficients or max(intr.dist.size, 5)
    return Intrinsics(K=K, dist=dist[:n], width_px=intr.width_px, height_px=intr.height_px, source=intr.source)


def _skews(v: np.ndarray) -> np.ndarray:
    """(n, 3, 3) cross-product matrices of the rows of ``v`` (n, 3)."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return S


def view_jacobians(intr: Intrinsics, names: tuple, p_board_m: np.ndarray, T_cam_board: np.ndarray):
    """Projection of one view's board points and its Jacobians.

    Args:
        intr: the camera (no skew).
        names: the intrinsics parameters to differentiate (:func:`model_parameters`).
        p_board_m: (n, 3) board points.
        T_cam_board: (4, 4) the view's pose.
    Returns:
        uv_px (n, 2), A (2n, 6) d(uv)/d(pose tangent), B (2n, len(names)) d(uv)/d(intrinsics); rows
        interleave u, v per point.
    """
    R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
    Rp = p_board_m @ R.T
    p_c = Rp + t
    uv, J = intr.project(p_c, with_jacobian=True)
    n = len(p_board_m)
    A = np.empty((n, 2, 6))
    # d p_c / d w = -[R p]x ; d p_c / d t = I
    A[:, :, 3:] = J
    A[:, :, :3] = -np.einsum("nij,njk->nik", J, _skews(Rp))
    x, y = p_c[:, 0] / p_c[:, 2], p_c[:, 1] / p_c[:, 2]
    dx, dy = distortion_partials(x, y, intr.dist8)
    fx, fy = intr.K[0, 0], intr.K[1, 1]
    xd = (uv[:, 0] - intr.K[0, 2]) / fx
    yd = (uv[:, 1] - intr.K[1, 2]) / fy
    B = np.zeros((n, 2, len(names)))
    for j, name in enumerate(names):
        if name == "fx":
            B[:, 0, j] = xd
        elif name == "fy":
            B[:, 1, j] = yd
        elif name == "cx":
            B[:, 0, j] = 1.0
        elif name == "cy":
            B[:, 1, j] = 1.0
        else:
            i = DIST_NAMES.index(name)
            B[:, 0, j] = fx * dx[:, i]
            B[:, 1, j] = fy * dy[:, i]
    return uv, A.reshape(2 * n, 6), B.reshape(2 * n, len(names))


def reduced_information(blocks) -> np.ndarray:
    """Information matrix of the intrinsics with every view's pose eliminated: the sum over views of
    ``B^T B - B^T A (A^T A)^-1 A^T B`` for the whitened Jacobians ``(A, B)`` of each view."""
    S = None
    for A, B in blocks:
        Hpp, Hpi = A.T @ A, A.T @ B
        s = B.T @ B - Hpi.T @ np.linalg.solve(Hpp, Hpi)
        S = s if S is None else S + s
    return S


def intrinsics_block(covariance: np.ndarray, names: tuple, size: int | None = None) -> np.ndarray:
    """The block of ``covariance`` (rows ``names``) over the first ``size`` of ``INTRINSICS_FULL``
    (fx, fy, cx, cy, k1, k2 [, p1, p2 [, k3]]; default: as many of 9, 8, 6 as ``names`` cover): their
    marginal covariance, the other coefficients marginalised out."""
    n = covered_size(names) if size is None else size
    idx = [list(names).index(m) for m in INTRINSICS_FULL[:n]]
    return covariance[np.ix_(idx, idx)]
