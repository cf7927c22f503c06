"""``capture --view`` / ``capture --auto --view``: the live rerun view of a capture run (issue 37 part 4).

Small simulated runs of the default cell (8 poses); each recording is checked against the dataset the
same run wrote: the board found exactly where the capture kept a view, as many corners as it stored,
the next planned pose where the robot then grabbed, the last 1-sigma the plan log's.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
WORLD = REPO / "datasets" / "workcells" / "default.yaml"
POSES = 8


def _cli(*argv):
    from calibgraph.cli.main import main

    return main([str(a) for a in argv])


def _read_rrd(path: Path) -> dict:
    """entity -> {capture index: [the columns of each row logged at it]} of a recording that `rerun rrd
    verify` accepts."""
    from rerun.chunk import RrdReader

    from calibgraph.report.rerun_view import rerun_cli

    r = subprocess.run(rerun_cli() + ["rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    out = {}
    for ch in RrdReader(str(path)).stream():
        if ch.is_static:
            continue
        b = ch.to_record_batch()
        for row, k in enumerate(b.column("capture").to_pylist()):
            out.setdefault(ch.entity_path, {}).setdefault(k, []).append(
                {n: b.column(n)[row].as_py() for n in b.schema.names if not n.startswith("log_")})  # rerun's clocks
    return out


def _column(rows: list, suffix: str):
    """The value of the last of ``rows`` with a column whose name ends with ``suffix`` (rerun's names
    carry the archetype), else None."""
    for row in reversed(rows):
        for n, v in row.items():
            if n.endswith(suffix) and v is not None:
                return v
    return None


def _captures(out: Path) -> dict:
    return {int(f.stem): json.loads(f.read_text()) for f in sorted((out / "captures").glob("*.json"))}


def _check_frames_match_the_dataset(rec: dict, caps: dict, cameras) -> None:
    for k, cap in caps.items():
        for c in cameras:
            assert k in rec[f"/{c}/image"], (c, k)  # every camera's frame, board found or not
            found = _column(rec[f"/{c}/board_found"][k], "scalars")[0]
            corners = rec[f"/{c}/image/corners"][k]
            if c in cap["views"]:
                assert found == 1.0
                n = len(cap["views"][c]["detection"]["ids"])
                assert len(_column(corners, "positions")) == n
            else:
                assert found == 0.0 and _column(corners, "positions") is None
                assert _column(corners, "is_recursive") is not None  # the last view's corners cleared


def _translation(row: dict) -> np.ndarray:
    return np.asarray(_column(row, "translation"), float).reshape(3)


@pytest.fixture(scope="module")
def auto_run(tmp_path_factory):
    pytest.importorskip("rerun", reason="rerun-sdk not installed (pip install calibgraph[viz])")
    tmp = tmp_path_factory.mktemp("auto_view")
    rc = _cli("capture", "--auto", "--robot", "sim", "--sim-world", WORLD, "--max-poses", POSES, "--out",
              tmp / "auto", "--rrd", tmp / "auto.rrd", "--quiet")
    return tmp, rc


def test_auto_rrd_holds_every_camera_the_robot_the_next_pose_and_the_sigma(auto_run, capsys):
    tmp, rc = auto_run
    assert rc in (0, 3)  # 8 poses: usually short of 0.5 mm (exit 3); the recording is written either way
    assert (tmp / "auto.rrd").is_file() and not list(tmp.glob(".auto.rrd*"))  # the temporary file moved into place
    rec = _read_rrd(tmp / "auto.rrd")
    caps = _captures(tmp / "auto")
    log = json.loads((tmp / "auto" / "plan_log.json").read_text())
    cameras = log["cameras"]
    assert len(caps) == POSES and len(cameras) == 3
    _check_frames_match_the_dataset(rec, caps, cameras)
    for k, cap in caps.items():
        # the robot at the grab, and the pose the plan sent it to before it moved (the FK of its joint
        # target: the simulated arm arrives within its 0.01 rad tolerance, so within a few mm)
        T = np.asarray(cap["T_base_flange"])
        np.testing.assert_allclose(_translation(rec["/world/flange"][k]), T[:3, 3], atol=1e-9)
        assert np.linalg.norm(_translation(rec["/world/next_pose"][k]) - T[:3, 3]) < 0.01
        assert k in rec["/world/board"] and k in rec["/world/flange_path"]
    # the 1-sigma per camera against the tolerance: the last values are the plan log's last step
    last = log["steps"][-1]["achieved"]
    assert last, "the 8-pose survey placed no camera"
    for c, (mm, deg) in last.items():
        at = max(rec[f"/sigma/{c}/mm"])
        assert at == POSES - 1
        assert _column(rec[f"/sigma/{c}/mm"][at], "scalars")[0] == pytest.approx(mm, abs=1e-9)
        assert _column(rec[f"/sigma/{c}/deg"][at], "scalars")[0] == pytest.approx(deg, abs=1e-9)
        assert f"/world/cameras/{c}" in rec
    assert {_column(r, "scalars")[0] for r in rec["/sigma/tolerance_mm"].values()} == {0.5}
    assert {_column(r, "scalars")[0] for r in rec["/sigma/tolerance_deg"].values()} == {0.03}
    assert _column(rec["/world/next_pose"][POSES - 1], "is_recursive") is not None  # cleared at the end
    assert len(rec["/log"]) == POSES


def test_trajectory_view_without_a_display_writes_beside_out(auto_run, tmp_path, monkeypatch, capsys):
    """``capture --view`` of a trajectory with no display: the .rrd beside --out, with iSAM2's 1-sigma."""
    from calibgraph.plan.trajectory import Trajectory, save_trajectory

    src, _ = auto_run
    caps = _captures(src / "auto")
    traj = save_trajectory(Trajectory(poses=tuple(c["q_rad"] for c in caps.values()), speed_scale=0.2),
                           tmp_path / "t.yaml")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    rc = _cli("capture", "--workcell", WORLD, "--trajectory", traj, "--out", tmp_path / "ds", "--view", "--quiet")
    assert rc == 0
    assert f"wrote {tmp_path / 'ds.rrd'}" in capsys.readouterr().out
    rec = _read_rrd(tmp_path / "ds.rrd")
    got = _captures(tmp_path / "ds")
    assert len(got) == POSES
    _check_frames_match_the_dataset(rec, got, ("cam0", "cam1", "cam2"))
    seen = {c for cap in got.values() for c in cap["views"]}
    placed = {e.split("/")[2] for e in rec if e.startswith("/sigma/cam")}
    assert placed and placed <= seen  # iSAM2 places a camera once it has views of it
    assert max(rec["/world/next_pose"]) == POSES - 1


def test_view_arguments_are_checked_before_anything_runs(tmp_path, capsys):
    pytest.importorskip("rerun", reason="rerun-sdk not installed (pip install calibgraph[viz])")
    auto = ["capture", "--auto", "--robot", "sim", "--sim-world", WORLD, "--max-poses", POSES, "--out", tmp_path / "o"]
    before = WORLD.read_bytes()
    assert _cli(*auto, "--rrd", WORLD) == 2  # an input is never overwritten
    assert _cli(*auto, "--rrd", tmp_path) == 2  # a folder is no recording
    assert _cli(*auto, "--view", "--dry-run") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("calibgraph capture: error:") for line in err), err
    assert "dry run" in err[2]
    assert WORLD.read_bytes() == before and not (tmp_path / "o").exists()


class _Recorder:
    """An observer that keeps what it was shown, and fails at ``fail_at`` (a grab index) when asked."""

    def __init__(self, fail_at=None):
        self.grabs, self.nexts, self.fail_at = [], [], fail_at

    def frames(self, k, T_base_flange, images, found, why):
        if k == self.fail_at:
            raise RuntimeError("viewer went away")
        self.grabs.append((k, set(images), {c for c, uv in found.items() if uv is not None}))

    def next_pose(self, k, T_base_flange, estimates):
        self.nexts.append((k, T_base_flange is not None, dict(estimates)))


def test_observer_sees_every_grab_and_a_failing_one_costs_nothing(tmp_path):
    from calibgraph.acquire.run import run_acquisition
    from calibgraph.sim.fakes import make_fake_cell
    from calibgraph.solver.solve.incremental import IncrementalSolver

    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=3)
    inc = IncrementalSolver(cell.target.points_board_m, {c.name: c.intrinsics() for c in cell.cameras})
    seen = _Recorder()
    rep = run_acquisition(cell.robot, cell.cameras, cell.trajectory, tmp_path / "a", cell.target,
                          detector=cell.detector, progress=False, on_capture=inc.add_capture, watch=seen)
    caps = _captures(tmp_path / "a")
    assert rep.complete and [g[0] for g in seen.grabs] == sorted(caps)
    assert all(found == set(caps[k]["views"]) for k, _, found in seen.grabs)
    assert [n[0] for n in seen.nexts] == sorted(caps) + [None]  # each visit before it moves, then the end
    last = seen.nexts[-1][2]  # the estimate at the end: the solver's last, with its 1-sigma norms
    assert set(last) == set(rep.last_estimate.cameras)
    for c, (T, mm, deg) in last.items():
        ce = rep.last_estimate.cameras[c]
        np.testing.assert_array_equal(T, ce.T_ref_cam)
        assert mm == pytest.approx(np.linalg.norm(ce.sigma_translation_mm))
        assert deg == pytest.approx(np.linalg.norm(ce.sigma_rotation_deg))
    lines = []
    cell = make_fake_cell(n_cameras=2, n_poses=6, seed=3)
    rep = run_acquisition(cell.robot, cell.cameras, cell.trajectory, tmp_path / "b", cell.target,
                          detector=cell.detector, progress=lines.append, watch=_Recorder(fail_at=2))
    assert rep.complete and len(_captures(tmp_path / "b")) == len(caps)
    assert sum("live view stopped (RuntimeError: viewer went away)" in s for s in lines) == 1
