"""capture --verify: poses planned from a stored result, captured on the simulated cell, verified.

The stored calibration comes from a 30-pose capture of the default cell (three L515 at 3 m), the
oracle's (its cameras report their true intrinsics, held: the 1-sigma is conditional on them), with
cameras that deliver projected corners (:mod:`calibgraph.sim.corner_devices`, 0.05 px: what the batch
solver estimates on rendered L515 frames at 3 m; stored 1-sigma about 0.5-0.7 mm / 0.01-0.02 deg
per camera). A 2 mm bump then gives m2 of several hundred from 5 verify poses (measured 683), an
unmoved camera a few (chi-square 6 dof, mean 6; the threshold at alpha 0.001 is 22.5). The
rendered runs (the CLI) use the simulator's images and detector.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import yaml

from calibgraph.cli.main import main
from calibgraph.io.files import read_yaml
from calibgraph.solver.output.result import Result
from tests.helpers import REPO, require_sim

DEFAULT = REPO / "datasets" / "workcells" / "default.yaml"


def _stored(tmp_root: str):
    """(Result as read back from result.json, Workcell) of the default cell calibrated from 30 poses of
    projected corners."""
    from calibgraph.acquire.run import run_acquisition
    from calibgraph.io.layouts import load_dataset
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.corner_devices import corner_devices
    from calibgraph.sim.workcell import workcell_from_dict
    from calibgraph.solver.solve.batch import solve
    from calibgraph.solver.solve.build import build_problem

    wc = workcell_from_dict(read_yaml(DEFAULT, "world"), "world").with_reported_intrinsics("exact")
    sim = SimWorld(wc)
    robot, cams, oracle = corner_devices(sim, 0.05, 0)
    out = f"{tmp_root}/calibration"
    run_acquisition(robot, cams, plan_trajectory(sim, 30, seed=0), out, wc.target, detector=oracle, progress=False)
    res = solve(build_problem(load_dataset(out), progress=False)[0])
    return Result.from_dict(json.loads(json.dumps(res.to_dict()))), wc


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    require_sim()
    return _stored(str(tmp_path_factory.mktemp("verify_capture")))


def _bumped(wc, name, dt_m=(0, 0, 0)):
    cams = tuple(replace(c, T_base_cam=np.vstack([np.hstack([c.T_base_cam[:3, :3], (c.T_base_cam[:3, 3] + dt_m)[:, None]]),
                                                   [0, 0, 0, 1]]))
                 if c.name == name else c for c in wc.cameras)
    return replace(wc, cameras=cams)


def _verify_run(stored, wc, out, n_poses=5, seed=1):
    from calibgraph.acquire.verify import run_verify_capture
    from calibgraph.plan.cell import cell_from_world_dict
    from calibgraph.sim.planning_world import planning_world
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.corner_devices import corner_devices

    cell = cell_from_world_dict(read_yaml(DEFAULT, "world"), "world")
    robot, cams, oracle = corner_devices(SimWorld(wc), 0.05, seed)
    return run_verify_capture(robot, cams, stored, cell, planning_world(cell), out, detector=oracle, n_poses=n_poses,
                              progress=False)


def test_verify_poses_see_every_camera_and_nothing_moved_is_unchanged(stored, tmp_path):
    result, wc = stored
    rep = _verify_run(result, wc, tmp_path / "v")
    traj = yaml.safe_load((tmp_path / "v" / "trajectory.yaml").read_text())
    assert sum(p.get("capture", True) for p in traj["poses"]) == 5
    vr = rep.verify
    assert vr.verdict == "unchanged", {n: c.mahalanobis2 for n, c in vr.cameras.items()}
    assert all(c.status == "unchanged" and c.views >= 1 for c in vr.cameras.values())
    assert json.loads((tmp_path / "v" / "verify.json").read_text())["verdict"] == "unchanged"


def test_a_camera_bumped_2mm_is_named_from_5_poses(stored, tmp_path):
    result, wc = stored
    vr = _verify_run(result, _bumped(wc, "cam1", np.array([0.0, 0.002, 0.0])), tmp_path / "v").verify
    assert vr.verdict == "cameras_moved" and vr.moved == ["cam1"]
    c = vr.cameras["cam1"]
    assert abs(c.displacement_mm - 2.0) < 3 * c.sigma_displacement_mm
    assert all(vr.cameras[n].status == "unchanged" for n in ("cam0", "cam2"))


def test_cli_capture_verify_renders_and_passes_an_unmoved_cell(stored, tmp_path, capsys):
    from calibgraph.sim.workcell import workcell_to_dict

    result, wc = stored
    result.save(tmp_path / "result.json")
    world = tmp_path / "world.yaml"  # the default cell with the stored calibration's (oracle's) intrinsics
    world.write_text(yaml.safe_dump(workcell_to_dict(wc)))
    out = tmp_path / "verify"
    rc = main(["capture", "--verify", "--result", str(tmp_path / "result.json"), "--robot", "sim", "--sim-world",
               str(world), "--out", str(out), "--quiet"])
    text = capsys.readouterr().out
    assert rc == 0, text
    v = json.loads((out / "verify.json").read_text())
    assert v["verdict"] == "unchanged" and v["moved"] == []
    assert all(c["status"] == "unchanged" for c in v["cameras"].values())
    assert (out / "ground_truth.json").is_file() and "verdict: nothing moved" in text


def test_cli_sim_capture_of_a_bumped_cell_is_verified_as_moved(stored, tmp_path, capsys):
    """`calibgraph sim --workcell WORLD.yaml --poses N` makes the verify capture of a simulated cell."""
    from calibgraph.sim.workcell import workcell_to_dict

    result, wc = stored
    result.save(tmp_path / "result.json")
    world = tmp_path / "bumped.yaml"
    world.write_text(yaml.safe_dump(workcell_to_dict(_bumped(wc, "cam2", np.array([0.002, 0.0, 0.0])))))
    out = tmp_path / "sim"
    assert main(["sim", "--workcell", str(world), "--poses", "6", "--out", str(out), "--quiet"]) == 0
    assert main(["verify", "--result", str(tmp_path / "result.json"), str(out), "--quiet"]) == 3
    v = json.loads((out / "verify.json").read_text())
    assert v["moved"] == ["cam2"], v
    assert v["cameras"]["cam2"]["p_value"] < 1e-3


def test_cli_capture_verify_refuses_bad_input_with_one_line(tmp_path, capsys):
    result = tmp_path / "result.json"
    result.write_text("{}")
    args = ["capture", "--verify", "--robot", "sim", "--sim-world", str(DEFAULT), "--out", str(tmp_path / "o")]
    assert main(args) == 2  # no --result
    assert main(args + ["--result", str(tmp_path / "nope.json")]) == 2
    assert main(args + ["--result", str(result), "--verify-poses", "0"]) == 2
    assert main(args + ["--result", str(result), "--auto"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 4 and all(line.startswith("calibgraph capture: error:") for line in err), err
    assert "--result" in err[0] and "nope.json" in err[1] and "verify-poses" in err[2] and "--auto" in err[3]
    assert not (tmp_path / "o").exists()
