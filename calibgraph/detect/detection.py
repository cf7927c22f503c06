"""The record of one image's detection: which target points were found, where, and how well.

:class:`ImageDetection` is what every detector returns and what the dataset cache stores (as a
dict); :func:`failed_detection` is the record of a miss, which keeps its reason.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target


@dataclass(frozen=True)
class ImageDetection:
    """The detection of a target in one image.

    Attributes:
        ids: (N,) target point ids (rows of ``Target.points_board_m``).
        uv_px: (N, 2) sub-pixel positions, OpenCV convention (pixel centres at integers).
        ok: True when the detection is usable; False keeps the points (if any) for diagnosis.
        reason: why it was rejected (or a note on an accepted one); empty when clean.
        n_expected: number of points on the target.
        size_px: square root of the image area covered by the detected points' convex hull.
        spread: fraction of the image area covered by that hull.
        pitch_px: median distance between neighbouring grid points, pixels.
        sharpness_px: edge blur at the points as a Gaussian sigma, pixels (lower is sharper).
        upscale: up-scaling factor of the region the points came from (1 = original image).
        method: detector that produced the points ('classic', 'sb', 'charuco', 'circles', ...).
        n_refined: points moved by the photometric board fit (checkerboards and ChArUco; circle grids keep the
            detector's position).
        homography_rms_px: residual of the board-to-image homography.
        time_s: detection time.
        image: source file, when read from disk.
        other_grid: (rows, cols) inner corners of a chessboard of another size than the target's seen in
            the image (a sign of a wrong board spec, :mod:`calibgraph.detect.spec_check`), else None.
        deferred: the image was not searched yet: while the board spec is in doubt, a quick probe saw no
            chessboard of the declared size in it (:mod:`calibgraph.detect.blind`); the dataset driver
            searches it in full once the spec is settled, and never caches such a record.
        pattern: (x0, y0, x1, y1, pitch_px) of the chessboard a deferred frame's quick probe saw (its
            corners' bounding box and square size in full-resolution pixels): where a full search of the
            frame looks for the declared board (:func:`calibgraph.detect.blind.search_in_full`), else None.
        unreadable: the image file could not be read (missing, empty, truncated, not an image): the
            frame says nothing about the board, and costs its view only.
        other_whole: with ``other_grid``, whether that chessboard is a whole board (a margin all round
            it, :func:`calibgraph.detect.board_size.board_whole`) rather than a part of one (covered,
            cut off), else None.
        inverted: the board was found in the inverted image: printed white on black
            (:mod:`calibgraph.detect.polarity`).
        spec_note: what the image says about the target spec, in words, when the board was found but
            the spec cannot number it (a symmetric board; a ChArUco board declared a checkerboard of
            such a grid), else empty: the dataset's wrong-spec line repeats it.
    """

    ids: np.ndarray
    uv_px: np.ndarray
    ok: bool
    reason: str = ""
    n_expected: int = 0
    size_px: float = 0.0
    spread: float = 0.0
    pitch_px: float = 0.0
    sharpness_px: float = float("nan")
    upscale: int = 1
    method: str = ""
    homography_rms_px: float = float("nan")
    n_refined: int = 0
    time_s: float = 0.0
    image: str | None = None
    other_grid: tuple | None = None
    deferred: bool = False
    pattern: tuple | None = None
    unreadable: bool = False
    inverted: bool = False
    spec_note: str = ""
    other_whole: bool | None = None

    def __post_init__(self):
        ids = np.asarray(self.ids, int).reshape(-1)
        uv = np.asarray(self.uv_px, float).reshape(-1, 2)
        if ids.shape[0] != uv.shape[0]:
            raise InputError(f"detection: {ids.shape[0]} ids but {uv.shape[0]} points.")
        if self.ok and ids.size == 0:
            raise InputError("detection: ok=True with no points.")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "uv_px", uv)
        if self.other_grid is not None:
            object.__setattr__(self, "other_grid", tuple(int(v) for v in self.other_grid))
        if self.pattern is not None:
            object.__setattr__(self, "pattern", tuple(float(v) for v in self.pattern))

    @property
    def n_found(self) -> int:
        return int(self.ids.size)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["ids"] = self.ids.tolist()
        d["uv_px"] = self.uv_px.tolist()
        for k, v in list(d.items()):
            if isinstance(v, float) and not np.isfinite(v):
                d[k] = None
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ImageDetection":
        d = dict(d)
        for k in ("sharpness_px", "homography_rms_px"):
            if d.get(k) is None:
                d[k] = float("nan")
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})



def failed_detection(reason: str, target: Target, image: str | None = None, t0: float | None = None, **kw) -> ImageDetection:
    """A detection that found nothing usable, with ``reason``; ``t0`` (a ``perf_counter``) sets ``time_s``."""
    return ImageDetection(ids=np.zeros(0, int), uv_px=np.zeros((0, 2)), ok=False, reason=reason,
                          n_expected=target.n_points, image=image,
                          time_s=0.0 if t0 is None else time.perf_counter() - t0, **kw)
