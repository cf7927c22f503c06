"""The simulated workcell: projection convention, board texture, rendered corners vs ground
truth, sensor degradations, workcell files, and the Robot/Camera interfaces."""

import numpy as np
import pytest
from helpers import require_sim, sim_world_fixture

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.targets import a4_board_54, thesis_board
from calibgraph.core.transforms import inv
from calibgraph.sim.workcell import Realism, ring_workcell

pytestmark = pytest.mark.sim


world = sim_world_fixture(lambda: ring_workcell(n_cameras=2, distance_m=1.5, preset_name="d455", spread_deg=60.0,
                                                realism=Realism(noise_sigma_dn=2.0, blur_sigma_px=0.6)))


def test_board_texture_matches_board_frame():
    from calibgraph.sim.scene import board_texture

    for target in (a4_board_54(), thesis_board()):
        tex = board_texture(target)
        p = target.pitch_m

        def texel_at(x, y):
            c = int(np.floor((x - tex.x0_m) / tex.texel_m))
            r = int(np.floor((y - tex.y0_m) / tex.texel_m))
            return int(tex.image[r, c, 0])

        # the square touching point 0 from outside is black; its neighbours are white; the
        # cell between points (i, j) and (i+1, j+1) is black iff i + j is even (detector convention)
        assert texel_at(-p / 2, -p / 2) == 0
        assert texel_at(p / 2, -p / 2) == 255
        assert texel_at(-p / 2, p / 2) == 255
        for i in range(target.rows - 1):
            for j in range(target.cols - 1):
                want = 0 if (i + j) % 2 == 0 else 255
                assert texel_at(p * (j + 0.5), p * (i + 0.5)) == want
        # square edges fall on texel boundaries (so mipmaps keep them in place)
        assert abs((-tex.x0_m / tex.texel_m) - round(-tex.x0_m / tex.texel_m)) < 1e-6
        assert tex.image.shape[0] % 64 == 0 and tex.image.shape[1] % 64 == 0
        # white margin all round
        assert tex.image[0].min() == 255 and tex.image[-1].min() == 255


def test_projection_convention_matches_intrinsics(world):
    """Bright spheres at known camera-frame points: their rendered centroids sit where
    Intrinsics.project (with the sphere's exact ellipse centre) says, to < 0.05 px."""
    from calibgraph.sim.scene import build_spec, import_mujoco
    from calibgraph.sim.workcell import ring_workcell

    mj = import_mujoco()
    cell = ring_workcell(n_cameras=1, distance_m=1.5, preset_name="l515")
    cam = cell.cameras[0]
    intr, T = cam.intrinsics, cam.T_base_cam
    spec = build_spec(cell)
    spec.visual.quality.numslices = 200  # smooth silhouettes: polygon facets would bias centroids
    spec.visual.quality.numstacks = 200
    r_m = 0.04  # ~50 px radius: rasterisation noise of the centroid stays ~0.01 px
    pts = np.array([[0.0, 0.0, 1.0], [0.2, -0.1, 1.2], [-0.3, 0.15, 1.1], [0.35, 0.2, 1.3], [-0.25, -0.2, 0.9]])
    for k, p in enumerate(pts):
        g = spec.worldbody.add_geom()
        g.name = f"dot{k}"
        g.type = mj.mjtGeom.mjGEOM_SPHERE
        g.size = [r_m, 0, 0]
        g.pos = (T[:3, :3] @ p + T[:3, 3]).tolist()
        g.contype = g.conaffinity = 0
    m = spec.compile()
    d = mj.MjData(m)
    mj.mj_forward(m, d)
    r = mj.Renderer(m, intr.height_px, intr.width_px)
    r.enable_segmentation_rendering()
    r.update_scene(d, camera=cam.name)
    seg = r.render()[..., 0]
    r.close()
    for k, p in enumerate(pts):
        ys, xs = np.nonzero(seg == m.geom(f"dot{k}").id)
        assert xs.size > 4000
        # a sphere images as an ellipse whose centre is the mean of the tangent-cone extremes
        D = np.linalg.norm(p)
        th, a, phi = np.arccos(p[2] / D), np.arcsin(r_m / D), np.arctan2(p[1], p[0])
        rho = (np.tan(th + a) + np.tan(th - a)) / 2
        uv = intr.project(np.array([[rho * np.cos(phi), rho * np.sin(phi), 1.0]]))[0]
        err = np.array([xs.mean(), ys.mean()]) - uv
        # measured: <= 0.028 px; a half-pixel convention slip would show as 0.5 px, a wrong
        # fovy (horizontal taken for vertical) as tens of pixels
        assert np.abs(err).max() < 0.05, (k, err)


def test_rendered_corners_match_projected_truth(world):
    """Detected corners in rendered images (noise + blur) agree with the board points projected
    through the true chain: same ids, no bias, sub-pixel scatter."""
    from calibgraph.detect.corners import detect_image
    from calibgraph.plan.planner import plan_trajectory

    traj = plan_trajectory(world, 4, seed=3)
    errs = []
    for pose in traj.poses:
        world.set_q(pose.q_rad)
        for cam in pose.cameras:
            spec = world.cell.camera(cam)
            img = world.render(cam)
            assert img.shape == (spec.intrinsics.height_px, spec.intrinsics.width_px) and img.dtype == np.uint8
            det = detect_image(img, world.cell.target, spec.intrinsics)
            assert det.ok, det.reason
            T_cb = inv(spec.T_base_cam) @ world.T_base_board()
            p_c = world.cell.target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3]
            uv = spec.intrinsics.project(p_c)
            errs.append(det.uv_px - uv[det.ids])
    E = np.concatenate(errs)
    # measured at 1.5 m (D455): |mean| ~0.01 px, rms ~0.05 px. A wrong id order would give
    # errors of a whole square (tens of px); a half-texel or half-pixel slip a bias >= 0.1 px.
    assert np.abs(E.mean(axis=0)).max() < 0.05
    assert np.sqrt((E**2).sum(axis=1).mean()) < 0.25
    assert np.abs(E).max() < 1.0


def test_degrade_noise_level_and_blur():
    from calibgraph.sim.render import degrade
    from calibgraph.sim.workcell import Realism

    rng = np.random.default_rng(0)
    flat = np.full((200, 300), 100, np.uint8)
    out = degrade(flat, Realism(noise_sigma_dn=3.0, shot_noise=False, blur_sigma_px=0.0), rng)
    assert out.dtype == np.uint8 and out.shape == flat.shape
    assert abs(out.astype(float).std() - 3.0) < 0.3
    assert abs(out.astype(float).mean() - 100) < 0.3
    shot = degrade(flat, Realism(noise_sigma_dn=0.0, shot_noise=True, blur_sigma_px=0.0), rng)
    assert abs(shot.astype(float).std() - np.sqrt(100 * 255 / 4000)) < 0.3
    dark = degrade(flat, Realism(noise_sigma_dn=0.0, shot_noise=False, blur_sigma_px=0.0, exposure=0.5), rng)
    assert np.all(dark == 50)
    step = np.zeros((50, 50), np.uint8)
    step[:, 25:] = 200
    b = degrade(step, Realism(noise_sigma_dn=0.0, shot_noise=False, blur_sigma_px=1.5), rng)
    assert 0 < b[10, 24] < 200 and 0 < b[10, 25] < 200  # the edge is spread over several pixels


def test_distortion_maps_follow_opencv_model():
    """The remap tables send each distorted pixel to the ideal pixel whose ray Intrinsics.project
    (with distortion) puts there."""
    import cv2

    from calibgraph.sim.render import distortion_maps

    intr = Intrinsics.from_hfov(320, 200, 80.0, dist=[0.1, -0.05, 0.001, -0.002, 0.01])
    mx, my = distortion_maps(intr)
    rng = np.random.default_rng(1)
    uv_ideal = np.column_stack([rng.uniform(40, 280, 50), rng.uniform(30, 170, 50)])
    rays = np.column_stack([(uv_ideal - intr.K[:2, 2]) / intr.K[0, 0], np.ones(50)])
    uv_dist = intr.project(rays)
    m = uv_dist.astype(np.float32).reshape(-1, 1, 2)
    back_u = cv2.remap(mx, m[..., 0], m[..., 1], cv2.INTER_LINEAR).ravel()
    back_v = cv2.remap(my, m[..., 0], m[..., 1], cv2.INTER_LINEAR).ravel()
    # bilinear interpolation of a smooth map: measured error < 0.01 px
    assert np.abs(np.column_stack([back_u, back_v]) - uv_ideal).max() < 0.02


def test_workcell_yaml_round_trip_and_errors(tmp_path):
    import yaml

    from calibgraph.sim.workcell import (
        load_workcell,
        workcell_from_dict,
        workcell_to_dict,
    )

    for name in ("default", "thesis_one_side", "large_cell"):
        from pathlib import Path

        cell = load_workcell(Path(__file__).resolve().parents[1] / "datasets" / "workcells" / f"{name}.yaml")
        assert len(cell.cameras) >= 3
        back = workcell_from_dict(yaml.safe_load(yaml.safe_dump(workcell_to_dict(cell))))
        assert back.target == cell.target
        for a, b in zip(cell.cameras, back.cameras):
            assert a.name == b.name and np.allclose(a.T_base_cam, b.T_base_cam) and np.allclose(a.intrinsics.K, b.intrinsics.K)
        assert np.allclose(back.T_flange_board, cell.T_flange_board)
    default = load_workcell(Path(__file__).resolve().parents[1] / "datasets" / "workcells" / "default.yaml")
    d = [np.hypot(*c.T_base_cam[:2, 3]) for c in default.cameras]
    assert np.allclose(d, 3.0) and np.allclose([c.T_base_cam[2, 3] for c in default.cameras], 0.8)
    o = [0.0, 1e-3, -2e-3, 0.5e-3, 0.0, 1e-3, 0.0]
    cell = workcell_from_dict({"ring": {"distances_m": [2.0]}, "robot": {"joint_offsets_rad": o}})
    assert cell.joint_offsets_rad == tuple(o) and default.joint_offsets_rad == (0.0,) * 7
    assert workcell_from_dict(yaml.safe_load(yaml.safe_dump(workcell_to_dict(cell)))).joint_offsets_rad == tuple(o)
    for bad in ([0.0] * 6, [0.0] * 6 + ["x"], 0.1):
        with pytest.raises(InputError, match="joint_offsets_rad"):
            workcell_from_dict({"ring": {"distances_m": [2.0]}, "robot": {"joint_offsets_rad": bad}})
    with pytest.raises(InputError, match="unknown keys"):
        workcell_from_dict({"ring": {"distances_m": [2.0]}, "camras": {}})
    with pytest.raises(InputError, match="no cameras"):
        workcell_from_dict({"board": "a4_54"})
    with pytest.raises(InputError, match="unknown board"):
        workcell_from_dict({"board": "huge", "ring": {"distances_m": [2.0]}})
    with pytest.raises(InputError, match="position_m"):
        workcell_from_dict({"cameras": {"c": {"preset": "l515"}}})
    p = tmp_path / "bad.yaml"
    p.write_text("ring: [unclosed")
    with pytest.raises(InputError, match="cannot read workcell"):
        load_workcell(p)


def test_sim_devices_implement_interfaces(world):
    from calibgraph.acquire.interfaces import Camera, Robot, UnreachableError
    from calibgraph.acquire.safety import franka_fk
    from calibgraph.sim.devices import make_devices
    from calibgraph.sim.scene import HOME_Q_RAD

    robot, cams = make_devices(world, fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=1e-4, seed=1)
    assert isinstance(robot, Robot)
    assert all(isinstance(c, Camera) for c in cams.values())
    robot.move_to_joints(HOME_Q_RAD)
    assert np.allclose(robot.joint_positions(), HOME_Q_RAD) and robot.is_settled()
    # the MuJoCo FR3 flange is libfranka's flange frame
    assert np.allclose(robot.true_flange_pose(), franka_fk(HOME_Q_RAD), atol=1e-9)
    d = robot.flange_pose()[:3, 3] - robot.true_flange_pose()[:3, 3]
    assert 0 < np.linalg.norm(d) < 1e-3  # reported pose carries the kinematic error
    assert np.allclose(robot.flange_pose(), robot.flange_pose())  # ... fixed while the arm is still
    lo, hi = robot.joint_limits()
    with pytest.raises(UnreachableError, match="joint 4"):
        q = HOME_Q_RAD.copy()
        q[3] = hi[3] + 0.1
        robot.move_to_joints(q)
    with pytest.raises(UnreachableError, match="collides"):
        q = HOME_Q_RAD.copy()
        q[1] = 1.5  # shoulder forward, elbow folded: link 6 goes into the pedestal
        q[3] = -3.0
        robot.move_to_joints(q)
    assert np.allclose(robot.joint_positions(), HOME_Q_RAD)  # a refused motion does not move
    f0 = cams["cam0"].grab()
    f1 = cams["cam0"].grab()
    assert f1.stamp_s > f0.stamp_s and f0.image.dtype == np.uint8 and f0.camera == "cam0"
    assert cams["cam0"].intrinsics().width_px == 1280


def test_lens_distortion_renders_the_opencv_model():
    """With distortion on, the camera reports the coefficients and rendered corners follow
    Intrinsics.project with them (measured: |mean| < 0.01 px, rms ~0.05 px at 1.5 m)."""
    require_sim()
    from calibgraph.detect.corners import detect_image
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.workcell import Realism, ring_workcell

    w = SimWorld(ring_workcell(n_cameras=1, distance_m=1.5, preset_name="d455", realism=Realism(distortion=True)))
    spec = w.cell.cameras[0]
    assert np.allclose(spec.intrinsics.dist, Realism().distortion_coeffs)
    traj = plan_trajectory(w, 2, seed=5)
    errs = []
    for p in traj.poses:
        w.set_q(p.q_rad)
        det = detect_image(w.render(spec.name), w.cell.target, spec.intrinsics)
        assert det.ok, det.reason
        T_cb = inv(spec.T_base_cam) @ w.T_base_board()
        uv = spec.intrinsics.project(w.cell.target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3])
        errs.append(det.uv_px - uv[det.ids])
    E = np.concatenate(errs)
    # the lens really bends the image: the top-left pixel shows a point ~20 px further out
    mx, my = w._distortion_maps[spec.name]
    assert np.hypot(mx[0, 0], my[0, 0]) > 10
    assert np.abs(E.mean(axis=0)).max() < 0.05 and np.sqrt((E**2).sum(axis=1).mean()) < 0.25
    w.close()


@pytest.mark.parametrize("q_rad, cam", [
    # Poses of `calibgraph demo` (3 x L515 at 3 m, seed 0) whose fully visible board was missed
    # before the detector searched the arm-merged saddle region (squares 13.2 px and 9.2 px).
    ([1.404788, -0.074993, -0.13124, -2.61221, 2.297638, 1.858225, -0.604387], "cam2"),
    ([-1.086852, -0.484282, -0.141066, -2.488678, 2.536052, 2.440888, -0.519721], "cam0"),
])
def test_board_touching_the_arm_is_detected(q_rad, cam):
    """A board on the flange sits next to the arm; the saddle filter's region then spans both
    and looked too big for a small board, and OpenCV's fast check on the whole frame rejects
    ~10-13 px squares: such boards were lost although fully in view."""
    require_sim()
    from calibgraph.detect.corners import detect_image
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.workcell import ring_workcell

    cell = ring_workcell(n_cameras=3, distance_m=3.0, preset_name="l515", board="a4_54", spread_deg=200.0, seed=0)
    w = SimWorld(cell)
    try:
        w.set_q(np.array(q_rad))
        spec = cell.camera(cam)
        det = detect_image(w.render(cam, rng=np.random.default_rng(0)), cell.target, spec.intrinsics)
        assert det.ok, det.reason
        T_cb = inv(spec.T_base_cam) @ w.T_base_board()
        uv = spec.intrinsics.project(cell.target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3])
        err = det.uv_px - uv[det.ids]
        # rendered corners at 3 m scatter ~0.06 px; a wrong ordering would be off by whole squares
        assert det.ids.size == cell.target.n_points
        assert np.sqrt((err**2).sum(axis=1).mean()) < 0.2 and np.abs(err).max() < 0.6
    finally:
        w.close()
