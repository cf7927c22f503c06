"""What a camera's 1-sigma is made of: its error budget, and the one step that would shrink it most.

Two labelled sets of shares of the trace of a camera's translation covariance (its 1-sigma squared),
over the same four sources:

    corners      the detected corners (their noise, at the a posteriori pixel sigma)
    intrinsics   the cameras' intrinsics (their priors and what the views leave uncertain)
    robot_fk     the forward-kinematics priors on the flange poses (and the joint-offset prior)
    board        the board's printed scale (and, in the corner formulation, its points)

``shares`` (by parameter, "were it known exactly"): the fraction of the variance that would go were
that source known exactly, i.e. its information made infinite (for a prior on a parameter: the
parameter held at its true value; for the corners: noise-free corners). These answer the question
the advice answers: a remedy that improves a source cannot take the 1-sigma below
``sigma * sqrt(1 - share)``. Each is alone, so they overlap and do not sum to 1. For the intrinsics
this includes what the hand-eye views themselves leave uncertain, not only the file's prior: a camera
whose fx the views pin loosely loses most of its variance when fx is known, however tight its prior's
share of the noise. ``own_intrinsics_share``: the same for this camera's own intrinsics alone (the
bound a close-range session of this camera could reach).

``shares_by_noise_source`` (sums to 1, said "sums to 100 %"): the estimate is linear in the graph's whitened noise near
the optimum, ``dx = Sigma J^T e`` with ``Sigma = (J^T J)^-1``, so each independent noise source ``s``
adds ``Sigma J_s^T J_s Sigma`` to the covariance, and these parts sum to ``Sigma`` exactly. This says
where the scatter comes from, not what removing a source would save: a tight intrinsics prior carries
little of the noise even when the views leave the focal length, and so the pose, loosely known.

``covariance_by_noise_source`` (source -> 6x6, rotation first, the camera pose's reference axes like
its ``covariance``; they sum to it): the same split of the whole pose covariance. The corners' and the
robot's parts are redrawn by every new set of captures; the intrinsics' and the board's (their priors'
errors) are shared by every solve with those priors, however many captures: a cross-validation's
split-to-split scatter can show only the first two (scripts/bench_heldout.py).

Both are computed on the graph reduced to its global variables (:mod:`calibgraph.solver.terms.reduced`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gtsam
import numpy as np

from calibgraph.solver.terms.reduced import SOURCES, TRANSLATION, Linear, columns, sigma_with
from calibgraph.solver.camera.session_plan import session_command

KNOWN_EXACTLY = 1e9  # the factor a source's information is multiplied by for "known exactly"
SHARE_LABELS = {
    "shares": "by parameter: the fraction of the variance that would go were it known exactly (each alone; they overlap)",
    "shares_by_noise_source": "by noise source: where the variance comes from (sums to 100 %)",
}
SOURCE_NAMES = {"corners": "corners", "intrinsics": "intrinsics", "robot_fk": "robot FK", "board": "board"}


@dataclass(frozen=True)
class Budget:
    """A camera's error budget: ``sigma_mm`` = sqrt(trace of its translation covariance); ``shares``:
    source -> fraction of that trace that would go were the source known exactly; ``own_intrinsics``:
    the same for the camera's own intrinsics; ``by_noise``: each noise source's part of the trace
    (summing to 1)."""

    sigma_mm: float
    shares: dict
    own_intrinsics: float
    by_noise: dict
    # source -> (6, 6) its part of the pose covariance (GTSAM's body frame here; reference axes once
    # the caller has turned them, as ``covariance_by_noise_source``)
    cov_by_noise: dict = field(default_factory=dict)

    def to_dict(self, advice: str = "") -> dict:
        return {"sigma_translation_norm_mm": self.sigma_mm, "shares": dict(self.shares),
                "own_intrinsics_share": self.own_intrinsics, "shares_by_noise_source": dict(self.by_noise),
                "share_labels": dict(SHARE_LABELS), "advice": advice,
                "covariance_by_noise_source": {src: np.asarray(c).tolist() for src, c in self.cov_by_noise.items()}}


def _translation_variances(L: Linear, S: np.ndarray, keys: list) -> np.ndarray:
    """trace of each camera's translation covariance (m^2) from the global information ``S``
    (inverted Jacobi-scaled: a source made 1e9 times more informative stays well conditioned)."""
    d = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
    C = np.linalg.inv(S * d[:, None] * d[None, :]) * d[:, None] * d[None, :]
    return np.array([np.trace(C[np.ix_(r, r)]) for r in
                     (np.arange(L.index[k].start, L.index[k].stop)[TRANSLATION] for k in keys)])


def conditioned_variance(L: Linear, cam_key, known: list) -> float:
    """trace of the translation covariance (m^2) of camera ``cam_key`` given the global variables
    ``known`` exactly: ``Sigma_tt - Sigma_tk Sigma_kk^-1 Sigma_kt``."""
    C = L.covariance
    t = np.arange(L.index[cam_key].start, L.index[cam_key].stop)[TRANSLATION]
    k = np.concatenate([np.arange(L.index[x].start, L.index[x].stop) for x in known])
    C_tk = C[np.ix_(t, k)]
    return float(np.trace(C[np.ix_(t, t)]) - np.trace(C_tk @ np.linalg.solve(C[np.ix_(k, k)], C_tk.T)))


def budgets(L: Linear, cameras: dict) -> dict:
    """name -> :class:`Budget` for ``cameras`` (name -> (pose key, own intrinsics key or None)): the
    noise-source split from one solve for all their translation columns and one pass over the
    factors; each "known exactly" share from the reduced information with that source's multiplied
    by :data:`KNOWN_EXACTLY`."""
    names = list(cameras)
    X = columns(L, L.S, [(cameras[n][0], slice(0, 6)) for n in names])
    n_c = len(names)
    parts = {src: np.zeros((n_c, 6, 6)) for src in SOURCES}  # each source's part of each camera's pose covariance
    for src, keys, blocks in L.factors:
        if src == "corners":
            continue  # the many view factors: their part is the rest (the parts sum to the covariance exactly)
        JX = sum(blocks[k] @ X[k] for k in keys).reshape(-1, n_c, 6)
        parts[src] += np.einsum("rci,rcj->cij", JX, JX)
    for i, n in enumerate(names):
        own = X[cameras[n][0]][:, 6 * i:6 * i + 6]  # the camera's own covariance block
        parts["corners"][i] = 0.5 * (own + own.T) - sum(parts[src][i] for src in SOURCES if src != "corners")
    cam_keys = [cameras[n][0] for n in names]
    total = _translation_variances(L, L.S, cam_keys)
    present = {src for src, _, _ in L.factors}
    known = {src: (_translation_variances(L, L.information({src: KNOWN_EXACTLY}), cam_keys) if src in present
                   else total) for src in SOURCES}
    out = {}
    for i, n in enumerate(names):
        v = total[i]
        cov = {src: p[i] for src, p in parts.items()}

        def gone(rest: float) -> float:
            return float(min(max(1.0 - rest / v, 0.0), 1.0)) if v > 0 else 0.0
        by_noise = {src: (float(np.trace(c[TRANSLATION, TRANSLATION])) / v if v > 0 else 0.0) for src, c in cov.items()}
        own_key = cameras[n][1]
        own = gone(conditioned_variance(L, cam_keys[i], [own_key])) if own_key is not None and own_key in L.index else 0.0
        out[n] = Budget(1e3 * np.sqrt(max(v, 0.0)), {src: gone(known[src][i]) for src in SOURCES}, own, by_noise, cov)
    return out


def share_lines(name: str, b: dict) -> list:
    """The console's lines for one camera's ``error_budget`` dict: both share sets, labelled (a
    result written before the sets were labelled has only ``shares``, split by noise source)."""
    def pct(x: float) -> str:
        return f"{100 * x:.0f} %" if x >= 0.01 or x == 0 else f"{100 * x:.1f} %"
    if "share_labels" not in b:
        b = {**b, "shares": {}, "shares_by_noise_source": b.get("shares", {})}
    s, by = b.get("shares", {}), b.get("shares_by_noise_source", {})
    known = ", ".join(f"{SOURCE_NAMES.get(k, k)} {pct(v)}" + (f" (its own {pct(b['own_intrinsics_share'])})"
                                                           if k == "intrinsics" and "own_intrinsics_share" in b else "")
                      for k, v in sorted(s.items(), key=lambda kv: -kv[1]))
    lines = [f"{name} {b['sigma_translation_norm_mm']:.2f} mm" + (f"; variance gone were each known exactly: {known}"
                                                                  if s else "")]
    if by:
        lines.append(" " * (len(name) + 1) + "by noise source (sums to 100 %): "
                     + ", ".join(f"{SOURCE_NAMES.get(k, k)} {pct(v)}" for k, v in sorted(by.items(), key=lambda kv: -kv[1])))
    return lines


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
    close-range images, whose information adds to the file's rather than replacing it.

    The line opens with the bound of what the remedy improves (:func:`_head`): the remedy's predicted
    1-sigma is never below it."""
    options = {}
    has_K = own_K_key is not None and own_K_key in L.prior_K
    if has_K:  # the bound first: intrinsics known exactly
        n_k = L.prior_K[own_K_key].shape[0]
        options["session"] = sigma_with(L, cam_key, add_info={own_K_key: np.eye(n_k) * 1e12 - L.prior_K[own_K_key]})
    options["poses"] = sigma_with(L, cam_key, S=doubled if doubled is not None else doubled_information(L),
                                  cov=doubled_cov)
    s_keys = [k for k in L.index if chr(gtsam.Symbol(k).chr()) == "s"]
    if s_keys:
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
    head = _head(name, b, best)
    if best == "session":
        how, bound = ((("25 more close-range images, calibrated together with its first session's" if has_session
                        else "a close-range session of 25 images"), "") if realistic
                      else ("a close-range intrinsics session", " at best (its intrinsics then known exactly)"))
        return (f"{head}; {how} ({session_command(name)}) would bring it to about "
                f"{s:.2f} mm{bound}")
    if best == "board":
        return (f"{head}; measuring the board's pitch (ruler or caliper) and solving with it fixed "
                f"(--fixed-board-scale) would bring it to about {s:.2f} mm")
    return (f"{head}; twice the poses, with more depth spread and tilt in its view, would bring it to about "
            f"{s:.2f} mm")


def _head(name: str, b: Budget, remedy: str) -> str:
    """The advice line's opening: the bound of what the remedy improves. A session or a measured
    board: what that source known exactly would leave, ``sigma * sqrt(1 - share)`` (by parameter).
    Twice the poses: twice the views' information (corners and robot poses, ``J_v``) gives the
    covariance ``(Sigma^-1 + J_v^T J_v)^-1``; in the whitened system its eigenvalues are ``1 / (1 + m)``
    (``0 <= m <= 1``), and the trace over the camera's translation is a weighted mean of them whose
    weighted mean ``m`` is the views' share by noise source. ``1 / (1 + m)`` is convex, so (Jensen) the
    bound is ``sigma / sqrt(1 + share)``: at most a factor sqrt(2), however large the share (it was
    ``sigma * sqrt(1 - share)``, true but empty when the views are all of the variance)."""
    if remedy == "session":
        what, share = "its intrinsics known exactly would take", b.own_intrinsics
    elif remedy == "board":
        what, share = "the board's scale known exactly would take", b.shares["board"]
    else:
        share = b.by_noise["corners"] + b.by_noise["robot_fk"]
        return (f"{name}: its views' noise (corners and robot poses) is {100 * share:.0f} % of its variance, so twice "
                f"the poses take its {b.sigma_mm:.2f} mm 1σ to no less than "
                f"{b.sigma_mm / np.sqrt(1.0 + max(share, 0.0)):.2f} mm")
    return (f"{name}: {what} its {b.sigma_mm:.2f} mm 1σ to {b.sigma_mm * np.sqrt(max(1.0 - share, 0.0)):.2f} mm "
            f"({100 * share:.0f} % of its variance)")
