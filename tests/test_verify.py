"""calibgraph verify: the chi-square test of a camera's pose against a stored calibration.

Synthetic cells (sim.synthetic_corners, 0.3 px corner noise), the oracle's (true intrinsics held: the
1-sigma below is conditional on them): three cameras at 3 m calibrated from 40 poses
(stored 1-sigma 0.6-1.1 mm, 0.010-0.019 deg per axis), verified from 6 fresh poses. Unmoved
cameras give m2 of a few (chi-square 6 dof: mean 6), a 2 mm bump gives m2 > 100 (measured), so
the thresholds below (alpha 0.001: m2 > 22.5) leave a wide margin on both sides.
"""

from __future__ import annotations

import json
from functools import lru_cache

import numpy as np
import pytest

from calibgraph.cli.main import main
from calibgraph.core.transforms import exp_so3, make_T
from calibgraph.sim.synthetic_corners import make_scene, ring_cameras
from calibgraph.solver.solve.batch import solve
from calibgraph.solver.output.result import Result
from calibgraph.solver.changes.verify import chi2_isf_6, chi2_sf_6, verify
from helpers import write_sim_dataset


@lru_cache(maxsize=1)
def _calibrated():
    cams = ring_cameras([3.0, 3.0, 3.0], spread_deg=200)
    res = solve(make_scene(cams, n_poses=40, seed=1, reported_intrinsics="exact").problem)
    return cams, Result.from_dict(json.loads(json.dumps(res.to_dict())))  # as read back from result.json


def _verify_scene(cams, seed=7, **kw):
    return make_scene(cams, n_poses=6, seed=seed, shared_fraction=0.6, reported_intrinsics="exact", **kw)


def _bumped(cams, name, dt_m=(0, 0, 0), drot_rad=(0, 0, 0)):
    T, intr = cams[name]
    T2 = make_T(exp_so3(np.asarray(drot_rad, float)) @ T[:3, :3], T[:3, 3] + np.asarray(dt_m, float))
    return {**cams, name: (T2, intr)}


def test_chi2_6_closed_form():
    # scipy.stats.chi2(6): sf(12.5916) = 0.05, sf(22.4577) = 0.001
    assert chi2_sf_6(12.5916) == pytest.approx(0.05, abs=1e-5)
    assert chi2_sf_6(22.4577) == pytest.approx(0.001, abs=1e-6)
    assert chi2_isf_6(0.001) == pytest.approx(22.4577, abs=1e-3)


def test_nothing_moved_is_unchanged():
    cams, stored = _calibrated()
    vr = verify(_verify_scene(cams).problem, stored)
    assert vr.verdict == "unchanged"
    assert all(c.status == "unchanged" and c.mahalanobis2 < chi2_isf_6(1e-3) for c in vr.cameras.values())


def test_bumped_camera_is_named():
    cams, stored = _calibrated()
    vr = verify(_verify_scene(_bumped(cams, "cam1", dt_m=(0.0, 0.0015, 0.0015))).problem, stored)
    assert vr.verdict == "cameras_moved" and vr.moved == ["cam1"]
    c = vr.cameras["cam1"]
    assert c.p_value < 1e-6
    # the estimated displacement agrees with the 2.1 mm bump within 3 sigma along it
    assert abs(c.displacement_mm - 2.12) < 3 * c.sigma_displacement_mm


def test_rotated_camera_is_named():
    cams, stored = _calibrated()
    vr = verify(_verify_scene(_bumped(cams, "cam2", drot_rad=np.radians([0.2, 0, 0]))).problem, stored)
    assert vr.moved == ["cam2"]
    assert abs(vr.cameras["cam2"].rotation_deg - 0.2) < 3 * vr.cameras["cam2"].sigma_rotation_deg


def test_moved_board_mount_is_not_blamed_on_the_cameras():
    cams, stored = _calibrated()
    T_fb = stored.T_flange_board
    moved_mount = make_T(exp_so3(np.radians([0.5, 0, 0])) @ T_fb[:3, :3], T_fb[:3, 3] + [0.004, 0, 0])
    vr = verify(_verify_scene(cams, T_flange_board=moved_mount).problem, stored)
    assert vr.verdict == "mount_or_robot_moved", vr.cameras
    assert np.linalg.norm(vr.mount_change[3:]) == pytest.approx(0.004, abs=0.002)


def test_cli_exit_codes_and_verdict(tmp_path, capsys):
    cams, stored = _calibrated()
    stored.save(tmp_path / "result.json")
    still = write_sim_dataset(tmp_path / "still", _verify_scene(cams).problem)
    bumped = write_sim_dataset(tmp_path / "bumped", _verify_scene(_bumped(cams, "cam0", dt_m=(0.002, 0, 0))).problem)
    assert main(["verify", "--result", str(tmp_path / "result.json"), str(still)]) == 0
    assert json.loads((still / "verify.json").read_text())["verdict"] == "unchanged"
    assert main(["verify", "--result", str(tmp_path / "result.json"), str(bumped)]) == 3
    out = capsys.readouterr().out
    assert "verdict: moved: cam0" in out and "cam1" in out
    v = json.loads((bumped / "verify.json").read_text())
    assert v["moved"] == ["cam0"] and v["cameras"]["cam0"]["p_value"] < 1e-3
    # a re-run keeps the verdict it replaces, as a result is kept (it was replaced silently)
    first = (still / "verify.json").read_bytes()
    assert main(["verify", "--result", str(tmp_path / "result.json"), str(still)]) == 0
    assert (still / "verify.1.json").read_bytes() == first and "kept the previous verdict as" in capsys.readouterr().out


def test_cli_bad_input_is_one_line(tmp_path, capsys):
    cams, stored = _calibrated()
    ds = write_sim_dataset(tmp_path / "ds", _verify_scene(cams).problem)
    assert main(["verify", "--result", str(tmp_path / "missing.json"), str(ds)]) == 2
    (tmp_path / "r.json").write_text(json.dumps({**stored.to_dict(), "mode": "eye_in_hand"}))
    assert main(["verify", "--result", str(tmp_path / "r.json"), str(ds)]) == 2
    assert main(["verify", "--result", str(tmp_path / "r.json"), str(tmp_path / "nope")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 3
