"""Live rerun views: a guided intrinsics session (``calibgraph intrinsics --live --view``,
:class:`LiveView`) and a capture run (``calibgraph capture [--auto] --view``, :class:`CaptureView`,
whose entities are listed there). Both stream through :class:`Stream`.

:class:`LiveView`'s entities (timeline "frame", one step per frame read)::

    <camera>/image               the frame (JPEG, at most ``MAX_WIDTH_PX`` wide)
    <camera>/image/corners       the board's corners: yellow while it moves, green when still, blue when taken
    coverage                     the taken views' corners per image cell (the heat map the coverage check
                                 counts: ``GRID_COLS`` cells across), brighter = more corners
    fx_sigma/now_px              fx 1-sigma after the frame (predicted until the first calibration)
    fx_sigma/goal_px             the goal
    log                          the console line of every taken frame

A view streams to a viewer (``spawn``) where there is a display, else into a ``.rrd`` file, written
under a temporary name and moved into place when the run ends. rerun is imported lazily.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from calibgraph.io.files import begin_atomic_write, finish_atomic_write
from calibgraph.report.rerun_view import axes, import_rerun, pose, viridis
from calibgraph.solver.camera.intrinsics_session import GRID_COLS

MAX_WIDTH_PX = 960
JPEG_QUALITY = 80
CELL_PX = 24  # each coverage cell drawn as a square of this many pixels
COLOURS = {"moving": (240, 200, 0), "still": (40, 200, 60), "taken": (40, 120, 255)}


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class Stream:
    """A rerun recording streamed to a viewer (``rrd`` None: ``spawn``) or into the file ``rrd``,
    written under a temporary name beside it and moved into place by :meth:`close`."""

    def __init__(self, app_id: str, rrd: Path | None = None):
        self.rr = import_rerun()
        self.rrd = Path(rrd) if rrd else None
        self._tmp = begin_atomic_write(self.rrd, ".rrd") if rrd else None
        self.rec = self.rr.RecordingStream(app_id)
        if self.rrd is None:
            self.rec.spawn()
        else:
            self.rec.save(str(self._tmp))
        self.scales = {}  # image entity -> the factor its images are shrunk by

    def pinhole(self, entity: str, width_px: int, height_px: int) -> None:
        """Declare the 2-D image space of ``entity`` (images at most ``MAX_WIDTH_PX`` wide)."""
        s = self.scales[entity] = min(1.0, MAX_WIDTH_PX / int(width_px))
        self.rec.log(entity, self.rr.Pinhole(resolution=[round(width_px * s), round(height_px * s)],
                                             focal_length=float(width_px * s)), static=True)

    def image(self, entity: str, image: np.ndarray, uv_px, colour) -> None:
        """The frame as JPEG at ``entity`` and its points ``uv_px`` (full-size pixels; None clears
        them) at ``entity/corners``."""
        import cv2

        rr, s = self.rr, self.scales.get(entity, 1.0)
        small = image if s == 1.0 else cv2.resize(image, None, fx=s, fy=s, interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if ok:
            self.rec.log(entity, rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg"))
        if uv_px is None:
            self.rec.log(f"{entity}/corners", rr.Clear(recursive=False))
        else:
            self.rec.log(f"{entity}/corners", rr.Points2D(np.asarray(uv_px, float) * s, radii=2.5, colors=colour))

    def close(self) -> Path | None:
        """Flush; the recording file (moved into place), or None for a viewer."""
        self.rec.flush()
        self.rec.disconnect()
        if self.rrd is None:
            return None
        return finish_atomic_write(self._tmp, self.rrd)


class LiveView:
    """Callable ``(frame_no, image, uv_px or None, status)`` logging one frame (module docstring).

    Args:
        camera: the camera's name (the entity root).
        width_px, height_px, fx_px: its image size and focal length (for the log's percentages).
        rrd: the file to write; None spawns a viewer instead.
    """

    def __init__(self, camera: str, width_px: int, height_px: int, fx_px: float, rrd: Path | None = None):
        self.stream = Stream("calibgraph_intrinsics_live", rrd)
        self.rr, self.rec = self.stream.rr, self.stream.rec
        self.camera, self.W, self.H, self.fx_px = camera, int(width_px), int(height_px), float(fx_px)
        self.rows = max(2, int(round(GRID_COLS * self.H / self.W)))
        self.counts = np.zeros((self.rows, GRID_COLS))
        self.stream.pinhole(f"{camera}/image", self.W, self.H)

    def __call__(self, k: int, image: np.ndarray, uv_px, status) -> None:
        rr, rec = self.rr, self.rec
        rec.set_time("frame", sequence=int(k))
        self.stream.image(f"{self.camera}/image", image, uv_px, COLOURS.get(status.board, (200, 200, 200)))
        if status.board == "taken" and uv_px is not None:
            uv = np.asarray(uv_px, float)
            ci = np.clip((uv[:, 0] + 0.5) * GRID_COLS / self.W, 0, GRID_COLS - 1e-9).astype(int)
            ri = np.clip((uv[:, 1] + 0.5) * self.rows / self.H, 0, self.rows - 1e-9).astype(int)
            np.add.at(self.counts, (ri, ci), 1)
            heat = self.counts / self.counts.max()
            img = viridis(heat.ravel()).reshape(self.rows, GRID_COLS, 3)
            img[self.counts == 0] = 0
            rec.log("coverage", rr.Image(np.repeat(np.repeat(img, CELL_PX, axis=0), CELL_PX, axis=1)))
            rec.log("log", rr.TextLog(status.line(self.fx_px)))
        if np.isfinite(status.sigma_fx_px):
            rec.log("fx_sigma/now_px", rr.Scalars(float(status.sigma_fx_px)))
        rec.log("fx_sigma/goal_px", rr.Scalars(float(status.goal_px)))

    def close(self) -> Path | None:
        """Flush; the recording file (moved into place), or None for a viewer."""
        return self.stream.close()


FOUND, NOT_FOUND = (40, 200, 60), (230, 40, 40)


class CaptureView:
    """The live view of ``calibgraph capture --view`` (``--auto`` or a trajectory): an observer of the
    acquisition loop (:attr:`calibgraph.acquire.loop.Station.watch`). Entities (timeline "capture",
    the visit's index)::

        <camera>/image              every frame grabbed (JPEG, at most ``MAX_WIDTH_PX`` wide)
        <camera>/image/corners      the detected corners (green), cleared when the board is not found
        <camera>/board_found        1 found, 0 not (a scalar per grab)
        world/flange                the flange pose in the base frame at each grab (axes)
        world/board                 the board pose in the base frame (flange pose x the nominal mount)
        world/flange_path           every grab's flange position so far
        world/next_pose             the flange pose the plan sends the robot to for capture k (axes, logged
                                    before it moves), cleared at the end
        world/cameras/<camera>      each camera's current estimated pose (eye-to-hand; under
                                    world/flange/cameras for eye-in-hand)
        sigma/<camera>/mm, /deg     each camera's 1-sigma translation / rotation norm after capture k (the
                                    plan's: batch solve or scaled iSAM2 for --auto, iSAM2 for a trajectory)
        sigma/tolerance_mm, _deg    the tolerance
        log                         one line per grab: which cameras found the board, and why not

    Args:
        tolerance: (mm, deg) the 1-sigma series are drawn against.
        rrd: the file to write; None spawns a viewer instead.
        T_flange_board: the board's nominal mount (None: no world/board).
        eye_in_hand: cameras ride on the flange.
    """

    def __init__(self, tolerance: tuple, rrd: Path | None = None, T_flange_board=None,
                 eye_in_hand: bool = False):
        self.stream = Stream("calibgraph_capture", rrd)
        self.rr, self.rec = rr, rec = self.stream.rr, self.stream.rec
        self.tol = (float(tolerance[0]), float(tolerance[1]))
        self.T_fb = None if T_flange_board is None else np.asarray(T_flange_board, float)
        self.cam_root = "world/flange/cameras" if eye_in_hand else "world/cameras"
        self.path = []
        self.k = 0
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for e, length in (("world/flange", 0.08), ("world/board", 0.05), ("world/next_pose", 0.12)):
            rec.log(f"{e}/axes", axes(rr, length), static=True)

    def _pose(self, entity: str, T) -> None:
        self.rec.log(entity, pose(self.rr, np.asarray(T, float)))

    def frames(self, k: int, T_base_flange, images: dict, found: dict, why: dict) -> None:
        """One grab: ``images`` camera -> frame, ``found`` camera -> uv_px (N,2) or None, ``why`` camera -> reason."""
        rr, rec = self.rr, self.rec
        self.k = int(k)
        rec.set_time("capture", sequence=self.k)
        T = np.asarray(T_base_flange, float)
        self._pose("world/flange", T)
        if self.T_fb is not None:
            self._pose("world/board", T @ self.T_fb)
        self.path.append(T[:3, 3])
        rec.log("world/flange_path", rr.Points3D(np.array(self.path), radii=0.004, colors=(150, 150, 150)))
        words = []
        for c, img in images.items():
            uv = found.get(c)
            if f"{c}/image" not in self.stream.scales:  # a camera's image space, at its first frame
                self.stream.pinhole(f"{c}/image", img.shape[1], img.shape[0])
            self.stream.image(f"{c}/image", img, uv, FOUND)
            rec.log(f"{c}/board_found", rr.Scalars(0.0 if uv is None else 1.0))
            words.append(f"{c} found {len(uv)} corners" if uv is not None else f"{c} no board ({why.get(c, 'not found')})")
        rec.log("log", rr.TextLog(f"capture {self.k}: " + ("; ".join(words) or "no frame"),
                                  level="INFO" if any(v is not None for v in found.values()) else "WARN"))

    def next_pose(self, k, T_base_flange, estimates: dict) -> None:
        """Before visit ``k`` (None: the run ended): the flange pose it goes to (None: unknown) and the
        plan's estimates, camera -> (T_ref_cam or None, 1-sigma mm or None, 1-sigma deg or None)."""
        rr, rec = self.rr, self.rec
        rec.set_time("capture", sequence=self.k if k is None else int(k))  # where capture k goes
        if T_base_flange is None:
            rec.log("world/next_pose", rr.Clear(recursive=False))
        else:
            self._pose("world/next_pose", T_base_flange)
        rec.set_time("capture", sequence=self.k)  # the estimates of the captures up to the last grab
        for c, (T, mm, deg) in estimates.items():
            if T is not None:
                self._pose(f"{self.cam_root}/{c}", T)
                rec.log(f"{self.cam_root}/{c}/axes", axes(rr, 0.1))
            if mm is not None and np.isfinite(mm):
                rec.log(f"sigma/{c}/mm", rr.Scalars(float(mm)))
            if deg is not None and np.isfinite(deg):
                rec.log(f"sigma/{c}/deg", rr.Scalars(float(deg)))
        rec.log("sigma/tolerance_mm", rr.Scalars(self.tol[0]))
        rec.log("sigma/tolerance_deg", rr.Scalars(self.tol[1]))

    def close(self) -> Path | None:
        """Flush; the recording file (moved into place), or None for a viewer."""
        return self.stream.close()
