"""Verify poses: the few robot poses most sensitive to every camera's motion, from a stored result.

``calibgraph verify`` tests ``d = new - stored`` by ``m2 = d^T (Sigma_c + I_c^-1)^-1 d`` where
``I_c`` is the Fisher information the verify views give on camera c's pose (mount and intrinsics
held; the robot pose of each view marginalised under its FK prior:
:func:`calibgraph.plan.active.view_information`). A bump ``delta`` of the camera shifts ``m2`` by
the non-centrality ``delta^T (Sigma_c + I_c^-1)^-1 delta``. What must be caught is a bump of
``bump_mm`` or ``bump_deg`` in any direction, so a camera's sensitivity is the smallest eigenvalue
of ``W (Sigma_c + I_c^-1)^-1 W`` with ``W = diag(bump_rad x3, bump_m x3)``: the non-centrality of
the worst-placed bump of that size. Poses are chosen greedily to maximise
``sum_c log(sensitivity_c + 1e-3)`` (every camera counts, a camera not yet seen most).

Works from the stored camera poses alone (no placements): the candidates' visibility is
:func:`calibgraph.plan.visibility.board_visible` at the stored ``T_base_cam``.
"""

from __future__ import annotations

import numpy as np

from calibgraph.plan.active import view_information
from calibgraph.plan.visibility import board_visible

__all__ = ["sensitivity", "choose_verify_poses"]

BUMP_MM, BUMP_DEG = 2.0, 0.2


def sensitivity(cov_stored: np.ndarray, info: np.ndarray, bump_mm: float = BUMP_MM, bump_deg: float = BUMP_DEG) -> float:
    """Non-centrality of the worst-placed bump of ``bump_mm`` / ``bump_deg`` (module docstring)."""
    M = np.linalg.solve(np.eye(6) + info @ cov_stored, info)  # (Sigma + I^-1)^-1, valid for singular I
    M = 0.5 * (M + M.T)
    w = np.array([np.radians(bump_deg)] * 3 + [bump_mm * 1e-3] * 3)
    return float(max(np.linalg.eigvalsh(w[:, None] * M * w[None, :])[0], 0.0))


def choose_verify_poses(candidates, cameras: dict, T_flange_board: np.ndarray, target, n: int, pixel_sigma_px: float,
                        fk_sigma_translation_m: float = 1e-4, fk_sigma_rotation_rad: float = float(np.radians(0.01)),
                        visible=None, bump_mm: float = BUMP_MM, bump_deg: float = BUMP_DEG) -> tuple[list, dict]:
    """Indices of at most ``n`` of ``candidates`` (T_base_flange (4, 4) each) in the order chosen,
    and camera -> predicted sensitivity after them.

    ``cameras``: name -> (intrinsics, T_base_cam (4, 4) stored, covariance (6, 6) stored);
    ``visible(i, name) -> bool`` overrides the geometric visibility test (e.g. to add occlusion)."""
    infos = []
    for i, T_bf in enumerate(candidates):
        T_bb = np.asarray(T_bf) @ T_flange_board
        row = {}
        for name, (intr, T_bc, _) in cameras.items():
            ok = visible(i, name) if visible is not None else board_visible(intr, T_bc, target, T_bb)
            if ok:
                row[name] = view_information(intr, T_bc, T_bb, target.points_board_m, pixel_sigma_px, T_flange_board,
                                             fk_sigma_translation_m, fk_sigma_rotation_rad)
        infos.append(row)
    total = {name: np.zeros((6, 6)) for name in cameras}

    def score(tot):
        return sum(np.log(sensitivity(cameras[c][2], tot[c], bump_mm, bump_deg) + 1e-3) for c in tot)

    chosen = []
    for _ in range(min(n, len(candidates))):
        best, best_s = None, -np.inf
        for i, row in enumerate(infos):
            if i in chosen or not row:
                continue
            s = score({c: total[c] + row.get(c, 0.0) for c in total})
            if s > best_s:
                best, best_s = i, s
        if best is None:
            break
        chosen.append(best)
        for c, info in infos[best].items():
            total[c] = total[c] + info
    return chosen, {c: sensitivity(cameras[c][2], total[c], bump_mm, bump_deg) for c in cameras}
