"""Inverse kinematics and collision checks on the simulated arm (MuJoCo model).

Damped least squares on MuJoCo's site Jacobian of the flange, with joint limits enforced by
clamping (a margin keeps solutions off the hard stops), restarted from several seeds. A
configuration is accepted only when MuJoCo's collision detection finds no contact between the arm
(links, mount, board) and anything but the pedestal it stands on.

Motions are checked too: every driver moves along the straight joint-space line
``q(s) = q0 + s (q1 - q0)`` (see :mod:`calibgraph.acquire.safety`), so :func:`path_collision` samples
that line densely enough (``max_step_rad`` per joint between samples) that no link sweeps
through an obstacle between two samples.
"""

from __future__ import annotations

import math

import numpy as np

from calibgraph.core.transforms import log_so3
from calibgraph.sim.scene import HOME_Q_RAD

LIMIT_MARGIN_RAD = 0.05


def _fk(world, q):
    world.data.qpos[world.qadr] = q
    world.mujoco.mj_kinematics(world.model, world.data)
    return world.T_base_flange()


def solve_ik(world, T_base_flange_target: np.ndarray, q_seed, max_iter: int = 150, tol_m: float = 1e-5,
             tol_rad: float = 1e-5, damping: float = 0.05):
    """Joint angles reaching ``T_base_flange_target`` from ``q_seed``, or None.

    Args:
        world: a :class:`calibgraph.sim.render.SimWorld` (only its model/data are used).
        T_base_flange_target: (4, 4) target flange pose.
        q_seed: (7,) start configuration.
    Returns:
        q_rad (7,) within the joint limits (minus a margin), or None when it did not converge.
    """
    mj = world.mujoco
    m, d = world.model, world.data
    lo, hi = world.q_lo + LIMIT_MARGIN_RAD, world.q_hi - LIMIT_MARGIN_RAD
    q = np.clip(np.asarray(q_seed, float), lo, hi)
    jacp = np.zeros((3, m.nv))
    jacr = np.zeros((3, m.nv))
    cols = getattr(world, "_ik_cols", None)
    if cols is None:
        cols = world._ik_cols = np.array([m.jnt_dofadr[m.joint(f"fr3_joint{i}").id] for i in range(1, 8)])
    damp = damping**2 * np.eye(6)
    J = np.empty((6, 7))
    e = np.empty(6)
    site, qadr = world.flange_site, world.qadr
    R_t = np.asarray(T_base_flange_target[:3, :3], float)
    p_t = np.asarray(T_base_flange_target[:3, 3], float)
    # the loop runs thousands of times per planning step: scalar maths where numpy's overhead dominates
    for _ in range(max_iter):
        d.qpos[qadr] = q
        mj.mj_kinematics(m, d)
        e[:3] = p_t - d.site_xpos[site]
        e[3:] = _log_so3_fast(R_t @ d.site_xmat[site].reshape(3, 3).T)  # world-frame rotation error, matches jacr
        ep, er = e[:3] @ e[:3], e[3:] @ e[3:]
        if math.sqrt(ep) < tol_m and math.sqrt(er) < tol_rad:
            return q
        mj.mj_comPos(m, d)
        mj.mj_jacSite(m, d, jacp, jacr, site)
        J[:3] = jacp[:, cols]
        J[3:] = jacr[:, cols]
        # cap the step so linearisation holds far from the solution
        n = math.sqrt(ep + er)
        if n > 0.2:
            e *= 0.2 / n
        dq = J.T @ np.linalg.solve(J @ J.T + damp, e)
        q = np.minimum(np.maximum(q + dq, lo), hi)  # np.clip, without its overhead
    T = _fk(world, q)
    if np.linalg.norm(p_t - T[:3, 3]) < 10 * tol_m and np.linalg.norm(log_so3(R_t @ T[:3, :3].T)) < 10 * tol_rad:
        return q
    return None


def _log_so3_fast(R: np.ndarray) -> np.ndarray:
    """:func:`calibgraph.core.transforms.log_so3` in scalar maths (the IK's inner loop)."""
    r = R.tolist()
    c = min(max((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0, -1.0), 1.0)
    theta = math.acos(c)
    if theta < 1e-7 or math.pi - theta < 1e-4:
        return log_so3(R)
    k = theta / (2.0 * math.sin(theta))
    return np.array([(r[2][1] - r[1][2]) * k, (r[0][2] - r[2][0]) * k, (r[1][0] - r[0][1]) * k])


def start_configuration(world) -> np.ndarray:
    """Where the simulated arm starts: the world's current joint angles when they are a valid
    configuration (inside the joint limits, collision-free), else the home posture
    :data:`calibgraph.sim.scene.HOME_Q_RAD`. A fresh MuJoCo model sits at all-zero joints, which
    is outside the FR3's limits (joints 4 and 6) and self-colliding: no real arm is ever there.
    The model state is left unchanged."""

    q = world.q()
    if np.all(q >= world.q_lo) and np.all(q <= world.q_hi):
        saved = world.data.qpos.copy()
        free = not in_collision(world, q)
        world.data.qpos[:] = saved
        world.mujoco.mj_fwdPosition(world.model, world.data)
        if free:
            return q
    return HOME_Q_RAD.copy()


def arm_geom_ids(world) -> set:
    """Geoms that move with the arm (links, mount, board): collisions involving them matter."""
    m = world.model
    base = m.body("fr3_link0").id
    ids = set()
    for g in range(m.ngeom):
        b = m.geom_bodyid[g]
        if b != 0 and b != base:
            ids.add(g)
    return ids


def in_collision(world, q) -> list:
    """Contacts (name pairs) at ``q`` that involve a moving part of the arm, the board or its mount;
    empty when the configuration is free. Leaves the model at ``q``."""
    mj = world.mujoco
    m, d = world.model, world.data
    d.qpos[world.qadr] = q
    mj.mj_fwdPosition(m, d)
    return _arm_contacts(world)


def path_collision(world, q0, q1, max_step_rad: float = 0.03) -> list:
    """Contacts (name pairs) at the first colliding sample of the straight joint-space motion
    from ``q0`` to ``q1``; empty when the whole motion is free.

    The line is sampled at ``s = k / n``, k = 1..n, with ``n`` chosen so no joint moves more than
    ``max_step_rad`` between samples (0.03 rad swings a point 1 m from the axis by 3 cm, less
    than the thickness of any link); the start ``q0`` itself is not checked (the arm is there
    already). The model state (joint angles and everything derived) is restored before returning.
    """
    if not max_step_rad > 0:
        raise ValueError(f"path_collision: max_step_rad must be > 0, got {max_step_rad}.")
    q0 = np.asarray(q0, float).reshape(-1)
    q1 = np.asarray(q1, float).reshape(-1)
    mj = world.mujoco
    m, d = world.model, world.data
    saved = d.qpos.copy()
    n = max(1, int(np.ceil(np.max(np.abs(q1 - q0)) / max_step_rad)))
    hits = []
    try:
        for k in range(1, n + 1):
            d.qpos[world.qadr] = q0 + (k / n) * (q1 - q0)
            mj.mj_fwdPosition(m, d)
            hits = _arm_contacts(world)
            if hits:
                break
    finally:
        d.qpos[:] = saved
        mj.mj_fwdPosition(m, d)
    return hits


def _arm_contacts(world) -> list:
    m, d = world.model, world.data
    moving = getattr(world, "_moving_geoms", None)
    if moving is None:
        moving = world._moving_geoms = arm_geom_ids(world)
    ped = {m.geom("pedestal").id} if _has_geom(m, "pedestal") else set()
    link1 = m.body("fr3_link1").id
    hits = []
    for i in range(d.ncon):
        c = d.contact[i]
        g1, g2 = int(c.geom1), int(c.geom2)
        if g1 not in moving and g2 not in moving:
            continue
        # link1 sits on the pedestal by design
        pair = {g1, g2}
        if pair & ped and any(m.geom_bodyid[g] == link1 for g in pair):
            continue
        hits.append((_name(m, g1), _name(m, g2)))
    return hits


def _has_geom(m, name) -> bool:
    try:
        m.geom(name)
        return True
    except KeyError:
        return False


def _name(m, g) -> str:
    n = m.geom(g).name
    return n or f"geom{g}@{m.body(m.geom_bodyid[g]).name}"
