"""Autonomous calibration of a cell whose camera placements are unknown.

    survey (discover) -> refine each camera's coarse pose -> active loop -> stop rule -> batch solve

1. **Survey** (:mod:`calibgraph.plan.survey`): the board is swept round the base in widening
   rounds; every live camera grabs at every stop. A camera that sees the board gets tilted
   refinement stops until the iSAM2 solver (:class:`~calibgraph.solver.incremental.IncrementalSolver`,
   whose consensus initialiser resolves the planar mirror ambiguity across views) gives it a pose
   with a covariance. The survey ends when every camera has one, or after the last round, with a
   line per camera that was never seen (or seen but not initialised) and what it saw.
2. **Pixel noise**: a batch solve of the survey estimates the corner noise; the iSAM2 solver is
   rebuilt with it, so its 1-sigma is the batch solver's.
3. **Active loop** (:mod:`calibgraph.plan.active`): the next pose is the candidate with the highest
   expected reduction of the cameras' shortfall per second, predicted on the linearised graph of
   the captures so far; after each capture iSAM2 updates, the batch solver solves every capture
   so far (a fraction of a second at these sizes) and its 1-sigma goes into the plan log beside
   the predicted one.
4. **Stop**: when the batch solve says every placed camera is within tolerance (its 1-sigma is
   what ``result.json`` reports), otherwise the loop goes on until ``max_poses`` captures. (The
   loop used to trust iSAM2, scaled once to the survey's batch solve; the ratio shrinks as the
   board scale and mount get determined, and the top-down cell ran ~10 captures past convergence.)
   A camera short of tolerance at the end gets a line saying why and what would help.

Every motion goes through the same checks as :func:`calibgraph.acquire.run.run_acquisition`
(joint limits, workspace box along the path, speed cap; :mod:`calibgraph.acquire.safety`), after a
collision check in the planning world (the robot and the cell's declared geometry, with keep-out
volumes round the estimated camera stands).

Files in ``out_dir`` (a ``calibgraph-dataset/1``, solvable by ``calibgraph solve`` at any time):

- ``captures/NNNNNN.json`` and ``images/<camera>/NNNNNN.png`` as always: step k is capture k;
- ``plan_log.json`` (``calibgraph-plan-log/1``), the journal: per step the pose, the phase, why it
  was chosen, the cameras expected and those that saw the board, predicted and achieved 1-sigma
  per camera (mm, deg), the motion time, the board centre of the capture (``board_centre_m``);
  active steps add the best candidates of the choice (``candidates``: board centre, score = gain
  per second, gain; best first, at most 20), ``chosen_candidate`` (its index there) and
  ``chosen_board_centre_m``, which the rerun recording shows; rewritten atomically after each
  step's capture file;
- ``result.json``: the batch solve at the stop.

Resume (``resume=True``) after a kill at any instant: captures on disk are replayed into the
solver (a capture written just before the kill but missing from the log is recovered), survey
stops already done are not repeated, and the loop carries on from the robot's actual joints.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, UnreachableError
from calibgraph.acquire.run import normalise_detection
from calibgraph.acquire.safety import (
    FRANKA_LIMITS,
    SafetyLimits,
    check_motion,
    check_speed,
    fk_function,
)
from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.core.problem import Capture, Detection
from calibgraph.core.transforms import pose_error
from calibgraph.detect.corners import detect_image
from calibgraph.io.dataset import image_relpath, write_capture, write_header
from calibgraph.io.files import atomic_write_png, atomic_write_text, output_folder
from calibgraph.io.layouts import load_dataset
from calibgraph.plan.active import (
    ActivePlanner,
    CameraBelief,
    explain_shortfall,
    keepout_violation,
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
from calibgraph.solver.batch import solve
from calibgraph.solver.build import build_problem
from calibgraph.solver.incremental import IncrementalSolver
from calibgraph.solver.initialise import pnp_candidates

__all__ = ["AutoOptions", "AutoReport", "run_auto", "PLAN_LOG_NAME"]

PLAN_LOG_FORMAT = "calibgraph-plan-log/1"
PLAN_LOG_NAME = "plan_log.json"
REFINE_BATCHES = 2  # refinement batches (of 4 stops) per camera before the survey gives up on it


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
        result: the batch :class:`~calibgraph.solver.result.Result` at the stop, or None.
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


def _sig(cov):
    return None if cov is None else [round(v, 4) for v in sigma_norms(cov)]


@dataclass
class _Loop:
    robot: object
    cams: dict
    cell: object
    world: object
    out: Path
    detector: object
    safety: SafetyLimits
    opts: AutoOptions
    log: callable
    intr: dict = field(default_factory=dict)
    steps: list = field(default_factory=list)
    views_bb: dict = field(default_factory=dict)  # camera -> [T_base_board (nominal mount) of its views]
    first_view: dict = field(default_factory=dict)  # camera -> (T_base_board, R (m,3,3), t (m,3))
    pnp_views: dict = field(default_factory=dict)  # camera not placed -> [(T_base_board, R, t, rms)] of its views
    refuted: dict = field(default_factory=dict)  # camera -> camera positions a facing stop did not show the board to
    history: list = field(default_factory=list)  # per capture fed: (T_base_flange, cameras that saw the board)
    rejections: dict = field(default_factory=dict)  # camera -> {reason: count}
    pixel_sigma_px: float | None = None
    cov_scale: dict = field(default_factory=dict)  # camera -> variance factor bringing iSAM2 to the batch 1-sigma
    est: object = None
    ref: object = None  # the batch Result of the captures so far (None: stale or failed), see refresh()
    ref_at: int = -1  # n_captures when ``ref`` was solved
    lost: list = field(default_factory=list)
    messages: list = field(default_factory=list)

    # -- solver ------------------------------------------------------------------------------------
    def new_solver(self):
        kw = {"pixel_sigma_px": self.pixel_sigma_px} if self.pixel_sigma_px else {}
        self.inc = IncrementalSolver(self.cell.target.points_board_m, dict(self.intr), **kw)
        self.est = None

    def feed(self, cap, dets):
        self.est = self.inc.add_capture(cap, dets)
        self.history.append((np.asarray(cap.T_base_flange, float), tuple(sorted({d.camera for d in dets}))))
        for d in dets:
            T_bb = cap.T_base_flange @ self.cell.T_flange_board
            self.views_bb.setdefault(d.camera, []).append(T_bb)
            if d.camera not in self.first_view or d.camera not in _placed(self):
                R, t, rms = pnp_candidates(self.cell.target.points_board_m[d.ids], d.uv_px, self.intr[d.camera])
                if len(R):
                    self.first_view.setdefault(d.camera, (T_bb, R, t))
                    self.pnp_views.setdefault(d.camera, []).append((T_bb, R, t, rms))

    def replay(self):
        """Rebuild the solver from the capture files on disk (resume, or a new pixel sigma)."""
        self.new_solver()
        self.views_bb, self.first_view, self.history, self.pnp_views = {}, {}, [], {}
        for cap, dets in self.captures_on_disk():
            self.feed(cap, dets)

    def captures_on_disk(self):
        out = []
        for f in sorted((self.out / "captures").glob("*.json")):
            d = json.loads(f.read_text())
            cap = Capture(index=int(d["index"]), T_base_flange=np.asarray(d["T_base_flange"], float),
                          q_rad=None if d.get("q_rad") is None else np.asarray(d["q_rad"], float), stamp_s=d.get("stamp_s"))
            dets = []
            for c, v in (d.get("views") or {}).items():
                det = v.get("detection")
                if det and c in self.intr:
                    dets.append(Detection(camera=c, capture=cap.index, ids=np.asarray(det["ids"], int),
                                          uv_px=np.asarray(det["uv_px"], float)))
            out.append((cap, dets))
        return out

    def mount(self):
        if self.est is not None and self.est.T_mount_board is not None:
            return self.est.T_mount_board
        return self.cell.T_flange_board

    def cov(self, name):
        ce = self.est.cameras.get(name) if self.est else None
        if ce is None or ce.covariance is None:
            return None
        return ce.covariance * self.cov_scale.get(name, 1.0)

    def _ref_camera(self, name):
        """The batch solve's camera result when that solve covers every capture so far, else None."""
        if self.ref is None or self.ref_at != self.n_captures:
            return None
        return self.ref.cameras.get(name)

    def beliefs(self) -> dict:
        """What the planner knows per placed camera: the batch solve of every capture so far when there
        is one (pose and covariance marginal over the mount, board scale and intrinsics: the numbers the
        stop rule and ``result.json`` use), else iSAM2's, scaled to the last batch solve."""
        out = {}
        for n, ce in (self.est.cameras if self.est else {}).items():
            rc = self._ref_camera(n)
            if rc is not None:
                out[n] = CameraBelief(n, self.intr[n], rc.T_ref_cam, rc.covariance, ce.views)
            else:
                out[n] = CameraBelief(n, self.intr[n], ce.T_ref_cam, self.cov(n), ce.views)
        return out

    def sigmas(self) -> dict:
        """camera -> [1-sigma mm, deg] the loop works with (see :meth:`beliefs`)."""
        return {n: _sig(b.covariance) for n, b in self.beliefs().items()}

    def refresh(self):
        """Batch-solve every capture so far (a fraction of a second: the views of a calibration are few)
        and make it the loop's reference: the stop rule and the next choice use its 1-sigma, iSAM2 is
        re-scaled to it. Without this the stop rule trusted iSAM2 scaled once by the batch solve of the
        survey, whose ratio shrinks as the board scale and mount get determined: on the top-down cell
        the loop went on ~10 captures past the batch solve's convergence. Returns the result or None."""
        if self.ref_at == self.n_captures:
            return self.ref
        res, _ = _batch(self)
        self.ref, self.ref_at = res, self.n_captures
        if res is not None:
            self.calibrate_to(res)
        return res

    def calibrate_to(self, res):
        """Scale each camera's iSAM2 covariance so its shortfall matches the batch result ``res``:
        the batch solver (IRLS, estimated pixel noise) is the reference the stop rule trusts."""
        tol = (self.opts.tolerance_mm, self.opts.tolerance_deg)
        for n, c in res.cameras.items():
            ce = self.est.cameras.get(n) if self.est else None
            if ce is None or ce.covariance is None:
                continue
            r_isam, r_batch = shortfall(ce.covariance, *tol), shortfall(c.covariance, *tol)
            if np.isfinite(r_isam) and r_isam > 0:
                self.cov_scale[n] = float(np.clip((r_batch / r_isam) ** 2, 0.25, 16.0))

    # -- journal -----------------------------------------------------------------------------------
    def save_log(self, stop=None):
        d = {"format": PLAN_LOG_FORMAT, "cell": self.cell.name, "cameras": list(self.intr),
             "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.opts.__dict__.items()},
             "pixel_sigma_px": self.pixel_sigma_px, "cov_scale": self.cov_scale, "steps": self.steps,
             "messages": self.messages}
        if stop is not None:
            d["stop"] = stop
        atomic_write_text(self.out / PLAN_LOG_NAME, json.dumps(d, indent=1))

    @property
    def n_captures(self) -> int:
        return sum(s["status"] in ("captured", "no_views", "recovered") for s in self.steps)

    def robot_time(self) -> float:
        return float(sum(s.get("motion_time_s", 0.0) for s in self.steps))

    def free(self, q) -> bool:
        """Keep-out round the estimated camera stands (checked for survey stops too)."""
        b = self.beliefs()
        if not b:
            return True
        T_bf = self.world.T_base_flange()
        T_bb = T_bf @ self.mount()
        tg = self.cell.target
        outline = tg.points_board_m[[0, tg.cols - 1, tg.n_points - tg.cols, tg.n_points - 1]]
        pts = np.vstack([T_bf[:3, 3], outline @ T_bb[:3, :3].T + T_bb[:3, 3]])
        return keepout_violation(pts, b, self.cell.floor_z_m) is None

    # -- one step ----------------------------------------------------------------------------------
    def step(self, phase: str, label: str, q_goal, why: str, expected=(), predicted=None, motion=None):
        """Move to ``q_goal`` (through ``motion``'s vias, or a planned free motion), capture every
        live camera, write the capture and the log. Returns the step dict."""
        k = len(self.steps)
        q_now = np.asarray(self.robot.joint_positions(), float)
        entry = {"step": k, "phase": phase, "label": label, "why": why, "q_rad": np.asarray(q_goal).tolist(),
                 "expected": list(expected), "predicted": predicted or {}, "sigma_before": self.sigmas()}
        if motion is None:
            motion = free_motion(self.world, q_now, q_goal)
        if motion is None:
            return self._skip(entry, "skipped_unreachable", "no collision-free motion in the planning world")
        fk = fk_function(self.robot, self.safety)
        limits = self.robot.joint_limits() if callable(getattr(self.robot, "joint_limits", None)) else None
        t_motion, q = 0.0, q_now
        for qq in motion:
            v = check_motion(q, qq, self.safety, fk=fk, robot_limits=limits)
            if not v.ok:
                return self._skip(entry, "skipped_unsafe", v.message, t_motion)
            try:
                self.robot.move_to_joints(qq, speed_scale=self.opts.speed_scale)
            except UnreachableError as e:
                return self._skip(entry, "skipped_unreachable", str(e), t_motion)
            t_motion += motion_time_s(q, qq, self.opts.dq_max_rad_s, self.opts.speed_scale)
            q = qq
            t_end = time.monotonic() + self.opts.settle_timeout_s
            while not self.robot.is_settled():
                if time.monotonic() > t_end:
                    return self._skip(entry, "not_settled", f"still moving after {self.opts.settle_timeout_s:g} s", t_motion)
                time.sleep(0.01)
        entry["motion_time_s"] = round(t_motion, 3)
        entry["vias"] = len(motion) - 1
        if self.opts.settle_dwell_s > 0:
            time.sleep(self.opts.settle_dwell_s)
        q_rad = np.asarray(self.robot.joint_positions(), float)
        T0 = np.asarray(self.robot.flange_pose(), float)
        stamp = time.time()
        frames = {}
        for c, cam in self.cams.items():
            if c in self.lost:
                continue
            try:
                fr = cam.grab()
                if fr is None or getattr(fr, "image", None) is None:
                    raise DeviceError("no frame")
                frames[c] = fr
            except Exception as e:  # a camera failure costs its view, never the run
                self.log(f"camera {c}: grab failed at step {k} ({type(e).__name__}: {e})")
                self.rejections.setdefault(c, {}).setdefault("grab failed", 0)
                self.rejections[c]["grab failed"] += 1
                if self.rejections[c]["grab failed"] >= 3:
                    self.lost.append(c)
                    self.messages.append(f"camera {c} lost after 3 failed grabs; continuing without it")
        T1 = np.asarray(self.robot.flange_pose(), float)
        dt_m, dr_deg = pose_error(T0, T1)
        if dt_m > 5e-4 or dr_deg > 0.05:
            return self._skip(entry, "moved_during_grab", f"flange moved {dt_m * 1e3:.2f} mm during the grab", t_motion)
        views, dets, rej = {}, [], {}
        for c, fr in frames.items():
            try:
                got, reason = normalise_detection(self.detector(fr.image, self.cell.target, self.intr[c]))
            except Exception as e:  # a detector crash costs the view
                got, reason = None, f"detection failed ({type(e).__name__}: {e})"
            if got is not None:
                ids, uv = np.asarray(got[0]).reshape(-1).astype(int), np.asarray(got[1], float).reshape(-1, 2)
                if ids.size < self.opts.min_corners:
                    got, reason = None, f"only {ids.size} points detected"
                elif ids.min() < 0 or ids.max() >= self.cell.target.n_points:
                    got, reason = None, "point ids not on the target"
            if got is None:
                rej[c] = reason
                self.rejections.setdefault(c, {}).setdefault(reason, 0)
                self.rejections[c][reason] += 1
                continue
            rel = image_relpath(c, k)
            atomic_write_png(self.out / rel, fr.image)
            views[c] = dict(image=rel, stamp_s=float(fr.stamp_s), ids=ids, uv_px=uv)
            dets.append(Detection(camera=c, capture=k, ids=ids, uv_px=uv, image=str(self.out / rel)))
        entry["T_base_flange"] = T0.tolist()
        T_bb = T0 @ self.mount()
        entry["board_centre_m"] = [round(float(v), 4) for v in T_bb[:3, :3] @ self.cell.target.points_board_m.mean(axis=0)
                                   + T_bb[:3, 3]]
        entry["seen_by"] = sorted(views)
        entry["rejected"] = rej
        if views:
            cap = Capture(index=k, T_base_flange=T0, q_rad=q_rad, stamp_s=stamp)
            write_capture(self.out, cap, views)  # the commit point of this step
            entry["status"] = "captured"
            try:
                self.feed(cap, dets)
            except Exception as e:  # the live estimate is advisory; the capture is safe on disk
                self.messages.append(f"step {k}: the live solver could not take the capture ({type(e).__name__}: {e})")
        else:
            entry["status"] = "no_views"
        self.steps.append(entry)
        if views and self.pixel_sigma_px is not None:  # past the survey: the batch solve is the reference
            self.refresh()
        entry["achieved"] = self.sigmas()
        self.save_log()
        self.log(self._line(entry))
        return entry

    def _skip(self, entry, status, msg, t_motion=0.0):
        entry.update(status=status, message=msg, motion_time_s=round(t_motion, 3), seen_by=[], achieved=self.sigmas())
        self.steps.append(entry)
        self.save_log()
        self.log(f"step {entry['step']} ({entry['label']}): {status.replace('_', ' ')}: {msg}")
        return entry

    def _line(self, e) -> str:
        s = ", ".join(f"{c} {v[0]:.2f} mm/{v[1]:.3f}°" for c, v in sorted(e["achieved"].items()) if v) or "no pose yet"
        seen = ", ".join(e["seen_by"]) or "no camera"
        return (f"step {e['step']} [{e['phase']}] {e['label']}: seen by {seen}; {e['motion_time_s']:.1f} s motion | 1σ {s}")


def _intrinsics(cams: dict, cell, log, lost) -> dict:
    intr = {}
    for name, cam in cams.items():
        try:
            intr[name] = cam.intrinsics()
        except Exception as e:  # a camera that cannot report intrinsics is left out, the others go on
            lost.append(name)
            log(f"camera {name}: LOST at start ({type(e).__name__}: {e}); continuing without it")
    missing = [c for c in cell.camera_names if c not in cams]
    if missing:
        log(f"cell cameras without a device: {missing}; calibrating the others")
    return intr


def _check_header(out: Path, target, intr: dict, resume: bool):
    head = out / "dataset.yaml"
    if head.exists() and not resume:
        raise InputError(f"{out}: a dataset already exists here; pass --resume to continue it or choose a new --out.")
    if not head.exists():
        write_header(out, target, intr)
        return
    import yaml

    d = yaml.safe_load(head.read_text()) or {}
    for c, v in (d.get("cameras") or {}).items():
        if c in intr and not np.allclose(Intrinsics.from_dict(v).K, intr[c].K, atol=1e-6):
            raise InputError(f"{head}: camera {c!r} now reports different intrinsics than when the dataset was started; "
                             "start a new dataset.")


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
             options: AutoOptions | None = None, resume: bool = False, progress=True) -> AutoReport:
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
    Returns:
        :class:`AutoReport` (``result.json`` and ``plan_log.json`` are in ``out_dir``).
    """
    import sys

    opts = options or AutoOptions()
    safety = safety or SafetyLimits()
    check_speed(opts.speed_scale, safety)
    log = progress if callable(progress) else ((lambda s: print(s, file=sys.stderr, flush=True)) if progress else
                                               (lambda s: None))
    out = Path(out_dir)
    lost = []
    cams = dict(cameras)
    intr = _intrinsics(cams, cell, log, lost)
    if not intr:
        raise DeviceError("auto: no camera could be opened.")
    output_folder(out, "dataset folder")
    _check_header(out, cell.target, intr, resume)
    L = _Loop(robot, {c: v for c, v in cams.items() if c in intr}, cell, world, out, detector or detect_image, safety,
              opts, log, intr=intr, lost=lost)
    if resume and (out / PLAN_LOG_NAME).is_file():
        d = json.loads((out / PLAN_LOG_NAME).read_text())
        L.steps = list(d.get("steps", []))
        L.refuted = refuted_from_steps(L.steps)
        L.pixel_sigma_px = d.get("pixel_sigma_px")
        L.cov_scale = dict(d.get("cov_scale") or {})
        L.messages = list(d.get("messages", []))
        logged = {s["step"] for s in L.steps}
        L.replay()
        for cap, dets in L.captures_on_disk():  # written just before a kill, before its log entry
            if cap.index not in logged:
                L.steps.append({"step": cap.index, "phase": "recovered", "label": f"capture {cap.index}",
                                "why": "capture file found on resume", "status": "recovered",
                                "seen_by": sorted(d.camera for d in dets), "motion_time_s": 0.0,
                                "q_rad": None if cap.q_rad is None else cap.q_rad.tolist()})
        L.steps.sort(key=lambda s: s["step"])
        log(f"resume: {len(L.steps)} steps in the log, {L.n_captures} capture poses; cameras placed: "
            f"{sorted(L.est.cameras) if L.est else []}")
    else:
        L.new_solver()
    L.save_log()
    stop = _survey(L)
    if stop is None:
        stop = _active(L)
    return _finish(L, stop)


def refuted_from_steps(steps) -> dict:
    """camera -> [camera positions (3,)] that a facing stop refuted, from the journaled steps."""
    out = {}
    for s in steps:
        r = s.get("refutes")
        if isinstance(r, dict) and isinstance(r.get("camera"), str):
            try:
                pos = np.asarray(r["position_m"], float).reshape(3)
            except (KeyError, TypeError, ValueError):
                continue  # a damaged entry costs one repeated stop, not the resume
            if np.all(np.isfinite(pos)):
                out.setdefault(r["camera"], []).append(pos)
    return out


def _budget_left(L) -> bool:
    return L.n_captures < L.opts.max_poses


def _placed(L) -> set:
    return set(L.est.cameras) if L.est else set()


def _survey(L):
    done = {s["label"] for s in L.steps}
    refine_tries = {}
    for s in L.steps:
        if s["label"].startswith("refine "):
            c = s["label"].split()[1]
            refine_tries[c] = refine_tries.get(c, 0) + 1
    live = [c for c in L.intr if c not in L.lost]
    for k in range(len(SURVEY_ROUNDS)):
        if set(live) <= _placed(L):
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
            L.step(f"survey round {k}", st.label, st.q_rad, st.why)
            done.add(st.label)
            r = _refine(L, done, refine_tries)
            if r:
                return r
        r = _refine(L, done, refine_tries, final=True)
        if r:
            return r
    return None


def _refine(L, done, tries, final=False):
    """Tilted stops for every camera seen but not placed yet (at most REFINE_BATCHES x 4 each),
    facing where its views put it (:func:`~calibgraph.plan.survey.camera_position_hypothesis`);
    while the two mirror candidates of an oblique view are in a tie, one stop facing the likelier
    one squarely, refuting it when the camera does not see the board."""
    while True:
        todo = [c for c in L.first_view if c not in _placed(L) and tries.get(c, 0) < 4 * REFINE_BATCHES]
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
            if c in _placed(L):
                break
            if not _budget_left(L):
                return "budget"
            label = f"refine {c} {tries.get(c, 0)}"
            tries[c] = tries.get(c, 0) + 1
            if label in done:
                continue
            e = L.step("survey refine", label, st.q_rad, st.why, expected=(c,))
            done.add(label)
            if ambiguous and e.get("status") in ("captured", "no_views") and c not in e.get("seen_by", []):
                L.refuted.setdefault(c, []).append(np.asarray(p_cam, float))
                # journaled with the step, so that --resume does not face the refuted candidate again
                e["refutes"] = {"camera": c, "position_m": [float(x) for x in p_cam]}
                L.save_log()


def _batch(L):
    """Batch solve of the dataset so far, over the cameras placed by the live solver (a camera
    never seen, or seen too little to place, would make the whole solve refuse)."""
    try:
        problem, _ = build_problem(load_dataset(L.out), "joint", None, progress=False)
        keep = _placed(L) & set(problem.cameras)
        if not keep:
            return None, "no camera placed yet"
        if keep != set(problem.cameras):
            problem = problem.with_(cameras={c: i for c, i in problem.cameras.items() if c in keep},
                                    detections=tuple(d for d in problem.detections if d.camera in keep))
        return solve(problem, seed=L.opts.seed), None
    except CalibgraphError as e:
        return None, str(e)


def _within(L, cov) -> bool:
    return shortfall(cov, L.opts.tolerance_mm, L.opts.tolerance_deg) <= 1.0


def _active(L):
    if not _placed(L):
        return "no camera could be placed during the survey"
    if L.pixel_sigma_px is None:
        res, err = _batch(L)
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
        if res is not None and res.cameras and all(_within(L, c.covariance) for c in res.cameras.values()):
            L.batch = res
            return "converged"
        b = L.beliefs()
        if not _budget_left(L):
            return "budget"
        q = np.asarray(L.robot.joint_positions(), float)
        t0 = time.perf_counter()
        ch = planner.choose(b, L.mount(), L.pixel_sigma_px or 0.5, L.opts.tolerance_mm, L.opts.tolerance_deg, q,
                            n_top_up=L.opts.candidates_per_step, history=L.history)
        t_choose = time.perf_counter() - t0
        L.world.set_q(q)
        if ch is None:
            if b and all(_within(L, x.covariance) for x in b.values()):
                return "converged_isam"
            return "no_candidate"
        e = L.step("active", f"active {L.n_captures}", ch.candidate.q_rad, ch.why, expected=ch.sees,
                   predicted={n: [round(v[0], 4), round(v[1], 4)] for n, v in ch.predicted.items()}, motion=ch.motion)
        e["choose_time_s"] = round(t_choose, 3)
        e["candidates"] = list(ch.candidates)  # the best ones, best first (the rerun recording shows them)
        e["chosen_candidate"] = ch.chosen_index
        e["chosen_board_centre_m"] = list(ch.board_centre_m)
        L.save_log()


def _finish(L, stop) -> AutoReport:
    tol = f"{L.opts.tolerance_mm:g} mm / {L.opts.tolerance_deg:g}°"
    res = getattr(L, "batch", None)
    err = None
    if res is None and L.n_captures:
        res, err = (L.ref, None) if (L.ref is not None and L.ref_at == L.n_captures) else _batch(L)
    if res is not None:
        res.save(L.out / "result.json")
    status, msgs = {}, list(L.messages)
    converged = res is not None and all(c in res.cameras and _within(L, res.cameras[c].covariance) for c in L.intr
                                        if c not in L.lost)
    for c in L.intr:
        views = L.views_bb.get(c, [])
        if c in L.lost:
            status[c] = "lost (grab failures); not calibrated"
        elif res is not None and c in res.cameras:
            t, r = sigma_norms(res.cameras[c].covariance)
            if _within(L, res.cameras[c].covariance):
                status[c] = f"within tolerance: 1σ {t:.2f} mm / {r:.3f}° from {res.cameras[c].views_used} views"
            else:
                b = CameraBelief(c, L.intr[c], res.cameras[c].T_ref_cam, res.cameras[c].covariance)
                status[c] = "SHORT of tolerance: " + explain_shortfall(c, b, views, L.cell.target, L.opts.tolerance_mm,
                                                                         L.opts.tolerance_deg)
        elif not views:
            rej = L.rejections.get(c, {})
            what = ", ".join(f"{n}x {r}" for r, n in sorted(rej.items(), key=lambda x: -x[1])[:3]) or "no frames"
            status[c] = (f"NOT FOUND: never saw the whole board in {L.n_captures} capture poses ({what}); check that it "
                         "looks at the robot's reach, or give it a hint (position_m or azimuth_deg) in the cell file")
        else:
            status[c] = (f"NOT PLACED: saw the board in {len(views)} views, too few consistent ones for a pose; "
                         "it needs views from several tilts (a hint or a larger --max-poses may help)")
    if stop == "converged":
        reason = f"every camera within {tol} (1σ, batch solve) after {L.n_captures} capture poses"
    elif stop == "converged_isam":
        reason = f"iSAM2 says every camera is within {tol} but no candidate improves the batch estimate further"
    elif stop == "budget":
        reason = f"budget of {L.opts.max_poses} capture poses used up before every camera reached {tol}"
    elif stop == "no_candidate":
        reason = ("no reachable, collision-free pose shows the board to a camera still short of tolerance "
                  "(unreachable region); stopped early")
    else:
        reason = str(stop)
    if err:
        msgs.append(f"final batch solve failed: {err}")
    L.save_log(stop={"reason": reason, "converged": converged, "captures": L.n_captures,
                     "robot_time_s": round(L.robot_time(), 2), "cameras": status})
    return AutoReport(L.out, tuple(L.steps), res, status, converged, reason, L.robot_time(), messages=tuple(msgs))
