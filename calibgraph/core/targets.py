"""Calibration targets: their geometry in the board frame and a YAML spec.

``rows`` and ``cols`` always count the *points* (inner corners of a checkerboard, circles of a
grid, inner ChArUco corners); ``squares_x/squares_y`` are derived for boards of squares. Point
``id = cols * i + j`` is the point in row ``i`` (0..rows-1) and column ``j`` (0..cols-1), rows
and columns counted as the board is printed (row 0 at the top of the page, column 0 at the left).

Board frames (one per kind, each documented where the kind differs):

* ``checkerboard``, ``circles``: origin at point 0 (top-left inner corner / circle centre), x along
  a row (increasing ``j``), y down a column (increasing ``i``), z = x cross y, i.e. *into* the
  board for a target seen from its printed side. Point ``(i, j)`` is at ``(pitch * j, pitch * i, 0)``.
  Square colours (checkerboard): the outer square at the top-left of the page is black, so the
  cell between inner corners ``(i, j)`` and ``(i + 1, j + 1)`` is black iff ``i + j`` is even.
* ``acircles``: OpenCV's asymmetric grid: point ``(i, j)`` at ``(pitch * (2 j + i % 2), pitch * i, 0)``.
* ``charuco``: OpenCV's ``cv2.aruco.CharucoBoard((cols + 1, rows + 1), pitch_m, marker_m, dict)``
  frame and ids (OpenCV >= 4.6 layout, or the pre-4.6 layout with ``legacy_charuco``): origin at
  the *outer* top-left corner of the board, so inner corner ``(i, j)`` is at
  ``(pitch * (j + 1), pitch * (i + 1), 0)``; id = OpenCV's ChArUco corner id. This is also the
  target frame of industrial_calibration's ``CharucoGridTargetFinder``.
* ``modified_circles``: industrial_calibration's modified circle grid (a symmetric dot grid whose
  origin dot is enlarged to twice the diameter, fixing the orientation). Its frame and ids are the
  peer's: origin at the big dot, which is printed at the *bottom-left* of the page; x along the
  bottom row to the right, y *up* the page, z = x cross y out of the page (towards a viewer).
  Point ``(i, j)`` (row 0 at the top of the page) is at ``(pitch * j, pitch * (rows - 1 - i), 0)``,
  so the big dot is id ``(rows - 1) * cols``.

Ordering is unambiguous only when the pattern has no symmetry (see ``Target.is_symmetric``); the
detector refuses symmetric boards unless told to accept an image-based orientation guess.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.errors import InputError

KINDS = ("checkerboard", "charuco", "circles", "acircles", "modified_circles")


@dataclass(frozen=True)
class Target:
    """A planar calibration target (see the module docstring for each kind's board frame).

    Attributes:
        kind: one of KINDS.
        rows, cols: number of points per column and per row (inner corners for squares boards).
        pitch_m: square size (checkerboard, ChArUco) or centre spacing (circle grids), metres.
        marker_m: ArUco marker side (ChArUco only).
        dictionary: ArUco dictionary name, e.g. "DICT_6X6_250" (ChArUco only); OpenCV's integer
            ids (as industrial_calibration writes them, 10 = DICT_6X6_250) are accepted and converted.
        circle_diameter_m: circle diameter (circle grids; used for printing and rendering; the
            modified circle grid's origin dot has twice this diameter). 0 = pitch / 2.
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
            object.__setattr__(self, "dictionary", dictionary_name(self.dictionary))
            if not (0 < self.marker_m < self.pitch_m):
                raise InputError("target: ChArUco marker_m must be positive and smaller than pitch_m.")
            if not self.dictionary:
                raise InputError("target: ChArUco needs an ArUco dictionary name, e.g. DICT_6X6_250.")
        if self.kind in ("circles", "acircles", "modified_circles"):
            d = self.circle_diameter_m
            if not (np.isfinite(d) and 0 <= d):
                raise InputError(f"target: circle_diameter_m must be >= 0, got {d}.")
            limit = self.pitch_m * (0.5 if self.kind == "modified_circles" else 1.0)
            if d >= limit:
                raise InputError(
                    f"target: circle_diameter_m = {d} m is too large for pitch {self.pitch_m} m "
                    f"(circles would touch{' the doubled origin dot' if self.kind == 'modified_circles' else ''})."
                )
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

    def describe(self) -> str:
        """The board in words, rows first as in the spec: 'checkerboard, 7 x 10 squares of 25 mm,
        6 x 9 inner corners' (the one description every command and the printout use)."""
        mm = f"{self.pitch_m * 1e3:.6g} mm"
        if self.kind == "checkerboard":
            return f"checkerboard, {self.squares_y} x {self.squares_x} squares of {mm}, {self.rows} x {self.cols} inner corners"
        if self.kind == "charuco":
            return (f"ChArUco, {self.squares_y} x {self.squares_x} squares of {mm}, {self.rows} x {self.cols} inner corners, "
                    f"{self.marker_m * 1e3:.6g} mm {self.dictionary} markers{' (legacy layout)' if self.legacy_charuco else ''}")
        name = {"circles": "circle grid", "acircles": "asymmetric circle grid", "modified_circles": "modified circle grid"}[self.kind]
        return f"{name}, {self.rows} x {self.cols} dots of {self.circle_d_m * 1e3:.6g} mm, pitch {mm}"

    @property
    def circle_d_m(self) -> float:
        """Circle diameter used for printing/rendering (``circle_diameter_m`` or half the pitch,
        a quarter for the modified grid so its doubled origin dot fits)."""
        if self.circle_diameter_m:
            return float(self.circle_diameter_m)
        return self.pitch_m * (0.25 if self.kind == "modified_circles" else 0.5)

    @property
    def is_symmetric(self) -> bool:
        """True when a 180-degree turn of the board maps the pattern onto itself, so point ids are
        ambiguous without extra cues: plain checkerboards with ``rows + cols`` even (square colours
        repeat under the turn), symmetric circle grids, asymmetric grids with an even row count.
        ChArUco (markers) and the modified circle grid (big origin dot) are never ambiguous."""
        if self.kind == "checkerboard":
            return (self.rows % 2) == (self.cols % 2)
        if self.kind == "acircles":
            return self.rows % 2 == 0
        return self.kind == "circles"

    @property
    def points_board_m(self) -> np.ndarray:
        """(N, 3) board-frame coordinates of point ids 0..N-1 (frames in the module docstring)."""
        i, j = np.divmod(np.arange(self.n_points), self.cols)
        x = self.pitch_m * j.astype(float)
        y = self.pitch_m * i.astype(float)
        if self.kind == "acircles":
            # OpenCV asymmetric grid: odd rows are shifted by one pitch, columns are 2 pitches apart.
            x = self.pitch_m * (2 * j + (i % 2)).astype(float)
        elif self.kind == "charuco":
            # OpenCV's CharucoBoard frame starts at the outer board corner, one square before corner 0.
            x = x + self.pitch_m
            y = y + self.pitch_m
        elif self.kind == "modified_circles":
            y = self.pitch_m * (self.rows - 1 - i).astype(float)
        return np.column_stack([x, y, np.zeros_like(x)])

    @property
    def grid_ij(self) -> np.ndarray:
        """(N, 2) integer (row i, column j) of each point id, as printed (row 0 at the top)."""
        i, j = np.divmod(np.arange(self.n_points), self.cols)
        return np.column_stack([i, j])

    @property
    def line_ij(self) -> np.ndarray:
        """(N, 2) integer (line, position) indices in which straight rows/columns of points share
        the first/second index and neighbours along a line differ by 1 step of ``pitch_m``
        (equals ``grid_ij`` except for asymmetric grids, whose columns hold every other row)."""
        ij = self.grid_ij
        if self.kind == "acircles":
            return np.column_stack([ij[:, 0], 2 * ij[:, 1] + ij[:, 0] % 2])
        return ij

    @property
    def extent_m(self) -> tuple:
        """(x_min, y_min, x_max, y_max) of the printed pattern in the board frame, metres
        (outer squares of boards of squares, circle edges of grids)."""
        if self.kind in ("checkerboard", "charuco"):
            x0 = -self.pitch_m if self.kind == "checkerboard" else 0.0
            return (x0, x0, x0 + self.squares_x * self.pitch_m, x0 + self.squares_y * self.pitch_m)
        p = self.points_board_m
        r = self.circle_d_m * (1.0 if self.kind == "modified_circles" else 0.5)
        return (p[:, 0].min() - r, p[:, 1].min() - r, p[:, 0].max() + r, p[:, 1].max() + r)

    def cv_charuco_board(self):
        """The equivalent ``cv2.aruco.CharucoBoard`` (ChArUco only); ids and frame match
        ``points_board_m`` exactly (checked in the tests)."""
        if self.kind != "charuco":
            raise InputError(f"target: {self.kind} is not a ChArUco board.")
        import cv2

        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        b = cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), float(self.pitch_m), float(self.marker_m), d)
        if self.legacy_charuco:
            b.setLegacyPattern(True)
        return b

    def spec_hash(self) -> str:
        """Short stable hash of the spec (cache keys)."""
        import hashlib
        import json

        return hashlib.sha1(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[:12]

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "rows": self.rows, "cols": self.cols, "pitch_m": self.pitch_m}
        if self.kind == "charuco":
            d.update(marker_m=self.marker_m, dictionary=self.dictionary, legacy_charuco=self.legacy_charuco)
        if self.circle_diameter_m:
            d["circle_diameter_m"] = float(self.circle_diameter_m)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Target":
        d = dict(d)
        if "square_m" in d and "pitch_m" not in d:
            d["pitch_m"] = d.pop("square_m")
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


# OpenCV's predefined ArUco dictionaries by enum value (cv2.aruco.DICT_*), so specs written with
# integer ids (industrial_calibration: ``dictionary: 10``) load without importing OpenCV.
ARUCO_DICTIONARIES = (
    "DICT_4X4_50", "DICT_4X4_100", "DICT_4X4_250", "DICT_4X4_1000",
    "DICT_5X5_50", "DICT_5X5_100", "DICT_5X5_250", "DICT_5X5_1000",
    "DICT_6X6_50", "DICT_6X6_100", "DICT_6X6_250", "DICT_6X6_1000",
    "DICT_7X7_50", "DICT_7X7_100", "DICT_7X7_250", "DICT_7X7_1000",
    "DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_16h5", "DICT_APRILTAG_25h9", "DICT_APRILTAG_36h10",
    "DICT_APRILTAG_36h11", "DICT_ARUCO_MIP_36h12",
)


def dictionary_name(d) -> str:
    """Canonical ArUco dictionary name from a name (any case, with or without ``DICT_``) or an
    OpenCV integer id."""
    if isinstance(d, (int, np.integer)) or (isinstance(d, str) and d.strip().isdigit()):
        k = int(d)
        if not 0 <= k < len(ARUCO_DICTIONARIES):
            raise InputError(f"target: ArUco dictionary id {k} is not one of OpenCV's predefined ids 0..{len(ARUCO_DICTIONARIES) - 1}.")
        return ARUCO_DICTIONARIES[k]
    name = str(d).strip()
    key = name.upper() if name.upper().startswith("DICT_") else "DICT_" + name.upper()
    for n in ARUCO_DICTIONARIES:
        if n.upper() == key:
            return n
    raise InputError(f"target: unknown ArUco dictionary {d!r}; use one of {', '.join(ARUCO_DICTIONARIES)}.")


def thesis_board() -> Target:
    """``thesis_5x4_46mm``, the thesis's A4 board: 4 x 5 squares of 46 mm -> 3 x 4 inner corners.

    3 + 4 is odd, so the board has no 180-degree symmetry and its corner ids are unambiguous.
    """
    return Target(kind="checkerboard", rows=3, cols=4, pitch_m=0.046)


def a4_board_54() -> Target:
    """``a4_7x10_25mm`` (alias ``a4_54``): 7 x 10 squares of 25 mm (6 x 9 = 54 inner corners), fits A4."""
    return Target(kind="checkerboard", rows=6, cols=9, pitch_m=0.025)


def rct_charuco_board() -> Target:
    """industrial_calibration's example ChArUco: 5 x 7 squares of 36.195 mm, 18.256 mm markers,
    DICT_6X6_250 (24 inner corners)."""
    return Target(kind="charuco", rows=6, cols=4, pitch_m=0.036195, marker_m=0.018256, dictionary="DICT_6X6_250")
