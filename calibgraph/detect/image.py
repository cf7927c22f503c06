"""Image input for the detectors: files and arrays of any common depth to 8-bit grey.

A file that cannot be used (missing, empty, truncated, an unsupported pixel type) raises
:class:`~calibgraph.core.errors.DetectionError` naming the file and what to do.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.errors import DetectionError


def read_grey(path) -> np.ndarray:
    """Read an image file as 8-bit grey. Raises :class:`DetectionError` naming the file and the
    problem (missing, empty, truncated/unreadable, unsupported bit depth)."""
    import cv2

    p = Path(path)
    if not p.is_file():
        raise DetectionError(f"{p}: image file not found.")
    if p.stat().st_size == 0:
        raise DetectionError(f"{p}: image file is empty (0 bytes); re-capture it or delete the view.")
    data = np.fromfile(str(p), np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise DetectionError(f"{p}: cannot decode the image (truncated or not an image file); re-capture it.")
    return to_grey8(img, str(p))


def to_grey8(img: np.ndarray, where: str = "image") -> np.ndarray:
    """Convert an image array to 8-bit grey: colour -> grey, 16-bit scaled by its white point,
    float in [0, 1] scaled to 255. Other depths are refused with a clear message."""
    import cv2

    img = np.asarray(img)
    if img.size == 0 or img.ndim < 2 or min(img.shape[:2]) < 8:
        raise DetectionError(f"{where}: empty image (shape {img.shape}).")
    if img.ndim == 3:
        if img.shape[2] == 1:
            img = img[:, :, 0]
        elif img.shape[2] in (3, 4):
            img = cv2.cvtColor(img[:, :, :3], cv2.COLOR_BGR2GRAY)
        else:
            raise DetectionError(f"{where}: {img.shape[2]} channels; expected grey, BGR or BGRA.")
    elif img.ndim != 2:
        raise DetectionError(f"{where}: image must be 2-D (grey) or 3-D (colour), got shape {img.shape}.")
    if img.dtype == np.uint8:
        return np.ascontiguousarray(img)
    if img.dtype == np.uint16:
        # Cameras often write 10/12-bit data in 16-bit containers: scale by the observed white point.
        hi = float(np.percentile(img, 99.9))
        if hi <= 0:
            raise DetectionError(f"{where}: 16-bit image is black.")
        return np.clip(img.astype(np.float32) * (255.0 / hi), 0, 255).astype(np.uint8)
    if img.dtype in (np.float32, np.float64):
        if not np.all(np.isfinite(img)):
            raise DetectionError(f"{where}: float image contains NaN/inf.")
        scale = 255.0 if img.max() <= 1.0 + 1e-6 else 1.0
        return np.clip(img * scale, 0, 255).astype(np.uint8)
    raise DetectionError(f"{where}: unsupported pixel type {img.dtype}; give 8- or 16-bit grey/colour images.")
