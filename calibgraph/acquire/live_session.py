"""A guided live intrinsics session: frames from one camera device, the board held in front of it.

:func:`run_live_session` reads frames until the camera's focal length is known to the goal:

- a frame is **taken** when the board is still (every corner moved less than ``STILL_PX`` since
  the previous frame), is in a new hold (its corners moved since the last hold judged, taken or not)
  and adds information: the predicted fx 1-sigma falls by at least ``MIN_FALL`` of what an average
  view taken so far brought, or a coverage cell of the image or a tilt bin is new;
- the predicted fx 1-sigma is the information of the taken views' corners at the camera's current
  intrinsics, every view's pose eliminated (as :func:`calibgraph.solver.camera.session_plan.predict_session_covariance`
  and the calibration compute it), at the corner noise the last calibration measured (before one:
  ``SESSION_PIXEL_SIGMA_PX``);
- from ``min_views`` taken views on, every taken view is calibrated with all the others
  (:func:`calibgraph.solver.camera.intrinsics_session.calibrate_views`, the same stage as ``calibgraph
  intrinsics``), so the fx 1-sigma shown is the calibration's after every taken view; the session
  stops when that calibration's fx and fy 1-sigma meet the goal, from at least ``MIN_STOP_VIEWS``
  views. The stop is the calibration's, never the prediction's.

**The goal** defaults to the fx 1-sigma the error budget's advice assumes for this camera
(:func:`default_goal_px`): a session of ``ADVICE_SESSION_VIEWS`` planned views
(:func:`~calibgraph.solver.camera.session_plan.session_poses`) with corners as good as the camera's own,
at most ``SESSION_PIXEL_SIGMA_PX`` (the advice takes the camera's corner noise from the hand-eye
views; the session measures its own). Before the first calibration the noise is not known, so the
goal is only bounded (the value at ``SESSION_PIXEL_SIGMA_PX``); the first calibration sets it, with
one note saying so and at what noise, and it stays set: a later calibration changes it only when
its noise moves the goal by more than ``GOAL_CHANGE``, again with one note. A goal given
(``goal_px``) never changes.

**The hint** is always a pose: the session plans ``PLAN_POSES`` poses
(:func:`~calibgraph.solver.camera.session_plan.session_poses`, whose first ``ADVICE_SESSION_VIEWS`` are the
advice's session): the four image corners first, then, of the planned poses no hold has
matched yet (board centre within ``MATCH_IMAGE_FRACTION`` of the image, distance within
``MATCH_DISTANCE``, normal within ``MATCH_TILT_DEG``), the one that would lower the predicted fx
1-sigma most. It says in words where, how far and how tilted, and what no taken view has yet (that
place, that distance there, that tilt there); it changes once a still hold matches it (its view taken
or not: the user did what it said). A device
that can act on it (the simulated hand-held board's guided user) is told the pose
(``camera.guide(T_cam_board, taken)``).

A device that stops sending frames (a recording's end) or a Ctrl-C ends the session with what it has.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibgraph.acquire.interfaces import DeviceError
from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError, ObservabilityError
from calibgraph.core.targets import Target
from calibgraph.detect.corners import detect_image
from calibgraph.detect.image import to_grey8
from calibgraph.solver.camera.intrinsics_model import DEFAULT_MODEL, model_parameters, reduced_information, view_jacobians
from calibgraph.solver.camera.intrinsics_session import GRID_COLS, MIN_VIEWS, SessionView, calibrate_views, coverage
from calibgraph.solver.camera.session_plan import SESSION_PIXEL_SIGMA_PX, predict_session_covariance, session_poses

STILL_PX = 0.5  # every corner moved less than this since the previous frame: the board is still
NEW_HOLD_PX = 10.0  # the corners' median travel since the last taken frame that makes a new pose
MIN_FALL = 0.5  # a taken frame lowers the predicted fx 1-sigma by at least this share of what an average view
                # of those taken so far did (n views: 1 - sqrt(n / (n + 1))) ...
TILT_BIN_DEG = 15.0  # ... or reaches a new bin of tilt about the image's vertical / horizontal axis
MIN_STOP_VIEWS = 10  # the session stops with no fewer views: a 6-view fit's 1-sigma rests on few views' scatter
DEFAULT_GOAL_FRACTION = 5e-4  # 0.05 % of fx, when the advice's session cannot be predicted
ADVICE_SESSION_VIEWS = 25  # the session the error budget's advice assumes
GOAL_CHANGE = 0.2  # a later calibration changes the set goal only when it moves it by more than this share
PLAN_POSES = 2 * ADVICE_SESSION_VIEWS  # planned poses the hint chooses from (the advice's session first)
FIRST_HINTS = 4  # the first planned poses, hinted in order: the image's four corners (distortion)
MATCH_IMAGE_FRACTION = 0.12  # a taken view matches a planned pose: board centre within this share of the image
MATCH_DISTANCE = (0.08, 0.15)  # ... distance within max(m, share of the distance)
MATCH_TILT_DEG = 12.0  # ... and board normal within this angle
CORNER_CELLS = ("top-left", "top-right", "bottom-left", "bottom-right")


def default_goal_px(intr: Intrinsics, target: Target, model: str = DEFAULT_MODEL,
                    pixel_sigma_px: float = SESSION_PIXEL_SIGMA_PX) -> tuple:
    """(fx 1-sigma in px, how it was chosen): what the error budget's advice assumes a session gives,
    :func:`~calibgraph.solver.camera.session_plan.predict_session_covariance` of ``ADVICE_SESSION_VIEWS`` views
    with corners of ``pixel_sigma_px`` capped at ``SESSION_PIXEL_SIGMA_PX`` (as the advice caps the
    camera's own corner noise); else 0.05 % of fx."""
    sigma = min(float(pixel_sigma_px), SESSION_PIXEL_SIGMA_PX)
    try:
        cov = predict_session_covariance(intr, target, ADVICE_SESSION_VIEWS, pixel_sigma_px=sigma, model=model)
        s = float(np.sqrt(cov[0, 0]))
        if np.isfinite(s) and s > 0:
            return s, (f"what the error budget's advice assumes: {ADVICE_SESSION_VIEWS} views with corners of "
                       f"{sigma:.3g} px")
    except (InputError, np.linalg.LinAlgError):
        pass
    return DEFAULT_GOAL_FRACTION * float(intr.K[0, 0]), f"{100 * DEFAULT_GOAL_FRACTION:g} % of fx"


def _pose(intr: Intrinsics, p_board_m: np.ndarray, uv_px: np.ndarray):
    """The board's pose from its corners at ``intr`` (OpenCV's iterative PnP), or None."""
    import cv2

    ok, rvec, tvec = cv2.solvePnP(p_board_m.astype(np.float64), uv_px.astype(np.float64), intr.K, intr.dist,
                                  flags=cv2.SOLVEPNP_ITERATIVE)
    if not ok or tvec[2, 0] <= 0:
        return None
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, tvec[:, 0]
    return T


def _centre_b(target: Target) -> np.ndarray:
    return np.append(np.mean(np.reshape(target.extent_m, (2, 2)), axis=0), 0.0)


def _pose_parts(T: np.ndarray, intr: Intrinsics, target: Target) -> tuple:
    """(where in the image, distance m, tilt in words) of a board pose (:func:`describe_pose`)."""
    p = T[:3, :3] @ _centre_b(target) + T[:3, 3]
    u, v = intr.project(p[None])[0]
    col = ("left", "centre", "right")[int(np.clip(3 * u / intr.width_px, 0, 2))]
    row = ("top", "middle", "bottom")[int(np.clip(3 * v / intr.height_px, 0, 2))]
    where = "the centre" if (row, col) == ("middle", "centre") else (
        f"the {row} edge" if col == "centre" else f"the {col} edge" if row == "middle" else f"the {row}-{col} corner")
    n = T[:3, 2] * np.sign(T[2, 2] or 1.0)
    about_v, about_h = np.degrees(np.arctan2(n[0], n[2])), np.degrees(np.arctan2(n[1], n[2]))
    if max(abs(about_v), abs(about_h)) < 10:
        tilt = "facing the camera"
    elif abs(about_v) >= abs(about_h):
        tilt = f"turned about {abs(about_v):.0f} deg about its vertical axis ({'right' if about_v > 0 else 'left'} edge nearer)"
    else:
        tilt = f"tilted about {abs(about_h):.0f} deg about its horizontal axis ({'bottom' if about_h > 0 else 'top'} edge nearer)"
    return where, float(p[2]), tilt


def describe_pose(T: np.ndarray, intr: Intrinsics, target: Target) -> str:
    """A board pose in words: where its centre falls in the image, how far, how it is tilted."""
    where, d, tilt = _pose_parts(T, intr, target)
    return f"the board at {where} of the image, about {d:.1f} m away, {tilt}"


def _matches(T: np.ndarray, P: np.ndarray, intr: Intrinsics, target: Target) -> tuple:
    """(same place, same distance, same tilt) of board pose ``T`` against ``P`` (``MATCH_*``)."""
    c = _centre_b(target)
    p, q = T[:3, :3] @ c + T[:3, 3], P[:3, :3] @ c + P[:3, 3]
    uv = intr.project(np.vstack([p, q]))
    place = (abs(uv[0, 0] - uv[1, 0]) <= MATCH_IMAGE_FRACTION * intr.width_px
             and abs(uv[0, 1] - uv[1, 1]) <= MATCH_IMAGE_FRACTION * intr.height_px)
    dist = abs(p[2] - q[2]) <= max(MATCH_DISTANCE[0], MATCH_DISTANCE[1] * q[2])
    cos = float(np.clip(abs(T[:3, 2] @ P[:3, 2]), -1.0, 1.0))
    return place, dist, bool(np.degrees(np.arccos(cos)) <= MATCH_TILT_DEG)


def _tilt_bin(T: np.ndarray) -> tuple:
    """The board's tilt about the image's vertical and horizontal axes, binned by ``TILT_BIN_DEG``."""
    n = T[:3, 2] * np.sign(T[2, 2] or 1.0)
    about_vertical = np.degrees(np.arctan2(n[0], n[2]))
    about_horizontal = np.degrees(np.arctan2(n[1], n[2]))
    return int(np.floor(about_vertical / TILT_BIN_DEG)), int(np.floor(about_horizontal / TILT_BIN_DEG))


@dataclass
class LiveStatus:
    """What the console line shows after a frame."""

    frames: int = 0
    views: int = 0
    board: str = "not seen"  # 'not seen', 'moving', 'still', 'taken'
    cells_fraction: float = 0.0
    corners_reached: tuple = ()
    distance_m: tuple = ()  # (nearest, farthest) of the taken views
    max_tilt_deg: float = 0.0
    sigma_fx_px: float = float("inf")  # the last calibration's (after every taken view from min_views), else the prediction
    fitted: bool = False  # sigma_fx_px is a calibration's
    goal_px: float = 0.0  # the goal; before it is set (goal_set False), the bound it cannot exceed
    goal_set: bool = True
    hint: str = ""
    next_pose: object = None  # T_cam_board (4, 4) the hint describes, or None

    def line(self, fx_px: float) -> str:
        corners = " ".join("".join(w[0].upper() for w in c.split("-")) if c in self.corners_reached else "--"
                           for c in CORNER_CELLS)
        dist = f"{self.distance_m[0]:.2f}-{self.distance_m[1]:.2f} m" if self.distance_m else "-"
        s = (f"{self.sigma_fx_px:.3f} px ({100 * self.sigma_fx_px / fx_px:.3f} %)" if np.isfinite(self.sigma_fx_px)
             else "-")
        goal = f"{self.goal_px:.3f} px" if self.goal_set else f"<= {self.goal_px:.2f} px (set by the first calibration)"
        return (f"frame {self.frames} views {self.views} [{self.board}] cells {100 * self.cells_fraction:.0f} % "
                f"corners {corners} dist {dist} tilt {self.max_tilt_deg:.0f} deg fx 1-sigma "
                f"{s} {'calibrated' if self.fitted else 'predicted'} / goal {goal}; next: {self.hint}")


@dataclass
class LiveOutcome:
    """How a live session ended: ``result`` (the last calibration, or None when too few views),
    ``reason`` ('goal met', 'interrupted', or why the device stopped), ``frames`` read, the taken
    ``views`` and their ``images`` (name -> the frame as read), ``goal_px``, ``error`` (why no
    calibration could be made from the views, when none), ``notes`` (the lines said during the
    session: the goal set or changed)."""

    result: object
    reason: str
    frames: int
    views: list
    goal_px: float
    images: dict = field(default_factory=dict, repr=False)
    error: str = ""
    notes: list = field(default_factory=list)

    @property
    def goal_met(self) -> bool:
        return self.reason == "goal met"


class _Session:
    def __init__(self, intr: Intrinsics, target: Target, model: str, goal_px: float | None, min_views: int,
                 on_note=None):
        self.intr, self.target, self.model = intr, target, model
        self.intr0 = intr  # the device's: the plan is made at them
        self.auto_goal = goal_px is None  # the advice's: set by the first calibration's corner noise
        self.goal_px = default_goal_px(intr, target, model)[0] if goal_px is None else float(goal_px)
        self.goal_set = goal_px is not None
        self.goal_noise_px = None  # the corner noise the goal was set at
        self.notes, self.on_note = [], on_note
        self.names = model_parameters(model)
        self.min_views = min_views
        self.views, self.poses, self.images = [], [], {}
        self.info = None
        self.pixel_sigma_px = SESSION_PIXEL_SIGMA_PX
        self.tilt_bins = set()
        self.cov = None  # Coverage of the taken views
        self.result = None
        self.last_fit_at = 0  # views when a calibration was last tried
        self.result_views = 0  # views of the last calibration that succeeded
        self.error = ""
        self._plan = None  # planned poses the hint chooses from
        self.done = set()  # indices of planned poses a judged hold (taken or not) has matched
        self._next = ((-1, -1), None, "")

    def note(self, line: str) -> None:
        self.notes.append(line)
        if self.on_note:
            self.on_note(line)

    def predicted_sigma(self, info) -> float:
        if info is None:
            return float("inf")
        try:
            cov = np.linalg.inv(info)
        except np.linalg.LinAlgError:
            return float("inf")
        v = cov[0, 0]
        if not np.isfinite(v) or v <= 0 or np.linalg.cond(info) > 1e14:
            return float("inf")
        return float(np.sqrt(v)) * self.pixel_sigma_px

    def sigma_fx(self) -> float:
        if self.fitted:
            return self.result.sigma["fx"]
        return self.predicted_sigma(self.info)

    @property
    def fitted(self) -> bool:
        """The last calibration has every taken view."""
        return self.result is not None and self.result_views == len(self.views)

    @property
    def plan(self) -> list:
        if self._plan is None:
            self._plan = session_poses(self.intr0, self.target, PLAN_POSES, (0.3, 0.8))
        return self._plan

    def consider(self, name: str, det_ids, uv) -> bool:
        """Take the view when it adds information; True when taken."""
        pts = self.target.points_board_m[det_ids]
        T = _pose(self.intr, pts, uv)
        if T is None:
            return False
        _, A, B = view_jacobians(self.intr, self.names, pts, T)
        add = reduced_information([(A, B)])
        info = add if self.info is None else self.info + add
        before, after = self.predicted_sigma(self.info), self.predicted_sigma(info)
        view = SessionView(name, det_ids, uv)
        new_cov = coverage(self.views + [view], self.poses + [T], self.intr, self.target)
        tilt = _tilt_bin(T)
        new_cell = self.cov is None or new_cov.cells_fraction > self.cov.cells_fraction + 1e-9
        n = len(self.views)
        typical = 1.0 - np.sqrt(n / (n + 1.0))  # an average view's share of the fall
        adds = (not np.isfinite(before) or (1.0 - after / before) >= MIN_FALL * typical or new_cell
                or tilt not in self.tilt_bins)
        # a planned pose held is done whether or not its view is taken: the hint moves on either way
        self.done.update(i for i, P in enumerate(self.plan) if all(_matches(T, P, self.intr, self.target)))
        if not adds:
            return False
        self.views.append(view)
        self.poses.append(T)
        self.info, self.cov = info, new_cov
        self.tilt_bins.add(tilt)
        return True

    def refit(self) -> None:
        """Calibrate the taken views (every taken view from ``min_views`` on)."""
        n = len(self.views)
        if n < self.min_views:
            return
        self.last_fit_at = n
        try:
            r = calibrate_views(self.views, self.target, self.intr.width_px, self.intr.height_px, self.model,
                                self.min_views)
        except ObservabilityError as e:
            self.error = str(e)
            return
        self.result, self.error, self.result_views = r, "", n
        self.intr = r.intrinsics  # the next views' poses and predictions at the fitted camera
        self.pixel_sigma_px = max(r.pixel_sigma_px * np.sqrt(r.mode_variance_ratio), 1e-3)
        if self.auto_goal:
            self._set_goal(r, n)
        blocks = [view_jacobians(self.intr, self.names, self.target.points_board_m[v.ids], r.T_cam_board[v.name])[1:]
                  if v.name in r.T_cam_board else None for v in self.views]
        self.info = reduced_information([b for b in blocks if b is not None])

    def _set_goal(self, r, n: int) -> None:
        """The advice's goal at the corner noise calibration ``r`` (of ``n`` views) measured: set by the
        first calibration, changed later only by more than ``GOAL_CHANGE`` (one note each time)."""
        goal, _ = default_goal_px(self.intr, self.target, self.model, r.pixel_sigma_px)
        noise = min(r.pixel_sigma_px, SESSION_PIXEL_SIGMA_PX)
        fx = float(self.intr.K[0, 0])
        measured = (f"the {noise:.4f} px corner noise" if r.pixel_sigma_px <= SESSION_PIXEL_SIGMA_PX else
                    f"{SESSION_PIXEL_SIGMA_PX:g} px corners (the corners measure {r.pixel_sigma_px:.3f} px; the "
                    f"advice caps them there)")
        if not self.goal_set:
            bound, self.goal_px, self.goal_set, self.goal_noise_px = self.goal_px, goal, True, noise
            self.note(f"goal set: fx 1-sigma {goal:.3f} px ({100 * goal / fx:.4f} %), the advice's "
                      f"{ADVICE_SESSION_VIEWS}-view session at {measured} the first {n} views measured "
                      f"(the bound before: {bound:.2f} px, at {SESSION_PIXEL_SIGMA_PX:g} px); the fx 1-sigma shown is "
                      "now the calibration's of every view taken, after each one")
        elif abs(goal / self.goal_px - 1.0) > GOAL_CHANGE:
            old, was = self.goal_px, self.goal_noise_px
            self.goal_px, self.goal_noise_px = goal, noise
            self.note(f"goal changed: fx 1-sigma {goal:.3f} px (was {old:.3f} px): {n} views measure {measured} "
                      f"where the goal was set at {was:.4f} px")

    def goal_met(self) -> bool:
        if (self.result is None or not self.goal_set or len(self.result.views_used) < max(MIN_STOP_VIEWS, self.min_views)
                or len(self.result.views_used) < len(self.views) * 0.5):
            return False
        s, K = self.result.sigma, self.result.intrinsics.K
        return s["fx"] <= self.goal_px and s["fy"] <= self.goal_px * K[1, 1] / K[0, 0]

    def next_pose(self) -> tuple:
        """(T_cam_board, words) of the hint: of the planned poses no taken view has matched, the four image
        corners first (in order), then the one that would lower the predicted fx 1-sigma most; with what
        no taken view has yet. Computed again only when a view is taken or a planned pose is done."""
        n = (len(self.views), len(self.done))
        if self._next[0] == n:
            return self._next[1:]
        plan = self.plan
        left = [i for i in range(len(plan)) if i not in self.done] or list(range(len(plan)))
        pick = next((i for i in left if i < FIRST_HINTS), None)
        if pick is None:
            pts = self.target.points_board_m
            best_s = np.inf
            for i in left:
                _, A, B = view_jacobians(self.intr, self.names, pts, plan[i])
                add = reduced_information([(A, B)])
                sig = self.predicted_sigma(add if self.info is None else self.info + add)
                if sig < best_s:
                    pick, best_s = i, sig
            pick = left[0] if pick is None else pick
        T = plan[pick]
        words = f"{describe_pose(T, self.intr, self.target)} ({self._missing(T)})"
        self._next = (n, T, words)
        return T, words

    def _missing(self, P: np.ndarray) -> str:
        """What no taken view has of planned pose ``P``: its place in the image, its distance there, its tilt there."""
        where, d, _ = _pose_parts(P, self.intr, self.target)
        m = [_matches(T, P, self.intr, self.target) for T in self.poses]
        if not any(a for a, _, _ in m):
            return f"no view at {where} yet"
        if not any(a and b for a, b, _ in m):
            return f"no view there at {d:.1f} m yet"
        if not any(all(x) for x in m):
            return f"no view there at {d:.1f} m with this tilt yet"
        return "every planned pose has a view: more views like these"

    def status(self, frames: int, board: str) -> LiveStatus:
        st = LiveStatus(frames=frames, views=len(self.views), board=board, goal_px=self.goal_px, goal_set=self.goal_set,
                        sigma_fx_px=self.sigma_fx(), fitted=self.fitted)
        if self.cov is not None:
            st.cells_fraction, st.corners_reached = self.cov.cells_fraction, self.cov.corners_reached
            st.max_tilt_deg = self.cov.max_tilt_deg
            d = [T[2, 3] for T in self.poses]
            st.distance_m = (min(d), max(d))
        if self.goal_met():
            st.hint = "the goal is met"
        else:
            st.next_pose, st.hint = self.next_pose()
            if board == "not seen" and not self.views:
                st.hint = f"show the whole board to the camera: {st.hint}"
        return st


def run_live_session(camera, target: Target, goal_px: float | None = None, model: str = DEFAULT_MODEL,
                     min_views: int = MIN_VIEWS, max_frames: int | None = None, on_status=None,
                     on_take=None, on_frame=None, on_note=None) -> LiveOutcome:
    """Read frames from ``camera`` (a :class:`calibgraph.acquire.interfaces.Camera`) until the goal is met
    (module docstring).

    Args:
        camera: the device; its ``intrinsics()`` start the predictions (the image size is its). When it
            has ``guide(T_cam_board, taken)`` (the simulated hand-held board), it is told the hint's
            pose (None once the goal is met) and whether the frame was taken, after every frame.
        target: the board.
        goal_px: the fx 1-sigma to reach, px (default: the advice's, set by the first calibration,
            :func:`default_goal_px` at the corner noise it measured, capped at 0.1 px).
        model: the distortion model to calibrate.
        min_views: the fewest views calibrated.
        max_frames: stop after this many frames (None: until the goal, the device's end or Ctrl-C).
        on_status: callable(LiveStatus) after every frame.
        on_take: callable(name, image) for every taken frame.
        on_frame: callable(frame_no, image, corners (n, 2) or None, LiveStatus) after every frame (a live view).
        on_note: callable(str) for a line said once (the goal set or changed).
    Returns:
        :class:`LiveOutcome`; a Ctrl-C (KeyboardInterrupt) during a frame ends it with 'interrupted'.
    """
    intr = camera.intrinsics()
    if intr.width_px <= 0 or intr.height_px <= 0:
        raise InputError("live intrinsics: the camera reports no image size.")
    s = _Session(intr, target, model, goal_px, int(min_views), on_note)
    guide = getattr(camera, "guide", None)
    prev, judged_uv = None, None  # the previous frame's and the last judged hold's corners (id -> uv)
    frames, reason = 0, ""
    try:
        while max_frames is None or frames < max_frames:
            try:
                frame = camera.grab()
            except DeviceError as e:
                reason = f"the camera stopped: {e}"
                break
            frames += 1
            grey = to_grey8(frame.image, f"frame {frames}")
            if grey.shape != (intr.height_px, intr.width_px):
                raise InputError(f"live intrinsics: frame {frames} is {grey.shape[1]}x{grey.shape[0]}, the camera "
                                 f"reports {intr.width_px}x{intr.height_px}.")
            det = detect_image(grey, target, upscale="off", method="classic", refine=False)  # tracking only
            shown = det.uv_px if det.ok else None
            board = "not seen"
            if det.ok:
                cur = dict(zip(det.ids.tolist(), det.uv_px))
                common = [i for i in cur if prev is not None and i in prev]
                still = len(common) >= 6 and max(float(np.hypot(*(cur[i] - prev[i]))) for i in common) < STILL_PX
                board = "still" if still else "moving"
                if still:
                    same = [i for i in cur if judged_uv is not None and i in judged_uv]
                    new_hold = (judged_uv is None or len(same) < 0.5 * len(cur)
                                or float(np.median([np.hypot(*(cur[i] - judged_uv[i])) for i in same])) > NEW_HOLD_PX)
                    if new_hold:
                        name = f"frame_{frames:05d}.png"
                        full = detect_image(grey, target)  # the calibration's corners
                        if full.ok:
                            judged_uv = cur  # this hold is judged: its other frames are the same pose
                            if s.consider(name, full.ids, full.uv_px):
                                board = "taken"
                                s.images[name] = frame.image
                                if on_take:
                                    on_take(name, frame.image)
                                s.refit()
                prev = cur
            else:
                prev = None
            met = s.goal_met()
            if on_status or on_frame:
                st = s.status(frames, board)
                if on_status:
                    on_status(st)
                if on_frame:
                    on_frame(frames, frame.image, shown, st)
            if guide is not None:
                guide(None if met else s.next_pose()[0], board == "taken")
            if met:
                reason = "goal met"
                break
        else:
            reason = f"{frames} frames read (the limit)"
    except KeyboardInterrupt:
        reason = "interrupted"
    if not s.goal_met() and len(s.views) >= s.min_views and s.last_fit_at != len(s.views):
        s.refit()  # a last calibration of every view taken
    return LiveOutcome(result=s.result, reason=reason, frames=frames, views=list(s.views), goal_px=s.goal_px,
                       images=s.images, error=s.error, notes=list(s.notes))
