"""``calibgraph check RESULT --truth ground_truth.json``: the tour's step 3, a result against a known truth."""

from __future__ import annotations

import json
import re

import numpy as np
from helpers import make_sim_result

from calibgraph.cli.main import main
from calibgraph.core.transforms import log_so3
from calibgraph.io.ground_truth import write_ground_truth_file

CHI2_6_999 = 22.458  # P(chi2_6 > x) = 0.001


def _case(tmp_path, shift_m=None):
    """A solved synthetic cell written as a dataset folder's result.json with its ground truth
    (cam0 moved by ``shift_m`` in the truth when given)."""
    r, scene, _prob, _res = make_sim_result(seed=2)
    ds = tmp_path / "ds"
    ds.mkdir()
    r.save(ds / "result.json")
    cams = {}
    for n, T in scene.truth.T_ref_cam.items():
        T = np.array(T, float)
        if shift_m is not None and n == "cam0":
            T[:3, 3] += shift_m
        cams[n] = {"T_base_cam": T.tolist()}
    write_ground_truth_file(ds, {"mode": "eye_to_hand", "T_flange_board": np.asarray(scene.truth.T_mount_board).tolist(),
                                 "cameras": cams, "captures": {}})
    return ds, r, cams


def _rows(out: str) -> dict:
    return {m[0]: [float(v) for v in m[1:7]] + [m[7]] for m in
            re.findall(r"^(cam\d)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s+(\S+)\s.*\s(inside|outside)$", out, re.M)}


def test_check_prints_each_cameras_error_against_its_covariance(tmp_path, capsys):
    ds, r, cams = _case(tmp_path)
    rc = main(["check", str(ds)])  # the dataset folder: its result.json and ground_truth.json
    out = capsys.readouterr().out
    rows = _rows(out)
    assert set(rows) == set(r.cameras), out
    for n, c in r.cameras.items():
        T = np.asarray(cams[n]["T_base_cam"])
        d = np.concatenate([log_so3(c.T_ref_cam[:3, :3] @ T[:3, :3].T), c.T_ref_cam[:3, 3] - T[:3, 3]])
        m2 = float(d @ np.linalg.solve(c.covariance, d))
        err, _deg, sigma, ratio, m2_printed, _p, status = rows[n][:6] + [rows[n][-1]]
        assert err == round(np.linalg.norm(d[3:]) * 1e3, 3) and sigma == round(np.linalg.norm(c.sigma_translation_mm), 3)
        assert abs(ratio - err / sigma) < 0.01 and abs(m2_printed - m2) < 0.01 * max(1, m2)
        assert status == ("inside" if m2 < CHI2_6_999 else "outside")
    last = out.rstrip().splitlines()[-1]
    assert last.startswith("verdict: PASS" if rc == 0 else "verdict: FAIL") and "worst error/1σ" in last
    assert rc == 0, out  # seed 2's errors are inside (measured M² 2-9)
    assert "the norm of the per-axis translation 1σ" in out  # the columns are explained


def test_a_camera_outside_its_covariance_fails_with_exit_3(tmp_path, capsys):
    r0, *_ = make_sim_result(seed=2)
    shift = 10 * np.linalg.norm(r0.cameras["cam0"].sigma_translation_mm) * 1e-3  # 10 sigma along x
    ds, _r, _ = _case(tmp_path, np.array([shift, 0.0, 0.0]))
    rc = main(["check", str(ds / "result.json"), "--truth", str(ds / "ground_truth.json")])
    out = capsys.readouterr().out
    assert rc == 3 and _rows(out)["cam0"][-1] == "outside", out
    assert re.search(r"^verdict: FAIL: cam0 outside \(M² \d", out, re.M), out


def test_no_ground_truth_is_one_line(tmp_path, capsys):
    ds, _r, _ = _case(tmp_path)
    (ds / "ground_truth.json").unlink()
    assert main(["check", str(ds)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no ground truth found" in err[0] and "--truth" in err[0]
    (tmp_path / "gt.json").write_text(json.dumps({"format": "something else"}))
    assert main(["check", str(ds), "--truth", str(tmp_path / "gt.json")]) == 2
