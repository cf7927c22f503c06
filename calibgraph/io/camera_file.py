"""Camera files: one camera's intrinsics with their covariance (``calibgraph intrinsics`` writes
them; ``calibgraph solve --intrinsics NAME=CAM.yaml`` and dataset files read them).

A camera file is a YAML mapping that :meth:`calibgraph.core.camera.Intrinsics.from_dict` reads::

    format: calibgraph-camera/1
    source: calibration
    width_px: 1280
    height_px: 800
    K: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortion: {model: k1k2p1p2k3, coefficients: [k1, k2, p1, p2, k3], names: [k1, k2, p1, p2, k3]}
    sigma: {fx: px, fy: px, cx: px, cy: px, k1: ., k2: ., p1: ., p2: ., k3: .}
    covariance_order: [fx, fy, cx, cy, k1, k2, p1, p2, k3]
    covariance: [[...], ...]          # rows and columns in covariance_order
    rms_px: ...                       # RMS reprojection error of the corners used
    views_used: 23
    ...                               # views used and rejected (with reasons), coverage, warnings

Only ``K`` (or fx, fy, cx, cy), ``width_px``/``height_px``, ``distortion`` and ``source`` are needed
to use it; ``covariance`` (with ``covariance_order``) makes it the camera's prior in the joint graph.

:func:`read_camera_file` also reads the intrinsics files other tools write (no covariance: the
solver's prior for their source, ``--intrinsics-source``, applies):

- a ROS camera_info YAML (``camera_calibration``'s ``image_width``, ``camera_matrix: {rows, cols,
  data}``, ``distortion_model``, ``distortion_coefficients``), or a ROS 2 CameraInfo message dump
  (``width``, ``height``, ``k``, ``d``, ``distortion_model``);
- an OpenCV FileStorage file (``%YAML:1.0`` or XML: ``camera_matrix``, ``distortion_coefficients``,
  ``image_width``, ``image_height``), as OpenCV's calibration samples and ``calibgraph export
  --format opencv-yaml`` write;
- a Kalibr camchain or camera YAML with one pinhole camera (``intrinsics: [fu, fv, pu, pv]``,
  ``distortion_model: radtan | none``, ``distortion_coeffs``, ``resolution: [w, h]``).

Fisheye models (ROS ``equidistant``, Kalibr ``equidistant`` / ``fov``) are refused: the engine models
OpenCV's pinhole with radial-tangential distortion.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.io.files import atomic_write_text, is_opencv_storage, parse_yaml, read_input_bytes, read_opencv_storage


def write_camera_file(path, content: dict) -> Path:
    """Write a camera file atomically; ``content`` must load back through ``Intrinsics.from_dict``
    (checked before anything is written). Returns the path."""
    import yaml

    try:
        Intrinsics.from_dict(content)
    except CalibgraphError as e:
        raise InputError(f"{path}: refusing to write a camera file that would not load back: {e}") from None
    head = ("# calibgraph camera file: intrinsics (OpenCV model) with their covariance; "
            "covariance rows follow covariance_order (px, unitless)\n")
    return atomic_write_text(path, head + yaml.safe_dump(_plain(content), sort_keys=False, default_flow_style=None,
                                                         width=120))


def read_camera_file(path) -> Intrinsics:
    """The :class:`Intrinsics` of a camera file (or any intrinsics YAML ``Intrinsics.from_dict`` reads,
    or a ROS camera_info, OpenCV FileStorage or Kalibr file: see the module's docstring); a malformed
    file is refused naming it."""
    p = Path(path)
    raw = read_input_bytes(p, "camera file")
    if is_opencv_storage(raw):
        d = _from_opencv(p, read_opencv_storage(p, "camera file", raw))
    else:
        d = parse_yaml(raw, p, "camera file")
        d = _from_ros(p, d) if _is_ros(d) else _from_kalibr(p, d) if _kalibr_camera(d) is not None else d
    _refuse_other_files(p, d)
    try:
        return Intrinsics.from_dict(d)
    except CalibgraphError as e:
        raise InputError(f"{p}: {e}") from None
    except (TypeError, ValueError) as e:
        raise InputError(f"{p}: not a camera file ({e}); it needs K (3x3) or fx, fy, cx, cy, and width_px, "
                         "height_px.") from None


def _refuse_other_files(p: Path, d) -> None:
    """A workcell or a dataset header given where a camera file belongs is said as such, with where
    it goes (not as a camera file missing 'fx')."""
    if not isinstance(d, dict) or any(k in d for k in ("K", "fx", "camera_matrix")):
        return
    if str(d.get("format", "")).startswith("calibgraph-dataset"):
        raise InputError(f"{p}: this is a dataset's header (dataset.yaml), not a camera file: give the dataset folder "
                         "to solve; --intrinsics NAME=FILE takes one camera's file (calibgraph intrinsics --out writes "
                         "one).")
    keys = [k for k in ("cameras", "robot", "board", "safety", "mount") if k in d]
    if keys:
        raise InputError(f"{p}: this is a workcell file (it has {', '.join(k + ':' for k in keys)}), not a camera file: "
                         "a workcell goes to --workcell (capture, sim, intrinsics --live); --intrinsics NAME=FILE takes "
                         "one camera's file (calibgraph intrinsics --out writes one, e.g. intrinsics --live --camera "
                         f"NAME --workcell {p} --out NAME.yaml).")


# distortion models other tools name -> True when calibgraph's OpenCV model carries them
_PINHOLE_MODELS = {"plumb_bob": True, "rational_polynomial": True, "radtan": True, "none": True, "": True,
                   "equidistant": False, "fisheye": False, "fov": False, "kannala_brandt": False}


def _check_model(p: Path, model, where: str) -> None:
    m = str(model or "").strip().lower()
    if not _PINHOLE_MODELS.get(m, False):
        raise InputError(f"{p}: {where} distortion model {model!r} is not supported: calibgraph models OpenCV's "
                         "pinhole with radial-tangential distortion (plumb_bob / radtan, rational_polynomial); "
                         "calibrate the camera with that model (calibgraph intrinsics does).")


def _numbers(p: Path, x, what: str, n=None) -> list:
    """A flat list of numbers from a list or a ROS/OpenCV matrix mapping ``{rows, cols, data}``."""
    if isinstance(x, dict):
        x = x.get("data")
    try:
        v = np.asarray(x if x is not None else [], float).reshape(-1)
    except (TypeError, ValueError):
        raise InputError(f"{p}: {what} is not a list of numbers.") from None
    if n is not None and v.size != n:
        raise InputError(f"{p}: {what} has {v.size} numbers, expected {n}.")
    return v.tolist()


def _is_ros(d: dict) -> bool:
    return ("camera_matrix" in d and "image_width" in d) or ("k" in d and "width" in d and "height" in d)


def _from_ros(p: Path, d: dict) -> dict:
    """A ROS camera_info YAML (or a ROS 2 CameraInfo message dump) as ``Intrinsics.from_dict`` reads it."""
    _check_model(p, d.get("distortion_model", "plumb_bob"), "ROS camera_info")
    if "camera_matrix" in d:
        K = _numbers(p, d["camera_matrix"], "camera_matrix", 9)
        dist = _numbers(p, d.get("distortion_coefficients"), "distortion_coefficients")
        w, h = d.get("image_width"), d.get("image_height")
    else:
        K = _numbers(p, d["k"], "k", 9)
        dist = _numbers(p, d.get("d"), "d")
        w, h = d.get("width"), d.get("height")
    return {"K": np.reshape(K, (3, 3)).tolist(), "dist": dist, "width_px": w, "height_px": h}


def _from_opencv(p: Path, d: dict) -> dict:
    """An OpenCV FileStorage camera file as ``Intrinsics.from_dict`` reads it."""
    if d.get("camera_matrix") is None:
        raise InputError(f"{p}: an OpenCV FileStorage file without a camera_matrix; not a camera's intrinsics.")
    K = np.asarray(d["camera_matrix"], float)
    if K.shape != (3, 3):
        raise InputError(f"{p}: camera_matrix is {K.shape[0]}x{K.shape[1] if K.ndim > 1 else 1}, expected 3x3.")
    dist = d.get("distortion_coefficients", d.get("dist_coeffs"))
    return {"K": K.tolist(), "dist": [] if dist is None else np.asarray(dist, float).reshape(-1).tolist(),
            "width_px": d.get("image_width", 0), "height_px": d.get("image_height", 0)}


def _kalibr_camera(d: dict):
    """The one camera entry of a Kalibr camchain (``cam0: {...}``) or camera YAML; None when ``d`` is
    not one."""
    if "intrinsics" in d and "camera_model" in d:
        return d
    cams = {k: v for k, v in d.items() if isinstance(v, dict) and "intrinsics" in v and "camera_model" in v}
    if not cams or len(cams) != len(d):
        return None
    return cams


def _from_kalibr(p: Path, d: dict) -> dict:
    """A Kalibr camera (one pinhole camera) as ``Intrinsics.from_dict`` reads it."""
    cam = _kalibr_camera(d)
    if cam is not d:
        if len(cam) != 1:
            raise InputError(f"{p}: a Kalibr camchain of {len(cam)} cameras ({', '.join(cam)}); give a file with the "
                             "one camera this name refers to.")
        cam = next(iter(cam.values()))
    if str(cam.get("camera_model", "")).lower() != "pinhole":
        raise InputError(f"{p}: Kalibr camera_model {cam.get('camera_model')!r} is not supported: calibgraph models "
                         "OpenCV's pinhole camera.")
    _check_model(p, cam.get("distortion_model", "none"), "Kalibr")
    fu, fv, pu, pv = _numbers(p, cam["intrinsics"], "intrinsics", 4)
    res = _numbers(p, cam.get("resolution"), "resolution", 2)
    dist = _numbers(p, cam.get("distortion_coeffs"), "distortion_coeffs")
    return {"K": [[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]], "dist": dist,
            "width_px": int(res[0]), "height_px": int(res[1])}


def read_camera_file_args(specs, flag: str = "--intrinsics") -> dict:
    """``{name: Intrinsics}`` from ``NAME=CAM.yaml`` arguments (``flag`` names them in errors); a
    malformed argument, a camera named twice or an unreadable file is refused in one line."""
    out = {}
    for spec in specs or ():
        name, sep, path = str(spec).partition("=")
        name, path = name.strip(), path.strip()
        if not sep or not name or not path:
            raise InputError(f"{flag} {spec!r}: expected NAME=CAM.yaml (the camera's name in the dataset or "
                             "workcell, then its camera file).")
        if name in out:
            raise InputError(f"{flag}: camera {name!r} is given two camera files; give one.")
        out[name] = read_camera_file(path)
    return out


def apply_camera_files(cameras: dict, files: dict, where: str, flag: str = "--intrinsics") -> dict:
    """``cameras`` (name -> Intrinsics) with each camera named in ``files`` replaced by its camera
    file's intrinsics (values, source and covariance: the solver's prior for that camera). A name
    ``cameras`` lacks, or a file made for another image size, is refused naming both."""
    check_camera_names(files, list(cameras), where, flag)
    out = dict(cameras)
    for name, intr in files.items():
        check_image_size(name, cameras[name], intr, where, flag)
        out[name] = intr
    return out


def check_camera_names(files: dict, known, where: str, flag: str = "--intrinsics") -> None:
    """Refuse camera files for cameras ``where`` does not have (``known``: its camera names)."""
    unknown = sorted(set(files) - set(known))
    if unknown:
        raise InputError(f"{flag}: {where} has no camera {', '.join(map(repr, unknown))} (its cameras: "
                         f"{', '.join(known) or 'none'}).")


def check_image_size(name: str, have, intr, where: str, flag: str = "--intrinsics") -> None:
    """Refuse a camera file whose image size differs from the camera's own (a zero size: unknown)."""
    w, h = int(getattr(have, "width_px", 0) or 0), int(getattr(have, "height_px", 0) or 0)
    if w and h and intr.width_px and intr.height_px and (w, h) != (intr.width_px, intr.height_px):
        raise InputError(f"{flag} {name}: the camera file is for {intr.width_px}x{intr.height_px} images, but "
                         f"camera {name!r} of {where} has {w}x{h}; calibrate it at the resolution it captures.")


def _plain(x):
    """numpy scalars and arrays as plain Python for YAML."""
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    return x
