"""Calibration targets: their geometry in the board frame and a YAML spec.

Board frame (all targets): origin at the first point (id 0), x along a row (increasing column
index), y along a column (increasing row index), z = x cross y (into the board for a target seen
from the front). Point ``id = cols * i + j`` sits at ``(pitch * j, pitch * i, 0)`` for grids;
asymmetric circle grids shift odd rows by half a pitch, as OpenCV's ``findCirclesGrid`` expects.

``rows`` and ``cols`` always count the *points* (inner corners of a checkerboard, circles of a
grid, inner ChArUco corners); ``squares_x/squares_y`` are derived for boards of squares.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError

KINDS = ("checkerboard", "charuco", "circles", "acircles", "modified_circles")


@dataclass(frozen=True)
class Target:
    """A planar calibration target.

    Attributes:
        kind: one of KINDS.
        rows, cols: number of points per column and per row (inner corners for squares boards).
        pitch_m: square size (checkerboard, ChArUco) or centre spacing (circle grids), metres.
        marker_m: ArUco marker side (ChArUco only).
        dictionary: ArUco dictionary name, e.g. "DICT_6X6_250" (ChArUco only).
        circle_diameter_m: circle diameter (circle grids; informative, used for printing).
        legacy_charuco: OpenCV < 4.6 ChArUco layout (board starts with a marker on even rows).
    """

    kind: str
    rows: int
    cols: int
    pitch_m: float
    marker_m: float = 0.0
    dictionary: str = ""
    circle_diameter_m: float = 0.0
    legacy_charuco: bool = False

    def __post_init__(self):
        if self.kind not in KINDS:
            raise InputError(f"target: unknown kind {self.kind!r}; choose one of {', '.join(KINDS)}.")
        if int(self.rows) < 2 or int(self.cols) < 2:
            raise InputError(f"target: rows and cols must be >= 2 points, got {self.rows} x {self.cols}.")
        if not (np.isfinite(self.pitch_m) and self.pitch_m > 0):
            raise InputError(f"target: pitch_m must be a positive length in metres, got {self.pitch_m}.")
        if self.pitch_m > 1.0:
            raise InputError(f"target: pitch_m = {self.pitch_m} looks like millimetres; give metres.")
        if self.kind == "charuco":
            if not (0 < self.marker_m < self.pitch_m):
                raise InputError("target: ChArUco marker_m must be positive and smaller than pitch_m.")
            if not self.dictionary:
                raise InputError("target: ChArUco needs an ArUco dictionary name, e.g. DICT_6X6_250.")
        object.__setattr__(self, "rows", int(self.rows))
        object.__setattr__(self, "cols", int(self.cols))

    @property
    def n_points(self) -> int:
        return self.rows * self.cols

    @property
    def squares_x(self) -> int:
        """Squares along a row (boards of squares)."""
        return self.cols + 1

    @property
    def squares_y(self) -> int:
        """Squares along a column (boards of squares)."""
        return self.rows + 1

    @property
    def is_symmetric(self) -> bool:
        """True when a 180-degree turn of the board maps the point grid onto itself, so corner ids
        are ambiguous without extra cues (plain checkerboards with both counts odd or both even,
        symmetric circle grids)."""
        if self.kind == "checkerboard":
            return (self.rows % 2) == (self.cols % 2)
        return self.kind == "circles"

    @property
    def points_board_m(self) -> np.ndarray:
        """(N, 3) board-frame coordinates of point ids 0..N-1."""
        i, j = np.divmod(np.arange(self.n_points), self.cols)
        x = self.pitch_m * j.astype(float)
        y = self.pitch_m * i.astype(float)
        if self.kind == "acircles":
            # OpenCV asymmetric grid: each row is offset by half the (2*pitch) spacing on odd rows.
            x = self.pitch_m * (2 * j + (i % 2)).astype(float)
        return np.column_stack([x, y, np.zeros_like(x)])

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "rows": self.rows, "cols": self.cols, "pitch_m": self.pitch_m}
        if self.kind == "charuco":
            d.update(marker_m=self.marker_m, dictionary=self.dictionary, legacy_charuco=self.legacy_charuco)
        if self.circle_diameter_m:
            d["circle_diameter_m"] = self.circle_diameter_m
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Target":
        d = dict(d)
        if "squares_x" in d and "cols" not in d:
            d["cols"] = int(d.pop("squares_x")) - 1
        if "squares_y" in d and "rows" not in d:
            d["rows"] = int(d.pop("squares_y")) - 1
        allowed = {f for f in cls.__dataclass_fields__}
        unknown = set(d) - allowed
        if unknown:
            raise InputError(f"target spec: unknown keys {sorted(unknown)}; allowed: {sorted(allowed)}.")
        try:
            return cls(**d)
        except TypeError as e:
            raise InputError(f"target spec: {e}") from None


def load_target(path) -> Target:
    """Read a target spec YAML file (keys as in ``Target``)."""
    import yaml

    p = Path(path)
    try:
        d = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise InputError(f"{p}: cannot read target spec: {e}") from None
    if not isinstance(d, dict):
        raise InputError(f"{p}: target spec must be a mapping.")
    return Target.from_dict(d.get("target", d))


def thesis_board() -> Target:
    """The thesis's A4 board: 5 x 4 squares of 46 mm -> 4 x 3 inner corners.

    The issue text counts its 54-corner variant (7x10 squares of 25 mm -> 6 x 9 = 54 corners).
    """
    return Target(kind="checkerboard", rows=3, cols=4, pitch_m=0.046)


def a4_board_54() -> Target:
    """7 x 10 squares of 25 mm (6 x 9 = 54 inner corners), fits A4."""
    return Target(kind="checkerboard", rows=6, cols=9, pitch_m=0.025)
