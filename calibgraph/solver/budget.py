"""What a camera's 1-sigma is made of: its error budget, and the one step that would shrink it most.

The estimate is linear in the graph's whitened noise near the optimum, ``dx = Sigma J^T e`` with
``Sigma = (J^T J)^-1``, so each independent noise source ``s`` (a group of factors) adds
``Sigma J_s^T J_s Sigma`` to the covariance, and these parts sum to ``Sigma`` exactly. A camera's
budget is the share of each source in the trace of its translation covariance:

    corners      the detected corners (their noise, at the a posteriori pixel sigma)
    intrinsics   the priors on the cameras' intrinsics (the uncertainty of the given values)
    robot_fk     the forward-kinematics priors on the flange poses (and the joint-offset prior)
    board        the board's printed scale (and, in the corner formulation, its points)

Only the column of ``Sigma`` for the camera's translation is needed, from the graph reduced to its
global variables (:mod:`calibgraph.solver.reduced`).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from calibgraph.solver.reduced import SOURCES, TRANSLATION, Linear, columns, sigma_with


@dataclass(frozen=True)
class Budget:
    """A camera's error budget: ``sigma_mm`` = sqrt(trace of its translation covariance) and each
    source's share of that trace (summing to 1); ``own_intrinsics``: the part of the
    ``intrinsics`` share due to this camera's own intrinsics prior."""

    sigma_mm: float
    shares: dict
    own_intrinsics: float

    def to_dict(self, advice: str = "") -> dict:
        return {"sigma_translation_norm_mm": self.sigma_mm, "shares": dict(self.shares),
                "own_intrinsics_share": self.own_intrinsics, "advice": advice}


def budgets(L: Linear, cameras: dict) -> dict:
    """name -> :class:`Budget` for ``cameras`` (name -> (pose key, own intrinsics key or None)), from
    one solve for all their translation columns and one pass over the factors."""
    names = list(cameras)
    X = columns(L, L.S, [(cameras[n][0], TRANSLATION) for n in names])
    m = 3 * len(names)
    parts = {src: np.zeros(m) for src in SOURCES}
    own = np.zeros(m)
    own_cols = {cameras[n][1]: slice(3 * i, 3 * i + 3) for i, n in enumerate(names) if cameras[n][1] is not None}
    for src, keys, blocks in L.factors:
        JX = sum(blocks[k] @ X[k] for k in keys)
        v = np.sum(JX * JX, axis=0)
        parts[src] += v
        if src == "intrinsics" and keys[0] in own_cols:
            own[own_cols[keys[0]]] += v[own_cols[keys[0]]]
    out = {}
    for i, n in enumerate(names):
        sl = slice(3 * i, 3 * i + 3)
        total = float(np.trace(X[cameras[n][0]][TRANSLATION][:, sl]))
        shares = {src: (float(v[sl].sum()) / total if total > 0 else 0.0) for src, v in parts.items()}
        out[n] = Budget(1e3 * np.sqrt(max(total, 0.0)), shares, float(own[sl].sum()) / total if total > 0 else 0.0)
    return out


def doubled_information(L: Linear) -> np.ndarray:
    """The global information were every capture's data (corners, FK) doubled: the Schur complement
    of the data doubles, the global priors (intrinsics, scale, offsets) stay."""
    P = np.zeros_like(L.S)
    for src, keys, blocks in L.factors:
        if len(keys) == 1 and keys[0] in L.index and src != "corners":
            k = keys[0]
            P[L.index[k], L.index[k]] += blocks[k].T @ blocks[k]
    return 2.0 * L.S - P  # 2 (S - P) + P


def advice(name: str, b: Budget, L: Linear, cam_key, own_K_key=None, session_info=None,
           doubled: np.ndarray | None = None, doubled_cov: np.ndarray | None = None, has_session: bool = False) -> str:
    """One line with numbers: what would shrink camera ``name``'s 1-sigma most, judged by what the
    camera's 1-sigma would become after each remedy: a close-range intrinsics session, twice the
    poses, the board's scale measured.

    ``session_info``: the information on the camera's intrinsics vector ([fx, fy, cx, cy, k1, k2],
    with p1, p2 (, k3) when its graph estimates them) that a
    close-range session of 25 images gives (or a callable returning it, called only when a session
    could be the best remedy); without it, the intrinsics known exactly, the best any session can do.
    ``doubled``: :func:`doubled_information` of ``L`` (computed here when not given; one per graph
    serves every camera); ``doubled_cov``: its inverse, when the caller has it. ``has_session``: the
    camera's intrinsics prior is already a calibration file's covariance: the remedy is then 25 more
    close-range images, whose information adds to the file's rather than replacing it."""
    top = max(b.shares, key=b.shares.get)
    head = f"{name}: {100 * b.shares[top]:.0f} % of its {b.sigma_mm:.2f} mm 1σ is " + {
        "corners": "corner noise", "intrinsics": "the intrinsics' prior" if b.own_intrinsics < 0.5 * b.shares["intrinsics"]
        else "its own intrinsics", "robot_fk": "the robot's forward-kinematics accuracy",
        "board": "the board's printed scale"}[top]
    options = {}
    has_K = own_K_key is not None and own_K_key in L.prior_K
    if has_K:  # the bound first: intrinsics known exactly
        n_k = L.prior_K[own_K_key].shape[0]
        options["session"] = sigma_with(L, cam_key, add_info={own_K_key: np.eye(n_k) * 1e12 - L.prior_K[own_K_key]})
    options["poses"] = sigma_with(L, cam_key, S=doubled if doubled is not None else doubled_information(L),
                                  cov=doubled_cov)
    s_keys = [k for k in L.index if chr(gtsam.Symbol(k).chr()) == "s"]
    if s_keys and b.shares["board"] > 0.05:
        options["board"] = sigma_with(L, cam_key, add_info={k: np.eye(1) * 1e12 for k in s_keys})
    realistic = False
    if has_K and min(options, key=options.get) == "session" and session_info is not None:
        info = session_info() if callable(session_info) else session_info
        if info is not None:  # what a real session would give, instead of the bound
            options["session"] = sigma_with(L, cam_key, add_info={own_K_key: info if has_session
                                                                 else info - L.prior_K[own_K_key]})
            realistic = True
    best = min(options, key=options.get)
    s = options[best]
    if best == "session":
        how, bound = ((("25 more close-range images, calibrated together with its first session's" if has_session
                        else "a close-range session of 25 images"), "") if realistic
                      else ("a close-range intrinsics session", " at best (its intrinsics then known exactly)"))
        return (f"{head}; {how} (calibgraph intrinsics, then --intrinsics {name}=CAM.yaml) would bring it to about "
                f"{s:.2f} mm{bound}")
    if best == "board":
        return (f"{head}; measuring the board's pitch (ruler or caliper) and solving with it fixed "
                f"(--fixed-board-scale) would bring it to about {s:.2f} mm")
    return (f"{head}; twice the poses, with more depth spread and tilt in its view, would bring it to about "
            f"{s:.2f} mm")
