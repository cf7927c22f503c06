"""The trajectory: robot poses for a calibration run, and its file (``calibgraph-trajectory/1``).

Written by the planner (:mod:`calibgraph.plan.planner`) or by hand, replayed by the acquisition
(:mod:`calibgraph.acquire.run`) on a simulated or real robot::

    format: calibgraph-trajectory/1
    speed_scale: 0.2
    poses:
      - q_rad: [7 joint angles]
        T_base_flange: 4x4 (m)     # expected flange pose
        cameras: [cam0, cam1]      # cameras expected to see the whole board
      - q_rad: [...]               # a via pose: moved through, nothing captured
        capture: false
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import check_pose
from calibgraph.io.files import atomic_write_bytes, read_yaml

TRAJECTORY_FORMAT = "calibgraph-trajectory/1"


# -- trajectory --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrajectoryPose:
    """One pose of a trajectory.

    Attributes:
        q_rad: (n,) joint target.
        T_base_flange: (4, 4) planned flange pose at ``q_rad``, or None (used by the safety
            checks when the robot offers no forward kinematics).
        cameras: names of the cameras expected to see the whole board (what the planner aimed
            for; advisory, the acquisition grabs every live camera).
        capture: False for a via (transit) pose: the robot moves there and settles, nothing is
            grabbed or written. The planner inserts via poses where the straight joint path
            between two capture poses would collide.
    """

    q_rad: np.ndarray
    T_base_flange: np.ndarray | None = None
    cameras: tuple = ()
    capture: bool = True

    def __post_init__(self):
        try:
            q = np.asarray(self.q_rad, float).reshape(-1)
        except (TypeError, ValueError):
            raise InputError(f"trajectory pose: q_rad must be a list of joint angles (rad), got {self.q_rad!r}.") from None
        if q.size == 0 or not np.all(np.isfinite(q)):
            raise InputError(f"trajectory pose: q_rad must be a finite joint vector, got {np.asarray(self.q_rad).tolist()}.")
        object.__setattr__(self, "q_rad", q)
        if self.T_base_flange is not None:

            object.__setattr__(self, "T_base_flange", check_pose(self.T_base_flange, "trajectory pose T_base_flange"))
        cams = self.cameras
        if cams is None:
            cams = ()
        elif isinstance(cams, str):
            cams = (cams,)
        if not isinstance(cams, (list, tuple)) or not all(isinstance(c, str) and c for c in cams):
            raise InputError(f"trajectory pose: cameras must be a list of camera names, got {self.cameras!r}.")
        object.__setattr__(self, "cameras", tuple(cams))
        if not isinstance(self.capture, (bool, np.bool_)):
            raise InputError(f"trajectory pose: capture must be true or false, got {self.capture!r}.")
        object.__setattr__(self, "capture", bool(self.capture))
        if not self.capture and self.cameras:
            raise InputError("trajectory pose: a via pose (capture: false) cannot list cameras expected to see the board.")


@dataclass(frozen=True)
class Trajectory:
    """Robot poses to visit in order, the speed to move at, and where the plan came from.

    Attributes:
        poses: :class:`TrajectoryPose` (or bare joint vectors), visited in order.
        speed_scale: fraction of the robot's maximum joint velocity, in (0, 1].
        workcell: name of the workcell it was planned for ("" when unknown).
        seed: seed of the planner, or None.
        notes: free-text remarks of the planner (e.g. poses dropped for want of a free path).
    """

    poses: tuple
    speed_scale: float = 0.2
    workcell: str = ""
    seed: int | None = None
    notes: tuple = ()

    def __post_init__(self):
        poses = tuple(p if isinstance(p, TrajectoryPose) else TrajectoryPose(q_rad=p) for p in self.poses)
        if not poses:
            raise InputError("trajectory: no poses.")
        n = {p.q_rad.size for p in poses}
        if len(n) != 1:
            raise InputError(f"trajectory: poses have different joint counts {sorted(n)}.")
        object.__setattr__(self, "poses", poses)
        try:
            ok = bool(np.isfinite(self.speed_scale) and 0 < self.speed_scale <= 1)
        except TypeError:
            ok = False
        if not ok:
            raise InputError(f"trajectory: speed_scale must be in (0, 1], got {self.speed_scale!r}.")
        object.__setattr__(self, "speed_scale", float(self.speed_scale))
        object.__setattr__(self, "workcell", str(self.workcell or ""))
        if self.seed is not None:
            if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)):
                raise InputError(f"trajectory: seed must be an integer or absent, got {self.seed!r}.")
            object.__setattr__(self, "seed", int(self.seed))
        notes = (self.notes,) if isinstance(self.notes, str) else tuple(self.notes or ())
        object.__setattr__(self, "notes", tuple(str(x) for x in notes))

    def __len__(self) -> int:
        return len(self.poses)

    @property
    def n_capture(self) -> int:
        """Number of capture poses (via poses excluded)."""
        return sum(p.capture for p in self.poses)

    @property
    def n_via(self) -> int:
        """Number of via (transit) poses."""
        return len(self.poses) - self.n_capture

    def views_per_camera(self) -> dict:
        """camera -> number of capture poses planned to show it the whole board."""
        out = {}
        for p in self.poses:
            if p.capture:
                for c in p.cameras:
                    out[c] = out.get(c, 0) + 1
        return out

    def to_dict(self) -> dict:
        """The ``calibgraph-trajectory/1`` mapping; ``cameras``/``capture`` only when not default."""
        ps = []
        for p in self.poses:
            d = {"q_rad": p.q_rad.tolist()}
            if p.T_base_flange is not None:
                d["T_base_flange"] = p.T_base_flange.tolist()
            if p.cameras:
                d["cameras"] = list(p.cameras)
            if not p.capture:
                d["capture"] = False
            ps.append(d)
        d = {"format": TRAJECTORY_FORMAT,
             "frame_convention": "T_a_b maps points from frame b to frame a (p_a = T_a_b @ p_b), metres, radians",
             "speed_scale": float(self.speed_scale)}
        if self.workcell:
            d["workcell"] = self.workcell
        if self.seed is not None:
            d["seed"] = self.seed
        if self.notes:
            d["notes"] = list(self.notes)
        d["poses"] = ps
        return d

    @classmethod
    def from_dict(cls, d, where: str = "trajectory") -> "Trajectory":
        """Build from a mapping (or a bare list of joint vectors); errors name ``where`` and the pose."""
        if isinstance(d, list):
            d = {"poses": d}
        if not isinstance(d, dict) or "poses" not in d:
            raise InputError(f"{where}: expected a mapping with 'poses' (see calibgraph.acquire.run docstring).")
        if d.get("format", TRAJECTORY_FORMAT) != TRAJECTORY_FORMAT:
            raise InputError(f"{where}: unsupported format {d.get('format')!r}; expected {TRAJECTORY_FORMAT}.")
        raw = d["poses"] or []
        if not isinstance(raw, list):
            raise InputError(f"{where}: 'poses' must be a list, got {type(raw).__name__}.")
        poses = []
        for k, p in enumerate(raw):
            try:
                if isinstance(p, dict):
                    unknown = set(p) - {"q_rad", "T_base_flange", "cameras", "capture"}
                    if unknown:
                        raise InputError(f"unknown keys {', '.join(sorted(unknown))} (allowed: q_rad, T_base_flange, cameras, capture)")
                    poses.append(TrajectoryPose(q_rad=p["q_rad"], T_base_flange=p.get("T_base_flange"),
                                                cameras=p.get("cameras") or (), capture=p.get("capture", True)))
                else:
                    poses.append(TrajectoryPose(q_rad=p))
            except KeyError as e:
                raise InputError(f"{where}: pose {k}: missing {e}; each pose needs q_rad.") from None
            except (InputError, TypeError, ValueError) as e:
                raise InputError(f"{where}: pose {k}: {e}") from None
        try:
            speed = float(d.get("speed_scale", 0.2))
        except (TypeError, ValueError):
            raise InputError(f"{where}: speed_scale must be a number in (0, 1], got {d.get('speed_scale')!r}.") from None
        try:
            return cls(poses=tuple(poses), speed_scale=speed, workcell=d.get("workcell") or "", seed=d.get("seed"),
                       notes=d.get("notes") or ())
        except InputError as e:
            raise InputError(f"{where}: {e}") from None

    def sha256(self) -> str:
        """Fingerprint of what the robot does: joint targets, planned flange poses, capture flags
        and speed (rounded to 1e-9, so a YAML round trip keeps it). ``cameras``, ``workcell``,
        ``seed`` and ``notes`` are bookkeeping and left out, so a trajectory without via poses
        hashes exactly as before those keys existed (and resume accepts it)."""
        poses = []
        for p in self.poses:
            d = {"q_rad": np.round(p.q_rad, 9).tolist()}
            if p.T_base_flange is not None:
                d["T_base_flange"] = np.round(p.T_base_flange, 9).tolist()
            if not p.capture:
                d["capture"] = False
            poses.append(d)
        d = {"format": TRAJECTORY_FORMAT, "speed_scale": round(float(self.speed_scale), 9), "poses": poses}
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def save(self, path) -> Path:
        """Write the trajectory YAML atomically (tmp + rename); returns the path."""
        import yaml

        p = Path(path)
        atomic_write_bytes(p, yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None,
                                              width=200).encode())
        return p

    @classmethod
    def load(cls, path) -> "Trajectory":
        """Read a trajectory YAML (or JSON) file."""

        p = Path(path)
        return cls.from_dict(read_yaml(p, "trajectory", mapping=False), where=str(p))


def load_trajectory(path) -> Trajectory:
    """Read a trajectory YAML (or JSON) file."""
    return Trajectory.load(path)


def save_trajectory(traj: Trajectory, path) -> Path:
    """Write ``traj`` as YAML atomically; returns the path."""
    return traj.save(path)
