"""Camera files other tools write, read by ``--intrinsics NAME=CAM.yaml`` (and every reader of camera
files): a ROS camera_info YAML or ROS 2 CameraInfo dump, an OpenCV FileStorage file (YAML or XML), a
Kalibr camera. Fisheye models and multi-camera files are one clear line."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from calibgraph.core.errors import InputError
from calibgraph.io.camera_file import read_camera_file

K = np.array([[912.5, 0.0, 641.25], [0.0, 910.75, 362.5], [0.0, 0.0, 1.0]])
DIST = [0.11, -0.23, 0.0012, -0.0007, 0.05]


def _check(intr, dist=DIST):
    assert np.allclose(intr.K, K) and np.allclose(intr.dist, dist)
    assert (intr.width_px, intr.height_px) == (1280, 720)
    assert intr.covariance is None and intr.source == ""  # the solver's prior for the default source applies


def test_ros_camera_info(tmp_path):
    f = tmp_path / "ros.yaml"
    f.write_text(yaml.safe_dump({
        "image_width": 1280, "image_height": 720, "camera_name": "cam2",
        "camera_matrix": {"rows": 3, "cols": 3, "data": K.ravel().tolist()},
        "distortion_model": "plumb_bob",
        "distortion_coefficients": {"rows": 1, "cols": 5, "data": DIST},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": np.eye(3).ravel().tolist()},
        "projection_matrix": {"rows": 3, "cols": 4, "data": np.c_[K, np.zeros(3)].ravel().tolist()}}))
    _check(read_camera_file(f))


def test_ros2_camera_info_message(tmp_path):
    f = tmp_path / "info.yaml"
    f.write_text(yaml.safe_dump({"header": {"frame_id": "cam2_optical_frame"}, "height": 720, "width": 1280,
                                 "distortion_model": "rational_polynomial", "d": DIST[:4] + [0.05, 0.0, 0.0, 0.0],
                                 "k": K.ravel().tolist(), "r": np.eye(3).ravel().tolist()}))
    _check(read_camera_file(f), DIST[:4] + [0.05, 0.0, 0.0, 0.0])


@pytest.mark.parametrize("suffix", [".yaml", ".xml"])
def test_opencv_filestorage(tmp_path, suffix):
    f = tmp_path / f"cv{suffix}"
    fs = cv2.FileStorage(str(f), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 720)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", np.array(DIST).reshape(1, 5))
    fs.write("covariance", np.eye(6))  # a pose's (as calibgraph export writes): never taken for the intrinsics'
    fs.release()
    _check(read_camera_file(f))


def test_kalibr_camera(tmp_path):
    cam = {"camera_model": "pinhole", "intrinsics": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])],
           "distortion_model": "radtan", "distortion_coeffs": DIST[:4], "resolution": [1280, 720],
           "rostopic": "/cam2/image_raw"}
    f = tmp_path / "camchain.yaml"
    f.write_text(yaml.safe_dump({"cam0": cam}))
    _check(read_camera_file(f), DIST[:4])
    two = tmp_path / "two.yaml"
    two.write_text(yaml.safe_dump({"cam0": cam, "cam1": cam}))
    with pytest.raises(InputError, match="camchain of 2 cameras"):
        read_camera_file(two)


@pytest.mark.parametrize("doc", [
    {"image_width": 1280, "image_height": 720, "camera_matrix": {"data": K.ravel().tolist()},
     "distortion_model": "equidistant", "distortion_coefficients": {"data": [0.1, 0.0, 0.0, 0.0]}},
    {"cam0": {"camera_model": "pinhole", "intrinsics": [1, 1, 1, 1], "distortion_model": "equidistant",
              "distortion_coeffs": [0, 0, 0, 0], "resolution": [1280, 720]}},
    {"image_width": 1280, "image_height": 720, "camera_matrix": {"data": [1, 2, 3]}},
], ids=["ros_fisheye", "kalibr_fisheye", "ros_short_matrix"])
def test_unsupported_files_are_one_line(tmp_path, doc):
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError) as e:
        read_camera_file(f)
    msg = str(e.value)
    assert str(f) in msg and len(msg.splitlines()) == 1, msg


@pytest.mark.parametrize("raw", [
    b'<?xml version="1.0"?>\n<foo><bar>1</bar></foo>\n',
    b"%YAML:1.0\ncamera_matrix: !!opencv-matrix\n   rows: 2\n   cols: 2\n   dt: d\n   data: [ 1., 0., 0., 1. ]\n",
    bytes(range(200, 256)) * 4,
], ids=["xml_not_opencv", "opencv_2x2", "binary"])
def test_malformed_files_are_one_line(tmp_path, raw):
    f = tmp_path / "bad.yaml"
    f.write_bytes(raw)
    with pytest.raises(InputError) as e:
        read_camera_file(f)
    msg = str(e.value)
    assert str(f) in msg and len(msg.splitlines()) == 1, msg
