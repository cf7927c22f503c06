"""Readers for peer projects' dataset layouts, so ``calibgraph solve DIR`` runs on them as they are.

industrial_calibration / robot_cal_tools (RCT) layout::

    DIR/
      cal_data.yaml     data: [{image: images/0.png, pose: poses/0.yaml}, ...]
                        intrinsics: {fx, fy, cx, cy}          (no distortion: RCT ignores it)
                        target_finder: {type: CharucoGridTargetFinder | ModifiedCircleGridTargetFinder, ...}
                        static_camera: true                   (true = eye-to-hand, target on the wrist)
                        homography_threshold, camera_mount_to_camera_guess, target_mount_to_target_guess
      images/N.png
      poses/N.yaml      base -> tool0 as x, y, z (m) and qx, qy, qz, qw (any key order)

Conventions mapped (read from the peer's code, examples/extrinsic_hand_eye.cpp and the target
finders): each pose is ``T_base_tool0`` (``p_base = T @ p_tool0``), our ``T_base_flange``. With
``static_camera: true`` the pose moves the *target* mount (eye-to-hand), otherwise the camera mount
(eye-in-hand). ``CharucoGridTargetFinder`` builds ``cv::aruco::CharucoBoard::create(cols, rows,
chessboard_dim, aruco_marker_dim, dictionary)``: ``cols``/``rows`` count *squares*; its target
points are OpenCV's ``chessboardCorners`` (origin at the outer board corner), which is exactly
calibgraph's ChArUco frame. ``ModifiedCircleGridTargetFinder`` (rows, cols, spacing) numbers dots
row by row from the top of the printed page with the big origin dot at the bottom-left and
``y`` pointing up, which is calibgraph's ``modified_circles`` frame. The target finder may also be
given as the name of a YAML file next to ``cal_data.yaml`` (newer peer versions), and plugin names
such as ``industrial_calibration::CharucoGridTargetFinderPlugin`` are accepted.

Multi-Camera-Hand-Eye-Calibration datasets are read by ``calibgraph.io.peer_mchec`` when present.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.problem import Capture
from calibgraph.core.targets import Target
from calibgraph.core.transforms import check_pose, make_T, quat_xyzw_to_R
from calibgraph.io.checks import image_size
from calibgraph.io.dataset import Dataset, View
from calibgraph.io.files import read_yaml


def is_rct_dataset(root) -> bool:
    """True when ``root`` holds an industrial_calibration / RCT ``cal_data.yaml``."""
    return (Path(root) / "cal_data.yaml").is_file()


def _finder_type(name: str) -> str:
    t = str(name).split("::")[-1]
    return t[: -len("Plugin")] if t.endswith("Plugin") else t


def rct_target(cfg: dict, where: str = "target_finder"):
    """calibgraph :class:`Target` from an industrial_calibration ``target_finder`` mapping."""

    if not isinstance(cfg, dict) or "type" not in cfg:
        raise InputError(f"{where}: needs a mapping with a 'type' (CharucoGridTargetFinder or ModifiedCircleGridTargetFinder).")
    kind = _finder_type(cfg["type"])

    def get(key, conv=float):
        if key not in cfg:
            raise InputError(f"{where}: {kind} needs '{key}'.")
        try:
            return conv(cfg[key])
        except (TypeError, ValueError):
            raise InputError(f"{where}: '{key}' = {cfg[key]!r} is not a number.") from None

    if kind == "CharucoGridTargetFinder":
        squares_y, squares_x = get("rows", int), get("cols", int)
        # The peer built boards with cv::aruco::CharucoBoard::create (OpenCV < 4.6 layout); the
        # layouts differ only for an even number of square rows.
        return Target(kind="charuco", rows=squares_y - 1, cols=squares_x - 1, pitch_m=get("chessboard_dim"),
                      marker_m=get("aruco_marker_dim"), dictionary=get("dictionary", int), legacy_charuco=True)
    if kind == "ModifiedCircleGridTargetFinder":
        return Target(kind="modified_circles", rows=get("rows", int), cols=get("cols", int), pitch_m=get("spacing"))
    raise InputError(
        f"{where}: target finder type {cfg['type']!r} is not supported; calibgraph reads CharucoGridTargetFinder "
        "and ModifiedCircleGridTargetFinder (write a calibgraph target spec for other boards).")


def read_rct_pose(path) -> np.ndarray:
    """``T_base_tool0`` (4x4) from an RCT pose file (x, y, z, qx, qy, qz, qw in any order)."""

    p = Path(path)
    d = read_yaml(p, "pose file", mapping=False)
    keys = ("x", "y", "z", "qx", "qy", "qz", "qw")
    if not isinstance(d, dict) or any(k not in d for k in keys):
        raise InputError(f"{p}: pose file needs keys {', '.join(keys)} (base -> tool0, metres and unit quaternion).")
    try:
        v = {k: float(d[k]) for k in keys}
    except (TypeError, ValueError):
        raise InputError(f"{p}: pose values must be numbers.") from None
    q = np.array([v["qx"], v["qy"], v["qz"], v["qw"]])
    nq = np.linalg.norm(q)
    if not np.isfinite(nq) or abs(nq - 1.0) > 1e-3:
        raise InputError(f"{p}: quaternion norm is {nq:.6f}; expected a unit quaternion.")
    T = make_T(quat_xyzw_to_R(q / nq), [v["x"], v["y"], v["z"]])
    return check_pose(T, str(p))


def load_rct_dataset(root):
    """Read an industrial_calibration / RCT dataset folder as a :class:`calibgraph.io.dataset.Dataset`
    (one camera named ``camera``; views carry no detections, so they are detected on demand).
    Unreadable pose files are listed in ``Dataset.problems`` and skipped."""

    root = Path(root)
    cfg_path = root / "cal_data.yaml"
    cfg = read_yaml(cfg_path, "calibration config")
    tf = cfg.get("target_finder")
    if isinstance(tf, str):
        tf = read_yaml(root / tf, "the target finder file", mapping=False)
    elif tf is None and (root / "target_finder.yaml").is_file():
        tf = read_yaml(root / "target_finder.yaml", "the target finder file", mapping=False)
    if tf is None:
        raise InputError(f"{cfg_path}: no target_finder section (nor target_finder.yaml); cannot know the board.")
    target = rct_target(tf, f"{cfg_path}: target_finder")

    intr_d = cfg.get("intrinsics")
    if intr_d is None:
        for name in ("camera_intr.yaml", "camera_intr_nominal.yaml"):
            if (root / name).is_file():
                intr_d = read_yaml(root / name, "camera intrinsics", empty_ok=True).get("intrinsics")
                break
    if not isinstance(intr_d, dict):
        raise InputError(f"{cfg_path}: no intrinsics (fx, fy, cx, cy) given.")

    data = cfg.get("data")
    pairs = []
    if isinstance(data, list):
        for k, e in enumerate(data):
            if not isinstance(e, dict) or "image" not in e or "pose" not in e:
                raise InputError(f"{cfg_path}: data entry {k} needs 'image' and 'pose'.")
            pairs.append((str(e["image"]), str(e["pose"])))
    else:
        # Older RCT folders: images/N.png paired with poses/N.yaml.
        for img in sorted((root / "images").glob("*.png"), key=lambda p: (len(p.stem), p.stem)):
            pose = root / "poses" / f"{img.stem}.yaml"
            if pose.is_file():
                pairs.append((f"images/{img.name}", f"poses/{pose.name}"))
    if not pairs:
        raise InputError(f"{cfg_path}: no image/pose pairs listed under 'data' (and none found in images/ + poses/).")

    size = None
    for img, _ in pairs:
        size = image_size(root / img)
        if size is not None:
            break
    if size is None:
        raise InputError(f"{root}: none of the {len(pairs)} images can be read; cannot determine the image size.")
    try:
        intr = Intrinsics.from_dict({**intr_d, "width_px": size[0], "height_px": size[1]})
    except InputError as e:
        raise InputError(f"{cfg_path}: intrinsics: {e}") from None

    captures, views, problems = [], [], []
    for k, (img, pose) in enumerate(pairs):
        try:
            T = read_rct_pose(root / pose)
        except InputError as e:
            problems.append((str(root / pose), f"{e}; capture {k} skipped"))
            continue
        captures.append(Capture(index=k, T_base_flange=T))
        views.append(View(camera="camera", capture=k, image=img))
    static = cfg.get("static_camera", True)
    if not isinstance(static, bool):
        raise InputError(f"{cfg_path}: static_camera must be true or false, got {static!r}.")
    return Dataset(root=root, target=target, cameras={"camera": intr}, captures=tuple(captures), views=tuple(views),
                   mode="eye_to_hand" if static else "eye_in_hand", solver={}, problems=tuple(problems))
