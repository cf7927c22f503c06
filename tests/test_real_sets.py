"""scripts/real_sets.py without the network or the snapshots: the records, the pose conventions the
converters were verified with on the real files, and the output folder rules."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from calibgraph.core.camera import Intrinsics
from calibgraph.core.targets import Target
from calibgraph.io.dataset import read_calibgraph_dataset

_SPEC = importlib.util.spec_from_file_location("real_sets", Path(__file__).resolve().parents[1] / "scripts" / "real_sets.py")
rs = importlib.util.module_from_spec(_SPEC)
sys.modules.setdefault("real_sets", rs)  # dataclasses look their module up there
_SPEC.loader.exec_module(rs)


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_every_record_is_complete_and_its_board_a_calibgraph_target():
    assert len(rs.SETS) >= 20
    for r in rs.SETS.values():
        assert r.mode in ("eye_in_hand", "eye_to_hand"), r.name
        assert r.n_poses > 0 and r.licence and (r.writer is not None or r.why_listed), r.name
        if r.target:
            t = Target.from_dict(r.target)
            assert t.points_board_m.shape == (t.rows * t.cols, 3), r.name


def test_pose_conventions_the_converters_were_verified_with():
    # Open3DV pos<i>.txt: Rx Ry Rz in degrees composed R = Rz Ry Rx, then X Y Z in millimetres
    T = rs._open3dv_pose(b"10\n20\n30\n100\n-200\n300\n")
    a = np.radians([10, 20, 30])
    assert np.allclose(T[:3, :3], _rz(a[2]) @ _ry(a[1]) @ _rx(a[0]), atol=1e-12)
    assert np.allclose(T[:3, 3], [0.1, -0.2, 0.3])
    # leo038 poses.txt: x,y,z (m), rx,ry,rz (rad) with R = Rz Ry Rx (as its hand_eye_calibrate.py)
    v = [0.4, 0.0, 0.17, -3.05, 0.48, -2.4]
    assert np.allclose(rs._euler("ZYX", v[5:2:-1], False), _rz(v[5]) @ _ry(v[4]) @ _rx(v[3]), atol=1e-12)
    # the Franka Hand's F_T_EE: O_T_EE = T_base_flange @ F_T_EE
    assert np.allclose(rs.F_T_EE_FRANKA_HAND[:3, 3], [0, 0, 0.1034])
    assert np.allclose(rs.F_T_EE_FRANKA_HAND[:3, :3], _rz(np.radians(-45)), atol=1e-12)


def test_output_folder_rules(tmp_path):
    assert rs._check_out(tmp_path / "new", "rwhe_kuka_1") is False
    with pytest.raises(rs.SetError, match="inside"):
        rs._check_out(Path("/work/shared/datasets/x"), "rwhe_kuka_1")
    (tmp_path / "user").mkdir()
    (tmp_path / "user" / "notes.txt").write_text("mine")
    with pytest.raises(rs.SetError, match="not empty"):
        rs._check_out(tmp_path / "user", "rwhe_kuka_1")
    assert (tmp_path / "user" / "notes.txt").read_text() == "mine"
    (tmp_path / "done").mkdir()
    (tmp_path / "done" / rs.MARKER).write_text(json.dumps({"set": "rwhe_kuka_1"}))
    assert rs._check_out(tmp_path / "done", "rwhe_kuka_1") is True
    with pytest.raises(rs.SetError, match="holds the set"):
        rs._check_out(tmp_path / "done", "rwhe_kuka_2")


def test_a_set_without_its_snapshot_says_so(tmp_path, monkeypatch):
    monkeypatch.setattr(rs, "MIRROR", tmp_path)
    assert "fetch github:kvasios/franka-handeye" in rs.availability(rs.SETS["franka_handeye_s3"])
    with pytest.raises(rs.SetError, match="no snapshot"):
        rs.write("franka_handeye_s3", tmp_path / "out")
    assert not (tmp_path / "out").exists()
    with pytest.raises(rs.SetError, match="no set"):
        rs.write("no_such_set", tmp_path / "out")


def test_the_writer_makes_a_dataset_calibgraph_reads(tmp_path):
    rec = rs.SETS["leo038_eye_in_hand"]
    target = Target.from_dict(rec.target)
    cam = Intrinsics.unknown(64, 48)
    o = rs._Out(tmp_path / "ds", rec, target, {"cam": cam}, rec.mode)
    T = rs._pose(_rz(0.3) @ _rx(np.pi), [0.4, 0.1, 0.3])
    o.capture(0, T, {"cam": (b"not decoded here", "png")})
    with pytest.raises(rs.SetError, match="orthonormal"):
        o.capture(1, rs._pose(1.01 * np.eye(3), [0, 0, 0]), {})
    o.finish()
    ds = read_calibgraph_dataset(tmp_path / "ds")
    assert ds.mode == "eye_in_hand" and ds.target == target and set(ds.cameras) == {"cam"}
    assert len(ds.captures) == 1 and np.allclose(ds.captures[0].T_base_flange, T)
    assert ds.views[0].image == "images/cam/000000.png"
    assert json.loads((tmp_path / "ds" / rs.MARKER).read_text()) == {"set": rec.name, "captures": 1}
