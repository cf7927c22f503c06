"""A live rerun view of a guided intrinsics session (``calibgraph intrinsics --live --view``).

Entities (timeline "frame", one step per frame read)::

    <camera>/image               the frame (JPEG, at most ``MAX_WIDTH_PX`` wide)
    <camera>/image/corners       the board's corners: yellow while it moves, green when still, blue when taken
    coverage                     the taken views' corners per image cell (the heat map the coverage check
                                 counts: ``GRID_COLS`` cells across), brighter = more corners
    fx_sigma/now_px              fx 1-sigma after the frame (predicted until the first calibration)
    fx_sigma/goal_px             the goal
    log                          the console line of every taken frame

It streams to a viewer (``spawn``) where there is a display, else into a ``.rrd`` file, written
under a temporary name and moved into place when the session ends. rerun is imported lazily.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from calibgraph.report.rerun_view import _import_rerun, _viridis
from calibgraph.solver.intrinsics_session import GRID_COLS

MAX_WIDTH_PX = 960
JPEG_QUALITY = 80
CELL_PX = 24  # each coverage cell drawn as a square of this many pixels
COLOURS = {"moving": (240, 200, 0), "still": (40, 200, 60), "taken": (40, 120, 255)}


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class LiveView:
    """Callable ``(frame_no, image, uv_px or None, status)`` logging one frame (module docstring).

    Args:
        camera: the camera's name (the entity root).
        width_px, height_px, fx_px: its image size and focal length (for the log's percentages).
        rrd: the file to write; None spawns a viewer instead.
    """

    def __init__(self, camera: str, width_px: int, height_px: int, fx_px: float, rrd: Path | None = None):
        self.rr = rr = _import_rerun()
        self.camera, self.W, self.H, self.fx_px = camera, int(width_px), int(height_px), float(fx_px)
        self.scale = min(1.0, MAX_WIDTH_PX / self.W)
        self.rows = max(2, int(round(GRID_COLS * self.H / self.W)))
        self.counts = np.zeros((self.rows, GRID_COLS))
        self.rrd, self._tmp = (Path(rrd), Path(rrd).with_name(f".{Path(rrd).name}.{os.getpid()}.tmp")) if rrd else (None, None)
        self.rec = rr.RecordingStream("calibgraph_intrinsics_live")
        if self.rrd is None:
            self.rec.spawn()
        else:
            self.rec.save(str(self._tmp))
        self.rec.log(f"{camera}/image", rr.Pinhole(resolution=[round(self.W * self.scale), round(self.H * self.scale)],
                                                    focal_length=float(self.W * self.scale)), static=True)

    def __call__(self, k: int, image: np.ndarray, uv_px, status) -> None:
        import cv2

        rr, rec = self.rr, self.rec
        rec.set_time("frame", sequence=int(k))
        small = image if self.scale == 1.0 else cv2.resize(image, None, fx=self.scale, fy=self.scale,
                                                             interpolation=cv2.INTER_AREA)
        ok, buf = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if ok:
            rec.log(f"{self.camera}/image", rr.EncodedImage(contents=buf.tobytes(), media_type="image/jpeg"))
        if uv_px is None:
            rec.log(f"{self.camera}/image/corners", rr.Clear(recursive=False))
        else:
            rec.log(f"{self.camera}/image/corners", rr.Points2D(np.asarray(uv_px) * self.scale, radii=2.5,
                                                                colors=COLOURS.get(status.board, (200, 200, 200))))
        if status.board == "taken" and uv_px is not None:
            uv = np.asarray(uv_px, float)
            ci = np.clip((uv[:, 0] + 0.5) * GRID_COLS / self.W, 0, GRID_COLS - 1e-9).astype(int)
            ri = np.clip((uv[:, 1] + 0.5) * self.rows / self.H, 0, self.rows - 1e-9).astype(int)
            np.add.at(self.counts, (ri, ci), 1)
            heat = self.counts / self.counts.max()
            img = _viridis(heat.ravel()).reshape(self.rows, GRID_COLS, 3)
            img[self.counts == 0] = 0
            rec.log("coverage", rr.Image(np.repeat(np.repeat(img, CELL_PX, axis=0), CELL_PX, axis=1)))
            rec.log("log", rr.TextLog(status.line(self.fx_px)))
        if np.isfinite(status.sigma_fx_px):
            rec.log("fx_sigma/now_px", rr.Scalars(float(status.sigma_fx_px)))
        rec.log("fx_sigma/goal_px", rr.Scalars(float(status.goal_px)))

    def close(self) -> Path | None:
        """Flush; the recording file (moved into place), or None for a viewer."""
        self.rec.flush()
        self.rec.disconnect()
        if self.rrd is None:
            return None
        os.replace(self._tmp, self.rrd)
        return self.rrd
