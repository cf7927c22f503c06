"""Build the MuJoCo model of a workcell: FR3 arm, board on the flange, camera stands, cameras.

The FR3 model is the one franky-sim ships (``franky_sim/assets/fr3.xml``); its gripper is
replaced by the board mount. Frames the rest of calibgraph relies on:

- body ``base`` of the arm is the world frame (the robot base);
- site ``flange`` on ``fr3_link7`` at 0.107 m along its z axis (Franka's flange frame);
- body ``board`` is the board frame of :mod:`calibgraph.core.targets` (origin at point id 0, x along a
  row, y along a column, z into the board), child of ``fr3_link7`` through ``T_flange_board``;
- camera ``<name>`` is an OpenGL camera (looking along -z, y up) whose OpenCV optical frame is
  ``T_base_cam`` of the workcell (``R_gl = R_cv @ diag(1, -1, -1)``).

MuJoCo places a camera's principal point at the image centre, ``((W - 1) / 2, (H - 1) / 2)`` in
OpenCV pixel coordinates, and its ``fovy`` is the *vertical* field of view; both match
:meth:`calibgraph.core.camera.Intrinsics.from_hfov` for square pixels (checked by tests/test_sim.py).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.core.targets import Target
from calibgraph.core.transforms import R_to_quat_xyzw
from calibgraph.sim.workcell import Workcell

FLANGE_OFFSET_M = 0.107  # fr3_link7 -> flange along z (Franka FR3 datasheet, = the hand body's offset)
ARM_JOINTS = tuple(f"fr3_joint{i}" for i in range(1, 8))
HOME_Q_RAD = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.785])

# Texels per board square: squares stay >= 2 texels per pixel up close, and edges fall exactly on
# texel boundaries, so the rendered corner is where the geometry says it is.
TEXELS_PER_SQUARE = 64
BOARD_THICKNESS_M = 0.004


class SimulatorError(CalibgraphError):
    """The simulator (MuJoCo, its renderer or the robot model) is unavailable or failed."""


def fr3_xml_path() -> Path:
    """Path of franky-sim's FR3 MJCF model."""
    try:
        import franky_sim
    except ImportError:
        raise SimulatorError("the simulator needs franky-sim (pip install 'calibgraph[sim]').") from None
    p = Path(franky_sim.__file__).parent / "assets" / "fr3.xml"
    if not p.is_file():
        raise SimulatorError(f"franky-sim is installed but has no FR3 model at {p}; reinstall franky-sim.")
    return p


def ensure_gl_backend() -> None:
    """Pick a headless OpenGL backend before MuJoCo is imported (EGL, else OSMesa)."""
    if "MUJOCO_GL" not in os.environ:
        os.environ["MUJOCO_GL"] = "egl"
    if os.environ["MUJOCO_GL"] in ("egl", "osmesa") and "PYOPENGL_PLATFORM" not in os.environ:
        os.environ["PYOPENGL_PLATFORM"] = os.environ["MUJOCO_GL"]


# The system library each headless backend loads first, and the Debian packages it needs to render
# (measured by hiding packages: EGL renders with these three and without libgl1; OSMesa with
# libosmesa6 alone).
_GL_LIBRARIES = {
    "egl": ("libEGL.so.1",),
    "osmesa": ("libOSMesa.so.8", "libOSMesa.so.6"),
}
GL_INSTALL = {
    "egl": "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri",
    "osmesa": "apt-get install libosmesa6",
}


def gl_backend_problem() -> str | None:
    """Why MuJoCo's headless backend (``MUJOCO_GL``) cannot load here, in a phrase naming the
    package that fixes it; None when its system library loads (or the backend is not one of the
    headless ones checked here)."""
    import ctypes

    backend = os.environ.get("MUJOCO_GL", "").lower()
    if backend not in _GL_LIBRARIES:
        return None
    for name in _GL_LIBRARIES[backend]:
        try:
            ctypes.CDLL(name)
            return None
        except OSError:
            pass
    return (f"MUJOCO_GL={backend} needs {_GL_LIBRARIES[backend][0]}, which is not installed; "
            f"{GL_INSTALL[backend]} renders with MuJoCo")


# Why MuJoCo was imported without OpenGL (None when its GL backend loaded): the simulator then
# renders with calibgraph.sim.raster.
_NO_GL = {"reason": None}


def no_gl_reason() -> str | None:
    """Why MuJoCo's renderer is unavailable in this process (its headless backend's system library
    is missing, so MuJoCo was imported with ``MUJOCO_GL=disable``), or None."""
    return _NO_GL["reason"]


def import_mujoco():
    """Import MuJoCo lazily with a headless GL backend; clear error when it is missing.

    When the backend's system library (libEGL, libOSMesa) is absent, MuJoCo is imported with
    ``MUJOCO_GL=disable``: models still load, move and cast rays, and :func:`no_gl_reason` says
    why it cannot render (``SimWorld`` then renders with :mod:`calibgraph.sim.raster`). Without
    this, ``import mujoco`` itself fails under ``MUJOCO_GL=egl`` and no libEGL."""
    import importlib.util
    import sys

    if sys.modules.get("mujoco") is not None:
        return sys.modules["mujoco"]
    ensure_gl_backend()
    try:  # (a None in sys.modules blocks the import, as the tests do to mimic a machine without it)
        installed = "mujoco" not in sys.modules and importlib.util.find_spec("mujoco") is not None
    except (ImportError, ValueError):
        installed = False
    if not installed:
        raise SimulatorError("the simulator needs MuJoCo (pip install 'calibgraph[sim]').")
    backend = os.environ["MUJOCO_GL"]
    problem = gl_backend_problem()
    if problem is None:
        try:
            import mujoco

            return mujoco
        except Exception as e:  # PyOpenGL raises AttributeError when its platform library is missing
            problem = f"MUJOCO_GL={backend}: {type(e).__name__}: {e}"
            for name in [m for m in sys.modules if m == "mujoco" or m.startswith("mujoco.")]:
                del sys.modules[name]
    os.environ["MUJOCO_GL"] = "disable"
    try:
        import mujoco
    except Exception as e:
        raise SimulatorError(f"MuJoCo is installed but cannot be imported ({problem}; without OpenGL: "
                             f"{type(e).__name__}: {e})") from None
    finally:
        os.environ["MUJOCO_GL"] = backend
    _NO_GL["reason"] = problem
    return mujoco


@dataclass(frozen=True)
class BoardTexture:
    """The printed sheet: an RGB image and the board-frame rectangle it covers.

    ``image[r, c]`` shows board point ``(x0 + (c + 0.5) * texel, y0 + (r + 0.5) * texel)``.
    """

    image: np.ndarray
    x0_m: float
    y0_m: float
    texel_m: float

    @property
    def width_m(self) -> float:
        return self.image.shape[1] * self.texel_m

    @property
    def height_m(self) -> float:
        return self.image.shape[0] * self.texel_m


def board_texture(target: Target, sheet_m=(0.297, 0.210), texels_per_square: int = TEXELS_PER_SQUARE) -> BoardTexture:
    """Checkerboard texture of ``target`` centred on a white sheet (A4 landscape by default).

    Square (r, c) of the printed grid (r along y, c along x, starting at the square outside
    point 0) is black when r + c is even, so the square touching point 0 from outside is black,
    as in OpenCV's pattern generator.
    """
    if target.kind != "checkerboard":
        raise InputError(f"cannot render a {target.kind} target; the simulator renders checkerboards.")
    if texels_per_square & (texels_per_square - 1) or texels_per_square < 8:
        raise InputError("texels_per_square must be a power of two >= 8.")
    n = int(texels_per_square)
    sx, sy = target.squares_x, target.squares_y
    texel = target.pitch_m / n
    # Sheet size in whole multiples of 64 texels (and n a power of two): every mipmap level down
    # to 1/64 then averages whole texel blocks that never straddle a square edge, so the edges
    # (hence the corners) stay exactly in place when the board is seen small.
    W = 64 * int(np.ceil(max(sheet_m[0] / texel, sx * n + n // 2) / 64))
    H = 64 * int(np.ceil(max(sheet_m[1] / texel, sy * n + n // 2) / 64))
    mx, my = (W - sx * n) // 2, (H - sy * n) // 2
    img = np.full((H, W, 3), 255, np.uint8)
    r = np.arange(sy * n) // n
    c = np.arange(sx * n) // n
    black = ((r[:, None] + c[None, :]) % 2) == 0
    img[my:my + sy * n, mx:mx + sx * n][black] = 0
    # board frame: point 0 sits one square in from the grid's outer corner
    x0 = -target.pitch_m - mx * texel
    y0 = -target.pitch_m - my * texel
    return BoardTexture(image=img, x0_m=x0, y0_m=y0, texel_m=texel)


def _quat_wxyz(R: np.ndarray) -> list:
    x, y, z, w = R_to_quat_xyzw(R)
    return [w, x, y, z]


def _board_mesh(spec, tex: BoardTexture, thickness_m: float):
    """A thin box mesh in the board frame: printed face at z = 0 (facing -z), back at z = +thickness.

    Texture coordinates: the printed face spans the whole texture; other faces sample a white
    border texel. MuJoCo's texture v axis runs from the image's first row (checked by the
    detection test, which compares detected corner ids with projected ground truth).
    """
    x0, y0 = tex.x0_m, tex.y0_m
    x1, y1 = x0 + tex.width_m, y0 + tex.height_m
    z0, z1 = 0.0, thickness_m
    v = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)
    # texcoords: 0..3 map the front face corners; 4 is a white border texel
    half = 0.5 / max(tex.image.shape)
    tc = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [half, half]], float)
    # outward normals: front face is -z (counter-clockwise seen from -z)
    faces = [(0, 2, 1), (0, 3, 2),            # front (z = 0, normal -z)
             (4, 5, 6), (4, 6, 7),            # back
             (0, 1, 5), (0, 5, 4), (1, 2, 6), (1, 6, 5), (2, 3, 7), (2, 7, 6), (3, 0, 4), (3, 4, 7)]
    ftc = [(0, 2, 1), (0, 3, 2)] + [(4, 4, 4)] * 10
    mesh = spec.add_mesh()
    mesh.name = "board_mesh"
    mesh.uservert = v.reshape(-1).tolist()
    mesh.usertexcoord = tc.reshape(-1).tolist()
    mesh.userface = np.asarray(faces, int).reshape(-1).tolist()
    mesh.userfacetexcoord = np.asarray(ftc, int).reshape(-1).tolist()
    return mesh


def build_spec(cell: Workcell, max_size_px=(1920, 1080)):
    """MjSpec of the cell (see the module docstring for the frames)."""
    mujoco = import_mujoco()
    path = fr3_xml_path()
    spec = mujoco.MjSpec.from_file(str(path))
    spec.meshdir = str(path.parent / "meshes")
    spec.modelname = f"calibgraph_{cell.name}"
    # kinematic use only: drop the gripper and everything that drives it
    for a in list(spec.actuators):
        spec.delete(a)
    for t in list(spec.tendons):
        spec.delete(t)
    for e in list(spec.equalities):
        spec.delete(e)
    for k in list(spec.keys):
        spec.delete(k)
    spec.delete(spec.body("hand"))

    spec.visual.global_.offwidth = int(max_size_px[0]) * cell.realism.supersample
    spec.visual.global_.offheight = int(max_size_px[1]) * cell.realism.supersample
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0
    spec.visual.headlight.ambient = [0.35, 0.35, 0.35]
    spec.visual.headlight.diffuse = [0.45, 0.45, 0.45]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.visual.map.znear = 0.01
    spec.stat.extent = 4.0

    wb = spec.worldbody
    light = wb.add_light()
    light.pos = [0.0, 0.0, 2.5]
    light.dir = [0.0, 0.0, -1.0]
    light.diffuse = [0.5, 0.5, 0.5]
    light.specular = [0.0, 0.0, 0.0]
    light.castshadow = False

    # floor and pedestal (the base frame is the top of the pedestal)
    floor_mat = spec.add_material()
    floor_mat.name = "floor"
    floor_mat.rgba = [0.42, 0.43, 0.45, 1.0]
    g = wb.add_geom()
    g.name = "floor"
    g.type = mujoco.mjtGeom.mjGEOM_PLANE
    g.size = [10.0, 10.0, 0.1]
    g.pos = [0.0, 0.0, cell.floor_z_m]
    g.material = "floor"
    ped_h = -cell.floor_z_m
    if ped_h > 0:
        g = wb.add_geom()
        g.name = "pedestal"
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.size = [0.25, 0.25, ped_h / 2 - 0.001]
        g.pos = [-0.05, 0.0, -ped_h / 2 - 0.001]
        g.rgba = [0.25, 0.27, 0.3, 1.0]

    # declared static geometry: solid boxes render and collide; keep-out volumes only collide
    for b in cell.obstacles:
        g = wb.add_geom()
        g.name = f"{'keepout' if b.keep_out else 'obstacle'}_{b.name}"
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.size = (np.asarray(b.size_m, float) / 2).tolist()
        g.pos = np.asarray(b.centre_m, float).tolist()
        g.rgba = [0.8, 0.3, 0.2, 0.0] if b.keep_out else [0.55, 0.5, 0.45, 1.0]
        g.group = 3 if b.keep_out else 0

    # flange site and board mount
    link7 = spec.body("fr3_link7")
    s = link7.add_site()
    s.name = "flange"
    s.pos = [0.0, 0.0, FLANGE_OFFSET_M]
    s.size = [0.005, 0.005, 0.005]
    s.group = 4

    tex = board_texture(cell.target)
    t = spec.add_texture()
    t.name = "board_tex"
    t.type = mujoco.mjtTexture.mjTEXTURE_2D
    t.width = tex.image.shape[1]
    t.height = tex.image.shape[0]
    t.nchannel = 3
    t.data = tex.image.tobytes()
    m = spec.add_material()
    m.name = "board_mat"
    m.textures = ["", "board_tex"] + [""] * 8  # slot mjTEXROLE_RGB
    m.specular = 0.0
    m.shininess = 0.0
    m.reflectance = 0.0
    _board_mesh(spec, tex, BOARD_THICKNESS_M)

    T_flange_board = np.asarray(cell.T_flange_board, float)
    T_l7_board = np.eye(4)
    T_l7_board[2, 3] = FLANGE_OFFSET_M
    T_l7_board = T_l7_board @ T_flange_board
    board = link7.add_body()
    board.name = "board"
    board.pos = T_l7_board[:3, 3].tolist()
    board.quat = _quat_wxyz(T_l7_board[:3, :3])
    board.mass = 0.2
    board.inertia = [1e-3, 1e-3, 1e-3]
    bg = board.add_geom()
    bg.name = "board_geom"
    bg.type = mujoco.mjtGeom.mjGEOM_MESH
    bg.meshname = "board_mesh"
    bg.material = "board_mat"
    bg.mass = 0.0
    bg.density = 0.0

    # mount: a short rod from the flange to the back of the board (along the flange z axis)
    back_centre_f = T_flange_board[:3, :3] @ np.array([
        tex.x0_m + tex.width_m / 2, tex.y0_m + tex.height_m / 2, BOARD_THICKNESS_M]) + T_flange_board[:3, 3]
    length = float(back_centre_f[2])
    if length > 0.005:
        mg = link7.add_geom()
        mg.name = "mount_rod"
        mg.type = mujoco.mjtGeom.mjGEOM_CYLINDER
        mg.size = [0.03, length / 2, 0]
        mg.pos = [float(back_centre_f[0]), float(back_centre_f[1]), FLANGE_OFFSET_M + length / 2]
        mg.rgba = [0.15, 0.15, 0.17, 1.0]
        mg.mass = 0.0
        mg.density = 0.0

    # cameras and their stands
    for cam in cell.cameras:
        T = np.asarray(cam.T_base_cam, float)
        R_gl = T[:3, :3] @ np.diag([1.0, -1.0, -1.0])
        c = wb.add_camera()
        c.name = cam.name
        c.pos = T[:3, 3].tolist()
        c.quat = _quat_wxyz(R_gl)
        K = cam.intrinsics.K
        c.fovy = float(np.degrees(2 * np.arctan(cam.intrinsics.height_px / (2 * K[1, 1]))))
        body_c = T[:3, 3] - 0.045 * T[:3, 2]  # housing entirely behind the optical centre
        hg = wb.add_geom()
        hg.name = f"{cam.name}_housing"
        hg.type = mujoco.mjtGeom.mjGEOM_BOX
        hg.size = [0.06, 0.03, 0.02]  # camera axes: width, height, depth
        hg.pos = body_c.tolist()
        hg.quat = _quat_wxyz(T[:3, :3])
        hg.rgba = [0.1, 0.1, 0.1, 1.0]
        top = body_c[2] - 0.035
        if top - cell.floor_z_m > 0.05:
            sg = wb.add_geom()
            sg.name = f"{cam.name}_stand"
            sg.type = mujoco.mjtGeom.mjGEOM_CYLINDER
            sg.size = [0.025, (top - cell.floor_z_m) / 2, 0]
            sg.pos = [float(body_c[0]), float(body_c[1]), (top + cell.floor_z_m) / 2]
            sg.rgba = [0.3, 0.3, 0.32, 1.0]
    return spec


def build_model(cell: Workcell):
    """Compile the cell into an ``MjModel``."""
    sizes = [(c.intrinsics.width_px, c.intrinsics.height_px) for c in cell.cameras] or [(640, 480)]
    spec = build_spec(cell, (max(s[0] for s in sizes), max(s[1] for s in sizes)))
    try:
        return spec.compile()
    except Exception as e:  # MuJoCo raises ValueError with the compiler message
        raise SimulatorError(f"cannot compile the simulated workcell {cell.name!r}: {e}") from None
