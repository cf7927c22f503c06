"""Robot poses for a calibration run: reachable flange poses that show the board to every camera.

The thesis drove the arm along a predefined, hand-written trajectory; here it is generated. For
each camera in turn (and for pairs of neighbouring cameras, so that some captures are seen by
several cameras at once) a board pose is sampled in front of the camera with a varied tilt, the
flange pose follows through the board mount, and inverse kinematics on the arm model finds joint
angles within the limits. A pose is kept only when MuJoCo finds no collision (self, camera stands,
floor) and the board is fully visible, unoccluded and large enough in the intended camera(s).

A :class:`Trajectory` is saved as YAML and replayed by ``calibgraph sim`` (or on hardware, after
checking it against the real cell)::

    format: calibgraph-trajectory/1
    frame_convention: T_a_b maps points from frame b to frame a
    poses:
      - q_rad: [7 joint angles]
        T_base_flange: 4x4 (m)     # expected flange pose
        cameras: [cam0, cam1]      # cameras expected to see the whole board

Needs the simulator (MuJoCo, franky-sim); it is imported when a plan is made.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .transforms import check_pose, exp_so3, inv, make_T

FORMAT = "calibgraph-trajectory/1"


@dataclass(frozen=True)
class TrajectoryPose:
    """One planned robot pose.

    Attributes:
        q_rad: (7,) joint angles.
        T_base_flange: (4, 4) flange pose expected at ``q_rad``.
        cameras: names of the cameras expected to see the whole board.
    """

    q_rad: np.ndarray
    T_base_flange: np.ndarray
    cameras: tuple = ()

    def __post_init__(self):
        q = np.asarray(self.q_rad, float).reshape(-1)
        if not np.all(np.isfinite(q)):
            raise InputError("trajectory pose: joint angles contain NaN/inf.")
        object.__setattr__(self, "q_rad", q)
        object.__setattr__(self, "T_base_flange", check_pose(self.T_base_flange, "trajectory pose: T_base_flange"))
        object.__setattr__(self, "cameras", tuple(str(c) for c in self.cameras))


@dataclass(frozen=True)
class Trajectory:
    """An ordered list of :class:`TrajectoryPose` (plus where it came from)."""

    poses: tuple
    workcell: str = ""
    seed: int | None = None
    speed_scale: float = 0.2

    def __post_init__(self):
        object.__setattr__(self, "poses", tuple(self.poses))
        if not (0 < self.speed_scale <= 1):
            raise InputError(f"trajectory: speed_scale must be in (0, 1], got {self.speed_scale}.")

    def to_acquire(self):
        """The same poses as a :class:`calibgraph.acquire.Trajectory` (what the capture state
        machine executes; it ignores the expected-camera lists)."""
        from .acquire import Trajectory as AcqTrajectory, TrajectoryPose as AcqPose

        return AcqTrajectory(poses=tuple(AcqPose(q_rad=p.q_rad, T_base_flange=p.T_base_flange) for p in self.poses),
                             speed_scale=self.speed_scale)

    def __len__(self) -> int:
        return len(self.poses)

    def views_per_camera(self) -> dict:
        out = {}
        for p in self.poses:
            for c in p.cameras:
                out[c] = out.get(c, 0) + 1
        return out

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "frame_convention": "T_a_b maps points from frame b to frame a (p_a = T_a_b @ p_b), metres, radians",
            "workcell": self.workcell,
            "seed": self.seed,
            "speed_scale": float(self.speed_scale),
            "poses": [{"q_rad": [float(x) for x in p.q_rad], "T_base_flange": np.round(p.T_base_flange, 10).tolist(),
                       "cameras": list(p.cameras)} for p in self.poses],
        }

    def save(self, path) -> Path:
        import yaml

        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None, width=200))
        return p

    @classmethod
    def from_dict(cls, d: dict, where: str = "trajectory") -> "Trajectory":
        if not isinstance(d, dict) or "poses" not in d:
            raise InputError(f"{where}: not a trajectory file (needs a 'poses' list).")
        if d.get("format", FORMAT) != FORMAT:
            raise InputError(f"{where}: unsupported format {d.get('format')!r}; expected {FORMAT}.")
        poses = []
        for i, p in enumerate(d["poses"] or []):
            try:
                poses.append(TrajectoryPose(q_rad=p["q_rad"], T_base_flange=p["T_base_flange"],
                                            cameras=p.get("cameras") or ()))
            except (KeyError, TypeError) as e:
                raise InputError(f"{where}: pose {i}: missing or malformed {e}; each pose needs q_rad and T_base_flange.") from None
            except InputError as e:
                raise InputError(f"{where}: pose {i}: {e}") from None
        return cls(poses=tuple(poses), workcell=str(d.get("workcell") or ""), seed=d.get("seed"),
                   speed_scale=float(d.get("speed_scale", 0.2)))


def load_trajectory(path) -> Trajectory:
    """Read a trajectory YAML file."""
    from .yamlio import read_yaml

    p = Path(path)
    d = read_yaml(p, "trajectory", mapping=False)
    return Trajectory.from_dict(d, str(p))


# -- visibility ---------------------------------------------------------------------------------------

def board_visibility(world, cam_name: str, T_base_board: np.ndarray, margin_px: float = 12.0,
                     max_angle_deg: float = 60.0, min_square_px: float = 7.0, check_occlusion: bool = True) -> bool:
    """True when camera ``cam_name`` sees every board point: in front, inside the image (with a
    margin), the board facing it within ``max_angle_deg``, squares at least ``min_square_px``
    wide, and (optionally) no robot link or other geometry in the way (MuJoCo ray casts)."""
    cell = world.cell
    spec = cell.camera(cam_name)
    target = cell.target
    pts_b = target.points_board_m
    T_cb = inv(spec.T_base_cam) @ T_base_board
    p_c = pts_b @ T_cb[:3, :3].T + T_cb[:3, 3]
    if np.any(p_c[:, 2] < 0.2):
        return False
    # the printed face looks along -z_board: the camera must be on that side
    cam_in_board = inv(T_cb)[:3, 3]
    if cam_in_board[2] >= 0:
        return False
    centre_c = p_c.mean(axis=0)
    n_c = T_cb[:3, 2]
    cosang = float(n_c @ centre_c / np.linalg.norm(centre_c))
    if cosang < np.cos(np.radians(max_angle_deg)):
        return False
    uv = spec.intrinsics.project(p_c)
    if not np.all(spec.intrinsics.in_image(uv, margin_px=margin_px)):
        return False
    grid = uv.reshape(target.rows, target.cols, 2)
    step = min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(), np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
    if step < min_square_px:
        return False
    if check_occlusion:
        mj = world.mujoco
        origin = spec.T_base_cam[:3, 3].astype(np.float64)
        p_base = pts_b @ T_base_board[:3, :3].T + T_base_board[:3, 3]
        # outer points and the centre: a link crossing the board hides at least one of them
        ids = _probe_ids(target.rows, target.cols)
        geomgroup = np.array([1, 1, 1, 0, 0, 0], np.uint8)  # rendered groups only
        gid = np.zeros(1, np.int32)
        for k in ids:
            v = p_base[k] - origin
            dist = np.linalg.norm(v)
            hit = mj.mj_ray(world.model, world.data, origin, v / dist, geomgroup, 1, world.board_body, gid)
            if hit >= 0 and hit < dist - 2e-3:
                return False
    return True


def _probe_ids(rows: int, cols: int) -> list:
    ids = set()
    for i in (0, rows // 2, rows - 1):
        for j in (0, cols // 3, (2 * cols) // 3, cols - 1):
            ids.add(i * cols + j)
    return sorted(ids)


def visible_cameras(world, T_base_board: np.ndarray, **kw) -> tuple:
    """Cameras that see the whole board at the world's current configuration."""
    return tuple(c.name for c in world.cell.cameras if board_visibility(world, c.name, T_base_board, **kw))


# -- generation --------------------------------------------------------------------------------------

def _board_pose_facing(eye_m, centre_m, tilt_rad, roll_rad, rng, centre_b):
    """T_base_board with the board centre at ``centre_m`` and its printed face (-z) towards ``eye_m``,
    tilted by ``tilt_rad`` about a random in-plane axis and rolled by ``roll_rad``."""
    z = centre_m - eye_m
    z /= np.linalg.norm(z)
    up = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, up)  # board x horizontal; y then points down on a hanging sheet
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.column_stack([x, y, z])
    a = rng.uniform(0, 2 * np.pi)
    R = R @ exp_so3(tilt_rad * np.array([np.cos(a), np.sin(a), 0.0])) @ exp_so3([0.0, 0.0, roll_rad])
    return make_T(R, centre_m - R @ centre_b)


def plan_trajectory(world, n_poses: int = 60, seed: int = 0, shared_fraction: float = 0.3, tilt_deg: float = 35.0,
                    roll_deg: float = 30.0, radius_m=(0.38, 0.62), height_m=(0.25, 0.7), max_attempts: int | None = None,
                    progress=None) -> Trajectory:
    """Generate ``n_poses`` reachable, collision-free poses that show the board to the cameras.

    Args:
        world: :class:`calibgraph.sim.render.SimWorld` of the cell (its model is used for IK,
            collisions and occlusion ray casts; nothing is rendered).
        n_poses: poses wanted; cameras are served round robin so each gets a similar share.
        shared_fraction: fraction of poses aimed between two neighbouring cameras (seen by both
            when the geometry allows).
        tilt_deg: maximum tilt of the board away from facing the camera.
        roll_deg: maximum in-plane rotation of the board.
        radius_m, height_m: where the board centre is placed (distance from the base z axis,
            height in the base frame).
        progress: optional callable(n_done, n_total).
    Raises:
        InputError when fewer than ``n_poses`` poses were found (camera too far, board too small,
        cameras outside the arm's reach).
    """
    from .sim.ik import in_collision, solve_ik

    rng = np.random.default_rng(seed)
    cell = world.cell
    names = cell.camera_names
    eyes = {c.name: c.T_base_cam[:3, 3] for c in cell.cameras}
    az = {n: np.arctan2(eyes[n][1], eyes[n][0]) for n in names}
    centre_b = cell.target.points_board_m.mean(axis=0)
    T_fb_inv = inv(cell.T_flange_board)
    # neighbour in azimuth for shared poses, only when the two are less than 130 degrees apart
    neighbour = {}
    for n in names:
        others = [(abs(np.angle(np.exp(1j * (az[o] - az[n])))), o) for o in names if o != n]
        if others:
            d, o = min(others)
            if d < np.radians(130):
                neighbour[n] = o
    poses, q_prev = [], None
    max_attempts = max_attempts or 60 * n_poses
    attempts = 0
    k = 0
    while len(poses) < n_poses and attempts < max_attempts:
        attempts += 1
        cam = names[k % len(names)]
        pair = neighbour.get(cam) if rng.uniform() < shared_fraction else None
        if pair is not None:
            a = np.angle(np.exp(1j * az[cam]) + np.exp(1j * az[pair]))
            eye = 0.5 * (eyes[cam] + eyes[pair])
            want = {cam, pair}
            tilt = np.radians(tilt_deg) * rng.uniform(0.0, 0.4)
        else:
            a = az[cam]
            eye = eyes[cam]
            want = {cam}
            tilt = np.radians(tilt_deg) * rng.uniform(0.3, 1.0)
        a += rng.uniform(-1, 1) * np.radians(20)
        r = rng.uniform(*radius_m)
        centre = np.array([r * np.cos(a), r * np.sin(a), rng.uniform(*height_m)])
        T_bb = _board_pose_facing(eye, centre, tilt, np.radians(roll_deg) * rng.uniform(-1, 1), rng, centre_b)
        T_bf = T_bb @ T_fb_inv
        seeds = []
        if q_prev is not None and abs(np.angle(np.exp(1j * (q_prev[0] - a)))) < 0.6:
            seeds.append(q_prev)
        base = np.array([a, 0.1, 0.0, -2.0, 0.0, 2.0, 0.785])
        seeds += [base, base + rng.normal(scale=0.4, size=7), base + rng.normal(scale=0.8, size=7)]
        q = None
        for s in seeds:
            q = solve_ik(world, T_bf, s)
            if q is not None and not in_collision(world, q):
                break
            q = None
        if q is None:
            continue
        world.set_q(q)
        seen = visible_cameras(world, world.T_base_board())
        if not want <= set(seen):
            continue
        poses.append(TrajectoryPose(q_rad=q, T_base_flange=world.T_base_flange(), cameras=seen))
        q_prev = q
        k += 1
        if progress:
            progress(len(poses), n_poses)
    if len(poses) < n_poses:
        per = Trajectory(tuple(poses)).views_per_camera()
        raise InputError(
            f"planned only {len(poses)} of {n_poses} poses after {attempts} attempts (views per camera: {per}); "
            "move the cameras closer, use a larger board, or ask for fewer poses."
        )
    # visit in order of base rotation so the arm sweeps round the cell instead of zig-zagging
    order = np.argsort([np.round(p.q_rad[0], 1) for p in poses], kind="stable")
    return Trajectory(poses=tuple(poses[i] for i in order), workcell=cell.name, seed=seed)
