"""Intel RealSense D455 / L515 (and other D400 / L500 devices) through pyrealsense2 (the
``realsense`` extra).

    pip install 'calibgraph[realsense]'      # pyrealsense2 and libusb-package

On Linux the pyrealsense2 wheel links against ``libusb-1.0.so.0`` without shipping it; the
``libusb-package`` wheel ships one, which is loaded (``RTLD_GLOBAL``) before pyrealsense2 so that
no system package is needed (:data:`LIBUSB`; without libusb-package, the system's libusb-1.0-0 is
used).

Implements :class:`calibgraph.acquire.interfaces.Camera` for the **colour** stream.

Sources:

- a live device by ``serial`` (or the first one found): the colour sensor is opened directly and
  streams into an ``rs.syncer``;
- ``device=``: any ``rs.device`` object, e.g. an ``rs.software_device`` (how the tests feed it);
- ``file=``: a recording (``.db3`` from ``rs.recorder`` / the RealSense Viewer; ``.bag`` on older
  SDKs) played back through ``rs.config.enable_device_from_file`` and an ``rs.pipeline``, not in
  real time, so no frame is dropped.

Resolution: the native (largest) colour mode unless ``width_px``/``height_px`` are given
(D455: 1280x800, L515: 1920x1080). Formats are preferred in the order BGR8, RGB8, YUYV, Y8;
frames are returned as OpenCV BGR (or grey for Y8).

Intrinsics are the factory calibration the device reports for the active stream, mapped to
calibgraph's OpenCV model (:func:`intrinsics_from_rs`). librealsense puts pixel centres at
integer coordinates like OpenCV, so ``ppx, ppy`` map to ``cx, cy`` unchanged. Distortion models:

- ``brown_conrady``: the same polynomial as OpenCV (``coeffs = k1 k2 p1 p2 k3``, tangential terms
  on the undistorted point), mapped one to one.
- ``none``: zero coefficients.
- ``inverse_brown_conrady`` (many D400 colour streams): the polynomial maps *distorted* to
  *undistorted* points, which OpenCV's model cannot represent exactly; forward coefficients are
  fitted over a grid covering the image (linear least squares for k1 k2 p1 p2 k3, then
  Gauss-Newton on OpenCV's 8-term rational model when that is closer), and the worst pixel
  error of the fit is kept in :attr:`RealSenseCamera.notes` (D455-like coefficients: < 0.01 px).
- ``modified_brown_conrady`` (tangential terms on the radially distorted point): fitted the same way.
- ``kannala_brandt4`` / ``ftheta`` (fisheye, T265): refused.

Exposure settling: after the stream starts, ``settle_frames`` frames are dropped, then, when the
frames carry ``actual_exposure`` metadata, frames are read until the exposure has changed by less
than 2 % over four frames (or ``exposure_settle_timeout_s`` passes: noted, not fatal). A fixed
``exposure_us`` turns auto-exposure off instead (recommended for calibration under steady light).

Freshness: :meth:`RealSenseCamera.grab` first discards every frame already queued, then waits for
the next one, so the frame returned started after the call (never a frame from before the robot
settled).
"""

from __future__ import annotations

import time

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame
from calibgraph.core.camera import Intrinsics

try:
    # Load rclpy's libraries (when installed) before librealsense's: with pyrealsense2 2.59 loaded
    # first, a process that later starts rclpy (calibgraph_drivers.ros2) double-frees in its C exit handlers
    # and dies with SIGSEGV after all work is done. Loaded in this order both exit cleanly.
    import rclpy  # noqa: F401
except ImportError:
    pass


def _load_libusb() -> str | None:
    """Load the libusb that the ``libusb-package`` wheel ships, with ``RTLD_GLOBAL``, so that
    pyrealsense2's dependency on ``libusb-1.0.so.0`` (that library's soname) resolves to it rather
    than to a system library that a fresh machine does not have. Returns its path, or None when
    libusb-package is not installed (then the system's libusb-1.0-0, if any, is used)."""
    import ctypes
    import sys

    if not sys.platform.startswith("linux"):  # the macOS and Windows SDK wheels do not need it
        return None
    try:
        import libusb_package

        path = libusb_package.get_library_path()
        if path is None:
            return None
        ctypes.CDLL(str(path), mode=ctypes.RTLD_GLOBAL)
        return str(path)
    except (ImportError, OSError):
        return None


#: the libusb loaded for pyrealsense2 from libusb-package (None: not installed, or not Linux)
LIBUSB = _load_libusb()

try:  # the SDK is an optional extra; the engine and other drivers must import without it
    import pyrealsense2 as _rs
except ImportError as _e:  # pragma: no cover - exercised only where pyrealsense2 is absent or cannot load
    _rs = None
    _IMPORT_ERROR = str(_e)


def _require_sdk():
    if _rs is None:
        raise DeviceError("the RealSense driver needs pyrealsense2 and libusb: pip install 'calibgraph[realsense]' "
                          f"(pyrealsense2 and libusb-package) [{_IMPORT_ERROR}].")
    return _rs


# -- intrinsics ---------------------------------------------------------------------------------------
def _bc_radial(c, r2):
    return 1.0 + c[0] * r2 + c[1] * r2 * r2 + c[4] * r2 * r2 * r2


def _fit_forward(x_u, y_u, x_d, y_d):
    """OpenCV (k1 k2 p1 p2 k3) mapping undistorted (x_u, y_u) to distorted (x_d, y_d), least squares."""
    r2 = x_u * x_u + y_u * y_u
    # x_d - x_u = x_u (k1 r2 + k2 r4 + k3 r6) + 2 p1 x y + p2 (r2 + 2 x^2), and likewise for y
    Ax = np.column_stack([x_u * r2, x_u * r2 ** 2, 2 * x_u * y_u, r2 + 2 * x_u ** 2, x_u * r2 ** 3])
    Ay = np.column_stack([y_u * r2, y_u * r2 ** 2, r2 + 2 * y_u ** 2, 2 * x_u * y_u, y_u * r2 ** 3])
    A = np.vstack([Ax, Ay])
    b = np.concatenate([x_d - x_u, y_d - y_u])
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    k1, k2, p1, p2, k3 = sol
    return np.array([k1, k2, p1, p2, k3])


def _grid(width, height, n=24):
    u, v = np.meshgrid(np.linspace(0, width - 1, n), np.linspace(0, height - 1, n))
    return u.ravel(), v.ravel()


def distortion_from_rs(model_name: str, coeffs, fx, fy, ppx, ppy, width, height):
    """OpenCV coefficients (5,) and the worst fit error in pixels for a librealsense model.

    ``model_name`` is the ``rs.distortion`` member name ('brown_conrady', 'none', ...)."""
    c = np.asarray(list(coeffs) + [0.0] * 5, float)[:5]
    if model_name == "none":
        return np.zeros(5), 0.0
    if model_name == "brown_conrady":
        return c.copy(), 0.0
    u, v = _grid(width, height)
    if model_name == "inverse_brown_conrady":
        # rs2_deproject_pixel_to_point: the pixel is distorted; the polynomial gives the undistorted point
        x_d, y_d = (u - ppx) / fx, (v - ppy) / fy
        r2 = x_d * x_d + y_d * y_d
        f = _bc_radial(c, r2)
        x_u = x_d * f + 2 * c[2] * x_d * y_d + c[3] * (r2 + 2 * x_d * x_d)
        y_u = y_d * f + 2 * c[3] * x_d * y_d + c[2] * (r2 + 2 * y_d * y_d)
    elif model_name == "modified_brown_conrady":
        # rs2_project_point_to_pixel: radial first, then tangential on the radially distorted point
        x_u, y_u = (u - ppx) / fx, (v - ppy) / fy
        r2 = x_u * x_u + y_u * y_u
        f = _bc_radial(c, r2)
        xr, yr = x_u * f, y_u * f
        x_d = xr + 2 * c[2] * xr * yr + c[3] * (r2 + 2 * xr * xr)
        y_d = yr + 2 * c[3] * xr * yr + c[2] * (r2 + 2 * yr * yr)
    else:
        raise DeviceError(f"RealSense distortion model {model_name!r} (fisheye) is not supported by calibgraph's "
                          "OpenCV pinhole model; use a colour stream with Brown-Conrady distortion.")
    K = np.array([[fx, 0, ppx], [0, fy, ppy], [0, 0, 1.0]])
    P = np.column_stack([x_u, y_u, np.ones_like(x_u)])
    target = np.column_stack([x_d * fx + ppx, y_d * fy + ppy])

    def residual(d):
        return (Intrinsics(K=K, dist=d, width_px=width, height_px=height).project(P) - target).ravel()

    dist = _fit_forward(x_u, y_u, x_d, y_d)
    err = float(np.max(np.abs(residual(dist))))
    if err > 1e-3:
        # the 5-term polynomial cannot invert a polynomial exactly; OpenCV's rational model
        # (k4 k5 k6 in the denominator) can come much closer: Gauss-Newton from the linear fit
        d8 = np.concatenate([dist, np.zeros(3)])
        r = residual(d8)
        lam = 1e-3
        for _ in range(100):  # Levenberg-Marquardt with a numeric Jacobian (8 parameters)
            J = np.empty((r.size, 8))
            for k in range(8):
                step = np.zeros(8)
                step[k] = 1e-7
                J[:, k] = (residual(d8 + step) - r) / 1e-7
            A = J.T @ J
            g = J.T @ r
            delta = np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12), -g)
            r_new = residual(d8 + delta)
            if r_new @ r_new < r @ r:
                d8, r, lam = d8 + delta, r_new, lam * 0.3
                if np.max(np.abs(delta)) < 1e-12:
                    break
            else:
                lam *= 10.0
                if lam > 1e8:
                    break
        err8 = float(np.max(np.abs(residual(d8))))
        if err8 < err:
            dist, err = d8, err8
    return dist, err


def intrinsics_from_rs(rs_intr) -> tuple[Intrinsics, float]:
    """(calibgraph Intrinsics, distortion fit error px) from a ``pyrealsense2.intrinsics``."""
    name = str(rs_intr.model).split(".")[-1]
    dist, err = distortion_from_rs(name, rs_intr.coeffs, rs_intr.fx, rs_intr.fy, rs_intr.ppx, rs_intr.ppy,
                                   rs_intr.width, rs_intr.height)
    K = np.array([[rs_intr.fx, 0.0, rs_intr.ppx], [0.0, rs_intr.fy, rs_intr.ppy], [0.0, 0.0, 1.0]])
    return Intrinsics(K=K, dist=dist, width_px=int(rs_intr.width), height_px=int(rs_intr.height)), err


# -- camera --------------------------------------------------------------------------------------------
_FORMAT_PREFERENCE = ("bgr8", "rgb8", "yuyv", "y8")


def _fmt_name(fmt) -> str:
    return str(fmt).split(".")[-1]


def _to_image(frame) -> np.ndarray:
    a = np.asanyarray(frame.get_data()).copy()  # copy: the SDK recycles its buffer
    fmt = _fmt_name(frame.profile.format())
    if fmt == "bgr8" or fmt == "y8":
        return a
    if fmt == "rgb8":
        return np.ascontiguousarray(a[..., ::-1])
    if fmt == "yuyv":
        import cv2

        return cv2.cvtColor(a.reshape(a.shape[0], -1, 2), cv2.COLOR_YUV2BGR_YUYV)
    raise DeviceError(f"RealSense colour format {fmt} is not supported; use BGR8, RGB8, YUYV or Y8.")


class RealSenseCamera:
    """A RealSense colour stream (see the module docstring).

    Args:
        name: camera name in the dataset.
        serial: device serial number (default: the first device found).
        file: a recording to play back instead of a live device.
        device: an ``rs.device`` to use directly (e.g. a software device).
        width_px, height_px, fps: colour mode (default: native resolution, 30 fps or the closest).
        settle_frames: frames dropped after the stream starts.
        exposure_us: fixed exposure (disables auto-exposure); None keeps the device's setting.
        exposure_settle_timeout_s: longest wait for auto-exposure to settle.
        timeout_s: longest wait for a frame before a grab fails.
    """

    def __init__(self, name: str, serial: str | None = None, file: str | None = None, device=None,
                 width_px: int | None = None, height_px: int | None = None, fps: int = 30, settle_frames: int = 30,
                 exposure_us: float | None = None, exposure_settle_timeout_s: float = 3.0, timeout_s: float = 2.0):
        rs = _require_sdk()
        self.name = name
        self.timeout_ms = int(1000 * timeout_s)
        self.notes = []
        self.exposure_history = []
        self._pipe = self._sensor = self._sync = None
        self._closed = False
        if file is not None:
            self._open_file(rs, str(file))
        else:
            self._open_device(rs, serial, device, width_px, height_px, fps, exposure_us)
        self._intr, err = intrinsics_from_rs(self._profile.get_intrinsics())
        self.distortion_model = str(self._profile.get_intrinsics().model).split(".")[-1]
        if err > 0:
            self.notes.append(f"{self.distortion_model} distortion fitted to OpenCV's model, worst error {err:.3f} px")
        self._settle(int(settle_frames), exposure_settle_timeout_s)

    # -- opening ---------------------------------------------------------------------------------
    def _open_file(self, rs, path):
        import os

        if not os.path.isfile(path):
            raise DeviceError(f"RealSense camera {self.name}: recording {path} does not exist.")
        cfg = rs.config()
        cfg.enable_device_from_file(path, repeat_playback=False)
        cfg.enable_stream(rs.stream.color)
        self._pipe = rs.pipeline()
        try:
            # non-real-time playback (no frame dropped) must be set before streaming starts
            cfg.resolve(self._pipe).get_device().as_playback().set_real_time(False)
            prof = self._pipe.start(cfg)
        except RuntimeError as e:
            raise DeviceError(f"RealSense camera {self.name}: cannot play {path} ({e}); is it a colour recording?") from None
        prof.get_device().as_playback().set_real_time(False)
        self._profile = prof.get_stream(rs.stream.color).as_video_stream_profile()
        self.serial = prof.get_device().get_info(rs.camera_info.serial_number) \
            if prof.get_device().supports(rs.camera_info.serial_number) else ""

    def _open_device(self, rs, serial, device, width_px, height_px, fps, exposure_us):
        if device is None:
            devs = list(rs.context().query_devices())
            if serial is not None:
                devs = [d for d in devs if d.supports(rs.camera_info.serial_number)
                        and d.get_info(rs.camera_info.serial_number) == str(serial)]
            if not devs:
                raise DeviceError(f"RealSense camera {self.name}: no device" + (f" with serial {serial}" if serial else "")
                                  + " is connected; check the USB 3 cable and `rs-enumerate-devices`.")
            device = devs[0]
        self.serial = device.get_info(rs.camera_info.serial_number) if device.supports(rs.camera_info.serial_number) else ""
        sensor = None
        for s in device.query_sensors():
            if any(p.stream_type() == rs.stream.color for p in s.get_stream_profiles()):
                sensor = s
                break
        if sensor is None:
            raise DeviceError(f"RealSense camera {self.name} ({self.serial}): the device has no colour stream.")
        profiles = [p.as_video_stream_profile() for p in sensor.get_stream_profiles()
                    if p.stream_type() == rs.stream.color and _fmt_name(p.format()) in _FORMAT_PREFERENCE]
        if width_px is not None:
            profiles = [p for p in profiles if p.width() == int(width_px) and p.height() == int(height_px)]
        if not profiles:
            raise DeviceError(f"RealSense camera {self.name} ({self.serial}): no colour mode "
                              + (f"{width_px}x{height_px} " if width_px else "") + "in BGR8/RGB8/YUYV/Y8.")

        def rank(p):
            return (p.width() * p.height(), -abs(p.fps() - fps), -_FORMAT_PREFERENCE.index(_fmt_name(p.format())))

        prof = max(profiles, key=rank)
        if exposure_us is not None:
            try:
                sensor.set_option(rs.option.enable_auto_exposure, 0)
                sensor.set_option(rs.option.exposure, float(exposure_us))
            except RuntimeError as e:
                raise DeviceError(f"RealSense camera {self.name}: cannot set exposure {exposure_us} us ({e}).") from None
        self._sync = rs.syncer()
        try:
            sensor.open(prof)
            sensor.start(self._sync)
        except RuntimeError as e:
            raise DeviceError(f"RealSense camera {self.name} ({self.serial}): cannot start the colour stream ({e}).") from None
        self._sensor = sensor
        self._device = device
        self._profile = prof

    # -- frames ----------------------------------------------------------------------------------
    def _wait(self):
        try:
            if self._pipe is not None:
                ok, fs = self._pipe.try_wait_for_frames(self.timeout_ms)
            else:
                ok, fs = self._sync.try_wait_for_frames(self.timeout_ms)
        except RuntimeError as e:
            raise DeviceError(f"RealSense camera {self.name}: {e}") from None
        if not ok:
            what = "the recording ended" if self._pipe is not None else f"no frame within {self.timeout_ms} ms"
            raise DeviceError(f"RealSense camera {self.name} ({self.serial}): {what} (disconnected or stalled).")
        c = fs.get_color_frame() if hasattr(fs, "get_color_frame") else fs
        if not c:
            raise DeviceError(f"RealSense camera {self.name}: frame set without a colour frame.")
        return c

    def _drain(self):
        src = self._pipe if self._pipe is not None else self._sync
        if self._pipe is not None:
            return  # playback is not real time: queued frames are not stale, they are the recording
        while True:
            fs = src.poll_for_frames()
            if not fs:
                return

    def _settle(self, n, timeout_s):
        rs = _rs
        for _ in range(n):
            self._wait()
        t_end = time.monotonic() + timeout_s
        while True:
            f = self._wait()
            if not f.supports_frame_metadata(rs.frame_metadata_value.actual_exposure):
                return
            self.exposure_history.append(float(f.get_frame_metadata(rs.frame_metadata_value.actual_exposure)))
            last = self.exposure_history[-4:]
            if len(last) == 4 and max(last) - min(last) <= 0.02 * max(max(last), 1e-9):
                return
            if time.monotonic() > t_end:
                self.notes.append(f"auto-exposure still changing after {timeout_s:g} s (last {last})")
                return

    def intrinsics(self) -> Intrinsics:
        return self._intr

    def grab(self) -> Frame:
        if self._closed:
            raise DeviceError(f"RealSense camera {self.name}: used after close().")
        self._drain()
        f = self._wait()
        return Frame(camera=self.name, image=_to_image(f), stamp_s=float(f.get_timestamp()) * 1e-3)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            if self._pipe is not None:
                self._pipe.stop()
            elif self._sensor is not None:
                self._sensor.stop()
                self._sensor.close()
        except RuntimeError:  # already stopped or unplugged
            pass
