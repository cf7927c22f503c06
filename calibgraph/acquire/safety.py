"""Safety checks done before any robot motion: joint limits, a workspace box, a speed cap.

Every check runs *before* a command is sent, on the target and on the path to it. The drivers
move in joint space along the straight line ``q(s) = q_start + s (q_goal - q_start)``, s in
[0, 1] (only the timing law differs), so checking joint limits at both ends and the flange
position at samples of that line covers the whole motion.

Workspace box: an axis-aligned box in the robot base frame (metres) that the flange origin
must stay inside, with an optional extra ``tool_radius_m`` kept clear of the box faces (the
board and its mount stick out of the flange). The flange pose for a joint vector comes from
the robot's own forward kinematics (``robot.forward_kinematics(q)``), or from a named model
here (``kinematics: franka`` uses :func:`franka_fk`), or, for the target only, from the pose
the trajectory states. With a box configured and no way to compute the pose, the pose is
refused: a workspace that cannot be checked is not assumed to be clear.

Config (the ``safety:`` section of a workcell YAML)::

    safety:
      q_min_rad: [-2.7, -1.7, -2.8, -3.0, -2.8, 0.6, -3.0]   # default: the robot model's limits
      q_max_rad: [ 2.7,  1.7,  2.8, -0.2,  2.8, 4.4,  3.0]
      joint_margin_rad: 0.05        # kept clear of each limit
      workspace_min_m: [0.2, -0.6, 0.05]
      workspace_max_m: [0.9,  0.6, 1.0]
      tool_radius_m: 0.0
      max_speed_scale: 0.3          # fraction of the robot's maximum joint velocity
      kinematics: franka            # optional named FK model for the path check
      path_samples: 20
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.kinematics import franka_fk  # noqa: F401 - the one Franka FK, re-exported for callers

# Franka Robotics datasheet values (rad, rad/s). Panda and FR3 differ in joints 1-4 and 6.
FRANKA_LIMITS = {
    "panda": dict(
        q_min_rad=[-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973],
        q_max_rad=[2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973],
        dq_max_rad_s=[2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100],
        ddq_max_rad_s2=[15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0],
    ),
    "fr3": dict(
        q_min_rad=[-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159],
        q_max_rad=[2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159],
        dq_max_rad_s=[2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26],
        ddq_max_rad_s2=[10.0, 10.0, 10.0, 10.0, 10.0, 10.0, 10.0],
    ),
}

KINEMATICS = {"franka": franka_fk, "panda": franka_fk, "fr3": franka_fk}


class UnsafeTargetError(InputError):
    """A configuration that must not be executed (speed above the cap, malformed limits)."""


def _vec(d, key, n=None):
    v = d.get(key)
    if v is None:
        return None
    a = np.asarray(v, float).reshape(-1)
    if n is not None and a.size != n:
        raise InputError(f"safety: {key} must have {n} values, got {a.size}.")
    if not np.all(np.isfinite(a)):
        raise InputError(f"safety: {key} contains NaN/inf.")
    return a


@dataclass(frozen=True)
class SafetyLimits:
    """Limits checked before any motion (see the module docstring for the YAML form).

    Attributes:
        q_min_rad, q_max_rad: (n,) joint limits, or None to rely on the robot's own limits.
        joint_margin_rad: distance kept from each joint limit.
        workspace_min_m, workspace_max_m: (3,) corners of the allowed box for the flange origin in
            the base frame, or None for no box.
        tool_radius_m: the flange origin stays this far inside the box faces.
        max_speed_scale: highest allowed fraction of the robot's maximum joint velocity.
        kinematics: name of an FK model in :data:`KINEMATICS` used when the robot has none.
        path_samples: samples of the joint-space path checked against the box.
    """

    q_min_rad: np.ndarray | None = None
    q_max_rad: np.ndarray | None = None
    joint_margin_rad: float = 0.0
    workspace_min_m: np.ndarray | None = None
    workspace_max_m: np.ndarray | None = None
    tool_radius_m: float = 0.0
    max_speed_scale: float = 0.3
    kinematics: str | None = None
    path_samples: int = 20

    def __post_init__(self):
        for a, b in (("q_min_rad", "q_max_rad"), ("workspace_min_m", "workspace_max_m")):
            lo, hi = getattr(self, a), getattr(self, b)
            if (lo is None) != (hi is None):
                raise InputError(f"safety: give both {a} and {b}, or neither.")
            if lo is not None:
                lo = np.asarray(lo, float).reshape(-1)
                hi = np.asarray(hi, float).reshape(-1)
                if lo.shape != hi.shape or not np.all(lo < hi):
                    raise InputError(f"safety: {a} must be element-wise below {b} ({lo.tolist()} vs {hi.tolist()}).")
                if a == "workspace_min_m" and lo.size != 3:
                    raise InputError("safety: the workspace box needs 3 values per corner (x, y, z in metres).")
                object.__setattr__(self, a, lo)
                object.__setattr__(self, b, hi)
        if not (0.0 < self.max_speed_scale <= 1.0):
            raise InputError(f"safety: max_speed_scale must be in (0, 1], got {self.max_speed_scale}.")
        if self.joint_margin_rad < 0 or self.tool_radius_m < 0:
            raise InputError("safety: joint_margin_rad and tool_radius_m must be >= 0.")
        if self.kinematics is not None and self.kinematics not in KINEMATICS:
            raise InputError(f"safety: unknown kinematics {self.kinematics!r}; known: {sorted(KINEMATICS)}.")
        if int(self.path_samples) < 2:
            raise InputError("safety: path_samples must be >= 2.")

    @classmethod
    def from_dict(cls, d: dict | None) -> "SafetyLimits":
        """Build from the ``safety:`` mapping of a workcell file; ``robot_model`` presets
        ('panda', 'fr3') fill in joint limits that are not given."""
        d = dict(d or {})
        allowed = set(cls.__dataclass_fields__) | {"robot_model"}
        unknown = set(d) - allowed
        if unknown:
            raise InputError(f"safety: unknown keys {sorted(unknown)}; allowed: {sorted(allowed)}.")
        model = d.pop("robot_model", None)
        if model is not None:
            if model not in FRANKA_LIMITS:
                raise InputError(f"safety: unknown robot_model {model!r}; known: {sorted(FRANKA_LIMITS)}.")
            d.setdefault("q_min_rad", FRANKA_LIMITS[model]["q_min_rad"])
            d.setdefault("q_max_rad", FRANKA_LIMITS[model]["q_max_rad"])
            d.setdefault("kinematics", "franka")
        kw = {}
        for k in ("q_min_rad", "q_max_rad", "workspace_min_m", "workspace_max_m"):
            kw[k] = _vec(d, k)
        for k in ("joint_margin_rad", "tool_radius_m", "max_speed_scale"):
            if k in d:
                kw[k] = float(d[k])
        if "kinematics" in d:
            kw["kinematics"] = d["kinematics"]
        if "path_samples" in d:
            kw["path_samples"] = int(d["path_samples"])
        return cls(**kw)

    def to_dict(self) -> dict:
        out = {}
        for k in ("q_min_rad", "q_max_rad", "workspace_min_m", "workspace_max_m"):
            v = getattr(self, k)
            if v is not None:
                out[k] = np.asarray(v).tolist()
        out.update(joint_margin_rad=self.joint_margin_rad, tool_radius_m=self.tool_radius_m,
                   max_speed_scale=self.max_speed_scale, path_samples=int(self.path_samples))
        if self.kinematics:
            out["kinematics"] = self.kinematics
        return out

    @property
    def has_workspace(self) -> bool:
        return self.workspace_min_m is not None


def check_speed(speed_scale: float, limits: SafetyLimits) -> None:
    """Raise :class:`UnsafeTargetError` when ``speed_scale`` exceeds the configured cap."""
    s = float(speed_scale)
    if not (np.isfinite(s) and s > 0):
        raise UnsafeTargetError(f"speed_scale must be a positive number, got {speed_scale}.")
    if s > limits.max_speed_scale + 1e-12:
        raise UnsafeTargetError(
            f"speed_scale {s:g} exceeds the safety cap max_speed_scale {limits.max_speed_scale:g}; lower the "
            "trajectory's speed_scale or raise the cap in the workcell's safety section after a risk assessment."
        )


def joint_problems(q_rad, limits: SafetyLimits, robot_limits=None) -> list:
    """Reasons why ``q_rad`` violates the joint limits (configured ones, then the robot's own
    ``(q_min, q_max)`` when given); empty when it is inside."""
    q = np.asarray(q_rad, float).reshape(-1)
    out = []
    if not np.all(np.isfinite(q)):
        return ["joint target contains NaN/inf"]
    for name, lims in (("safety", (limits.q_min_rad, limits.q_max_rad)), ("robot", robot_limits)):
        if lims is None or lims[0] is None:
            continue
        lo = np.asarray(lims[0], float) + limits.joint_margin_rad
        hi = np.asarray(lims[1], float) - limits.joint_margin_rad
        if lo.size != q.size:
            out.append(f"joint target has {q.size} values but the {name} limits have {lo.size}")
            continue
        for j in np.nonzero((q < lo) | (q > hi))[0]:
            out.append(f"joint {j + 1} = {q[j]:.3f} rad outside the {name} limits [{lo[j]:.3f}, {hi[j]:.3f}] "
                       f"(margin {limits.joint_margin_rad:g} rad included)")
    return out


def workspace_problems(T_base_flange, limits: SafetyLimits, what: str = "flange") -> list:
    """Reasons why the flange origin of ``T_base_flange`` is outside the workspace box."""
    if not limits.has_workspace:
        return []
    T = np.asarray(T_base_flange, float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return [f"{what} pose is not a finite 4x4 transform"]
    p = T[:3, 3]
    lo = limits.workspace_min_m + limits.tool_radius_m
    hi = limits.workspace_max_m - limits.tool_radius_m
    bad = (p < lo) | (p > hi)
    if not np.any(bad):
        return []
    axes = ", ".join("xyz"[i] for i in np.nonzero(bad)[0])
    return [f"{what} at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m leaves the workspace box along {axes} "
            f"(box [{', '.join(f'{v:.3f}' for v in lo)}] .. [{', '.join(f'{v:.3f}' for v in hi)}] m, "
            f"tool radius {limits.tool_radius_m:g} m included)"]


def fk_function(robot, limits: SafetyLimits):
    """The forward-kinematics callable used for workspace checks, or None: the robot's own
    ``forward_kinematics(q)`` first, else the model named in ``limits.kinematics``."""
    f = getattr(robot, "forward_kinematics", None) if robot is not None else None
    if callable(f):
        return f
    if limits.kinematics:
        return KINEMATICS[limits.kinematics]
    return None


@dataclass(frozen=True)
class Verdict:
    """Outcome of checking one motion: ``ok`` and the reasons when not."""

    ok: bool
    reasons: tuple = field(default_factory=tuple)

    @property
    def message(self) -> str:
        return "; ".join(self.reasons)


def check_motion(q_start_rad, q_goal_rad, limits: SafetyLimits, fk=None, T_goal_stated=None,
                 robot_limits=None) -> Verdict:
    """Check a joint-space motion from ``q_start_rad`` to ``q_goal_rad`` before it is sent.

    Joint limits: the goal (the start is where the robot is; the straight joint path between two
    in-limit points stays in the limit box). Workspace: the flange at ``path_samples`` points of
    the path via ``fk``; without ``fk`` only the goal can be checked, from ``T_goal_stated``, and
    with neither the motion is refused.
    """
    reasons = list(joint_problems(q_goal_rad, limits, robot_limits))
    if reasons:
        return Verdict(False, tuple(reasons))
    if not limits.has_workspace:
        return Verdict(True)
    q1 = np.asarray(q_goal_rad, float).reshape(-1)
    if fk is not None:
        probs = workspace_problems(fk(q1), limits, what="goal flange")
        if probs:
            return Verdict(False, tuple(probs))
        q0 = q1 if q_start_rad is None else np.asarray(q_start_rad, float).reshape(-1)
        # s = 0 is where the robot already is; a start outside the box shows up at the first sample
        for s in np.linspace(0.0, 1.0, int(limits.path_samples))[1:-1]:
            T = fk(q0 + s * (q1 - q0))
            probs = workspace_problems(T, limits, what=f"flange at {100 * s:.0f}% of the path")
            if probs:
                return Verdict(False, tuple(probs))
        return Verdict(True)
    if T_goal_stated is not None:
        probs = workspace_problems(T_goal_stated, limits, what="stated goal flange")
        if probs:
            return Verdict(False, tuple(probs))
        return Verdict(True, ("path not checked: no forward kinematics; only the stated goal pose was checked",))
    return Verdict(False, ("cannot check the workspace box: the robot offers no forward kinematics, no safety.kinematics "
                           "model is configured and the trajectory pose states no T_base_flange",))
