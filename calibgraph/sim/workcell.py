"""The simulated workcell as data: robot, board mount, cameras and image realism.

A workcell is read from YAML (``datasets/workcells/*.yaml``) or built by
:func:`ring_workcell`. Every pose uses the robot base as the world frame
(``T_base_cam``: OpenCV optical frame of the camera in the base frame, metres). The robot stands
on a pedestal whose top is the base frame; the floor is at ``floor_z_m`` (negative), so a camera
``height_above_floor_m = 1.6`` sits at ``z = floor_z_m + 1.6`` in the base frame.

YAML::

    name: default
    board: a4_7x10_25mm           # a shipped board (calibgraph target list; alias a4_54) or {kind: checkerboard, rows: 6, cols: 9, pitch_m: 0.025}
    floor_z_m: -0.8
    robot: {fk_sigma_translation_m: 5.0e-5, fk_sigma_rotation_deg: 0.005,   # reported-pose error
            joint_offsets_rad: [0, 0.001, 0, 0, 0, 0, 0]}   # optional: the arm's joint zero offsets
    mount: {translation_m: [0.01, -0.015, 0.06], rotvec_rad: [0.0, 3.14159, 0.0]}   # T_flange_board (optional)
    realism: {noise_sigma_dn: 2.0, blur_sigma_px: 0.6, exposure: 1.0, motion_blur_px: 0.0,
              distortion: false,
              reported_intrinsics: {focal_rel_sigma: 0.006, principal_point_sigma_px: 3.0,
                                    k1_sigma: 0.01, k2_sigma: 0.01, seed: 11}}   # or: exact
    ring: {distances_m: [3.0, 3.0, 3.0], height_above_floor_m: 1.6, spread_deg: 360, start_deg: 0,
           presets: [l515]}     # cameras on a ring around the robot base ...
    cameras:                    # ... and/or explicit ones
      side: {preset: d455, position_m: [2.0, 1.0, 0.8], look_at_m: [0.5, 0.0, 0.4]}

``robot.joint_offsets_rad`` (7 values, default zeros) gives the simulated arm the error a real
arm's joint zero offsets make: it reports ``q_rad`` = true angles - offsets and ``T_base_flange`` =
the nominal forward kinematics of the reported angles, while the world (images, ground truth)
follows the true angles.

``realism.reported_intrinsics`` says how far the intrinsics each simulated camera reports (the
ones written into the dataset) are from the true ones it renders with
(:mod:`calibgraph.sim.reported_intrinsics`; default: the factory-class values above). ``exact``
makes the cameras report their true intrinsics: an oracle, for tests that need one.

``ring.spread_deg: 360`` spreads cameras evenly around the robot; a smaller spread puts them on
one side (the thesis's one-side layout), centred on ``start_deg`` (0 = in front of the robot,
along base x).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics, preset
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.core.transforms import check_pose, look_at
from calibgraph.io.files import read_yaml
from calibgraph.io.shipped import resolve_shipped
from calibgraph.plan.cell import board_by_name, boxes_from_list, default_T_flange_board
from calibgraph.plan.cell import pose_from_spec as _pose_from_spec
from calibgraph.sim.reported_intrinsics import FACTORY, parse_reported, reported_intrinsics, reported_to_yaml

__all__ = ["Realism", "SimCameraSpec", "Workcell", "board_by_name", "default_T_flange_board", "load_workcell",
           "realism_to_dict", "ring_workcell", "ring_cameras", "workcell_from_dict", "workcell_to_dict"]

# Where the robot presents the board, relative to a camera's azimuth: radius from the base z axis
# and height in the base frame. Cameras aim here, so the board lands near their image centre.
PRESENT_RADIUS_M = 0.5
PRESENT_HEIGHT_M = 0.45


@dataclass(frozen=True)
class Realism:
    """How the simulated sensors differ from ideal ones: degradations of every rendered frame, and
    the intrinsics the cameras report.

    Attributes:
        noise_sigma_dn: Gaussian read noise, in 8-bit digital numbers.
        shot_noise: add signal-dependent (Poisson-like) noise as well.
        blur_sigma_px: Gaussian defocus blur sigma (0 = sharp).
        motion_blur_px: length of a linear motion-blur kernel in a random direction per frame.
        exposure: gain on the rendered radiance (1 = nominal; < 1 darker, > 1 brighter, clipped).
        distortion: render through OpenCV radial/tangential distortion (coefficients in
            ``distortion_coeffs``); the intrinsics reported by the camera include them.
        distortion_coeffs: (k1, k2, p1, p2, k3) used when ``distortion`` is on.
        supersample: render at this integer factor and area-average down (anti-aliasing).
        reported_intrinsics: how far the intrinsics the cameras report are from the true ones the
            images are rendered with: a :class:`~calibgraph.sim.reported_intrinsics.ReportedIntrinsics`
            (default: factory-class errors; YAML: a mapping of its fields, or ``factory``) or
            ``'exact'`` (the true ones: an oracle).
    """

    noise_sigma_dn: float = 2.0
    shot_noise: bool = True
    blur_sigma_px: float = 0.6
    motion_blur_px: float = 0.0
    exposure: float = 1.0
    distortion: bool = False
    distortion_coeffs: tuple = (0.08, -0.12, 0.0005, -0.0004, 0.03)
    supersample: int = 1
    reported_intrinsics: object = FACTORY

    def __post_init__(self):
        object.__setattr__(self, "reported_intrinsics",
                           parse_reported(self.reported_intrinsics, "workcell realism: reported_intrinsics"))
        for name in ("noise_sigma_dn", "blur_sigma_px", "motion_blur_px"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise InputError(f"workcell realism: {name} must be >= 0, got {getattr(self, name)}.")
        if not (self.exposure > 0):
            raise InputError(f"workcell realism: exposure must be > 0, got {self.exposure}.")
        if int(self.supersample) < 1 or int(self.supersample) > 4:
            raise InputError(f"workcell realism: supersample must be 1..4, got {self.supersample}.")
        object.__setattr__(self, "supersample", int(self.supersample))
        object.__setattr__(self, "distortion_coeffs", tuple(float(x) for x in self.distortion_coeffs))
        if len(self.distortion_coeffs) not in (4, 5, 8):
            raise InputError("workcell realism: distortion_coeffs needs 4, 5 or 8 values (k1 k2 p1 p2 [k3 ...]).")


@dataclass(frozen=True)
class SimCameraSpec:
    """One fixed camera of the cell.

    Attributes:
        name: camera name (dataset key).
        T_base_cam: (4, 4) OpenCV optical frame in the robot base frame.
        intrinsics: the true intrinsics the camera renders with (pinhole, plus distortion when the
            realism asks for it); what it reports is :meth:`Workcell.reported_intrinsics`.
        preset: preset name it came from ('' when explicit).
    """

    name: str
    T_base_cam: np.ndarray
    intrinsics: Intrinsics
    preset: str = ""



@dataclass(frozen=True)
class Workcell:
    """A simulated cell: cameras, target and its mount on the flange, image realism.

    Attributes:
        name: label.
        target: the board (checkerboard).
        T_flange_board: (4, 4) board mount.
        cameras: tuple of :class:`SimCameraSpec`.
        realism: :class:`Realism`.
        floor_z_m: floor height in the base frame (the robot stands on a pedestal).
        seed: seed of the image noise and of the robot's kinematic error.
        fk_sigma_translation_m, fk_sigma_rotation_deg: error of the flange pose the robot reports
            (its kinematic model is not exact), 1-sigma per axis, drawn once per pose.
        joint_offsets_rad: (7,) the arm's joint zero offsets (physical angle = reported + offset).
        obstacles: static boxes (:class:`calibgraph.plan.cell.Box`): tables, fences (rendered,
            collide) and keep-out volumes (collide only).
        planning_only: a model of the robot and the static geometry without cameras (what the
            autonomous loop plans in before it knows where the cameras are); nothing renders.
    """

    name: str
    target: Target
    T_flange_board: np.ndarray
    cameras: tuple
    realism: Realism = field(default_factory=Realism)
    floor_z_m: float = -0.8
    seed: int = 0
    fk_sigma_translation_m: float = 5e-5
    fk_sigma_rotation_deg: float = 0.005
    joint_offsets_rad: tuple = (0.0,) * 7
    obstacles: tuple = ()
    planning_only: bool = False

    def __post_init__(self):
        if not (self.fk_sigma_translation_m >= 0 and self.fk_sigma_rotation_deg >= 0):
            raise InputError(f"workcell {self.name!r}: robot fk sigmas must be >= 0.")
        if self.target.kind != "checkerboard":
            raise InputError(f"workcell {self.name!r}: the simulator renders checkerboards only, got {self.target.kind!r}.")
        o = np.asarray(self.joint_offsets_rad, float).reshape(-1)
        if o.size != 7 or not np.all(np.isfinite(o)) or np.any(np.abs(o) > 0.2):
            raise InputError(f"workcell {self.name!r}: robot joint_offsets_rad needs 7 finite values of at most 0.2 rad "
                             f"(one per FR3 joint), got {list(np.asarray(self.joint_offsets_rad).reshape(-1))}.")
        object.__setattr__(self, "joint_offsets_rad", tuple(float(x) for x in o))
        names = [c.name for c in self.cameras]
        if not names and not self.planning_only:
            raise InputError(f"workcell {self.name!r}: no cameras; add a 'ring' or 'cameras' section.")
        if len(set(names)) != len(names):
            raise InputError(f"workcell {self.name!r}: duplicate camera names {', '.join(map(str, names))}.")
        object.__setattr__(self, "cameras", tuple(self.cameras))
        object.__setattr__(self, "obstacles", tuple(self.obstacles))

    @property
    def camera_names(self) -> list:
        return [c.name for c in self.cameras]

    def camera(self, name: str) -> SimCameraSpec:
        for c in self.cameras:
            if c.name == name:
                return c
        raise InputError(f"workcell {self.name!r}: no camera {name!r}; cameras are {self.camera_names}.")

    def reported_intrinsics(self, name: str) -> Intrinsics:
        """The intrinsics camera ``name`` reports (and the dataset holds): its true ones with the
        error ``realism.reported_intrinsics`` draws, ``source='factory'``; the true ones,
        ``source='exact'``, when that is ``'exact'``."""
        return reported_intrinsics(self.camera(name).intrinsics, name, self.realism.reported_intrinsics)

    def intrinsics(self) -> dict:
        """name -> Intrinsics the cameras report (see :meth:`reported_intrinsics`)."""
        return {c.name: self.reported_intrinsics(c.name) for c in self.cameras}

    def true_intrinsics(self) -> dict:
        """name -> the true Intrinsics the images are rendered with."""
        return {c.name: c.intrinsics for c in self.cameras}

    @property
    def oracle_intrinsics(self) -> bool:
        """True when the cameras report their true intrinsics (``reported_intrinsics: exact``)."""
        return self.realism.reported_intrinsics == "exact"

    def with_(self, **changes) -> "Workcell":
        return replace(self, **changes)

    def with_reported_intrinsics(self, reported) -> "Workcell":
        """The same cell whose cameras report ``reported`` ('exact', 'factory', or a
        :class:`~calibgraph.sim.reported_intrinsics.ReportedIntrinsics` or mapping of its fields)."""
        return replace(self, realism=replace(self.realism, reported_intrinsics=reported))



def _camera_intrinsics(preset_name: str, realism: Realism) -> Intrinsics:
    """The simulated camera's true intrinsics, the very values the renderer uses ('exact')."""
    intr = preset(preset_name)
    dist = np.asarray(realism.distortion_coeffs) if realism.distortion else intr.dist
    return Intrinsics(K=intr.K, dist=dist, width_px=intr.width_px, height_px=intr.height_px, source="exact")


def ring_cameras(distances_m, height_above_floor_m: float = 1.6, presets=("l515",), spread_deg: float = 360.0,
                 start_deg: float = 0.0, floor_z_m: float = -0.8, realism: Realism | None = None) -> tuple:
    """Cameras on a ring around the robot base z axis at horizontal ``distances_m``, each aimed at
    the point where the robot presents the board towards it."""
    realism = realism or Realism()
    n = len(distances_m)
    specs = []
    for i, d in enumerate(distances_m):
        if spread_deg >= 360:
            az = start_deg + 360.0 * i / n
        else:
            az = start_deg - spread_deg / 2 + spread_deg * i / max(n - 1, 1)
        a = np.radians(az)
        u = np.array([np.cos(a), np.sin(a), 0.0])
        eye = float(d) * u
        eye[2] = floor_z_m + height_above_floor_m
        aim = PRESENT_RADIUS_M * u + np.array([0, 0, PRESENT_HEIGHT_M])
        p = presets[i % len(presets)]
        specs.append(SimCameraSpec(name=f"cam{i}", T_base_cam=look_at(eye, aim), intrinsics=_camera_intrinsics(p, realism),
                                   preset=p))
    return tuple(specs)


def ring_workcell(n_cameras: int = 3, distance_m: float = 3.0, preset_name: str = "l515", board="a4_7x10_25mm",
                  spread_deg: float = 360.0, height_above_floor_m: float = 1.6, realism: Realism | None = None,
                  distances_m=None, name: str = "ring", seed: int = 0) -> Workcell:
    """A cell with ``n_cameras`` of one preset on a ring at ``distance_m`` (or per-camera ``distances_m``)."""
    if n_cameras < 1:
        raise InputError("a workcell needs at least one camera (--cameras >= 1).")
    if not (0.8 <= distance_m <= 8.0):
        raise InputError(f"camera distance {distance_m} m is outside the simulated range 0.8..8 m.")
    realism = realism or Realism()
    target = board_by_name(board)
    d = list(distances_m) if distances_m is not None else [distance_m] * n_cameras
    cams = ring_cameras(d, height_above_floor_m, (preset_name,), spread_deg, 0.0, -0.8, realism)
    return Workcell(name=name, target=target, T_flange_board=default_T_flange_board(target), cameras=cams,
                    realism=realism, seed=seed)



def workcell_from_dict(d: dict, where: str = "workcell") -> Workcell:
    """Build a :class:`Workcell` from its YAML mapping (see the module docstring)."""
    if not isinstance(d, dict):
        raise InputError(f"{where}: must be a mapping.")
    known = {"name", "board", "floor_z_m", "mount", "realism", "ring", "cameras", "seed", "description", "robot",
             "obstacles", "keep_out"}
    unknown = set(d) - known
    if unknown:
        raise InputError(f"{where}: unknown keys {', '.join(sorted(unknown))}; allowed: {', '.join(sorted(known))}.")
    try:
        realism = Realism(**(d.get("realism") or {}))
    except TypeError as e:
        raise InputError(f"{where}: realism: {e}") from None
    target = board_by_name(d.get("board", "a4_7x10_25mm"))
    floor_z = float(d.get("floor_z_m", -0.8))
    cams = []
    ring = d.get("ring")
    if ring:
        try:
            cams.extend(ring_cameras(ring["distances_m"], float(ring.get("height_above_floor_m", 1.6)),
                                     tuple(ring.get("presets", ["l515"])), float(ring.get("spread_deg", 360.0)),
                                     float(ring.get("start_deg", 0.0)), floor_z, realism))
        except KeyError as e:
            raise InputError(f"{where}: ring needs {e} (list of horizontal distances in metres).") from None
    for name, c in (d.get("cameras") or {}).items():
        p = c.get("preset", "l515")
        if "T_base_cam" in c:

            T = check_pose(np.asarray(c["T_base_cam"], float), f"{where}: camera {name}: T_base_cam")
        elif "position_m" in c:
            T = look_at(np.asarray(c["position_m"], float),
                        np.asarray(c.get("look_at_m", [PRESENT_RADIUS_M, 0, PRESENT_HEIGHT_M]), float))
        else:
            raise InputError(f"{where}: camera {name!r} needs position_m (+ look_at_m) or T_base_cam.")
        cams.append(SimCameraSpec(name=str(name), T_base_cam=T, intrinsics=_camera_intrinsics(p, realism), preset=p))
    mount = d.get("mount")
    T_fb = _pose_from_spec(mount, f"{where}: mount") if mount else default_T_flange_board(target)
    robot = d.get("robot") or {}
    if not isinstance(robot, dict):
        raise InputError(f"{where}: robot must be a mapping (fk_sigma_translation_m, fk_sigma_rotation_deg, joint_offsets_rad).")
    unknown = set(robot) - {"fk_sigma_translation_m", "fk_sigma_rotation_deg", "joint_offsets_rad"}
    if unknown:
        raise InputError(f"{where}: robot: unknown keys {', '.join(sorted(unknown))}; allowed: fk_sigma_translation_m, "
                         "fk_sigma_rotation_deg, joint_offsets_rad.")
    offsets = robot.get("joint_offsets_rad", [0.0] * 7)
    try:
        offsets = tuple(float(x) for x in offsets)
    except (TypeError, ValueError):
        raise InputError(f"{where}: robot: joint_offsets_rad must be a list of 7 numbers (rad), got {offsets!r}.") from None
    return Workcell(name=str(d.get("name", Path(where).stem)), target=target, T_flange_board=T_fb, cameras=tuple(cams),
                    realism=realism, floor_z_m=floor_z, seed=int(d.get("seed", 0)),
                    fk_sigma_translation_m=float(robot.get("fk_sigma_translation_m", 5e-5)),
                    fk_sigma_rotation_deg=float(robot.get("fk_sigma_rotation_deg", 0.005)), joint_offsets_rad=offsets,
                    obstacles=tuple(boxes_from_list(d.get("obstacles"), where, False) + boxes_from_list(d.get("keep_out"), where, True)))


def load_workcell(path) -> Workcell:
    """Read a workcell YAML file."""

    p = resolve_shipped(path, "workcell")  # a shipped name or datasets/workcells/... from any folder
    d = read_yaml(p, "workcell file", mapping=False)
    return workcell_from_dict(d, str(p))


def workcell_to_dict(cell: Workcell) -> dict:
    """Explicit (camera poses spelled out) YAML mapping of a workcell; round-trips through
    :func:`workcell_from_dict`."""
    return {
        "name": cell.name,
        "board": cell.target.to_dict(),
        "floor_z_m": cell.floor_z_m,
        "mount": {"T": np.asarray(cell.T_flange_board).tolist()},
        "realism": realism_to_dict(cell.realism),
        "cameras": {c.name: {"preset": c.preset or "l515", "T_base_cam": np.asarray(c.T_base_cam).tolist()}
                    for c in cell.cameras},
        "seed": cell.seed,
        "robot": {"fk_sigma_translation_m": cell.fk_sigma_translation_m, "fk_sigma_rotation_deg": cell.fk_sigma_rotation_deg,
                  "joint_offsets_rad": list(cell.joint_offsets_rad)},
        **_boxes_to_dict(cell.obstacles),
    }


def realism_to_dict(realism: Realism) -> dict:
    """The YAML mapping of a :class:`Realism` (round-trips through ``Realism(**mapping)``)."""
    d = {f: getattr(realism, f) for f in realism.__dataclass_fields__}
    d["reported_intrinsics"] = reported_to_yaml(realism.reported_intrinsics)
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}


def _boxes_to_dict(boxes) -> dict:
    out = {}
    for b in boxes:
        out.setdefault("keep_out" if b.keep_out else "obstacles", []).append(
            {"name": b.name, "centre_m": b.centre_m.tolist(), "size_m": b.size_m.tolist()})
    return out
