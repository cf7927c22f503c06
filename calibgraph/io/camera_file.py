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
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.io.files import atomic_write_text, read_yaml


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
    """The :class:`Intrinsics` of a camera file (or any intrinsics YAML ``Intrinsics.from_dict`` reads);
    a malformed file is refused naming it."""
    d = read_yaml(path, "camera file")
    try:
        return Intrinsics.from_dict(d)
    except CalibgraphError as e:
        raise InputError(f"{path}: {e}") from None
    except (TypeError, ValueError) as e:
        raise InputError(f"{path}: not a camera file ({e}); it needs K (3x3) or fx, fy, cx, cy, and width_px, "
                         "height_px.") from None


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
