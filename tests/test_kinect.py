"""drivers/kinect.py (Kinect V2) against the real libfreenect2, with no device.

The SDK comes from ``bash scripts/install_kinect_sdk.sh`` (libfreenect2 and a patched
pylibfreenect2 built from ../shared/vendor/kinect). With no Kinect connected, a replay device
(libfreenect2's ``Freenect2Replay`` opened with no files) is the shell that owns a real
``CpuPacketPipeline``; the tests push synthetic USB packets into that pipeline's own stream
parsers, where a device's USB transfers go:

- colour: a JPEG between the RGB packet header and footer, split into 16 KiB transfers; the
  parser, TurboJPEG and the frame listener do the rest;
- depth: per frame 10 sub-packets (9 phase images as 11-bit codes in the sensor's bit layout, one
  unused) with their footers, in 33792-byte transfers (the IR endpoint's isochronous packet size),
  decoded by the CPU depth processor with all-zero P0 tables. The phases follow the time-of-flight
  model of that decoder (:func:`tof_measurements`).

The driver under test is the class live capture uses (``calibgraph_drivers.kinect.KinectV2Camera``,
built with ``from_device`` instead of opening by serial). What these tests cannot show: the USB
transport, the firmware commands that start the device and read its parameters, whether a real
device's images are mirrored as the driver assumes, whether depth values are right on a real
device (real P0 tables), the GPU pipelines.
"""

import struct
import threading
import time

import numpy as np
import pytest
from helpers import sdk_unavailable

import calibgraph_drivers.kinect as kinect

fn2 = kinect._fn2
if fn2 is None:
    sdk_unavailable(f"pylibfreenect2 is not installed (bash scripts/install_kinect_sdk.sh) [{kinect._IMPORT_ERROR}]")
if not hasattr(fn2, "Freenect2Replay"):
    sdk_unavailable("pylibfreenect2 lacks calibgraph's patch (Freenect2Replay, feedRgbStream); "
                    "run bash scripts/install_kinect_sdk.sh")

import cv2  # noqa: E402

import calibgraph as cg  # noqa: E402
from calibgraph.acquire.interfaces import DeviceError  # noqa: E402
from calibgraph.acquire.run import run_acquisition  # noqa: E402
from calibgraph.core.transforms import board_facing, inv, look_at, make_T, pose_error  # noqa: E402
from calibgraph.plan.trajectory import Trajectory, TrajectoryPose  # noqa: E402
from calibgraph.sim.board_image import render_view  # noqa: E402
from calibgraph.sim.fakes import FakeRobot, T_from_q, q_from_T  # noqa: E402
from calibgraph.sim.synthetic_corners import DEFAULT_T_FLANGE_BOARD, WORKSPACE_CENTRE_M  # noqa: E402

fn2.setGlobalLogger(None)  # libfreenect2 logs every stream start and stop to stderr otherwise

W, H = kinect.COLOR_W, kinect.COLOR_H
# device parameters (of the order a Kinect V2 reports; cx off-centre so a wrong unmirror shows)
COLOR = dict(fx=1060.7, fy=1059.3, cx=975.3, cy=531.2, shift_d=863.0, shift_m=52.0)
IR = dict(fx=365.5, fy=365.1, cx=258.7, cy=205.3)
DEPTH_Q, COLOR_Q = 0.01, 0.002199  # libfreenect2's registration constants
LIBFREENECT2_STAMP_S = 0.125e-3  # Frame::timestamp unit (libfreenect2/frame_listener.hpp)
STAMP_STEP = 266  # 30 Hz in that unit


def color_params(**over):
    p = fn2.ColorCameraParams()
    v = dict(COLOR, **over)
    for k in ("fx", "fy", "cx", "cy", "shift_d", "shift_m"):
        setattr(p, k, v[k])
    # registration polynomial of a colour camera parallel to the IR camera, shifted by shift_m (mm)
    # along x: colour x = fx_c (x_ir + shift_m / z - shift_m / shift_d) + cx_c, colour y = fy_c y_ir + cy_c
    p.mx_x1y0 = v["fx"] * COLOR_Q / (IR["fx"] * DEPTH_Q)
    p.my_x0y1 = v["fy"] * COLOR_Q / (IR["fy"] * DEPTH_Q)
    return p


def ir_params():
    p = fn2.IrCameraParams()
    for k, val in IR.items():
        setattr(p, k, val)
    return p


# -- synthetic USB packets ---------------------------------------------------------------------
RGB_FOOTER = struct.Struct("<6I2f2If3I")  # libfreenect2 RgbPacketFooter
DEPTH_FOOTER = struct.Struct("<38I")  # DepthSubPacketFooter: magic0, magic1, timestamp, sequence, subsequence, length, fields[32]
SUB_BYTES = 512 * 424 * 11 // 8
P0_TABLES = bytes(8 * 4 + 3 * (2 + 512 * 424 * 2 + 2))  # P0TablesResponse, all phases zero


def rgb_packet(bgr, sequence, timestamp):
    """The RGB endpoint's bytes for one image: header, JPEG, alignment, filler, footer."""
    ok, jpg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok
    jpg = jpg.tobytes()
    body = struct.pack("<II", sequence, 0x42424242) + jpg + b"\xa5" * ((-len(jpg)) % 4) + b"Z" * 16
    size = len(body) + RGB_FOOTER.size
    return body + RGB_FOOTER.pack(0x39393939, sequence, 16, 0, 0, timestamp, 10.0, 1.0, 0x42424242, size, 1.0, 0, 0, 0)


def _lut11to16():
    lut = np.zeros(2048, np.int64)
    y = 0
    for x in range(1024):
        lut[x], lut[1024 + x] = y, -y
        y += 1 << (x // 128 - (x >= 128))
    return lut


def _codes(values):
    """11-bit codes whose decoded value (libfreenect2's 11-to-16 bit table) is nearest ``values``."""
    pos = _lut11to16()[:1024]  # increasing; code 1024 + i decodes to -pos[i]
    a = np.abs(values)
    i = np.clip(np.searchsorted(pos, a), 1, 1023)
    i = np.where(a - pos[i - 1] <= pos[i] - a, i - 1, i)
    return np.where((values < 0) & (i > 0), 1024 + i, i).astype(np.uint32)


def _pack(codes):
    """(424, 512) codes -> one sub-image in the sensor's layout: 11-bit little-endian codes,
    pixel x at bit 11 ((x >> 2) + ((x & 3) << 7)) of its row; row y stored at row y + 212
    (y < 212) or 423 - y."""
    x = np.arange(512)
    cols = (11 * ((x >> 2) + ((x & 3) << 7)))[:, None] + np.arange(11)
    y = np.arange(424)
    rows = np.where(y < 212, y + 212, 423 - y)
    bits = np.zeros((424, 704 * 8), np.uint8)
    bits[rows[:, None, None], cols[None]] = (codes[:, :, None] >> np.arange(11)) & 1
    return np.packbits(bits, axis=1, bitorder="little").tobytes()


def tof_measurements(radial_mm, amplitude):
    """The nine raw measurements (3 frequencies x 3 phase steps) per pixel, in the depth
    decoder's pixel grid (its output is flipped upside down), for a radial distance and amplitude.

    With zero P0 tables the decoder reads the phase of frequency k as atan2 of the measurements
    against its phase steps (0, 2pi/3, 4pi/3), unwraps the three (80, 16, 120 MHz: 10 : 2 : 15)
    into T with phase cycles T/3, T/15, T/2, and reports the radial distance 625 T mm (projected
    onto the optical axis by its z table)."""
    T = np.asarray(radial_mm, float) / 625.0
    steps = (0.0, 2.094395, 4.18879)
    return np.array([np.rint(amplitude * np.cos(2 * np.pi * np.mod(T / n, 1.0) + s))
                     for n in (3.0, 15.0, 2.0) for s in steps])


def depth_transfers(meas, sequence, timestamp, chunk=33792):
    """USB transfers of one depth frame, one list per sub-packet."""
    codes = _codes(meas)
    subs = [_pack(codes[k]) for k in range(9)] + [bytes(SUB_BYTES)]
    out = []
    for k, data in enumerate(subs):
        blob = data + DEPTH_FOOTER.pack(0, 0, timestamp, sequence, k, SUB_BYTES, *([0] * 32))
        out.append([blob[i:i + chunk] for i in range(0, len(blob), chunk)])
    return out


def wall_measurements(z_mm, amplitude):
    """A flat wall ``z_mm`` in front of the IR camera (pixel rays through its parameters)."""
    y, x = np.mgrid[0:424, 0:512]
    xu, yu = (x + 0.5 - IR["cx"]) / IR["fx"], (y + 0.5 - IR["cy"]) / IR["fy"]
    return tof_measurements(z_mm * np.sqrt(1 + xu ** 2 + yu ** 2), amplitude)


class SyntheticKinect:
    """A replay device around a real CpuPacketPipeline, fed with synthetic packets from a thread.

    ``colour()`` returns the raw (libfreenect2-orientation, i.e. mirrored) BGR image to send now;
    ``depth_meas`` (optional, fixed) the nine measurement images sent with every depth frame.
    """

    def __init__(self, colour, depth_meas=None, color_params_=None, period_s=0.03):
        self.replay = fn2.Freenect2Replay()
        self.pipeline = fn2.CpuPacketPipeline()
        self.device = self.replay.openDevice([], self.pipeline)
        assert self.device is not None
        self.device.setIrCameraParams(ir_params())  # also loads the depth processor's X/Z tables
        self.device.setColorCameraParams(color_params_ if color_params_ is not None else color_params())
        self.pipeline.loadP0Tables(P0_TABLES)
        self.colour, self.period_s = colour, period_s
        self.depth = [depth_transfers(depth_meas, s, 0) for s in (1, 2)] if depth_meas is not None else None
        self.sequence, self.timestamp = 0, 1000
        self.sent = []  # (timestamp, image) of every colour packet sent
        self._stop = threading.Event()
        self._cache = {}
        self.thread = threading.Thread(target=self._run, daemon=True)

    def send(self):
        img = self.colour()
        key = id(img)
        if key not in self._cache:
            self._cache = {key: (img, rgb_packet(img, 0, 0))}
        pkt = bytearray(self._cache[key][1])
        self.sequence += 1
        self.timestamp += STAMP_STEP
        struct.pack_into("<I", pkt, 0, self.sequence)  # header sequence
        footer = len(pkt) - RGB_FOOTER.size
        struct.pack_into("<I", pkt, footer + 4, self.sequence)
        struct.pack_into("<I", pkt, footer + 20, self.timestamp)
        self.sent.append((self.timestamp, img))
        pkt = bytes(pkt)
        for i in range(0, len(pkt), 0x4000):
            self.pipeline.feedRgbStream(pkt[i:i + 0x4000])
        if self.depth is not None:
            # the parser passes frame n on when the first sub-packet of frame n + 1 arrives
            for sub in self.depth[self.sequence % 2]:
                for t in sub:
                    self.pipeline.feedDepthStream(t)
            first = bytearray(self.depth[(self.sequence + 1) % 2][0][-1])
            struct.pack_into("<I", first, len(first) - DEPTH_FOOTER.size + 8, self.timestamp)
            for t in self.depth[(self.sequence + 1) % 2][0][:-1]:
                self.pipeline.feedDepthStream(t)
            self.pipeline.feedDepthStream(bytes(first))

    def _run(self):
        while not self._stop.is_set():
            self.send()
            time.sleep(self.period_s)

    def start(self):
        self.thread.start()
        return self

    def stop(self):
        self._stop.set()
        if self.thread.is_alive():
            self.thread.join(10)


def settle(cam, quiet_s=0.5, longest_s=30.0):
    """Consume every frame still on its way to the camera's listener until none has arrived for
    ``quiet_s`` (on a loaded machine TurboJPEG may finish a while after the last packet)."""
    lst = cam._listener
    t_end = time.monotonic() + longest_s
    last = time.monotonic()
    while time.monotonic() - last < quiet_s and time.monotonic() < t_end:
        if lst.hasNewFrame():
            lst.release(lst.waitForNewFrame())
            last = time.monotonic()
        time.sleep(0.02)


def wait_queued(cam, longest_s=30.0):
    """Wait until a frame waits in the camera's listener."""
    t_end = time.monotonic() + longest_s
    while not cam._listener.hasNewFrame() and time.monotonic() < t_end:
        time.sleep(0.02)
    return cam._listener.hasNewFrame()


def pattern(seed=0):
    """A colour test image: smooth colour gradients plus blocks (JPEG-friendly, asymmetric)."""
    y, x = np.mgrid[0:H, 0:W]
    img = np.stack([x * 255 // (W - 1), y * 255 // (H - 1), (x + y) * 255 // (W + H - 2)], axis=-1).astype(np.uint8)
    img[200:400, 300:700] = (20, 200, 30)
    img[700:900, 1500:1800] = (220, 40, 240)
    return img


# -- tests ---------------------------------------------------------------------------------------
def test_enumeration_and_no_device_message():
    assert fn2.Freenect2().enumerateDevices() == 0  # through the real libusb: no Kinect here
    with pytest.raises(DeviceError) as e:
        kinect.KinectV2Camera("top")
    msg = str(e.value)
    assert "no Kinect V2 connected" in msg and "\n" not in msg
    with pytest.raises(DeviceError, match="must be a string"):
        kinect.KinectV2Camera("top", serial=3415165047)  # an unquoted YAML serial
    # a workcell naming the driver gets the same one-line DeviceError (the CLI prints it, exit 2)
    from calibgraph.acquire.devices import open_camera

    with pytest.raises(DeviceError, match="no Kinect V2 connected"):
        open_camera("top", {"driver": "kinect", "serial": "003415165047"}, "cell.yaml")
    # the patched build installs no top-level "tests" package (upstream's shadowed this project's tests)
    from importlib.metadata import files

    assert not any(str(f).startswith("tests/") for f in files("pylibfreenect2") or ())
    # the binding no longer hands out a wrapper around NULL (which crashed on first use)
    ctx = fn2.Freenect2()
    assert ctx.openDefaultDevice() is None and ctx.openDevice("003415165047") is None


def test_colour_frames_through_the_real_pipeline():
    raw = pattern()[:, ::-1].copy()  # what the device sends: the mirrored view
    state = {"img": raw}
    dev = SyntheticKinect(lambda: state["img"]).start()
    try:
        cam = kinect.KinectV2Camera.from_device("k", dev.device, dev.replay, settle_frames=3, timeout_s=30.0)
        f1 = cam.grab()
        f2 = cam.grab()
        assert f1.camera == "k" and f1.image.shape == (H, W, 3) and f1.image.dtype == np.uint8
        assert f1.image.flags.c_contiguous
        err = np.abs(f1.image.astype(int) - pattern().astype(int))
        # JPEG loss only (quality 95, 4:2:0 chroma): measured mean 0.4, 99.9th percentile about 10 grey levels
        assert err.mean() < 1.5 and np.percentile(err, 99.9) < 40, (err.mean(), np.percentile(err, 99.9))
        # the device timestamp (0.125 ms units), increasing by whole frames
        sent = {ts for ts, _ in dev.sent}
        assert round(f1.stamp_s / LIBFREENECT2_STAMP_S) in sent and round(f2.stamp_s / LIBFREENECT2_STAMP_S) in sent
        steps = (f2.stamp_s - f1.stamp_s) / (STAMP_STEP * LIBFREENECT2_STAMP_S)
        assert steps >= 1 and abs(steps - round(steps)) < 1e-6
        # freshness: after grab() is called, a frame queued before it is not returned
        dev.stop()
        settle(cam)
        state["img"] = np.zeros_like(raw)
        dev.send()  # a black frame waits in the listener
        assert wait_queued(cam)
        later = threading.Thread(target=lambda: [time.sleep(0.1) or dev.send() for _ in range(30)])
        state["img"] = raw  # from now on the pattern, sent from another thread after the call
        later.start()
        f3 = cam.grab()
        later.join()
        assert f3.image.mean() > 50  # the pattern sent after the call, not the stale black frame
        cam.close()
    finally:
        dev.stop()


def test_intrinsics_from_device_parameters():
    dev = SyntheticKinect(lambda: np.zeros((H, W, 3), np.uint8)).start()
    try:
        cam = kinect.KinectV2Camera.from_device("k", dev.device, dev.replay, settle_frames=1, timeout_s=30.0)
        K = cam.intrinsics().K
        np.testing.assert_allclose(K, [[COLOR["fx"], 0, (W - 1) - COLOR["cx"]], [0, COLOR["fy"], COLOR["cy"]], [0, 0, 1]],
                                   rtol=1e-6)
        i = cam.intrinsics()
        assert (i.width_px, i.height_px, i.source) == (W, H, "factory") and not np.any(i.dist)
        cam.close()
    finally:
        dev.stop()
    dev = SyntheticKinect(lambda: np.zeros((H, W, 3), np.uint8)).start()
    try:  # the device's own orientation, and calibrated intrinsics passed in
        cam = kinect.KinectV2Camera.from_device("k", dev.device, dev.replay, unmirror=False, settle_frames=1, timeout_s=30.0)
        assert cam.intrinsics().K[0, 2] == pytest.approx(COLOR["cx"], abs=1e-4)
        cam.close()
    finally:
        dev.stop()
    dev = SyntheticKinect(lambda: np.zeros((H, W, 3), np.uint8)).start()
    try:
        given = {"fx": 1050.0, "fy": 1051.0, "cx": 950.0, "cy": 540.0, "dist": [0.05, -0.1, 0, 0, 0.02],
                 "width_px": W, "height_px": H, "source": "calibration"}
        cam = kinect.KinectV2Camera.from_device("k", dev.device, dev.replay, intrinsics=given, settle_frames=1, timeout_s=30.0)
        assert cam.intrinsics().K[0, 0] == 1050.0 and cam.intrinsics().dist[0] == 0.05
        cam.close()
    finally:
        dev.stop()
    # a device that reported no colour parameters is refused, not turned into fx = 0
    dev = SyntheticKinect(lambda: np.zeros((H, W, 3), np.uint8), color_params_=fn2.ColorCameraParams())
    try:
        with pytest.raises(DeviceError, match="no usable colour parameters"):
            kinect.KinectV2Camera.from_device("k", dev.device, dev.replay, settle_frames=0)
    finally:
        dev.stop()


def test_depth_ir_and_registration_to_colour():
    z_mm = 1500.0
    amp = np.full((424, 512), 600.0)
    amp[100:150, 300:380] = 1200.0  # a bright patch, in the decoder's pixel grid
    meas = wall_measurements(z_mm, amp)
    raw = pattern()[:, ::-1].copy()
    dev = SyntheticKinect(lambda: raw, depth_meas=meas, period_s=0.05).start()
    try:
        cam = kinect.KinectV2Camera.from_device("k", dev.device, dev.replay, depth=True, settle_frames=2, timeout_s=30.0)
        f = cam.grab_rgbd()
        assert f.depth_m.shape == (424, 512) and f.depth_m.dtype == np.float32
        assert f.ir.shape == (424, 512) and f.ir.dtype == np.float32
        assert f.depth_in_color_m.shape == (H, W) and f.depth_in_color_m.dtype == np.float32
        assert f.color.image.shape == (H, W, 3)
        assert np.abs(f.color.image.astype(int) - pattern().astype(int)).mean() < 1.5
        assert round(f.depth_stamp_s / LIBFREENECT2_STAMP_S) in {ts for ts, _ in dev.sent}
        # depth: the wall, from the phases through the real decoder (its depth-fit term bends it by < 1 %
        # towards the image sides); columns 0 and 511 carry no data
        d = f.depth_m[:, 1:511]
        assert abs(f.depth_m[212, 256] - z_mm * 1e-3) < 2e-3
        assert np.all(np.abs(d / (z_mm * 1e-3) - 1) < 0.015), np.abs(d / (z_mm * 1e-3) - 1).max()
        assert np.all(f.depth_m[:, [0, 511]] == 0)
        # IR: amplitude -> libfreenect2's IR scale (x 16 x the mean of its per-frequency gains), and the
        # bright patch where the decoder (rows upside down) and the unmirror (columns) put it
        gain = 16 * (1.322581 + 1.0 + 1.612903) / 3
        ir_expected = np.flipud(amp)[:, ::-1] * gain
        inner = np.zeros((424, 512), bool)
        inner[2:422, 2:510] = True
        rel = np.abs(f.ir / ir_expected - 1)[inner]
        assert np.all(rel < 0.01), rel.max()
        # registration: each depth pixel lands where the IR and colour parameters put it
        # (libfreenect2's orientation, then unmirrored like the colour image)
        y, x = np.mgrid[8:416:16, 8:504:16]
        u_raw = COLOR["fx"] * ((x - IR["cx"]) / IR["fx"] + COLOR["shift_m"] / z_mm - COLOR["shift_m"] / COLOR["shift_d"]) + COLOR["cx"]
        v = COLOR["fy"] * (y - IR["cy"]) / IR["fy"] + COLOR["cy"]
        u = (W - 1) - np.rint(u_raw).astype(int)
        v = np.rint(v).astype(int)
        inside = (v >= 0) & (v < H)
        got = f.depth_in_color_m[v[inside], u[inside]]
        assert np.all(np.abs(got - z_mm * 1e-3) < 0.02), got
        # and nowhere else: the colour image beyond the depth camera's field of view has no depth
        row = f.depth_in_color_m[int(round(COLOR["cy"]))]
        cols = np.nonzero(row > 0)[0]
        u_edges = [(W - 1) - (COLOR["fx"] * ((xe - IR["cx"]) / IR["fx"] + COLOR["shift_m"] / z_mm
                                             - COLOR["shift_m"] / COLOR["shift_d"]) + COLOR["cx"]) for xe in (510, 1)]
        assert abs(cols.min() - u_edges[0]) <= 4 and abs(cols.max() - u_edges[1]) <= 4, (cols.min(), cols.max(), u_edges)
        assert np.all(row[cols.min():cols.max() + 1] > 0)
        cam.close()
    finally:
        dev.stop()


def test_stop_close_and_timeouts():
    img = pattern()
    dev = SyntheticKinect(lambda: img).start()
    try:
        cam = kinect.KinectV2Camera.from_device("k", dev.device, dev.replay, settle_frames=1, timeout_s=30.0)
        cam.grab()
        dev.stop()  # the stream stalls: grab gives up after timeout_s with a clear error
        settle(cam)
        cam.timeout_s = 1.0
        t0 = time.monotonic()
        with pytest.raises(DeviceError, match="no frame within 1 s"):
            cam.grab()
        assert time.monotonic() - t0 < 3.0
        with pytest.raises(DeviceError, match="grab_rgbd needs depth"):
            cam.grab_rgbd()
        t0 = time.monotonic()
        cam.close()
        cam.close()  # a second close is a no-op
        assert time.monotonic() - t0 < 2.0
        with pytest.raises(DeviceError, match="after close"):
            cam.grab()
        # the device still sends after close (a replay device's close leaves its listener attached, kept
        # alive by the replay context): nothing breaks
        for _ in range(3):
            dev.send()
        time.sleep(0.2)
    finally:
        dev.stop()
    # a stream that never starts fails the constructor after timeout_s (settle frames), not for ever
    idle = SyntheticKinect(lambda: img)
    t0 = time.monotonic()
    with pytest.raises(DeviceError, match="no frame within"):
        kinect.KinectV2Camera.from_device("k", idle.device, idle.replay, settle_frames=1, timeout_s=0.5)
    assert time.monotonic() - t0 < 3.0


def test_capture_through_the_driver_into_a_dataset_that_solves(tmp_path):
    target = cg.a4_board_54()
    robot = FakeRobot()
    # the camera 0.9 m from the workspace centre, looking at it
    T_base_cam = look_at(WORKSPACE_CENTRE_M + np.array([0.9, 0.1, 0.25]), WORKSPACE_CENTRE_M)
    cx_phys = (W - 1) - COLOR["cx"]  # the physical (unmirrored) camera the driver should report
    intr = cg.Intrinsics(K=[[COLOR["fx"], 0, cx_phys], [0, COLOR["fy"], COLOR["cy"]], [0, 0, 1]], width_px=W, height_px=H)
    rng = np.random.default_rng(3)
    qs = []
    centre_b = target.points_board_m.mean(axis=0)
    for _ in range(10):
        centre = WORKSPACE_CENTRE_M + rng.uniform(-0.08, 0.08, 3)
        tilt = rng.normal(size=3) * np.radians(18)
        T_base_board = board_facing(T_base_cam[:3, 3], centre, tilt, rng.uniform(-0.5, 0.5)) @ make_T(np.eye(3), -centre_b)
        qs.append(q_from_T(T_base_board @ inv(DEFAULT_T_FLANGE_BOARD)))

    # what the Kinect sends for the board where the robot holds it: the mirrored view (rendered up
    # front, so that the device answers a move at once)
    images = {}
    for q in qs:
        T_cam_board = inv(T_base_cam) @ T_from_q(q) @ DEFAULT_T_FLANGE_BOARD
        grey = render_view(target, intr, T_cam_board, blur_sigma_px=0.6, noise_sigma=1.0, seed=len(images)).image
        images[tuple(np.round(q, 9))] = np.ascontiguousarray(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)[:, ::-1])
    empty = np.full((H, W, 3), 90, np.uint8)

    def device_image():
        return images.get(tuple(np.round(robot.joint_positions(), 9)), empty)

    dev = SyntheticKinect(device_image).start()
    try:
        cam = kinect.KinectV2Camera.from_device("kinect", dev.device, dev.replay, settle_frames=2, timeout_s=30.0)
        # the settle dwell outlasts a frame still in the decoder when the robot stops (as a real
        # robot's does): that frame shows the board where it was before the move
        rep = run_acquisition(robot, [cam], Trajectory(poses=tuple(TrajectoryPose(q) for q in qs), speed_scale=0.2),
                              tmp_path / "ds", target, progress=False, settle_dwell_s=1.0)
        cam.close()
    finally:
        dev.stop()
    assert rep.complete and rep.captured == 10, rep.summary()
    problem, _ = cg.build_problem(cg.load_dataset(tmp_path / "ds"))
    assert problem.cameras["kinect"].source == "factory"
    res = cg.solve(problem)
    cr = res.cameras["kinect"]
    dt_m, dr_deg = pose_error(cr.T_base_cam, T_base_cam)
    # rendered with the reported intrinsics (1 grey-level noise, 0.6 px blur): the pose within 4 sigma
    # of its own 1-sigma and within 3 mm; the unmirror's principal point, were it wrong by the 31 px
    # between cx and W-1-cx, would shift it by about 25 mm
    sigma_mm = float(np.linalg.norm(cr.sigma_translation_mm))
    print(f"kinect capture: |dt| {dt_m * 1e3:.3f} mm (1-sigma norm {sigma_mm:.3f} mm), dR {dr_deg:.4f} deg")
    assert dt_m * 1e3 < max(4 * sigma_mm, 0.5) and dt_m < 3e-3, (dt_m, sigma_mm)
    assert dr_deg < 0.3, dr_deg
