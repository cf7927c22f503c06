"""The acquisition loop: move, settle, grab, check, write; the plan is the only thing that varies.

Every capture run (a trajectory, ``capture --auto``, a verify capture, ``calibgraph sim``) goes
through :func:`acquisition_loop` with a :class:`Station` (the robot, the cameras and the dataset
folder) and a *plan*: a generator that yields a :class:`Visit` (where to go, and whether to
capture there), receives what happened (an :class:`Outcome`) and decides the next visit. A fixed
trajectory (:mod:`calibgraph.acquire.run`) and the active planner (:mod:`calibgraph.acquire.auto`)
are two such plans; the motion, the safety checks and the frame checks are the ones here::

    START -> MOVE -> SETTLE -> [MOVE -> SETTLE ...] -> ACQUIRE -> NEXT -> MOVE -> ... -> END

MOVE    check the motion from the robot's *actual* joints to the next joint target (joint limits,
        workspace box along the joint path, static geometry, speed cap, the stated flange pose
        against FK), then ``robot.move_to_joints``. An unsafe or unreachable target costs the
        visit (``skipped_unsafe`` / ``skipped_unreachable``), never the run.
SETTLE  wait until ``robot.is_settled()`` (a robot that does not settle in time costs the visit:
        ``not_settled``), dwell before a capture, check the arm arrived within
        ``arrival_tolerance_rad``. A visit may pass through several targets (via poses) first.
ACQUIRE read the flange pose and joints, grab every live camera, read the pose again (a flange
        that moved during the grab discards the visit: ``moved_during_grab``), check every frame
        and its detection (:func:`check_frame`, :func:`detect_and_filter`), write the accepted
        images (tmp + rename) and then the capture file, the commit point of the visit.
NEXT    the plan records the outcome (journal, progress line, live estimate) and yields the next
        visit, or ends.

Cameras. A grab that raises (any exception), times out, returns no image, an unusable image or a
stale frame (a timestamp not after the camera's previous one) is retried ``grab_retries`` times,
then costs that camera's view; after ``max_camera_failures`` failed poses in a row the camera is
declared lost and the run goes on with the others. A detection is kept only with at least
``min_corners`` points, valid ids on the target, finite pixels inside the image.
"""

from __future__ import annotations

import enum
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, UnreachableError
from calibgraph.acquire.safety import SafetyLimits, check_motion, fk_function
from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.core.problem import Capture, Detection
from calibgraph.core.targets import Target
from calibgraph.core.transforms import pose_error
from calibgraph.io.dataset import image_relpath, write_capture
from calibgraph.io.files import atomic_write_png

__all__ = ["State", "Settings", "Visit", "Outcome", "Station", "acquisition_loop", "check_frame", "detect_and_filter",
           "normalise_detection", "make_log", "PASSED"]

PASSED = ("captured", "no_views", "via")  # outcomes after which the run is in NEXT (the others are skips)


class State(enum.Enum):
    START = "START"
    MOVE = "MOVE"
    SETTLE = "SETTLE"
    ACQUIRE = "ACQUIRE"
    NEXT = "NEXT"
    END = "END"


@dataclass(frozen=True)
class Settings:
    """The timing and tolerance knobs of the loop (see the module docstring)."""

    settle_timeout_s: float = 10.0
    settle_dwell_s: float = 0.0
    settle_poll_s: float = 0.01
    max_camera_failures: int = 3
    grab_retries: int = 1
    min_corners: int = 6
    arrival_tolerance_rad: float = 0.01
    still_tolerance_m: float = 5e-4
    still_tolerance_deg: float = 0.05


@dataclass(frozen=True)
class Visit:
    """One thing the plan asks for: pass through ``legs`` (joint targets, each with the flange pose
    the plan states for it or None) and, when ``capture``, acquire capture ``index`` at the last."""

    index: int
    legs: tuple
    capture: bool = True


@dataclass(frozen=True)
class Outcome:
    """What happened at a :class:`Visit`.

    status: 'captured' | 'no_views' | 'via' (passed, nothing grabbed) | 'skipped_unsafe' |
        'skipped_unreachable' | 'not_settled' | 'moved_during_grab'.
    legs_done: legs the robot moved along (for the plan's motion-time bookkeeping).
    views: camera -> the view written to the capture file; detections: their :class:`Detection`.
    rejected: [(camera, why)] of the frames refused; capture: the :class:`Capture` written.
    T_base_flange, q_rad: the robot state read at ACQUIRE (None before it).
    """

    index: int
    status: str
    message: str = ""
    legs_done: int = 0
    views: dict = field(default_factory=dict)
    detections: tuple = ()
    rejected: tuple = ()
    capture: Capture | None = None
    T_base_flange: np.ndarray | None = None
    q_rad: np.ndarray | None = None


def make_log(progress):
    """The progress sink: stderr lines (True), the given callable, or nothing (False)."""
    if callable(progress):
        return progress
    if progress:
        return lambda s: print(s, file=sys.stderr, flush=True)
    return lambda s: None


# -- the frame checks --------------------------------------------------------------------------------
def normalise_detection(res):
    """(ids, uv_px) or (None, reason) from what a detector returned."""
    if res is None:
        return None, "target not found"
    if isinstance(res, tuple) and len(res) == 2 and not hasattr(res, "ok"):
        return (np.asarray(res[0]), np.asarray(res[1], float)), None
    if not getattr(res, "ok", True):
        return None, str(getattr(res, "reason", "") or "target not found")
    return (np.asarray(res.ids), np.asarray(res.uv_px, float)), None


def check_frame(fr, last_stamp_s):
    """Raise :class:`DeviceError` saying why ``fr`` is not a usable fresh frame: none, no image, an
    image that is not uint8 grey/colour, or a timestamp not after ``last_stamp_s`` (stale)."""
    if fr is None or getattr(fr, "image", None) is None:
        raise DeviceError("no frame")
    img = np.asarray(fr.image)
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or img.size == 0:
        raise DeviceError(f"unusable frame (dtype {img.dtype}, shape {img.shape})")
    if last_stamp_s is not None and fr.stamp_s <= last_stamp_s:
        raise DeviceError(f"stale frame (timestamp {fr.stamp_s} not after the previous {last_stamp_s})")


def detect_and_filter(detector, image, target: Target, intr, min_corners: int, cam: str, i: int):
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


# -- the station -------------------------------------------------------------------------------------
class Station:
    """The robot, the cameras and the dataset folder of one run, and what happened to them.

    Attributes (the counts cover this run plus what the plan adds from earlier runs):
        intr: camera -> intrinsics of every camera that opened.
        lost: cameras declared lost (at start or after failures in a row).
        accepted, rejected: camera -> views stored / frames refused.
        reasons: camera -> {why refused: count}.
        camera_errors: camera -> messages of failed grabs.
        trace: state transitions ``(state, index)``.
        watch: an observer (e.g. :class:`calibgraph.report.live_view.CaptureView`) or None: its
            ``frames(index, T_base_flange, images, found, why)`` sees every grab (camera -> image,
            -> uv_px or None, -> why not found), its ``next_pose(index or None, T_base_flange or None,
            estimates)`` each visit before it moves (and the end, index None). A failing observer is
            dropped with one line; it never costs the run.
        estimate: None, or the plan's ``estimate() -> {camera: (T_ref_cam or None, 1-sigma mm, deg)}``
            handed to the observer.
    """

    def __init__(self, robot, cameras, out_dir, target: Target, detector, safety: SafetyLimits | None,
                 speed_scale: float, settings: Settings | None = None, log=None):
        self.robot, self.out, self.target, self.detector = robot, out_dir, target, detector
        self.safety = safety or SafetyLimits()
        self.speed_scale = float(speed_scale)
        self.settings = settings or Settings()
        self.log = log or (lambda s: None)
        self.cams = dict(cameras) if isinstance(cameras, dict) else {c.name: c for c in cameras}
        self.fk = fk_function(robot, self.safety)
        has_limits = robot is not None and callable(getattr(robot, "joint_limits", None))
        self.robot_limits = robot.joint_limits() if has_limits else None
        self.intr, self.lost, self.trace = {}, [], []
        self.accepted = {c: 0 for c in self.cams}
        self.rejected = {c: 0 for c in self.cams}
        self.reasons = {}
        self.camera_errors = {c: [] for c in self.cams}
        self.fails_in_row = {c: 0 for c in self.cams}
        self.last_stamp = {}  # camera -> stamp of its last frame: a repeated stamp is a stale (re-delivered) frame
        self.watch, self.estimate = None, None

    def notify(self, what: str, *args) -> None:
        """Call the observer's ``what(*args)``; one that fails is dropped (the run goes on)."""
        if self.watch is None:
            return
        try:
            getattr(self.watch, what)(*args)
        except Exception as e:  # the view is advisory: never lose a capture to it
            self.watch = None
            self.log(f"live view stopped ({type(e).__name__}: {e}); the capture goes on")

    def notify_next(self, v) -> None:
        """Tell the observer where visit ``v`` goes (None: the run ended) and the plan's estimates."""
        if self.watch is None:
            return
        T = None
        if v is not None and v.legs:
            q_goal, T = v.legs[-1]
            if T is None and self.fk is not None:
                try:
                    T = self.fk(np.asarray(q_goal, float))
                except Exception:  # no pose to show, nothing else lost
                    T = None
        try:
            est = self.estimate() if self.estimate is not None else {}
        except Exception as e:  # the estimate is advisory too
            est = {}
            self.log(f"live view: no estimate ({type(e).__name__}: {e})")
        self.notify("next_pose", None if v is None else v.index, T, est)

    def enter(self, state: State, i=None) -> None:
        """Record a state transition in the trace."""
        self.trace.append((state.value, i))

    def live(self) -> list:
        return [c for c in self.cams if c not in self.lost]

    def open_cameras(self, who: str = "capture") -> dict:
        """Every camera's intrinsics; a camera that cannot report them is lost, no camera at all is an error."""
        for name, cam in self.cams.items():
            try:
                self.intr[name] = cam.intrinsics()
            except Exception as e:  # a camera that cannot even report intrinsics is lost, the others go on
                self.camera_errors[name].append(f"intrinsics: {e}")
                self.lost.append(name)
                self.log(f"camera {name}: LOST at start ({type(e).__name__}: {e}); continuing without it")
        if not self.live():
            raise DeviceError(f"{who}: no camera could be opened" + "".join(
                f"; {c}: {m[-1]}" for c, m in self.camera_errors.items() if m) + ".")
        return self.intr

    # ---- MOVE -> SETTLE -> ACQUIRE ------------------------------------------------------------------
    def visit(self, v: Visit) -> Outcome:
        """Move through the visit's legs (checked, settled, arrived) and acquire at the last when asked.
        A :class:`DeviceError` (the robot failed) propagates."""
        q_rad = None
        for n, (q_goal, T_stated) in enumerate(v.legs):
            self.enter(State.MOVE, v.index)
            v_ok = check_motion(self.robot.joint_positions(), q_goal, self.safety, fk=self.fk,
                                T_goal_stated=T_stated, robot_limits=self.robot_limits)
            if not v_ok.ok:
                return Outcome(v.index, "skipped_unsafe", v_ok.message, n)
            try:
                self.robot.move_to_joints(q_goal, speed_scale=self.speed_scale)
            except UnreachableError as e:
                return Outcome(v.index, "skipped_unreachable", str(e), n)
            self.enter(State.SETTLE, v.index)
            skip = self._settle(q_goal, dwell=v.capture and n == len(v.legs) - 1)
            if isinstance(skip, tuple):
                return Outcome(v.index, skip[0], skip[1], n + 1)
            q_rad = skip
        if not v.capture:
            return Outcome(v.index, "via", "passed through (no capture)", len(v.legs))
        return self._acquire(v.index, q_rad, len(v.legs))

    def _settle(self, q_goal, dwell: bool):
        """The joints (rad) once the arm is still and arrived, else (status, why)."""
        s = self.settings
        t_end = time.monotonic() + s.settle_timeout_s
        while not self.robot.is_settled():
            if time.monotonic() > t_end:
                return "not_settled", f"the robot was still moving after {s.settle_timeout_s:g} s"
            time.sleep(s.settle_poll_s)
        if dwell and s.settle_dwell_s > 0:  # the dwell lets images get sharp; a via pose takes none
            time.sleep(s.settle_dwell_s)
        q_rad = np.asarray(self.robot.joint_positions(), float)
        off = float(np.max(np.abs(q_rad - np.asarray(q_goal, float))))
        if off > s.arrival_tolerance_rad:
            return "skipped_unreachable", (f"the robot stopped {off:.4f} rad from the target "
                                           f"(tolerance {s.arrival_tolerance_rad:g} rad)")
        return q_rad

    def _acquire(self, i: int, q_rad, legs: int) -> Outcome:
        """ACQUIRE: flange pose, grab, flange pose again; detect and write the accepted views, then
        the capture file (the commit point of the visit)."""
        self.enter(State.ACQUIRE, i)
        T0 = np.asarray(self.robot.flange_pose(), float)
        stamp_s = time.time()
        frames = self._grab_all(i)
        T1 = np.asarray(self.robot.flange_pose(), float)
        dt_m, dr_deg = pose_error(T0, T1)
        if dt_m > self.settings.still_tolerance_m or dr_deg > self.settings.still_tolerance_deg:
            return Outcome(i, "moved_during_grab", f"the flange moved {1e3 * dt_m:.2f} mm / {dr_deg:.3f} deg while "
                           "the cameras grabbed", legs, T_base_flange=T0, q_rad=q_rad)
        views, dets, rej = {}, [], []
        for c, fr in frames.items():
            ok, why = detect_and_filter(self.detector, fr.image, self.target, self.intr[c], self.settings.min_corners,
                                        c, i)
            if ok is None:
                rej.append((c, why))
                self.rejected[c] = self.rejected.get(c, 0) + 1
                self.reasons.setdefault(c, {})[why] = self.reasons.get(c, {}).get(why, 0) + 1
                continue
            ids, uv = ok
            rel = image_relpath(c, i)
            atomic_write_png(self.out / rel, fr.image)
            views[c] = dict(image=rel, stamp_s=float(fr.stamp_s), ids=ids, uv_px=uv)
            dets.append(Detection(camera=c, capture=i, ids=ids, uv_px=uv, image=str(self.out / rel)))
        if self.watch is not None:
            self.notify("frames", i, T0, {c: fr.image for c, fr in frames.items()},
                        {c: views[c]["uv_px"] if c in views else None for c in frames}, dict(rej))
        if not views:
            msg = "; ".join(f"{c}: {w}" for c, w in rej) or "no camera delivered a frame"
            return Outcome(i, "no_views", msg, legs, rejected=tuple(rej), T_base_flange=T0, q_rad=q_rad)
        cap = Capture(index=i, T_base_flange=T0, q_rad=q_rad, stamp_s=stamp_s)
        write_capture(self.out, cap, views)  # the capture file is the commit point of this visit
        for c in views:
            self.accepted[c] = self.accepted.get(c, 0) + 1
        return Outcome(i, "captured", "", legs, views, tuple(dets), tuple(rej), cap, T0, q_rad)

    def _grab_all(self, i: int) -> dict:
        """camera -> fresh frame of every live camera that delivered one; too many failures in a row lose a camera."""
        frames = {}
        for c in self.live():
            fr = self._grab(c, i)
            if fr is not None:
                frames[c] = fr
            elif self.fails_in_row[c] >= self.settings.max_camera_failures:
                self.lost.append(c)
                self.log(f"camera {c}: LOST after {self.fails_in_row[c]} failed grabs in a row; continuing with the "
                         "others")
        return frames

    def _grab(self, name: str, i: int):
        """One fresh frame or None; failures are counted per camera."""
        retries = self.settings.grab_retries
        for attempt in range(retries + 1):
            try:
                fr = self.cams[name].grab()
                check_frame(fr, self.last_stamp.get(name))
                self.last_stamp[name] = float(fr.stamp_s)
                self.fails_in_row[name] = 0
                return fr
            except Exception as e:  # any driver failure costs this camera's view, never the run
                msg = f"pose {i}: grab failed ({type(e).__name__}: {e})"
                self.camera_errors[name].append(msg)
                self.log(f"camera {name}: {msg}" + (" ; retrying" if attempt < retries else ""))
        self.fails_in_row[name] += 1
        self.reasons.setdefault(name, {})["grab failed"] = self.reasons.get(name, {}).get("grab failed", 0) + 1
        return None


# -- the loop ----------------------------------------------------------------------------------------
def acquisition_loop(station: Station, plan):
    """Run ``plan`` (a generator of :class:`Visit`, sent each :class:`Outcome`) on ``station``.

    Returns ``(what the plan returned, why the run stopped early or None)``. The run stops early
    when every camera is lost or the robot fails (:class:`DeviceError`); a write failure
    (disk full, permissions) is a :class:`CalibgraphError`; Ctrl-C propagates. Whole captures
    already written are kept in every case.
    """
    current = None
    try:
        visit = next(plan)
        while True:
            current = visit.index
            if not station.live():
                return None, "every camera is lost; fix the cameras and resume with --resume"
            station.notify_next(visit)
            outcome = station.visit(visit)
            if outcome.status in PASSED:
                station.enter(State.NEXT, visit.index)
            visit = plan.send(outcome)
    except StopIteration as stop:
        station.notify_next(None)
        return stop.value, None
    except DeviceError as e:  # cameras never get here (their failures are caught per grab): the robot failed
        return None, f"robot failed at pose {current}: {e}; check the robot and resume with --resume"
    except OSError as e:
        raise CalibgraphError(f"{station.out}: cannot write pose {current} ({e}); free disk space or fix permissions, "
                              "then resume with --resume (whole captures already written are kept).") from None
