"""The corner-factor formulation: one C++ ``ProjectionFactorPPPCal3DS2`` per detected corner.

GTSAM's PPP factor projects a landmark through ``pose * transform``. Written for the board frame
as the landmark frame, the chain becomes

    T_board_cam = H(k) * C(c),   H(k) = T_board_ref[k] = (T_ref_mount[k] T_mount_board)^-1

(C(c) = T_ref_cam; ``ref`` and ``mount`` as in :mod:`calibgraph.solver.terms.factors`), so each corner
is ``PPP(uv, pose=H(k), transform=C(c), point=P(id))``. The robot prior ties H(k) to the board
mount: ``BetweenFactorPose3(M, H(k), T_ref_mount[k]^-1)`` with ``M = T_board_mount`` (the mount
inverse), because ``M^-1 H(k) = T_mount_ref[k] = T_ref_mount[k]^-1``. The FK covariance, defined
on T_base_flange with a right perturbation, becomes ``Ad(T_base_flange) Sigma Ad(T_base_flange)^T``
on its inverse. Board points are variables held by 1 micrometre priors.

No Python runs inside the optimiser, which makes this the fast path for large cells. It needs the
Cal3DS2 distortion model (k1, k2, p1, p2); cameras with k3..k6 use the per-view CustomFactor.
"""

from __future__ import annotations

import gtsam
import gtsam_unstable
import numpy as np

from calibgraph.core.transforms import inv
from calibgraph.solver.terms.keys import C

POINT_SIGMA_M = 1e-6
# The FK prior here sits *between* two variables (M and H(k)), so eliminating H(k) subtracts
# information terms of size 1/sigma^2 from each other; below these floors (1 urad, 1 um) the
# cancellation loses every digit of the pixel information. Both floors are far below any real arm.
FK_SIGMA_FLOOR = np.array([1e-6] * 3 + [1e-6] * 3)


def H(k: int) -> int:
    """Key of T_board_ref for capture k."""
    return gtsam.symbol("h", k)


def P(i: int) -> int:
    """Key of board point i."""
    return gtsam.symbol("p", i)


M0 = gtsam.symbol("m", 0)  # T_board_mount, the inverse board mount
PPP = gtsam_unstable.ProjectionFactorPPPCal3DS2


class _PointKeys(dict):
    """Cache of P(i) keys (building 10^5 factors, key construction is a visible cost)."""

    def __missing__(self, i):
        self[i] = P(i)
        return self[i]


PKEYS = _PointKeys()


def supports(intr) -> bool:
    """True when the camera's distortion fits Cal3DS2 (no k3..k6)."""
    return not np.any(intr.dist8[4:])


def cal3ds2(intr) -> gtsam.Cal3DS2:
    k1, k2, p1, p2 = intr.dist8[:4]
    return gtsam.Cal3DS2(intr.K[0, 0], intr.K[1, 1], intr.K[0, 1], intr.K[0, 2], intr.K[1, 2], k1, k2, p1, p2)


def build(views, slots, problem, est, sigma_px, fk_sigmas):
    """Graph and initial values; ``est`` is the solver's Estimate (T_ref_cam, T_mount_board, T_ref_mount)."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    M = inv(est.T_mount_board)
    values.insert(M0, gtsam.Pose3(M))
    for name, i in slots.items():
        values.insert(C(i), gtsam.Pose3(est.T_ref_cam[name]))
    cals = {name: cal3ds2(problem.cameras[name]) for name in slots}
    pix = gtsam.noiseModel.Isotropic.Sigma(2, sigma_px)
    point_noise = gtsam.noiseModel.Isotropic.Sigma(3, POINT_SIGMA_M)
    used_points = set()
    done_caps = set()
    for v in views:
        if not v.active:
            continue
        k = v.capture
        if k not in done_caps:
            done_caps.add(k)
            T_ref_mount_fk = v.T_ref_mount
            # With A = T_ref_mount: information of A^-1's right perturbation is Ad(A)^-T Sigma^-1 Ad(A)^-1,
            # so its square root is diag(1/sigma) Ad(A^-1): exact, without inverting a covariance spanning
            # 1e-16..1e-8. In eye-in-hand A itself is T_flange_base, the inverse of the pose the sigmas
            # describe, so the between measurement A^-1 = T_base_flange carries them directly.
            s_inv = np.diag(1.0 / np.maximum(fk_sigmas, FK_SIGMA_FLOOR))
            sqrt_info = s_inv if problem.mode == "eye_in_hand" else s_inv @ gtsam.Pose3(inv(T_ref_mount_fk)).AdjointMap()
            graph.add(gtsam.BetweenFactorPose3(M0, H(k), gtsam.Pose3(inv(T_ref_mount_fk)),
                                               gtsam.noiseModel.Gaussian.SqrtInformation(sqrt_info, False)))
            values.insert(H(k), gtsam.Pose3(inv(est.T_ref_mount.get(k, T_ref_mount_fk) @ est.T_mount_board)))
        cal = cals[v.camera]
        ci = C(slots[v.camera])
        hk = H(k)
        keep = v.w > 0
        ids = v.ids[keep].tolist()
        ws = v.weight[keep].tolist()
        for cid, uv, w in zip(ids, v.uv_px[keep], ws):
            noise = pix if w == 1.0 else gtsam.noiseModel.Isotropic.Sigma(2, sigma_px / np.sqrt(w))
            graph.add(PPP(uv, noise, hk, ci, PKEYS[cid], cal, False, False))
        used_points.update(ids)
    for cid in sorted(used_points):
        p = problem.points_board_m[cid]
        graph.add(gtsam.PriorFactorPoint3(PKEYS[cid], p, point_noise))
        values.insert(PKEYS[cid], p)
    return graph, values


def ordering(values) -> gtsam.Ordering:
    """Per-capture poses first, then board points, cameras and the mount."""
    groups = {"h": [], "p": [], "x": []}
    for key in values.keys():
        c = chr(gtsam.Symbol(key).chr())
        groups[c if c in ("h", "p") else "x"].append(key)
    order = gtsam.Ordering()
    for key in groups["h"] + groups["p"] + groups["x"]:
        order.push_back(key)
    return order


def extract(values, slots, views):
    """(T_ref_cam dict, T_mount_board, T_ref_mount dict) from optimised values."""
    T_ref_cam = {name: values.atPose3(C(i)).matrix() for name, i in slots.items()}
    M = values.atPose3(M0).matrix()
    T_ref_mount = {}
    for k in {v.capture for v in views if v.active}:
        T_ref_mount[k] = inv(values.atPose3(H(k)).matrix()) @ M
    return T_ref_cam, inv(M), T_ref_mount


def mount_cov_body(marg, values):
    """Right-perturbation covariance of T_mount_board from that of M = T_board_mount."""
    M = values.atPose3(M0)
    Ad = M.AdjointMap()
    return Ad @ marg.marginalCovariance(M0) @ Ad.T
