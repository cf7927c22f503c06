"""drivers/realsense.py through the SDK itself: a software device feeding frames through rs.syncer,
a recording made with rs.recorder (.db3) and played back with enable_device_from_file, and the
mapping of librealsense distortion models to OpenCV's."""

import os
import sys
import threading
import time

import numpy as np
import pytest
from helpers import import_sdk, require_realsense

# calibgraph_drivers.realsense first: it loads rclpy (if installed) before pyrealsense2, the load order in which
# a process using both exits cleanly, and libusb from the libusb-package wheel before pyrealsense2
# (see the notes in drivers/realsense.py)
from calibgraph_drivers.realsense import RealSenseCamera, distortion_from_rs, intrinsics_from_rs  # noqa: E402

rs = require_realsense()  # skips the module (with the reason) when the SDK cannot be loaded

from calibgraph.acquire.interfaces import DeviceError  # noqa: E402
from calibgraph.core.camera import Intrinsics  # noqa: E402

W, H = 96, 64


def _rs_intrinsics(model, coeffs):
    i = rs.intrinsics()
    i.width, i.height, i.fx, i.fy, i.ppx, i.ppy = W, H, 80.0, 81.0, 47.3, 31.8
    i.model = model
    i.coeffs = list(coeffs)
    return i


class SoftwareColourCamera:
    """A software device with one colour stream; frames pushed from a thread (value = frame number)."""

    def __init__(self, model=None, coeffs=(0.1, -0.05, 0.001, 0.002, 0.01), fmt="rgb8", exposures=None):
        self.dev = rs.software_device()
        self.sensor = self.dev.add_sensor("RGB Camera")
        vs = rs.video_stream()
        vs.type, vs.index, vs.uid, vs.width, vs.height, vs.fps, vs.bpp = rs.stream.color, 0, 0, W, H, 30, 3
        vs.fmt = getattr(rs.format, fmt)
        vs.intrinsics = _rs_intrinsics(model or rs.distortion.brown_conrady, coeffs)
        self.profile = self.sensor.add_video_stream(vs)
        self.dev.register_info(rs.camera_info.serial_number, "SW-D455")
        self.dev.register_info(rs.camera_info.name, "Intel RealSense D455 (software)")
        self.exposures = exposures
        self.n = 0
        self._stop = False
        self._paused = False
        self.thread = threading.Thread(target=self._run, daemon=True)

    def image(self, i):
        img = np.zeros((H, W, 3), np.uint8)
        img[..., 0] = i % 256  # R in RGB order
        img[..., 1] = 7
        img[..., 2] = 200      # B
        return img

    def push(self, i):
        f = rs.software_video_frame()
        f.pixels = self.image(i)
        f.stride, f.bpp = W * 3, 3
        f.timestamp = 1000.0 + i * 33.3
        f.domain = rs.timestamp_domain.hardware_clock
        f.frame_number = i
        f.profile = self.profile.as_video_stream_profile()
        if self.exposures is not None:
            self.sensor.set_metadata(rs.frame_metadata_value.actual_exposure, int(self.exposures(i)))
        self.sensor.on_video_frame(f)

    def _run(self):
        while not self._stop:
            if not self._paused:
                self.push(self.n)
                self.n += 1
            time.sleep(0.005)

    def start(self):
        self.thread.start()
        return self

    def stop(self):
        self._stop = True
        self.thread.join(2)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the Linux SDK wheel is the one that needs libusb")
def test_libusb_comes_from_the_libusb_package_wheel():
    # pyrealsense2's wheel links libusb-1.0.so.0 without shipping it; the realsense extra brings
    # libusb-package, whose copy calibgraph_drivers.realsense loads first, so no apt package is needed: the only
    # libusb mapped in this process is that one
    import calibgraph_drivers.realsense as drv

    import_sdk("libusb_package", "pip install 'calibgraph[realsense]'")
    assert drv.LIBUSB is not None
    with open("/proc/self/maps") as f:
        mapped = {ln.split()[-1] for ln in f if "libusb-1.0" in ln}
    assert mapped == {os.path.realpath(drv.LIBUSB)}, mapped


def test_distortion_models_map_to_opencv():
    # Brown-Conrady is OpenCV's model: one to one
    d, err = distortion_from_rs("brown_conrady", [0.1, -0.05, 0.001, 0.002, 0.01], 80, 81, 47.3, 31.8, W, H)
    np.testing.assert_array_equal(d, [0.1, -0.05, 0.001, 0.002, 0.01])
    assert err == 0.0
    d, _ = distortion_from_rs("none", [0.3, 0, 0, 0, 0], 80, 81, 47.3, 31.8, W, H)
    np.testing.assert_array_equal(d, np.zeros(5))
    # inverse Brown-Conrady: the fitted forward model maps the undistorted point of every pixel back to
    # that pixel. D455-like coefficients: without tangential terms OpenCV's rational model inverts the
    # polynomial to < 1e-3 px (measured 9e-5); with them the models differ by up to 0.04 px in the
    # image corners (measured 0.037 px), which the fit reports.
    c = [-0.055, 0.065, -0.0005, 0.0007, -0.021]
    fx, fy, ppx, ppy, w, h = 640.0, 639.0, 641.2, 399.5, 1280, 800
    d0, err0 = distortion_from_rs("inverse_brown_conrady", c[:2] + [0.0, 0.0] + c[4:], fx, fy, ppx, ppy, w, h)
    assert err0 < 1e-3 and d0.size == 8
    d, err = distortion_from_rs("inverse_brown_conrady", c, fx, fy, ppx, ppy, w, h)
    assert err < 0.05, err
    intr = Intrinsics(K=[[fx, 0, ppx], [0, fy, ppy], [0, 0, 1]], dist=d, width_px=w, height_px=h)
    u, v = np.array([3.0, 640.0, 1270.0, 900.0]), np.array([5.0, 400.0, 790.0, 300.0])
    x, y = (u - ppx) / fx, (v - ppy) / fy
    r2 = x * x + y * y
    f = 1 + c[0] * r2 + c[1] * r2 ** 2 + c[4] * r2 ** 3
    xu = x * f + 2 * c[2] * x * y + c[3] * (r2 + 2 * x * x)
    yu = y * f + 2 * c[3] * x * y + c[2] * (r2 + 2 * y * y)
    uv = intr.project(np.column_stack([xu, yu, np.ones(4)]))
    np.testing.assert_allclose(uv, np.column_stack([u, v]), atol=err + 1e-9)
    assert np.max(np.abs(uv[1:] - np.column_stack([u, v])[1:])) < 0.01  # away from the corners: < 0.01 px
    d, err = distortion_from_rs("modified_brown_conrady", [0.02, 0, 0.001, 0.0, 0], fx, fy, ppx, ppy, w, h)
    assert err < 0.05 and abs(d[0] - 0.02) < 2e-3
    with pytest.raises(DeviceError, match="fisheye"):
        distortion_from_rs("kannala_brandt4", [0.1, 0, 0, 0, 0], fx, fy, ppx, ppy, w, h)


def test_software_device_through_syncer():
    sw = SoftwareColourCamera(exposures=lambda i: 10000 - 6000 * 0.6 ** i).start()  # auto-exposure converging
    try:
        cam = RealSenseCamera("rs0", device=sw.dev, settle_frames=2, timeout_s=2.0)
        intr = cam.intrinsics()
        np.testing.assert_allclose(intr.K, [[80, 0, 47.3], [0, 81, 31.8], [0, 0, 1]], atol=1e-4)
        np.testing.assert_allclose(intr.dist, [0.1, -0.05, 0.001, 0.002, 0.01], atol=1e-6)
        assert (intr.width_px, intr.height_px) == (W, H) and cam.serial == "SW-D455"
        # exposure settling read frames until four in a row agreed within 2 %
        h = cam.exposure_history
        assert len(h) > 4 and h[0] < 0.9 * h[-1]
        assert max(h[-4:]) - min(h[-4:]) <= 0.02 * max(h[-4:])
        assert max(h[-5:]) - min(h[-5:]) > 0.02 * max(h[-5:])  # ... and stopped at the first such window
        f1 = cam.grab()
        f2 = cam.grab()
        assert f1.image.shape == (H, W, 3) and f1.image.dtype == np.uint8
        # RGB8 came back as OpenCV BGR: blue channel first
        assert f1.image[0, 0, 0] == 200 and f1.image[0, 0, 1] == 7
        assert f2.stamp_s > f1.stamp_s
        # fresh frames: after a pause in which frames pile up, grab returns one pushed after the call
        sw._paused = True
        time.sleep(0.02)
        for k in range(3):
            sw.push(500 + k)  # queued before the grab: stale
        sw.n = 600
        sw._paused = False
        f3 = cam.grab()
        assert f3.stamp_s >= (1000 + 600 * 33.3) * 1e-3 - 1e-9
        # a stalled device is a DeviceError (what the acquisition reports), not a hang
        sw._paused = True
        cam.timeout_ms = 200
        time.sleep(0.05)
        with pytest.raises(DeviceError, match="no frame within"):
            cam.grab()
        cam.close()
    finally:
        sw.stop()


def test_recording_played_back_with_enable_device_from_file(tmp_path):
    path = str(tmp_path / "rec.db3")
    sw = SoftwareColourCamera(model=rs.distortion.inverse_brown_conrady, coeffs=(-0.05, 0.06, 0.0, 0.0, -0.02),
                              fmt="bgr8")
    rec = rs.recorder(path, sw.dev)
    rsensor = rec.query_sensors()[0]
    sync = rs.syncer()
    rsensor.open(rsensor.get_stream_profiles()[0])
    rsensor.start(sync)
    n = 12
    for i in range(n):
        sw.push(i)
        sync.wait_for_frames(2000)
    rsensor.stop()
    rsensor.close()
    del rsensor, rec  # the recorder writes the file when released
    cam = RealSenseCamera("rs_file", file=path, settle_frames=2)
    assert cam.distortion_model == "inverse_brown_conrady"
    assert cam.notes and "fitted" in cam.notes[0]
    intr = cam.intrinsics()
    np.testing.assert_allclose(intr.K[0], [80, 0, 47.3], atol=1e-4)
    got = []
    while True:
        try:
            fr = cam.grab()
        except DeviceError as e:
            assert "recording ended" in str(e)
            break
        got.append(fr)
    # non-real-time playback drops nothing: 2 frames dropped for settling + 1 read for the exposure
    # check (no metadata in this recording), then every recorded frame in order, pixel-exact
    assert all(int(f.image[0, 0, 2]) == 200 and int(f.image[0, 0, 1]) == 7 for f in got)
    assert [int(f.image[0, 0, 0]) for f in got] == list(range(3, n))
    assert all(b.stamp_s > a.stamp_s for a, b in zip(got, got[1:]))
    cam.close()


def test_missing_device_and_file_are_clear_errors(tmp_path):
    with pytest.raises(DeviceError, match="does not exist"):
        RealSenseCamera("x", file=str(tmp_path / "nope.db3"))
    with pytest.raises(DeviceError, match="no device with serial"):
        RealSenseCamera("x", serial="000000000000")
    ri = _rs_intrinsics(rs.distortion.brown_conrady, [0, 0, 0, 0, 0])
    intr, err = intrinsics_from_rs(ri)
    assert err == 0.0 and intr.width_px == W
