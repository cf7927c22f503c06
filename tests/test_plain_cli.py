"""The command line speaks plainly (issue 47): a verdict a script can act on (`solve --strict`), the
user's own files named (the workcell a dataset records, the camera file given with --intrinsics), one
line per mistake without doubled prefixes or Python lists, tables that stay aligned."""

import yaml
from helpers import write_sim_dataset

from calibgraph.cli.main import main
from calibgraph.sim.synthetic_corners import make_scene


def _record_workcell(ds, cell):
    head = ds / "dataset.yaml"
    d = yaml.safe_load(head.read_text())
    d["made_by"] = {"mode": "sim", "calibgraph": "test", "workcell_file": str(cell.resolve())}
    head.write_text(yaml.safe_dump(d))


def test_solve_strict_exits_3_on_the_reports_fail_and_names_the_recorded_workcell(tmp_path, capsys):
    """`solve --strict`: the report's verdict on the console and exit 3 on FAIL (the result written);
    without it exit 0. The result's advice names the workcell file dataset.yaml records (made_by)."""
    from calibgraph.solver.result import load_result

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
