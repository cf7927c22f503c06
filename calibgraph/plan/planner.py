"""Robot poses for a calibration run: reachable flange poses that show the board to every camera,
joined by collision-free motions.

The thesis drove the arm along a predefined, hand-written trajectory; here it is generated. For
each camera in turn (and for pairs of neighbouring cameras, so that some captures are seen by
several cameras at once) a board pose is sampled in front of the camera with a varied tilt, the
flange pose follows through the board mount, and inverse kinematics on the arm model finds joint
angles within the limits. A pose is kept only when MuJoCo finds no collision (self, camera stands,
floor) and the board is fully visible, unoccluded and large enough in the intended camera(s).

The poses are then ordered by base rotation and the motions between them are checked: every
driver moves along the straight joint-space line between consecutive poses (see
:mod:`calibgraph.acquire.safety`), and a big base swing with the arm stretched out can sweep a link or
the board through the pedestal. Where a motion collides, one or two via poses (``capture:
false``, a compact transit posture at the base angle of either end) are inserted; a pose that
no via reaches freely is dropped and replaced by a new one. The result has ``n_poses`` capture
poses and a collision-free motion from the arm's start configuration through every pose.

The trajectory is the one :class:`calibgraph.plan.trajectory.Trajectory` (re-exported here), saved as
``calibgraph-trajectory/1`` YAML and replayed by ``calibgraph sim`` (or on hardware, after
checking it against the real cell)::

    format: calibgraph-trajectory/1
    frame_convention: T_a_b maps points from frame b to frame a
    poses:
      - q_rad: [7 joint angles]
        T_base_flange: 4x4 (m)     # expected flange pose
        cameras: [cam0, cam1]      # cameras expected to see the whole board
      - q_rad: [...]               # a via pose: moved through, nothing captured
        T_base_flange: 4x4
        capture: false

The arm model comes in as a :class:`RobotWorld`; today the simulator's (MuJoCo, franky-sim) is the one implementation.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import board_facing, inv, make_T
from calibgraph.plan.trajectory import Trajectory, TrajectoryPose
from calibgraph.plan.visibility import visible_cameras

__all__ = ["RobotWorld", "plan_trajectory", "free_motion", "TRANSIT_Q_RAD"]

# Compact transit posture (elbow folded, board held close above the base); its joint 1 is set to
# the base angle of the motion it serves. It is the simulator's home posture.
TRANSIT_Q_RAD = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785])


class RobotWorld(Protocol):
    """What the planner needs of a cell: the cameras, the board mount, and a model of the arm.

    :class:`calibgraph.sim.render.SimWorld` implements it on MuJoCo (the simulator's FR3 and the
    cell's geometry). Methods that set joint angles move the model only; the planner restores
    the state it found.
    """

    cell: object  # .cameras (name, T_base_cam, intrinsics), .camera(name), .target, .T_flange_board, .name
    q_lo: np.ndarray  # (7,) joint limits, rad
    q_hi: np.ndarray
    limit_margin_rad: float

    def q(self) -> np.ndarray: ...
    def set_q(self, q_rad) -> None: ...
    def T_base_flange(self) -> np.ndarray: ...
    def T_base_board(self) -> np.ndarray: ...
    def solve_ik(self, T_base_flange: np.ndarray, q_seed) -> np.ndarray | None: ...
    def in_collision(self, q_rad) -> list: ...
    def path_collision(self, q0_rad, q1_rad, max_step_rad: float) -> list: ...
    def start_configuration(self) -> np.ndarray: ...
    def occluded(self, origin_m: np.ndarray, points_m: np.ndarray) -> bool: ...


# -- generation --------------------------------------------------------------------------------------

def _board_pose_facing(eye_m, centre_m, tilt_rad, roll_rad, rng, centre_b):
    """T_base_board with the board centre at ``centre_m`` and its printed face (-z) towards ``eye_m``,
    tilted by ``tilt_rad`` about a random in-plane axis and rolled by ``roll_rad``."""
    a = rng.uniform(0, 2 * np.pi)
    tilt = tilt_rad * np.array([np.cos(a), np.sin(a), 0.0])
    return board_facing(eye_m, centre_m, tilt, roll_rad) @ make_T(np.eye(3), -np.asarray(centre_b))


def plan_trajectory(world, n_poses: int = 60, seed: int = 0, shared_fraction: float = 0.3, tilt_deg: float = 50.0,
                    roll_deg: float = 30.0, radius_m=(0.30, 0.75), height_m=(0.15, 0.80), max_attempts: int | None = None,
                    progress=None, q_start=None, max_step_rad: float = 0.03,
                    min_square_px: float = 7.0) -> Trajectory:
    """Generate ``n_poses`` reachable, collision-free poses that show the board to the cameras,
    joined by collision-free motions (via poses inserted where needed).

    Args:
        world: the cell as a :class:`RobotWorld` (e.g. :class:`calibgraph.sim.render.SimWorld`; its
            model is used for IK, collisions and occlusion; nothing is rendered). Its state is restored on return.
        n_poses: capture poses wanted (via poses come on top); cameras are served round robin so
            each gets a similar share.
        shared_fraction: fraction of poses aimed between two neighbouring cameras (seen by both
            when the geometry allows).
        tilt_deg: maximum tilt of the board away from facing the camera.
        roll_deg: maximum in-plane rotation of the board.
        radius_m, height_m: where the board centre is placed (distance from the base z axis,
            height in the base frame). The defaults use most of the FR3's reach: spreading the
            board over depth and height decouples each camera's position from its rotation
            (figures: ``scripts/results/design_figures.md``).
        max_attempts: pose samples allowed in all (default 60 per pose).
        progress: optional callable(n_done, n_total).
        q_start: (7,) joint angles the robot starts from (default
            ``world.start_configuration()``: the world's state when it is a valid
            arm configuration, else the simulator's home, where :class:`~calibgraph.sim.devices.SimRobot`
            starts).
        max_step_rad: joint step between collision samples along each motion.
        min_square_px: smallest square (pixels) a camera must see for a pose to count for it; far
            cameras with small boards need less (the detector up-scales down to ~4 px squares).
    Returns:
        a :class:`Trajectory` whose first motion (from ``q_start``) and every motion between
        consecutive poses is collision-free; ``notes`` says how many via poses were inserted and
        which poses were replaced.
    Raises:
        InputError when fewer than ``n_poses`` poses were found (camera too far, board too small,
        cameras outside the arm's reach) or could be joined by free motions.
    """
    q_saved = world.q()
    try:
        q0 = world.start_configuration() if q_start is None else np.asarray(q_start, float).reshape(-1)
        return _plan(world, n_poses, seed, shared_fraction, tilt_deg, roll_deg, radius_m, height_m, max_attempts,
                     progress, q0, max_step_rad, min_square_px)
    finally:
        world.set_q(q_saved)


def _plan(world, n_poses, seed, shared_fraction, tilt_deg, roll_deg, radius_m, height_m, max_attempts, progress,
          q_start, max_step_rad, min_square_px=7.0) -> Trajectory:
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
    max_attempts = max_attempts or 60 * n_poses
    state = {"attempts": 0, "k": 0, "q_prev": None, "reported": 0}

    def sample(poses, n_wanted):
        """Append sampled poses to ``poses`` until it holds ``n_wanted`` or the budget is spent."""
        while len(poses) < n_wanted and state["attempts"] < max_attempts:
            state["attempts"] += 1
            cam = names[state["k"] % len(names)]
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
            q_prev = state["q_prev"]
            if q_prev is not None and abs(np.angle(np.exp(1j * (q_prev[0] - a)))) < 0.6:
                seeds.append(q_prev)
            base = np.array([a, 0.1, 0.0, -2.0, 0.0, 2.0, 0.785])
            seeds += [base, base + rng.normal(scale=0.4, size=7), base + rng.normal(scale=0.8, size=7)]
            q = None
            for s in seeds:
                q = world.solve_ik(T_bf, s)
                if q is not None and not world.in_collision(q):
                    break
                q = None
            if q is None:
                continue
            world.set_q(q)
            seen = visible_cameras(world, world.T_base_board(), min_square_px=min_square_px)
            if not want <= set(seen):
                continue
            poses.append(TrajectoryPose(q_rad=q, T_base_flange=world.T_base_flange(), cameras=seen))
            state["q_prev"] = q
            state["k"] += 1
            if progress and len(poses) > state["reported"]:  # replacements of dropped poses do not step back
                state["reported"] = len(poses)
                progress(len(poses), n_poses)

    poses, dropped, notes = [], [], []
    while True:
        sample(poses, n_poses)
        if len(poses) < n_poses:
            per = _views(poses)
            lost = (f"; {len(dropped)} more were found but no collision-free motion reached them" if dropped else "")
            raise InputError(
                f"planned only {len(poses)} of {n_poses} poses after {state['attempts']} attempts (views per camera: "
                f"{per}){lost}; move the cameras closer, use a larger board, or ask for fewer poses."
            )
        # visit in order of base rotation so the arm sweeps round the cell instead of zig-zagging
        order = np.argsort([np.round(p.q_rad[0], 1) for p in poses], kind="stable")
        seq, cut = _connect(world, q_start, [poses[i] for i in order], max_step_rad)
        if not cut:
            break
        for p, hit in cut:
            dropped.append(p)
            notes.append(f"dropped a pose at joint 1 = {p.q_rad[0]:.2f} rad: no free motion to it even through a "
                         f"transit pose ({hit[0]} hits {hit[1]}); replaced by a new one")
        keep = {id(p) for p, _ in cut}
        poses = [p for p in poses if id(p) not in keep]
    n_via = sum(not p.capture for p in seq)
    if n_via:
        notes.insert(0, f"{n_via} via poses inserted where the straight joint motion between two poses collides")
    return Trajectory(poses=tuple(seq), workcell=cell.name, seed=seed, notes=tuple(notes))


def free_motion(world, q0_rad, q1_rad, max_step_rad: float = 0.03):
    """Joint targets ``[via..., q1]`` whose straight joint motions from ``q0`` are collision-free
    (no via when the direct motion is), or None when no transit pose helps. The world's state is
    restored."""
    q_saved = world.q()
    try:
        q0, q1 = np.asarray(q0_rad, float), np.asarray(q1_rad, float)
        if not world.path_collision(q0, q1, max_step_rad):
            return [q1.copy()]
        vias = _find_vias(world, q0, q1, max_step_rad)
        return None if vias is None else [*vias, q1.copy()]
    finally:
        world.set_q(q_saved)


def _views(poses) -> dict:
    out = {}
    for p in poses:
        for c in p.cameras:
            out[c] = out.get(c, 0) + 1
    return out


def _connect(world, q_start, poses, max_step_rad):
    """Walk ``poses`` from ``q_start``; where a motion collides insert via poses, and where no via
    helps leave the pose out. Returns (sequence with via poses, [(left-out pose, contact pair)])."""
    seq, cut = [], []
    q = np.asarray(q_start, float)
    for p in poses:
        hit = world.path_collision(q, p.q_rad, max_step_rad)
        if hit:
            vias = _find_vias(world, q, p.q_rad, max_step_rad)
            if vias is None:
                cut.append((p, hit[0]))
                continue
            for v in vias:
                world.set_q(v)
                seq.append(TrajectoryPose(q_rad=v, T_base_flange=world.T_base_flange(), capture=False))
        seq.append(p)
        q = p.q_rad
    return seq, cut


def _transit(world, a_rad, wrist=None):
    """The transit posture at base angle ``a_rad`` (optionally keeping the wrist joints 5-7 of
    another pose), or None when it breaks a joint limit or collides."""
    q = TRANSIT_Q_RAD.copy()
    q[0] = a_rad
    if wrist is not None:
        q[4:] = wrist
    if np.any(q < world.q_lo + world.limit_margin_rad) or np.any(q > world.q_hi - world.limit_margin_rad):
        return None
    if world.in_collision(q):
        return None
    return q


def _find_vias(world, q0, q1, max_step_rad):
    """One or two transit poses making ``q0 -> vias -> q1`` collision-free, or None.

    Candidates, fewest motions first: fold the arm at the goal's base angle (then extend), at the
    start's base angle (then swing), fold at the start's angle and swing folded to the goal's;
    each also with the wrist (joints 5-7) of the nearer end held, which keeps the board from
    spinning past the links."""
    a0, a1 = float(q0[0]), float(q1[0])
    am = 0.5 * (a0 + a1)
    cands = []
    for keep_wrist in (False, True):
        w0, w1 = (q0[4:], q1[4:]) if keep_wrist else (None, None)
        t0, t1 = _transit(world, a0, w0), _transit(world, a1, w1)
        cands += [(t1,), (t0,), (t0, t1), (_transit(world, am, w1),)]
    tried = set()
    for vias in cands:
        if any(v is None for v in vias):
            continue
        key = tuple(np.round(np.concatenate(vias), 6))
        if key in tried:
            continue
        tried.add(key)
        chain = [q0, *vias, q1]
        if all(not world.path_collision(chain[k], chain[k + 1], max_step_rad) for k in range(len(chain) - 1)):
            return [v.copy() for v in vias]
    return None
