"""Kinematic model of a serial arm: forward kinematics and its Jacobians, vectorised over captures.

A :class:`SerialChain` is the URDF picture of an arm with revolute joints: joint i sits at a fixed
origin ``T_prev_origin[i]`` in the frame of joint i-1 (the base for i = 0) and turns about a unit
``axes[i]`` of that origin frame, so

    T_base_flange(q) = prod_i (T_prev_origin[i] @ Rot(axes[i], q_i)) @ T_last_flange.

The Franka Panda / FR3 is built in (:func:`franka_chain`, Craig's modified DH parameters as Franka
Robotics publishes them; the flange is libfranka's ``F`` frame), other arms come from a URDF file
(:func:`chain_from_urdf`). :func:`franka_fk` is the one Franka FK of calibgraph (the safety checks,
the driver and the simulator's reported poses use it).

Jacobians follow GTSAM's right perturbation with rotation first: ``J`` (6, n) is such that
``T(q + dq) = T(q) @ Exp(J @ dq)``, the twist expressed at the flange. A joint zero offset ``o``
(the physical angle is ``q_reported + o``) has the same Jacobian as ``q``.

Why numpy and not pinocchio: both give the same pose and flange Jacobian, and although pinocchio
computes a configuration faster, the FK calls are a small part of a solve with joint offsets: not
worth a compiled dependency (and a URDF round trip for the built-in arm). ``scripts/bench_kinematics.py
--fk`` compares the two (``scripts/results/bench_kinematics.md``). This chain is one
tested numpy file and the solver keeps it; pinocchio, or a one-configuration fast path, is the
lever if solves with kinematics grow long.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.inputs import read_input_text
from calibgraph.core.transforms import make_T


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _rpy_to_R(rpy) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _R_to_rpy(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_rpy_to_R` (pitch in [-pi/2, pi/2])."""
    p = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    if abs(np.cos(p)) < 1e-9:  # gimbal lock: put everything in roll
        return np.array([np.arctan2(-R[1, 2], R[1, 1]), p, 0.0])
    return np.array([np.arctan2(R[2, 1], R[2, 2]), p, np.arctan2(R[1, 0], R[0, 0])])


def _axis_rotations(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """(N, 3, 3) rotations about a unit ``axis`` by ``angles`` (N,) (Rodrigues, batched)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


@dataclass(frozen=True)
class SerialChain:
    """A serial arm of revolute joints (see the module docstring for the convention).

    Attributes:
        name: model name ('franka' for the built-in Panda / FR3).
        joint_names: (n,) names (URDF joint names, or joint1..joint7).
        T_prev_origin: (n, 4, 4) origin of joint i in the frame of joint i-1 (the base for i = 0).
        axes: (n, 3) unit rotation axis of each joint in its origin frame.
        T_last_flange: (4, 4) the flange in the frame of the last joint.
        link_names: (n + 1,) parent link of each joint, then the link of the last joint (for URDF export).
        flange_link: name of the flange link.
        urdf_text: the URDF the chain was read from, when it was (kept for the corrected export).
    """

    name: str
    joint_names: tuple
    T_prev_origin: np.ndarray
    axes: np.ndarray
    T_last_flange: np.ndarray
    link_names: tuple = ()
    flange_link: str = "flange"
    urdf_text: str | None = field(default=None, repr=False)

    def __post_init__(self):
        T = np.asarray(self.T_prev_origin, float)
        a = np.asarray(self.axes, float)
        n = len(self.joint_names)
        if T.shape != (n, 4, 4) or a.shape != (n, 3):
            raise InputError(f"kinematic model {self.name!r}: {n} joints need (n, 4, 4) origins and (n, 3) axes, "
                             f"got {T.shape} and {a.shape}.")
        norms = np.linalg.norm(a, axis=1)
        if np.any(norms < 1e-9):
            raise InputError(f"kinematic model {self.name!r}: a joint axis is zero.")
        object.__setattr__(self, "T_prev_origin", T)
        object.__setattr__(self, "axes", a / norms[:, None])
        object.__setattr__(self, "T_last_flange", np.asarray(self.T_last_flange, float))
        if not self.link_names:
            object.__setattr__(self, "link_names", tuple(f"link{i}" for i in range(n + 1)))

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def _q(self, q_rad) -> tuple[np.ndarray, bool]:
        q = np.asarray(q_rad, float)
        single = q.ndim == 1
        q = np.atleast_2d(q)
        if q.shape[1] != self.n_joints:
            raise InputError(f"kinematic model {self.name!r}: expected {self.n_joints} joint angles, got {q.shape[1]}.")
        return q, single

    def _joint_frames(self, q: np.ndarray):
        """(T_base_origin (N, n, 4, 4) before each joint's rotation, T_base_flange (N, 4, 4))."""
        N = q.shape[0]
        T = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
        origins = np.empty((N, self.n_joints, 4, 4))
        rot = np.broadcast_to(np.eye(4), (N, 4, 4)).copy()
        for i in range(self.n_joints):
            T = T @ self.T_prev_origin[i]
            origins[:, i] = T
            rot[:, :3, :3] = _axis_rotations(self.axes[i], q[:, i])
            T = T @ rot
        return origins, T @ self.T_last_flange

    def fk(self, q_rad) -> np.ndarray:
        """T_base_flange: (4, 4) for ``q_rad`` (n,), (N, 4, 4) for (N, n)."""
        q, single = self._q(q_rad)
        T = self._joint_frames(q)[1]
        return T[0] if single else T

    def fk_jacobian(self, q_rad) -> tuple[np.ndarray, np.ndarray]:
        """(T_base_flange, J) with J (6, n) — or (N, 6, n) — the flange-frame Jacobian w.r.t. the joint
        angles (= w.r.t. joint zero offsets), rotation rows first: T(q + dq) ~ T(q) Exp(J dq)."""
        q, single = self._q(q_rad)
        origins, T = self._joint_frames(q)
        R_bf, p_bf = T[:, :3, :3], T[:, :3, 3]
        # joint axis and a point on it, in flange axes relative to the flange origin
        w_b = np.einsum("nkij,kj->nki", origins[:, :, :3, :3], self.axes)
        p_b = origins[:, :, :3, 3] - p_bf[:, None, :]
        w_f = np.einsum("nji,nkj->nki", R_bf, w_b)
        p_f = np.einsum("nji,nkj->nki", R_bf, p_b)
        # a turn about axis w through point p (flange frame) moves the flange origin by w x (0 - p) = p x w
        J = np.concatenate([w_f, np.cross(p_f, w_f)], axis=2).transpose(0, 2, 1)
        return (T[0], J[0]) if single else (T, J)

    def origin_jacobian(self, q_rad) -> np.ndarray:
        """(N, 6, 6n) flange-frame Jacobian w.r.t. a right perturbation ``T_prev_origin[i] Exp(xi_i)`` of
        every joint origin (rotation first): the link length / twist parameters of a URDF or DH chain."""
        q, _ = self._q(q_rad)
        origins, T = self._joint_frames(q)
        Tinv_f = np.linalg.inv(T)
        out = np.empty((q.shape[0], 6, 6 * self.n_joints))
        for i in range(self.n_joints):
            T_fo = Tinv_f @ origins[:, i]
            R, p = T_fo[:, :3, :3], T_fo[:, :3, 3]
            px = np.zeros((q.shape[0], 3, 3))
            px[:, 0, 1], px[:, 0, 2], px[:, 1, 2] = -p[:, 2], p[:, 1], -p[:, 0]
            px[:, 1, 0], px[:, 2, 0], px[:, 2, 1] = p[:, 2], -p[:, 1], p[:, 0]
            out[:, :3, 6 * i: 6 * i + 3] = R
            out[:, 3:, 6 * i: 6 * i + 3] = px @ R
            out[:, :3, 6 * i + 3: 6 * i + 6] = 0.0
            out[:, 3:, 6 * i + 3: 6 * i + 6] = R
        return out

    def with_joint_offsets(self, offsets_rad) -> "SerialChain":
        """The chain whose joint i reads ``q_i`` where this one reads ``q_i + offsets_rad[i]``: each joint
        origin turned by its offset about its axis (what a corrected URDF carries)."""
        o = np.asarray(offsets_rad, float).reshape(-1)
        if o.size != self.n_joints:
            raise InputError(f"kinematic model {self.name!r}: expected {self.n_joints} offsets, got {o.size}.")
        T = self.T_prev_origin.copy()
        for i in range(self.n_joints):
            T[i] = T[i] @ make_T(_axis_rotations(self.axes[i], np.array([o[i]]))[0], np.zeros(3))
        return SerialChain(self.name, self.joint_names, T, self.axes, self.T_last_flange, self.link_names,
                           self.flange_link, None)

    def to_urdf(self, robot_name: str | None = None) -> str:
        """A kinematic-only URDF of the chain (links without inertia or geometry, revolute joints)."""
        name = robot_name or self.name
        lines = ['<?xml version="1.0"?>', f'<robot name="{name}">']
        for link in (*self.link_names, self.flange_link):
            lines.append(f'  <link name="{link}"/>')
        for i, j in enumerate(self.joint_names):
            lines.append(_urdf_joint(j, "revolute", self.link_names[i], self.link_names[i + 1], self.T_prev_origin[i],
                                     self.axes[i]))
        lines.append(_urdf_joint(f"{self.link_names[-1]}_{self.flange_link}_joint", "fixed", self.link_names[-1],
                                 self.flange_link, self.T_last_flange, None))
        lines.append("</robot>")
        return "\n".join(lines) + "\n"


def _fmt(v) -> str:
    return " ".join(f"{float(x):.10g}" for x in v)


def _urdf_joint(name, kind, parent, child, T, axis) -> str:
    s = (f'  <joint name="{name}" type="{kind}">\n    <parent link="{parent}"/>\n    <child link="{child}"/>\n'
         f'    <origin xyz="{_fmt(T[:3, 3])}" rpy="{_fmt(_R_to_rpy(T[:3, :3]))}"/>\n')
    if axis is not None:
        s += f'    <axis xyz="{_fmt(axis)}"/>\n    <limit lower="-6.2832" upper="6.2832" effort="0" velocity="0"/>\n'
    return s + "  </joint>"


# Craig (modified) DH parameters of the Panda / FR3: (a_m, d_m, alpha_rad) per joint, then the flange
# 0.107 m along z of link 7 (Franka Robotics, "Robot and interface specifications"). Both arms share them.
FRANKA_DH = (
    (0.0, 0.333, 0.0),
    (0.0, 0.0, -np.pi / 2),
    (0.0, 0.316, np.pi / 2),
    (0.0825, 0.0, np.pi / 2),
    (-0.0825, 0.384, -np.pi / 2),
    (0.0, 0.0, np.pi / 2),
    (0.088, 0.0, np.pi / 2),
)
FRANKA_FLANGE_D_M = 0.107


def chain_from_mdh(name: str, dh, flange_d_m: float = 0.0) -> SerialChain:
    """A :class:`SerialChain` from Craig's modified DH rows (a_m, d_m, alpha_rad): joint i's origin is
    Rx(alpha) Tx(a) Tz(d) in frame i-1 and it turns about its z axis."""
    T = np.stack([make_T(_rot_x(al), [a, -d * np.sin(al), d * np.cos(al)]) for a, d, al in dh])
    n = len(dh)
    return SerialChain(name, tuple(f"joint{i + 1}" for i in range(n)), T, np.tile([0.0, 0.0, 1.0], (n, 1)),
                       make_T(np.eye(3), [0.0, 0.0, flange_d_m]), tuple(f"link{i}" for i in range(n + 1)), "flange")


def franka_chain() -> SerialChain:
    """The built-in Panda / FR3 chain (modified DH, libfranka's flange frame ``F``)."""
    return chain_from_mdh("franka", FRANKA_DH, FRANKA_FLANGE_D_M)


_FRANKA = franka_chain()


def franka_fk(q_rad) -> np.ndarray:
    """T_base_flange (4, 4) of a Panda / FR3 arm for joint angles ``q_rad`` (7,).

    The flange frame is libfranka's ``F`` frame (``O_T_EE @ inv(F_T_EE)``), not the hand's EE/TCP.
    """
    q = np.asarray(q_rad, float).reshape(-1)
    if q.size != 7:
        raise InputError(f"franka_fk: expected 7 joint angles, got {q.size}.")
    return _FRANKA.fk(q)


def _origin(el) -> np.ndarray:
    o = el.find("origin")
    if o is None:
        return np.eye(4)
    xyz = np.array([float(x) for x in o.get("xyz", "0 0 0").split()])
    rpy = np.array([float(x) for x in o.get("rpy", "0 0 0").split()])
    return make_T(_rpy_to_R(rpy), xyz)


def chain_from_urdf(path, tip_link: str | None = None, base_link: str | None = None) -> SerialChain:
    """The serial chain from ``base_link`` (default: the URDF's root) to ``tip_link`` (default: the end of
    the only chain of movable joints); fixed joints are folded into the next origin (or the flange).
    Prismatic joints are refused; the joint limits are not read (the safety checks have their own)."""
    path = Path(path)
    try:
        text = read_input_text(path, "URDF")
        root = ET.fromstring(text)
    except (OSError, ET.ParseError) as e:
        raise InputError(f"{path}: cannot read the URDF ({e}).") from None
    joints = {}
    for j in root.findall("joint"):
        child = j.find("child").get("link")
        joints[child] = j
    parents = {j.find("parent").get("link") for j in joints.values()}
    links = [ln.get("name") for ln in root.findall("link")]
    if tip_link is None:
        leaves = [ln for ln in links if ln not in parents and ln in joints]
        # the deepest leaf (an arm's flange/hand is the end of the longest chain)
        depth = {}
        for leaf in leaves:
            d, cur = 0, leaf
            while cur in joints:
                cur = joints[cur].find("parent").get("link")
                d += 1
            depth[leaf] = d
        if not depth:
            raise InputError(f"{path}: no joints in the URDF.")
        tip_link = max(depth, key=depth.get)
    if tip_link not in joints:
        raise InputError(f"{path}: link {tip_link!r} is not the child of any joint; links: {links}.")
    path_joints, cur = [], tip_link
    while cur in joints and cur != base_link:
        path_joints.append(joints[cur])
        cur = joints[cur].find("parent").get("link")
    if base_link is not None and cur != base_link:
        raise InputError(f"{path}: link {base_link!r} is not an ancestor of {tip_link!r}.")
    path_joints.reverse()
    T_pending, origins, axes, names, link_names = np.eye(4), [], [], [], [cur]
    for j in path_joints:
        kind = j.get("type")
        T_pending = T_pending @ _origin(j)
        if kind == "fixed":
            continue
        if kind not in ("revolute", "continuous"):
            raise InputError(f"{path}: joint {j.get('name')!r} is {kind}; only revolute joints are modelled.")
        ax = j.find("axis")
        axes.append([float(x) for x in (ax.get("xyz") if ax is not None else "1 0 0").split()])
        origins.append(T_pending)
        names.append(j.get("name"))
        link_names.append(j.find("child").get("link"))
        T_pending = np.eye(4)
    if not names:
        raise InputError(f"{path}: no revolute joints between {cur!r} and {tip_link!r}.")
    if link_names[-1] == tip_link:  # the tip is the last joint's link: keep a distinct flange name
        flange = f"{tip_link}_flange"
    else:
        flange = tip_link
    return SerialChain(root.get("name", path.stem), tuple(names), np.stack(origins), np.array(axes), T_pending,
                       tuple(link_names), flange, text)


def corrected_urdf(chain: SerialChain, offsets_rad) -> str:
    """URDF text of ``chain`` with each joint origin turned by its offset about the joint axis, so that a
    controller reading the same encoder values computes the true flange pose. A chain read from a
    URDF keeps that file (geometry, inertia, limits) and only its joint origins change."""
    fixed = chain.with_joint_offsets(offsets_rad)
    if chain.urdf_text is None:
        return fixed.to_urdf(f"{chain.name}_corrected")
    root = ET.fromstring(chain.urdf_text)
    by_name = {j.get("name"): j for j in root.findall("joint")}
    o = np.asarray(offsets_rad, float).reshape(-1)
    for i, name in enumerate(chain.joint_names):
        j = by_name[name]
        T = _origin(j) @ make_T(_axis_rotations(chain.axes[i], np.array([o[i]]))[0], np.zeros(3))
        el = j.find("origin")
        if el is None:
            el = ET.SubElement(j, "origin")
        el.set("xyz", _fmt(T[:3, 3]))
        el.set("rpy", _fmt(_R_to_rpy(T[:3, :3])))
    return ET.tostring(root, encoding="unicode") + "\n"
