"""Discovery: where are the cameras? A safe survey that shows the board in many directions.

Before anything is known about the camera placements the robot sweeps the board round its base
(6 azimuths, every other one first, outwards from the arm's heading; the ones between only while
a camera is unseen), facing outwards, and every camera grabs a frame at every stop. A round that leaves
a camera unseen is followed by a wider one (offset azimuths, the board tilted up for cameras
mounted high, down for low ones, straight up for a camera looking down on the cell); a camera
with a :class:`~calibgraph.plan.cell.CameraHint` gets stops aimed at its hint first, and the sweep
follows whatever the hint says, so a wrong hint costs a few stops, never the run.

A camera that has seen the board gets *refinement* stops: the board facing the camera position
that its views' PnP suggest, tilted in several directions. A planar view has two PnP solutions
whose camera centres are mirror images about the board normal: close together for a view seen
head-on, metres apart for one seen obliquely, so stops aimed at their mean can miss the camera
altogether. :func:`camera_position_hypothesis` keeps the candidate that most views
agree on; while two remain in a tie, the next stop faces one of them squarely, and a stop the
camera does not see refutes it. Those views give the rotation diversity the solver's consensus
initialiser needs (:class:`calibgraph.solver.solve.incremental.IncrementalSolver`): it resolves the
mirror ambiguity across views and hands back a coarse pose with a covariance.

Every stop is reachable by IK within the joint limits and collision-free in the planning world
(:class:`calibgraph.plan.planner.RobotWorld`): the robot and the cell's declared geometry only,
no camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.transforms import board_facing, inv, make_T

__all__ = ["SurveyStop", "SURVEY_ROUNDS", "survey_round", "refinement_stops", "board_pose_facing", "reach_pose",
           "coarse_camera_position", "camera_position_hypothesis", "seeds_at"]

# (azimuth offset deg, elevation of the board normal deg, radius m, height m) of each round's
# 6-azimuth sweep; later rounds widen the directions the board faces.
SURVEY_ROUNDS = (
    (0.0, 15.0, 0.60, 0.45),
    (30.0, 35.0, 0.55, 0.40),
    (0.0, -5.0, 0.60, 0.60),
    (30.0, 60.0, 0.50, 0.35),
)
N_AZIMUTHS = 6
BASE_SEED_Q = np.array([0.0, 0.1, 0.0, -2.0, 0.0, 2.0, 0.785])  # arm reaching forward at joint-1 angle 0
# IK starts in the arm's vertical plane (joints 3 and 5 at 0): shoulder, elbow, wrist pitch and
# flange roll over a small grid. From the single seed above, IK seldom finds a board held facing
# outwards at survey distance; from this family it mostly does (scripts/results/design_figures.md).
SEED_FAMILY = tuple(np.array([0.0, q2, 0.0, q4, 0.0, q6, q7]) for q4 in (-2.4, -1.7) for q6 in (2.2, 3.2)
                    for q2 in (-0.3, 0.3, 0.8) for q7 in (0.785, -0.785))


@dataclass(frozen=True)
class SurveyStop:
    """One survey pose: joint angles, the flange and (nominal-mount) board poses, and why."""

    label: str
    q_rad: np.ndarray
    T_base_flange: np.ndarray
    T_base_board: np.ndarray
    why: str


def board_pose_facing(eye_m, centre_m, target, tilt_rotvec=(0.0, 0.0, 0.0), roll_rad: float = 0.0) -> np.ndarray:
    """T_base_board with the pattern centre at ``centre_m``, the printed face towards ``eye_m``."""
    centre_b = target.points_board_m.mean(axis=0)
    return board_facing(eye_m, centre_m, tilt_rotvec, roll_rad) @ make_T(np.eye(3), -centre_b)


def reach_pose(world, T_base_board, T_flange_board, seeds, free=None):
    """(q_rad, T_base_flange) reaching ``T_base_board`` through the mount, collision-free (and
    ``free(q)`` true when given), or None. Leaves the world at the answer."""
    T_bf = T_base_board @ inv(T_flange_board)
    for s in seeds:
        q = world.solve_ik(T_bf, s)
        if q is None or world.in_collision(q):
            continue
        world.set_q(q)
        if free is not None and not free(q):
            continue
        return q, world.T_base_flange()
    return None


def seeds_at(a_rad, q_prev=None, n: int | None = None, rng=None) -> list:
    """IK starts at joint-1 angle ``a_rad``: ``q_prev`` first (short motions), then the
    :data:`SEED_FAMILY` (all of it, or ``n`` drawn at random)."""
    fam = list(SEED_FAMILY)
    if n is not None and rng is not None:
        fam = [fam[i] for i in rng.choice(len(fam), size=min(n, len(fam)), replace=False)]
    out = [] if q_prev is None else [np.asarray(q_prev, float)]
    for f in fam:
        q = f.copy()
        q[0] = a_rad
        out.append(q)
    return out


def _direction(az_rad, el_rad):
    return np.array([np.cos(el_rad) * np.cos(az_rad), np.cos(el_rad) * np.sin(az_rad), np.sin(el_rad)])


def survey_round(world, cell, k: int, q_start=None, free=None) -> list:
    """The reachable stops of survey round ``k`` (0-based; [] past the last round), in sweep order.

    Round 0 starts with two stops aimed at each hinted camera. ``free(q) -> bool`` adds a check
    of the planner's own (keep-out volumes)."""
    if k >= len(SURVEY_ROUNDS):
        return []
    off_deg, el_deg, r, h = SURVEY_ROUNDS[k]
    lo, hi = world.q_lo[0] + world.limit_margin_rad, world.q_hi[0] - world.limit_margin_rad
    wanted = []  # (azimuth, direction the board faces, radius, height, label, why)
    if k == 0:
        for name, hint in cell.hints().items():
            d = hint.towards()
            az = float(np.arctan2(d[1], d[0]))
            for j, dz in enumerate((0.0, 0.12)):
                wanted.append((az, d, r, h + dz, f"hint {name} {j}", f"aimed at the hint of {name}"))
    for i in range(N_AZIMUTHS):
        az = np.radians(off_deg + 360.0 * i / N_AZIMUTHS)
        az = float(np.angle(np.exp(1j * az)))
        wanted.append((az, _direction(az, np.radians(el_deg)), r, h, f"sweep r{k} az{np.degrees(az):+.0f}",
                       f"survey round {k}: board facing azimuth {np.degrees(az):+.0f} deg, elevation {el_deg:+.0f} deg"))
    if k == 2:  # straight up, for a camera looking down on the cell
        for i in range(4):
            az = np.radians(45.0 + 90.0 * i)
            az = float(np.angle(np.exp(1j * az)))
            wanted.append((az, _direction(az, np.radians(80.0)), 0.45, 0.35, f"up r{k} az{np.degrees(az):+.0f}",
                           f"survey round {k}: board facing up (elevation 80 deg)"))
    # hinted stops first; then coarse to fine: every other azimuth of the sweep (the board is seen
    # up to ~60 deg off its normal, so stops 120 deg apart already face every direction once), the
    # azimuths between them after, for the cameras still unseen (the loop ends the round when every
    # camera has been seen); each pass outwards from the arm's current heading, nearest first (the
    # first sightings cost the least motion; where a camera is, is not known, so no start is better).
    a0 = 0.0 if q_start is None else float(np.asarray(q_start, float)[0])

    def off(j):
        return abs(float(np.angle(np.exp(1j * (wanted[j][0] - a0)))))

    sweep = [j for j in range(len(wanted)) if wanted[j][4].startswith("sweep")]
    first = min(sweep, key=off) if sweep else None
    fine = {j for j in sweep if (sweep.index(j) - sweep.index(first)) % 2}
    order = sorted(range(len(wanted)), key=lambda j: (not wanted[j][4].startswith("hint"), j in fine, round(off(j), 3),
                                                      wanted[j][0] < a0, wanted[j][0]))
    stops, q_prev = [], q_start
    for j in order:
        az, d, rr, hh, label, why = wanted[j]
        got = None
        for dr, dh in ((0.0, 0.0), (-0.1, 0.05), (0.1, -0.1)):
            centre = np.array([(rr + dr) * np.cos(az), (rr + dr) * np.sin(az), hh + dh])
            T_bb = board_pose_facing(centre + 3.0 * d, centre, cell.target)
            a_seed = float(np.clip(az, lo, hi))
            got = reach_pose(world, T_bb, cell.T_flange_board, seeds_at(a_seed, q_prev), free)
            if got is not None:
                break
        if got is None:
            continue
        q, T_bf = got
        stops.append(SurveyStop(label, q, T_bf, T_bf @ cell.T_flange_board, why))
        q_prev = q
    return stops


def refinement_stops(world, cell, camera: str, T_base_board_seen: np.ndarray, p_cam_m: np.ndarray, n: int = 4,
                     q_start=None, seed: int = 0, free=None, tilt_deg: float = 30.0) -> list:
    """Up to ``n`` stops that show the board to ``camera`` again, from other angles: the board
    centre near where the camera saw it (``T_base_board_seen``), facing the rough camera
    position ``p_cam_m``, tilted by ``tilt_deg`` in ``n`` directions."""
    rng = np.random.default_rng(seed * 7919 + sum(map(ord, camera)))
    centre_b = cell.target.points_board_m.mean(axis=0)
    c0 = T_base_board_seen[:3, :3] @ centre_b + T_base_board_seen[:3, 3]
    az = float(np.arctan2(c0[1], c0[0]))
    stops, q_prev = [], q_start
    for i in range(3 * n):
        if len(stops) >= n:
            break
        a = 2 * np.pi * (i + 0.5 * (i // n)) / n
        tilt = np.radians(tilt_deg) * np.array([np.cos(a), np.sin(a), 0.0])
        centre = c0 + rng.uniform(-0.25, 0.25, 3) * np.array([1.0, 1.0, 0.8])
        T_bb = board_pose_facing(p_cam_m, centre, cell.target, tilt, np.radians(rng.uniform(-20, 20)))
        got = reach_pose(world, T_bb, cell.T_flange_board, seeds_at(az, q_prev), free)
        if got is None:
            continue
        q, T_bf = got
        stops.append(SurveyStop(f"refine {camera} {len(stops)}", q, T_bf, T_bf @ cell.T_flange_board,
                                f"{camera} saw the board once: tilted views for its consensus pose"))
        q_prev = q
    return stops


def camera_position_hypothesis(views: list, refuted=(), agree_m: float = 0.35, ambiguous_deg: float = 20.0):
    """The most likely centre of a camera not placed yet, from its views' PnP candidates.

    Args:
        views: per view (T_base_board, R (m, 3, 3), t (m, 3), rms (m,)) (the nominal mount).
        refuted: positions a squarely facing stop did not show the board to (the candidates within
            ``agree_m`` of one are dropped).
    Returns:
        (position (3,), T_base_board of a view that supports it, ambiguous): ``ambiguous`` when
        another candidate, more than ``ambiguous_deg`` away as seen from that board, has as many
        supporting views (only one stop facing the answer squarely tells them apart). None when no
        candidate is left.
    """
    cands = []  # (position, view index, rms)
    for i, (T_bb, R, t, rms) in enumerate(views):
        for Rk, tk, ek in zip(np.asarray(R).reshape(-1, 3, 3), np.asarray(t).reshape(-1, 3), np.asarray(rms).reshape(-1)):
            p = T_bb[:3, :3] @ (-(Rk.T @ tk)) + T_bb[:3, 3]
            if not any(np.linalg.norm(p - np.asarray(r)) < agree_m for r in refuted):
                cands.append((p, i, float(ek)))
    if not cands:
        return None
    P = np.array([c[0] for c in cands])
    view_of = np.array([c[1] for c in cands])
    near = np.linalg.norm(P[:, None] - P[None], axis=2) < agree_m
    support = np.array([len(set(view_of[near[j]])) for j in range(len(cands))])
    best = min(range(len(cands)), key=lambda j: (-support[j], cands[j][2]))
    T_bb = views[cands[best][1]][0]
    members = near[best]
    pos = np.median(P[members], axis=0)
    c0 = T_bb[:3, 3]
    u = (pos - c0) / max(np.linalg.norm(pos - c0), 1e-9)
    ambiguous = False
    for j in range(len(cands)):
        if members[j] or support[j] < support[best]:
            continue
        v = (P[j] - c0) / max(np.linalg.norm(P[j] - c0), 1e-9)
        if np.degrees(np.arccos(np.clip(u @ v, -1, 1))) > ambiguous_deg:
            ambiguous = True
    return pos, T_bb, ambiguous


def coarse_camera_position(T_base_board: np.ndarray, R_cam_board: np.ndarray, t_cam_board: np.ndarray) -> np.ndarray:
    """Camera centre in the base frame from one view's PnP candidate(s) and the nominal board pose:
    the mean over candidates (both planar-pose solutions put the camera on the same side)."""
    R = np.asarray(R_cam_board).reshape(-1, 3, 3)
    t = np.asarray(t_cam_board).reshape(-1, 3)
    p_board = np.array([-(Rk.T @ tk) for Rk, tk in zip(R, t)])  # camera centre in board axes
    return (p_board @ T_base_board[:3, :3].T + T_base_board[:3, 3]).mean(axis=0)

