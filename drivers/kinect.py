"""Microsoft Kinect V2 (Kinect for Xbox One) through libfreenect2's Python binding ``pylibfreenect2``.

Install: ``bash scripts/install_kinect_sdk.sh`` builds libfreenect2 and a patched pylibfreenect2 from
the upstream sources in ``../shared/vendor/kinect/`` into the active Python environment (neither is on
a package registry). A live device also needs USB 3 and access to it (libfreenect2's udev rule, or
root). The other supported way to use a Kinect V2 is its ROS 2 bridge with :mod:`calibgraph_drivers.ros2`.

Implements :class:`calibgraph.acquire.interfaces.Camera` for the 1920x1080 colour stream, and with
``depth=True`` also gives depth, IR and depth registered to the colour image (:meth:`KinectV2Camera.grab_rgbd`):

- colour frames arrive as BGRX; the X channel is dropped (OpenCV BGR);
- libfreenect2 delivers the images mirrored left-right (iai_kinect2 flips them back);
  ``unmirror=True`` (default) flips colour, depth, IR and registered depth, and maps the factory
  principal point accordingly (``cx -> (W - 1) - cx``), so the image is the physical camera's view;
- intrinsics: the factory ``ColorCameraParams`` (fx, fy, cx, cy) the device reports when its
  streams start, with ``source='factory'`` (the solver gives them a factory-sized prior).
  libfreenect2 exposes no distortion for the colour camera, so it is zero here -- for accurate
  work calibrate the colour intrinsics first and pass them as ``intrinsics=``;
- freshness: frames queued before :meth:`KinectV2Camera.grab` are released unused, then the next
  one is taken (polling ``hasNewFrame``, so a stalled device raises
  :class:`~calibgraph.acquire.interfaces.DeviceError` after ``timeout_s`` instead of blocking);
- stamp: the frame's device timestamp; libfreenect2's unit is 0.125 ms (a 30 Hz stream advances
  by 266 or 267 per frame);
- registration: libfreenect2's ``Registration`` (the device's IR and colour parameters) maps the
  depth image into the colour image; where several depth pixels land on one colour pixel the
  nearest wins, and colour pixels no depth pixel reaches are 0.

What ``tests/test_kinect.py`` shows, without a device: the real libfreenect2 (enumeration over
the real libusb, the real packet pipeline: RGB and depth stream parsers, TurboJPEG, the CPU depth
decoder, the frame listener, registration) running under this driver, fed with synthetic USB
packets through a replay device (see ``scripts/patches/pylibfreenect2``). What they cannot show:
the USB transport and isochronous transfers, the firmware commands that start, stop and
configure the device and read its parameters, whether a real device's images are mirrored as
assumed above, whether the factory colour parameters are right, and whether depth values are
right (that needs a real device's P0 tables and optics; the tests load all-zero P0 tables), nor
the OpenGL/OpenCL/CUDA pipelines (the script builds the CPU one only).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame
from calibgraph.core.camera import Intrinsics

try:  # built from source by scripts/install_kinect_sdk.sh; see the module docstring
    import pylibfreenect2 as _fn2
except ImportError as _e:  # pylibfreenect2 is on no package registry
    _fn2 = None
    _IMPORT_ERROR = str(_e)

COLOR_W, COLOR_H = 1920, 1080
DEPTH_W, DEPTH_H = 512, 424
STAMP_UNIT_S = 0.125e-3  # libfreenect2 Frame::timestamp unit


def _require_sdk():
    if _fn2 is None:
        raise DeviceError("the Kinect V2 driver needs pylibfreenect2 built against libfreenect2 (not on PyPI: run "
                          "bash scripts/install_kinect_sdk.sh). Alternatively run the Kinect's ROS 2 bridge and use "
                          f"driver: ros2 [{_IMPORT_ERROR}].")
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


def _text(s) -> str:
    return s.decode(errors="replace") if isinstance(s, bytes) else str(s)


def color_intrinsics(params, unmirror: bool = True) -> Intrinsics:
    """calibgraph intrinsics of the colour image from libfreenect2's ``ColorCameraParams``
    (no distortion: libfreenect2 has none for the colour camera)."""
    fx, fy, cx, cy = (float(params.fx), float(params.fy), float(params.cx), float(params.cy))
    if not (fx > 0 and fy > 0 and np.isfinite([cx, cy]).all()):
        raise DeviceError(f"Kinect V2: the device reported no usable colour parameters (fx={fx:g}, fy={fy:g}).")
    if unmirror:
        cx = (COLOR_W - 1) - cx
    return Intrinsics(K=[[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dist=np.zeros(5), width_px=COLOR_W,
                      height_px=COLOR_H, source="factory")


@dataclass(frozen=True)
class RgbdFrame:
    """One synchronised colour + depth frame of :meth:`KinectV2Camera.grab_rgbd`.

    Attributes:
        color: the colour frame, as :meth:`KinectV2Camera.grab` returns it.
        depth_m: (424, 512) float32 depth along the IR camera's axis, metres; 0 = no measurement.
        ir: (424, 512) float32 IR amplitude (libfreenect2's scale, at most 65535).
        depth_in_color_m: (1080, 1920) float32 depth registered to the colour image, metres; 0 where
            no depth pixel lands.
        depth_stamp_s: the depth frame's device timestamp, seconds.
    """

    color: Frame
    depth_m: np.ndarray
    ir: np.ndarray
    depth_in_color_m: np.ndarray
    depth_stamp_s: float


class KinectV2Camera:
    """A Kinect V2 colour stream, optionally with depth (see the module docstring).

    Args:
        name: camera name in the dataset.
        serial: device serial, a string (default: the first device).
        pipeline: libfreenect2 packet pipeline ('cpu', 'opengl', 'opencl', 'cuda'); colour decoding
            is the same in all of them.
        unmirror: flip libfreenect2's mirrored images back.
        intrinsics: calibrated colour intrinsics to report instead of the factory values.
        settle_frames: frames dropped after start (auto-exposure).
        timeout_s: longest wait for a frame.
        depth: also stream depth and IR (:meth:`grab_rgbd`); costs USB bandwidth and CPU.
    """

    def __init__(self, name: str, serial: str | None = None, pipeline: str = "cpu", unmirror: bool = True,
                 intrinsics: dict | None = None, settle_frames: int = 30, timeout_s: float = 2.0,
                 depth: bool = False):
        fn2 = _require_sdk()
        if serial is not None and not isinstance(serial, str):
            raise DeviceError(f"Kinect V2 camera {name}: serial must be a string, got {serial!r} (quote it in YAML, "
                              "so that leading zeros survive).")
        context = fn2.Freenect2()
        n = context.enumerateDevices()
        if n == 0:
            raise DeviceError(f"Kinect V2 camera {name}: no Kinect V2 connected (USB 3 port, power supply, "
                              "udev rules or root for USB access?).")
        serials = [_text(context.getDeviceSerialNumber(i)) for i in range(n)]
        if serial is None:
            serial = serials[0]
        elif serial not in serials:
            raise DeviceError(f"Kinect V2 camera {name}: no device with serial {serial}; connected: {', '.join(serials)}.")
        dev = context.openDevice(serial.encode(), pipeline=_pipeline(fn2, pipeline))
        # the patched binding returns None when libfreenect2 cannot open it (busy, no permission);
        # an unpatched one returns a wrapper around NULL that crashes on use
        if dev is None:
            raise DeviceError(f"Kinect V2 camera {name}: cannot open device {serial} (in use by another program, or "
                              "no permission on its USB device?).")
        self._setup(name, fn2, context, dev, serial, unmirror, intrinsics, settle_frames, timeout_s, depth)

    @classmethod
    def from_device(cls, name: str, device, context=None, unmirror: bool = True, intrinsics: dict | None = None,
                    settle_frames: int = 30, timeout_s: float = 2.0, depth: bool = False) -> "KinectV2Camera":
        """The driver on an already opened pylibfreenect2 device (e.g. one a ``Freenect2Replay``
        opened); ``context`` is the object that opened it, kept alive as long as the camera."""
        self = cls.__new__(cls)
        self._setup(name, _require_sdk(), context, device, _text(device.getSerialNumber()), unmirror, intrinsics,
                    settle_frames, timeout_s, depth)
        return self

    def _setup(self, name, fn2, context, dev, serial, unmirror, intrinsics, settle_frames, timeout_s, depth):
        self.name = name
        self.serial = serial
        self.unmirror = bool(unmirror)
        self.timeout_s = float(timeout_s)
        self.depth = bool(depth)
        self._fn, self._dev = context, dev
        types = fn2.FrameType.Color | ((fn2.FrameType.Ir | fn2.FrameType.Depth) if self.depth else 0)
        self._listener = fn2.SyncMultiFrameListener(types)
        dev.setColorFrameListener(self._listener)
        if self.depth:
            dev.setIrAndDepthFrameListener(self._listener)
        self._closed = False
        try:
            ok = dev.startStreams(rgb=True, depth=self.depth)
            if ok is False:  # the patched binding returns libfreenect2's result (older ones return None)
                raise DeviceError(f"Kinect V2 camera {name} ({serial}): the device did not start streaming "
                                  "(USB 3 bandwidth or firmware?).")
            # the device reads its camera parameters when its streams start
            self._intr = (Intrinsics.from_dict(intrinsics) if intrinsics is not None
                          else color_intrinsics(dev.getColorCameraParams(), self.unmirror))
            if self.depth:
                self._reg = fn2.Registration(dev.getIrCameraParams(), dev.getColorCameraParams())
                self._undistorted = fn2.Frame(DEPTH_W, DEPTH_H, 4)
                self._registered = fn2.Frame(DEPTH_W, DEPTH_H, 4)
                self._bigdepth = fn2.Frame(COLOR_W, COLOR_H + 2, 4)
            for _ in range(int(settle_frames)):
                self._next()
        except BaseException:
            self.close()
            raise

    def _flip(self, img: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(img[:, ::-1]) if self.unmirror else img

    def _next(self) -> dict:
        """The next frame set, copied out of the listener, waiting at most ``timeout_s``."""
        t_end = time.monotonic() + self.timeout_s
        while not self._listener.hasNewFrame():
            if time.monotonic() > t_end:
                raise DeviceError(f"Kinect V2 camera {self.name} ({self.serial}): no frame within {self.timeout_s:g} s "
                                  "(disconnected or USB bandwidth exhausted).")
            time.sleep(0.002)
        frames = self._listener.waitForNewFrame()
        try:
            color = frames["color"]
            out = {"color": self._flip(np.array(color.asarray(np.uint8)[..., :3])),  # BGRX -> BGR, copied
                   "stamp_s": float(color.timestamp) * STAMP_UNIT_S}
            if self.depth:
                depth, ir = frames["depth"], frames["ir"]
                self._reg.apply(color, depth, self._undistorted, self._registered, enable_filter=True,
                                bigdepth=self._bigdepth)
                big = self._bigdepth.asarray(np.float32)[1:-1]  # one padding row above and below
                out["depth_in_color_m"] = self._flip(np.where(np.isfinite(big), big * 1e-3, 0.0).astype(np.float32))
                out["depth_m"] = self._flip(np.array(depth.asarray(np.float32)) * np.float32(1e-3))
                out["ir"] = self._flip(np.array(ir.asarray(np.float32)))
                out["depth_stamp_s"] = float(depth.timestamp) * STAMP_UNIT_S
        finally:
            self._listener.release(frames)
        return out

    def intrinsics(self) -> Intrinsics:
        return self._intr

    def _fresh(self) -> dict:
        if self._closed:
            raise DeviceError(f"Kinect V2 camera {self.name}: used after close().")
        while self._listener.hasNewFrame():  # frames exposed before the call are stale
            self._listener.release(self._listener.waitForNewFrame())
        return self._next()

    def grab(self) -> Frame:
        f = self._fresh()
        return Frame(camera=self.name, image=f["color"], stamp_s=f["stamp_s"])

    def grab_rgbd(self) -> RgbdFrame:
        """A fresh colour frame with the depth and IR frames synchronised to it (needs ``depth=True``)."""
        if not self.depth:
            raise DeviceError(f"Kinect V2 camera {self.name}: grab_rgbd needs depth: true.")
        f = self._fresh()
        return RgbdFrame(color=Frame(camera=self.name, image=f["color"], stamp_s=f["stamp_s"]), depth_m=f["depth_m"],
                         ir=f["ir"], depth_in_color_m=f["depth_in_color_m"], depth_stamp_s=f["depth_stamp_s"])

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self._dev.stop()
            self._dev.close()  # detaches the listener, so it may be freed
        except Exception:  # best effort: the device may be gone already
            pass
        # the context deletes the device (and its USB handle) when the last reference goes
        self._dev = self._fn = None
