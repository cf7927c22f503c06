"""Trajectory capture: drive the robot through a fixed trajectory and record every camera's view of the board.

The trajectory is one *plan* of the acquisition loop (:mod:`calibgraph.acquire.loop`, where the
states MOVE, SETTLE, ACQUIRE, NEXT, the safety checks and the frame checks are described)::

    START -> (MOVE -> SETTLE -> ACQUIRE -> NEXT)* -> END

START   read every camera's intrinsics, claim the dataset folder (:mod:`calibgraph.acquire.claim`:
        ``dataset.yaml`` written or, on resume, checked; the lock taken), plan the whole
        trajectory against the safety limits and print what would be skipped.
NEXT    the journal entry of the pose, a progress line (views accepted per camera, and the
        incremental solver's current 1-sigma when ``on_capture`` is given), then the next
        pending pose or END.

Via poses (``capture: false``) go through MOVE and SETTLE (no dwell) and straight to NEXT:
nothing is grabbed or written; the journal and the report give them the status ``via``. They
exist because the drivers move along the straight joint-space line between consecutive poses and
:func:`calibgraph.plan.planner.plan_trajectory` checks those lines for collisions: where a line
collides it inserts via poses (a folded transit posture) so that the motion goes round the
obstacle. A via pose that cannot be reached (unsafe, unreachable, not settled) is reported like
any skipped pose, and the capture pose it led to is skipped as well (``skipped_unsafe``): the
direct motion to it is the one the planner found colliding.

Crash safety. Pose ``i`` of the trajectory becomes capture ``i``; the capture file is the proof
that the pose is done. ``acquisition.json`` (the journal, rewritten atomically after each pose)
records skipped poses and the trajectory's SHA-256. After a kill at any instant the folder
holds whole captures only: a pose whose capture file is missing is redone on ``resume`` (its
half-written images are removed first), a pose whose capture file exists is never redone, so
nothing is lost and nothing is duplicated.

What resume means for the motions. The pending poses are visited in trajectory order, skipping
the done ones. Via poses write no capture file, so they are never "done": a via pose is visited
when the capture pose it leads to (the next capture pose after it) is pending, and left out when
that pose is done before (a trailing via pose, with no capture pose after it, is always visited).
The motions the planner checked are those between *consecutive* poses of the trajectory. The
first motion after a resume starts wherever the arm is (where it stopped, or where an operator
jogged it), and a skipped pose (unsafe, unreachable, done before) joins the poses around it by a
motion that nobody checked for collisions either. Those motions still get every safety check
of MOVE (joint limits, workspace box along the path, speed cap) and the robot's own collision
reflex, but the cell geometry is not known here: before resuming on hardware, jog the arm to (or
near) the last captured pose, or to the transit posture, and watch the first motion. The
simulated robot refuses (``skipped_unreachable``) a motion whose path collides.

Trajectory YAML (``calibgraph-trajectory/1``; :class:`Trajectory` is the one trajectory type of
calibgraph, also what :func:`calibgraph.plan.planner.plan_trajectory` returns)::

    format: calibgraph-trajectory/1
    speed_scale: 0.2                   # fraction of the robot's maximum joint velocity
    workcell: default                  # optional: what it was planned for, and the planner's seed
    seed: 0
    poses:
      - q_rad: [0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785]
        T_base_flange: [[...4x4...]]   # optional: planned flange pose (used when no FK exists)
        cameras: [cam0, cam1]          # optional: cameras expected to see the whole board
      - q_rad: [1.2, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785]
        capture: false                 # optional (default true): a via pose, moved through only
      - [0.1, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785]   # a bare joint vector is fine too

The SHA-256 of a trajectory (stored in the journal and in ``dataset.yaml``'s ``made_by``, checked
on resume) covers the joint targets, the flange poses, the capture flags and the speed, not the
bookkeeping (cameras, workcell, seed).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibgraph.acquire.claim import TRAJECTORY_RUNS, claim_dataset, write_or_check_header
from calibgraph.acquire.loop import (
    Outcome,
    Settings,
    State,
    Station,
    Visit,
    acquisition_loop,
    make_log,
    normalise_detection,
)
from calibgraph.acquire.safety import SafetyLimits, Verdict, check_motion, check_speed
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.detect.corners import detect_image
from calibgraph.io.dataset import capture_path, image_relpath
from calibgraph.io.files import atomic_write_bytes, read_input_bytes
from calibgraph.plan.information import sigma_norms
from calibgraph.plan.trajectory import Trajectory, load_trajectory, save_trajectory

__all__ = ["AcquisitionReport", "PoseOutcome", "State", "run_acquisition", "normalise_detection", "JOURNAL_NAME",
           "Trajectory", "load_trajectory"]

JOURNAL_FORMAT = "calibgraph-acquisition/1"
JOURNAL_NAME = "acquisition.json"


# -- report ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseOutcome:
    """What happened at one trajectory pose.

    status: 'captured' | 'no_views' | 'skipped_unsafe' | 'skipped_unreachable' | 'not_settled' |
        'moved_during_grab' | 'planned' (dry run) | 'done_before' (resume) | 'via' (a via pose
        passed through, or in a dry run one that passes the checks).
    """

    index: int
    status: str
    message: str = ""
    accepted: tuple = ()
    rejected: tuple = ()


@dataclass(frozen=True)
class AcquisitionReport:
    """Result of :func:`run_acquisition`.

    Attributes:
        out_dir: dataset folder.
        n_poses: poses in the trajectory, via poses included.
        outcomes: one :class:`PoseOutcome` per pose handled in this run (and 'done_before' ones;
            a via pose whose capture pose was done before is not handled and has none).
        accepted_per_camera: views stored, over the whole dataset so far.
        rejected_per_camera: frames the detector or the filter refused, over every run (a pose
            retried after a resume counts again).
        camera_errors: camera -> messages of failed grabs in this run.
        lost_cameras: cameras declared lost (too many failures in a row) in this run.
        stopped_reason: why the run ended before the trajectory did (None when it completed).
        elapsed_s: wall time of this run; ``captures_per_s`` derived from it.
        trace: state transitions ``(state, pose_index)`` of this run.
        last_estimate: the last value returned by ``on_capture``.
        n_via_poses: via poses (``capture: false``) in the trajectory.
    """

    out_dir: Path
    n_poses: int
    dry_run: bool
    resumed: bool
    outcomes: tuple
    accepted_per_camera: dict
    rejected_per_camera: dict
    camera_errors: dict
    lost_cameras: tuple
    stopped_reason: str | None
    elapsed_s: float
    trace: tuple = ()
    last_estimate: object = None
    n_via_poses: int = 0

    def count(self, status: str) -> int:
        return sum(o.status == status for o in self.outcomes)

    @property
    def captured(self) -> int:
        return self.count("captured")

    @property
    def skipped(self) -> list:
        return [(o.index, o.status, o.message) for o in self.outcomes if o.status.startswith("skipped")
                or o.status in ("not_settled", "moved_during_grab")]

    @property
    def captures_per_s(self) -> float:
        return self.captured / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def complete(self) -> bool:
        return self.stopped_reason is None

    def summary(self) -> str:
        via = f" (+{self.n_via_poses} via poses)" if self.n_via_poses else ""
        passed = f", {self.count('via')} via poses {'planned' if self.dry_run else 'passed'}" if self.n_via_poses else ""
        lines = [f"{'dry run' if self.dry_run else 'capture'} of {self.n_poses - self.n_via_poses} poses{via} into "
                 f"{self.out_dir}{' (resumed)' if self.resumed else ''}: {self.captured} captured, "
                 f"{self.count('no_views')} without accepted views, {len(self.skipped)} skipped, "
                 f"{self.count('done_before')} done before, {self.count('planned')} planned{passed}; "
                 f"{self.elapsed_s:.1f} s"]
        for cam in sorted(set(self.accepted_per_camera) | set(self.rejected_per_camera)):
            # "rejected" is the solver's word (a view it saw and discarded); a capture's frame without
            # the board is no view at all
            lines.append(f"  {cam}: board seen in {self.accepted_per_camera.get(cam, 0)} frames (views kept), "
                         f"not in {self.rejected_per_camera.get(cam, 0)} (out of view, facing away or not found)"
                         f"{', LOST' if cam in self.lost_cameras else ''}"
                         f"{f', {len(self.camera_errors[cam])} grab errors' if self.camera_errors.get(cam) else ''}")
        for i, status, msg in self.skipped:
            lines.append(f"  pose {i}: {status}: {msg}")
        if self.stopped_reason:
            lines.append(f"  stopped: {self.stopped_reason}")
        return "\n".join(lines)


# -- helpers -----------------------------------------------------------------------------------------
def _format_estimate(est) -> str:
    """Per-camera 1-sigma text from what an incremental solver returned: a
    :class:`calibgraph.solver.solve.incremental.IncrementalEstimate` (cameras -> sigma_translation_mm /
    sigma_rotation_deg), a mapping camera -> sigma in metres, or an object with
    ``sigma_translation_m`` / ``per_camera_sigma_m`` mappings."""
    if est is None:
        return ""
    cams = getattr(est, "cameras", None)
    if isinstance(cams, dict) and all(hasattr(v, "sigma_translation_mm") for v in cams.values()):
        parts = []
        for c, ce in sorted(cams.items()):
            st, sr = ce.sigma_translation_mm, ce.sigma_rotation_deg
            parts.append(f"{c} -" if st is None else
                         f"{c} {float(np.linalg.norm(st)):.2f} mm/{float(np.linalg.norm(sr)):.3f} deg")
        waiting = [c for c, v in (getattr(est, "pending", None) or {}).items() if v and c not in cams]
        return "1σ " + (", ".join(parts) or "not initialised yet") + (f" (waiting: {', '.join(waiting)})" if waiting else "")
    m = est if isinstance(est, dict) else getattr(est, "sigma_translation_m", None) or getattr(est, "per_camera_sigma_m", None)
    if isinstance(m, dict):
        parts = []
        for c, v in sorted(m.items()):
            try:
                parts.append(f"{c} {1e3 * float(v):.2f} mm")
            except (TypeError, ValueError):
                parts.append(f"{c} {v}")
        return "1σ " + ", ".join(parts)
    return str(est)


class _Journal:
    """``acquisition.json``: each pose's status and message, the runs, the trajectory's SHA-256."""

    def __init__(self, root: Path, traj_sha: str, n_poses: int):
        self.path = root / JOURNAL_NAME
        self.d = {"format": JOURNAL_FORMAT, "trajectory_sha256": traj_sha, "n_poses": n_poses, "poses": {},
                  "runs": []}

    @classmethod
    def load(cls, root: Path):
        p = root / JOURNAL_NAME
        if not p.is_file():
            return None
        try:
            d = json.loads(read_input_bytes(p, "journal"))
        except (OSError, ValueError) as e:
            raise InputError(f"{p}: journal unreadable ({e}); move it aside to resume from the capture files alone.") from None
        j = cls(root, d.get("trajectory_sha256", ""), int(d.get("n_poses", 0)))
        j.d.update(d)
        return j

    def set(self, index: int, status: str, message: str = "", **extra) -> None:
        self.d["poses"][str(index)] = {"status": status, "message": message, **extra}

    def status(self, index: int):
        e = self.d["poses"].get(str(index))
        return None if e is None else e["status"]

    def save(self) -> None:
        atomic_write_bytes(self.path, json.dumps(self.d, indent=1).encode())


# -- the run -----------------------------------------------------------------------------------------
def run_acquisition(robot, cameras, trajectory, out_dir, target: Target, detector=None, resume: bool = False,
                    safety: SafetyLimits | None = None, on_capture=None, progress=True, dry_run: bool = False,
                    mode: str = "eye_to_hand", settle_timeout_s: float = 10.0, settle_dwell_s: float = 0.0,
                    settle_poll_s: float = 0.01, max_camera_failures: int = 3, grab_retries: int = 1,
                    min_corners: int = 6, arrival_tolerance_rad: float = 0.01,
                    still_tolerance_m: float = 5e-4, still_tolerance_deg: float = 0.05, watch=None) -> AcquisitionReport:
    """Capture along a trajectory (see the module docstring).

    Args:
        robot: a :class:`~calibgraph.acquire.interfaces.Robot` (may be None for ``dry_run``).
        cameras: Camera objects (list, or mapping name -> Camera).
        trajectory: :class:`Trajectory`, a path to a trajectory YAML, or a list of joint vectors.
        out_dir: dataset folder to create (or to continue with ``resume=True``).
        target: the board.
        detector: ``detector(image, target, intrinsics)`` returning an object with ``ok, ids,
            uv_px, reason`` or a tuple ``(ids, uv_px)`` or None; default
            :func:`calibgraph.detect.corners.detect_image`.
        resume: continue a dataset whose run was interrupted (starts a new one when ``out_dir``
            holds none). Without it an existing dataset folder is refused; with it, a dataset made
            by another kind of run or with another trajectory is refused.
        safety: limits checked before every motion (default: no box, speed cap 0.3, the robot's
            own joint limits when it exposes ``joint_limits()``).
        on_capture: ``on_capture(capture, detections) -> estimate`` called after each capture is
            on disk (e.g. ``IncrementalSolver.add_capture``); its estimate feeds the progress line.
        progress: True prints progress lines to stderr; a callable receives them instead; False is quiet.
        dry_run: plan and check every pose, never move, grab or write.
        mode: 'eye_to_hand' or 'eye_in_hand', stored in dataset.yaml.
        min_corners: views with fewer detected points are rejected.
        settle_timeout_s ... still_tolerance_deg: the loop's :class:`~calibgraph.acquire.loop.Settings`.
        watch: an observer of every grab and next pose (:attr:`~calibgraph.acquire.loop.Station.watch`;
            ``capture --view``), shown ``on_capture``'s estimate when it is an iSAM2 one; or None.
    Returns:
        :class:`AcquisitionReport`.
    """
    settings = Settings(settle_timeout_s, settle_dwell_s, settle_poll_s, max_camera_failures, grab_retries,
                        min_corners, arrival_tolerance_rad, still_tolerance_m, still_tolerance_deg)
    run = _TrajectoryRun(robot, cameras, trajectory, out_dir, target, detector, safety, on_capture, progress, dry_run,
                         mode, settings)
    if dry_run:
        return run.dry_run_report(run.plan())
    with claim_dataset(run.out, "trajectory", {"trajectory_sha256": run.trajectory.sha256()}, resume, run.log,
                       accept=TRAJECTORY_RUNS) as claim:
        run.station.open_cameras()
        run.station.watch, run.station.estimate = watch, run.estimates
        run.open_journal(resume)
        run.plan()
        pending = run.prepare_dataset(claim)
        try:
            _, stopped = acquisition_loop(run.station, run.visits(pending))
        except KeyboardInterrupt:
            run.journal.d["runs"][-1]["stopped"] = "interrupted"
            run.journal.save()
            raise
        return run.finish(stopped)


class _TrajectoryRun:
    """The trajectory as a plan of the acquisition loop: its poses, the journal, the report.

    :func:`run_acquisition` drives it: ``plan`` (START), then ``dry_run_report``, or
    ``prepare_dataset``, :meth:`visits` (the plan the loop runs) and ``finish`` (END).
    """

    def __init__(self, robot, cameras, trajectory, out_dir, target: Target, detector, safety, on_capture, progress,
                 dry_run: bool, mode: str, settings: Settings):
        self.t_start = time.monotonic()
        self.out = Path(out_dir)
        self.log = make_log(progress)
        safety = safety or SafetyLimits()
        if not isinstance(trajectory, Trajectory):
            trajectory = (load_trajectory(trajectory) if isinstance(trajectory, (str, os.PathLike))
                          else Trajectory(tuple(trajectory)))
        check_speed(trajectory.speed_scale, safety)
        cams = dict(cameras) if isinstance(cameras, dict) else {c.name: c for c in cameras}
        if len(cams) == 0 and not dry_run:
            raise InputError("capture: no cameras configured.")
        if robot is None and not dry_run:
            raise InputError("capture: no robot given (only a dry run can plan without one).")
        if detector is None and not dry_run:
            detector = detect_image
        self.station = Station(robot, cams, self.out, target, detector, safety, trajectory.speed_scale, settings,
                               self.log)
        self.robot, self.trajectory, self.poses, self.target = robot, trajectory, trajectory.poses, target
        self.on_capture, self.dry_run, self.mode = on_capture, dry_run, mode
        self.journal = _Journal(self.out, trajectory.sha256(), len(self.poses))
        self.resumed = False
        self.n_via = sum(not p.capture for p in self.poses)
        self.leads_to = _via_targets(self.poses)
        self.outcomes = []
        self.failed_leg = {}  # capture pose -> the via pose on the way to it that was not reached
        self.last_estimate = None

    def estimates(self) -> dict:
        """camera -> (T_ref_cam, 1-sigma mm, deg) of the last iSAM2 estimate (the live view's), else {}."""
        cams = getattr(self.last_estimate, "cameras", None)
        if not isinstance(cams, dict):
            return {}
        return {n: (c.T_ref_cam, *(sigma_norms(c.covariance) if c.covariance is not None else (None, None)))
                for n, c in cams.items() if hasattr(c, "covariance")}

    # ---- START --------------------------------------------------------------------------------------
    def open_journal(self, resume: bool) -> None:
        """On resume, load the journal and refuse another trajectory."""
        out = self.out
        if resume and (out / "dataset.yaml").exists():
            self.resumed = True
            journal = _Journal.load(out)
            if journal is not None:
                if journal.d.get("trajectory_sha256") not in ("", self.trajectory.sha256()):
                    raise InputError(f"{out}: this dataset was captured with a different trajectory (SHA-256 "
                                     f"differs); resume with the original one ({out / 'trajectory.yaml'}) or start a "
                                     "new dataset.")
                self.journal = journal

    def plan(self) -> list:
        """Check every motion once before anything moves (each from the last pose that passed); one Verdict per pose."""
        self.station.enter(State.START)
        st = self.station
        plan_q = self.robot.joint_positions() if self.robot is not None else None
        plan = []
        for pose in self.poses:
            v = check_motion(plan_q, pose.q_rad, st.safety, fk=st.fk, T_goal_stated=pose.T_base_flange,
                             robot_limits=st.robot_limits)
            plan.append(v)
            if v.ok:
                plan_q = pose.q_rad
        n_bad = sum(not v.ok for v in plan)
        self.log(f"plan: {len(plan) - n_bad}/{len(plan)} poses pass the safety checks"
                 + (f"; {n_bad} will be skipped" if n_bad else "") + f"; speed scale {self.trajectory.speed_scale:g}")
        return plan

    def dry_run_report(self, plan: list) -> AcquisitionReport:
        """A dry run's report: every pose 'planned', 'via' or 'skipped_unsafe' as the plan says."""
        cut = {}  # as in a real run: a via pose that fails costs the pose it leads to
        leads_to = self.leads_to
        for i, v in enumerate(plan):
            self.station.enter(State.MOVE, i)
            ok_status = "planned" if self.poses[i].capture else "via"
            if v.ok and (i in cut or leads_to.get(i, -1) in cut):
                j = cut.get(i, cut.get(leads_to.get(i)))
                v = Verdict(False, (f"via pose {j} on the way to it would be skipped",))
            self.outcomes.append(PoseOutcome(i, ok_status if v.ok else "skipped_unsafe", v.message))
            if not v.ok:
                self.log(f"pose {i}: would be skipped: {v.message}")
                if not self.poses[i].capture and leads_to[i] is not None:
                    cut.setdefault(leads_to[i], i)
        self.station.enter(State.END)
        return self._report(None, dry_run=True)

    def prepare_dataset(self, claim) -> list:
        """Create or reopen the dataset (header, trajectory copy, counts, leftovers removed); the
        poses still to visit, in trajectory order."""
        out, st = self.out, self.station
        write_or_check_header(out, self.target, st.intr, self.mode, claim)
        if not (out / "trajectory.yaml").exists():
            save_trajectory(self.trajectory, out / "trajectory.yaml")
        done = self._done_poses()
        for c, n in (self.journal.d.get("rejected_per_camera") or {}).items():
            st.rejected[c] = st.rejected.get(c, 0) + int(n)
        for tmp in [*(out / "images").glob("*/.*.tmp*"), *(out / "captures").glob(".*.tmp*"), *out.glob(".*.tmp*")]:
            tmp.unlink()
        self.journal.d["runs"].append({"started_unix_s": time.time(), "resume": bool(self.resumed)})
        self.journal.save()
        # a via pose is only worth passing on the way to a pose still to capture (see the module docstring)
        pending = [i for i in range(len(self.poses))
                   if i not in done and (self.poses[i].capture or self.leads_to[i] not in done)]
        for i in sorted(done):
            message = self.journal.d["poses"].get(str(i), {}).get("message", "")
            self.outcomes.append(PoseOutcome(i, "done_before", message))
        if self.resumed:
            n_go = sum(self.poses[i].capture for i in pending)
            self.log(f"resume: {len(done)} poses done before, {n_go} to go"
                     + (f" (and {len(pending) - n_go} via poses on the way)" if len(pending) > n_go else ""))
        return pending

    def _done_poses(self) -> set:
        """Poses whose capture file exists (their views counted as accepted); the images a pose
        without one left behind are removed, since that pose is redone."""
        done, st = set(), self.station
        for i in range(len(self.poses)):
            cp = capture_path(self.out, i)
            if self.poses[i].capture and cp.exists():
                done.add(i)
                try:
                    views = json.loads(read_input_bytes(cp, "capture file")).get("views", {})
                except (OSError, ValueError, InputError):
                    views = {}
                for c in views:
                    st.accepted[c] = st.accepted.get(c, 0) + 1
            else:  # skipped or interrupted poses are tried again (the safety check re-runs first)
                for c in st.cams:
                    p = self.out / image_relpath(c, i)
                    if p.exists():
                        p.unlink()  # half-written pose: it is redone, so its images must not linger
        return done

    # ---- the plan the loop runs ---------------------------------------------------------------------
    def visits(self, pending: list):
        """Every pending pose as a :class:`Visit` (a pose whose detour failed is skipped without
        one); each outcome is journaled."""
        for i in pending:
            pose = self.poses[i]
            if i in self.failed_leg or self.leads_to.get(i, -1) in self.failed_leg:
                j = self.failed_leg.get(i, self.failed_leg.get(self.leads_to.get(i)))
                self._skip(i, "skipped_unsafe", f"via pose {j} on the way to it was not reached, and the direct "
                                                "motion was planned as colliding" if pose.capture else
                                                f"via pose {j} of the same detour was not reached")
                continue
            outcome = yield Visit(i, ((pose.q_rad, pose.T_base_flange),), pose.capture)
            self._record(outcome)

    def _record(self, o: Outcome) -> None:
        """NEXT: journal the outcome; after a capture the incremental estimate (advisory: its failure
        costs nothing) and the progress line."""
        i, st = o.index, self.station
        if o.status == "via":
            self.journal.set(i, "via", "")
            self.journal.save()
            self.outcomes.append(PoseOutcome(i, "via", o.message))
            self.log(f"pose {i + 1}/{len(self.poses)}: via pose passed (no capture)")
            return
        if o.status not in ("captured", "no_views"):
            self._skip(i, o.status, o.message)
            return
        rej = list(o.rejected)
        self.journal.d["rejected_per_camera"] = dict(st.rejected)
        extra = {"accepted": sorted(o.views)} if o.status == "captured" else {}
        self.journal.set(i, o.status, o.message, **extra, rejected=[c for c, _ in rej])
        self.journal.save()
        self.outcomes.append(PoseOutcome(i, o.status, o.message, tuple(sorted(o.views)), tuple(c for c, _ in rej)))
        if o.status == "captured" and self.on_capture is not None:
            try:
                self.last_estimate = self.on_capture(o.capture, list(o.detections))
            except Exception as e:  # the estimate is advisory; the data is already safe on disk
                self.log(f"incremental estimate unavailable after pose {i}: {type(e).__name__}: {e}")
        self.log(_progress_line(i, len(self.poses), o.views, rej, st.accepted, st.lost, self.last_estimate))

    def _skip(self, i: int, status: str, msg: str) -> None:
        """Journal and report a skipped pose; a skipped via pose costs the capture pose it leads to."""
        self.journal.set(i, status, msg)
        self.journal.save()
        self.outcomes.append(PoseOutcome(i, status, msg))
        self.log(f"pose {i}: {status.replace('_', ' ')}: {msg}")
        if not self.poses[i].capture and self.leads_to[i] is not None:
            self.failed_leg.setdefault(self.leads_to[i], i)

    # ---- END ----------------------------------------------------------------------------------------
    def finish(self, stopped: str | None) -> AcquisitionReport:
        """END: close the journal's run entry; the report of the run."""
        self.journal.d["runs"][-1]["stopped"] = stopped
        self.journal.d["runs"][-1]["lost_cameras"] = list(self.station.lost)
        self.journal.save()
        self.station.enter(State.END)
        if stopped:
            self.log(f"stopped: {stopped}")
        return self._report(stopped)

    def _report(self, stopped, dry_run: bool = False) -> AcquisitionReport:
        st = self.station
        outcomes = tuple(sorted(self.outcomes, key=lambda o: o.index)) if not dry_run else tuple(self.outcomes)
        return AcquisitionReport(self.out, len(self.poses), dry_run, self.resumed and not dry_run, outcomes,
                                 st.accepted, st.rejected, {c: tuple(m) for c, m in st.camera_errors.items()},
                                 tuple(st.lost), stopped, time.monotonic() - self.t_start, tuple(st.trace),
                                 None if dry_run else self.last_estimate, self.n_via)


def _via_targets(poses) -> dict:
    """via pose -> the capture pose it leads to (None after the last capture pose)."""
    leads_to = {}
    nxt = None
    for i in range(len(poses) - 1, -1, -1):
        if poses[i].capture:
            nxt = i
        else:
            leads_to[i] = nxt
    return leads_to


def _progress_line(i, n, views, rej, accepted, lost, est) -> str:
    """The NEXT state's line: this pose's views, the totals per camera and the incremental estimate."""
    seen = ", ".join(f"{c} ✓" for c in sorted(views)) or "no view"
    rj = "".join(f", {c} ✗ ({w})" for c, w in rej)
    tot = ", ".join(f"{c} {k}" + (" LOST" if c in lost else "") for c, k in sorted(accepted.items()))
    e = _format_estimate(est)
    return f"pose {i + 1}/{n}: {seen}{rj} | views: {tot}" + (f" | {e}" if e else "")
