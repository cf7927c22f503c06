"""Initial values of the graph: every camera pose and the board mount, before any optimisation.

The initialiser (:mod:`calibgraph.solver.terms.initialise`) proposes hypotheses from both PnP poses of
every view; they are ranked here by reprojection error after the linear translation solve. Per-view
PnP rotations of a small far board can be tens of degrees off, and a wrong hypothesis can be as
self-consistent in rotation as the right one; it cannot explain the corners.
"""

from __future__ import annotations

import cv2
import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import ObservabilityError
from calibgraph.core.problem import Problem
from calibgraph.solver.fit.graph import Estimate
from calibgraph.solver.terms.initialise import initialise, refine_translations
from calibgraph.solver.fit.timing import timed

INIT_SCORE_MAX_VIEWS = 300  # hypotheses of a joint graph are ranked on a subsample of this many views
# Zhang's method needs three views of a plane. From three the pose's 1-sigma holds once the wide prior
# is centred on no lens rather than on Zhang's values (solver.fit.graph.intrinsics_prior_mean): its
# Mahalanobis^2 averaged 5.9 over 89 seeds in the ring cell and 4.8 over 30 eye-in-hand (6 expected;
# before, 11.9 and up to 92: scripts/results/bench_unknown_few_views_findings.md); a camera of unknown
# intrinsics with fewer views is not calibrated
MIN_VIEWS_FOR_INTRINSICS = 3


def _plane_coordinates(p_board_m: np.ndarray) -> np.ndarray:
    """(M, 3) board points expressed in the board's own plane (z = 0), as Zhang's method needs."""
    c = p_board_m.mean(axis=0)
    _, _, Vt = np.linalg.svd(p_board_m - c)
    q = (p_board_m - c) @ Vt.T
    q[:, 2] = 0.0
    return q


def initial_intrinsics(problem: Problem) -> Problem:
    """``problem`` with every camera of unknown intrinsics given values from its own views: Zhang's
    method on the board homographies (fx, fy, cx, cy, k1, k2; OpenCV's calibrateCamera), which the
    joint graph then refines under a wide prior. Refuses a camera with too few views to do so."""
    unknown = [n for n, c in problem.cameras.items() if not c.known]
    if not unknown:
        return problem
    plane = _plane_coordinates(problem.points_board_m).astype(np.float32)
    cameras = dict(problem.cameras)
    for name in unknown:
        given = problem.cameras[name]
        dets = [d for d in problem.detections if d.camera == name and len(d.ids) >= 6]
        if len(dets) < MIN_VIEWS_FOR_INTRINSICS:
            raise ObservabilityError(
                f"camera {name!r} has no intrinsics and only {len(dets)} view(s) with 6 or more corners: at least "
                f"{MIN_VIEWS_FOR_INTRINSICS} views of the board at different tilts are needed to find them with a "
                "1-sigma that holds (or give its intrinsics: calibgraph intrinsics IMAGES --target T.yaml --out "
                "CAM.yaml).", camera=name)
        obj = [plane[d.ids] for d in dets]
        img = [d.uv_px.astype(np.float32) for d in dets]
        flags = cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_K3
        try:
            rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, (given.width_px, given.height_px), None, None,
                                                     flags=flags)
        except cv2.error as e:
            raise ObservabilityError(f"camera {name!r}: its intrinsics could not be found from its views "
                                     f"({str(e).strip().splitlines()[-1][:100]}); tilt the board more between views, "
                                     "or give its intrinsics.", camera=name) from None
        if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0):
            raise ObservabilityError(f"camera {name!r}: its views do not determine its intrinsics; tilt the board "
                                     "more between views, or give its intrinsics.", camera=name)
        cameras[name] = Intrinsics(K=K, dist=np.asarray(dist, float).reshape(-1)[:5], width_px=given.width_px,
                                   height_px=given.height_px, source="unknown")
    return problem.with_(cameras=cameras)


def _init_score(cameras: dict, views, T_ref_cam, T_mount_board) -> float:
    """Median per-view RMS reprojection error (px) of an initial guess over the views it covers."""
    vs = [v for v in views if v.camera in T_ref_cam]
    if not vs:
        return np.inf
    est = Estimate(T_ref_cam=T_ref_cam, T_mount_board=T_mount_board, T_ref_mount={})
    return float(np.median([np.sqrt(np.mean(r ** 2)) for r in est.residual_norms(vs, cameras)]))


def _subsample(cands: dict, views: list, max_views: int, seed: int):
    """At most ~max_views views, spread over cameras in proportion (at least 5 each when available)."""
    total = sum(len(v) for v in cands.values())
    if total <= max_views:
        return cands, views
    rng = np.random.default_rng(seed)
    out = {}
    for name, vs in cands.items():
        k = min(len(vs), max(5, int(np.ceil(len(vs) * max_views / total))))
        out[name] = [vs[i] for i in sorted(rng.choice(len(vs), size=k, replace=False))]
    keep = {(v.camera, v.capture) for vs in out.values() for v in vs}
    return out, [v for v in views if (v.camera, v.capture) in keep]


def best_initial_guess(cameras: dict, views: list, cands: dict, joint: bool, seed: int = 0,
                       timings: dict | None = None) -> tuple[dict, dict]:
    """The best of the initialiser's hypotheses.

    ``cameras``: name -> Intrinsics, in slot order; ``cands``: from :func:`views.view_candidates`.
    Returns (camera -> T_ref_cam, mounts) with mounts {0: T_mount_board} when ``joint``, else
    camera -> its own mount; a camera that could not be initialised is missing.
    """
    p_by_view = {(v.camera, v.capture): v.p_board_m for v in views}
    uv_by_view = {(v.camera, v.capture): v.uv_px for v in views}
    with timed(timings, "initialise"):
        hyps = initialise(list(cameras), cands, joint=joint, seed=seed)

    def translations(*args):
        with timed(timings, "refine_translations"):
            return refine_translations(*args)

    if joint:
        # rank on a subsample (large cells have thousands of views), refine the winner on all
        s_cands, s_views = _subsample(cands, views, INIT_SCORE_MAX_VIEWS, seed)
        best = None
        for T0, mounts in hyps:
            if len(hyps) > 1:
                T1, m1 = translations(s_cands, cameras, T0, mounts[0], p_by_view, uv_by_view)
                score = (-len(T1), _init_score(cameras, s_views, T1, m1))
            else:
                score = (0, 0.0)
            if best is None or score < best[0]:
                best = (score, T0, mounts[0])
        T0, m0 = translations(cands, cameras, best[1], best[2], p_by_view, uv_by_view)
        return T0, {0: m0}
    T_best, m_best, s_best = {}, {}, {}
    for T0, mounts in hyps:
        for n in mounts:
            Tn, mn = translations({n: cands.get(n, [])}, cameras, {n: T0[n]}, mounts[n], p_by_view, uv_by_view)
            sc = _init_score(cameras, [v for v in views if v.camera == n], {n: Tn[n]}, mn)
            if n not in s_best or sc < s_best[n]:
                T_best[n], m_best[n], s_best[n] = Tn[n], mn, sc
    return T_best, m_best


def initial_values(problem: Problem, views: list, cands: dict, seed: int = 0, initial: dict | None = None,
                   timings: dict | None = None) -> list:
    """The starts of the solve, as Estimates: in 'joint' the initialiser's best guess, then the
    user's ``initial`` guess ({"T_ref_cam": {name: 4x4}, "T_mount_board": 4x4}) when given; in
    'single' one start per camera, in camera order. Refuses with advice when a camera could not be
    initialised."""
    joint = problem.method == "joint"
    T_ref_cam0, mounts0 = best_initial_guess(problem.cameras, views, cands, joint, seed, timings)
    missing = [n for n in problem.cameras if n not in T_ref_cam0]
    if missing:
        raise ObservabilityError(
            f"camera(s) {missing} could not be initialised: no consistent set of views (each view's PnP disagrees "
            "with the board mount found from the other cameras); check their intrinsics and the target spec."
        )
    if not joint:
        return [Estimate(T_ref_cam={n: T_ref_cam0[n]}, T_mount_board=mounts0[n], T_ref_mount={})
                for n in problem.cameras]
    starts = [Estimate(T_ref_cam=T_ref_cam0, T_mount_board=mounts0[0], T_ref_mount={})]
    if initial:
        # a camera the guess does not name (e.g. a moved camera's pose before the move) starts where the initialiser put it
        given = {**T_ref_cam0, **{n: T for n, T in initial["T_ref_cam"].items() if n in problem.cameras}}
        starts.append(Estimate(T_ref_cam=given, T_mount_board=np.asarray(initial["T_mount_board"]), T_ref_mount={}))
    return starts
