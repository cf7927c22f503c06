"""A workcell described without camera placements: what the autonomous loop plans from.

The cell lists the cameras (a device or a preset for the intrinsics, no pose), the board and its
nominal mount, and the static geometry the robot must avoid. A camera may carry a rough ``hint``;
nothing requires one, and a wrong hint only costs a few survey stops
(:mod:`calibgraph.plan.survey` always falls back on its sweep)::

    name: my_cell
    board: a4_7x10_25mm                     # a shipped board (calibgraph target list), a spec file or {kind, rows, cols, pitch_m}
    mount: {translation_m: [0.01, -0.015, 0.06], rotvec_rad: [0, 3.14159, 0]}   # nominal T_flange_board
    floor_z_m: -0.8                         # floor below the base frame; the pedestal fills the gap
    obstacles:                              # static geometry the robot must avoid (boxes, base frame)
      - {name: table, centre_m: [0.7, 0.0, -0.05], size_m: [0.6, 1.2, 0.1]}
    keep_out:                               # volumes the robot must stay out of (not rendered)
      - {name: operator_side, centre_m: [-0.8, 0.0, 0.5], size_m: [0.4, 2.0, 2.0]}
    cameras:
      left:  {preset: l515, hint: {position_m: [0.5, 2.8, 0.8], sigma_m: 1.0}}
      right: {driver: realsense, serial: "233522071234", hint: {azimuth_deg: -90}}
      top:   {preset: d455, hint: {direction: [0.2, 0.0, 1.0]}}   # seen from the base, roughly up
      far:   {preset: l515}                                       # no hint at all

The capture workcell YAML (``calibgraph capture``) is read as it is: hardware keys (``driver``,
``serial``, ``robot``, ``safety``...) are ignored here. A simulator workcell with true placements
(``ring:``, ``position_m``/``look_at_m``, ``T_base_cam``) becomes a cell by
:func:`cell_from_world_dict`, which strips every placement.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.camera import Intrinsics, preset
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.core.transforms import check_pose, exp_so3, make_T
from calibgraph.io.files import read_yaml
from calibgraph.io.shipped import canonical_name, resolve_shipped, shipped_names
from calibgraph.io.specs import load_target

__all__ = ["Box", "CameraHint", "CellCamera", "CellDescription", "board_by_name", "default_T_flange_board",
           "pose_from_spec", "boxes_from_list", "cell_from_dict", "cell_from_world_dict", "load_cell",
           "PLACEMENT_KEYS", "has_placements"]


def board_by_name(spec) -> Target:
    """A shipped board by name (``a4_7x10_25mm``: 7 x 10 squares of 25 mm; ``thesis_5x4_46mm``: 5 x 4
    squares of 46 mm; any of ``calibgraph target list``, an alias such as ``a4_54`` or ``thesis``,
    or a documented path ``datasets/targets/NAME.yaml``), a target spec file, or a Target dict."""
    if isinstance(spec, Target):
        return spec
    if isinstance(spec, dict):
        return Target.from_dict(spec)
    key = str(spec)
    if canonical_name("target", key) is not None or key.lower().endswith((".yaml", ".yml")):
        return load_target(key)
    raise InputError(f"unknown board {spec!r}; use a shipped board ({', '.join(shipped_names('target'))}; aliases "
                     "a4_54, thesis), a target spec file or a target mapping (kind, rows, cols, pitch_m).")


def default_T_flange_board(target: Target) -> np.ndarray:
    """Board mount used when a workcell does not give one.

    The board's printed face looks along the flange z axis (board z = -flange z), 6 cm out from
    the flange, its centre slightly off the flange axis (an asymmetric mount exercises the solver
    better than a perfectly centred one).
    """
    centre_b = target.points_board_m.mean(axis=0)
    R_fb = exp_so3([0.0, np.pi, 0.0]) @ exp_so3([0.0, 0.0, np.radians(7.0)])
    # choose t so that the board centre lands at (0.01, -0.015, 0.06) in the flange frame
    t = np.array([0.01, -0.015, 0.06]) - R_fb @ centre_b
    return make_T(R_fb, t)


def pose_from_spec(d: dict, what: str) -> np.ndarray:
    """4x4 pose from ``{T: 4x4}``, ``{translation_m, rotvec_rad}`` or ``{translation_m, rpy_deg}``."""
    if not isinstance(d, dict):
        raise InputError(f"{what}: must be a mapping (T, or translation_m with rotvec_rad / rpy_deg).")
    if "T" in d:
        return check_pose(np.asarray(d["T"], float), what)
    t = np.asarray(d.get("translation_m", [0, 0, 0]), float)
    R = exp_so3(np.asarray(d.get("rotvec_rad", [0, 0, 0]), float))
    if "rpy_deg" in d:
        r, p, y = np.radians(np.asarray(d["rpy_deg"], float))
        R = exp_so3([0, 0, y]) @ exp_so3([0, p, 0]) @ exp_so3([r, 0, 0])
    return make_T(R, t)


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in the base frame: ``centre_m`` (3,), full ``size_m`` (3,).

    ``keep_out`` boxes are volumes the robot must not enter (collision only, never rendered);
    the others are solid geometry (a table, a fence) that also hides what is behind it."""

    name: str
    centre_m: np.ndarray
    size_m: np.ndarray
    keep_out: bool = False

    def __post_init__(self):
        c = np.asarray(self.centre_m, float).reshape(-1)
        s = np.asarray(self.size_m, float).reshape(-1)
        if c.shape != (3,) or s.shape != (3,) or not (np.all(np.isfinite(c)) and np.all(s > 0)):
            raise InputError(f"box {self.name!r}: centre_m needs 3 finite values and size_m 3 positive ones.")
        object.__setattr__(self, "centre_m", c)
        object.__setattr__(self, "size_m", s)

    def contains(self, p_m: np.ndarray, inflate_m: float = 0.0) -> np.ndarray:
        """Mask of points ``p_m`` (N, 3) inside the box grown by ``inflate_m``."""
        d = np.abs(np.asarray(p_m, float).reshape(-1, 3) - self.centre_m)
        return np.all(d <= self.size_m / 2 + inflate_m, axis=1)


@dataclass(frozen=True)
class CameraHint:
    """Rough knowledge of where a camera is (all optional, all base frame).

    Attributes:
        position_m: (3,) rough camera position, or None.
        sigma_m: how far off ``position_m`` may be (1-sigma, metres).
        direction: (3,) unit vector from the robot base towards the camera, or None
            (``azimuth_deg`` in the YAML gives a horizontal one).
    """

    position_m: np.ndarray | None = None
    sigma_m: float = 1.0
    direction: np.ndarray | None = None

    def __post_init__(self):
        if self.position_m is not None:
            p = np.asarray(self.position_m, float).reshape(-1)
            if p.shape != (3,) or not np.all(np.isfinite(p)):
                raise InputError(f"camera hint: position_m needs 3 finite values, got {self.position_m!r}.")
            object.__setattr__(self, "position_m", p)
        if self.direction is not None:
            v = np.asarray(self.direction, float).reshape(-1)
            if v.shape != (3,) or not np.linalg.norm(v) > 0:
                raise InputError(f"camera hint: direction needs 3 values, not all zero, got {self.direction!r}.")
            object.__setattr__(self, "direction", v / np.linalg.norm(v))
        if not self.sigma_m > 0:
            raise InputError(f"camera hint: sigma_m must be > 0, got {self.sigma_m}.")

    def towards(self) -> np.ndarray:
        """Unit vector from the base towards the camera (from the position when given)."""
        if self.position_m is not None:
            return self.position_m / max(np.linalg.norm(self.position_m), 1e-9)
        return self.direction

    @classmethod
    def from_dict(cls, d, where: str) -> "CameraHint":
        if not isinstance(d, dict):
            raise InputError(f"{where}: hint must be a mapping (position_m + sigma_m, direction or azimuth_deg).")
        unknown = set(d) - {"position_m", "sigma_m", "direction", "azimuth_deg", "elevation_deg"}
        if unknown:
            raise InputError(f"{where}: hint: unknown keys {', '.join(sorted(unknown))}; allowed: position_m, sigma_m, direction, "
                             "azimuth_deg, elevation_deg.")
        direction = d.get("direction")
        if direction is None and "azimuth_deg" in d:
            a, e = np.radians(float(d["azimuth_deg"])), np.radians(float(d.get("elevation_deg", 10.0)))
            direction = [np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)]
        if d.get("position_m") is None and direction is None:
            raise InputError(f"{where}: hint needs position_m, direction or azimuth_deg.")
        try:
            return cls(position_m=d.get("position_m"), sigma_m=float(d.get("sigma_m", 1.0)), direction=direction)
        except InputError as e:
            raise InputError(f"{where}: {e}") from None


@dataclass(frozen=True)
class CellCamera:
    """A camera of the cell: name, intrinsics when known beforehand (a preset or a file; a device
    reports its own at capture time), and an optional :class:`CameraHint`."""

    name: str
    intrinsics: Intrinsics | None = None
    preset: str = ""
    hint: CameraHint | None = None


@dataclass(frozen=True)
class CellDescription:
    """A cell without camera placements.

    Attributes:
        name: label.
        target: the board.
        T_flange_board: (4, 4) nominal board mount (the graph estimates the true one).
        cameras: tuple of :class:`CellCamera`.
        floor_z_m: floor height in the base frame (a pedestal fills the gap under the base).
        obstacles: static :class:`Box` geometry, keep-out boxes included.
    """

    name: str
    target: Target
    T_flange_board: np.ndarray
    cameras: tuple
    floor_z_m: float = -0.8
    obstacles: tuple = ()

    def __post_init__(self):
        names = [c.name for c in self.cameras]
        if not names:
            raise InputError(f"cell {self.name!r}: no cameras listed; add a 'cameras' section.")
        if len(set(names)) != len(names):
            raise InputError(f"cell {self.name!r}: duplicate camera names {', '.join(map(str, names))}.")
        object.__setattr__(self, "cameras", tuple(self.cameras))
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        check_pose(np.asarray(self.T_flange_board, float), f"cell {self.name!r}: mount")

    @property
    def camera_names(self) -> list:
        return [c.name for c in self.cameras]

    def camera(self, name: str) -> CellCamera:
        for c in self.cameras:
            if c.name == name:
                return c
        raise InputError(f"cell {self.name!r}: no camera {name!r}; cameras are {self.camera_names}.")

    def hints(self) -> dict:
        return {c.name: c.hint for c in self.cameras if c.hint is not None}


PLACEMENT_KEYS = {"position_m", "look_at_m", "T_base_cam"}  # what places a camera in a simulator workcell


def has_placements(d: dict) -> bool:
    """True when a workcell mapping places its cameras (a ``ring:`` or a camera with a placement key)."""
    if not isinstance(d, dict):
        return False
    cams = d.get("cameras") or {}
    entries = cams.values() if isinstance(cams, dict) else ()
    return bool(d.get("ring")) or any(isinstance(c, dict) and bool(PLACEMENT_KEYS & set(c)) for c in entries)


def boxes_from_list(items, where: str, keep_out: bool) -> list:
    """:class:`Box` list from YAML entries ``{name, centre_m, size_m}``."""
    out = []
    for k, b in enumerate(items or []):
        if not isinstance(b, dict) or "centre_m" not in b or "size_m" not in b:
            raise InputError(f"{where}: {'keep_out' if keep_out else 'obstacles'}[{k}] needs centre_m and size_m (metres).")
        out.append(Box(str(b.get("name", f"{'keep_out' if keep_out else 'obstacle'}{k}")), b["centre_m"], b["size_m"],
                       keep_out))
    return out


def cell_from_dict(d: dict, where: str = "cell") -> CellDescription:
    """Build a :class:`CellDescription` from a cell YAML mapping (see the module docstring). A
    camera entry that carries a placement is refused: use :func:`cell_from_world_dict` to strip it."""
    if not isinstance(d, dict):
        raise InputError(f"{where}: must be a mapping.")
    target = board_by_name(d.get("board", "a4_7x10_25mm"))
    mount = d.get("mount")
    T_fb = pose_from_spec(mount, f"{where}: mount") if mount else default_T_flange_board(target)
    cams = []
    entries = d.get("cameras") or {}
    if not isinstance(entries, dict):
        raise InputError(f"{where}: cameras must be a mapping name -> settings.")
    for name, c in entries.items():
        c = dict(c or {})
        placed = PLACEMENT_KEYS & set(c)
        if placed:
            raise InputError(f"{where}: camera {name!r} gives its placement ({', '.join(sorted(placed))}); the autonomous loop "
                             "finds placements itself: remove them or give a rough hint instead.")
        intr = None
        if "intrinsics" in c:
            intr = Intrinsics.from_dict(c["intrinsics"])
        elif c.get("preset") or c.get("driver", "sim") == "sim":
            intr = preset(c.get("preset", "l515"))
        hint = CameraHint.from_dict(c["hint"], f"{where}: camera {name!r}") if c.get("hint") is not None else None
        cams.append(CellCamera(str(name), intr, str(c.get("preset", "")), hint))
    if not cams:
        raise InputError(f"{where}: no cameras listed; add a 'cameras' section (name -> preset or driver).")
    boxes = boxes_from_list(d.get("obstacles"), where, False) + boxes_from_list(d.get("keep_out"), where, True)
    try:
        floor_z = float(d.get("floor_z_m", -0.8))
    except (TypeError, ValueError):
        raise InputError(f"{where}: floor_z_m must be a number (metres, negative: below the base).") from None
    return CellDescription(name=str(d.get("name", "cell")), target=target, T_flange_board=T_fb, cameras=tuple(cams),
                           floor_z_m=floor_z, obstacles=tuple(boxes))


def cell_from_world_dict(d: dict, where: str = "world") -> CellDescription:
    """The cell of a simulator workcell mapping with every camera placement stripped: ring
    cameras become ``cam0..`` with their preset, explicit cameras keep their name and preset."""
    if not isinstance(d, dict):
        raise InputError(f"{where}: must be a mapping.")
    cams = {}
    ring = d.get("ring") or {}
    if ring:
        presets = list(ring.get("presets", ["l515"])) or ["l515"]
        for i in range(len(ring.get("distances_m", []))):
            cams[f"cam{i}"] = {"preset": presets[i % len(presets)]}
    for name, c in (d.get("cameras") or {}).items():
        cams[str(name)] = {k: v for k, v in (c or {}).items() if k not in PLACEMENT_KEYS}
    out = {k: d[k] for k in ("name", "board", "mount", "floor_z_m", "obstacles", "keep_out") if k in d}
    out["cameras"] = cams
    return cell_from_dict(out, where)


def load_cell(path) -> CellDescription:
    """Read a cell YAML file (placements, if any, are refused; see :func:`cell_from_world_dict`)."""
    p = resolve_shipped(path, "workcell")  # a shipped name or datasets/workcells/... from any folder
    return cell_from_dict(read_yaml(p, "cell file"), str(p))
