"""Live capture: drive the robot through a trajectory and record every camera's view of the board.

The acquisition state machine (thesis Fig. 4.5, made robust)::

    START -> MOVE -> SETTLE -> ACQUIRE -> NEXT -> MOVE -> ... -> NEXT -> END

START   read every camera's intrinsics, write (or, on resume, check) ``dataset.yaml``, plan the
        whole trajectory against the safety limits and print what would be skipped.
MOVE    re-check the motion from the robot's *actual* joints to the pose (joint limits, workspace
        box along the joint path, speed cap), then ``robot.move_to_joints``. An unsafe or
        unreachable pose is skipped with a message; it never stops the run.
SETTLE  wait until ``robot.is_settled()`` (plus an optional dwell): no image is taken while
        the arm moves. A robot that does not settle in time costs that pose, not the run.
ACQUIRE read the flange pose and joints, grab every live camera, read the pose again (a pose
        that moved during the grab is discarded), detect and filter each frame on the spot and
        write the accepted views: images first (tmp + rename), then ``captures/NNNNNN.json``
        (atomic), then the journal. Only then does the robot move again.
NEXT    progress line (views accepted per camera, and the incremental solver's current 1-sigma
        when ``on_capture`` is given), then the next pending pose or END.

Via poses (``capture: false``) go through MOVE (same safety checks) and SETTLE (no dwell) and
straight to NEXT: nothing is grabbed or written; the journal and the report give them the status
``via``. They exist because the drivers move along the straight joint-space line between
consecutive poses and :func:`calibgraph.plan.planner.plan_trajectory` checks those lines for
collisions: where a line collides it inserts via poses (a folded transit posture) so that the
motion goes round the obstacle. A via pose that cannot be reached (unsafe, unreachable, not
settled) is reported like any skipped pose, and the capture pose it led to is skipped as well
(``skipped_unsafe``): the direct motion to it is the one the planner found colliding.

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

Cameras. A camera that raises :class:`~calibgraph.acquire.interfaces.DeviceError` (or anything else),
times out or returns a stale frame is reported; after ``max_camera_failures`` failures in a row it
is declared lost and the run continues with the others.

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

The SHA-256 of a trajectory (stored in the journal, checked on resume) covers the joint targets,
the flange poses, the capture flags and the speed, not the bookkeeping (cameras, workcell, seed).
"""

from __future__ import annotations

import enum
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, UnreachableError
from calibgraph.acquire.safety import (
    SafetyLimits,
    Verdict,
    check_motion,
    check_speed,
    fk_function,
)
from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.core.problem import Capture, Detection
from calibgraph.core.targets import Target
from calibgraph.core.transforms import pose_error
from calibgraph.detect.corners import detect_image
from calibgraph.io.dataset import (
    capture_path,
    image_relpath,
    write_capture,
    write_header,
)
from calibgraph.io.files import atomic_write_bytes, atomic_write_png, output_folder
from calibgraph.plan.trajectory import Trajectory, load_trajectory, save_trajectory

JOURNAL_FORMAT = "calibgraph-acquisition/1"
JOURNAL_NAME = "acquisition.json"


class State(enum.Enum):
    START = "START"
    MOVE = "MOVE"
    SETTLE = "SETTLE"
    ACQUIRE = "ACQUIRE"
    NEXT = "NEXT"
    END = "END"


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
            lines.append(f"  {cam}: {self.accepted_per_camera.get(cam, 0)} views accepted, "
                         f"{self.rejected_per_camera.get(cam, 0)} rejected"
                         f"{', LOST' if cam in self.lost_cameras else ''}"
                         f"{f', {len(self.camera_errors[cam])} grab errors' if self.camera_errors.get(cam) else ''}")
        for i, status, msg in self.skipped:
            lines.append(f"  pose {i}: {status}: {msg}")
        if self.stopped_reason:
            lines.append(f"  stopped: {self.stopped_reason}")
        return "\n".join(lines)


# -- helpers -----------------------------------------------------------------------------------------
def normalise_detection(res):
    """(ids, uv_px) or (None, reason) from what a detector returned."""
    if res is None:
        return None, "target not found"
    if isinstance(res, tuple) and len(res) == 2 and not hasattr(res, "ok"):
        return (np.asarray(res[0]), np.asarray(res[1], float)), None
    if not getattr(res, "ok", True):
        return None, str(getattr(res, "reason", "") or "target not found")
    return (np.asarray(res.ids), np.asarray(res.uv_px, float)), None


def _format_estimate(est) -> str:
    """Per-camera 1-sigma text from what an incremental solver returned: a
    :class:`calibgraph.solver.incremental.IncrementalEstimate` (cameras -> sigma_translation_mm /
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
            d = json.loads(p.read_text())
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


# -- the state machine -------------------------------------------------------------------------------
def run_acquisition(robot, cameras, trajectory, out_dir, target: Target, detector=None, resume: bool = False,
                    safety: SafetyLimits | None = None, on_capture=None, progress=True, dry_run: bool = False,
                    mode: str = "eye_to_hand", settle_timeout_s: float = 10.0, settle_dwell_s: float = 0.0,
                    settle_poll_s: float = 0.01, max_camera_failures: int = 3, grab_retries: int = 1,
                    min_corners: int = 6, arrival_tolerance_rad: float = 0.01,
                    still_tolerance_m: float = 5e-4, still_tolerance_deg: float = 0.05) -> AcquisitionReport:
    """Run the acquisition state machine (see the module docstring).

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
            holds none). Without it an existing dataset folder is refused.
        safety: limits checked before every motion (default: no box, speed cap 0.3, the robot's
            own joint limits when it exposes ``joint_limits()``).
        on_capture: ``on_capture(capture, detections) -> estimate`` called after each capture is
            on disk (e.g. ``IncrementalSolver.add_capture``); its estimate feeds the progress line.
        progress: True prints progress lines to stderr; a callable receives them instead; False is quiet.
        dry_run: plan and check every pose, never move, grab or write.
        mode: 'eye_to_hand' or 'eye_in_hand', stored in dataset.yaml.
        min_corners: views with fewer detected points are rejected.
    Returns:
        :class:`AcquisitionReport`.
    """
    settings = _Settings(settle_timeout_s, settle_dwell_s, settle_poll_s, max_camera_failures, grab_retries,
                         min_corners, arrival_tolerance_rad, still_tolerance_m, still_tolerance_deg)
    run = _Acquisition(robot, cameras, trajectory, out_dir, target, detector, safety, on_capture, progress, dry_run,
                       mode, settings)
    plan = run.start(resume)
    if dry_run:
        return run.dry_run_report(plan)
    pending = run.prepare_dataset()
    stopped = run.visit(pending)
    return run.finish(stopped)


@dataclass(frozen=True)
class _Settings:
    """The timing and tolerance knobs of :func:`run_acquisition`."""

    settle_timeout_s: float
    settle_dwell_s: float
    settle_poll_s: float
    max_camera_failures: int
    grab_retries: int
    min_corners: int
    arrival_tolerance_rad: float
    still_tolerance_m: float
    still_tolerance_deg: float


class _Acquisition:
    """One run of the state machine: its inputs, the dataset's counts and journal, the cameras' state.

    :func:`run_acquisition` drives it: ``start`` (START), then ``dry_run_report``, or ``prepare_dataset``,
    ``visit`` (MOVE, SETTLE, ACQUIRE, NEXT for every pending pose) and ``finish`` (END).
    """

    def __init__(self, robot, cameras, trajectory, out_dir, target: Target, detector, safety, on_capture, progress,
                 dry_run: bool, mode: str, settings: _Settings):
        self.t_start = time.monotonic()
        self.out = Path(out_dir)
        self.log = _make_log(progress)
        self.safety = safety or SafetyLimits()
        if not isinstance(trajectory, Trajectory):
            trajectory = (load_trajectory(trajectory) if isinstance(trajectory, (str, os.PathLike))
                          else Trajectory(tuple(trajectory)))
        check_speed(trajectory.speed_scale, self.safety)
        self.cams = dict(cameras) if isinstance(cameras, dict) else {c.name: c for c in cameras}
        if len(self.cams) == 0 and not dry_run:
            raise InputError("capture: no cameras configured.")
        if robot is None and not dry_run:
            raise InputError("capture: no robot given (only a dry run can plan without one).")
        if detector is None and not dry_run:
            detector = detect_image
        self.robot, self.trajectory, self.poses, self.target = robot, trajectory, trajectory.poses, target
        self.detector, self.on_capture, self.dry_run, self.mode = detector, on_capture, dry_run, mode
        self.settings = settings
        self.fk = fk_function(robot, self.safety)
        has_limits = robot is not None and callable(getattr(robot, "joint_limits", None))
        self.robot_limits = robot.joint_limits() if has_limits else None
        self.trace = []  # (state, pose index) transitions
        self.journal = None
        self.resumed = False
        self.camera_errors = {c: [] for c in self.cams}
        self.fails_in_row = {c: 0 for c in self.cams}
        self.last_stamp = {}  # camera -> stamp of its last frame: a repeated stamp is a stale (re-delivered) frame
        self.lost = []
        self.intr = {}
        self.n_via = sum(not p.capture for p in self.poses)
        self.leads_to = _via_targets(self.poses)
        self.outcomes = []
        self.accepted = {c: 0 for c in self.cams}
        self.rejected = {c: 0 for c in self.cams}
        self.failed_leg = {}  # capture pose -> the via pose on the way to it that was not reached
        self.last_estimate = None

    def enter(self, state: State, i=None) -> None:
        """Record a state transition in the trace."""
        self.trace.append((state.value, i))

    # ---- START --------------------------------------------------------------------------------------
    def start(self, resume: bool) -> list:
        """START: open (or, on resume, check) the journal, read the intrinsics, plan every pose; the plan."""
        self.enter(State.START)
        self._open_journal(resume)
        self._read_intrinsics()
        return self._plan()

    def _open_journal(self, resume: bool) -> None:
        """Load or start the journal; refuse an existing dataset without ``resume``, and another trajectory."""
        out, traj_sha = self.out, self.trajectory.sha256()
        journal = None
        if not self.dry_run:
            if out.exists() and (out / "dataset.yaml").exists() and not resume:
                raise InputError(f"{out}: a dataset already exists here; pass --resume to continue it or choose a "
                                 "new --out.")
            if resume and (out / "dataset.yaml").exists():
                journal = _Journal.load(out)
                if journal is not None and journal.d.get("trajectory_sha256") not in ("", traj_sha):
                    raise InputError(f"{out}: this dataset was captured with a different trajectory (SHA-256 "
                                     f"differs); resume with the original one ({out / 'trajectory.yaml'}) or start a "
                                     "new dataset.")
        self.resumed = journal is not None or (resume and (out / "dataset.yaml").exists())
        self.journal = journal if journal is not None else _Journal(out, traj_sha, len(self.poses))

    def _read_intrinsics(self) -> None:
        """Every camera's intrinsics (none in a dry run); a camera that cannot report them is lost."""
        for name, cam in ({} if self.dry_run else self.cams).items():  # a dry run touches no camera
            try:
                self.intr[name] = cam.intrinsics()
            except Exception as e:  # a camera that cannot even report intrinsics is lost, the others go on
                self.camera_errors[name].append(f"intrinsics: {e}")
                self.lost.append(name)
                self.log(f"camera {name}: LOST at start ({type(e).__name__}: {e}); continuing without it")
        live = [c for c in self.cams if c not in self.lost]
        if not live and not self.dry_run:
            raise DeviceError("capture: no camera could be opened: "
                              + "; ".join(f"{c}: {m[-1]}" for c, m in self.camera_errors.items()))

    def _plan(self) -> list:
        """Check every motion once before anything moves (each from the last pose that passed); one Verdict per pose."""
        plan_q = self.robot.joint_positions() if self.robot is not None else None
        plan = []
        for pose in self.poses:
            v = check_motion(plan_q, pose.q_rad, self.safety, fk=self.fk, T_goal_stated=pose.T_base_flange,
                             robot_limits=self.robot_limits)
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
            self.enter(State.MOVE, i)
            ok_status = "planned" if self.poses[i].capture else "via"
            if v.ok and (i in cut or leads_to.get(i, -1) in cut):
                j = cut.get(i, cut.get(leads_to.get(i)))
                v = Verdict(False, (f"via pose {j} on the way to it would be skipped",))
            self.outcomes.append(PoseOutcome(i, ok_status if v.ok else "skipped_unsafe", v.message))
            if not v.ok:
                self.log(f"pose {i}: would be skipped: {v.message}")
                if not self.poses[i].capture and leads_to[i] is not None:
                    cut.setdefault(leads_to[i], i)
        self.enter(State.END)
        return AcquisitionReport(self.out, len(self.poses), True, False, tuple(self.outcomes), self.accepted,
                                 self.rejected, {c: tuple(m) for c, m in self.camera_errors.items()}, tuple(self.lost),
                                 None, time.monotonic() - self.t_start, tuple(self.trace), n_via_poses=self.n_via)

    def prepare_dataset(self) -> list:
        """Create or reopen the dataset folder (header, trajectory copy, counts, leftovers removed);
        the poses still to visit, in trajectory order."""
        out = output_folder(self.out, "dataset folder")
        _write_or_check_header(out, self.target, self.intr, self.mode)
        if not (out / "trajectory.yaml").exists():
            save_trajectory(self.trajectory, out / "trajectory.yaml")
        done = self._done_poses()
        for c, n in (self.journal.d.get("rejected_per_camera") or {}).items():
            self.rejected[c] = self.rejected.get(c, 0) + int(n)
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
        done = set()
        for i in range(len(self.poses)):
            cp = capture_path(self.out, i)
            if self.poses[i].capture and cp.exists():
                done.add(i)
                try:
                    views = json.loads(cp.read_text()).get("views", {})
                except (OSError, ValueError):
                    views = {}
                for c in views:
                    self.accepted[c] = self.accepted.get(c, 0) + 1
            else:  # skipped or interrupted poses are tried again (the safety check re-runs first)
                for c in self.cams:
                    p = self.out / image_relpath(c, i)
                    if p.exists():
                        p.unlink()  # half-written pose: it is redone, so its images must not linger
        return done

    # ---- MOVE -> SETTLE -> ACQUIRE -> NEXT ------------------------------------------------------------
    def visit(self, pending: list) -> str | None:
        """Every pending pose through the states; why the run stopped early, or None when it did not."""
        current = None
        try:
            for i in pending:
                current = i
                live = [c for c in self.cams if c not in self.lost]
                if not live:
                    return "every camera is lost; fix the cameras and resume with --resume"
                self._visit_pose(i, live)
        except KeyboardInterrupt:
            self.journal.d["runs"][-1]["stopped"] = "interrupted"
            self.journal.save()
            raise
        except DeviceError as e:  # cameras never get here (their failures are caught per grab): the robot failed
            return f"robot failed at pose {current}: {e}; check the robot and resume with --resume"
        except OSError as e:
            raise CalibgraphError(f"{self.out}: cannot write pose {current} ({e}); free disk space or fix permissions, "
                                  "then resume with --resume (whole captures already written are kept).") from None
        return None

    def _visit_pose(self, i: int, live: list) -> None:
        """One pose: skipped when its detour failed, else MOVE, SETTLE, then pass it (via) or ACQUIRE it."""
        pose = self.poses[i]
        if i in self.failed_leg or self.leads_to.get(i, -1) in self.failed_leg:
            j = self.failed_leg.get(i, self.failed_leg.get(self.leads_to.get(i)))
            self._skip(i, "skipped_unsafe", f"via pose {j} on the way to it was not reached, and the direct motion "
                                            "was planned as colliding" if pose.capture else
                                            f"via pose {j} of the same detour was not reached")
            return
        if not self._move(i, pose):
            return
        q_rad = self._settle(i, pose)
        if q_rad is None:
            return
        if not pose.capture:
            self._pass_via(i)
            return
        self._acquire(i, q_rad, live)

    def _move(self, i: int, pose) -> bool:
        """MOVE: re-check the motion from the actual joints, then move; False when the pose is skipped.
        A DeviceError (the robot failed) propagates and stops the run."""
        self.enter(State.MOVE, i)
        q_now = self.robot.joint_positions()
        v = check_motion(q_now, pose.q_rad, self.safety, fk=self.fk, T_goal_stated=pose.T_base_flange,
                         robot_limits=self.robot_limits)
        if not v.ok:
            self._skip(i, "skipped_unsafe", v.message)
            return False
        try:
            self.robot.move_to_joints(pose.q_rad, speed_scale=self.trajectory.speed_scale)
        except UnreachableError as e:
            self._skip(i, "skipped_unreachable", str(e))
            return False
        return True

    def _settle(self, i: int, pose):
        """SETTLE: wait for the arm to stop (and dwell) and check it arrived; its joints (rad), or None when skipped."""
        self.enter(State.SETTLE, i)
        s = self.settings
        if not _wait_settled(self.robot, s.settle_timeout_s, s.settle_poll_s):
            self._skip(i, "not_settled", f"the robot was still moving after {s.settle_timeout_s:g} s")
            return None
        if s.settle_dwell_s > 0 and pose.capture:  # the dwell lets images get sharp; a via pose takes none
            time.sleep(s.settle_dwell_s)
        q_rad = np.asarray(self.robot.joint_positions(), float)
        if np.max(np.abs(q_rad - pose.q_rad)) > s.arrival_tolerance_rad:
            self._skip(i, "skipped_unreachable",
                       f"the robot stopped {np.max(np.abs(q_rad - pose.q_rad)):.4f} rad from the target "
                       f"(tolerance {s.arrival_tolerance_rad:g} rad)")
            return None
        return q_rad

    def _pass_via(self, i: int) -> None:
        """A via pose reached: journal it and go on (NEXT) without grabbing."""
        self.journal.set(i, "via", "")
        self.journal.save()
        self.outcomes.append(PoseOutcome(i, "via", "passed through (no capture)"))
        self.enter(State.NEXT, i)
        self.log(f"pose {i + 1}/{len(self.poses)}: via pose passed (no capture)")

    def _acquire(self, i: int, q_rad: np.ndarray, live: list) -> None:
        """ACQUIRE: flange pose, grab, flange pose again; detect and write the accepted views, then the
        capture file (the commit point of the pose) and the journal; then NEXT."""
        self.enter(State.ACQUIRE, i)
        T0 = np.asarray(self.robot.flange_pose(), float)
        stamp_s = time.time()
        frames = self._grab_all(i, live)
        T1 = np.asarray(self.robot.flange_pose(), float)
        dt_m, dr_deg = pose_error(T0, T1)
        if dt_m > self.settings.still_tolerance_m or dr_deg > self.settings.still_tolerance_deg:
            self._skip(i, "moved_during_grab",
                       f"the flange moved {1e3 * dt_m:.2f} mm / {dr_deg:.3f} deg while the cameras grabbed")
            return
        views, dets, rej = self._detect_and_write(i, frames)
        self.journal.d["rejected_per_camera"] = dict(self.rejected)
        if not views:
            self._no_views(i, rej)
            return
        cap = Capture(index=i, T_base_flange=T0, q_rad=q_rad, stamp_s=stamp_s)
        write_capture(self.out, cap, views)  # the capture file is the commit point of this pose
        for c in views:
            self.accepted[c] = self.accepted.get(c, 0) + 1
        self.journal.set(i, "captured", "", accepted=sorted(views), rejected=[c for c, _ in rej])
        self.journal.save()
        self.outcomes.append(PoseOutcome(i, "captured", "", tuple(sorted(views)), tuple(c for c, _ in rej)))
        self._next(i, cap, dets, views, rej)

    def _grab_all(self, i: int, live: list) -> dict:
        """camera -> fresh frame of every live camera that delivered one; too many failures in a row lose a camera."""
        frames = {}
        for c in live:
            fr = _grab(self.cams[c], c, self.settings.grab_retries, self.camera_errors, self.fails_in_row, self.log, i,
                       self.last_stamp)
            if fr is not None:
                frames[c] = fr
            elif self.fails_in_row[c] >= self.settings.max_camera_failures and c not in self.lost:
                self.lost.append(c)
                self.log(f"camera {c}: LOST after {self.fails_in_row[c]} failed grabs in a row; continuing with the "
                         "others")
        return frames

    def _detect_and_write(self, i: int, frames: dict):
        """Detect and filter every frame, write the accepted images: (views for the capture file,
        their Detections, [(camera, why rejected)])."""
        views, dets, rej = {}, [], []
        for c, fr in frames.items():
            ok, why = _detect_and_filter(self.detector, fr.image, self.target, self.intr[c],
                                         self.settings.min_corners, c, i)
            if ok is None:
                rej.append((c, why))
                self.rejected[c] = self.rejected.get(c, 0) + 1
                continue
            ids, uv = ok
            rel = image_relpath(c, i)
            atomic_write_png(self.out / rel, fr.image)
            views[c] = dict(image=rel, stamp_s=float(fr.stamp_s), ids=ids, uv_px=uv)
            dets.append(Detection(camera=c, capture=i, ids=ids, uv_px=uv, image=str(self.out / rel)))
        return views, dets, rej

    def _no_views(self, i: int, rej: list) -> None:
        """A pose without any accepted view: journal why, then NEXT (no capture file)."""
        msg = "; ".join(f"{c}: {w}" for c, w in rej) or "no camera delivered a frame"
        self.journal.set(i, "no_views", msg, rejected=[c for c, _ in rej])
        self.journal.save()
        self.outcomes.append(PoseOutcome(i, "no_views", msg, (), tuple(c for c, _ in rej)))
        self.enter(State.NEXT, i)
        self.log(_progress_line(i, len(self.poses), {}, rej, self.accepted, self.lost, self.last_estimate))

    def _next(self, i: int, cap: Capture, dets: list, views: dict, rej: list) -> None:
        """NEXT: the incremental estimate (advisory: its failure costs nothing) and the progress line."""
        self.enter(State.NEXT, i)
        if self.on_capture is not None:
            try:
                self.last_estimate = self.on_capture(cap, dets)
            except Exception as e:  # the estimate is advisory; the data is already safe on disk
                self.log(f"incremental estimate unavailable after pose {i}: {type(e).__name__}: {e}")
        self.log(_progress_line(i, len(self.poses), views, rej, self.accepted, self.lost, self.last_estimate))

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
        self.journal.d["runs"][-1]["lost_cameras"] = list(self.lost)
        self.journal.save()
        self.enter(State.END)
        if stopped:
            self.log(f"stopped: {stopped}")
        return AcquisitionReport(self.out, len(self.poses), False, self.resumed,
                                 tuple(sorted(self.outcomes, key=lambda o: o.index)), self.accepted, self.rejected,
                                 {c: tuple(m) for c, m in self.camera_errors.items()}, tuple(self.lost), stopped,
                                 time.monotonic() - self.t_start, tuple(self.trace), self.last_estimate, self.n_via)


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


def _make_log(progress):
    """The progress sink: stderr lines (True), the given callable, or nothing (False)."""
    if callable(progress):
        return progress
    if progress:
        return lambda s: print(s, file=sys.stderr, flush=True)
    return lambda s: None


def _wait_settled(robot, timeout_s, poll_s) -> bool:
    """True once ``robot.is_settled()``, False after ``timeout_s``."""
    t_end = time.monotonic() + timeout_s
    while True:
        if robot.is_settled():
            return True
        if time.monotonic() > t_end:
            return False
        time.sleep(poll_s)


def _grab(cam, name, retries, errors, fails_in_row, log, i, last_stamp):
    """One fresh frame or None; failures are counted per camera."""
    last = last_stamp.get(name)
    for attempt in range(retries + 1):
        try:
            fr = cam.grab()
            if fr is None or getattr(fr, "image", None) is None:
                raise DeviceError("no frame")
            img = np.asarray(fr.image)
            if img.dtype != np.uint8 or img.ndim not in (2, 3) or img.size == 0:
                raise DeviceError(f"unusable frame (dtype {img.dtype}, shape {img.shape})")
            if last is not None and fr.stamp_s <= last:
                raise DeviceError(f"stale frame (timestamp {fr.stamp_s} not after the previous {last})")
            last_stamp[name] = float(fr.stamp_s)
            fails_in_row[name] = 0
            return fr
        except Exception as e:  # any driver failure costs this camera's view, never the run
            msg = f"pose {i}: grab failed ({type(e).__name__}: {e})"
            errors[name].append(msg)
            log(f"camera {name}: {msg}" + (" ; retrying" if attempt < retries else ""))
    fails_in_row[name] += 1
    return None


def _detect_and_filter(detector, image, target, intr, min_corners, cam, i):
    """((ids, uv_px), None) for a usable detection of the target in ``image``, else (None, why not)."""
    try:
        got, why = normalise_detection(detector(image, target, intr))
    except Exception as e:  # a detector crash on one frame costs that view, not the run
        return None, f"detection failed ({type(e).__name__}: {e})"
    if got is None:
        return None, why
    ids, uv = got
    ids = np.asarray(ids).reshape(-1)
    uv = np.asarray(uv, float).reshape(-1, 2)
    if ids.size < min_corners:
        return None, f"only {ids.size} points detected (< {min_corners})"
    try:
        Detection(camera=cam, capture=i, ids=ids, uv_px=uv)
    except InputError as e:
        return None, f"invalid detection: {e}"
    if ids.min() < 0 or ids.max() >= target.n_points:
        return None, f"point id {int(ids.max())} is not on the target"
    if intr.width_px and not np.all(intr.in_image(uv)):
        return None, "detected points outside the image"
    return (ids.astype(int), uv), None


def _progress_line(i, n, views, rej, accepted, lost, est) -> str:
    """The NEXT state's line: this pose's views, the totals per camera and the incremental estimate."""
    seen = ", ".join(f"{c} ✓" for c in sorted(views)) or "no view"
    rj = "".join(f", {c} ✗ ({w})" for c, w in rej)
    tot = ", ".join(f"{c} {k}" + (" LOST" if c in lost else "") for c, k in sorted(accepted.items()))
    e = _format_estimate(est)
    return f"pose {i + 1}/{n}: {seen}{rj} | views: {tot}" + (f" | {e}" if e else "")


def _write_or_check_header(out: Path, target: Target, intr: dict, mode: str) -> None:
    """Write dataset.yaml, or check that an existing one matches the target and cameras (adding cameras new to it)."""
    import yaml

    head = out / "dataset.yaml"
    if not head.exists():
        write_header(out, target, intr, mode=mode)
        return
    d = yaml.safe_load(head.read_text()) or {}
    old_t = Target.from_dict(d.get("target", {}))
    if old_t != target:
        raise InputError(f"{head}: the dataset was captured with target {old_t.to_dict()}, not {target.to_dict()}; "
                         "use the original target or a new --out.")
    cams = {}
    for c, v in (d.get("cameras") or {}).items():
        cams[c] = Intrinsics.from_dict(v)
    changed = False
    for c, k in intr.items():
        if c in cams:
            if not (np.allclose(cams[c].K, k.K, rtol=1e-6, atol=1e-6) and cams[c].width_px == k.width_px
                    and cams[c].height_px == k.height_px):
                raise InputError(f"{head}: camera {c!r} now reports different intrinsics than when the dataset was started; "
                                 "resolution or device changed: start a new dataset.")
        else:
            cams[c] = k  # a camera that was lost at the first start joins now
            changed = True
    if changed:
        write_header(out, target, cams, mode=d.get("mode", mode))
