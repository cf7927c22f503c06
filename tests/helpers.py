"""Helpers shared by the tests (not a test module): the simulator gate, the hardware-SDK gate, the
browser gate (headless Chromium), one
simulated-world fixture factory, and a solved simulated cell with injected outliers for the report,
viewer and export tests."""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import signal
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from calibgraph import solve
from calibgraph.core.problem import Detection
from calibgraph.core.targets import a4_board_54
from calibgraph.core.transforms import exp_so3, make_T
from calibgraph.io.dataset import write_problem
from calibgraph.sim.synthetic_corners import make_scene
from calibgraph.solver.output.result import Result

REPO = Path(__file__).resolve().parents[1]


def require_sim():
    """Skip (or fail when CALIBGRAPH_SIM_REQUIRED=1) without MuJoCo, franky-sim or headless GL."""
    try:
        from calibgraph.sim.scene import fr3_xml_path, import_mujoco

        mj = import_mujoco()
        fr3_xml_path()
        m = mj.MjModel.from_xml_string("<mujoco><worldbody><geom size='1'/></worldbody></mujoco>")
        r = mj.Renderer(m, 8, 8)
        r.close()
    except Exception as e:  # any missing piece means: no simulator here
        msg = f"simulator unavailable: {type(e).__name__}: {e}"
        if os.environ.get("CALIBGRAPH_SIM_REQUIRED") == "1":
            pytest.fail(msg)
        pytest.skip(msg)


# -- hardware SDKs ------------------------------------------------------------------------------
# An SDK that is not installed, or installed but unable to load (a missing system library, say),
# skips the tests that need it with the reason; with CALIBGRAPH_HW_SDK_REQUIRED=1 (CI, which
# installs every extra) it fails them instead. ``pytest.importorskip`` is not enough: since pytest 9
# it lets an ImportError that is not a ModuleNotFoundError (``libusb-1.0.so.0: cannot open shared
# object file``) through, which stops the whole run at collection.
def sdk_unavailable(msg: str):
    """Skip with ``msg`` (the whole module when called at import), or fail in CI."""
    if os.environ.get("CALIBGRAPH_HW_SDK_REQUIRED") == "1":
        pytest.fail(msg + " (and CALIBGRAPH_HW_SDK_REQUIRED=1)", pytrace=False)
    pytest.skip(msg, allow_module_level=True)


def import_sdk(name: str, install_hint: str):
    """The module ``name``, or a skip saying why it is unavailable and how to install it."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as e:
        sdk_unavailable(f"{name} is not installed ({install_hint}) [{e}]")
    except Exception as e:  # installed, but it (or a library it needs) fails to load
        sdk_unavailable(f"{name} is installed but cannot be imported: {type(e).__name__}: {e} ({install_hint})")


def require_realsense():
    """pyrealsense2 as calibgraph_drivers.realsense loaded it: rclpy's libraries first, then libusb from the
    libusb-package wheel (see the notes there), then the SDK."""
    import calibgraph_drivers.realsense as drv

    if drv._rs is None:
        sdk_unavailable(f"pyrealsense2 is unavailable (pip install 'calibgraph[realsense]') [{drv._IMPORT_ERROR}]")
    return drv._rs


# -- a real browser ------------------------------------------------------------------------------
def chromium_binary():
    """The path of a Chromium (or Chrome) on PATH, or None."""
    import shutil

    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    return None


def require_chromium() -> str:
    """The Chromium binary; without one, skip with the reason, or fail when
    CALIBGRAPH_BROWSER_REQUIRED=1 (CI, whose .ci/run installs it)."""
    exe = chromium_binary()
    if exe is None:
        msg = "chromium not installed (apt-get install chromium)"
        if os.environ.get("CALIBGRAPH_BROWSER_REQUIRED") == "1":
            pytest.fail(msg + " and CALIBGRAPH_BROWSER_REQUIRED=1", pytrace=False)
        pytest.skip(msg)
    return exe


def run_chromium(args: list, timeout_s: float = 60.0):
    """Headless Chromium with a fresh profile, no network chatter, as root-safe flags."""
    import subprocess
    import tempfile

    exe = require_chromium()
    with tempfile.TemporaryDirectory() as prof:
        cmd = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               "--hide-scrollbars", f"--user-data-dir={prof}", *args]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)


def sim_world_fixture(make_cell):
    """A module-scoped pytest fixture yielding a :class:`~calibgraph.sim.render.SimWorld` of the cell
    ``make_cell()`` returns (skipped without the simulator), closed after the module."""

    @pytest.fixture(scope="module")
    def world():
        require_sim()
        from calibgraph.sim.render import SimWorld

        w = SimWorld(make_cell())
        yield w
        w.close()

    return world


OUTLIER_VIEW = 5        # detection index whose corners are all garbage -> a rejected view
OUTLIER_CORNERS = 2     # detection index with 3 corners moved by 25 px -> rejected corners


@lru_cache(maxsize=4)
def _solved(seed: int, mode: str):
    # the oracle's scene (true intrinsics, held): the report, viewer and export tests recompute
    # residuals with the dataset's intrinsics, which are then the ones the solver used
    scene = make_scene(n_poses=24, seed=seed, mode=mode, reported_intrinsics="exact")
    prob = scene.problem
    dets = list(prob.detections)
    rng = np.random.default_rng(seed + 100)
    d = dets[OUTLIER_CORNERS]
    uv = d.uv_px.copy()
    uv[[3, 10, 20]] += 25.0
    dets[OUTLIER_CORNERS] = Detection(d.camera, d.capture, d.ids, uv)
    if mode == "eye_to_hand":
        d = dets[OUTLIER_VIEW]
        dets[OUTLIER_VIEW] = Detection(d.camera, d.capture, d.ids, d.uv_px + rng.normal(scale=40.0, size=d.uv_px.shape))
    prob = prob.with_(detections=tuple(dets))
    return scene, prob, solve(prob)


def make_sim_result(seed: int = 0, mode: str = "eye_to_hand", intrinsics: bool = True, residuals: bool = True):
    """(the Result as read back from its result.json, scene, problem, the solver's Result) of a
    solved simulated cell with injected outliers. ``intrinsics=False`` / ``residuals=False`` drop
    those sections, as in a result.json of an earlier calibgraph."""
    scene, prob, res = _solved(seed, mode)
    d = json.loads(json.dumps(res.to_dict()))
    d["dataset"] = "simulated (calibgraph.sim.synthetic_corners.make_scene seed %d)" % seed
    if not residuals:
        d.pop("residuals")
    for c in d["cameras"].values():
        if not intrinsics:
            c.pop("intrinsics")
    return Result.from_dict(d), scene, prob, res


@lru_cache(maxsize=1)
def knocked_result():
    """The solved Result of a simulated 3-camera cell (36 poses, FK noise 0.1 mm / 0.01 deg) whose
    cam0 was knocked 5 mm after capture 18: a moved camera, its notes, each camera's budget."""
    from calibgraph.sim.synthetic_corners import bump_camera

    scene = make_scene(n_poses=36, seed=0, fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=np.radians(0.01))
    prob, _ = bump_camera(scene, "cam0", 18, 0.005, seed=0)
    return solve(prob)


def write_sim_dataset(root: Path, prob) -> Path:
    """Write a problem as a calibgraph dataset folder (detections stored, no images)."""
    write_problem(root, prob, a4_board_54())
    return root


# A capture run in its own process, to be killed and resumed by the tests (arguments: dataset
# folder, poses, seed of the fake cell, robot move delay in seconds).
CAPTURE_SCRIPT = r"""
import sys
from calibgraph.acquire.run import run_acquisition
from calibgraph.sim.fakes import make_fake_cell
cell = make_fake_cell(n_cameras=2, n_poses=int(sys.argv[2]), seed=int(sys.argv[3]),
                      robot_kwargs=dict(move_delay_s=float(sys.argv[4])))
run_acquisition(cell.robot, cell.cameras, cell.trajectory, sys.argv[1], cell.target, detector=cell.detector,
                resume=True, progress=False)
"""


def dataset_content(root):
    """Everything in a dataset except wall-clock stamps, for comparing two runs: (captures, images)."""
    caps = {}
    for f in sorted((Path(root) / "captures").glob("*.json")):
        d = json.loads(f.read_text())
        d.pop("stamp_s")
        for v in d["views"].values():
            v.pop("stamp_s")
        caps[f.name] = d
    imgs = {str(p.relative_to(root)): p.read_bytes() for p in sorted((Path(root) / "images").rglob("*.png"))}
    return caps, imgs


@contextlib.contextmanager
def fails_instead_of_hanging(seconds: int, what: str):
    """Run the block with an alarm: a call that blocks (a FIFO opened for reading, say) raises
    TimeoutError naming ``what`` after ``seconds`` instead of hanging the test run."""
    def hung(*_):
        raise TimeoutError(f"{what} blocked for {seconds} s")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def square_to_the_image(intr, target, n, rng, max_tilt_deg=2.0, distance_m=(0.3, 0.8)) -> list:
    """``n`` poses of a board square to the image plane (tilted under ``max_tilt_deg``), its centre
    aimed all over the image, the whole pattern inside it."""
    centre, Kinv, poses = target.points_board_m.mean(axis=0), np.linalg.inv(intr.K), []
    while len(poses) < n:
        psi = rng.uniform(0, 2 * np.pi)
        R = exp_so3(np.radians(rng.uniform(0, max_tilt_deg)) * np.array([np.cos(psi), np.sin(psi), 0.0])) @ exp_so3(
            [0.0, 0.0, np.radians(rng.uniform(-30, 30))])
        ray = Kinv @ np.array([rng.uniform(0, intr.width_px), rng.uniform(0, intr.height_px), 1.0])
        T = make_T(R, ray / ray[2] * rng.uniform(*distance_m) - R @ centre)
        uv = intr.project(target.points_board_m @ R.T + T[:3, 3])
        if np.all((uv > 8) & (uv < np.array([intr.width_px, intr.height_px]) - 8)):
            poses.append(T)
    return poses
