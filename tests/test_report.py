"""Commissioning report: built from a solved simulated workcell; numbers checked against result.json;
rendered in headless Chromium.

"""

import html.parser
import json

import numpy as np
import pytest
from helpers import knocked_result, make_sim_result, run_chromium, write_sim_dataset

from calibgraph.io.layouts import load_dataset
from calibgraph.report.findings import advice_for
from calibgraph.report.html import (
    compute_residuals,
    load_tolerances,
    report_verdicts,
    write_report,
)
from calibgraph.solver.output.result import load_result


class _Spans(html.parser.HTMLParser):
    """Collect data-value numbers per table row marked with data-camera / data-pair, and element ids."""

    def __init__(self):
        super().__init__()
        self.rows = {}
        self._row = None
        self.ids = set()
        self.script = None
        self._in_script = False

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if "id" in a:
            self.ids.add(a["id"])
        if tag == "tr" and ("data-camera" in a or "data-pair" in a):
            self._row = (a.get("data-camera") or a.get("data-pair"), self._table)
            self.rows.setdefault(self._row, [])
        if tag == "table":
            self._table = a.get("id")
        if tag == "span" and "data-value" in a and self._row is not None:
            self.rows[self._row].append(float(a["data-value"]))
        if tag == "script" and a.get("id") == "calibgraph-result":
            self._in_script = True
            self.script = ""

    _table = None

    def handle_endtag(self, tag):
        if tag == "tr":
            self._row = None
        if tag == "script":
            self._in_script = False

    def handle_data(self, data):
        if self._in_script:
            self.script += data


def test_report_numbers_equal_result_json(tmp_path):
    r, scene, prob, res = make_sim_result()
    res_path = r.save(tmp_path / "result.json")
    out = write_report(load_result(res_path), tmp_path / "report.html", result_path=res_path)
    text = out.read_text()
    d = json.loads(res_path.read_text())
    p = _Spans()
    p.feed(text)
    # the embedded copy of the result is the result
    assert json.loads(p.script) == d
    for n, c in d["cameras"].items():
        vals = p.rows[(n, "summary")]
        T = np.asarray(c["T_base_cam"])
        # each 1σ as one figure, the norm, with its axes beside it
        expect = [*T[:3, 3], None, None, None, np.linalg.norm(c["sigma_translation_mm"]), *c["sigma_translation_mm"],
                  np.linalg.norm(c["sigma_rotation_deg"]), *c["sigma_rotation_deg"],
                  c["reprojection_rms_px"], c["reprojection_max_px"], c["views_used"], len(c["views_rejected"])]
        assert len(vals) == len(expect)
        for got, want in zip(vals, expect):
            if want is not None:
                assert got == want  # exact: data-value carries repr(float)
        assert f">{c['reprojection_rms_px']:.3f}<" in text
    for key, pr in d["camera_pairs"].items():
        vals = p.rows[(key, "pairs")]
        T = np.asarray(pr[f"T_{pr['a']}_{pr['b']}"])
        assert vals[:3] == T[:3, 3].tolist()
        assert vals[-6:] == pr["sigma_translation_mm"] + pr["sigma_rotation_deg"]
    for sect in ("summary", "pairs", "workspace", "provenance", "verdict"):
        assert sect in p.ids
    # the injected outliers show up: a rejected view with its reason, rejected corners in the plot legend
    rejected = [v for c in d["cameras"].values() for v in c["views_rejected"]]
    assert rejected, "the garbage view should have been rejected by the solver"
    assert all(v["reason"] in text for v in rejected)
    assert "rejected corner" in text and "weakest" in text.lower()


def test_pass_fail_follows_tolerances(tmp_path):
    d, *_ = make_sim_result()
    names = list(d.cameras)
    worst_t = {n: float(np.linalg.norm(c.sigma_translation_mm)) for n, c in d.cameras.items()}  # the 1σ norm
    # cam limits straddle the values: the first camera passes the translation check, the last fails it
    lo, hi = min(worst_t.values()), max(worst_t.values())
    cfg = {"defaults": {"max_sigma_translation_mm": (lo + hi) / 2, "max_sigma_rotation_deg": None,
                        "max_reprojection_rms_px": 10.0, "max_reprojection_max_px": 100.0, "min_views_used": 1,
                        "max_workspace_sigma_mm": None}}
    text = write_report(d, tmp_path / "r.html", config=cfg).read_text()
    failing = [n for n in names if worst_t[n] > (lo + hi) / 2]
    assert failing and len(failing) < len(names)
    assert "Overall: FAIL" in text and f"failing: {', '.join(failing)}" in text
    cfg["defaults"]["max_sigma_translation_mm"] = hi * 1.01
    assert "Overall: PASS" in write_report(d, tmp_path / "r2.html", config=cfg).read_text()
    # an old tolerance file's key limits the norm now, not the largest axis: a limit between the two fails
    n0 = names[0]
    between = (max(d.cameras[n0].sigma_translation_mm) + worst_t[n0]) / 2
    cfg["cameras"] = {n0: {"max_sigma_translation_mm": between}}
    reasons = report_verdicts(d, config=cfg)[n0]["reasons"]
    assert reasons == [f"1σ translation (mm) {worst_t[n0]:.4g} not <= {between:g}"], reasons


def test_tolerance_file_errors_are_clear(tmp_path):
    bad = tmp_path / "tol.yaml"
    bad.write_text("defaults: {max_sigma_mm: 1}\n")
    from calibgraph.core.errors import InputError

    with pytest.raises(InputError, match="unknown tolerance 'max_sigma_mm'"):
        load_tolerances(bad)
    assert load_tolerances()["defaults"]["max_reprojection_rms_px"] == 0.5  # datasets/tolerances/default.yaml


def test_report_from_file_alone_and_with_dataset(tmp_path):
    d, scene, prob, res = make_sim_result(intrinsics=False, residuals=False)
    text = write_report(d, tmp_path / "bare.html").read_text()
    assert "No per-corner residuals" in text and "no detections available" in text
    ds = write_sim_dataset(tmp_path / "ds", prob)
    # recomputed residuals agree with the solver's own (same chain, same sign convention, same rejections)
    rec = compute_residuals(d, load_dataset(ds))
    for n, c in res.cameras.items():
        # views the solver set aside before solving (no PnP) have no residuals of its own
        assert all(rec[n][k]["rejected"] for k in rec[n].keys() - c.residuals_px.keys())
        for k, v in c.residuals_px.items():
            assert np.allclose(rec[n][k]["residual_px"], v["residual_px"], atol=1e-6)
            assert rec[n][k]["rejected"] == v["rejected"]
            assert np.array_equal(rec[n][k]["weight"] == 0, v["weight"] == 0)
    text = write_report(d, tmp_path / "ds.html", dataset=ds).read_text()
    assert "recomputed from the dataset" in text and "image coverage (" in text


def test_report_eye_in_hand(tmp_path):
    d, *_ = make_sim_result(mode="eye_in_hand")
    text = write_report(d, tmp_path / "eih.html").read_text()
    assert "T_flange_cam" in text and "depth, camera z (m)" in text


def test_cli_report(tmp_path):
    from calibgraph.cli.main import main

    d, *_ = make_sim_result()
    d.save(tmp_path / "result.json")
    assert main(["report", str(tmp_path / "result.json"), "--out", str(tmp_path / "x.html")]) == 0
    assert (tmp_path / "x.html").stat().st_size > 10000
    assert main(["report", str(tmp_path / "missing.json")]) == 2


def test_result_commands_take_the_dataset_folder_solve_wrote_into(tmp_path, capsys):
    """``calibgraph solve DATASET`` writes DATASET/result.json: report, view and export given the folder
    read that file (the report lands beside it); a folder with no result is one line and exit 2."""
    from calibgraph.cli.main import main

    d, *_ = make_sim_result()
    ds = tmp_path / "ds"
    ds.mkdir()
    d.save(ds / "result.json")
    assert main(["report", str(ds)]) == 0
    assert (ds / "report.html").stat().st_size > 10000 and not (tmp_path / "report.html").exists()
    assert main(["export", str(ds), "--format", "yaml", "--out", str(tmp_path / "exp")]) == 0
    assert (tmp_path / "exp" / "result.yaml").is_file()
    try:
        import rerun  # noqa: F401 - view writes a rerun recording
    except ImportError:
        pass
    else:
        assert main(["view", str(ds), "--rrd", str(tmp_path / "v.rrd")]) == 0 and (tmp_path / "v.rrd").is_file()
    capsys.readouterr()
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["report", str(empty)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no result.json or result.yaml" in err[0] and f"calibgraph solve {empty}" in err[0]
    assert list(empty.iterdir()) == []


# -- real browser --------------------------------------------------------------------------------------
def test_report_renders_in_headless_chromium(tmp_path):
    d, *_ = make_sim_result()
    out = write_report(d, tmp_path / "report.html")
    png = tmp_path / "shot.png"
    r = run_chromium([f"--screenshot={png}", "--window-size=1280,2000", out.resolve().as_uri()])
    assert png.is_file(), r.stderr[-2000:]
    import cv2

    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] >= 1000 and img.shape[1] >= 1000
    assert img.std() > 20, "screenshot is blank"
    # the verdict banner was styled (CSS applied): green PASS or red FAIL pixels near the top
    top = img[:400].reshape(-1, 3).astype(int)  # BGR
    green = np.all(np.abs(top - [0x3a, 0x8a, 0x2a]) < 12, axis=1).sum()
    red = np.all(np.abs(top - [0x28, 0x28, 0xc6]) < 12, axis=1).sum()
    assert green + red > 2000
    # the DOM the browser built contains the report, not an error page
    dom = run_chromium(["--dump-dom", out.resolve().as_uri()]).stdout
    assert "calibgraph commissioning report" in dom and "ERR_" not in dom
    for n, c in d.cameras.items():
        assert f'data-camera="{n}"' in dom
        assert f">{c.reprojection_rms_px:.3f}<" in dom
    assert dom.count("<svg") >= 3 * len(d.cameras)


def test_recomputed_residuals_match_solver_eye_in_hand():
    d, scene, prob, res = make_sim_result(mode="eye_in_hand", residuals=False)
    rec = compute_residuals(d, prob)
    assert all(c.residuals_px for c in res.cameras.values())
    for n, c in res.cameras.items():
        assert rec[n].keys() == c.residuals_px.keys()
        for k, v in c.residuals_px.items():
            assert np.allclose(rec[n][k]["residual_px"], v["residual_px"], atol=1e-6)


def test_ticks_of_a_constant_map_are_few():
    """A workspace map that is constant within rounding (a degenerate covariance) once made the tick
    loop step by less than the values' precision and never end."""
    from calibgraph.report.svgplot import heatmap, nice_ticks

    lo = 0.552268050859363
    hi = np.nextafter(lo, 1.0)
    assert 1 <= len(nice_ticks(lo, hi, 4)) <= 10
    assert len(nice_ticks(0.0, 0.0)) <= 10 and nice_ticks(1.0, np.inf) == []
    assert "<svg" in heatmap(np.full((3, 3), lo) + np.eye(3) * (hi - lo), np.arange(4.0), np.arange(4.0))


def test_a_dataset_that_is_not_the_results_is_named(tmp_path):
    from dataclasses import replace

    from calibgraph.core.errors import InputError
    from calibgraph.report.html import dataset_mismatch

    d, scene, prob, res = make_sim_result()
    ds = load_dataset(write_sim_dataset(tmp_path / "ds", prob))
    assert dataset_mismatch(d, ds) == []  # its own dataset
    fewer = replace(d, cameras={n: c for n, c in d.cameras.items() if n != "cam2"})
    assert any("cam2 are not in the result" in s for s in dataset_mismatch(fewer, ds))
    more = replace(d, T_base_flange_est={**d.T_base_flange_est, 999: np.eye(4)})
    assert any("captures are not in it" in s and "999" in s for s in dataset_mismatch(more, ds))
    with pytest.raises(InputError, match="not the dataset this result was solved from"):
        write_report(more, tmp_path / "r.html", dataset=ds)
    assert not (tmp_path / "r.html").exists()


# -- what the solver knows: budget, advice, notes, intrinsics, moves (issue 35) ------------------------
def _report_text_of(fragment: str) -> str:
    """The text of an HTML fragment as a reader sees it (tags dropped, entities decoded, whitespace folded)."""
    import html as _html
    import re

    return re.sub(r"\s+", " ", _html.unescape(re.sub(r"<[^>]+>", " ", fragment)))


def _report_text(path) -> str:
    """The report's text, without the result JSON it embeds."""
    return _report_text_of(path.read_text().split('<script type="application/json"')[0])


def test_report_says_budget_advice_notes_intrinsics_and_a_move(tmp_path):
    """Per camera: the error budget's shares (every labelled set, a second one included), its advice,
    its notes, its intrinsics' source and given -> estimated values; a moved camera's displacement
    with its 1-sigma, before and after; a box of advice at the top; the cell's notes apart."""
    from dataclasses import replace

    res = knocked_result()
    # a budget with a second labelled set of shares (as a later budget may carry) is shown too
    b1 = dict(res.cameras["cam1"].error_budget)
    b1["shares_by_parameter"] = {"cam1 pose": 0.5, "intrinsics of cam1": 0.3, "flange poses": 0.2}
    # and labelled sets of shares that overlap (not adding up to 1: not stacked)
    b1["share_sets"] = {"gone were it known exactly": {"corners": 0.6, "intrinsics": 0.7}}
    res = replace(res, cameras={**res.cameras, "cam1": replace(res.cameras["cam1"], error_budget=b1)})
    out = write_report(res, tmp_path / "report.html")
    text = _report_text(out)
    page = out.read_text()
    assert "What would improve this calibration" in text.split("Summary")[0]
    for n, c in res.cameras.items():
        sec = page.split(f'id="cam-{n}"')[1].split('<div class="cam"')[0]
        sec_text = _report_text_of(sec)
        # the advice is said once, in the box at the top; the camera's section points to it
        assert advice_for(n, c) in text.split("Summary")[0] and text.count(advice_for(n, c)) == 1
        assert "What would shrink it most: its advice in What would improve this calibration" in sec_text
        for src, share in c.error_budget["shares"].items():
            assert f'data-source="{src}"' in sec and f'data-value="{share!r}"' in sec
        assert "by noise source" in sec_text
        for note in res.camera_notes(n):
            assert note in sec_text
        assert "source: factory values (device or datasheet), as stated with the camera" in sec_text
        assert "used: estimated under the factory prior" in sec_text
        for k in ("fx", "fy", "cx", "cy", "k1", "k2"):
            assert f'data-param="{k}"' in sec
            assert f'data-value="{c.intrinsics["given"][k]!r}"' in sec and f'data-value="{c.intrinsics["sigma"][k]!r}"' in sec
    cam1 = page.split('id="cam-cam1"')[1].split('<div class="cam"')[0]
    assert "by parameter" in _report_text_of(cam1) and 'data-source="flange poses"' in cam1
    overlap = cam1.split('data-set="gone were it known exactly"')[1].split('<div class="shareset"')[0]
    assert overlap.count('class="bar one"') == 2 and "they overlap" in overlap and "70 %" in overlap
    by_parameter = cam1.split('data-set="by parameter"')[1].split('<div class="shareset"')[0]
    assert 'class="bar"' in by_parameter and "bar one" not in by_parameter  # adding up to 1: one stacked bar
    m = res.cameras["cam0"].moved
    sec0 = _report_text_of(page.split('id="cam-cam0"')[1].split('<div class="cam"')[0])
    assert "Moved during capture" in sec0 and f"between captures {m['last_capture_before']} and {m['capture']}" in sec0
    assert f"{m['displacement_mm']:.1f} ± {m['sigma_displacement_mm']:.1f} mm (1σ)" in sec0
    assert "before the move" in sec0 and "after the move (the pose reported)" in sec0
    cell = text.split("Notes on the whole cell")[1].split("Cameras")[0]
    for note in res.cell_notes:
        assert note in cell
    assert not any(note in cell for n in res.cameras for note in res.camera_notes(n))


def test_a_camera_not_calibrated_says_why_and_has_its_notes(tmp_path):
    from calibgraph import solve
    from calibgraph.sim.synthetic_corners import bump_camera, make_scene

    scene = make_scene(n_poses=30, seed=1, fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=np.radians(0.01))
    caps = sorted(d.capture for d in scene.problem.detections if d.camera == "cam0")
    prob, _ = bump_camera(scene, "cam0", caps[-2], 0.02, seed=1)
    res = solve(prob)
    assert not res.cameras["cam0"].calibrated
    page = write_report(res, tmp_path / "report.html").read_text()
    top = _report_text_of(page.split("<h2>Summary</h2>")[0])
    assert f"cam0 : not calibrated — {res.cameras['cam0'].why}" in top
    k = len(res.camera_notes("cam0"))
    banner = page.split('id="failing-reasons"')[1].split("</ul>")[0]
    assert f'<a href="#cam-cam0">the solver\'s note{"s" if k != 1 else ""} on it ({k})</a>' in banner
    sec = _report_text_of(page.split('id="cam-cam0"')[1].split('<div class="cam"')[0])
    assert "Not calibrated" in sec and res.cameras["cam0"].why in sec and "Moved during capture" in sec
    assert sec.split("after the move (the pose reported)")[1].lstrip().startswith("not calibrated")
    assert res.camera_notes("cam0") and all(t in sec for t in res.camera_notes("cam0"))


# -- a report that speaks plainly (issue 47): a FAIL says what fixes it, --strict exits non-zero --------------
def test_a_failing_views_check_says_how_many_more_poses_where_and_with_which_command(tmp_path):
    """Too few views: how many more (the tolerance's count less the views used), how many poses that is at
    the rate the camera saw the board, the parts of its image its corners never reached, and the command
    of the run that made the dataset, naming the workcell it recorded."""
    from types import SimpleNamespace

    from calibgraph.report.remedies import fixes, unseen_regions
    from calibgraph.report.tolerances import camera_verdict

    d, *_ = make_sim_result()
    n, c = next(iter(d.cameras.items()))
    tol = load_tolerances({"defaults": {"min_views_used": c.views_used + 3}})
    v = camera_verdict(n, c, tol, None)
    assert not v["pass"] and ("min_views_used", c.views_used, c.views_used + 3) in v["failed"]
    # corners only in the image's top-left ninth: every other part is named
    res = {0: {"uv_detected_px": [[10.0, 10.0], [50.0, 40.0]]}}
    assert unseen_regions(res, 900, 600) == ["top", "top-right", "left", "centre", "right", "bottom-left", "bottom",
                                             "bottom-right"]
    cell = tmp_path / "cell.yaml"
    cell.write_text("{}\n")
    run = {"mode": "sim", "workcell_file": str(cell)}
    seen = c.views_used + len(c.views_rejected)
    (line,) = fixes(n, c, v, res, SimpleNamespace(width_px=900, height_px=600), run, n_captures=2 * seen)
    assert line.startswith(f"{n}: 3 more views needed (it has {c.views_used}; the tolerance asks for {c.views_used + 3})")
    assert f"{seen} of {2 * seen} poses: about 6 more poses" in line
    assert f"--workcell {cell}" in line and f"--poses {2 * seen + 6}" in line, line


def test_report_strict_exits_3_on_fail_and_0_on_pass(tmp_path, capsys):
    """`report --strict`: exit 3 when the verdict is FAIL (the report written, each failing check with
    its fix on the console); 0 on PASS; without --strict 0 either way (the documented default)."""
    from calibgraph.cli.main import main

    d, *_ = make_sim_result()
    res = d.save(tmp_path / "result.json")
    fail = tmp_path / "fail.yaml"
    fail.write_text(f"defaults: {{min_views_used: {max(c.views_used for c in d.cameras.values()) + 1}}}\n")
    assert main(["report", str(res), "--out", str(tmp_path / "a.html"), "--config", str(fail), "--strict"]) == 3
    out = capsys.readouterr().out
    assert "verdict: FAIL" in out and "to fix: " in out and "more view" in out and (tmp_path / "a.html").is_file()
    assert main(["report", str(res), "--out", str(tmp_path / "b.html"), "--config", str(fail)]) == 0
    ok = tmp_path / "ok.yaml"
    ok.write_text("defaults: {min_views_used: 1, max_sigma_translation_mm: 1000, max_sigma_rotation_deg: 1000, "
                  "max_reprojection_rms_px: 100, max_reprojection_max_px: 1000, max_workspace_sigma_mm: null}\n")
    assert main(["report", str(res), "--out", str(tmp_path / "c.html"), "--config", str(ok), "--strict"]) == 0
    assert "verdict: PASS" in capsys.readouterr().out


def test_plots_keep_legends_off_the_data_and_draw_the_camera_on_the_workspace_map():
    """The residual scatter's legend stands right of its frame, each key drawn as its series is (a
    cross for the rejected corners); a heat map's label is dark text on a white halo; a camera beyond
    the workspace map is drawn on its edge (a diamond) with an arrow the way it looks."""
    import re

    import numpy as np

    from calibgraph.report import svgplot
    from calibgraph.report.workspace import camera_marker

    svg = svgplot.scatter([{"x": [0, 1], "y": [0, 1], "label": "corner (used)"},
                           {"x": [1], "y": [1], "label": "rejected corner", "marker": "x", "color": svgplot.RED}],
                          width=640)
    frame = re.search(r'<rect x="([\d.]+)" y="[\d.]+" width="([\d.]+)"[^>]*fill="none" stroke="#333"', svg)
    right_edge = float(frame.group(1)) + float(frame.group(2))
    keys = [float(x) for x in re.findall(r'<text x="([\d.]+)" y="[\d.]+">(?:corner|rejected)', svg)]
    assert len(keys) == 2 and min(keys) > right_edge, (keys, right_edge)
    cross = re.findall(rf'<path d="M([\d.]+),[^"]*" stroke="{svgplot.RED}"', svg)
    assert len(cross) == 2 and float(cross[1]) > right_edge  # the data's cross and the legend's
    # a camera 3 m beyond a 1.2 m map, looking back at the robot along +y
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # optical z along base +y
    T[:3, 3] = [0.0, -3.0, 0.8]
    xe, ye = np.linspace(-0.6, 0.6, 5), np.linspace(-0.6, 0.6, 5)
    m = camera_marker("cam0", T, xe, ye)
    assert m["dir"] == (0.0, 1.0) and "3.0 m off the map" in m["label"]
    svg = svgplot.heatmap(np.ones((4, 4)), xe, ye, markers=[m, {"x": 0, "y": 0, "label": "robot base"}])
    assert 'stroke="#fff" stroke-width="3" paint-order="stroke">robot base</text>' in svg
    frame = re.search(r'<rect x="[\d.]+" y="([\d.]+)" width="[\d.]+" height="([\d.]+)" fill="none" stroke="#333"', svg)
    bottom = float(frame.group(1)) + float(frame.group(2))
    diamond = re.search(r'<path d="M([\d.]+),([\d.]+)L[^"]*Z" fill="#ff7f0e"', svg)
    assert diamond and abs(float(diamond.group(2)) + 7 - bottom) < 0.2, (diamond, bottom)  # on the map's lower edge
    assert re.search(r'<line [^>]*stroke="#111" stroke-width="2"/>', svg)  # the arrow the way it looks
