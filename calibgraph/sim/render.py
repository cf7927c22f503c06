"""Rendering a workcell camera, and the image degradations that make it look like a sensor.

:class:`SimWorld` owns the MuJoCo model, its state and an offscreen renderer; the simulated robot
and cameras (:mod:`calibgraph.sim.devices`) share one world. :func:`degrade` turns the ideal
render into a sensor image: exposure, distortion, defocus and motion blur, read and shot noise.

Renderers: MuJoCo's (OpenGL through ``MUJOCO_GL``, EGL by default) or calibgraph's built-in one
(:mod:`calibgraph.sim.raster`, no system library). ``renderer='auto'`` (the default, or the
``CALIBGRAPH_RENDERER`` environment variable: auto | mujoco | raster) uses MuJoCo's when an OpenGL
context opens and otherwise falls back, saying so in one line on stderr. Both feed the same
:func:`degrade`, so noise, blur, exposure and distortion do not depend on the renderer.
"""

from __future__ import annotations

import os
import sys

import numpy as np

from calibgraph.core.camera import undistort_normalised
from calibgraph.core.errors import InputError
from calibgraph.sim import ik
from calibgraph.sim.raster import Rasteriser
from calibgraph.sim.scene import (
    ARM_JOINTS,
    GL_INSTALL,
    SimulatorError,
    build_model,
    import_mujoco,
    no_gl_reason,
)
from calibgraph.sim.workcell import Realism, Workcell


class SimWorld:
    """MuJoCo model + data + renderer of a workcell.

    Attributes:
        cell: the :class:`Workcell`.
        model, data: MuJoCo model and state (qpos holds the 7 arm joints).
        renderer: 'auto', 'mujoco' or 'raster' (argument, else ``CALIBGRAPH_RENDERER``, else
            'auto'); 'auto' becomes 'mujoco' or 'raster' at the first render (module docstring).
    """

    RENDERERS = ("auto", "mujoco", "raster")

    def __init__(self, cell: Workcell, renderer: str | None = None):
        renderer = (renderer or os.environ.get("CALIBGRAPH_RENDERER") or "auto").strip().lower()
        if renderer not in self.RENDERERS:
            raise InputError(f"renderer {renderer!r} (CALIBGRAPH_RENDERER): expected one of {', '.join(self.RENDERERS)}.")
        self.renderer = renderer  # resolved to 'mujoco' or 'raster' at the first render
        self._raster = None
        self.mujoco = import_mujoco()
        self.cell = cell
        self.model = build_model(cell)
        self.data = self.mujoco.MjData(self.model)
        self.qadr = np.array([self.model.jnt_qposadr[self.model.joint(j).id] for j in ARM_JOINTS])
        self.q_lo = np.array([self.model.jnt_range[self.model.joint(j).id][0] for j in ARM_JOINTS])
        self.q_hi = np.array([self.model.jnt_range[self.model.joint(j).id][1] for j in ARM_JOINTS])
        self.flange_site = self.model.site("flange").id
        self.board_body = self.model.body("board").id
        self._renderers = {}
        self.clock_s = 0.0  # simulated time: motions and frame periods advance it
        self.last_frame_camera = {}  # id(image) -> camera name of frames handed out by SimCamera
        self.skip_hidden_renders = False  # see SimCamera
        self.mujoco.mj_forward(self.model, self.data)
        self._distortion_maps = {}
        self.rng = np.random.default_rng(cell.seed)

    # -- state -------------------------------------------------------------------------------------
    def set_q(self, q_rad) -> None:
        q = np.asarray(q_rad, float).reshape(-1)
        if q.shape != (7,) or not np.all(np.isfinite(q)):
            raise InputError(f"simulated robot: expected 7 finite joint angles, got {q.tolist()}.")
        self.data.qpos[self.qadr] = q
        self.mujoco.mj_kinematics(self.model, self.data)
        self.mujoco.mj_camlight(self.model, self.data)  # camera poses live here, not in kinematics

    def q(self) -> np.ndarray:
        return self.data.qpos[self.qadr].copy()

    def T_base_flange(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.data.site_xmat[self.flange_site].reshape(3, 3)
        T[:3, 3] = self.data.site_xpos[self.flange_site]
        return T

    def T_base_board(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.data.xmat[self.board_body].reshape(3, 3)
        T[:3, 3] = self.data.xpos[self.board_body]
        return T

    def board_truth_px(self, camera: str) -> np.ndarray:
        """(N, 2) exact pixels of the board's points in ``camera`` at the current state: the
        board pose through the camera's true intrinsics (the ones it renders with, distortion
        included)."""
        spec = self.cell.camera(camera)
        T_cam_board = np.linalg.solve(spec.T_base_cam, self.T_base_board())
        return spec.intrinsics.project(self.cell.target.points_board_m @ T_cam_board[:3, :3].T + T_cam_board[:3, 3])

    # -- the planner's robot model (calibgraph.plan.planner.RobotWorld) ---------------------------
    limit_margin_rad = ik.LIMIT_MARGIN_RAD

    def solve_ik(self, T_base_flange: np.ndarray, q_seed) -> np.ndarray | None:
        """Joint angles reaching ``T_base_flange`` from ``q_seed`` within the limits, or None."""
        return ik.solve_ik(self, T_base_flange, q_seed)

    def in_collision(self, q_rad) -> list:
        """Contact pairs of the arm (and board) at ``q_rad``; empty when free."""
        return ik.in_collision(self, q_rad)

    def path_collision(self, q0_rad, q1_rad, max_step_rad: float = 0.03) -> list:
        """Contact pairs met along the straight joint-space motion ``q0 -> q1``; empty when free."""
        return ik.path_collision(self, q0_rad, q1_rad, max_step_rad)

    def start_configuration(self) -> np.ndarray:
        """Where the arm starts (see :func:`calibgraph.sim.ik.start_configuration`)."""
        return ik.start_configuration(self)

    def occluded(self, origin_m: np.ndarray, points_m: np.ndarray) -> bool:
        """True when any rendered geometry other than the board lies on a ray from ``origin_m`` to
        one of ``points_m`` (N, 3), base frame (MuJoCo ray casts)."""
        geomgroup = np.array([1, 1, 1, 0, 0, 0], np.uint8)  # rendered groups only
        gid = np.zeros(1, np.int32)
        origin = np.asarray(origin_m, np.float64)
        for p in np.asarray(points_m, float):
            v = p - origin
            dist = np.linalg.norm(v)
            hit = self.mujoco.mj_ray(self.model, self.data, origin, v / dist, geomgroup, 1, self.board_body, gid)
            if 0 <= hit < dist - 2e-3:
                return True
        return False

    # -- rendering ---------------------------------------------------------------------------------
    def _renderer(self, w: int, h: int):
        key = (w, h)
        if key not in self._renderers:
            try:
                if no_gl_reason():
                    raise SimulatorError(no_gl_reason())
                self._renderers[key] = self.mujoco.Renderer(self.model, height=h, width=w)
            except Exception as e:
                why = str(e) if isinstance(e, SimulatorError) else f"{type(e).__name__}: {e}"
                raise SimulatorError(
                    f"cannot open a headless OpenGL context ({why}); for MUJOCO_GL=egl: "
                    f"{GL_INSTALL['egl']}, for MUJOCO_GL=osmesa: {GL_INSTALL['osmesa']}."
                ) from None
        return self._renderers[key]

    def _use_raster(self, w: int, h: int) -> bool:
        """Which renderer draws: fixed at the first call ('auto' tries MuJoCo's, then falls back)."""
        if self.renderer == "auto":
            why = no_gl_reason()
            if why is None:
                try:
                    self._renderers[(w, h)] = self.mujoco.Renderer(self.model, height=h, width=w)
                except Exception as e:  # a library that loads but no context: no display, no driver
                    why = f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"
            self.renderer = "mujoco" if why is None else "raster"
            if why is not None:
                _say_once(f"no GL backend ({why}): rendering with calibgraph's built-in rasteriser")
        if self.renderer == "raster" and self._raster is None:
            self._raster = Rasteriser(self)
        return self.renderer == "raster"

    def check_rendering(self) -> None:
        """Open every camera's renderer now (they are kept for the renders), so that a machine whose
        OpenGL cannot render fails at once with :class:`SimulatorError` (renderer 'mujoco') or says
        now that it falls back (renderer 'auto'), not after the planning."""
        s = self.cell.realism.supersample
        for c in self.cell.cameras:
            w, h = c.intrinsics.width_px * s, c.intrinsics.height_px * s
            if not self._use_raster(w, h):
                self._renderer(w, h)

    def render_ideal(self, camera: str) -> np.ndarray:
        """Noise-free RGB render (H, W, 3) uint8 of ``camera`` at the current state, pinhole, no
        distortion; supersampled renders are area-averaged back to the sensor size."""
        spec = self.cell.camera(camera)
        s = self.cell.realism.supersample
        w, h = spec.intrinsics.width_px, spec.intrinsics.height_px
        if self._use_raster(w * s, h * s):
            return self._raster.render(camera, w, h, s)
        r = self._renderer(w * s, h * s)
        r.update_scene(self.data, camera=camera)
        img = r.render()
        if s > 1:
            # Averaging s x s blocks keeps the principal point at ((W-1)/2, (H-1)/2): block k
            # covers fine pixels [k s, (k+1) s), whose centre maps to k exactly.
            img = img.reshape(h, s, w, s, 3).mean(axis=(1, 3)).astype(np.uint8)
        return img

    def render(self, camera: str, rng=None) -> np.ndarray:
        """Sensor-like grey image (H, W) uint8 of ``camera``: ideal render + :func:`degrade`.

        Grey because corner detection works on grey and it keeps noise synthesis 3x cheaper.
        """
        import cv2

        ideal = cv2.cvtColor(self.render_ideal(camera), cv2.COLOR_RGB2GRAY)
        spec = self.cell.camera(camera)
        maps = None
        if self.cell.realism.distortion:
            maps = self._distortion_maps.get(camera)
            if maps is None:
                maps = self._distortion_maps[camera] = distortion_maps(spec.intrinsics)
        return degrade(ideal, self.cell.realism, self.rng if rng is None else rng, maps)

    def close(self) -> None:
        for r in self._renderers.values():
            try:
                r.close()
            except Exception:
                pass
        self._renderers.clear()


_SAID = set()


def _say_once(line: str) -> None:
    """A line on stderr, once per process (every world of a run falls back for the same reason)."""
    if line not in _SAID:
        _SAID.add(line)
        print(line, file=sys.stderr, flush=True)


def distortion_maps(intr, iterations: int = 30):
    """cv2.remap maps that turn an ideal pinhole image (same K) into one seen through ``intr.dist``.

    For every distorted output pixel we need the ideal pixel it shows, i.e. the pixel grid
    undistorted (:func:`calibgraph.core.camera.undistort_normalised`, fixed-point iteration on the
    OpenCV model, vectorised over the whole image); converges to < 1e-4 px for the moderate distortion of real lenses.
    """
    w, h = intr.width_px, intr.height_px
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    xy = undistort_normalised(intr, np.column_stack([u.ravel(), v.ravel()]), iterations)
    uv = xy @ intr.K[:2, :2].T + intr.K[:2, 2]
    return uv[:, 0].reshape(h, w).astype(np.float32), uv[:, 1].reshape(h, w).astype(np.float32)


def degrade(img: np.ndarray, realism: Realism, rng, maps=None) -> np.ndarray:
    """Apply exposure, distortion, defocus/motion blur and sensor noise to an ideal image
    ((H, W) grey or (H, W, 3)); returns uint8 of the same shape."""
    import cv2

    x = img.astype(np.float32)
    if realism.exposure != 1.0:
        x *= float(realism.exposure)
    if maps is not None:
        x = cv2.remap(x, maps[0], maps[1], interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if realism.blur_sigma_px > 0:
        x = cv2.GaussianBlur(x, (0, 0), float(realism.blur_sigma_px))
    if realism.motion_blur_px > 0:
        L = float(realism.motion_blur_px)
        n = int(np.ceil(L)) | 1
        k = np.zeros((n, n), np.float32)
        a = rng.uniform(0, np.pi)
        c = (n - 1) / 2
        for t in np.linspace(-L / 2, L / 2, 4 * n):
            k[int(round(c + t * np.sin(a))), int(round(c + t * np.cos(a)))] += 1
        x = cv2.filter2D(x, -1, k / k.sum())
    np.clip(x, 0, 255, out=x)
    if realism.shot_noise or realism.noise_sigma_dn > 0:
        # read noise + photon noise of a sensor with a ~4000 e- full well mapped to 255 DN, drawn
        # as one Gaussian with the summed variance
        import cv2

        gain = np.float32(255.0 / 4000.0) if realism.shot_noise else np.float32(0.0)
        sigma = cv2.sqrt(x * gain + np.float32(float(realism.noise_sigma_dn) ** 2))
        # cv2's generator is ~5x faster than numpy's here; seed it from the world's generator so
        # a seeded run renders identical images
        cv2.setRNGSeed(int(rng.integers(0, 2**31 - 1)))
        noise = cv2.randn(np.empty_like(x), 0.0, 1.0)
        x += noise * sigma
        np.clip(x, 0, 255, out=x)
    return cv2.convertScaleAbs(x)  # saturating round to uint8
