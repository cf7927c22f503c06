"""A guided live intrinsics session: frames from one camera device, the board held in front of it.

:func:`run_live_session` reads frames until the camera's focal length is known to the goal:

- a frame is **taken** when the board is still (every corner moved less than ``STILL_PX`` since
  the previous frame), has moved since the last taken frame (a new hold, not the same pose again)
  and adds information: the predicted fx 1-sigma falls by at least ``MIN_FALL`` of what an average
  view taken so far brought, or a coverage cell of the image or a tilt bin is new;
- the predicted fx 1-sigma is the information of the taken views' corners at the camera's current
  intrinsics, every view's pose eliminated (as :func:`calibgraph.solver.session_plan.predict_session_covariance`
  and the calibration compute it), at the corner noise the last fit measured (before one:
  ``SESSION_PIXEL_SIGMA_PX``, what the error budget's advice assumes);
- once enough views are taken and the prediction reaches the goal (or every ``REFIT_EVERY`` views),
  the views are calibrated (:func:`calibgraph.solver.intrinsics_session.calibrate_views`, the same
  stage as ``calibgraph intrinsics``); the session stops when that calibration's fx and fy 1-sigma
  meet the goal. The stop is the calibration's, never the prediction's.

The goal defaults to the fx 1-sigma the error budget's advice assumes for this camera
(:func:`default_goal_px`: a 25-image session with the camera's own corner noise capped at
``SESSION_PIXEL_SIGMA_PX``; the advice takes that noise from the hand-eye views, the session from its
own calibration, so the goal tightens after the first one), else ``DEFAULT_GOAL_FRACTION`` of fx.
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
from calibgraph.solver.intrinsics_model import DEFAULT_MODEL, model_parameters, reduced_information, view_jacobians
from calibgraph.solver.intrinsics_session import GRID_COLS, MIN_VIEWS, SessionView, calibrate_views, coverage
from calibgraph.solver.session_plan import SESSION_PIXEL_SIGMA_PX, predict_session_covariance, session_poses

STILL_PX = 0.5  # every corner moved less than this since the previous frame: the board is still
NEW_HOLD_PX = 10.0  # the corners' median travel since the last taken frame that makes a new pose
MIN_FALL = 0.5  # a taken frame lowers the predicted fx 1-sigma by at least this share of what an average view
                # of those taken so far did (n views: 1 - sqrt(n / (n + 1))) ...
TILT_BIN_DEG = 15.0  # ... or reaches a new bin of tilt about the image's vertical / horizontal axis
MIN_STOP_VIEWS = 10  # the session stops with no fewer views: a 6-view fit's 1-sigma rests on few views' scatter
REFIT_EVERY = 5  # calibrate after this many new views even while the prediction is above the goal
DEFAULT_GOAL_FRACTION = 5e-4  # 0.05 % of fx, when the advice's session cannot be predicted
ADVICE_SESSION_VIEWS = 25  # the session the error budget's advice assumes
NEXT_CANDIDATES = 24  # planned poses the next-pose hint chooses from
CORNER_CELLS = ("top-left", "top-right", "bottom-left", "bottom-right")


def default_goal_px(intr: Intrinsics, target: Target, model: str = DEFAULT_MODEL,
                    pixel_sigma_px: float = SESSION_PIXEL_SIGMA_PX) -> tuple:
    """(fx 1-sigma in px, how it was chosen): what the error budget's advice assumes a session gives,
    :func:`~calibgraph.solver.session_plan.predict_session_covariance` of ``ADVICE_SESSION_VIEWS`` views
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


def describe_pose(T: np.ndarray, intr: Intrinsics, target: Target) -> str:
    """A board pose in words: where its centre falls in the image, how far, how it is tilted."""
    centre_b = np.append(np.mean(np.reshape(target.extent_m, (2, 2)), axis=0), 0.0)
    p = T[:3, :3] @ centre_b + T[:3, 3]
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
    return f"the board at {where} of the image, about {p[2]:.1f} m away, {tilt}"


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
    sigma_fx_px: float = float("inf")  # the last calibration's, else the prediction
    fitted: bool = False  # sigma_fx_px is a calibration's
    goal_px: float = 0.0
    hint: str = ""

    def line(self, fx_px: float) -> str:
        corners = " ".join("".join(w[0].upper() for w in c.split("-")) if c in self.corners_reached else "--"
                           for c in CORNER_CELLS)
        dist = f"{self.distance_m[0]:.2f}-{self.distance_m[1]:.2f} m" if self.distance_m else "-"
        s = (f"{self.sigma_fx_px:.2f} px ({100 * self.sigma_fx_px / fx_px:.3f} %)" if np.isfinite(self.sigma_fx_px)
             else "-")
        return (f"frame {self.frames} views {self.views} [{self.board}] cells {100 * self.cells_fraction:.0f} % "
                f"corners {corners} dist {dist} tilt {self.max_tilt_deg:.0f} deg fx 1-sigma "
                f"{s}{'' if self.fitted else ' predicted'} / goal {self.goal_px:.2f} px; next: {self.hint}")


@dataclass
class LiveOutcome:
    """How a live session ended: ``result`` (the last calibration, or None when too few views),
    ``reason`` ('goal met', 'interrupted', or why the device stopped), ``frames`` read, the taken
    ``views`` and their ``images`` (name -> the frame as read), ``goal_px``, ``error`` (why no
    calibration could be made from the views, when none)."""

    result: object
    reason: str
    frames: int
    views: list
    goal_px: float
    images: dict = field(default_factory=dict, repr=False)
    error: str = ""

    @property
    def goal_met(self) -> bool:
        return self.reason == "goal met"


class _Session:
    def __init__(self, intr: Intrinsics, target: Target, model: str, goal_px: float | None, min_views: int):
        self.intr, self.target, self.model = intr, target, model
        self.auto_goal = goal_px is None  # the advice's: follows the corner noise the session measures
        self.goal_px = default_goal_px(intr, target, model)[0] if goal_px is None else float(goal_px)
        self.names = model_parameters(model)
        self.min_views = min_views
        self.views, self.poses, self.images = [], [], {}
        self.info = None
        self.pixel_sigma_px = SESSION_PIXEL_SIGMA_PX
        self.tilt_bins = set()
        self.cov = None  # Coverage of the taken views
        self.result = None
        self.last_fit_at = 0
        self.error = ""
        self._candidates = None  # planned poses the next-pose hint chooses from
        self._next = (-1, "")

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
        return self.result.sigma["fx"] if self.result is not None else self.predicted_sigma(self.info)

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
        if not adds:
            return False
        self.views.append(view)
        self.poses.append(T)
        self.info, self.cov = info, new_cov
        self.tilt_bins.add(tilt)
        return True

    def refit(self) -> None:
        """Calibrate the taken views when the prediction says the goal may be met (or every few views)."""
        n = len(self.views)
        if n < self.min_views:
            return
        if not (self.predicted_sigma(self.info) <= self.goal_px or n - self.last_fit_at >= REFIT_EVERY):
            return
        self.last_fit_at = n
        try:
            r = calibrate_views(self.views, self.target, self.intr.width_px, self.intr.height_px, self.model,
                                self.min_views)
        except ObservabilityError as e:
            self.error = str(e)
            return
        self.result, self.error = r, ""
        self.intr = r.intrinsics  # the next views' poses and predictions at the fitted camera
        self.pixel_sigma_px = max(r.pixel_sigma_px * np.sqrt(r.mode_variance_ratio), 1e-3)
        if self.auto_goal:
            self.goal_px = default_goal_px(self.intr, self.target, self.model, r.pixel_sigma_px)[0]
        blocks = [view_jacobians(self.intr, self.names, self.target.points_board_m[v.ids], r.T_cam_board[v.name])[1:]
                  if v.name in r.T_cam_board else None for v in self.views]
        self.info = reduced_information([b for b in blocks if b is not None])

    def goal_met(self) -> bool:
        if (self.result is None or len(self.result.views_used) < max(MIN_STOP_VIEWS, self.min_views)
                or len(self.result.views_used) < len(self.views) * 0.5):
            return False
        s, K = self.result.sigma, self.result.intrinsics.K
        return s["fx"] <= self.goal_px and s["fy"] <= self.goal_px * K[1, 1] / K[0, 0]

    def hint(self, status: LiveStatus) -> str:
        if status.board == "not seen":
            return "show the whole board to the camera"
        if status.board == "moving" and self.views:
            return "hold the board still"
        if self.cov is None:
            return "hold the board still, about 0.5 m away"
        missed = [c for c in CORNER_CELLS if c not in self.cov.corners_reached]
        if missed:
            return f"bring it to the {missed[0]} corner"
        vert = {b[0] for b in self.tilt_bins}
        horiz = {b[1] for b in self.tilt_bins}
        if max(abs(min(vert)), abs(max(vert) + 1)) < 2 or min(vert) >= 0 or max(vert) < 0:
            return "tilt the board about its vertical axis (both ways, 30-45 degrees)"
        if max(abs(min(horiz)), abs(max(horiz) + 1)) < 2 or min(horiz) >= 0 or max(horiz) < 0:
            return "tilt the board about its horizontal axis (both ways, 30-45 degrees)"
        d = [T[2, 3] for T in self.poses]
        if min(d) > 0.45:
            return "closer"
        if max(d) - min(d) < 0.25:
            return "farther"
        if self.cov.cells_fraction < 0.6:
            return "move it over the parts of the image it has not covered"
        if self.info is None or not np.isfinite(self.predicted_sigma(self.info)):
            return "more poses: tilted, near and far, all over the image"
        return self.best_next()

    def best_next(self) -> str:
        """The pose of a planned session (:func:`session_poses`, ``NEXT_CANDIDATES`` of them) that would
        lower the predicted fx 1-sigma most, in words; computed once per new view."""
        if self._next[0] == len(self.views):
            return self._next[1]
        if self._candidates is None:
            self._candidates = session_poses(self.intr, self.target, NEXT_CANDIDATES, (0.3, 0.8))
        pts = self.target.points_board_m
        best, best_s = None, np.inf
        for T in self._candidates:
            _, A, B = view_jacobians(self.intr, self.names, pts, T)
            sig = self.predicted_sigma(self.info + reduced_information([(A, B)]))
            if sig < best_s:
                best, best_s = T, sig
        words = "more poses like these" if best is None else describe_pose(best, self.intr, self.target)
        self._next = (len(self.views), words)
        return words

    def status(self, frames: int, board: str) -> LiveStatus:
        st = LiveStatus(frames=frames, views=len(self.views), board=board, goal_px=self.goal_px,
                        sigma_fx_px=self.sigma_fx(), fitted=self.result is not None)
        if self.cov is not None:
            st.cells_fraction, st.corners_reached = self.cov.cells_fraction, self.cov.corners_reached
            st.max_tilt_deg = self.cov.max_tilt_deg
            d = [T[2, 3] for T in self.poses]
            st.distance_m = (min(d), max(d))
        st.hint = "the goal is met" if self.goal_met() else self.hint(st)
        return st


def run_live_session(camera, target: Target, goal_px: float | None = None, model: str = DEFAULT_MODEL,
                     min_views: int = MIN_VIEWS, max_frames: int | None = None, on_status=None,
                     on_take=None, on_frame=None) -> LiveOutcome:
    """Read frames from ``camera`` (a :class:`calibgraph.acquire.interfaces.Camera`) until the goal is met
    (module docstring).

    Args:
        camera: the device; its ``intrinsics()`` start the predictions (the image size is its).
        target: the board.
        goal_px: the fx 1-sigma to reach, px (default :func:`default_goal_px`: at 0.1 px corners until
            the first calibration, then at the corner noise it measured, capped at 0.1 px).
        model: the distortion model to calibrate.
        min_views: the fewest views calibrated.
        max_frames: stop after this many frames (None: until the goal, the device's end or Ctrl-C).
        on_status: callable(LiveStatus) after every frame.
        on_take: callable(name, image) for every taken frame.
        on_frame: callable(frame_no, image, corners (n, 2) or None, LiveStatus) after every frame (a live view).
    Returns:
        :class:`LiveOutcome`; a Ctrl-C (KeyboardInterrupt) during a frame ends it with 'interrupted'.
    """
    intr = camera.intrinsics()
    if intr.width_px <= 0 or intr.height_px <= 0:
        raise InputError("live intrinsics: the camera reports no image size.")
    s = _Session(intr, target, model, goal_px, int(min_views))
    prev, taken_uv = None, None  # the previous frame's and the last taken frame's corners (id -> uv)
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
            board = "not seen"
            if det.ok:
                cur = dict(zip(det.ids.tolist(), det.uv_px))
                common = [i for i in cur if prev is not None and i in prev]
                still = len(common) >= 6 and max(float(np.hypot(*(cur[i] - prev[i]))) for i in common) < STILL_PX
                board = "still" if still else "moving"
                if still:
                    same = [i for i in cur if taken_uv is not None and i in taken_uv]
                    new_hold = (taken_uv is None or len(same) < 0.5 * len(cur)
                                or float(np.median([np.hypot(*(cur[i] - taken_uv[i])) for i in same])) > NEW_HOLD_PX)
                    name = f"frame_{frames:05d}.png"
                    full = detect_image(grey, target) if new_hold else None  # the calibration's corners
                    if full is not None and full.ok and s.consider(name, full.ids, full.uv_px):
                        taken_uv, board = cur, "taken"
                        s.images[name] = frame.image
                        if on_take:
                            on_take(name, frame.image)
                        s.refit()
                prev = cur
            else:
                prev = None
            if on_status or on_frame:
                st = s.status(frames, board)
                if on_status:
                    on_status(st)
                if on_frame:
                    on_frame(frames, frame.image, det.uv_px if det.ok else None, st)
            if s.goal_met():
                reason = "goal met"
                break
        else:
            reason = f"{frames} frames read (the limit)"
    except KeyboardInterrupt:
        reason = "interrupted"
    if not s.goal_met() and len(s.views) >= s.min_views and s.last_fit_at != len(s.views):
        s.last_fit_at = -REFIT_EVERY  # a last calibration of every view taken
        s.refit()
    return LiveOutcome(result=s.result, reason=reason, frames=frames, views=list(s.views), goal_px=s.goal_px,
                       images=s.images, error=s.error)
