"""``calibgraph sim`` writes a loadable dataset with ground truth, through the acquisition state
machine, and replays a saved trajectory."""

import json

import numpy as np
import pytest
from helpers import require_sim

from calibgraph.core.transforms import inv, pose_error

pytestmark = pytest.mark.sim

CELL = """
name: small
board: a4_54
robot: {fk_sigma_translation_m: 5.0e-5, fk_sigma_rotation_deg: 0.005}
realism: {noise_sigma_dn: 2.0, blur_sigma_px: 0.6}
cameras:
  left: {preset: d455, position_m: [1.2, 0.7, 0.4], look_at_m: [0.5, 0.0, 0.45]}
  right: {preset: d455, position_m: [1.2, -0.7, 0.4], look_at_m: [0.5, 0.0, 0.45]}
"""


def test_cli_sim_writes_dataset_with_ground_truth(tmp_path):
    require_sim()
    from calibgraph.cli.main import main
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.io.layouts import load_dataset
    from calibgraph.plan.trajectory import load_trajectory

    cell = tmp_path / "cell.yaml"
    cell.write_text(CELL)
    out = tmp_path / "ds"
    assert main(["sim", "--workcell", str(cell), "--out", str(out), "--poses", "5", "--quiet"]) == 0
    ds = load_dataset(out)
    assert ds.problems == ()
    assert set(ds.cameras) == {"left", "right"} and ds.cameras["left"].width_px == 1280
    assert len(ds.captures) == 5 and all(v.detected for v in ds.views)
    assert all((out / v.image).is_file() for v in ds.views)
    gt = load_ground_truth(out)
    traj = load_trajectory(out / "planned_trajectory.yaml")
    assert traj.n_capture == 5  # via poses (capture: false), if any, come on top
    for cap in ds.captures:
        T_true = gt["T_base_flange_true"][cap.index]
        # the capture holds the robot's reported pose: true pose + its kinematic error (5e-5 m sigma)
        e_m, e_deg = pose_error(cap.T_base_flange, T_true)
        assert 0 < e_m < 5e-4 and e_deg < 0.05
        assert np.allclose(T_true, traj.poses[cap.index].T_base_flange, atol=1e-9)
    # stored detections agree with the board points projected through the ground truth (the images are
    # rendered with the true intrinsics, not the ones the cameras report)
    pts = ds.target.points_board_m
    for v in ds.views:
        T_cb = inv(gt["T_base_cam"][v.camera]) @ gt["T_base_flange_true"][v.capture] @ gt["T_flange_board"]
        uv = gt["intrinsics_true"][v.camera].project(pts @ T_cb[:3, :3].T + T_cb[:3, 3])
        assert np.abs(v.uv_px - uv[v.ids]).max() < 1.0
    raw = json.loads((out / "ground_truth.json").read_text())
    assert raw["format"] == "calibgraph-ground-truth/1" and "frame_convention" in raw
    assert raw["cameras"]["left"]["intrinsics"]["width_px"] == 1280
    # the cameras report factory-class intrinsics (the workcell's default): dataset.yaml holds them with
    # source 'factory', ground_truth.json holds both; 0.6 % focal, 3 px principal point, 0.01 k1/k2
    for name, intr in ds.cameras.items():
        true = gt["intrinsics_true"][name]
        assert intr.source == "factory" and raw["cameras"][name]["intrinsics_reported"] == intr.to_dict()
        assert np.allclose(raw["cameras"][name]["intrinsics_true"]["K"], true.K) and "source" not in raw["cameras"][name]["intrinsics_true"]
        f_rel = intr.K[[0, 1], [0, 1]] / true.K[[0, 1], [0, 1]] - 1
        assert 1e-5 < abs(f_rel[0]) < 5 * 0.006 and abs(f_rel[0] - f_rel[1]) < 5 * 0.0005  # fx, fy: one common error
        assert 0 < np.abs(intr.K[:2, 2] - true.K[:2, 2]).max() < 5 * 3.0
        assert 0 < np.abs(intr.dist[:2] - true.dist[:2]).max() < 5 * 0.01 and np.allclose(intr.dist[2:], true.dist[2:])
    # replaying the saved trajectory into a new folder gives the same captures
    out2 = tmp_path / "ds2"
    assert main(["sim", "--workcell", str(cell), "--trajectory", str(out / "planned_trajectory.yaml"),
                 "--out", str(out2), "--quiet"]) == 0
    ds2 = load_dataset(out2)
    assert [c.index for c in ds2.captures] == [c.index for c in ds.captures]
    gt2 = load_ground_truth(out2)
    for k, T in gt["T_base_flange_true"].items():
        assert np.allclose(gt2["T_base_flange_true"][k], T, atol=1e-12)
    # an existing dataset is refused with advice
    assert main(["sim", "--workcell", str(cell), "--out", str(out), "--poses", "2", "--quiet"]) == 2


def test_cli_sim_with_joint_offsets_reports_what_a_real_arm_does(tmp_path):
    # the arm's joint zeros are off: it reports q_rad = true - offsets and the nominal FK of those,
    # the images follow the true angles, and ground_truth.json records the offsets
    require_sim()
    from calibgraph.acquire.safety import franka_fk
    from calibgraph.cli.main import main
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.io.layouts import load_dataset

    o = np.array([0.0, 0.002, -0.001, 0.0015, -0.002, 0.001, 0.0])
    cell = tmp_path / "cell.yaml"
    cell.write_text(CELL.replace("fk_sigma_rotation_deg: 0.005}",
                                 f"fk_sigma_rotation_deg: 0.005, joint_offsets_rad: {o.tolist()}}}"))
    out = tmp_path / "ds"
    assert main(["sim", "--workcell", str(cell), "--out", str(out), "--poses", "3", "--quiet"]) == 0
    ds = load_dataset(out)
    gt = load_ground_truth(out)
    assert np.allclose(gt["joint_offsets_rad"], o, atol=0) and gt["raw"]["robot"]["joint_offsets_rad"] == o.tolist()
    assert gt["raw"]["workcell"]["robot"]["joint_offsets_rad"] == o.tolist()
    assert len(ds.captures) == 3
    for cap in ds.captures:
        raw = gt["raw"]["captures"][str(cap.index)]
        assert np.allclose(np.asarray(raw["q_rad_true"]) - o, cap.q_rad, atol=1e-12)
        # reported pose: nominal FK of the reported angles, up to the 5e-5 m / 0.005 deg repeatability
        e_m, e_deg = pose_error(cap.T_base_flange, franka_fk(cap.q_rad))
        assert e_m < 5e-4 and e_deg < 0.05
        # true pose: FK of the true angles; 1-2 mrad on joints 2-6 move the flange by about a millimetre,
        # well beyond the repeatability (3 x 5e-5 x sqrt(3) m)
        assert np.allclose(gt["T_base_flange_true"][cap.index], franka_fk(cap.q_rad + o), atol=1e-9)
        assert pose_error(cap.T_base_flange, gt["T_base_flange_true"][cap.index])[0] > 3e-4
    pts = ds.target.points_board_m
    for v in ds.views:
        T_cb = inv(gt["T_base_cam"][v.camera]) @ gt["T_base_flange_true"][v.capture] @ gt["T_flange_board"]
        uv = gt["intrinsics_true"][v.camera].project(pts @ T_cb[:3, :3].T + T_cb[:3, 3])
        assert np.abs(v.uv_px - uv[v.ids]).max() < 1.0
    bad = tmp_path / "bad.yaml"
    bad.write_text(CELL.replace("fk_sigma_rotation_deg: 0.005}", "fk_sigma_rotation_deg: 0.005, joint_offsets_rad: [0, 1]}"))
    assert main(["sim", "--workcell", str(bad), "--out", str(tmp_path / "ds3"), "--poses", "3", "--quiet"]) == 2
