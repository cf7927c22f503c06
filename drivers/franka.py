"""Franka Emika Panda / Franka Research 3 through pylibfranka (the ``franka`` extra).

    pip install 'calibgraph[franka]'      # pylibfranka >= 0.15 (tested with 0.21)

Implements :class:`calibgraph.acquire.interfaces.Robot`.

Frames (libfranka names, all column-major 4x4 in the robot state):

- ``O``: the robot base. calibgraph's ``base``.
- ``F``: the flange (link 8, 0.107 m past joint 7's axis). **calibgraph's ``flange``**:
  :meth:`FrankaRobot.flange_pose` returns ``T_base_flange = O_T_EE @ inv(F_T_EE)``, so the result
  does not depend on what the Franka Desk end-effector settings say (with the Franka Hand,
  ``F_T_EE`` is 0.1034 m along z and -45 deg about z; without it, identity).
- ``EE`` / ``NE``: the end effector (TCP) configured in Desk / with ``set_EE``. Available as
  :meth:`FrankaRobot.ee_pose`; not used for calibration, because a TCP setting that changes
  between capture and use would silently move the result.

Motion: :meth:`FrankaRobot.move_to_joints` plans a quintic (minimum-jerk) joint trajectory whose
duration keeps every joint's peak velocity, acceleration and jerk at or below ``speed_scale`` times
the datasheet limits, and streams it at 1 kHz through ``start_joint_position_control`` (internal
joint impedance controller). The straight joint-space path is what :mod:`calibgraph.acquire.safety`
checks. A control exception (reflex, collision, communication) stops the motion, runs
``automatic_error_recovery`` and raises :class:`~calibgraph.acquire.interfaces.DeviceError`.

Real-time: libfranka expects a real-time kernel (``RealtimeConfig.kEnforce``); pass
``realtime=False`` for the simulator or a development PC (``kIgnore``). The Python loop runs one
``readOnce``/``writeOnce`` pair per 1 ms tick; if the host misses ticks the robot's own
interpolation covers short gaps, and persistent misses end in a communication-constraints
reflex (reported as DeviceError).

One client at a time: like the robot's FCI, franky-sim serves a single libfranka connection, and
a second ``pylibfranka.Robot`` to a busy server blocks inside libfranka with the GIL held (no
Python-level timeout can interrupt it). Close one :class:`FrankaRobot` before opening another.

Tested against franky-sim (``franky-sim -s mujoco``), which serves the libfranka network protocol
on a loopback address: see ``tests/test_driver_franka.py``. Never run franky-sim in the same
process as pylibfranka: the connect call holds the GIL and deadlocks an in-process server.
"""

from __future__ import annotations

import socket
import time

import numpy as np

from calibgraph.acquire.interfaces import DeviceError, UnreachableError
from calibgraph.acquire.safety import FRANKA_LIMITS, franka_fk

_JERK_MAX_RAD_S3 = 5000.0  # Panda/FR3 datasheets: 5000-7500 rad/s^3; the lower value is used for both

try:  # the SDK is an optional extra; the engine and other drivers must import without it
    import pylibfranka as _franka
except ImportError:  # pragma: no cover - exercised only where pylibfranka is absent
    _franka = None


def _require_sdk():
    if _franka is None:
        raise DeviceError("the Franka driver needs pylibfranka: pip install 'calibgraph[franka]' "
                          "(pylibfranka >= 0.15, matching the robot's system version).")
    return _franka


def _T(colmajor16) -> np.ndarray:
    return np.asarray(colmajor16, float).reshape(4, 4).T


def quintic_duration_s(q0, q1, speed_scale: float, model: str = "fr3") -> float:
    """Shortest duration of the quintic ``q0 -> q1`` that keeps each joint's peak velocity
    (1.875 dq / T), acceleration (5.7735 dq / T^2) and jerk (60 dq / T^3) at ``speed_scale`` times
    the datasheet limits."""
    lim = FRANKA_LIMITS[model]
    dq = np.abs(np.asarray(q1, float) - np.asarray(q0, float))
    s = float(speed_scale)
    if not (0 < s <= 1):
        raise UnreachableError(f"speed_scale must be in (0, 1], got {speed_scale}.")
    T_v = np.max(1.875 * dq / (s * np.asarray(lim["dq_max_rad_s"])))
    T_a = np.max(np.sqrt(5.7735 * dq / (s * np.asarray(lim["ddq_max_rad_s2"]))))
    T_j = np.max(np.cbrt(60.0 * dq / (s * _JERK_MAX_RAD_S3)))
    return float(max(T_v, T_a, T_j, 0.05))


def _quintic(a: float) -> float:
    a = min(max(a, 0.0), 1.0)
    return a * a * a * (10.0 + a * (-15.0 + 6.0 * a))


class FrankaRobot:
    """A Panda / FR3 arm (see the module docstring).

    Args:
        ip: robot (or franky-sim) address.
        model: 'fr3' or 'panda' (joint limits, velocity limits).
        realtime: enforce libfranka's real-time checks (True on a real robot with an RT kernel).
        settle_velocity_rad_s, settle_window_s: :meth:`is_settled` threshold on the joint speed
            measured over that window.
        connect_timeout_s: a TCP probe of port 1337 fails fast instead of letting libfranka hang.
    """

    def __init__(self, ip: str, model: str = "fr3", realtime: bool = False, settle_velocity_rad_s: float = 0.005,
                 settle_window_s: float = 0.05, connect_timeout_s: float = 5.0):
        fr = _require_sdk()
        if model not in FRANKA_LIMITS:
            raise DeviceError(f"Franka model must be one of {sorted(FRANKA_LIMITS)}, got {model!r}.")
        self.ip = ip
        self.model = model
        self.settle_velocity_rad_s = float(settle_velocity_rad_s)
        self.settle_window_s = float(settle_window_s)
        self.last_motion = {}
        try:
            with socket.create_connection((ip, 1337), timeout=connect_timeout_s):
                pass
        except OSError as e:
            raise DeviceError(f"Franka at {ip}: cannot reach the control port 1337 ({e}); check the cable, the IP "
                              "and that FCI is enabled in Desk.") from None
        try:
            self._robot = fr.Robot(ip, fr.RealtimeConfig.kEnforce if realtime else fr.RealtimeConfig.kIgnore)
        except Exception as e:  # pylibfranka raises NetworkException / IncompatibleVersionException / RuntimeError
            raise DeviceError(f"Franka at {ip}: connection failed ({type(e).__name__}: {e}).") from None
        try:
            # Collision thresholds well above what a slow calibration motion needs, below the defaults.
            self._robot.set_collision_behavior([20.0] * 7, [40.0] * 7, [20.0] * 6, [40.0] * 6)
        except Exception as e:
            raise DeviceError(f"Franka at {ip}: cannot set collision behaviour ({e}).") from None

    # -- state --------------------------------------------------------------------------------------
    def _state(self):
        try:
            return self._robot.read_once()
        except Exception as e:
            raise DeviceError(f"Franka at {self.ip}: reading the robot state failed ({type(e).__name__}: {e}).") from None

    def joint_positions(self) -> np.ndarray:
        """q_rad (7,) measured."""
        return np.asarray(self._state().q, float)

    def flange_pose(self) -> np.ndarray:
        """T_base_flange (4, 4): libfranka's O_T_EE @ inv(F_T_EE) (flange, not the TCP)."""
        s = self._state()
        return _T(s.O_T_EE) @ np.linalg.inv(_T(s.F_T_EE))

    def ee_pose(self) -> np.ndarray:
        """T_base_EE (4, 4) of the configured end effector (TCP), libfranka's O_T_EE."""
        return _T(self._state().O_T_EE)

    def forward_kinematics(self, q_rad) -> np.ndarray:
        """T_base_flange for any q (nominal kinematics; used by the safety path check)."""
        return franka_fk(q_rad)

    def joint_limits(self):
        lim = FRANKA_LIMITS[self.model]
        return np.asarray(lim["q_min_rad"]), np.asarray(lim["q_max_rad"])

    def is_settled(self) -> bool:
        """True when every joint moved slower than ``settle_velocity_rad_s`` over a window of
        ``settle_window_s`` on the robot's clock. Measured from positions rather than the ``dq``
        signal, which is noisy (encoder differentiation on the robot, contact chatter in franky-sim)."""
        s0 = self._state()
        t_wall_end = time.monotonic() + max(2.0, 20 * self.settle_window_s)
        while True:
            time.sleep(0.25 * self.settle_window_s)
            s1 = self._state()
            # the window is measured on the robot's clock, so a simulator running slower than real
            # time is judged over the same motion as a real robot
            dt = s1.time.to_sec() - s0.time.to_sec()
            if dt >= self.settle_window_s:
                break
            if time.monotonic() > t_wall_end:
                return False  # the robot's clock hardly advances: not a state to call settled
        v = np.abs(np.asarray(s1.q, float) - np.asarray(s0.q, float)) / dt
        return float(np.max(v)) < self.settle_velocity_rad_s

    # -- motion -------------------------------------------------------------------------------------
    def move_to_joints(self, q_rad, speed_scale: float = 0.2) -> None:
        """Quintic joint-space motion to ``q_rad`` (7,) at ``speed_scale`` of the limits; blocks."""
        fr = _franka
        q1 = np.asarray(q_rad, float).reshape(-1)
        lo, hi = self.joint_limits()
        if q1.size != 7 or not np.all(np.isfinite(q1)):
            raise UnreachableError(f"Franka: a joint target needs 7 finite values, got {q1.tolist()}.")
        if np.any(q1 < lo) or np.any(q1 > hi):
            j = int(np.argmax((q1 < lo) | (q1 > hi)))
            raise UnreachableError(f"Franka: joint {j + 1} target {q1[j]:.3f} rad is outside [{lo[j]:.3f}, {hi[j]:.3f}].")
        try:
            ctrl = self._robot.start_joint_position_control(fr.ControllerMode.JointImpedance)
            state, _ = ctrl.readOnce()
            q0 = np.asarray(state.q_d if np.any(state.q_d) else state.q, float)
            T = quintic_duration_s(q0, q1, speed_scale, self.model)
            t = 0.0
            peak_dq = 0.0
            ticks = 0
            while True:
                a = t / T
                cmd = fr.JointPositions(list(q0 + (q1 - q0) * _quintic(a)))
                if a >= 1.0:
                    cmd.motion_finished = True
                    ctrl.writeOnce(cmd)
                    break
                ctrl.writeOnce(cmd)
                state, dur = ctrl.readOnce()
                t += dur.to_sec()
                ticks += 1
                peak_dq = max(peak_dq, float(np.max(np.abs(np.asarray(state.dq)))))
        except UnreachableError:
            raise
        except Exception as e:  # ControlException (reflex), NetworkException, ...
            self._recover()
            raise DeviceError(f"Franka at {self.ip}: motion aborted ({type(e).__name__}: {e}); the robot stopped "
                              "and error recovery ran.") from None
        self.last_motion = {"duration_s": T, "ticks": ticks, "peak_dq_rad_s": peak_dq, "q_start_rad": q0, "q_goal_rad": q1,
                            "speed_scale": float(speed_scale)}

    def _recover(self) -> None:
        try:
            self._robot.automatic_error_recovery()
        except Exception:  # recovery is best effort; the caller gets the original error
            pass

    def stop(self) -> None:
        try:
            self._robot.stop()
        except Exception:
            pass

    def close(self) -> None:
        """Drop the connection (the robot holds its position under its own brakes/controller)."""
        self._robot = None
