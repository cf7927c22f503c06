"""Image input for the detectors: files and arrays of any common depth to 8-bit grey.

A file that cannot be used (missing, empty, truncated, an unsupported pixel type) raises
:class:`~calibgraph.core.errors.DetectionError` naming the file and what to do.

:class:`Frame` decodes a file at the resolution a search needs, each at most once: a blind look
at the whole frame works on a reduced image, a search of a predicted region on the full one.
JPEG decodes reduced natively (the inverse DCT at 1/2, 1/4 or 1/8 scale) at a fraction of the
full cost; PNG and the other lossless formats have no such path, so their full image is decoded
once and reduced in memory.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.errors import DetectionError, InputError
from calibgraph.core.inputs import read_input_bytes


def read_grey(path) -> np.ndarray:
    """Read an image file as 8-bit grey. Raises :class:`DetectionError` naming the file and the
    problem (missing, empty, truncated/unreadable, unsupported bit depth)."""
    import cv2

    p = Path(path)
    return _decode(_read_bytes(p), p, cv2.IMREAD_UNCHANGED)


def _read_bytes(p: Path) -> np.ndarray:
    if not p.exists():
        raise DetectionError(f"{p}: image file not found.")
    try:
        data = read_input_bytes(p, "image file")  # a FIFO or a device is refused, never waited on
    except InputError as e:
        raise DetectionError(str(e)) from None
    if not data:
        raise DetectionError(f"{p}: image file is empty (0 bytes); re-capture it or delete the view.")
    return np.frombuffer(data, np.uint8)


def _decode(data: np.ndarray, p: Path, flags: int) -> np.ndarray:
    import cv2

    img = cv2.imdecode(data, flags)
    if img is None:
        raise DetectionError(f"{p}: cannot decode the image (truncated or not an image file); re-capture it.")
    return to_grey8(img, str(p))


_REDUCED_FLAGS = {2: "IMREAD_REDUCED_GRAYSCALE_2", 4: "IMREAD_REDUCED_GRAYSCALE_4", 8: "IMREAD_REDUCED_GRAYSCALE_8"}


class Frame:
    """One image, read once and decoded at the resolutions a search asks for (module docstring).

    ``source``: a file path, or an image array (any depth :func:`to_grey8` takes). ``grey()`` is
    the full-resolution 8-bit grey image, as :func:`read_grey` gives it; ``reduced(k)`` the image at
    1/``k`` of the resolution (k = 2, 4 or 8), pixel ``(x, y)`` covering full-resolution pixels
    ``k x`` to ``k x + k - 1``. Both raise :class:`DetectionError` for an unusable file.
    """

    def __init__(self, source, name: str | None = None):
        self.path = Path(source) if isinstance(source, (str, Path)) else None
        self.name = str(source) if self.path is not None else name
        self._full = None if self.path is not None else to_grey8(source, name or "image")
        self._data = None
        self._digest = None
        self._reduced = {}

    def _bytes(self) -> np.ndarray:
        if self._data is None:
            self._data = _read_bytes(self.path)
        return self._data

    def grey(self) -> np.ndarray:
        """The full-resolution 8-bit grey image."""
        import cv2

        if self._full is None:
            self._full = _decode(self._bytes(), self.path, cv2.IMREAD_UNCHANGED)
            self._data = None  # decoded: the file's bytes are not needed again
        return self._full

    def digest(self) -> bytes | None:
        """A hash of the file's bytes (None for an image array): what a result computed from the
        image alone can be remembered by, whatever the file's name or time stamps."""
        import hashlib

        if self.path is None:
            return None
        if self._digest is None:
            data = self._bytes() if self._full is None or self._data is not None else _read_bytes(self.path)
            self._digest = hashlib.blake2b(data, digest_size=16).digest()
        return self._digest

    @property
    def decoded(self) -> bool:
        """Whether the full-resolution image has been decoded."""
        return self._full is not None

    def reduced(self, k: int) -> np.ndarray:
        """The image at 1/``k`` resolution (area average), decoded natively where the format can."""
        import cv2

        if k not in _REDUCED_FLAGS:
            raise ValueError(f"reduction factor must be 2, 4 or 8, got {k}")
        if k not in self._reduced:
            if self._full is None and self._bytes()[:3].tobytes() == b"\xff\xd8\xff":  # JPEG
                self._reduced[k] = _decode(self._bytes(), self.path, getattr(cv2, _REDUCED_FLAGS[k]))
            else:
                full = self.grey()
                self._reduced[k] = cv2.resize(full, (full.shape[1] // k, full.shape[0] // k),
                                              interpolation=cv2.INTER_AREA)
        return self._reduced[k]


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


def sample_bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N,) values of ``img`` at sub-pixel positions ``uv`` (N, 2), bilinear, edges replicated."""
    import cv2

    m = np.asarray(uv, np.float32).reshape(-1, 1, 2)
    out = cv2.remap(img, m[:, :, 0], m[:, :, 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1).astype(float)
