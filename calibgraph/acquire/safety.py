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
      floor_z_m: -0.8               # static geometry the flange (plus clearance_m) must stay clear of:
      pedestal: true                #   the floor, the pedestal under the base (default 0.5 x 0.5 m, down to
      boxes:                        #   the floor; false for none, or {centre_m, size_m}) and declared boxes
        - {name: table, centre_m: [0.6, 0.0, -0.1], size_m: [0.8, 1.2, 0.2]}
      clearance_m: 0.05             # kept between the flange origin and the static geometry (board, mount)
      stated_tolerance_m: 0.01      # a pose's stated T_base_flange must agree with FK of its joints
      stated_tolerance_deg: 2.0

Static geometry. Every motion is checked against the cell's static geometry: the floor, the
pedestal the robot stands on and declared boxes (the workcell's ``obstacles`` and ``keep_out``
are added by ``calibgraph capture``). A workcell without a ``safety:`` section gets
:func:`default_cell_limits` (Franka FR3 limits and kinematics, pedestal, floor at -0.8 m) and a
warning saying so: a dry run never approves a pose nobody checked against the cell.

Stated pose against FK. A trajectory pose that states ``T_base_flange`` is refused when the
forward kinematics of its joints put the flange elsewhere (more than ``stated_tolerance_m`` /
``stated_tolerance_deg``): an edited joint or pose means that what was planned is not what would
be executed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.kinematics import franka_fk  # noqa: F401 - the one Franka FK, re-exported for callers
from calibgraph.core.transforms import pose_error
from calibgraph.plan.cell import Box, boxes_from_list

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
    floor_z_m: float | None = None
    pedestal: Box | None = None
    boxes: tuple = ()
    clearance_m: float = 0.05
    stated_tolerance_m: float = 0.01
    stated_tolerance_deg: float = 2.0
    default_model: bool = False

    def __post_init__(self):
        object.__setattr__(self, "boxes", tuple(self.boxes))
        if self.floor_z_m is not None and not np.isfinite(self.floor_z_m):
            raise InputError("safety: floor_z_m must be a finite number (metres).")
        if not (self.clearance_m >= 0 and self.stated_tolerance_m > 0 and self.stated_tolerance_deg > 0):
            raise InputError("safety: clearance_m must be >= 0, stated_tolerance_m and stated_tolerance_deg > 0.")
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
            raise InputError(f"safety: unknown kinematics {self.kinematics!r}; known: {', '.join(sorted(KINEMATICS))}.")
        if int(self.path_samples) < 2:
            raise InputError("safety: path_samples must be >= 2.")

    @classmethod
    def from_dict(cls, d: dict | None, floor_z_m: float | None = None, obstacles=()) -> "SafetyLimits":
        """Build from the ``safety:`` mapping of a workcell file; ``robot_model`` presets
        ('panda', 'fr3') fill in joint limits that are not given. The floor (``floor_z_m`` here, else
        the workcell's, else -0.8 m), the pedestal down to it and the boxes (``boxes`` here plus the
        workcell's ``obstacles``) are always part of the limits."""
        if d is not None and not isinstance(d, dict):
            raise InputError("safety: must be a mapping (see calibgraph.acquire.safety).")
        d = dict(d or {})
        allowed = (set(cls.__dataclass_fields__) | {"robot_model"}) - {"default_model"}
        unknown = set(d) - allowed
        if unknown:
            raise InputError(f"safety: unknown keys {', '.join(sorted(unknown))}; allowed: {', '.join(sorted(allowed))}.")
        model = d.pop("robot_model", None)
        if model is not None:
            if model not in FRANKA_LIMITS:
                raise InputError(f"safety: unknown robot_model {model!r}; known: {', '.join(sorted(FRANKA_LIMITS))}.")
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
        for k in ("clearance_m", "stated_tolerance_m", "stated_tolerance_deg"):
            if k in d:
                kw[k] = float(d[k])
        floor = d.get("floor_z_m", floor_z_m if floor_z_m is not None else DEFAULT_FLOOR_Z_M)
        kw["floor_z_m"] = None if floor is None else float(floor)
        ped = d.get("pedestal", True)
        if ped is True:
            kw["pedestal"] = default_pedestal(kw["floor_z_m"])
        elif isinstance(ped, dict):
            kw["pedestal"] = boxes_from_list([{"name": "pedestal", **ped}], "safety: pedestal", True)[0]
        elif ped not in (False, None):
            raise InputError("safety: pedestal must be true (the default pedestal), false or {centre_m, size_m}.")
        kw["boxes"] = tuple(boxes_from_list(d.get("boxes"), "safety: boxes", True)) + tuple(obstacles)
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
        if self.floor_z_m is not None:
            out["floor_z_m"] = float(self.floor_z_m)
        out["pedestal"] = (False if self.pedestal is None else
                           {"centre_m": self.pedestal.centre_m.tolist(), "size_m": self.pedestal.size_m.tolist()})
        if self.boxes:
            out["boxes"] = [{"name": b.name, "centre_m": b.centre_m.tolist(), "size_m": b.size_m.tolist()}
                            for b in self.boxes]
        out.update(clearance_m=self.clearance_m, stated_tolerance_m=self.stated_tolerance_m,
                   stated_tolerance_deg=self.stated_tolerance_deg)
        return out

    @property
    def has_workspace(self) -> bool:
        return self.workspace_min_m is not None

    @property
    def has_geometry(self) -> bool:
        return self.floor_z_m is not None or self.pedestal is not None or bool(self.boxes)

    def describe(self) -> str:
        """One line: what the static-geometry check knows of the cell."""
        parts = []
        if self.pedestal is not None:
            lo, hi = self.pedestal.centre_m - self.pedestal.size_m / 2, self.pedestal.centre_m + self.pedestal.size_m / 2
            parts.append(f"a {self.pedestal.size_m[0]:.2f} x {self.pedestal.size_m[1]:.2f} m pedestal "
                         f"(x {lo[0]:.2f}..{hi[0]:.2f}, y {lo[1]:.2f}..{hi[1]:.2f} m) under the base")
        if self.floor_z_m is not None:
            parts.append(f"the floor at z = {self.floor_z_m:.2f} m")
        if self.boxes:
            parts.append(f"{len(self.boxes)} declared box(es) ({', '.join(b.name for b in self.boxes)})")
        return ", ".join(parts) + f", clearance {self.clearance_m:g} m" if parts else "no static geometry"


DEFAULT_FLOOR_Z_M = -0.8
PEDESTAL_SIZE_M = (0.5, 0.5)
PEDESTAL_CENTRE_XY_M = (-0.05, 0.0)  # as the simulated cell's (calibgraph.sim.scene)


def default_pedestal(floor_z_m: float | None) -> Box:
    """The pedestal under the robot base (the base frame is its top), down to the floor (1 m without one)."""
    h = -floor_z_m if floor_z_m is not None and floor_z_m < 0 else 1.0
    return Box("pedestal", [PEDESTAL_CENTRE_XY_M[0], PEDESTAL_CENTRE_XY_M[1], -h / 2],
               [PEDESTAL_SIZE_M[0], PEDESTAL_SIZE_M[1], h], keep_out=True)


def default_cell_limits(robot_model: str = "fr3", floor_z_m: float | None = None, obstacles=()) -> SafetyLimits:
    """The limits used when a workcell declares no ``safety:`` section: the robot model's joint
    limits and kinematics, a pedestal under the base, the floor (-0.8 m unless the workcell says)
    and the workcell's obstacles; ``default_model`` is set so that callers warn."""
    model = robot_model if robot_model in FRANKA_LIMITS else "fr3"
    lim = SafetyLimits.from_dict({"robot_model": model}, floor_z_m=floor_z_m, obstacles=obstacles)
    from dataclasses import replace

    return replace(lim, default_model=True)


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


def geometry_problems(T_base_flange, limits: SafetyLimits, what: str = "flange") -> list:
    """Reasons why the flange origin of ``T_base_flange`` (with ``clearance_m`` around it) meets the
    cell's static geometry: the floor, the pedestal, declared boxes."""
    if not limits.has_geometry:
        return []
    T = np.asarray(T_base_flange, float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        return [f"{what} pose is not a finite 4x4 transform"]
    p = T[:3, 3]
    at = f"{what} at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m"
    c = limits.clearance_m
    out = []
    if limits.floor_z_m is not None and p[2] < limits.floor_z_m + c:
        out.append(f"{at} is {'below' if p[2] < limits.floor_z_m else 'within the clearance of'} the floor "
                   f"(z = {limits.floor_z_m:.2f} m, clearance {c:g} m)")
    for b in ((limits.pedestal,) if limits.pedestal is not None else ()) + limits.boxes:
        if b.contains(p[None], inflate_m=c)[0]:
            lo, hi = b.centre_m - b.size_m / 2, b.centre_m + b.size_m / 2
            inside = b.contains(p[None])[0]
            out.append(f"{at} is {'inside' if inside else 'within the clearance of'} the {b.name} "
                       f"([{', '.join(f'{v:.2f}' for v in lo)}] .. [{', '.join(f'{v:.2f}' for v in hi)}] m, "
                       f"clearance {c:g} m)")
    return out


def stated_pose_problems(T_fk, T_stated, limits: SafetyLimits) -> list:
    """A pose's stated ``T_base_flange`` against the forward kinematics of its joints."""
    d_m, d_deg = pose_error(np.asarray(T_fk, float), np.asarray(T_stated, float))
    if d_m <= limits.stated_tolerance_m and d_deg <= limits.stated_tolerance_deg:
        return []
    p = np.asarray(T_fk)[:3, 3]
    return [f"its stated T_base_flange is {d_m * 1e3:.0f} mm / {d_deg:.1f} deg from the forward kinematics of its "
            f"joints (which put the flange at ({p[0]:.3f}, {p[1]:.3f}, {p[2]:.3f}) m): the joints or the pose were "
            "edited; re-plan the trajectory or correct q_rad / T_base_flange"]


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
    in-limit points stays in the limit box). Stated pose: ``T_goal_stated`` must agree with
    ``fk(q_goal)``. Workspace box and static geometry (floor, pedestal, boxes): the flange at
    ``path_samples`` points of the path via ``fk``; without ``fk`` only the goal can be checked,
    from ``T_goal_stated``, and with neither the motion is refused.
    """
    reasons = list(joint_problems(q_goal_rad, limits, robot_limits))
    if reasons:
        return Verdict(False, tuple(reasons))
    q1 = np.asarray(q_goal_rad, float).reshape(-1)
    T_fk = fk(q1) if fk is not None else None
    if T_fk is not None and T_goal_stated is not None:
        probs = stated_pose_problems(T_fk, T_goal_stated, limits)
        if probs:
            return Verdict(False, tuple(probs))
    if not limits.has_workspace and not limits.has_geometry:
        return Verdict(True)

    def problems(T, what):
        return workspace_problems(T, limits, what) + geometry_problems(T, limits, what)

    if fk is not None:
        probs = problems(T_fk, "goal flange")
        if probs:
            return Verdict(False, tuple(probs))
        q0 = q1 if q_start_rad is None else np.asarray(q_start_rad, float).reshape(-1)
        # s = 0 is where the robot already is; a start outside the box shows up at the first sample
        for s in np.linspace(0.0, 1.0, int(limits.path_samples))[1:-1]:
            T = fk(q0 + s * (q1 - q0))
            probs = problems(T, f"flange at {100 * s:.0f}% of the path")
            if probs:
                return Verdict(False, tuple(probs))
        return Verdict(True)
    if T_goal_stated is not None:
        probs = problems(T_goal_stated, "stated goal flange")
        if probs:
            return Verdict(False, tuple(probs))
        return Verdict(True, ("path not checked: no forward kinematics; only the stated goal pose was checked",))
    return Verdict(False, ("cannot check the workspace box and the cell geometry: the robot offers no forward kinematics, "
                           "no safety.kinematics model is configured and the trajectory pose states no T_base_flange",))
