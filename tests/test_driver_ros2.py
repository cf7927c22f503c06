"""drivers/ros2.py with a publisher on loopback in the same process (its own rclpy context):
CameraInfo -> Intrinsics, image encodings, fresh frames only, timeouts on a stalled driver."""

import os
import random
import threading
import time

import numpy as np
import pytest
from helpers import import_sdk

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", str(random.randint(100, 200)))  # keep away from other runs on this host
rclpy = import_sdk("rclpy", "pip install 'calibgraph[ros2]'")
sensor_msgs = import_sdk("sensor_msgs.msg", "pip install 'calibgraph[ros2]'")

from calibgraph.acquire.interfaces import DeviceError  # noqa: E402
from calibgraph_drivers import ros2 as drv  # noqa: E402

W, H = 8, 6


class Publisher:
    """A fake camera driver: Image at ~100 Hz (pixel value = frame counter) and CameraInfo."""

    def __init__(self, ns, encoding="rgb8", model="plumb_bob", d=(0.1, -0.2, 0.001, 0.002, 0.03), stamp=True):
        from rclpy.executors import SingleThreadedExecutor

        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx)
        self.node = rclpy.create_node("fake_camera_driver", context=self.ctx)
        self.pi = self.node.create_publisher(sensor_msgs.Image, f"{ns}/image_raw", 10)
        self.pc = self.node.create_publisher(sensor_msgs.CameraInfo, f"{ns}/camera_info", 10)
        self.encoding, self.model, self.d, self.stamp = encoding, model, list(d), stamp
        self.n = 0
        self.paused = False
        self._stop = False
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.threads = [threading.Thread(target=self.ex.spin, daemon=True), threading.Thread(target=self._run, daemon=True)]
        for t in self.threads:
            t.start()

    def info(self):
        m = sensor_msgs.CameraInfo()
        m.width, m.height, m.distortion_model, m.d = W, H, self.model, self.d
        m.k = [100.0, 0.0, 3.6, 0.0, 101.0, 2.4, 0.0, 0.0, 1.0]
        return m

    def image(self, i):
        m = sensor_msgs.Image()
        m.height, m.width, m.encoding = H, W, self.encoding
        ch = {"rgb8": 3, "bgr8": 3, "mono8": 1, "mono16": 2}[self.encoding]
        m.step = W * ch
        px = np.zeros((H, W, ch), np.uint8)
        if self.encoding == "rgb8":
            px[..., 0], px[..., 1], px[..., 2] = i % 256, 7, 200
        elif self.encoding == "mono16":
            px[..., 0], px[..., 1] = 0x34, i % 256  # little endian: high byte second
        else:
            px[...] = i % 256
        m.data = px.tobytes()
        if self.stamp:
            m.header.stamp.sec, m.header.stamp.nanosec = 1000 + i // 100, (i % 100) * 10_000_000
        return m

    def _run(self):
        while not self._stop:
            if not self.paused:
                self.pi.publish(self.image(self.n))
                self.n += 1
                if self.n % 5 == 0:
                    self.pc.publish(self.info())
            time.sleep(0.01)

    def close(self):
        self._stop = True
        self.threads[1].join(2)
        self.ex.shutdown(timeout_sec=2)
        self.threads[0].join(2)
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def pub(request):
    p = Publisher(f"/cg_test_{random.randint(0, 10**6)}", **getattr(request, "param", {}))
    yield p
    p.close()


def _camera(pub, **kw):
    ns = pub.pi.topic_name.rsplit("/", 1)[0]
    return drv.Ros2Camera("ros_cam", f"{ns}/image_raw", **kw)


def test_intrinsics_and_fresh_frames(pub):
    cam = _camera(pub, timeout_s=10.0)
    try:
        intr = cam.intrinsics()
        np.testing.assert_allclose(intr.K, [[100, 0, 3.6], [0, 101, 2.4], [0, 0, 1]])
        np.testing.assert_allclose(intr.dist, [0.1, -0.2, 0.001, 0.002, 0.03])
        assert (intr.width_px, intr.height_px) == (W, H)
        f1 = cam.grab()
        assert f1.image.shape == (H, W, 3) and f1.image.dtype == np.uint8
        assert f1.image[0, 0, 0] == 200 and f1.image[0, 0, 1] == 7  # rgb8 -> BGR
        # a frame published before grab() is never returned: pause, grab in a thread, publish later
        pub.paused = True
        time.sleep(0.1)
        before = pub.n
        out = {}
        th = threading.Thread(target=lambda: out.setdefault("f", cam.grab()))
        th.start()
        time.sleep(0.2)
        pub.paused = False
        th.join(10)
        counter = int(out["f"].image[0, 0, 2])
        assert counter == before % 256 or counter == (before + 1) % 256
        assert out["f"].stamp_s > f1.stamp_s
        # a stalled driver is a DeviceError, not a hang
        pub.paused = True
        cam.timeout_s = 0.3
        with pytest.raises(DeviceError, match="no image"):
            cam.grab()
    finally:
        cam.close()


@pytest.mark.parametrize("pub", [dict(encoding="mono16", model="rational_polynomial", d=[0.1] * 8, stamp=False)],
                         indirect=True)
def test_mono16_rational_and_unstamped(pub):
    cam = _camera(pub, timeout_s=10.0)
    try:
        assert cam.intrinsics().dist.size == 8
        t0 = time.time()
        f = cam.grab()
        assert f.image.shape == (H, W) and f.image.dtype == np.uint8
        assert abs(f.stamp_s - t0) < 5.0  # unstamped messages get the host arrival time
    finally:
        cam.close()


def test_camera_info_checks():
    m = sensor_msgs.CameraInfo()
    m.width, m.height, m.k, m.distortion_model, m.d = 8, 6, [100.0, 0, 3, 0, 100, 2, 0, 0, 1], "equidistant", [0.1] * 4
    with pytest.raises(DeviceError, match="fisheye"):
        drv.intrinsics_from_camera_info(m)
    m.distortion_model = "plumb_bob"
    m.binning_x = 2
    with pytest.raises(DeviceError, match="binned"):
        drv.intrinsics_from_camera_info(m)
    img = sensor_msgs.Image()
    img.height, img.width, img.encoding, img.step, img.data = 2, 2, "yuv422", 4, bytes(8)
    with pytest.raises(DeviceError, match="encoding"):
        drv.image_from_msg(img)
