"""Standard outputs: URDF round trip, ROS 2 launch file, OpenCV FileStorage round trip, YAML."""

import ast
import json

import numpy as np
import pytest
import yaml
from helpers import make_sim_result

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.transforms import exp_so3, quat_xyzw_to_R
from calibgraph.report.exports import (
    R_to_rpy,
    export,
    parse_urdf_joints,
    read_opencv_yaml,
    rpy_to_R,
    urdf_snippet,
    write_opencv_yaml,
)


def test_rpy_round_trip_including_gimbal_lock():
    rng = np.random.default_rng(0)
    Rs = [exp_so3(rng.normal(size=3) * 2) for _ in range(200)]
    Rs += [rpy_to_R([0.3, np.pi / 2, -1.0]), rpy_to_R([0.3, -np.pi / 2, 2.0]), np.eye(3), exp_so3([np.pi, 0, 0])]
    for R in Rs:
        assert np.allclose(rpy_to_R(R_to_rpy(R)), R, atol=1e-12)
    # the URDF convention: rpy = (r, 0, 0) is a rotation about x by r, applied before pitch and yaw
    assert np.allclose(rpy_to_R([0.2, 0, 0]), exp_so3([0.2, 0, 0]))
    assert np.allclose(rpy_to_R([0.1, 0.2, 0.3]), exp_so3([0, 0, 0.3]) @ exp_so3([0, 0.2, 0]) @ exp_so3([0.1, 0, 0]))


@pytest.mark.parametrize("mode", ["eye_to_hand", "eye_in_hand"])
def test_urdf_round_trips(tmp_path, mode):
    d, *_ = make_sim_result(mode=mode)
    ref = "base" if mode == "eye_to_hand" else "flange"
    text = urdf_snippet(d)
    assert f"T_{ref}_cam" in text and "metres" in text and "radians" in text
    joints = parse_urdf_joints(text.replace("$(arg parent)", "PARENT"))
    assert len(joints) == len(d.cameras)
    for n, c in d.cameras.items():
        parent, T = joints[f"{n}_optical_frame"]
        assert parent == "PARENT"
        assert np.abs(T - getattr(c, f"T_{ref}_cam")).max() < 1e-9
    plain = parse_urdf_joints(urdf_snippet(d, parent="world", xacro=False))
    assert {p for p, _ in plain.values()} == {"world"}
    paths = export(d, "urdf", tmp_path)
    assert paths[0].name == "calibgraph_cameras.urdf.xacro" and paths[0].read_text() == text
    # and a plain URDF beside it: a whole tree (the parent link declared), no xacro in it
    import xml.etree.ElementTree as ET

    assert paths[1].name == "calibgraph_cameras.urdf"
    urdf = paths[1].read_text()
    assert "xmlns:xacro" not in urdf and "$(arg" not in urdf
    root = ET.fromstring(urdf.split("?>", 1)[1])
    links = {ln.get("name") for ln in root.iter("link")}
    default = "base_link" if mode == "eye_to_hand" else "flange"
    assert links == {default} | {f"{n}_optical_frame" for n in d.cameras}
    for n, c in d.cameras.items():
        p, T = parse_urdf_joints(urdf)[f"{n}_optical_frame"]
        assert p == default and np.abs(T - getattr(c, f"T_{ref}_cam")).max() < 1e-9


def test_ros2_launch_file(tmp_path):
    d, *_ = make_sim_result()
    (path,) = export(d, "ros2-launch", tmp_path)
    src = path.read_text()
    tree = ast.parse(src)  # valid Python
    assert "static_transform_publisher" in src and "tf2_ros" in src and "--child-frame-id" in src
    assert "metres" in src and "quaternion (x, y, z, w)" in src
    cams = next(n.value for n in tree.body if isinstance(n, ast.Assign) and n.targets[0].id == "CAMERAS")
    table = ast.literal_eval(cams)
    for n, c in d.cameras.items():
        x, y, z, qx, qy, qz, qw, parent, child = table[n]
        T = c.T_base_cam
        assert parent == "base_link" and child == f"{n}_optical_frame"
        assert np.allclose([x, y, z], T[:3, 3], atol=1e-12)
        assert np.allclose(quat_xyzw_to_R([qx, qy, qz, qw]), T[:3, :3], atol=1e-9)


def test_opencv_filestorage_round_trip(tmp_path):
    d, scene, prob, _ = make_sim_result()
    paths = write_opencv_yaml(d, tmp_path)
    assert len(paths) == len(d.cameras)
    for p in paths:
        back = read_opencv_yaml(p)
        n = back["camera_name"]
        c = d.cameras[n]
        intr = Intrinsics.from_dict(c.intrinsics)  # the intrinsics the calibration used (estimated by default)
        assert np.array_equal(back["camera_matrix"], intr.K)
        assert np.array_equal(back["distortion_coefficients"].ravel(), intr.dist)
        assert back["image_width"] == intr.width_px and back["image_height"] == intr.height_px
        assert np.array_equal(back["T_base_cam"], c.T_base_cam)
        assert np.array_equal(back["sigma_translation_mm"].ravel(), c.sigma_translation_mm)
        assert np.array_equal(back["sigma_rotation_deg"].ravel(), c.sigma_rotation_deg)
        assert np.array_equal(back["covariance"], c.covariance)
        # the parent frame every export names by default (was 'base' here, 'base_link' in the URDF)
        assert back["frame_parent"] == "base_link" and back["frame_child"] == f"{n}_optical_frame"
        text = p.read_text()
        assert text.startswith("%YAML") and "metres" in text and "optical" in text
        # and it is a camera file for --intrinsics: the intrinsics the calibration used, the pose's
        # covariance not taken for theirs
        from calibgraph.io.camera_file import read_camera_file
        cam = read_camera_file(p)
        assert np.array_equal(cam.K, intr.K) and np.array_equal(cam.dist, intr.dist) and cam.covariance is None


def test_ros_camera_info_round_trip(tmp_path):
    """export --format camera-info: one ROS camera_info YAML per camera, read back by the camera-file
    reader (and so by --intrinsics) as the intrinsics the calibration used."""
    from calibgraph.io.camera_file import read_camera_file

    d, *_ = make_sim_result()
    paths = export(d, "camera-info", tmp_path)
    assert len(paths) == len(d.cameras)
    for p in paths:
        doc = yaml.safe_load(p.read_text())
        intr = Intrinsics.from_dict(d.cameras[doc["camera_name"]].intrinsics)
        assert doc["distortion_model"] == "plumb_bob" and doc["projection_matrix"]["cols"] == 4
        back = read_camera_file(p)
        assert np.allclose(back.K, intr.K, rtol=0, atol=1e-12) and np.allclose(back.dist8, intr.dist8, atol=1e-15)
        assert (back.width_px, back.height_px) == (intr.width_px, intr.height_px)
    without, *_ = make_sim_result(intrinsics=False)
    with pytest.raises(InputError, match="camera-info needs cameras with known intrinsics"):
        export(without, "camera-info", tmp_path / "none")


def test_an_old_result_exported_with_the_datasets_intrinsics_says_they_are_the_given_ones(tmp_path):
    """Issue 34: a result that does not record the intrinsics its cameras were solved with, exported
    with --dataset, used to write the dataset's factory K under 'the intrinsics calibgraph solved this
    camera with'. Now each file carries the given values and says so; a result that records them
    is exported with those, whatever the dataset says."""
    from helpers import write_sim_dataset

    from calibgraph.io.camera_file import read_camera_file

    old, scene, prob, _ = make_sim_result(intrinsics=False)
    ds = write_sim_dataset(tmp_path / "ds", prob)
    for fmt in ("camera-info", "opencv-yaml"):
        for p in export(old, fmt, tmp_path / fmt, dataset=ds):
            text = p.read_text()
            assert "GIVEN values of the dataset" in text and str(ds) in text and "solved this camera with" not in text
            back = read_camera_file(p)
            name = next(n for n in prob.cameras if p.name.startswith(n))
            assert np.array_equal(back.K, prob.cameras[name].K)  # the given values, as said
    new, *_ = make_sim_result()
    for p in export(new, "camera-info", tmp_path / "new", dataset=ds):
        text = p.read_text()
        assert "solved this camera with" in text and "GIVEN" not in text
        name = yaml.safe_load(text)["camera_name"]
        assert np.array_equal(read_camera_file(p).K, Intrinsics.from_dict(new.cameras[name].intrinsics).K)


def test_opencv_yaml_without_intrinsics_says_so(tmp_path):
    d, *_ = make_sim_result(intrinsics=False)
    p = write_opencv_yaml(d, tmp_path)[0]
    back = read_opencv_yaml(p)
    assert "camera_matrix" not in back and "T_base_cam" in back
    assert "intrinsics unknown" in p.read_text()


def test_yaml_and_json_outputs_and_cli(tmp_path):
    from calibgraph.cli.main import main

    r, *_ = make_sim_result()
    r.save(tmp_path / "result.json")
    d = json.loads((tmp_path / "result.json").read_text())
    rc = main(["export", str(tmp_path / "result.json"), "--format", "yaml", "--format", "urdf",
               "--format", "ros2-launch", "--format", "opencv-yaml", "--out", str(tmp_path / "out")])
    assert rc == 0
    y = (tmp_path / "out" / "result.yaml").read_text()
    assert y.startswith("# calibgraph result. T_a_b maps points")
    assert yaml.safe_load(y) == d
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(
        ["result.yaml", "calibgraph_cameras.urdf", "calibgraph_cameras.urdf.xacro", "calibgraph_cameras.launch.py"]
        + [f"{n}.yaml" for n in d["cameras"]])
    assert main(["export", str(tmp_path / "nope.json"), "--format", "urdf", "--out", str(tmp_path)]) == 2
