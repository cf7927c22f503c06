"""Write a calibration result in the formats a robot stack reads.

All exporters take the result *dict* (as written by :meth:`calibgraph.solver.result.Result.save` and read
by :func:`calibgraph.solver.result.load_result_dict`), so they work from the file alone:

- :func:`write_result` -- result.json / result.yaml (same content; ``--format yaml``);
- :func:`write_urdf` -- a URDF/xacro snippet, one fixed joint per camera
  ``<parent> -> <camera>_optical_frame`` (``xyz`` in m, ``rpy`` in rad, URDF fixed-axis
  roll-pitch-yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)``);
- :func:`write_ros2_launch` -- a ROS 2 Python launch file with one ``tf2_ros``
  ``static_transform_publisher`` per camera (translation + quaternion x y z w);
- :func:`write_opencv_yaml` -- one OpenCV FileStorage YAML per camera with ``camera_matrix``,
  ``distortion_coefficients``, ``image_width/height``, ``T_<ref>_cam`` and its sigmas/covariance.

- :func:`write_robot_exports` -- when the result has a ``robot`` section (solved with
  ``--estimate-kinematics joint-offsets``): ``<model>_corrected.urdf``, the arm's URDF with each joint
  origin turned by its offset about the joint axis (so the controller's FK of the encoder angles is
  the true flange pose), and ``joint_offsets.yaml`` for the controller. ``--format urdf`` writes them
  beside the camera snippet; ``--format robot`` writes only them.

Frames: the parent frame is the robot base (eye-to-hand: ``T_base_cam``) or the flange
(eye-in-hand: ``T_flange_cam``); the child is the camera's OpenCV optical frame (x right, y down,
z forward), which is what ROS calls ``<camera>_optical_frame``. Every file states the frames
and units in comments or fields.

Intrinsics are read from ``cameras.<name>.intrinsics`` in the result when present (``K``,
``dist``, ``width_px``, ``height_px``), else from the dataset given with ``dataset=``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.kinematics import corrected_urdf
from calibgraph.core.problem import mode_frames
from calibgraph.core.transforms import R_to_quat_xyzw
from calibgraph.core.version import __version__
from calibgraph.io.files import atomic_write_text, atomic_write_via, output_folder
from calibgraph.io.layouts import as_dataset
from calibgraph.solver.kinematics import load_chain

FORMATS = ("urdf", "ros2-launch", "opencv-yaml", "yaml", "json", "robot")

DEFAULT_PARENT = {"base": "base_link", "flange": "flange"}


# -- rotation helpers ----------------------------------------------------------------------------
def rpy_to_R(rpy_rad) -> np.ndarray:
    """URDF/ROS roll-pitch-yaw (fixed axes x, y, z) to a rotation: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = (float(v) for v in rpy_rad)
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def R_to_rpy(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rpy_to_R`; pitch in [-pi/2, pi/2]. At gimbal lock (|pitch| = pi/2) roll is
    set to 0 and yaw absorbs the rest, which still recomposes to the same rotation."""
    R = np.asarray(R, float)
    sp = -R[2, 0]
    if abs(sp) < 1.0 - 1e-12:
        pitch = np.arcsin(np.clip(sp, -1.0, 1.0))
        roll = np.arctan2(R[2, 1], R[2, 2])
        yaw = np.arctan2(R[1, 0], R[0, 0])
    else:
        pitch = np.pi / 2 * np.sign(sp)
        roll = 0.0
        yaw = np.arctan2(-R[0, 1], R[1, 1])
    return np.array([roll, pitch, yaw])


# -- reading the result dict ------------------------------------------------------------------------
def ref_frame(result: dict) -> str:
    """'base' (eye-to-hand) or 'flange' (eye-in-hand)."""
    return mode_frames(result.get("mode")).ref


def camera_pose(result: dict, name: str) -> np.ndarray:
    """``T_<ref>_cam`` of camera ``name`` from a result dict as a (4, 4) array."""
    cam = result["cameras"][name]
    key = f"T_{ref_frame(result)}_cam"
    if key not in cam:
        raise InputError(f"result: camera {name!r} has no {key} (mode {result.get('mode')!r}).")
    T = np.asarray(cam[key], float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"result: camera {name!r}: {key} is not a finite 4x4 matrix.")
    return T


def camera_intrinsics(result: dict, name: str, dataset=None):
    """Intrinsics of camera ``name``: from the result's ``intrinsics`` field, else the dataset, else None."""

    d = result["cameras"][name].get("intrinsics")
    if d:
        return Intrinsics.from_dict(d)
    ds = _as_dataset(dataset)
    if ds is not None and name in ds.cameras:
        return ds.cameras[name]
    return None


def _as_dataset(dataset):

    return as_dataset(dataset)


def _safe(name: str) -> str:
    """A ROS/URDF-safe identifier from a camera name."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", str(name))
    return s if s and not s[0].isdigit() else f"cam_{s}"


def _header_lines(result: dict) -> list:
    ref = ref_frame(result)
    return [
        f"Generated by calibgraph {_version()} from a calibgraph result "
        f"(mode {result.get('mode')}, method {result.get('method')}, dataset {result.get('dataset') or 'n/a'}).",
        f"Frames: parent = robot {ref} frame; child = <camera>_optical_frame (OpenCV optical: x right, y down, z forward).",
        f"The transform is T_{ref}_cam: it maps points from the camera optical frame to the {ref} frame (p_{ref} = T @ p_cam).",
        "Units: translation metres, angles radians, quaternion (x, y, z, w); a name ending in _mm or _deg is in mm or degrees.",
    ]


def _version() -> str:

    return __version__


# -- writers -------------------------------------------------------------------------------------
def write_result(result: dict, out_path) -> Path:
    """result.json or result.yaml (by extension), atomically."""
    p = Path(out_path)
    if p.suffix.lower() in (".yaml", ".yml"):
        import yaml

        text = "# calibgraph result. " + result.get("frame_convention", "") + "\n" + yaml.safe_dump(result, sort_keys=False)
    else:
        text = json.dumps(result, indent=2)
    atomic_write_text(p, text)
    return p


def urdf_snippet(result: dict, parent: str | None = None, xacro: bool = True) -> str:
    """URDF (xacro-includable) text with one fixed joint and one link per camera."""
    ref = ref_frame(result)
    parent = parent or DEFAULT_PARENT[ref]
    lines = ['<?xml version="1.0"?>']
    lines.append("<!--")
    lines += ["  " + s.replace("--", "- -") for s in _header_lines(result)]
    lines.append(f"  URDF joint origin: xyz = translation of T_{ref}_cam (m); rpy = fixed-axis roll, pitch, yaw (rad),")
    lines.append("  R = Rz(yaw) Ry(pitch) Rx(roll). 1-sigma uncertainties are given per joint in a comment.")
    lines.append("-->")
    if xacro:
        lines.append('<robot xmlns:xacro="http://www.ros.org/wiki/xacro" name="calibgraph_cameras">')
        lines.append(f'  <xacro:arg name="parent" default="{parent}"/>')
    else:
        lines.append('<robot name="calibgraph_cameras">')
    for name in result["cameras"]:
        T = camera_pose(result, name)
        xyz = T[:3, 3]
        rpy = R_to_rpy(T[:3, :3])
        cam = result["cameras"][name]
        st = cam.get("sigma_translation_mm", [float("nan")] * 3)
        sr = cam.get("sigma_rotation_deg", [float("nan")] * 3)
        child = f"{_safe(name)}_optical_frame"
        par = "$(arg parent)" if xacro else parent
        lines.append(f"  <!-- camera {name}: 1-sigma translation (mm, {ref} axes) {_fmt3(st)}; "
                     f"rotation (deg, {ref} axes) {_fmt3(sr)} -->")
        lines.append(f'  <link name="{child}"/>')
        lines.append(f'  <joint name="{_safe(name)}_optical_joint" type="fixed">')
        lines.append(f'    <parent link="{par}"/>')
        lines.append(f'    <child link="{child}"/>')
        lines.append(f'    <origin xyz="{_r(xyz[0])} {_r(xyz[1])} {_r(xyz[2])}" rpy="{_r(rpy[0])} {_r(rpy[1])} {_r(rpy[2])}"/>')
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def write_urdf(result: dict, out_path, parent: str | None = None, xacro: bool = True) -> Path:
    """Write :func:`urdf_snippet` to ``out_path`` (e.g. ``cameras.urdf.xacro``)."""
    p = Path(out_path)
    atomic_write_text(p, urdf_snippet(result, parent=parent, xacro=xacro))
    return p


def parse_urdf_joints(text: str) -> dict:
    """Child link -> (parent, T_parent_child (4, 4)) of every fixed joint in a URDF text."""
    import xml.etree.ElementTree as ET

    root = ET.fromstring(text)
    out = {}
    for j in root.iter("joint"):
        o = j.find("origin")
        xyz = [float(v) for v in o.get("xyz", "0 0 0").split()]
        rpy = [float(v) for v in o.get("rpy", "0 0 0").split()]
        T = np.eye(4)
        T[:3, :3] = rpy_to_R(rpy)
        T[:3, 3] = xyz
        out[j.find("child").get("link")] = (j.find("parent").get("link"), T)
    return out


def ros2_launch_text(result: dict, parent: str | None = None) -> str:
    """A ROS 2 Python launch file publishing every camera's pose as a static transform."""
    ref = ref_frame(result)
    parent = parent or DEFAULT_PARENT[ref]
    lines = ['"""ROS 2 launch file: static transforms of the calibrated cameras.', ""]
    lines += _header_lines(result)
    lines += [
        f"Each node publishes the transform of <camera>_optical_frame in '{parent}' (tf2 parent -> child),",
        "i.e. the pose T_parent_child with translation (m) and quaternion (x, y, z, w).",
        "Run: ros2 launch <this file>",
        '"""',
        "",
        "from launch import LaunchDescription",
        "from launch_ros.actions import Node",
        "",
        "# name: (x_m, y_m, z_m, qx, qy, qz, qw, parent_frame, child_frame)",
        "CAMERAS = {",
    ]
    for name in result["cameras"]:
        T = camera_pose(result, name)
        q = R_to_quat_xyzw(T[:3, :3])
        t = T[:3, 3]
        vals = ", ".join(_r(v) for v in (*t, *q))
        lines.append(f'    {str(name)!r}: ({vals}, {parent!r}, {_safe(name) + "_optical_frame"!r}),')
    lines += [
        "}",
        "",
        "",
        "def generate_launch_description():",
        "    nodes = []",
        "    for name, (x, y, z, qx, qy, qz, qw, parent, child) in CAMERAS.items():",
        "        nodes.append(Node(",
        '            package="tf2_ros",',
        '            executable="static_transform_publisher",',
        '            name=f"calibgraph_{child}_tf",',
        "            arguments=[",
        '                "--x", repr(x), "--y", repr(y), "--z", repr(z),',
        '                "--qx", repr(qx), "--qy", repr(qy), "--qz", repr(qz), "--qw", repr(qw),',
        '                "--frame-id", parent, "--child-frame-id", child,',
        "            ],",
        "        ))",
        "    return LaunchDescription(nodes)",
        "",
    ]
    return "\n".join(lines)


def write_ros2_launch(result: dict, out_path, parent: str | None = None) -> Path:
    """Write :func:`ros2_launch_text` to ``out_path`` (e.g. ``calibgraph_cameras.launch.py``)."""
    p = Path(out_path)
    atomic_write_text(p, ros2_launch_text(result, parent=parent))
    return p


def write_opencv_yaml(result: dict, out_dir, dataset=None) -> list:
    """One OpenCV FileStorage YAML per camera (``<out_dir>/<camera>.yaml``); returns the paths.

    Fields: ``camera_name``, ``image_width``, ``image_height``, ``camera_matrix`` (3x3, px),
    ``distortion_coefficients`` (1xN, OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6]]),
    ``T_<ref>_cam`` (4x4, m), ``sigma_translation_mm`` (1x3), ``sigma_rotation_deg`` (1x3),
    ``covariance`` (6x6, rotation first, rad and m, in the ref frame's axes), ``reprojection_rms_px``.
    A camera without known intrinsics gets the pose fields only and a comment saying so.
    """

    out = output_folder(out_dir, "export folder")
    ref = ref_frame(result)
    paths = []
    for name in result["cameras"]:
        T = camera_pose(result, name)
        intr = camera_intrinsics(result, name, dataset)
        p = out / f"{_safe(name)}.yaml"
        atomic_write_via(p, lambda tmp: _write_opencv_camera(tmp, result, name, ref, T, intr), tmp_suffix=".yaml")
        paths.append(p)
    return paths


def _write_opencv_camera(tmp: Path, result: dict, name: str, ref: str, T: np.ndarray, intr) -> None:
    """One camera's OpenCV FileStorage YAML (pose, 1-sigma, covariance, intrinsics) written to ``tmp``."""
    import cv2

    cam = result["cameras"][name]
    fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise OSError(f"cannot open an OpenCV FileStorage file at {tmp}")
    for line in _header_lines(result):
        fs.writeComment(line)
    fs.write("camera_name", str(name))
    fs.write("frame_parent", ref)
    fs.write("frame_child", f"{_safe(name)}_optical_frame")
    if intr is not None:
        fs.writeComment("camera_matrix in pixels; distortion OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6]]")
        fs.write("image_width", int(intr.width_px))
        fs.write("image_height", int(intr.height_px))
        fs.write("camera_matrix", intr.K)
        fs.write("distortion_coefficients", intr.dist.reshape(1, -1))
    else:
        fs.writeComment("intrinsics unknown: the result has no 'intrinsics' for this camera and no dataset was given")
    fs.writeComment(f"T_{ref}_cam: 4x4, metres; maps optical-frame points into the {ref} frame")
    fs.write(f"T_{ref}_cam", T)
    fs.writeComment(f"1-sigma: translation in mm and rotation in deg, both along the {ref} frame axes")
    fs.write("sigma_translation_mm", np.asarray(cam.get("sigma_translation_mm", [np.nan] * 3), float).reshape(1, 3))
    fs.write("sigma_rotation_deg", np.asarray(cam.get("sigma_rotation_deg", [np.nan] * 3), float).reshape(1, 3))
    if "covariance" in cam:
        fs.writeComment(f"covariance: 6x6, rotation first (rad) then translation (m), {ref} frame axes")
        fs.write("covariance", np.asarray(cam["covariance"], float))
    if "reprojection_rms_px" in cam:
        fs.write("reprojection_rms_px", float(cam["reprojection_rms_px"]))
    fs.release()


def read_opencv_yaml(path) -> dict:
    """Read back a file written by :func:`write_opencv_yaml` (matrices as numpy arrays)."""
    import cv2

    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise InputError(f"{path}: cannot open as an OpenCV FileStorage file.")
    out = {}
    root = fs.root()
    for key in root.keys():
        node = fs.getNode(key)
        if node.isString():
            out[key] = node.string()
        elif node.isInt():
            out[key] = int(node.real())
        elif node.isReal():
            out[key] = node.real()
        else:
            out[key] = node.mat()
    fs.release()
    return out


def export(result: dict, fmt: str, out_dir, dataset=None, parent: str | None = None) -> list:
    """Write ``result`` in format ``fmt`` (one of FORMATS) into ``out_dir``; returns written paths."""
    out = output_folder(out_dir, "export folder")
    if fmt == "urdf":
        paths = [write_urdf(result, out / "calibgraph_cameras.urdf.xacro", parent=parent)]
        return paths + (write_robot_exports(result, out) if result.get("robot") else [])
    if fmt == "robot":
        if not result.get("robot"):
            raise InputError("export: --format robot needs a result solved with --estimate-kinematics joint-offsets "
                             "(it has no 'robot' section).")
        return write_robot_exports(result, out)
    if fmt == "ros2-launch":
        return [write_ros2_launch(result, out / "calibgraph_cameras.launch.py", parent=parent)]
    if fmt == "opencv-yaml":
        return write_opencv_yaml(result, out, dataset=dataset)
    if fmt == "yaml":
        return [write_result(result, out / "result.yaml")]
    if fmt == "json":
        return [write_result(result, out / "result.json")]
    raise InputError(f"export: unknown format {fmt!r}; choose one of {', '.join(FORMATS)}.")


def write_robot_exports(result: dict, out_dir) -> list:
    """``<model>_corrected.urdf`` and ``joint_offsets.yaml`` from the result's ``robot`` section.

    The URDF is the arm's model (the built-in Franka chain, or the URDF the solve used: geometry,
    inertia and limits kept, only the joint origins change) with the offsets folded into the joint
    origins. Joints held fixed (gauges) have offset 0 and are left as they are."""
    import yaml

    rb = result["robot"]
    o = np.asarray(rb["joint_offsets_rad"], float)
    source = rb.get("model_source") or (result.get("solver", {}).get("settings", {}) or {}).get("kinematics_model") or "franka"
    try:
        chain = load_chain(str(source))
    except InputError as e:
        raise InputError(f"export: cannot read the arm's kinematic model the result was solved with ({e}); run the export "
                         "where that URDF is, or solve again.") from None
    if chain.n_joints != o.size:
        raise InputError(f"export: the result has {o.size} joint offsets but the model {source!r} has {chain.n_joints} joints.")
    out = Path(out_dir)
    name = _safe(str(rb.get("model") or chain.name))
    urdf = out / f"{name}_corrected.urdf"
    text = corrected_urdf(chain, o)
    if text.startswith("<?xml"):
        text = text.split("?>", 1)[1].lstrip("\n")
    note = (f"<!-- Generated by calibgraph {_version()}: the arm's kinematic model with the estimated joint zero offsets "
            "folded into the joint origins (each origin turned by its offset about the joint axis), so the FK of the "
            f"angles the controller reports is the calibrated flange pose. Offsets (rad): {' '.join(_r(x) for x in o)}. "
            "Units: metres, radians. -->\n")
    atomic_write_text(urdf, '<?xml version="1.0"?>\n' + note + text)
    sig = rb.get("joint_offsets_sigma_rad") or [None] * o.size
    doc = {
        "model": rb.get("model"),
        "model_source": str(source),
        "joint_names": list(rb.get("joint_names") or chain.joint_names),
        "joint_offsets_rad": [float(x) for x in o],
        "joint_offsets_sigma_rad": [None if x is None else float(x) for x in sig],
        "fixed_joints": [int(f["joint"]) for f in rb.get("fixed", [])],
        "convention": "physical joint angle = reported (encoder) angle + joint_offsets_rad[i]; a controller that "
                      "corrects its readings adds the offsets (and subtracts them from commanded angles)",
    }
    head = (f"# calibgraph {_version()} joint zero offsets of the arm (dataset {result.get('dataset') or 'n/a'}).\n"
            "# Units: radians. 1-sigma null: held fixed (a gauge the cameras or the board mount absorb).\n")
    yml = out / "joint_offsets.yaml"
    atomic_write_text(yml, head + yaml.safe_dump(doc, sort_keys=False))
    return [urdf, yml]


# -- small helpers -------------------------------------------------------------------------------
def _r(v: float) -> str:
    """Full precision (round-trips exactly through float())."""
    return repr(float(v))


def _fmt3(v) -> str:
    return "[" + ", ".join(f"{float(x):.3g}" for x in v) + "]"


