"""Simulated cameras report intrinsics as real ones do: off by a factory calibration's error
(``realism.reported_intrinsics``), while images and synthetic corners come from the true ones;
``exact`` keeps the oracle. The same in a workcell, in ``make_scene`` and in every simulated device."""

from types import SimpleNamespace

import numpy as np
import pytest
import yaml
from helpers import require_sim

from calibgraph.core.camera import preset
from calibgraph.core.errors import InputError
from calibgraph.sim.reported_intrinsics import FACTORY, ReportedIntrinsics, parse_reported, reported_intrinsics
from calibgraph.sim.synthetic_corners import make_scene
from calibgraph.sim.workcell import workcell_from_dict, workcell_to_dict

CELL = {"name": "two", "board": "a4_54",
        "realism": {"reported_intrinsics": {"focal_rel_sigma": 0.006, "principal_point_sigma_px": 3.0,
                                            "k1_sigma": 0.01, "k2_sigma": 0.01, "seed": 11}},
        "cameras": {"left": {"preset": "d455", "position_m": [1.2, 0.7, 0.4], "look_at_m": [0.5, 0.0, 0.45]},
                    "right": {"preset": "d455", "position_m": [1.2, -0.7, 0.4], "look_at_m": [0.5, 0.0, 0.45]}}}


def test_draws_have_the_declared_spread_and_fx_fy_share_their_error():
    true = preset("l515")
    n = 4000
    draws = [reported_intrinsics(true, f"cam{i}", FACTORY) for i in range(n)]
    f = np.array([[d.K[0, 0] / true.K[0, 0] - 1, d.K[1, 1] / true.K[1, 1] - 1] for d in draws])
    c = np.array([d.K[:2, 2] - true.K[:2, 2] for d in draws])
    k = np.array([d.dist[:2] - true.dist[:2] for d in draws])
    # a sample sigma of 4000 draws is within +-5 % (4.5 of its standard errors) of the declared one
    for got, want in ((f[:, 0], 0.006), (c[:, 0], 3.0), (c[:, 1], 3.0), (k[:, 0], 0.01), (k[:, 1], 0.01)):
        assert got.std() == pytest.approx(want, rel=0.05) and abs(got.mean()) < 4 * want / np.sqrt(n)
    # one common focal error plus a 0.05 % aspect part: correlation (36 - 0.0625) / (36 + 0.0625)
    assert np.corrcoef(f.T)[0, 1] > 0.99
    assert (f[:, 0] - f[:, 1]).std() == pytest.approx(0.0005, rel=0.05)
    d = draws[0]
    assert d.source == "factory" and (d.width_px, d.height_px) == (true.width_px, true.height_px)
    assert np.allclose(d.dist[2:], true.dist[2:]) and d.K[0, 1] == 0


def test_exact_is_the_truth_and_a_camera_always_reports_the_same():
    true = preset("d455")
    ex = reported_intrinsics(true, "cam0", "exact")
    assert ex.source == "exact" and np.array_equal(ex.K, true.K) and np.array_equal(ex.dist, true.dist)
    a, b = reported_intrinsics(true, "cam0", FACTORY), reported_intrinsics(true, "cam0", FACTORY)
    assert np.array_equal(a.K, b.K) and np.array_equal(a.dist, b.dist)
    assert not np.array_equal(a.K, reported_intrinsics(true, "cam1", FACTORY).K)
    assert not np.array_equal(a.K, reported_intrinsics(true, "cam0", ReportedIntrinsics(seed=12)).K)


def test_workcell_block_round_trips_and_bad_blocks_are_refused_in_one_line(tmp_path, capsys):
    cell = workcell_from_dict(CELL, "cell.yaml")
    assert cell.realism.reported_intrinsics == FACTORY and not cell.oracle_intrinsics
    back = workcell_from_dict(yaml.safe_load(yaml.safe_dump(workcell_to_dict(cell))), "again.yaml")
    assert back.realism == cell.realism
    for n in cell.camera_names:
        assert np.array_equal(back.intrinsics()[n].K, cell.intrinsics()[n].K)
        assert cell.intrinsics()[n].source == "factory" and cell.true_intrinsics()[n].source == "exact"
    # no block: factory-class by default; 'exact': the oracle, also through the YAML round trip
    assert workcell_from_dict({k: v for k, v in CELL.items() if k != "realism"}, "c").realism.reported_intrinsics == FACTORY
    ex = cell.with_reported_intrinsics("exact")
    assert ex.oracle_intrinsics and workcell_from_dict(workcell_to_dict(ex), "c").oracle_intrinsics
    assert all(np.array_equal(ex.intrinsics()[n].K, ex.true_intrinsics()[n].K) for n in ex.camera_names)
    for bad, msg in (({"focal_rel_sigma": -0.1}, "focal_rel_sigma must be a number >= 0"),
                     ({"focal_rel_sigma": 0.6}, "relative"), ({"colour": 1}, "unknown keys"),
                     ("maybe", "give 'exact'")):
        with pytest.raises(InputError, match=msg):
            parse_reported(bad)
    from calibgraph.cli.main import main

    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump({**CELL, "realism": {"reported_intrinsics": {"focal_rel_sigma": "big"}}}))
    assert main(["sim", "--workcell", str(f), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "reported_intrinsics: focal_rel_sigma" in err[0]


def test_make_scene_projects_with_the_truth_and_hands_over_what_the_cameras_report():
    sc = make_scene(n_poses=8, pixel_sigma_px=0.0, seed=3)
    for n, intr in sc.problem.cameras.items():
        assert intr.source == "factory" and not np.allclose(intr.K, sc.truth.intrinsics[n].K)
    # noise-free corners are the truth's projections through the true intrinsics, to rounding
    pts = sc.problem.points_board_m
    for d in sc.problem.detections:
        T_cb = np.linalg.inv(sc.truth.T_ref_cam[d.camera]) @ sc.truth.T_base_flange_true[d.capture] @ sc.truth.T_mount_board
        uv = sc.truth.intrinsics[d.camera].project(pts @ T_cb[:3, :3].T + T_cb[:3, 3])
        assert np.abs(uv[d.ids] - d.uv_px).max() < 1e-9
    oracle = make_scene(n_poses=8, pixel_sigma_px=0.0, seed=3, reported_intrinsics="exact")
    for n, intr in oracle.problem.cameras.items():
        assert intr.source == "exact" and np.array_equal(intr.K, oracle.truth.intrinsics[n].K)
    # the same geometry and corners either way: only what the solver is told differs
    assert all(np.array_equal(a.uv_px, b.uv_px) for a, b in zip(sc.problem.detections, oracle.problem.detections))


def test_every_simulated_device_reports_what_the_workcell_says():
    from calibgraph.sim.corner_devices import CornerCamera
    from calibgraph.sim.devices import SimCamera

    for reported in ("factory", "exact"):
        cell = workcell_from_dict(CELL, "cell.yaml").with_reported_intrinsics(reported)
        world = SimpleNamespace(cell=cell)  # the cameras read the cell only until they grab
        for cam in (SimCamera(world, "left"), CornerCamera(world, "left", None)):
            got, want = cam.intrinsics(), cell.reported_intrinsics("left")
            assert got.source == ("exact" if reported == "exact" else "factory") and np.array_equal(got.K, want.K)
            assert np.array_equal(got.K, cell.camera("left").intrinsics.K) == (reported == "exact")


@pytest.mark.sim
def test_capture_with_the_simulated_robot_writes_factory_intrinsics_and_the_truth(tmp_path):
    """``calibgraph capture --robot sim`` (a trajectory replay on the simulated cell): dataset.yaml holds
    the reported intrinsics (source factory), ground_truth.json the true ones."""
    require_sim()
    from calibgraph.cli.main import main
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.io.layouts import load_dataset
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld

    cell = workcell_from_dict(CELL, "cell.yaml")
    world = SimWorld(cell)
    try:
        plan_trajectory(world, 2, seed=0).save(tmp_path / "t.yaml")
    finally:
        world.close()
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(CELL))
    out = tmp_path / "ds"
    assert main(["capture", "--workcell", str(tmp_path / "cell.yaml"), "--trajectory", str(tmp_path / "t.yaml"),
                 "--out", str(out), "--quiet"]) == 0
    ds, gt = load_dataset(out), load_ground_truth(out)
    for n in cell.camera_names:
        assert ds.cameras[n].source == "factory" and np.allclose(ds.cameras[n].K, cell.reported_intrinsics(n).K)
        assert np.allclose(gt["intrinsics_true"][n].K, cell.camera(n).intrinsics.K)


def test_the_public_synth_import_path_still_serves_make_scene_and_ring_cameras():
    """Scripts outside the repository import ``calibgraph.sim.synth.make_scene`` / ``ring_cameras``."""
    import calibgraph.sim.synth as synth
    import calibgraph.sim.synthetic_corners as corners

    assert synth.make_scene is corners.make_scene and synth.ring_cameras is corners.ring_cameras
    assert set(synth.__all__) <= set(dir(corners))
