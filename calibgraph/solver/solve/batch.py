"""The batch solve: a :class:`~calibgraph.core.problem.Problem` in, a :class:`Result` out.

It reads as GTSAM's own SFMExample does, one stage per module::

    views      the detections as views (too few corners, no PnP solution: refused)   terms/views.py
    start      unknown intrinsics from the board homographies; initial camera poses
               and board mount from the views' PnP poses                               fit/start.py
    optimise   robust rounds, FK check, corner-noise model, final graph, marginals     solve/optimise.py
    camera     intrinsics the data reject re-solved with a wide prior, board scale    solve/camera_model.py
    assemble   poses with covariances in reference axes, pairs, residuals, notes      solve/assemble.py

The graph itself (keys, factors, formulations, LM, marginals) is :mod:`calibgraph.solver.fit.graph`.
A camera moved during capture (its views split into two self-consistent groups) is calibrated
from the views after the move, with a note naming it (:mod:`calibgraph.solver.changes.moved`).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from calibgraph.core.errors import ObservabilityError
from calibgraph.core.problem import Problem, with_repeatability
from calibgraph.core.transforms import log_so3
from calibgraph.solver.robot import kinematics as kin
from calibgraph.solver.solve.assemble import (
    camera_result,
    error_budgets,
    mount_and_robot_poses,
    not_calibrated,
    pair_results,
    robot_result,
)
from calibgraph.solver.terms.reduced import linearise_graph
from calibgraph.solver.solve.camera_model import (board_scale, hold_unseparable_scale, offsets_depart, intrinsics_notes,
                                                  widen_inadequate_intrinsics)
from calibgraph.solver.uncertainty.covariance import crlb  # noqa: F401 - public here: the benchmarks' bound
from calibgraph.solver.robot.fk_check import fk_note, fk_record
from calibgraph.solver.terms.keys import B, C, K, O, S
from calibgraph.solver.robot.kinematics_select import choose_kinematics
from calibgraph.solver.changes.moved import solve_minding_moves
from calibgraph.solver.terms.noise_model import corner_noise_notes
from calibgraph.solver.uncertainty.observability import check_before_solve
from calibgraph.solver.solve.optimise import kinematics_start, solve_joint, solve_single
from calibgraph.solver.uncertainty.prediction import expected_prediction, prediction_notes
from calibgraph.solver.output.result import Result
from calibgraph.solver.fit.start import initial_intrinsics, initial_values
from calibgraph.solver.fit.timing import STAGES, timed  # noqa: F401 - STAGES: the keys of ``timings``
from calibgraph.solver.terms.views import captures_by_camera, usable_views


def solve(problem: Problem, initial: dict | None = None, seed: int = 0, timings: dict | None = None) -> Result:
    """Calibrate all cameras of ``problem``.

    Args:
        problem: a validated :class:`Problem`.
        initial: optional initial guess ``{"T_ref_cam": {name: 4x4}, "T_mount_board": 4x4}``; the
            robust initialiser runs anyway and the start that ends with the lower cost wins.
        seed: RANSAC seed (results are deterministic for a given seed).
        timings: when a dict, the wall time (s) of each stage in ``STAGES`` is added to it.
    Returns:
        :class:`Result`.
    Raises:
        ObservabilityError: a camera has too few views or the motion leaves a parameter undetermined.
        InputError: formulation 'corner' was asked for a camera with k3..k6 distortion; joint offsets
            were asked for and the recorded joint angles do not give the recorded flange poses.
    """
    t0 = time.perf_counter()
    problem = problem.with_(options=with_repeatability(problem.options))
    if problem.options.kinematics == "joint-offsets":  # asked for: checked as 'auto' checks before it tries them
        kin.check_recorded_angles(problem.options.kinematics_model, problem.captures)
    result = solve_minding_moves(problem, lambda p: solve_once(p, initial, seed, timings))
    if problem.options.kinematics == "auto":
        with timed(timings, "kinematics_select"):
            result = choose_kinematics(problem, result,
                                       lambda p: solve_minding_moves(p, lambda q: solve_once(q, initial, seed)))
    if not result.converged:
        result = unsettled(problem, result, lambda p, start: solve_minding_moves(p, lambda q: solve_once(q, start, seed)))
    return replace(result, solve_time_s=time.perf_counter() - t0)


UNSETTLED_MAHALANOBIS2 = 16.81  # a camera moved this far (6 dof, p = 0.01) between two solves is not calibrated


def unsettled(problem: Problem, result: Result, resolve) -> Result:
    """A solve that did not converge (an LM run stopped at its iteration limit, or the robust rounds kept
    changing which corners and views count) never gives a confident answer. It is solved once more from
    where it ended (``resolve(problem, start)``); if that one converges, it is the result. Otherwise each
    camera's pose moved ``d`` between the two (reference axes, as its covariance): its covariance takes
    ``d d^T`` more, a note says the camera's pose is unsettled by that much, and a camera whose move is
    beyond :data:`UNSETTLED_MAHALANOBIS2` of its own covariance is reported not calibrated (exit 3)."""
    cams = {n: c.T_ref_cam for n, c in result.cameras.items() if c.calibrated}
    if not cams or result.T_mount_board is None:
        return result
    try:
        again = resolve(problem, {"T_ref_cam": cams, "T_mount_board": result.T_mount_board})
    except ObservabilityError:
        again = None
    if again is not None and again.converged:
        return again
    if again is None:
        return result
    out, notes = dict(result.cameras), list(result.notes)
    for n, c in result.cameras.items():
        o = again.cameras.get(n)
        if not c.calibrated or o is None or not o.calibrated:
            continue
        d = np.concatenate([log_so3(c.T_ref_cam[:3, :3] @ o.T_ref_cam[:3, :3].T), c.T_ref_cam[:3, 3] - o.T_ref_cam[:3, 3]])
        m2 = float(d @ np.linalg.solve(c.covariance, d))
        mm, deg = 1e3 * float(np.linalg.norm(d[3:])), float(np.degrees(np.linalg.norm(d[:3])))
        if m2 > UNSETTLED_MAHALANOBIS2:
            why = (f"the solver did not converge, and solved again from where it stopped the camera moved {mm:.1f} mm "
                   f"and {deg:.2f} deg (Mahalanobis^2 {m2:.0f} in its 1-sigma): its pose is not settled; add views of it "
                   "or check them (the robust rounds kept changing which corners count)")
            out[n] = not_calibrated(problem, n, why, list(c.views_rejected))
            notes.append(f"camera {n} is NOT calibrated: {why}")
        else:
            out[n] = replace(c, covariance=c.covariance + np.outer(d, d))
            notes.append(f"camera {n}: the solver did not converge; solved again from where it stopped the camera moved "
                         f"{mm:.2f} mm and {deg:.3f} deg, and its 1-sigma is widened by that much")
    return replace(result, cameras=out, notes=tuple(notes))


def _pose_mount_covariances(problem: Problem, groups: list) -> dict:
    """camera -> (joint body-frame covariance of its pose, the board mount and, when estimated, its
    intrinsics K(c), the board scale S(0) and the joint offsets O(0); K(c)'s size or 0; whether S(0)
    is in; O(0)'s size or 0) (the view formulation's joint graph only; {} otherwise)."""
    est = groups[0].est
    if problem.method != "joint" or est.formulation != "view":
        return {}
    n_o = len(est.values.atVector(O(0))) if est.values.exists(O(0)) else 0
    out = {}
    for n in groups[0].names:
        if n in est.slots:
            s = est.slots[n]
            n_k = len(est.values.atVector(K(s))) if est.values.exists(K(s)) else 0
            scale = est.marginals.has(S(0))
            held = est.held_scale is not None and hasattr(est.marginals, "joint_with_scale")
            keys = [C(s), B(0)] + ([K(s)] if n_k else []) + ([S(0)] if scale else []) + ([O(0)] if n_o else [])
            try:
                if held:  # the board solved at its declared pitch: the scale's prior and how the poses move with it
                    out[n] = (est.marginals.joint_with_scale(keys, at=2 + int(bool(n_k))), n_k, True, n_o)
                    continue
                out[n] = (est.marginals.joint(keys), n_k, scale, n_o)
            except (RuntimeError, KeyError, IndexError):
                continue
    return out


def _corrected_flange_poses(problem: Problem, result: Result) -> dict | None:
    """With joint offsets estimated: capture -> (FK(q + offsets), its flange-frame Jacobian on the free
    offsets (6, n_free)): how a user applies the calibration then (the corrected arm model and the
    reported joint angles). None without kinematics or offsets."""
    ks = kin.setup(problem)
    if ks is None or not result.robot or result.robot.get("joint_offsets_rad") is None:
        return None
    return kin.corrected_flange_poses(ks, result.robot["joint_offsets_rad"]) or None


def with_prediction(problem: Problem, result: Result, pose_mount_cov: dict | None = None) -> Result:
    """``result`` with each calibrated camera's expected error for a new pose predicted from its
    reported FK, and a note saying it (:mod:`calibgraph.solver.uncertainty.prediction`); with joint offsets
    estimated, from its reported joint angles through the corrected arm model, the offsets'
    uncertainty in the calibration part."""
    corrected = None
    if problem.options.kinematics == "joint-offsets":
        corrected = _corrected_flange_poses(problem, result)
        if corrected is None:
            return result
    fk = result.fk_noise or {}
    # a component the held-out captures kept at its stated sigma still departs as far as the fit says
    # (fk_select): a new pose's FK error is that size, whatever weight the graph gave it
    pred = expected_prediction(problem, result,
                               fk.get("prediction_sigma_translation_m", fk.get("used_sigma_translation_m",
                                                                                problem.options.fk_sigma_translation_m)),
                               fk.get("prediction_sigma_rotation_rad", fk.get("used_sigma_rotation_rad",
                                                                              problem.options.fk_sigma_rotation_rad)),
                               pose_mount_cov, corrected=corrected)
    if not pred:
        return result
    cameras = {n: replace(c, prediction=pred[n]) if n in pred else c for n, c in result.cameras.items()}
    return replace(result, cameras=cameras, notes=result.notes + tuple(prediction_notes(pred)))


def solve_once(problem: Problem, initial: dict | None = None, seed: int = 0, timings: dict | None = None) -> Result:
    """One solve of ``problem``, without the moved-camera test (see :func:`solve`)."""
    t0 = time.perf_counter()
    given, aside = problem, {}
    while True:  # a camera too few of whose views are usable is not calibrated; the others are solved
        try:
            problem = initial_intrinsics(given if not aside else given.with_(
                cameras={n: c for n, c in given.cameras.items() if n not in aside},
                detections=tuple(d for d in given.detections if d.camera not in aside)))
            with timed(timings, "candidates"):
                views, cands, rejected = usable_views(problem)
            check_before_solve(problem, captures_by_camera(views))
            break
        except ObservabilityError as e:
            if e.camera not in given.cameras or e.camera in aside or len(given.cameras) - len(aside) < 2:
                raise
            aside[e.camera] = _why_not_solved(str(e), e.camera)
    starts = initial_values(problem, views, cands, seed, initial, timings)
    groups, notes = _optimise(problem, views, starts, timings)
    result = _assemble(problem, groups, rejected, notes, time.perf_counter() - t0)
    return _with_set_aside(given, result, aside, rejected) if aside else result


def _why_not_solved(message: str, name: str) -> str:
    """The refusal of camera ``name`` as the why of a camera not calibrated (its name said once)."""
    if message.startswith(f"camera {name!r}: "):
        return message[len(f"camera {name!r}: "):]
    return "it " + message[len(f"camera {name!r} "):] if message.startswith(f"camera {name!r} ") else message


def _with_set_aside(problem: Problem, result: Result, aside: dict, rejected: list) -> Result:
    """``result`` with the cameras of ``aside`` (name -> why) reported not calibrated, in the
    problem's camera order, each with a note."""
    cams = {**result.cameras, **{n: not_calibrated(problem, n, why, rejected) for n, why in aside.items()}}
    cams = {n: cams[n] for n in problem.cameras if n in cams}
    notes = [*result.notes, *(f"camera {n} is NOT calibrated: {why}" for n, why in aside.items())]
    return replace(result, cameras=cams, notes=tuple(notes),
                   rejected_views=tuple(rv for c in cams.values() for rv in c.views_rejected))


def _optimise(problem: Problem, views: list, starts: list, timings: dict | None) -> tuple[list, list]:
    """The solved graphs (one in 'joint', one per camera in 'single') and what was noticed on the way."""
    names = list(problem.cameras)
    if problem.method == "single":
        groups = [solve_single(problem, n, views, s, timings) for n, s in zip(names, starts)]
        notes = [n for g in groups for n in g.notes]
        if problem.options.intrinsics == "auto":  # judged per camera as the joint graph judges its cameras
            judged = [widen_inadequate_intrinsics(problem, g, timings) for g in groups]
            groups = [g for g, _ in judged]
            notes += [n for _, w in judged for n in w]
        return groups, notes
    ks = kin.setup(problem)
    if ks is not None:
        kin.check_motion(ks, sorted({v.capture for v in views}))
        if problem.options.kinematics_staging == "staged":
            first = kinematics_start(problem, names, views, starts, ks, timings)
            starts = [first] + [replace(s, joint_offsets=first.joint_offsets) for s in starts[1:]]
    group = solve_joint(problem, names, views, starts, timings)
    notes = list(group.notes)
    if problem.options.intrinsics == "auto":
        group, widened = widen_inadequate_intrinsics(problem, group, timings)
        notes += widened
    group = hold_unseparable_scale(problem, group, timings)
    return [group], notes


def _assemble(problem: Problem, groups: list, rejected: list, notes: list, solve_time_s: float) -> Result:
    cameras, rejected_corners = {}, []
    for g in groups:
        budget = error_budgets(problem, g, g.est.linear or linearise_graph(g.est.graph, g.est.values))
        for n in g.names:
            cameras[n], corners = camera_result(problem, n, g, rejected, budget[n])
            rejected_corners += corners
        for n, why in g.dropped.items():
            cameras[n] = not_calibrated(problem, n, why, rejected)
    cameras = {n: cameras[n] for n in problem.cameras if n in cameras}
    T_mount_board, mount_cov, T_base_flange_est = mount_and_robot_poses(problem, groups)
    angles = problem.records_joint_angles
    fk_notes = next((n for n in (fk_note(problem.options, g.est.fk_ratio, g.est.jackknife, angles) for g in groups)
                     if n), [])
    robot_suspect = any((g.est.fk_ratio is not None and g.est.fk_ratio.significant) or offsets_depart(g.est)
                        for g in groups)
    scale, scale_sigma, scale_notes = board_scale(problem, groups, robot_suspect)
    notes = [*notes, *scale_notes, *intrinsics_notes(cameras)]
    notes += [f"camera {n} is NOT calibrated: {c.why}" for n, c in cameras.items() if not c.calibrated]
    for g in groups:
        notes += corner_noise_notes(g.est.mode_ratios)
    notes += fk_notes
    robot = None
    ks = kin.setup(problem)
    if ks is not None:
        robot, robot_notes = robot_result(problem, ks, groups[0])
        notes += robot_notes
    settings = {k: getattr(problem.options, k) for k in problem.options.__dataclass_fields__}
    # the default applies only to cameras whose intrinsics do not state a source: each camera's own
    # provenance is in its intrinsics record (source_given, source_stated, source_used)
    settings["intrinsics_source_default"] = settings.pop("intrinsics_source")
    settings["kinematics_used"] = "joint-offsets" if problem.options.kinematics == "joint-offsets" else "none"
    settings["formulation_used"] = groups[0].est.formulation
    fk_ratio = groups[0].est.fk_ratio if len(groups) == 1 else None
    jackknife = groups[0].est.jackknife if len(groups) == 1 else None
    return with_prediction(problem, Result(
        mode=problem.mode, method=problem.method, cameras=cameras, T_mount_board=T_mount_board,
        mount_covariance=mount_cov, pairs=pair_results([n for n in problem.cameras if cameras[n].calibrated], cameras,
                                                       groups, problem.method == "joint"),
        converged=all(g.est.converged for g in groups),
        iterations=sum(g.est.iterations for g in groups), final_cost=sum(g.est.cost for g in groups),
        pixel_sigma_px=float(np.mean([g.est.sigma_px for g in groups])), solve_time_s=solve_time_s,
        rejected_views=tuple(rv for c in cameras.values() for rv in c.views_rejected),
        rejected_corners=tuple(rejected_corners), T_base_flange_est=T_base_flange_est, settings=settings,
        board_scale=scale, board_scale_sigma=scale_sigma, notes=tuple(notes), robot=robot,
        fk_noise=fk_record(problem.options, fk_ratio, jackknife),
    ), _pose_mount_covariances(problem, groups))
