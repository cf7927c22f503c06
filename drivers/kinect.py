"""Microsoft Kinect V2 (Kinect for Xbox One) colour camera through libfreenect2's Python binding
``pylibfreenect2``.

**Not tested.** libfreenect2 and pylibfreenect2 are on no package registry this project can
reach, and no Kinect V2 was available, so this module is written against pylibfreenect2's API
(``Freenect2``, ``SyncMultiFrameListener``, ``FrameType``, ``getColorCameraParams``) and
has never run. Treat it as a starting point to verify on hardware; the supported, tested way to
use a Kinect V2 is its ROS 2 bridge with :mod:`drivers.ros2`.

Install by hand: build libfreenect2 (github.com/OpenKinect/libfreenect2, with ``ENABLE_CXX11``),
then ``pip install pylibfreenect2`` with ``LIBFREENECT2_INSTALL_PREFIX`` pointing at it.

Implements :class:`calibgraph.acquire.interfaces.Camera` for the 1920x1080 colour stream:

- frames arrive as BGRX; the X channel is dropped (OpenCV BGR);
- libfreenect2 delivers the colour image mirrored left-right (iai_kinect2 flips it back);
  ``unmirror=True`` (default) flips it and maps the factory principal point accordingly
  (``cx -> (W - 1) - cx``), so the image is the physical camera's view;
- intrinsics: the factory ``ColorCameraParams`` (fx, fy, cx, cy); libfreenect2 exposes no
  distortion for the colour camera, so it is zero here -- for accurate work calibrate the
  colour intrinsics first and pass them as ``intrinsics=``;
- freshness: frames queued before :meth:`KinectV2Camera.grab` are released unused, then the next
  one is taken (polling ``hasNewFrame`` so a stalled device raises
  :class:`~calibgraph.acquire.interfaces.DeviceError` after ``timeout_s`` instead of blocking forever);
- stamp: the frame's device timestamp (libfreenect2: units of 0.1 ms).
"""

from __future__ import annotations

import time

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame
from calibgraph.core.camera import Intrinsics

try:  # hand-built optional dependency; see the module docstring
    import pylibfreenect2 as _fn2
except ImportError as _e:  # pragma: no cover - pylibfreenect2 is not installable from a registry
    _fn2 = None
    _IMPORT_ERROR = str(_e)

COLOR_W, COLOR_H = 1920, 1080


def _require_sdk():
    if _fn2 is None:
        raise DeviceError("the Kinect V2 driver needs pylibfreenect2 built against libfreenect2 (not on PyPI; see "
                          "drivers/kinect.py). Alternatively run the Kinect's ROS 2 bridge and use driver: ros2 "
                          f"[{_IMPORT_ERROR}].")
    return _fn2


def _pipeline(fn2, name: str):
    choices = {"cpu": "CpuPacketPipeline", "opengl": "OpenGLPacketPipeline", "opencl": "OpenCLPacketPipeline",
               "cuda": "CudaPacketPipeline"}
    if name not in choices:
        raise DeviceError(f"Kinect V2: unknown packet pipeline {name!r}; choose one of {sorted(choices)}.")
    cls = getattr(fn2, choices[name], None)
    if cls is None:
        raise DeviceError(f"Kinect V2: this pylibfreenect2 build has no {choices[name]}; use pipeline: cpu.")
    return cls()


class KinectV2Camera:
    """A Kinect V2 colour stream (see the module docstring; untested).

    Args:
        name: camera name in the dataset.
        serial: device serial (default: the first device).
        pipeline: libfreenect2 packet pipeline ('cpu', 'opengl', 'opencl', 'cuda'); colour decoding
            is the same in all of them.
        unmirror: flip libfreenect2's mirrored colour image back.
        intrinsics: calibrated colour intrinsics to report instead of the factory values.
        settle_frames: frames dropped after start (auto-exposure).
        timeout_s: longest wait for a frame.
    """

    def __init__(self, name: str, serial: str | None = None, pipeline: str = "cpu", unmirror: bool = True,
                 intrinsics: dict | None = None, settle_frames: int = 30, timeout_s: float = 2.0):
        fn2 = _require_sdk()
        self.name = name
        self.unmirror = bool(unmirror)
        self.timeout_s = float(timeout_s)
        self._closed = False
        self._fn = fn2.Freenect2()
        n = self._fn.enumerateDevices()
        if n == 0:
            raise DeviceError(f"Kinect V2 camera {name}: no device found (USB 3 port, power supply, udev rules?).")
        if serial is None:
            serial = self._fn.getDeviceSerialNumber(0)
        self.serial = serial
        self._dev = self._fn.openDevice(serial, pipeline=_pipeline(fn2, pipeline))
        if self._dev is None:
            raise DeviceError(f"Kinect V2 camera {name}: cannot open device {serial}.")
        self._listener = fn2.SyncMultiFrameListener(fn2.FrameType.Color)
        self._dev.setColorFrameListener(self._listener)
        self._dev.startStreams(rgb=True, depth=False)
        if intrinsics is not None:
            self._intr = Intrinsics.from_dict(intrinsics)
        else:
            p = self._dev.getColorCameraParams()
            cx = (COLOR_W - 1) - p.cx if self.unmirror else p.cx
            self._intr = Intrinsics(K=[[p.fx, 0.0, cx], [0.0, p.fy, p.cy], [0.0, 0.0, 1.0]], dist=np.zeros(5),
                                    width_px=COLOR_W, height_px=COLOR_H)
        for _ in range(int(settle_frames)):
            self._next()

    def _next(self):
        """(BGR image, stamp_s) of the next frame, waiting at most ``timeout_s``."""
        t_end = time.monotonic() + self.timeout_s
        while not self._listener.hasNewFrame():
            if time.monotonic() > t_end:
                raise DeviceError(f"Kinect V2 camera {self.name} ({self.serial}): no frame within {self.timeout_s:g} s "
                                  "(disconnected or USB bandwidth exhausted).")
            time.sleep(0.002)
        frames = self._listener.waitForNewFrame()
        try:
            color = frames["color"]
            img = np.array(color.asarray(np.uint8), copy=True)[..., :3]  # BGRX -> BGR, copied before release
            stamp_s = float(color.timestamp) * 1e-4
        finally:
            self._listener.release(frames)
        if self.unmirror:
            img = np.ascontiguousarray(img[:, ::-1])
        return img, stamp_s

    def intrinsics(self) -> Intrinsics:
        return self._intr

    def grab(self) -> Frame:
        if self._closed:
            raise DeviceError(f"Kinect V2 camera {self.name}: used after close().")
        while self._listener.hasNewFrame():  # frames exposed before the call are stale
            self._listener.release(self._listener.waitForNewFrame())
        img, stamp_s = self._next()
        return Frame(camera=self.name, image=img, stamp_s=stamp_s)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._dev.stop()
            self._dev.close()
        except Exception:  # best effort: the device may be gone already
            pass
