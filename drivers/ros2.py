"""ROS 2 cameras (``sensor_msgs/Image`` + ``sensor_msgs/CameraInfo``) through rclpy, so any camera
with a ROS 2 driver can be calibrated -- including a Kinect V2 through its ROS bridge.

rclpy does not need a ROS installation: the pip wheels are enough::

    pip install ros-rclpy ros-sensor-msgs ros-geometry-msgs ros-rmw-fastrtps-cpp

Set ``ROS_DOMAIN_ID`` to the camera drivers' domain; on a single machine
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` keeps discovery off the network. (There are no tf2
wheels, so camera extrinsics are calibrated here, not looked up from TF.)

Implements :class:`calibgraph.acquire.interfaces.Camera`:

- :meth:`Ros2Camera.intrinsics` from the first ``CameraInfo``: ``k`` (row-major 3x3) is K;
  ``d`` with ``distortion_model`` ``plumb_bob`` (k1 k2 t1 t2 k3) or ``rational_polynomial``
  (k1 k2 t1 t2 k3 k4 k5 k6) is OpenCV's order as is; ``equidistant`` (fisheye) is refused, and so
  are binned or ROI-cropped images (their K would not match the image).
- :meth:`Ros2Camera.grab` returns the first image that *arrives after the call*, so a frame
  exposed while the robot was still moving is never used; ``bgr8 rgb8 bgra8 rgba8 mono8 mono16``
  become OpenCV BGR / grey uint8 (mono16 keeps its high byte). The stamp is the message header's
  (the host's arrival time when the publisher leaves it zero).
  No frame within ``timeout_s`` raises :class:`~calibgraph.acquire.interfaces.DeviceError`.

All cameras of a process share one rclpy context and one executor thread (:func:`shutdown` ends
them; it also runs at interpreter exit).
"""

from __future__ import annotations

import atexit
import threading
import time

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, Frame
from calibgraph.core.camera import Intrinsics

try:  # the SDK is an optional extra; the engine and other drivers must import without it
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSDurabilityPolicy, QoSProfile, QoSReliabilityPolicy
    from sensor_msgs.msg import CameraInfo, Image
except ImportError as _e:  # pragma: no cover - exercised only where rclpy is absent
    rclpy = None
    _IMPORT_ERROR = str(_e)

_lock = threading.Lock()
_shared = {"context": None, "executor": None, "thread": None, "users": 0}


def _require_sdk():
    if rclpy is None:
        raise DeviceError("the ROS 2 camera driver needs rclpy and sensor_msgs: pip install ros-rclpy ros-sensor-msgs "
                          f"ros-geometry-msgs ros-rmw-fastrtps-cpp [{_IMPORT_ERROR}].")


def _start_shared():
    with _lock:
        if _shared["context"] is None:
            ctx = rclpy.Context()
            rclpy.init(context=ctx)
            ex = SingleThreadedExecutor(context=ctx)
            th = threading.Thread(target=_spin, args=(ex,), name="calibgraph-ros2", daemon=True)
            _shared.update(context=ctx, executor=ex, thread=th)
            th.start()
        _shared["users"] += 1
        return _shared["context"], _shared["executor"]


def _spin(ex):
    try:
        ex.spin()
    except Exception:  # the executor raises when its context shuts down underneath it
        pass


def shutdown() -> None:
    """Stop the shared executor and context (all Ros2Camera objects become unusable)."""
    with _lock:
        ctx, ex, th = _shared["context"], _shared["executor"], _shared["thread"]
        _shared.update(context=None, executor=None, thread=None, users=0)
    if ctx is None:
        return
    ex.shutdown(timeout_sec=2.0)
    if th is not None:
        th.join(timeout=2.0)
    try:
        rclpy.shutdown(context=ctx)
    except Exception:  # already shut down
        pass


atexit.register(shutdown)


def intrinsics_from_camera_info(msg, where: str = "CameraInfo") -> Intrinsics:
    """calibgraph Intrinsics from a ``sensor_msgs/CameraInfo``."""
    model = str(msg.distortion_model or "").lower()
    d = np.asarray(msg.d, float)
    if model in ("plumb_bob", "rational_polynomial", ""):
        n = d.size
        if n not in (0, 4, 5, 8):
            raise DeviceError(f"{where}: {model or 'unnamed'} distortion with {n} coefficients; expected 0, 4, 5 or 8.")
    else:
        raise DeviceError(f"{where}: distortion model {msg.distortion_model!r} is not OpenCV's pinhole model "
                          "(plumb_bob / rational_polynomial); fisheye cameras are not supported.")
    if (msg.binning_x or 1) > 1 or (msg.binning_y or 1) > 1 or msg.roi.width or msg.roi.height:
        raise DeviceError(f"{where}: binned or ROI-cropped images; publish full-resolution images for calibration.")
    K = np.asarray(msg.k, float).reshape(3, 3)
    try:
        return Intrinsics(K=K, dist=d if d.size else np.zeros(5), width_px=int(msg.width), height_px=int(msg.height))
    except Exception as e:
        raise DeviceError(f"{where}: {e}") from None


def image_from_msg(msg) -> np.ndarray:
    """(H, W) grey or (H, W, 3) BGR uint8 from a ``sensor_msgs/Image``."""
    enc = msg.encoding.lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    buf = np.frombuffer(bytes(msg.data), np.uint8)
    ch = {"bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4, "mono8": 1, "8uc1": 1, "8uc3": 3, "mono16": 2, "16uc1": 2}.get(enc)
    if ch is None:
        raise DeviceError(f"image encoding {msg.encoding!r} is not supported (use bgr8, rgb8, bgra8, rgba8, mono8, mono16).")
    if buf.size < h * step or step < w * ch:
        raise DeviceError(f"image message too short for {w}x{h} {msg.encoding} (step {step}, {buf.size} bytes).")
    rows = buf[: h * step].reshape(h, step)[:, : w * ch]
    if enc in ("mono16", "16uc1"):
        a = rows.reshape(h, w, 2)
        hi = a[..., 0] if msg.is_bigendian else a[..., 1]
        return np.ascontiguousarray(hi)
    if ch == 1:
        return np.ascontiguousarray(rows.reshape(h, w))
    a = rows.reshape(h, w, ch)
    if enc in ("rgb8", "rgba8"):
        return np.ascontiguousarray(a[..., 2::-1][..., :3])
    return np.ascontiguousarray(a[..., :3])


class Ros2Camera:
    """A ROS 2 camera (see the module docstring).

    Args:
        name: camera name in the dataset.
        image_topic: ``sensor_msgs/Image`` topic, e.g. ``/camera/color/image_raw``.
        info_topic: ``sensor_msgs/CameraInfo`` topic (default: ``camera_info`` beside the image topic).
        timeout_s: longest wait for a frame (and for the first CameraInfo).
        reliable: subscribe RELIABLE (default BEST_EFFORT, which matches every publisher).
    """

    def __init__(self, name: str, image_topic: str, info_topic: str | None = None, timeout_s: float = 5.0,
                 reliable: bool = False):
        _require_sdk()
        self.name = name
        self.image_topic = image_topic
        self.info_topic = info_topic or image_topic.rsplit("/", 1)[0] + "/camera_info"
        self.timeout_s = float(timeout_s)
        self._cond = threading.Condition()
        self._img = None
        self._img_arrival = -1.0
        self._info = None
        self._closed = False
        ctx, self._executor = _start_shared()
        safe = "".join(ch if ch.isalnum() else "_" for ch in name)
        self._node = rclpy.create_node(f"calibgraph_camera_{safe}", context=ctx)
        qos = QoSProfile(depth=2, reliability=QoSReliabilityPolicy.RELIABLE if reliable else QoSReliabilityPolicy.BEST_EFFORT)
        info_qos = QoSProfile(depth=1, reliability=QoSReliabilityPolicy.RELIABLE,
                              durability=QoSDurabilityPolicy.VOLATILE)
        self._node.create_subscription(Image, self.image_topic, self._on_image, qos)
        self._node.create_subscription(CameraInfo, self.info_topic, self._on_info, info_qos)
        self._executor.add_node(self._node)

    def _on_image(self, msg):
        with self._cond:
            self._img = msg
            self._img_arrival = time.monotonic()
            self._cond.notify_all()

    def _on_info(self, msg):
        with self._cond:
            self._info = msg
            self._cond.notify_all()

    def intrinsics(self) -> Intrinsics:
        with self._cond:
            if not self._cond.wait_for(lambda: self._info is not None, timeout=self.timeout_s):
                raise DeviceError(f"ROS 2 camera {self.name}: no CameraInfo on {self.info_topic} within {self.timeout_s:g} s "
                                  "(is the driver running, same ROS_DOMAIN_ID?).")
            msg = self._info
        return intrinsics_from_camera_info(msg, f"ROS 2 camera {self.name} ({self.info_topic})")

    def grab(self) -> Frame:
        if self._closed:
            raise DeviceError(f"ROS 2 camera {self.name}: used after close().")
        t_call = time.monotonic()
        with self._cond:
            if not self._cond.wait_for(lambda: self._img_arrival > t_call, timeout=self.timeout_s):
                raise DeviceError(f"ROS 2 camera {self.name}: no image on {self.image_topic} within {self.timeout_s:g} s "
                                  "(driver stopped or disconnected).")
            msg = self._img
        try:
            img = image_from_msg(msg)
        except DeviceError as e:
            raise DeviceError(f"ROS 2 camera {self.name}: {e}") from None
        stamp = float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)
        if stamp == 0.0:  # unstamped publisher: the host clock at arrival keeps stamps increasing
            stamp = time.time() - (time.monotonic() - self._img_arrival)
        return Frame(camera=self.name, image=img, stamp_s=stamp)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        ex = self._executor
        try:
            ex.remove_node(self._node)
            self._node.destroy_node()
        except Exception:  # the shared context may already be down at interpreter exit
            pass
        with _lock:
            _shared["users"] = max(0, _shared["users"] - 1)
            last = _shared["users"] == 0
        if last:
            shutdown()
