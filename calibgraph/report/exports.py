"""Write a calibration result in the formats a robot stack reads.

Every exporter takes a :class:`~calibgraph.solver.output.result.Result` (``calibgraph.load_result`` reads
one from result.json; a result dict is converted), so they work from the file alone:

- :func:`write_result` -- result.json / result.yaml (same content; ``--format yaml``);
- :func:`write_urdf` -- a plain URDF (``calibgraph_cameras.urdf``) and a xacro to include into the
  robot's (``calibgraph_cameras.urdf.xacro``, parent link ``$(arg parent)``), one fixed joint per camera
  ``<parent> -> <camera>_optical_frame`` (``xyz`` in m, ``rpy`` in rad, URDF fixed-axis
  roll-pitch-yaw: ``R = Rz(yaw) Ry(pitch) Rx(roll)``);
- :func:`write_ros2_launch` -- a ROS 2 Python launch file with one ``tf2_ros``
  ``static_transform_publisher`` per camera (translation + quaternion x y z w);
- :func:`write_opencv_yaml` -- one OpenCV FileStorage YAML per camera with ``camera_matrix``,
  ``distortion_coefficients``, ``image_width/height``, ``T_<ref>_cam`` and its sigmas/covariance.
- :func:`write_camera_info` -- one ROS camera_info YAML per camera (``camera_calibration``'s format,
  which ``camera_info_manager`` loads from a driver's ``camera_info_url``): the intrinsics the camera
  was solved with.

- :func:`write_robot_exports` -- when the result has a ``robot`` section (solved with
  ``--estimate-kinematics joint-offsets``): ``<model>_corrected.urdf``, the arm's URDF with each joint
  origin turned by its offset about the joint axis (so the controller's FK of the encoder angles is
  the true flange pose), and ``joint_offsets.yaml`` for the controller. ``--format urdf`` writes them
  beside the camera snippet; ``--format robot`` writes only them.

Frames: the parent frame is the robot base (eye-to-hand: ``T_base_cam``) or the flange
(eye-in-hand: ``T_flange_cam``); the child is the camera's OpenCV optical frame (x right, y down,
z forward), which is what ROS calls ``<camera>_optical_frame``. Every file states the frames
and units in comments or fields.

Intrinsics are those the camera was solved with when the result records them, else the dataset's
given with ``dataset=``, and then every file says so (:func:`given_intrinsics_note`: an old result
does not say which intrinsics its pose was solved with, and estimated ones differ). Camera names
become ROS/URDF identifiers (:func:`export_names`): unique even when two names sanitise alike, so no
link, joint or file is written twice.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.kinematics import corrected_urdf
from calibgraph.core.transforms import R_to_quat_xyzw
from calibgraph.core.version import __version__
from calibgraph.io.files import atomic_write_text, atomic_write_via, output_folder, read_opencv_storage
from calibgraph.io.layouts import as_dataset
from calibgraph.solver.robot.kinematics import stored_arm
from calibgraph.solver.output.result import as_result

FORMATS = ("urdf", "ros2-launch", "opencv-yaml", "camera-info", "yaml", "json", "robot")

# the parent frame every export names (URDF, xacro, ROS 2 launch, OpenCV YAML) unless --parent says another
DEFAULT_PARENT = {"base": "base_link", "flange": "flange"}
URDF_NAMES = ("calibgraph_cameras.urdf", "calibgraph_cameras.urdf.xacro")  # --format urdf: plain URDF, xacro
RESERVED_FILE_STEMS = ("result", "joint_offsets")  # file names other exports write into the same folder


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


# -- names ------------------------------------------------------------------------------------------
def _safe(name: str) -> str:
    """A ROS/URDF-safe identifier from a camera name."""
    s = re.sub(r"[^A-Za-z0-9_]", "_", str(name))
    return s if s and not s[0].isdigit() else f"cam_{s}"


def export_names(result) -> dict:
    """camera -> its identifier in the exported files (frame, link, joint and file names): the name
    made ROS/URDF-safe; names that become the same (``cam-1`` and ``cam_1``, or names differing only
    in non-ASCII letters) each get a suffix from a hash of the original, so no two cameras share a
    link or a file."""
    safe = {n: _safe(n) for n in result.cameras}
    count = {}
    for s in safe.values():
        count[s] = count.get(s, 0) + 1
    return {n: s if count[s] == 1 else f"{s}_{hashlib.sha1(str(n).encode()).hexdigest()[:6]}" for n, s in safe.items()}


def renamed(result) -> dict:
    """camera -> exported identifier, for the cameras whose name had to change beyond making it safe."""
    return {n: s for n, s in export_names(result).items() if s != _safe(n)}


def camera_intrinsics(result, name: str, dataset=None):
    """Intrinsics of camera ``name``: those it was solved with, else the dataset's, else None."""
    intr = result.cameras[name].solved_intrinsics
    if intr is not None:
        return intr
    ds = as_dataset(dataset)
    if ds is not None and name in ds.cameras:
        return ds.cameras[name]
    return None


def given_intrinsics_note(result, name: str, dataset) -> str:
    """'' when camera ``name``'s exported intrinsics are those the result records it was solved
    with; else the line every file that carries the dataset's instead says (the result predates
    their record, so what the pose was solved with is not known: estimated ones differ)."""
    if result.cameras[name].solved_intrinsics is not None:
        return ""
    where = dataset if isinstance(dataset, (str, Path)) else getattr(dataset, "root", "given")
    return (f"these intrinsics are the GIVEN values of the dataset {where} (its dataset.yaml), not intrinsics this "
            "result records: the result does not say which intrinsics its pose was solved with (if they were "
            "estimated, they differ from these); re-solve the dataset to export the ones it used")


def _header_lines(result) -> list:
    ref = result.ref_frame
    lines = [
        f"Generated by calibgraph {__version__} from a calibgraph result "
        f"(mode {result.mode}, method {result.method}, dataset {result.dataset or 'n/a'}).",
        f"Frames: parent = robot {ref} frame; child = <camera>_optical_frame (OpenCV optical: x right, y down, z forward).",
        f"The transform is T_{ref}_cam: it maps points from the camera optical frame to the {ref} frame (p_{ref} = T @ p_cam).",
        "Units: translation metres, angles radians, quaternion (x, y, z, w); a name ending in _mm or _deg is in mm or degrees.",
    ]
    for name, why in result.not_calibrated.items():
        lines.append(f"Camera {name!r} is not in this file: it was not calibrated ({why}).")
    changed = renamed(result)
    if changed:
        lines.append("Camera names that sanitise to the same identifier were made unique: "
                     + ", ".join(f"{n!r} -> {s}" for n, s in changed.items()) + ".")
    return lines


# -- writers -------------------------------------------------------------------------------------
def write_result(result, out_path) -> Path:
    """result.json or result.yaml (by extension), atomically (:meth:`Result.save`)."""
    return as_result(result, "export").save(out_path)


def urdf_snippet(result, parent: str | None = None, xacro: bool = True) -> str:
    """URDF text with one fixed joint and one link per camera: with ``xacro`` a xacro to include into
    the robot's own (the parent link is its ``parent`` argument, default ``parent``); without it a
    plain, complete URDF (the parent link declared, the cameras fixed to it: ``check_urdf``, RViz and
    any URDF reader take it as it is)."""
    result = as_result(result, "export")
    ref = result.ref_frame
    parent = parent or DEFAULT_PARENT[ref]
    ids = export_names(result)
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
        lines.append(f"  <!-- the parent link, declared so that this file is a whole URDF; merging into the robot's URDF, "
                     f"drop it (or include {URDF_NAMES[1]}) -->")
        lines.append(f'  <link name="{parent}"/>')
    for name, cam in result.calibrated.items():
        T = cam.T_ref_cam
        xyz = T[:3, 3]
        rpy = R_to_rpy(T[:3, :3])
        child = f"{ids[name]}_optical_frame"
        par = "$(arg parent)" if xacro else parent
        lines.append(f"  <!-- camera {str(name).replace('--', '- -')}: 1-sigma translation (mm, {ref} axes) "
                     f"{_fmt3(cam.sigma_translation_mm)}; rotation (deg, {ref} axes) {_fmt3(cam.sigma_rotation_deg)} -->")
        lines.append(f'  <link name="{child}"/>')
        lines.append(f'  <joint name="{ids[name]}_optical_joint" type="fixed">')
        lines.append(f'    <parent link="{par}"/>')
        lines.append(f'    <child link="{child}"/>')
        lines.append(f'    <origin xyz="{_r(xyz[0])} {_r(xyz[1])} {_r(xyz[2])}" rpy="{_r(rpy[0])} {_r(rpy[1])} {_r(rpy[2])}"/>')
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines) + "\n"


def write_urdf(result, out_path, parent: str | None = None, xacro: bool = True) -> Path:
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


def ros2_launch_text(result, parent: str | None = None) -> str:
    """A ROS 2 Python launch file publishing every camera's pose as a static transform."""
    result = as_result(result, "export")
    ref = result.ref_frame
    parent = parent or DEFAULT_PARENT[ref]
    ids = export_names(result)
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
    for name, cam in result.calibrated.items():
        T = cam.T_ref_cam
        q = R_to_quat_xyzw(T[:3, :3])
        t = T[:3, 3]
        vals = ", ".join(_r(v) for v in (*t, *q))
        lines.append(f'    {str(name)!r}: ({vals}, {parent!r}, {ids[name] + "_optical_frame"!r}),')
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


def write_ros2_launch(result, out_path, parent: str | None = None) -> Path:
    """Write :func:`ros2_launch_text` to ``out_path`` (e.g. ``calibgraph_cameras.launch.py``)."""
    p = Path(out_path)
    atomic_write_text(p, ros2_launch_text(result, parent=parent))
    return p


def write_opencv_yaml(result, out_dir, dataset=None, parent: str | None = None) -> list:
    """One OpenCV FileStorage YAML per camera (``<out_dir>/<camera>.yaml``); returns the paths.

    Fields: ``camera_name``, ``image_width``, ``image_height``, ``camera_matrix`` (3x3, px),
    ``distortion_coefficients`` (1xN, OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6]]),
    ``T_<ref>_cam`` (4x4, m), ``sigma_translation_mm`` (1x3), ``sigma_rotation_deg`` (1x3),
    ``covariance`` (6x6, rotation first, rad and m, in the ref frame's axes), ``reprojection_rms_px``;
    ``frame_parent``: ``parent`` (default :data:`DEFAULT_PARENT`, as the URDF and launch exports name it).
    A camera without known intrinsics gets the pose fields only and a comment saying so. The file
    is named by the camera's :func:`export_names` identifier (``camera_<id>.yaml`` when that would
    be the name of another export: result, joint_offsets).
    """
    result = as_result(result, "export")
    paths = []
    for out, name, ident, intr, given in _calibrated_cameras(result, out_dir, dataset):
        stem = ident if ident not in RESERVED_FILE_STEMS else f"camera_{ident}"
        p = out / f"{stem}.yaml"
        atomic_write_via(p, lambda tmp: _write_opencv_camera(tmp, result, name, ident, intr, given, parent),
                         tmp_suffix=".yaml")
        paths.append(p)
    return paths


def _calibrated_cameras(result, out_dir, dataset=None):
    """(export folder, camera name, its export identifier, its intrinsics or None, '' or the
    :func:`given_intrinsics_note` when they are the dataset's) of each calibrated camera of
    ``result`` (a :class:`~calibgraph.solver.output.result.Result`), the folder made first."""
    out = output_folder(out_dir, "export folder")
    ids = export_names(result)
    for name in result.calibrated:
        intr = camera_intrinsics(result, name, dataset)
        yield out, name, ids[name], intr, given_intrinsics_note(result, name, dataset) if intr is not None else ""


def _write_opencv_camera(tmp: Path, result, name: str, ident: str, intr, given: str = "", parent=None) -> None:
    """One camera's OpenCV FileStorage YAML (pose, 1-sigma, covariance, intrinsics) written to ``tmp``."""
    import cv2

    cam = result.cameras[name]
    ref, T = result.ref_frame, cam.T_ref_cam
    fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
    if not fs.isOpened():
        raise OSError(f"cannot open an OpenCV FileStorage file at {tmp}")
    for line in _header_lines(result):
        fs.writeComment(line)
    fs.write("camera_name", str(name))
    fs.write("frame_parent", parent or DEFAULT_PARENT[ref])  # the frame T_<ref>_cam is in, as the URDF names it
    fs.write("frame_child", f"{ident}_optical_frame")
    if intr is not None:
        if given:
            fs.writeComment(f"NOTE: {given}.")
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
    fs.write("sigma_translation_mm", cam.sigma_translation_mm.reshape(1, 3))
    fs.write("sigma_rotation_deg", cam.sigma_rotation_deg.reshape(1, 3))
    fs.writeComment(f"covariance: 6x6, rotation first (rad) then translation (m), {ref} frame axes")
    fs.write("covariance", cam.covariance)
    fs.write("reprojection_rms_px", float(cam.reprojection_rms_px))
    fs.release()


def write_camera_info(result, out_dir, dataset=None) -> list:
    """One ROS camera_info YAML per calibrated camera with known intrinsics
    (``<out_dir>/<camera>_camera_info.yaml``): ``image_width``, ``image_height``, ``camera_name``,
    ``camera_matrix``, ``distortion_model`` (``plumb_bob`` for up to 5 coefficients,
    ``rational_polynomial`` for 8), ``distortion_coefficients``, ``rectification_matrix`` (identity)
    and ``projection_matrix`` ([K | 0]: a monocular camera). Returns the paths; a camera without known
    intrinsics gets no file (and a result with none is refused)."""
    import yaml

    result = as_result(result, "export")
    paths = []
    for out, name, ident, intr, given in _calibrated_cameras(result, out_dir, dataset):
        if intr is None:
            continue
        dist = intr.dist8 if intr.dist.size > 5 else intr.dist8[:5]
        doc = {"image_width": int(intr.width_px), "image_height": int(intr.height_px), "camera_name": ident,
               "camera_matrix": _ros_matrix(intr.K),
               "distortion_model": "rational_polynomial" if dist.size == 8 else "plumb_bob",
               "distortion_coefficients": _ros_matrix(dist.reshape(1, -1)),
               "rectification_matrix": _ros_matrix(np.eye(3)),
               "projection_matrix": _ros_matrix(np.hstack([intr.K, np.zeros((3, 1))]))}
        head = "".join(f"# {line}\n" for line in _header_lines(result)[:1]) + (
            f"# ROS camera_info (camera_calibration format): {given}\n" if given else
            "# ROS camera_info (camera_calibration format): the intrinsics calibgraph solved this camera with\n")
        p = out / f"{ident}_camera_info.yaml"
        atomic_write_text(p, head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120))
        paths.append(p)
    if not paths:
        raise InputError("export: --format camera-info needs cameras with known intrinsics; the result records none "
                         "(give the dataset with --dataset).")
    return paths


def _ros_matrix(M: np.ndarray) -> dict:
    """A matrix as ROS camera_info YAML writes one: ``{rows, cols, data}`` (row-major)."""
    return {"rows": int(M.shape[0]), "cols": int(M.shape[1]), "data": [float(v) for v in M.ravel()]}


def read_opencv_yaml(path) -> dict:
    """Read back a file written by :func:`write_opencv_yaml` (matrices as numpy arrays)."""
    return read_opencv_storage(path, "OpenCV YAML")


def export(result, fmt: str, out_dir, dataset=None, parent: str | None = None) -> list:
    """Write ``result`` (a :class:`~calibgraph.solver.output.result.Result`) in format ``fmt`` (one of
    FORMATS) into ``out_dir``; returns written paths."""
    result = as_result(result, "export")
    out = output_folder(out_dir, "export folder")
    if fmt == "urdf":
        paths = [write_urdf(result, out / URDF_NAMES[1], parent=parent),
                 write_urdf(result, out / URDF_NAMES[0], parent=parent, xacro=False)]
        return paths + (write_robot_exports(result, out) if result.robot else [])
    if fmt == "robot":
        if not result.robot:
            raise InputError("export: --format robot needs a result solved with --estimate-kinematics joint-offsets "
                             "(it has no 'robot' section).")
        return write_robot_exports(result, out)
    if fmt == "ros2-launch":
        return [write_ros2_launch(result, out / "calibgraph_cameras.launch.py", parent=parent)]
    if fmt == "opencv-yaml":
        return write_opencv_yaml(result, out, dataset=dataset, parent=parent)
    if fmt == "camera-info":
        return write_camera_info(result, out, dataset=dataset)
    if fmt == "yaml":
        return [write_result(result, out / "result.yaml")]
    if fmt == "json":
        return [write_result(result, out / "result.json")]
    raise InputError(f"export: unknown format {fmt!r}; choose one of {', '.join(FORMATS)}.")


def write_robot_exports(result, out_dir) -> list:
    """``<model>_corrected.urdf`` and ``joint_offsets.yaml`` from the result's ``robot`` section.

    The URDF is the arm's model (the built-in Franka chain, or the URDF the solve used: geometry,
    inertia and limits kept, only the joint origins change) with the offsets folded into the joint
    origins. Joints held fixed (gauges) have offset 0 and are left as they are."""
    import yaml

    result = as_result(result, "export")
    rb = result.robot
    chain, o, source = stored_arm(result, "export")
    out = Path(out_dir)
    name = _safe(str(rb.get("model") or chain.name))
    urdf = out / f"{name}_corrected.urdf"
    text = corrected_urdf(chain, o)
    if text.startswith("<?xml"):
        text = text.split("?>", 1)[1].lstrip("\n")
    note = (f"<!-- Generated by calibgraph {__version__}: the arm's kinematic model with the estimated joint zero offsets "
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
    head = (f"# calibgraph {__version__} joint zero offsets of the arm (dataset {result.dataset or 'n/a'}).\n"
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


