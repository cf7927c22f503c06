"""The camera model and the target against the data: intrinsics the data reject, the board's scale.

Given intrinsics are estimated under a prior as wide as their source says. When the estimate moves
further than that prior allows (chi-square, 6 dof, p < 0.001), or the residuals stay large and
radial (a lens file without its distortion), the camera is solved again with a wide prior and a
note says so. The board's printed scale is estimated with the cameras; a scale more than 3 sigma
from 1 is named with the pitch it implies.
"""

from __future__ import annotations

from dataclasses import replace


import numpy as np

from calibgraph.core.errors import ObservabilityError
from calibgraph.core.problem import Problem, intrinsics_source, uses_file_covariance
from calibgraph.solver.terms.factors import intrinsics_vector
from calibgraph.core.camera import intrinsics_names
from calibgraph.solver.fit.graph import Estimate, estimates_intrinsics, intrinsics_prior
from calibgraph.solver.terms.keys import B, C, K, O, S
from calibgraph.solver.solve.optimise import Group, solve_from_start
from calibgraph.solver.terms.views import reprojections

# A camera whose kept corners miss by more than this (px RMS), mostly along the radial direction,
# has intrinsics the prior of their source cannot fix (sub-pixel detectors on sharp boards leave
# 0.05-0.3 px).
INADEQUATE_RMS_PX = 0.5
INADEQUATE_RADIAL_FRACTION = 0.25
CHI2_6_999 = 22.46  # chi-square, 6 dof, 0.999 quantile


def radial_structure(est: Estimate, views: list, name: str, cameras: dict) -> tuple[float, float]:
    """(RMS px of the kept corners' residuals, fraction of their energy along a radial distortion
    pattern about the principal point) of camera ``name``."""
    intr = est.camera_model(name, cameras)
    mine = [v for v in views if v.camera == name and v.active]
    uv_hats = reprojections(mine, est.T_ref_cam, est.T_mount_board, est.T_ref_mount, {name: intr}, est.board_scale)
    d_all, b_all = [], []
    for v, uv_hat in zip(mine, uv_hats):
        keep = v.kept
        d_all.append(uv_hat[keep] - v.uv_px[keep])
        x = (v.uv_px[keep] - intr.K[:2, 2]) / np.array([intr.K[0, 0], intr.K[1, 1]])
        b_all.append(x * np.sum(x * x, axis=1, keepdims=True) * np.array([intr.K[0, 0], intr.K[1, 1]]))
    if not d_all:
        return 0.0, 0.0
    d, b = np.concatenate(d_all), np.concatenate(b_all)
    e_d = float(np.sum(d * d))
    if e_d <= 0 or float(np.sum(b * b)) <= 0:
        return 0.0, 0.0
    alpha = float(np.sum(d * b) / np.sum(b * b))
    return float(np.sqrt(e_d / len(d))), alpha ** 2 * float(np.sum(b * b)) / e_d


def intrinsics_disagreement(problem: Problem, est: Estimate, name: str) -> float:
    """Squared Mahalanobis distance (6 dof) between the estimated and the given [fx, fy, cx, cy, k1,
    k2] of a camera, against the covariance of that difference (prior minus posterior): large when
    the data disagree with the given values more than their source's prior allows."""
    if est.marginals is None or not estimates_intrinsics(problem, name, est):
        return 0.0
    given = problem.cameras[name]
    delta = intrinsics_vector(est.camera_model(name, problem.cameras)) - intrinsics_vector(given)
    P_prior = intrinsics_prior(problem, name, est)[:6, :6]
    P_post = est.marginals.marginalCovariance(K(est.slots[name]))[:6, :6]
    w, V = np.linalg.eigh(0.5 * (P_prior - P_post + (P_prior - P_post).T))
    keep = w > 1e-9 * max(float(w.max()), 1e-30)
    z = V[:, keep].T @ delta
    return float(np.sum(z * z / w[keep]))


WARM_RESOLVE = True  # False: the re-solve screens afresh from the given intrinsics (the slow path tests compare)


def widen_inadequate_intrinsics(problem: Problem, group: Group, timings: dict | None = None) -> tuple[Group, list]:
    """(group, notes): the group re-solved with a wide intrinsics prior for the cameras whose data
    reject their given intrinsics, or the group as it was when none does (or the re-solve fails)."""
    est, views = group.est, group.views
    bad = {}
    for n in group.names:
        if not estimates_intrinsics(problem, n, est) or n in est.wide_intrinsics or not problem.cameras[n].known:
            continue  # (a camera of unknown intrinsics has the wide prior already, around no given values)
        d2 = intrinsics_disagreement(problem, est, n)
        rms, radial = radial_structure(est, views, n, problem.cameras)
        if d2 > CHI2_6_999 or (rms > INADEQUATE_RMS_PX and radial > INADEQUATE_RADIAL_FRACTION):
            bad[n] = (d2, rms)
    if not bad:
        return group, []
    # The re-solve starts where the first ended: its values (robot poses, intrinsics and board scale
    # too) and its robust rounds' weights, set-aside views and pixel sigma. Only the wider prior moves
    # the optimum, so the rounds settle in fewer LM runs than from a fresh screening; the answer is the
    # same fixed point (tests/test_speed_paths.py compares it with the fresh re-solve).
    start = Estimate(T_ref_cam=est.T_ref_cam, T_mount_board=est.T_mount_board, T_ref_mount=dict(est.T_ref_mount),
                     intrinsics=dict(est.intrinsics), board_scale=est.board_scale,
                     wide_intrinsics=est.wide_intrinsics | frozenset(bad), free_intrinsics=est.free_intrinsics,
                     joint_offsets=est.joint_offsets)
    try:
        g2 = solve_from_start(problem, group.names, views, start, timings,
                              warm_sigma_px=group.rounds_sigma_px if WARM_RESOLVE else None)
    except ObservabilityError:
        return group, [f"camera {n}: the data disagree with its given intrinsics (chi-square {d2:.0f} on 6 dof), and "
                       "they cannot be estimated from these views; check the intrinsics" for n, (d2, _) in bad.items()]
    notes = []
    for n, (d2, rms) in bad.items():
        given = intrinsics_vector(problem.cameras[n])
        new = intrinsics_vector(g2.est.camera_model(n, problem.cameras))
        rms2 = radial_structure(g2.est, g2.views, n, problem.cameras)[0]
        src = intrinsics_source(problem.cameras[n], problem.options)
        notes.append(f"camera {n}: its given ({src}) intrinsics do not fit its images, so they were estimated from "
                     f"them instead. Detail: the data disagree with its given ({src}) intrinsics (chi-square {d2:.0f} on 6 dof; "
                     f"residual {rms:.2f} -> {rms2:.2f} px): estimated with a wide prior, fx {100 * (new[0] / given[0] - 1):+.2f} %, "
                     f"fy {100 * (new[1] / given[1] - 1):+.2f} %, cx {new[2] - given[2]:+.1f} px, cy {new[3] - given[3]:+.1f} px, "
                     f"k1 {new[4] - given[4]:+.3f}, k2 {new[5] - given[5]:+.3f} (1-sigma in the result; "
                     "--fixed-intrinsics keeps the given ones)")
    return g2, notes


class HeldScaleMarginals:
    """The marginals of a graph solved with the board's scale held at its declared value, each variable's
    covariance widened by what the scale's prior leaves possible: ``sigma^2 b_k b_k^T``, ``b_k`` the
    variable's sensitivity to the scale (its covariance with the scale over the scale's variance, in the
    graph where the scale was estimated). Mirrors :class:`~calibgraph.solver.fit.graph.Marginals`."""

    def __init__(self, inner, sensitivity: dict, sigma: float):
        self._m, self._b, self._s2 = inner, sensitivity, float(sigma) ** 2

    def _b_of(self, key, n: int) -> np.ndarray:
        return self._b.get(key, np.zeros(n))

    def marginalCovariance(self, key) -> np.ndarray:  # noqa: N802
        c = self._m.marginalCovariance(key)
        b = self._b_of(key, c.shape[0])
        return c + self._s2 * np.outer(b, b)

    def has(self, key) -> bool:
        return self._m.has(key)

    def joint(self, keys) -> np.ndarray:
        c = self._m.joint(keys)
        dims = [self._m.marginalCovariance(k).shape[0] for k in keys]
        b = np.concatenate([self._b_of(k, d) for k, d in zip(keys, dims)])
        return c + self._s2 * np.outer(b, b)

    def joint_with_scale(self, keys, at: int) -> np.ndarray:
        """:meth:`joint` of ``keys`` with the held scale's own row and column put in at position ``at``
        (a scalar variable, its variance the prior's, its covariance with each variable ``sigma^2 b_k``):
        what a prediction needs, since the board's points move with the scale as the poses move with it
        (along that direction the views barely change, so adding the poses' spread alone overstates it)."""
        c = self.joint(keys)
        dims = [self._m.marginalCovariance(k).shape[0] for k in keys]
        b = np.concatenate([self._b_of(k, d) for k, d in zip(keys, dims)])
        i = int(sum(dims[:at]))
        n = len(b)
        out = np.zeros((n + 1, n + 1))
        idx = np.r_[0:i, i + 1:n + 1]
        out[np.ix_(idx, idx)] = c
        out[idx, i] = out[i, idx] = self._s2 * b
        out[i, i] = self._s2
        return out


def offsets_depart(est: Estimate) -> bool:
    """True when the graph estimated joint zero offsets and one differs from zero beyond 3 sigma: the arm
    departs from its nominal kinematics, and the errors offsets do not model (link lengths and origins)
    scale the board's apparent size as a misprint does (an FR3 off in both: a +0.66 % 'misprint' claimed
    of a board printed true, with the offsets estimated and the per-pose FK check then passing)."""
    if est.joint_offsets is None or est.marginals is None or not est.marginals.has(O(0)):
        return False
    sd = np.sqrt(np.clip(np.diag(est.marginals.marginalCovariance(O(0))), 0.0, None))
    return bool(np.any(np.abs(np.asarray(est.joint_offsets, float)) > 3.0 * sd))


def hold_unseparable_scale(problem: Problem, group: Group, timings: dict | None = None) -> Group:
    """``group``, or the group solved again with the board's scale held at its declared value when the
    estimated scale departs from it (beyond 3 sigma) while the robot departs from its stated FK too:
    a 12-pose arm whose error repeats with its configuration scales the board's apparent size as a
    misprint does (ViSP's 8-pose Panda sample: '+7.5 % (+- 1.05 %), printed at 107.5 %', and the hand-eye
    23.6 mm from ViSP's own; with the declared pitch within 0.3 mm). The data do not tell the two apart,
    so the board is not rescaled: its declared pitch stands, and every 1-sigma keeps what the scale's
    prior (``board_scale_sigma``) leaves possible (:class:`HeldScaleMarginals`). The estimate is kept in
    ``Estimate.held_scale`` for the note."""
    est = group.est
    if (not problem.options.board_scale or est.marginals is None or not est.marginals.has(S(0))
            or est.formulation != "view"):
        return group
    departs = (est.fk_ratio is not None and est.fk_ratio.significant) or \
        float((est.jackknife or {}).get("jackknife_applied", 1.0)) > 1.0 or offsets_depart(est)
    var_s = float(est.marginals.marginalCovariance(S(0))[0, 0])
    if not departs or abs(est.board_scale - 1.0) <= 3.0 * np.sqrt(max(var_s, 0.0)):
        return group
    keys = [C(est.slots[n]) for n in group.names if n in est.slots] + [B(0)]
    keys += [K(est.slots[n]) for n in group.names if n in est.slots and est.marginals.has(K(est.slots[n]))]
    keys += [O(0)] if est.marginals.has(O(0)) else []
    sens = {}
    for k in keys:
        J = est.marginals.joint([k, S(0)])
        sens[k] = J[:-1, -1] / var_s
    held = problem.with_(options=replace(problem.options, board_scale=False))
    start = Estimate(T_ref_cam=est.T_ref_cam, T_mount_board=est.T_mount_board, T_ref_mount=dict(est.T_ref_mount),
                     intrinsics=dict(est.intrinsics), board_scale=1.0, wide_intrinsics=est.wide_intrinsics,
                     free_intrinsics=est.free_intrinsics, joint_offsets=est.joint_offsets)
    try:
        g2 = solve_from_start(held, group.names, group.views, start, timings,
                              warm_sigma_px=group.rounds_sigma_px if WARM_RESOLVE else None)
    except ObservabilityError:
        return group
    marg = HeldScaleMarginals(g2.est.marginals, sens, problem.options.board_scale_sigma)
    e2 = replace(g2.est, marginals=marg, held_scale=(float(est.board_scale), float(np.sqrt(var_s))))
    return replace(g2, est=e2, notes=group.notes + g2.notes)


def board_scale(problem: Problem, groups: list, robot_suspect: bool = False) -> tuple[float, float | None, list]:
    """(estimated board scale, its 1-sigma, notes) of the joint graph — (1, None, []) when not
    estimated — with a note when the board's printed size differs from the declared one by more
    than 3 sigma. With several graphs (--method single) each camera's scale is judged so, and the
    result keeps no shared scale (1, None, notes naming the cameras). ``robot_suspect``: the robot poses depart from forward kinematics, and a scale
    departure is then as likely the arm's kinematics as the print (the note says so, and blames
    neither)."""
    if not problem.options.board_scale:
        return 1.0, None, []
    if len(groups) != 1:  # --method single: each camera's graph its own scale, each judged as the joint one is
        notes = []
        for g in groups:
            s, sigma, said = board_scale(problem, [g], robot_suspect)
            notes += [f"camera {g.names[0]} (its own graph, --method single): {n}" for n in said]
        return 1.0, None, notes
    est = groups[0].est
    if len(groups) == 1 and est.held_scale is not None:
        s, sig = est.held_scale
        return 1.0, None, [f"the board's fitted scale is {100 * (s - 1):+.2f} % (± {100 * sig:.2f} %) off its spec, and the "
                           "robot poses depart from forward kinematics too (below): these captures cannot tell a misprint "
                           "from the arm's own error, which scales the board's apparent size just so. The board is not "
                           f"rescaled: solved at its declared pitch, every 1-sigma keeping the {100 * problem.options.board_scale_sigma:.0f} % "
                           "a print may be off. Measure the printed pitch (a ruler over ten squares) and give it in the "
                           "target spec to tell them apart"]
    if est.marginals is None or not est.marginals.has(S(0)):
        return 1.0, None, []
    s = est.board_scale
    sigma = float(np.sqrt(max(est.marginals.marginalCovariance(S(0))[0, 0], 0.0)))
    if abs(s - 1.0) <= 3 * sigma:
        return s, sigma, []
    pts = problem.points_board_m
    d = np.linalg.norm(pts[1:] - pts[:1], axis=1)
    pitch = float(d[d > 1e-9].min()) if np.any(d > 1e-9) else 0.0
    if robot_suspect:
        angles = problem.records_joint_angles
        offsets = ("joint zero offsets are tried by default (the note on them below)"
                   if angles and problem.options.kinematics == "auto" else
                   "try --estimate-kinematics joint-offsets" if angles else
                   "joint zero offsets could be estimated with the joint angles (q_rad) recorded with each capture")
        return s, sigma, [f"the board's fitted scale is {100 * (s - 1):+.2f} % (± {100 * sigma:.2f} %) off its spec, but "
                          "the robot poses also depart from forward kinematics (below): kinematic errors such as joint "
                          "zero offsets scale the board's apparent size too, so this is not taken for a misprint; "
                          f"measure the board with a ruler; {offsets}"]
    return s, sigma, [f"the board is {100 * (s - 1):+.2f} % (± {100 * sigma:.2f} %) the size the target spec declares: "
                      f"printed at {100 * s:.1f} %" + (f" (pitch {1e3 * pitch * s:.2f} mm, not {1e3 * pitch:.2f} mm)"
                                                       if pitch else "")
                      + "; the calibration accounts for it — check the print with a ruler and fix the target spec"]


# how the solver used a camera's given intrinsics (result.json ``intrinsics.source_used``)
INTRINSICS_USES = {
    "held": "held as given, not estimated",
    "factory": "estimated under the factory prior",
    "calibration": "estimated under the calibration prior",
    "file-covariance": "estimated under the covariance its file came with",
    "wide": "estimated under a wide prior: the data disagreed with the given values",
    "refine": "estimated under the --refine-intrinsics prior",
    "own-views": "none given: found from its own views",
}


def intrinsics_use(problem: Problem, name: str, est: Estimate) -> str:
    """How the solver used camera ``name``'s given intrinsics (a key of :data:`INTRINSICS_USES`)."""
    intr, o = problem.cameras[name], problem.options
    if not intr.known:
        return "own-views"
    if not estimates_intrinsics(problem, name, est):
        return "held"
    if name in est.wide_intrinsics or name in est.free_intrinsics:
        return "wide"
    if o.intrinsics == "estimate":
        return "refine"
    return "file-covariance" if uses_file_covariance(intr, o) else intrinsics_source(intr, o)


def intrinsics_record(problem: Problem, name: str, est: Estimate) -> dict:
    """The camera's intrinsics as result.json records them: the model solved with; their provenance
    (``source_given``: the source they came with, the solver's default when the camera's own did
    not say, ``source_stated``: whether it did, ``source_used``: :func:`intrinsics_use`); and, when
    estimated, ``estimated``, ``prior`` (its source, or 'wide'), ``prior_sigma`` (the prior's 1-sigma),
    ``sigma`` and ``given`` (over fx, fy, cx, cy, k1, k2, and p1, p2 (, k3) when a calibration file's
    covariance brought them in, or the full model of a camera of unknown intrinsics)."""
    intr, o = problem.cameras[name], problem.options
    d = est.camera_model(name, problem.cameras).to_dict()
    d["source_given"] = intrinsics_source(intr, o)
    d["source_stated"] = bool(intr.source)
    d["source_used"] = intrinsics_use(problem, name, est)
    if est.marginals is None or not estimates_intrinsics(problem, name, est):
        return d
    sig = np.sqrt(np.clip(np.diag(est.marginals.marginalCovariance(K(est.slots[name]))), 0, None))
    wide = name in est.wide_intrinsics or name in est.free_intrinsics
    d["estimated"] = True
    d["prior"] = "wide" if wide else intrinsics_source(intr, o)
    d["prior_sigma"] = dict(zip(intrinsics_names(sig.size),
                                np.sqrt(np.clip(np.diag(intrinsics_prior(problem, name, est)), 0, None)).tolist()))
    d["sigma"] = dict(zip(intrinsics_names(sig.size), sig.tolist()))
    d["given"] = dict(zip(intrinsics_names(sig.size), intrinsics_vector(intr, sig.size).tolist()))
    return d


def intrinsics_notes(cameras: dict) -> list:
    """A note per camera whose estimated focal length or principal point is more than 3 sigma and
    0.2 % (focal) / 2 px (principal point) away from the given values, and one per camera whose
    intrinsics were not given at all (found from its views) (``cameras``: name -> CameraResult)."""
    out = []
    for n, c in cameras.items():
        d = c.intrinsics or {}
        if d.get("estimated") and d.get("prior") == "unknown":
            Km, sig = np.asarray(d["K"], float), d["sigma"]
            out.append(f"camera {n}: no intrinsics were given (only the image size): found from its own views, "
                       f"fx {Km[0, 0]:.1f} ± {sig['fx']:.1f}, fy {Km[1, 1]:.1f} ± {sig['fy']:.1f}, "
                       f"cx {Km[0, 2]:.1f} ± {sig['cx']:.1f}, cy {Km[1, 2]:.1f} ± {sig['cy']:.1f} px; "
                       "a close-range session (calibgraph intrinsics) pins them better")
            continue
        if not d.get("estimated") or d.get("prior") == "wide":
            continue
        given, sig = d["given"], d["sigma"]
        Km = np.asarray(d["K"], float)
        est = {"fx": Km[0, 0], "fy": Km[1, 1], "cx": Km[0, 2], "cy": Km[1, 2]}
        f_rel = [(est[k] - given[k]) / given[k] for k in ("fx", "fy")]
        f_sig = [sig[k] / given[k] for k in ("fx", "fy")]
        if all(abs(r) > max(3 * s, 0.002) for r, s in zip(f_rel, f_sig)):
            out.append(f"camera {n}: focal length estimated {100 * np.mean(f_rel):+.2f} % (± {100 * np.mean(f_sig):.2f} %) "
                       "from the given intrinsics; the poses and 1-sigma account for it")
        for k in ("cx", "cy"):
            if abs(est[k] - given[k]) > max(3 * sig[k], 2.0):
                out.append(f"camera {n}: principal point {k} estimated {est[k] - given[k]:+.1f} px (± {sig[k]:.1f}) "
                           "from the given value")
    return out
