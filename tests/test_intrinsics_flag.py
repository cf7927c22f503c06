"""``--intrinsics NAME=CAM.yaml`` on ``solve`` and ``capture`` (issue 23 part 2): a camera file's
values and covariance become that camera's prior; a wrong name, a file of another image size or a
malformed argument is one line and exit 2."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from helpers import write_sim_dataset

from calibgraph.acquire.devices import FileIntrinsicsCamera
from calibgraph.cli.main import main
from calibgraph.core.camera import INTRINSICS_VECTOR, Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.transforms import log_so3
from calibgraph.io.camera_file import write_camera_file
from calibgraph.sim.synthetic_corners import make_scene

FILE_SIGMA = np.array([0.3, 0.3, 0.4, 0.4, 1e-3, 2e-3])  # fx fy cx cy [px], k1 k2: a close-range session's


def _camera_file(path, true: Intrinsics, seed: int, sigma=FILE_SIGMA) -> Intrinsics:
    """A camera file as `calibgraph intrinsics` writes one: the truth plus an error drawn from its own
    covariance (so the file is honest about itself)."""
    rng = np.random.default_rng(seed)
    cov = np.diag(sigma ** 2)
    e = rng.multivariate_normal(np.zeros(6), cov)
    K = true.K.copy()
    K[0, 0] += e[0]
    K[1, 1] += e[1]
    K[0, 2] += e[2]
    K[1, 2] += e[3]
    dist = np.zeros(5)
    dist[: true.dist.size] = true.dist[:5]
    dist[:2] += e[4:]
    write_camera_file(path, {"format": "calibgraph-camera/1", "source": "calibration", "width_px": true.width_px,
                             "height_px": true.height_px, "K": K.tolist(), "distortion": dist.tolist(),
                             "covariance_order": list(INTRINSICS_VECTOR), "covariance": cov.tolist()})
    return Intrinsics(K, dist, true.width_px, true.height_px, "calibration", cov)


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    """Three cameras at 1.5 / 3 / 5 m reporting factory-class intrinsics; a camera file for the far one."""
    root = tmp_path_factory.mktemp("intrinsics_flag")
    scene = make_scene(n_poses=30, seed=4)
    ds = write_sim_dataset(root / "ds", scene.problem)
    true = scene.truth.intrinsics["cam2"]
    _camera_file(root / "cam2.yaml", true, seed=4)
    assert main(["solve", str(ds), "--out", str(root / "plain.json"), "--quiet"]) == 0
    assert main(["solve", str(ds), "--intrinsics", f"cam2={root / 'cam2.yaml'}", "--out", str(root / "file.json"),
                 "--quiet"]) == 0
    return root, scene


def _cam(path, name):
    return json.loads(path.read_text())["cameras"][name]


def test_the_file_is_the_camera_prior(cell):
    root, scene = cell
    plain, used = _cam(root / "plain.json", "cam2"), _cam(root / "file.json", "cam2")
    assert used["intrinsics"]["source"] == "calibration"
    # the file's covariance, far tighter than a factory prior, shrinks the far camera's 1-sigma
    # (a property of the information, not of the noise draw)
    s_plain, s_file = np.linalg.norm(plain["sigma_translation_mm"]), np.linalg.norm(used["sigma_translation_mm"])
    assert s_file < 0.8 * s_plain, (s_plain, s_file)
    # and the answer stays honest: within 4 sigma per axis of the truth
    T = np.asarray(used["T_base_cam"])
    cov = np.asarray(used["covariance"])
    T_true = scene.truth.T_ref_cam["cam2"]
    e = np.concatenate([log_so3(T[:3, :3] @ T_true[:3, :3].T), T[:3, 3] - T_true[:3, 3]])
    z = e / np.sqrt(np.diag(cov))
    assert np.all(np.abs(z) < 4.0), z
    # the other cameras keep their own (factory) intrinsics
    assert _cam(root / "file.json", "cam0")["intrinsics"].get("source") != "calibration"


def test_a_file_with_tangential_terms_has_them_estimated(cell, tmp_path):
    """A file whose covariance covers p1, p2 and k3 (as `calibgraph intrinsics` writes for its default
    model) has them estimated under that covariance, not held as if exact: held, their errors moved a
    rendered 5 m camera's principal point (and pan) by up to 1 sigma unaccounted."""
    root, scene = cell
    true = scene.truth.intrinsics["cam2"]
    sigma = np.r_[FILE_SIGMA, 7e-5, 8e-5, 3e-4]
    rng = np.random.default_rng(9)
    e = rng.normal(size=9) * sigma
    K = true.K.copy()
    K[0, 0], K[1, 1], K[0, 2], K[1, 2] = K[0, 0] + e[0], K[1, 1] + e[1], K[0, 2] + e[2], K[1, 2] + e[3]
    dist = true.dist8[:5] + e[4:]
    order = ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
    write_camera_file(tmp_path / "cam2.yaml", {"source": "calibration", "width_px": true.width_px,
                                               "height_px": true.height_px, "K": K.tolist(), "distortion": dist.tolist(), "covariance_order": order,
                                               "covariance": np.diag(sigma ** 2).tolist()})
    out = tmp_path / "r.json"
    assert main(["solve", str(root / "ds"), "--intrinsics", f"cam2={tmp_path / 'cam2.yaml'}", "--out", str(out),
                 "--quiet"]) == 0
    got = _cam(out, "cam2")["intrinsics"]
    assert got["estimated"] and got["prior"] == "calibration"
    assert list(got["sigma"]) == order and list(got["given"]) == order
    assert np.allclose([got["given"][n] for n in ("p1", "p2", "k3")], dist[2:])
    # the data add to the file's knowledge, never subtract from it
    assert all(got["sigma"][n] <= s * (1 + 1e-6) for n, s in zip(order, sigma)), got["sigma"]
    T = np.asarray(_cam(out, "cam2")["T_base_cam"])
    T_true = scene.truth.T_ref_cam["cam2"]
    z = np.concatenate([log_so3(T[:3, :3] @ T_true[:3, :3].T), T[:3, 3] - T_true[:3, 3]]) / np.sqrt(
        np.diag(np.asarray(_cam(out, "cam2")["covariance"])))
    assert np.all(np.abs(z) < 4.0), z


def test_a_ros_camera_info_is_a_camera_file(cell, tmp_path, capsys):
    """A ROS camera_info YAML is what integrators have: it is that camera's intrinsics (no covariance:
    the default source's prior); a fisheye one is one line and exit 2."""
    root, scene = cell
    true = scene.truth.intrinsics["cam2"]
    info = {"image_width": true.width_px, "image_height": true.height_px, "distortion_model": "plumb_bob",
            "camera_matrix": {"rows": 3, "cols": 3, "data": true.K.ravel().tolist()},
            "distortion_coefficients": {"rows": 1, "cols": 5, "data": true.dist8[:5].tolist()}}
    (tmp_path / "cam2_info.yaml").write_text(yaml.safe_dump(info))
    out = tmp_path / "r.json"
    assert main(["solve", str(root / "ds"), "--intrinsics", f"cam2={tmp_path / 'cam2_info.yaml'}", "--out", str(out),
                 "--quiet"]) == 0
    got = _cam(out, "cam2")["intrinsics"]
    assert got["prior"] == "calibration" and np.allclose(got["given"]["fx"], true.K[0, 0])
    (tmp_path / "fish.yaml").write_text(yaml.safe_dump({**info, "distortion_model": "equidistant"}))
    capsys.readouterr()
    assert main(["solve", str(root / "ds"), "--intrinsics", f"cam2={tmp_path / 'fish.yaml'}", "--out",
                 str(tmp_path / "f.json"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "equidistant" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "f.json").exists()


@pytest.mark.parametrize("case", ["unknown_name", "no_equals", "other_size", "missing_file", "twice"])
def test_bad_intrinsics_arguments_are_one_line(case, cell, tmp_path, capsys):
    root, scene = cell
    cam2 = root / "cam2.yaml"
    other = tmp_path / "vga.yaml"
    write_camera_file(other, {"K": [[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]], "distortion": [0.0] * 5,
                              "width_px": 640, "height_px": 480, "source": "calibration"})
    arg, said = {"unknown_name": ([f"camX={cam2}"], "has no camera 'camX'"),
                 "no_equals": ([str(cam2)], "expected NAME=CAM.yaml"),
                 "other_size": ([f"cam2={other}"], "640x480"),
                 "missing_file": ([f"cam2={tmp_path / 'none.yaml'}"], "none.yaml"),
                 "twice": ([f"cam2={cam2}", f"cam2={cam2}"], "two camera files")}[case]
    argv = ["solve", str(root / "ds"), "--out", str(tmp_path / "r.json"), "--quiet"]
    for a in arg:
        argv += ["--intrinsics", a]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "r.json").exists()


class _Cam:
    def __init__(self, intr):
        self._intr, self.name = intr, "c"

    def intrinsics(self):
        return self._intr

    def grab(self):
        return "frame"


def test_a_capture_camera_reports_the_file(tmp_path):
    dev = Intrinsics(np.array([[640.0, 0, 640], [0, 640.0, 400], [0, 0, 1]]), np.zeros(5), 1280, 800, "factory")
    filed = _camera_file(tmp_path / "c.yaml", dev, seed=1)
    cam = FileIntrinsicsCamera("c", _Cam(dev), filed, "workcell cell.yaml")
    got = cam.intrinsics()
    assert got.source == "calibration" and np.allclose(got.covariance, filed.covariance)
    assert cam.grab() == "frame"  # everything else is the device's
    small = Intrinsics(np.array([[400.0, 0, 320], [0, 400.0, 240], [0, 0, 1]]), np.zeros(5), 640, 480)
    with pytest.raises(InputError, match="640x480"):
        FileIntrinsicsCamera("c", _Cam(dev), small, "workcell cell.yaml").intrinsics()


def test_capture_names_an_unknown_camera(tmp_path, capsys):
    cell = tmp_path / "cell.yaml"
    cell.write_text(yaml.safe_dump({"board": "a4_54", "safety": {"robot_model": "fr3", "max_speed_scale": 0.5},
                                    "cameras": {"c0": {"preset": "d455", "position_m": [1.2, 0.3, 0.6],
                                                       "look_at_m": [0.5, 0.0, 0.45]}}}))
    dev = Intrinsics(np.array([[640.0, 0, 640], [0, 640.0, 400], [0, 0, 1]]), np.zeros(5), 1280, 800)
    _camera_file(tmp_path / "c.yaml", dev, seed=2)
    traj = tmp_path / "traj.yaml"
    assert main(["capture", "--auto", "--robot", "sim", "--workcell", str(cell), "--out", str(tmp_path / "o"),
                 "--dry-run", "--intrinsics", f"cam9={tmp_path / 'c.yaml'}", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "has no camera 'cam9'" in err and "Traceback" not in err, err
    assert not traj.exists() and not (tmp_path / "o").exists()
