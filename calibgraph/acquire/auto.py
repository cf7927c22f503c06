"""Autonomous calibration of a cell whose camera placements are unknown.

    survey (discover) -> refine each camera's coarse pose -> active loop -> stop rule -> batch solve

1. **Survey** (:mod:`calibgraph.plan.survey`): the board is swept round the base in widening
   rounds; every live camera grabs at every stop. A camera that sees the board gets tilted
   refinement stops until the iSAM2 solver (:class:`~calibgraph.solver.solve.incremental.IncrementalSolver`,
   whose consensus initialiser resolves the planar mirror ambiguity across views) gives it a pose
   with a covariance. The survey ends when every camera has one, or after the last round, with a
   line per camera that was never seen (or seen but not initialised) and what it saw.
2. **Pixel noise**: a batch solve of the survey estimates the corner noise; the iSAM2 solver is
   rebuilt with it, so its 1-sigma is the batch solver's.
3. **Active loop** (:mod:`calibgraph.plan.active`): the next pose is the candidate with the highest
   expected reduction of the cameras' shortfall per second, predicted on the linearised graph of
   the captures so far; after each capture iSAM2 updates, the batch solver solves every capture
   so far and its 1-sigma goes into the plan log beside the predicted one.
4. **Stop**: when the batch solve converged and says every placed camera is within tolerance, and
   passes the commissioning tolerances it is given (``accept``: the report's file; views >= 8 and
   the rest; a camera within the 1-sigma tolerance that fails them is planned for as if just
   short): its 1-sigma,
   marginal over the mount, the board scale, the FK and every camera model estimated from the
   captures (factory intrinsics under their prior), is what ``result.json`` reports; iSAM2's
   (rescaled) 1-sigma only stands in for the planner's beliefs while a batch solve fails and never
   stops the run. A camera that the captures left cannot bring within tolerance — the
   optimistic bound of :meth:`~calibgraph.plan.active.ActivePlanner.reach` stays above it at two
   choices in a row (a far camera with factory intrinsics: its focal length is tied to its depth) —
   is given up early and said so with the bound and what would help: the 1-sigma the same poses
   would give after a close-range intrinsics session (``calibgraph intrinsics``, then the camera
   file with ``--intrinsics NAME=CAM.yaml``; predicted by :mod:`calibgraph.solver.camera.session_plan`), else
   the batch solve's error-budget advice; the loop goes on for the others and stops when they
   are within tolerance ("stopped short": ``converged`` false, ``capture --auto`` exits 3),
   otherwise at ``max_poses`` captures. A camera short of tolerance at the end gets a line saying
   why and what would help.

These phases are the *plan* of the acquisition loop (:mod:`calibgraph.acquire.loop`), the one a
trajectory capture runs too: every step is a visit of that loop, so every motion gets the same
safety checks (joint limits, workspace box along the path, static geometry, speed cap;
:mod:`calibgraph.acquire.safety`) and every frame the same checks (fresh, usable, a detection with
enough valid points inside the image), after a collision check in the planning world (the robot
and the cell's declared geometry, with keep-out volumes round the estimated camera stands). The
dataset is claimed like every capture's (:mod:`calibgraph.acquire.claim`): ``made_by: auto``,
one process at a time, ``--resume`` only of an autonomous run.

Files in ``out_dir``: a ``calibgraph-dataset/1`` (solvable by ``calibgraph solve`` at any time), the
journal ``plan_log.json`` and ``result.json``, described in :mod:`calibgraph.acquire.auto_state`.

"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calibgraph.acquire.auto_state import PLAN_LOG_NAME, AutoState, refuted_from_steps
from calibgraph.acquire.claim import claim_dataset, write_or_check_header
from calibgraph.acquire.loop import Settings, Station, acquisition_loop, make_log
from calibgraph.acquire.safety import FRANKA_LIMITS, SafetyLimits, check_motion, check_speed, fk_function
from calibgraph.core.errors import InputError
from calibgraph.detect.corners import detect_image
from calibgraph.plan.active import (
    SESSION_VIEWS,
    ActivePlanner,
    CameraBelief,
    explain_shortfall,
    motion_time_s,
    shortfall,
    sigma_norms,
)
from calibgraph.plan.planner import free_motion
from calibgraph.plan.survey import (
    SURVEY_ROUNDS,
    camera_position_hypothesis,
    coarse_camera_position,
    refinement_stops,
    survey_round,
)
from calibgraph.solver.solve.incremental import IncrementalSolver
from calibgraph.solver.camera.session_plan import session_command

__all__ = ["AutoOptions", "AutoReport", "run_auto", "dry_run_survey", "refuted_from_steps", "PLAN_LOG_NAME"]

REFINE_BATCHES = 2  # refinement batches (of 4 stops) per camera before the survey gives up on it
REACH_AFTER = 3  # active captures before a camera may be given up (the first ones settle the estimates)


@dataclass(frozen=True)
class AutoOptions:
    """Knobs of the autonomous loop.

    Attributes:
        tolerance_mm, tolerance_deg: stop when every camera's 1-sigma norms are within both.
        max_poses: capture poses allowed in all (survey included).
        speed_scale: fraction of the joint velocity limits the robot moves at.
        dq_max_rad_s: joint velocity limits of the motion-time model (FR3 by default).
        seed: sampling seed of the planner.
        candidates_per_step: new candidate poses sampled before each choice.
        settle_dwell_s, settle_timeout_s: as in the acquisition state machine.
        min_corners: views with fewer detected points are rejected.
    """

    tolerance_mm: float = 0.5
    tolerance_deg: float = 0.03
    max_poses: int = 60
    speed_scale: float = 0.2
    dq_max_rad_s: tuple = tuple(FRANKA_LIMITS["fr3"]["dq_max_rad_s"])
    seed: int = 0
    candidates_per_step: int = 20
    settle_dwell_s: float = 0.0
    settle_timeout_s: float = 10.0
    min_corners: int = 6

    def __post_init__(self):
        if not (self.tolerance_mm > 0 and self.tolerance_deg > 0):
            raise InputError(f"auto: tolerances must be > 0, got {self.tolerance_mm} mm / {self.tolerance_deg} deg.")
        if int(self.max_poses) < 3:
            raise InputError(f"auto: --max-poses {self.max_poses}: at least 3 (a camera needs 3 views to be placed).")
        if not (0 < self.speed_scale <= 1):
            raise InputError(f"auto: speed scale must be in (0, 1], got {self.speed_scale}.")


@dataclass(frozen=True)
class AutoReport:
    """What the autonomous run did.

    Attributes:
        out_dir: dataset folder.
        steps: the plan log's steps (dicts, see the module docstring).
        result: the batch :class:`~calibgraph.solver.output.result.Result` at the stop, or None.
        cameras: camera -> status line (converged, short and why, never seen...).
        converged: every camera within tolerance (batch 1-sigma).
        stop_reason: why the loop ended.
        robot_time_s: predicted robot motion time of all steps (the simulated clock's model).
        dry_run: nothing moved.
    """

    out_dir: Path
    steps: tuple
    result: object
    cameras: dict
    converged: bool
    stop_reason: str
    robot_time_s: float
    dry_run: bool = False
    messages: tuple = ()

    @property
    def captures(self) -> int:
        return sum(s["status"] in ("captured", "no_views") for s in self.steps)

    def summary(self) -> str:
        if self.dry_run:
            return f"{self.stop_reason}; {self.robot_time_s:.0f} s of robot motion if every round runs; nothing moved"
        lines = [f"autonomous capture into {self.out_dir}: {self.captures} capture poses, "
                 f"robot motion {self.robot_time_s:.0f} s; {self.stop_reason}"]
        lines += [f"  {c}: {s}" for c, s in self.cameras.items()]
        lines += [f"  note: {m}" for m in self.messages]
        return "\n".join(lines)


def dry_run_survey(cell, world, safety: SafetyLimits, options: AutoOptions, q_start=None, log=print) -> AutoReport:
    """Plan every survey round and check each stop against the safety limits; nothing moves."""
    check_speed(options.speed_scale, safety)
    fk = fk_function(None, safety)
    q = world.start_configuration() if q_start is None else np.asarray(q_start, float)
    steps, t = [], 0.0
    for k in range(len(SURVEY_ROUNDS)):
        for s in survey_round(world, cell, k, q):
            motion = free_motion(world, q, s.q_rad)
            v = check_motion(q, s.q_rad, safety, fk=fk, T_goal_stated=s.T_base_flange)
            status = "planned" if (v.ok and motion is not None) else "skipped_unsafe"
            msg = v.message if not v.ok else ("" if motion is not None else "no collision-free motion")
            dt = motion_time_s(q, s.q_rad, options.dq_max_rad_s, options.speed_scale) if status == "planned" else 0.0
            steps.append({"step": len(steps), "phase": f"survey round {k}", "label": s.label, "why": s.why,
                          "q_rad": s.q_rad.tolist(), "T_base_flange": s.T_base_flange.tolist(), "status": status,
                          "message": msg, "motion_time_s": round(dt, 3)})
            log(f"survey round {k} {s.label}: {status}{': ' + msg if msg else ''}")
            if status == "planned":
                q, t = s.q_rad, t + dt
    n = sum(s["status"] == "planned" for s in steps)
    return AutoReport(Path("."), tuple(steps), None, {}, False,
                      f"dry run: {n} of {len(steps)} survey stops pass the checks (round 0 first; later rounds run "
                      "only while a camera is unseen)", t, dry_run=True)


def run_auto(robot, cameras, cell, world, out_dir, detector=None, safety: SafetyLimits | None = None,
             options: AutoOptions | None = None, resume: bool = False, progress=True, accept=None,
             watch=None) -> AutoReport:
    """Discover, refine and calibrate every camera of ``cell`` (see the module docstring).

    Args:
        robot: a :class:`~calibgraph.acquire.interfaces.Robot` (joint limits and FK used when it offers them).
        cameras: mapping name -> :class:`~calibgraph.acquire.interfaces.Camera`.
        cell: the :class:`~calibgraph.plan.cell.CellDescription` (no placements).
        world: the planning :class:`~calibgraph.plan.planner.RobotWorld` (robot + declared geometry).
        out_dir: dataset folder (new, or the one to continue with ``resume``).
        detector: ``detector(image, target, intrinsics)``; default :func:`calibgraph.detect.corners.detect_image`.
        safety: limits checked before every motion.
        options: :class:`AutoOptions`.
        progress: True prints lines to stderr, a callable receives them, False is quiet.
        accept: ``accept(result) -> {camera: [reasons]}``, the cameras a batch result fails against the
            commissioning tolerances (the commands pass the report's, ``datasets/tolerances/default.yaml``:
            views, reprojection, workspace 1σ); the stop rule then also needs it empty, so that "within
            tolerance" is never followed by the report's FAIL. None: the 1σ tolerances only.
        watch: an observer of every grab, next pose and estimate (:attr:`~calibgraph.acquire.loop.Station.watch`;
            ``capture --auto --view``), or None.
    Returns:
        :class:`AutoReport` (``result.json`` and ``plan_log.json`` are in ``out_dir``).
    """
    opts = options or AutoOptions()
    safety = safety or SafetyLimits()
    check_speed(opts.speed_scale, safety)
    log = make_log(progress)
    settings = Settings(settle_timeout_s=opts.settle_timeout_s, settle_dwell_s=opts.settle_dwell_s,
                        min_corners=opts.min_corners)
    station = Station(robot, cameras, Path(out_dir), cell.target, detector or detect_image, safety, opts.speed_scale,
                      settings, log)
    with claim_dataset(out_dir, "auto", {}, resume, log) as claim:
        station.open_cameras("auto")
        missing = [c for c in cell.camera_names if c not in station.cams]
        if missing:
            log(f"cell cameras without a device: {', '.join(missing)}; calibrating the others")
        write_or_check_header(station.out, cell.target, station.intr, "eye_to_hand", claim)
        L = AutoState(station, cell, world, opts, log, accept=accept)
        station.watch, station.estimate = watch, L.estimates
        if resume and (station.out / PLAN_LOG_NAME).is_file():
            L.reload()
        else:
            L.new_solver()
        L.save_log()
        stop, stopped = acquisition_loop(station, _phases(L))
        return _finish(L, stopped or stop)


def _phases(L):
    """The plan the acquisition loop runs: the survey, then the active loop; returns why it stopped."""
    stop = yield from _survey(L)
    if stop is None:
        stop = yield from _active(L)
    return stop


def _budget_left(L) -> bool:
    return L.n_captures < L.opts.max_poses


def _survey(L):
    done = {s["label"] for s in L.steps}
    refine_tries = {}
    for s in L.steps:
        if s["label"].startswith("refine "):
            c = s["label"].split()[1]
            refine_tries[c] = refine_tries.get(c, 0) + 1
    live = [c for c in L.intr if c not in L.lost]
    for k in range(len(SURVEY_ROUNDS)):
        if set(live) <= L.placed():
            break
        q = np.asarray(L.robot.joint_positions(), float)
        stops = survey_round(L.world, L.cell, k, q, free=L.free)
        L.world.set_q(q)
        for st in stops:
            if st.label in done:
                continue
            if not _budget_left(L):
                return "budget"
            if set(live) <= set(L.views_bb):  # every camera seen: refinement places them
                break
            yield from L.step(f"survey round {k}", st.label, st.q_rad, st.why)
            done.add(st.label)
            r = yield from _refine(L, done, refine_tries)
            if r:
                return r
        r = yield from _refine(L, done, refine_tries, final=True)
        if r:
            return r
    return None


def _refine(L, done, tries, final=False):
    """Tilted stops for every camera seen but not placed yet (at most REFINE_BATCHES x 4 each),
    facing where its views put it (:func:`~calibgraph.plan.survey.camera_position_hypothesis`);
    while the two mirror candidates of an oblique view are in a tie, one stop facing the likelier
    one squarely, refuting it when the camera does not see the board."""
    while True:
        todo = [c for c in L.first_view if c not in L.placed() and tries.get(c, 0) < 4 * REFINE_BATCHES]
        if not todo:
            return None
        c = todo[0]
        hyp = camera_position_hypothesis(L.pnp_views.get(c, []), L.refuted.get(c, ()))
        if hyp is None:  # every candidate refuted: start over from the first view's mean
            T_bb, R, t = L.first_view[c]
            p_cam, ambiguous = coarse_camera_position(T_bb, R, t), False
        else:
            p_cam, T_bb, ambiguous = hyp
        q = np.asarray(L.robot.joint_positions(), float)
        stops = refinement_stops(L.world, L.cell, c, T_bb, p_cam, 1 if ambiguous else 4, q,
                                 L.opts.seed + tries.get(c, 0), free=L.free, tilt_deg=0.0 if ambiguous else 30.0)
        L.world.set_q(q)
        if not stops:
            tries[c] = 4 * REFINE_BATCHES
            L.messages.append(f"camera {c}: no reachable tilted pose near where it saw the board")
            continue
        for st in stops:
            if c in L.placed():
                break
            if not _budget_left(L):
                return "budget"
            label = f"refine {c} {tries.get(c, 0)}"
            tries[c] = tries.get(c, 0) + 1
            if label in done:
                continue
            e = yield from L.step("survey refine", label, st.q_rad, st.why, expected=(c,))
            done.add(label)
            if ambiguous and e.get("status") in ("captured", "no_views") and c not in e.get("seen_by", []):
                L.refuted.setdefault(c, []).append(np.asarray(p_cam, float))
                # journaled with the step, so that --resume does not face the refuted candidate again
                e["refutes"] = {"camera": c, "position_m": [float(x) for x in p_cam]}
                L.save_log()


def _active(L):
    if not L.placed():
        return "no camera could be placed during the survey"
    if L.pixel_sigma_px is None:
        res, err = L.batch_solve()
        if res is not None:
            L.pixel_sigma_px = float(res.pixel_sigma_px)
            L.messages.append(f"pixel sigma {L.pixel_sigma_px:.3f} px estimated from the survey's {L.n_captures} captures")
            L.replay()
            L.calibrate_to(res)
            L.ref, L.ref_at = res, L.n_captures
        else:
            L.messages.append(f"batch solve of the survey failed ({err}); planning with iSAM2's default pixel noise")
        L.save_log()
    o = IncrementalSolver(L.cell.target.points_board_m, {}).options
    planner = ActivePlanner(L.world, L.cell, L.opts.dq_max_rad_s, L.opts.speed_scale, seed=L.opts.seed + 1,
                            fk_sigma_translation_m=o.fk_sigma_translation_m, fk_sigma_rotation_rad=o.fk_sigma_rotation_rad)
    while True:
        res = L.refresh()
        if L.accepted(res):
            L.final = res
            return "out_of_reach" if L.out_of_reach else "converged"
        b = L.beliefs()
        if not _budget_left(L):
            return "budget"
        q = np.asarray(L.robot.joint_positions(), float)
        t0 = time.perf_counter()
        ch = planner.choose(_pursue(L, res, b), L.mount(), L.pixel_sigma_px or 0.5, L.opts.tolerance_mm,
                            L.opts.tolerance_deg, q, n_top_up=L.opts.candidates_per_step, history=L.history, skip=tuple(L.out_of_reach))
        t_choose = time.perf_counter() - t0
        L.world.set_q(q)
        t0 = time.perf_counter()
        if _judge_reach(L, planner, b):
            continue  # a camera is given up: the stop rule first, then a choice without it
        t_reach = time.perf_counter() - t0
        if ch is None:  # (beliefs within tolerance but no batch solve saying so: iSAM2's 1-sigma never stops the run)
            return "no_candidate"
        e = yield from L.step("active", f"active {L.n_captures}", ch.candidate.q_rad, ch.why, expected=ch.sees,
                   predicted={n: [round(v[0], 4), round(v[1], 4)] for n, v in ch.predicted.items()}, motion=ch.motion)
        e["choose_time_s"] = round(t_choose, 3)
        e["reach_time_s"] = round(t_reach, 3)
        e["candidates"] = list(ch.candidates)  # the best ones, best first (the rerun recording shows them)
        e["chosen_candidate"] = ch.chosen_index
        e["chosen_board_centre_m"] = list(ch.board_centre_m)
        L.save_log()


PURSUE_SHORTFALL = 1.25  # how far short a camera within the 1σ tolerances is planned for while the stop rule refuses it


def _pursue(L, res, beliefs) -> dict:
    """The beliefs the planner chooses for: a camera within the 1σ tolerances that the stop rule
    still refuses - it fails the tolerance file (7 views where it asks for 8, ...), or the batch solve
    did not converge (then every camera) - is planned for as if 25 % short, so the next poses show it
    the board rather than end the run with "no candidate"."""
    if res is None or not res.cameras:
        return beliefs
    again = set(L.file_failures(res)) | (set(res.cameras) if not res.converged else set())
    out = dict(beliefs)
    for n in again & set(beliefs):
        b = beliefs[n]
        rho = shortfall(b.covariance, L.opts.tolerance_mm, L.opts.tolerance_deg) if b.covariance is not None else np.inf
        if n not in L.out_of_reach and np.isfinite(rho) and rho < PURSUE_SHORTFALL:
            out[n] = replace(b, covariance=np.asarray(b.covariance) * (PURSUE_SHORTFALL / max(rho, 1e-6)) ** 2)
    return out


def _judge_reach(L, planner, beliefs) -> bool:
    """Give up the cameras that the captures left cannot bring within tolerance: those whose
    optimistic bound (:meth:`~calibgraph.plan.active.ActivePlanner.reach`, every reachable candidate
    weighted at will) stays above it at two choices in a row. Returns True when one was given up;
    it is journaled with the bound and what would help, and the run goes on for the others."""
    tol = (L.opts.tolerance_mm, L.opts.tolerance_deg)
    short = [n for n, x in beliefs.items() if n not in L.out_of_reach and x.covariance is not None
             and not L.within(x.covariance)]
    if not short or L.pixel_sigma_px is None or sum(s["phase"] == "active" for s in L.steps) < REACH_AFTER:
        return False
    left = L.opts.max_poses - L.n_captures
    got = planner.reach(beliefs, L.mount(), L.pixel_sigma_px, left, short, history=L.history, tol_mm=tol[0],
                        tol_deg=tol[1])
    gave_up = False
    for n in short:
        r = got.get(n)
        if r is None or not r.out_of_reach(*tol):
            L.reach_strikes.pop(n, None)
            continue
        L.reach_strikes[n] = L.reach_strikes.get(n, 0) + 1
        if L.reach_strikes[n] < 2:
            continue
        t, d = sigma_norms(beliefs[n].covariance)
        L.out_of_reach[n] = {"at_capture": L.n_captures, "captures_left": left, "sigma_now": [round(t, 4), round(d, 5)],
                             "best_possible": [round(r.lower[0], 4), round(r.lower[1], 5)],
                             "design": [round(r.design[0], 4), round(r.design[1], 5)], "candidates": r.candidates}
        if r.with_session:
            L.out_of_reach[n]["with_session"] = [round(r.with_session[0], 4), round(r.with_session[1], 5)]
        line = (f"camera {n} cannot reach {tol[0]:g} mm / {tol[1]:g}° with the {_poses(left)} left: from the "
                f"reachable poses it could get to {_bound_text(r.lower, tol)} at best (now {t:.2f} mm / "
                f"{d:.3f}°){_session_text(n, r.with_session)}; calibrating the others")
        L.messages.append(line)
        L.log(line)
        gave_up = True
    if gave_up:
        L.save_log()
    return gave_up


def _poses(n) -> str:
    return f"{n} capture pose{'' if n == 1 else 's'}"


def _session_text(name, sigma) -> str:
    """'; a close-range intrinsics session ... would bring it to about 0.31 mm / 0.012° ...' (or '')."""
    if not sigma:
        return ""
    return (f"; a close-range intrinsics session of {SESSION_VIEWS} images ({session_command(name)}) would bring it to about {sigma[0]:.2f} mm / {sigma[1]:.3f}° with those poses")


def _bound_text(lower, tol) -> str:
    """'0.83 mm / 0.041°': the bounded norms (mm, deg) that exceed the tolerance (or, when none
    does, those bounded)."""
    out = [i for i in (0, 1) if lower[i] > tol[i]] or [i for i in (0, 1) if lower[i] > 0]
    return " / ".join(f"{lower[i]:.2f} mm" if i == 0 else f"{lower[i]:.3f}°" for i in out)


def _out_of_reach_status(c, rec, res, tol) -> str:
    """The summary line of camera ``c`` given up as out of reach (``rec``: its journal record): its
    1-sigma, the bound that said so, and what would help (the batch solve's error-budget advice)."""
    cr = res.cameras.get(c) if res is not None else None
    if cr is not None and cr.covariance is not None:
        t, r = sigma_norms(cr.covariance)
        now = f"1σ {t:.2f} mm / {r:.3f}° from {cr.views_used} views"
    else:
        now = "no pose"
    lo = rec.get("best_possible") or [0.0, 0.0]
    advice = _session_text(c, rec.get("with_session"))[2:] or ((cr.error_budget or {}).get("advice") if cr is not None
                                                              else None) or (
        f"a close-range intrinsics session ({session_command(c)})")
    return (f"OUT OF REACH of {tol[0]:g} mm / {tol[1]:g}°: {now}; at capture {rec.get('at_capture')} the model of the "
            f"captures so far predicted at best {_bound_text(lo, tol)} from the {_poses(rec.get('captures_left'))} "
            f"left (any reachable poses); would help: {advice}")


def _finish(L, stop) -> AutoReport:
    tol = f"{L.opts.tolerance_mm:g} mm / {L.opts.tolerance_deg:g}°"
    res = L.final
    err = None
    if res is None and L.n_captures:
        res, err = (L.ref, None) if (L.ref is not None and L.ref_at == L.n_captures) else L.batch_solve()
    if res is not None:
        res = replace(res, dataset=str(L.out), target=L.cell.target.to_dict())
        res.save(L.out / "result.json")
    status, msgs = {}, list(L.messages)
    failing = L.file_failures(res)
    converged = res is not None and res.converged and not failing and all(
        c in res.cameras and res.cameras[c].calibrated and L.within(res.cameras[c].covariance)
        for c in L.intr if c not in L.lost)
    if res is not None and not res.converged:
        msgs.append(f"the final batch solve did not converge ({res.iterations} iterations): its estimates may still "
                    "move, so the run is not reported as within tolerance")
    for c in L.intr:
        views = L.views_bb.get(c, [])
        if c in L.lost:
            status[c] = "lost (grab failures); not calibrated"
        elif res is not None and c in res.cameras and not res.cameras[c].calibrated:
            status[c] = f"NOT CALIBRATED: {res.cameras[c].why}"
        elif c in L.out_of_reach and not (res is not None and c in res.cameras and L.within(res.cameras[c].covariance)):
            status[c] = _out_of_reach_status(c, L.out_of_reach[c], res, (L.opts.tolerance_mm, L.opts.tolerance_deg))
        elif res is not None and c in res.cameras:
            t, r = sigma_norms(res.cameras[c].covariance)
            if L.within(res.cameras[c].covariance) and c in failing:
                status[c] = (f"SHORT of the commissioning tolerances (the report's file): {'; '.join(failing[c])} "
                             f"(1σ {t:.2f} mm / {r:.3f}° from {res.cameras[c].views_used} views)")
            elif L.within(res.cameras[c].covariance):
                status[c] = (f"within tolerance: 1σ {t:.2f} mm / {r:.3f}° from {res.cameras[c].views_used} views"
                             + ("" if res.converged else " (batch solve not converged)"))
            else:
                b = CameraBelief(c, L.intr[c], res.cameras[c].T_ref_cam, res.cameras[c].covariance)
                advice = (res.cameras[c].error_budget or {}).get("advice")
                status[c] = "SHORT of tolerance: " + explain_shortfall(c, b, views, L.cell.target, L.opts.tolerance_mm,
                                                                         L.opts.tolerance_deg) + (
                    f"; error budget: {advice}" if advice else "")
        elif not views:
            rej = L.station.reasons.get(c, {})
            what = ", ".join(f"{n}x {r}" for r, n in sorted(rej.items(), key=lambda x: -x[1])[:3]) or "no frames"
            status[c] = (f"NOT FOUND: never saw the whole board in {L.n_captures} capture poses ({what}); check that it "
                         "looks at the robot's reach, or give it a hint (position_m or azimuth_deg) in the cell file")
        else:
            status[c] = (f"NOT PLACED: saw the board in {len(views)} views, too few consistent ones for a pose; "
                         "it needs views from several tilts (a hint or a larger --max-poses may help)")
    if stop == "converged":
        reason = f"every camera within {tol} (1σ, batch solve) after {L.n_captures} capture poses"
    elif stop == "out_of_reach" and any(c not in L.out_of_reach for c in (res.cameras if res is not None else ())):
        reason = (f"stopped early after {L.n_captures} capture poses: every camera within {tol} (1σ, batch solve) "
                  f"except {', '.join(L.out_of_reach)}, which the reachable poses cannot bring there (see below)")
    elif stop == "out_of_reach":
        reason = (f"stopped early after {L.n_captures} capture poses: no camera can reach {tol} from the reachable "
                  "poses with the capture poses left (see below)")
    elif stop == "budget":
        reason = (f"budget of {L.opts.max_poses} capture poses used up before every camera reached {tol}"
                  + (" and the commissioning tolerances" if L.accept is not None else "")
                  + (" in a converged batch solve" if res is not None and not res.converged else ""))
    elif stop == "no_candidate":
        reason = ("no reachable, collision-free pose shows the board to a camera still short of tolerance "
                  "(unreachable region), or the batch solve failed; stopped early")
    else:
        reason = str(stop)
    if err:
        msgs.append(f"final batch solve failed: {err}")
    L.save_log(stop={"reason": reason, "converged": converged, "captures": L.n_captures,
                     "robot_time_s": round(L.robot_time(), 2), "cameras": status})
    return AutoReport(L.out, tuple(L.steps), res, status, converged, reason, L.robot_time(), messages=tuple(msgs))
