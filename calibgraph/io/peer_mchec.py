"""Reading the Multi-Camera-Hand-Eye-Calibration (MC-HEC) folder layout, the thesis's
published successor (github.com/davidea97/Multi-Camera-Hand-Eye-Calibration)::

    ROOT/
      CalibrationInfo.yaml          number_of_cameras, camera_folder_prefix (camera), pattern_type
                                    (checkerboard), number_of_rows, number_of_columns, size (m),
                                    resize_factor, visual_error, calibration_setup (0 eye-in-hand,
                                    1 eye-on-base)
      camera1/intrinsic_pars_file.yaml   fx fy cx cy has_dist_coeff dist_k0 dist_k1 dist_px dist_py
                                         dist_k2 dist_k3 dist_k4 dist_k5 img_width img_height
      camera1/image/0001.png ...    one image per robot waypoint
      camera1/pose/0001.csv ...     T_base_flange, 4x4, metres, space- or comma-separated
      camera2/...
      GT/gt_cam1.csv ...            optional ground truth T_base_cam (4x4)

Conventions, as MC-HEC's code reads them (``Reader.cpp``, ``Detector.cpp``, ``PinholeCameraModel``):

- Waypoint ``j`` is the ``j``-th file of each camera's sorted ``image/`` listing: every camera
  folder holds one image per waypoint, board visible or not. Only ``camera1``'s pose files are
  used (``poses_collected[0]``); the others are copies.
- The checkerboard is ``cv::Size(number_of_rows, number_of_columns)`` for OpenCV: ``number_of_rows``
  counts the corners along a row (calibgraph's ``cols``), ``number_of_columns`` the corners along a
  column (calibgraph's ``rows``). Corner ``k = number_of_rows * i + j`` sits at
  ``(size * j, size * i, 0)`` -- calibgraph's board frame exactly, origin at the first corner
  OpenCV's classic detector returns.
- Distortion ``dist_k0 dist_k1 dist_px dist_py dist_k2 dist_k3 dist_k4 dist_k5`` is OpenCV's
  ``k1 k2 p1 p2 k3 k4 k5 k6`` (rational model; ``px`` pairs with ``2xy`` in x like OpenCV's p1).
- ``resize_factor`` scales images and intrinsics together inside MC-HEC, so the files at their
  original size are read as they are and the factor is ignored.
- Its printed result is ``T_base_cam`` in the OpenCV optical frame (eye-on-base), as calibgraph's.

Export (:mod:`calibgraph.report.mchec_export`) writes the same layout. A capture where a camera has no image gets a black placeholder
image (so waypoint indices stay aligned across cameras); ``calibgraph_mchec.yaml`` lists the
placeholders and the original camera names so an import restores the dataset exactly. MC-HEC
only handles checkerboards, so other targets are refused.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.problem import Capture
from calibgraph.core.targets import Target
from calibgraph.core.transforms import check_pose
from calibgraph.io.dataset import Dataset, View
from calibgraph.io.files import read_input_text, read_yaml

INFO_NAME = "CalibrationInfo.yaml"
INTRINSICS_NAME = "intrinsic_pars_file.yaml"
SIDECAR_NAME = "calibgraph_mchec.yaml"  # must not start with the camera prefix: MC-HEC counts those entries
IMAGE_EXT = (".png", ".jpg", ".jpeg", ".tiff")
DIST_KEYS = ("dist_k0", "dist_k1", "dist_px", "dist_py", "dist_k2", "dist_k3", "dist_k4", "dist_k5")


def is_mchec_dataset(root) -> bool:
    """True when ``root`` holds an MC-HEC ``CalibrationInfo.yaml``."""
    return (Path(root) / INFO_NAME).is_file()


def _yaml(path: Path) -> dict:

    return read_yaml(path, "file")


def mchec_target(info: dict, where: str = INFO_NAME):
    """calibgraph :class:`~calibgraph.core.targets.Target` of an MC-HEC CalibrationInfo mapping."""

    kind = str(info.get("pattern_type", "checkerboard"))
    if kind != "checkerboard":
        raise InputError(f"{where}: pattern_type {kind!r}: MC-HEC datasets use checkerboards; calibgraph reads only those.")
    try:
        return Target(kind="checkerboard", rows=int(info["number_of_columns"]), cols=int(info["number_of_rows"]),
                      pitch_m=float(info["size"]))
    except KeyError as e:
        raise InputError(f"{where}: missing {e} (number_of_rows, number_of_columns and size are required).") from None


def read_mchec_intrinsics(path: Path):
    """:class:`~calibgraph.core.camera.Intrinsics` from an ``intrinsic_pars_file.yaml``."""

    d = _yaml(path)
    try:
        K = [[float(d["fx"]), 0.0, float(d["cx"])], [0.0, float(d["fy"]), float(d["cy"])], [0.0, 0.0, 1.0]]
        dist = [float(d.get(k, 0.0)) for k in DIST_KEYS] if int(d.get("has_dist_coeff", 1)) else [0.0] * 8
        return Intrinsics(K=K, dist=dist, width_px=int(d["img_width"]), height_px=int(d["img_height"]))
    except KeyError as e:
        raise InputError(f"{path}: missing {e}; MC-HEC intrinsics need fx fy cx cy img_width img_height.") from None
    except InputError as e:
        raise InputError(f"{path}: {e}") from None


def read_mchec_pose(path: Path) -> np.ndarray:
    """A 4x4 pose from an MC-HEC csv (space or comma separated, as its Reader accepts)."""

    try:
        rows = [re.split(r"[,\s]+", ln.strip()) for ln in read_input_text(path, "pose file").splitlines() if ln.strip()]
        T = np.array([[float(x) for x in r if x != ""] for r in rows], float)
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: not a 4x4 pose csv ({e}).") from None
    if T.shape != (4, 4):
        raise InputError(f"{path}: expected 4 rows of 4 numbers (T_base_flange in metres), got shape {T.shape}.")
    return check_pose(T, str(path))


def _sorted_files(folder: Path, exts) -> list:
    if not folder.is_dir():
        return []
    return sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in exts), key=lambda p: p.name)


def load_mchec_dataset(root):
    """Read an MC-HEC folder as a :class:`calibgraph.io.dataset.Dataset` (views carry images, no
    detections: the solver's detector finds the corners)."""

    root = Path(root)
    info = _yaml(root / INFO_NAME)
    target = mchec_target(info, str(root / INFO_NAME))
    prefix = str(info.get("camera_folder_prefix", "camera"))
    try:
        n_cams = int(info["number_of_cameras"])
    except (KeyError, ValueError, TypeError):
        raise InputError(f"{root / INFO_NAME}: number_of_cameras is required.") from None
    setup = int(info.get("calibration_setup", 1))
    if setup not in (0, 1):
        raise InputError(f"{root / INFO_NAME}: calibration_setup must be 0 (eye-in-hand) or 1 (eye-on-base), got {setup}.")
    mode = "eye_to_hand" if setup == 1 else "eye_in_hand"
    side = _yaml(root / SIDECAR_NAME) if (root / SIDECAR_NAME).is_file() else {}
    names = side.get("camera_names") or {}
    placeholders = set(side.get("placeholders") or [])
    folders = [root / f"{prefix}{k + 1}" for k in range(n_cams)]
    cameras, images = {}, {}
    for f in folders:
        if not f.is_dir():
            raise InputError(f"{f}: missing; CalibrationInfo.yaml says number_of_cameras = {n_cams} "
                             f"(folders {prefix}1..{prefix}{n_cams}).")
        name = str(names.get(f.name, f.name))
        cameras[name] = read_mchec_intrinsics(f / INTRINSICS_NAME)
        images[name] = _sorted_files(f / "image", IMAGE_EXT)
    poses = _sorted_files(folders[0] / "pose", (".csv",))
    n = len(poses)
    if n == 0:
        raise InputError(f"{folders[0] / 'pose'}: no pose csv files; MC-HEC uses camera1's poses for every camera.")
    for name, imgs in images.items():
        if len(imgs) != n:
            raise InputError(f"{root}: camera {name!r} has {len(imgs)} images but {folders[0].name}/pose has {n} poses; "
                             "MC-HEC pairs the j-th image of every camera with the j-th pose, so the counts must match.")
    stems = [p.stem for p in poses]
    indices = [int(s) for s in stems] if all(s.isdigit() for s in stems) and len(set(map(int, stems))) == n else list(range(n))
    captures, views, problems = [], [], []
    for j, (idx, pp) in enumerate(zip(indices, poses)):
        try:
            captures.append(Capture(index=idx, T_base_flange=read_mchec_pose(pp)))
        except InputError as e:
            problems.append((str(pp), f"{e}; skipped"))
            continue
        for name, imgs in images.items():
            rel = imgs[j].relative_to(root).as_posix()
            if rel in placeholders:
                continue
            views.append(View(camera=name, capture=idx, image=rel))
    return Dataset(root=root, target=target, cameras=cameras, captures=tuple(captures), views=tuple(views), mode=mode,
                   solver={}, problems=tuple(problems))


