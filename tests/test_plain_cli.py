"""The command line speaks plainly (issue 47): a verdict a script can act on (`solve --strict`), the
user's own files named (the workcell a dataset records, the camera file given with --intrinsics), one
line per mistake without doubled prefixes or Python lists, tables that stay aligned."""

import pytest
import yaml
from helpers import write_sim_dataset

from calibgraph.cli.main import main
from calibgraph.core.errors import InputError
from calibgraph.sim.synthetic_corners import make_scene


def _record_workcell(ds, cell):
    head = ds / "dataset.yaml"
    d = yaml.safe_load(head.read_text())
    d["made_by"] = {"mode": "sim", "calibgraph": "test", "workcell_file": str(cell.resolve())}
    head.write_text(yaml.safe_dump(d))


def test_solve_strict_exits_3_on_the_reports_fail_and_names_the_recorded_workcell(tmp_path, capsys):
    """`solve --strict`: the report's verdict on the console and exit 3 on FAIL (the result written);
    without it exit 0. The result's advice names the workcell file dataset.yaml records (made_by)."""
    from calibgraph.solver.output.result import load_result

    ds = write_sim_dataset(tmp_path / "ds", make_scene(n_poses=12, seed=1).problem)
    cell = tmp_path / "my_cell.yaml"
    cell.write_text("{}\n")
    _record_workcell(ds, cell)
    tol = tmp_path / "tol.yaml"
    tol.write_text("defaults: {min_views_used: 100}\n")
    assert main(["solve", str(ds), "--quiet", "--strict", "--config", str(tol)]) == 3
    out = capsys.readouterr().out
    assert "verdict: FAIL" in out and "to fix: " in out and (ds / "result.json").is_file()
    ok = tmp_path / "ok.yaml"
    ok.write_text("defaults: {min_views_used: 1, max_sigma_translation_mm: 1000, max_sigma_rotation_deg: 100, "
                  "max_workspace_sigma_mm: null}\n")
    assert main(["solve", str(ds), "--quiet", "--strict", "--config", str(ok)]) == 0
    assert "verdict: PASS" in capsys.readouterr().out
    assert main(["solve", str(ds), "--quiet", "--config", str(tol)]) == 2  # --config means nothing without --strict
    res = load_result(ds / "result.json")
    advice = [c.error_budget["advice"] for c in res.cameras.values()]
    assert all("CELL.yaml" not in a for a in advice)
    sessions = [a for a in advice if "--workcell" in a]
    assert sessions and all(f"--workcell {cell.resolve()}" in a for a in sessions), advice


def test_name_inputs_names_the_workcell_and_the_camera_file(tmp_path):
    from dataclasses import replace

    from helpers import make_sim_result

    from calibgraph.cli.solve import name_inputs
    from calibgraph.report.findings import provenance_text

    d, *_ = make_sim_result()
    n = next(iter(d.cameras))
    c = d.cameras[n]
    b = {**c.error_budget, "advice": f"{n}: ... (calibgraph intrinsics --live --camera {n} --workcell CELL.yaml "
                                      f"--out {n}.yaml, then --intrinsics {n}={n}.yaml) would ..."}
    d = replace(d, cameras={**d.cameras, n: replace(c, error_budget=b)})
    cell = tmp_path / "cell.yaml"
    named = name_inputs(d, cell, {n: tmp_path / "cam0.yaml"})
    assert f"--workcell {cell}" in named.cameras[n].error_budget["advice"]
    assert named.cameras[n].intrinsics["file"] == str(tmp_path / "cam0.yaml")
    assert provenance_text(named.cameras[n], named.settings).startswith(
        f"source: the camera file {tmp_path / 'cam0.yaml'} (given with --intrinsics)")


def test_solve_table_stays_aligned_for_long_camera_names():
    """The camera column is as wide as the longest name: every row's columns start where the header's do."""
    from dataclasses import replace

    from helpers import make_sim_result

    from calibgraph.cli.solve import format_summary

    d, *_ = make_sim_result()
    long = {f"{n}_overhead_rgb_left": c for n, c in d.cameras.items()}
    text = format_summary(replace(d, cameras=long, pairs={}))
    lines = text.splitlines()
    hdr = next(i for i, ln in enumerate(lines) if ln.startswith("camera "))
    rows = lines[hdr + 1:hdr + 1 + len(long)]
    col = lines[hdr].index("x [m]") + len("x [m]")  # right-aligned: the x column ends under its header
    for r in rows:
        assert r.split()[0] in long and r[:col].rstrip().endswith(r.split()[1]), (lines[hdr], r)


def test_errors_are_one_plain_line(tmp_path, capsys):
    """A workcell given as a camera file is named as a workcell, with where it goes (it said "missing key
    'fx'"); the command's name is not said twice ('calibgraph export: error: export: ...'); names are
    listed as words, not as a Python list."""
    from helpers import make_sim_result

    from calibgraph.report.tolerances import load_tolerances

    cell = tmp_path / "cell.yaml"
    cell.write_text("board: a4_54\ncameras:\n  cam0: {driver: realsense, serial: '1'}\n")
    ds = write_sim_dataset(tmp_path / "ds", make_scene(n_poses=4, seed=1).problem)
    assert main(["solve", str(ds), "--intrinsics", f"cam0={cell}", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{cell}: this is a workcell file (it has cameras:, board:), not a camera file: a workcell goes to --workcell" \
        in err and "'fx'" not in err, err
    d, *_ = make_sim_result()
    res = d.save(tmp_path / "result.json")
    assert main(["export", str(res), "--format", "mchec", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("calibgraph export: error: --format mchec needs a dataset folder"), err
    with pytest.raises(InputError) as e:
        load_tolerances({"defaults": {}, "foo": 1, "bar": 2})
    assert "unknown tolerance section(s) bar, foo;" in str(e.value) and "[" not in str(e.value), e.value
    assert main(["intrinsics", "--live", "--camera", "nope", "--workcell", str(cell), "--out", str(tmp_path / "c.yaml")]) == 2
    err = capsys.readouterr().err
    assert "(cameras: cam0)" in err and "['" not in err, err


def test_a_folder_given_as_an_output_file_gets_a_path_that_is_accepted(tmp_path, capsys):
    """`solve DS --out DS/captures` suggested DS/captures/result.json, which the guard then refused: the
    suggestion is now a file the same check accepts (the dataset's top folder for its own result)."""
    import re

    from calibgraph.io.output_guard import check_output_file

    ds = write_sim_dataset(tmp_path / "ds", make_scene(n_poses=4, seed=1).problem)
    for folder in (ds / "captures", tmp_path):
        assert main(["solve", str(ds), "--out", str(folder), "--quiet"]) == 2
        err = capsys.readouterr().err
        m = re.search(r"is a folder; name a file \(e\.g\. (.*)\)\.", err)
        assert m, err
        check_output_file(m.group(1), "result", "result file", "result.json", datasets=[ds])  # accepted
    assert m.group(1) == str(tmp_path / "result.json")
