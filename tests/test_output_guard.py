"""The output guard (calibgraph.io.output_guard): every calibgraph writer's file is recognised by its
header as its own kind (so a command replaces only its own kind of output), nothing else is; a
replaced result is kept as NAME.<n>.EXT; checking a folder creates nothing. The command-line cases
are in tests/test_bad_input.py (the corpus, end of the file)."""

from __future__ import annotations

import json

import pytest
from helpers import make_sim_result, write_sim_dataset

from calibgraph.core.errors import InputError
from calibgraph.io.output_guard import (
    KINDS,
    check_output_file,
    check_output_folder,
    dataset_above,
    keep_previous,
    kept_name,
    output_kind,
    write_keeping_previous,
)


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """kind -> files of that kind written by calibgraph's own writers."""
    from calibgraph.cli.main import main
    from calibgraph.core.targets import a4_board_54
    from calibgraph.io.camera_file import write_camera_file
    from calibgraph.report.exports import export
    from calibgraph.report.html import write_report
    from calibgraph.report.pdf import write_target_pdf
    from calibgraph.sim.fakes import make_fake_cell
    from calibgraph.sim.synthetic_corners import make_scene

    root = tmp_path_factory.mktemp("writers")
    r, scene, prob, _ = make_sim_result()
    out = {k: [] for k in KINDS}
    out["result"] += [r.save(root / "result.json"), r.save(root / "result.yaml")]
    out["report"].append(write_report(r, root / "report.html"))
    cam = root / "cam0.yaml"
    write_camera_file(cam, prob.cameras["cam0"].to_dict())
    out["camera file"].append(cam)
    exp = root / "exp"
    for fmt in ("urdf", "ros2-launch", "opencv-yaml", "camera-info"):
        out["export"] += export(r, fmt, exp)
    out["PDF"].append(write_target_pdf(a4_board_54(), root / "board.pdf", "A4") or root / "board.pdf")
    traj = make_fake_cell(n_cameras=1, n_poses=2, seed=1).trajectory
    out["trajectory"].append(traj.save(root / "trajectory.yaml"))
    ds = write_sim_dataset(root / "ds", make_scene(n_poses=8, seed=4).problem)
    assert main(["solve", str(ds), "--quiet"]) == 0
    assert main(["verify", "--result", str(ds / "result.json"), str(ds), "--verdict", str(root / "v.json"),
                 "--quiet"]) in (0, 3)
    out["verdict"].append(root / "v.json")
    try:
        from calibgraph.report.rerun_view import write_rrd

        out["recording"].append(write_rrd(r, None, root / "c.rrd"))
    except ImportError:
        pass
    return out, ds


def test_every_writer_is_recognised_as_its_own_kind_only(written):
    files, ds = written
    for kind, paths in files.items():
        if kind == "recording" and not paths:
            pytest.skip("rerun-sdk is not installed: the recording writer cannot be checked")
        assert paths, f"no {kind} written"
        for p in paths:
            assert output_kind(p) == kind, f"{p}: recognised as {output_kind(p)!r}, not {kind!r}"
    # what calibgraph writes into a dataset but no command may replace, and a user's files, are no kind
    for p in (ds / "dataset.yaml", *sorted((ds / "captures").glob("*.json"))[:2]):
        assert output_kind(p) is None, p


def test_user_files_are_no_kind(tmp_path):
    for name, text in (("notes.txt", "my notes\n"), ("empty.json", ""), ("other.json", json.dumps({"format": "x/1"})),
                       ("page.html", "<!DOCTYPE html><title>mine</title>"), ("a.yaml", "format: calibgraph-result/1\n")):
        (tmp_path / name).write_text(text)
        assert output_kind(tmp_path / name) is None, name


def test_check_output_file_refuses_and_allows_by_kind_and_place(written, tmp_path):
    files, ds = written
    res = ds / "result.json"
    assert check_output_file(res, "result", "result file", "result.json", datasets=[ds]) == res
    assert check_output_file(ds / "report.html", "report", "report", "report.html", datasets=[ds])
    with pytest.raises(InputError, match="not the dataset this command works on"):
        check_output_file(ds / "r2.json", "result", "result file", "result.json")
    with pytest.raises(InputError, match="not its top folder"):
        check_output_file(ds / "captures" / "new.json", "result", "result file", "result.json", datasets=[ds])
    with pytest.raises(InputError, match="is a calibgraph report, not a calibgraph result"):
        check_output_file(files["report"][0], "result", "result file", "result.json")
    with pytest.raises(InputError, match="is an input of this command"):
        check_output_file(res, "result", "result file", "result.json", inputs=[res], datasets=[ds])
    link = tmp_path / "link.json"  # a symlink into a dataset is judged where it points
    link.symlink_to(ds / "captures" / "000000.json")
    with pytest.raises(InputError, match="is a capture file"):
        check_output_file(link, "result", "result file", "result.json")


def test_check_output_folder_creates_nothing(tmp_path):
    new = tmp_path / "a" / "b" / "c"
    assert check_output_folder(new, "export folder") == new
    assert not (tmp_path / "a").exists()
    (tmp_path / "peer").mkdir()
    (tmp_path / "peer" / "CalibrationInfo.yaml").write_text("x: 1\n")  # MC-HEC layout
    assert dataset_above(tmp_path / "peer" / "x" / "y") == tmp_path / "peer"
    with pytest.raises(InputError, match="is inside the dataset"):
        check_output_folder(tmp_path / "peer" / "x", "export folder")
    with pytest.raises(InputError, match="holds a dataset"):
        check_output_folder(tmp_path / "peer", "export folder")


def test_keep_previous_numbers_and_a_failed_write_keeps_no_copy(written, tmp_path):
    files, _ = written
    res = tmp_path / "result.json"
    res.write_bytes(files["result"][0].read_bytes())
    assert kept_name(res).name == "result.1.json"
    (tmp_path / "result.7.json").write_text("{}")
    assert kept_name(res).name == "result.8.json"
    kept = keep_previous(res)
    assert kept.name == "result.8.json" and kept.read_bytes() == res.read_bytes()
    before = sorted(p.name for p in tmp_path.iterdir())

    def fails():
        raise InputError("disk full")

    with pytest.raises(InputError):
        write_keeping_previous(res, fails)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    (tmp_path / "notes.txt").write_text("mine")
    assert keep_previous(tmp_path / "notes.txt") is None and keep_previous(tmp_path / "none.json") is None


def test_the_test_run_refuses_writes_into_shared(shared_dir, tmp_path):
    """conftest's guard: a test that writes into ../shared (a solve of the shared data in place, which
    left .calibgraph_cache/ there) fails instead; nothing is written."""
    from calibgraph.cli.main import main
    from calibgraph.io.files import atomic_write_text

    with pytest.raises(AssertionError, match="writes into ../shared"):
        atomic_write_text(shared_dir / "datasets" / "x.txt", "x")
    with pytest.raises(AssertionError, match="writes into ../shared"):  # the dataset lock comes first
        main(["solve", str(shared_dir / "datasets" / "rct_static_camera_charuco"), "--out", str(tmp_path / "r.json")])
    assert not (shared_dir / "datasets" / "x.txt").exists() and not (tmp_path / "r.json").exists()


def test_a_report_knows_whether_it_was_edited_since_it_was_written(written, tmp_path):
    """Issue 46: a report edited by hand was replaced without a copy. Its fingerprint (the SHA-256 of
    its own text) tells it from one calibgraph wrote: only the edited one is kept when replaced."""
    import shutil

    from calibgraph.io.output_guard import edited_since_written

    out, _ = written
    page = tmp_path / "report.html"
    shutil.copy(out["report"][0], page)
    assert not edited_since_written(page) and keep_previous(page) is None
    page.write_text(page.read_text(encoding="utf-8").replace("<h2>", "<h2>(checked) ", 1), encoding="utf-8")
    assert edited_since_written(page) and output_kind(page) == "report"
    kept = keep_previous(page)
    assert kept == tmp_path / "report.1.html" and kept.read_bytes() == page.read_bytes()


def test_temporary_names_fit_the_file_system_and_stale_ones_are_removed(tmp_path):
    """Issue 46 case 7: a 250-byte name's temporary ('.NAME.tmpPID') passed the 255-byte limit, after the
    solve. A name that does not fit gets a short hashed temporary; one left by a killed writer is removed."""
    import subprocess
    import sys

    from calibgraph.io.files import atomic_write_text, temporary_name

    long = tmp_path / ("r" * 250 + ".json")  # 255 bytes
    name = temporary_name(long)
    assert name.startswith(".cg") and len(name.encode()) < 40 and temporary_name(tmp_path / "a.json").startswith(".a.json.tmp")
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    stale = tmp_path / temporary_name(long, pid=int(dead.stdout))
    stale.write_text("half a result")
    atomic_write_text(long, "{}")
    assert long.read_text() == "{}" and not stale.exists() and sorted(p.name for p in tmp_path.iterdir()) == [long.name]
