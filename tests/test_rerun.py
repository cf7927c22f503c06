"""rerun recording: written offline from a solved simulated cell, verified by the rerun CLI, read back."""

import json
import subprocess
import sys

import numpy as np
import pytest
from helpers import knocked_result, make_sim_result, write_sim_dataset

rr = pytest.importorskip("rerun", reason="rerun-sdk not installed (pip install calibgraph[viz])")


def _verify(path):
    from calibgraph.report.rerun_view import rerun_cli

    r = subprocess.run(rerun_cli() + ["rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "verified without error" in r.stdout + r.stderr


def _chunks(path):
    from rerun.chunk import RrdReader

    out = {}
    for ch in RrdReader(str(path)).stream():
        out.setdefault(ch.entity_path, []).append(ch)
    return out


def _series(chunks, entity):
    caps, vals = [], []
    for ch in chunks.get(entity, []):
        if ch.is_static:
            continue
        rb = ch.to_record_batch()
        if "Scalars:scalars" not in rb.schema.names:
            continue
        caps += rb.column("capture").to_pylist()
        vals += [v[0] for v in rb.column("Scalars:scalars").to_pylist()]
    return dict(zip(caps, vals))


def test_rrd_from_result_and_problem_verifies_and_holds_the_residuals(tmp_path):
    from calibgraph.report.rerun_view import write_rrd

    r, scene, prob, res = make_sim_result()
    d = r.to_dict()
    path = write_rrd(res, prob, tmp_path / "cal.rrd")  # what `calibgraph solve --rrd` calls
    _verify(path)
    from rerun.chunk import RrdReader

    assert len(RrdReader(str(path)).blueprints()) == 1  # the default layout travels with the file
    ch = _chunks(path)
    for n in d["cameras"]:
        for sub in ("", "/image", "/image/detected", "/image/reprojected", "/image/residual_x20"):
            assert f"/world/cameras/{n}{sub}" in ch, f"/world/cameras/{n}{sub}"
        # the per-capture RMS series equals the RMS of the result's residuals (used corners only)
        got = _series(ch, f"/residuals/{n}/rms_px")
        rej = {(r["capture"], r["id"]) for r in d["rejected_corners"] if r["camera"] == n}
        want = {}
        for k, v in d["residuals"][n].items():
            if v["rejected"]:
                continue
            keep = [(int(k), i) not in rej for i in v["ids"]]
            r = np.asarray(v["residual_px"])[keep]
            want[int(k)] = float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))
        assert got.keys() == want.keys() and np.allclose([got[k] for k in want], list(want.values()), rtol=1e-12)
    for e in ("/world/robot_base", "/world/flange", "/world/flange/board/points", "/world/flange_path", "/summary"):
        assert e in ch
    # the camera whose view carried the injected 25 px corners has them highlighted
    assert any(r["residual_px"] > 10 for r in d["rejected_corners"])
    cam_out = {r["camera"] for r in d["rejected_corners"]}
    assert all(f"/world/cameras/{n}/image/outliers" in ch for n in cam_out)


def test_rrd_from_result_file_and_dataset_with_images(tmp_path):
    import cv2

    from calibgraph.cli.main import main

    r, scene, prob, res = make_sim_result(residuals=False)
    d = r.to_dict()
    ds = write_sim_dataset(tmp_path / "ds", prob)
    # give three views an image file (grey frames; the point is that they are logged)
    caps = sorted(json.loads(p.read_text())["index"] for p in (ds / "captures").glob("*.json"))[:3]
    for k in caps:
        f = ds / "captures" / f"{k:06d}.json"
        c = json.loads(f.read_text())
        for cam in c["views"]:
            rel = f"images/{cam}/{k:06d}.png"
            (ds / rel).parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(ds / rel), np.full((1080 // 4, 1920 // 4), 128, np.uint8))
            c["views"][cam]["image"] = rel
        f.write_text(json.dumps(c))
    r.save(tmp_path / "result.json")
    out = tmp_path / "view.rrd"
    assert main(["view", str(tmp_path / "result.json"), "--dataset", str(ds), "--rrd", str(out)]) == 0
    _verify(out)
    ch = _chunks(out)
    images = [c for n in d["cameras"] for c in ch.get(f"/world/cameras/{n}/image", [])
              if not c.is_static and any("EncodedImage" in s for s in c.to_record_batch().schema.names)]
    assert images, "images of the dataset were not logged"
    # residuals recomputed from the dataset give the same series as in the solver's result
    n = next(iter(d["cameras"]))
    assert len(_series(ch, f"/residuals/{n}/rms_px")) == d["cameras"][n]["views_used"]


def test_eye_in_hand_rrd(tmp_path):
    from calibgraph.report.rerun_view import write_rrd

    r, scene, prob, res = make_sim_result(mode="eye_in_hand")
    d = r.to_dict()
    path = write_rrd(r, prob, tmp_path / "eih.rrd")
    _verify(path)
    ch = _chunks(path)
    n = next(iter(d["cameras"]))
    assert f"/world/flange/{n}/image/detected" in ch and "/world/board/points" in ch


def test_engine_does_not_import_rerun():
    code = ("import sys; import calibgraph, calibgraph.report.html, calibgraph.report.exports, calibgraph.solver.uncertainty.workspace, "
            "calibgraph.report.rerun_view, calibgraph.cli.view, calibgraph.cli.report, calibgraph.cli.export; "
            "assert 'rerun' not in sys.modules, 'rerun imported'; assert 'matplotlib' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)


def test_report_and_rrd_from_the_real_rct_dataset(rct_dir, tmp_path):
    """End to end on real images: solve -> report (coverage needs the dataset's intrinsics) -> .rrd with images.
    Solved in a private copy (``rct_dir``): a solve writes its detection cache and lock beside the data,
    and ../shared is never written to."""
    from calibgraph.cli.main import main
    from calibgraph.report.html import write_report
    from calibgraph.report.rerun_view import write_rrd
    from calibgraph.solver.output.result import load_result

    ds = rct_dir
    res = tmp_path / "result.json"
    assert main(["solve", str(ds), "--out", str(res), "--quiet"]) == 0
    r = load_result(res)
    d = r.to_dict()
    text = write_report(r, tmp_path / "report.html", dataset=ds, result_path=res).read_text()
    assert "1600×1200 px" in text and "image coverage (" in text
    assert f">{d['cameras']['camera']['reprojection_rms_px']:.3f}<" in text
    path = write_rrd(r, ds, tmp_path / "rct.rrd")
    _verify(path)
    ch = _chunks(path)
    imgs = [c for c in ch["/world/cameras/camera/image"] if not c.is_static]
    assert sum(c.num_rows for c in imgs) == len(d["residuals"]["camera"])


def test_rrd_shows_the_plan_of_an_autonomous_run(tmp_path):
    """Per step of plan_log.json: candidates coloured by score, the chosen pose, the 1-sigma series."""
    from calibgraph.report.rerun_view import plan_points, write_rrd

    r, scene, prob, res = make_sim_result()
    d = r.to_dict()
    rng = np.random.default_rng(3)
    steps = [{"step": 0, "phase": "survey round 0", "label": "sweep", "why": "survey", "status": "captured",
              "board_centre_m": [0.5, 0.0, 0.4], "seen_by": ["cam0"], "achieved": {}}]
    for k in (1, 2):
        cands = [{"board_centre_m": rng.uniform(-0.7, 0.7, 3).round(4).tolist(), "score": float(s), "gain": 1.0}
                 for s in sorted(rng.uniform(0.1, 2.0, 5), reverse=True)]
        steps.append({"step": k, "phase": "active", "label": f"active {k}", "why": "best", "status": "captured",
                      "candidates": cands, "chosen_candidate": 1, "chosen_board_centre_m": cands[1]["board_centre_m"],
                      "board_centre_m": cands[1]["board_centre_m"], "seen_by": ["cam0"],
                      "achieved": {"cam0": [1.0 / k, 0.01]}})
    log = {"cameras": ["cam0"], "steps": steps}
    (tmp_path / "plan_log.json").write_text(json.dumps(log))
    path = write_rrd(res, prob, tmp_path / "plan.rrd", plan_log=tmp_path / "plan_log.json")
    _verify(path)
    ch = _chunks(path)
    got = {}
    for e in ("/world/plan/candidates", "/world/plan/chosen"):
        for c in ch[e]:
            rb = c.to_record_batch()
            cols = {n: rb.column(n).to_pylist() for n in rb.schema.names if n.startswith("Points3D:") or n == "capture"}
            for i, k in enumerate(cols.get("capture", [])):
                if cols.get("Points3D:positions", [None])[i] is not None:
                    got[e, k] = (np.asarray(cols["Points3D:positions"][i]), cols.get("Points3D:colors", [None] * (i + 1))[i])
    for s in steps[1:]:
        P, _, colours, chosen = plan_points(s)
        assert np.allclose(P, [c["board_centre_m"] for c in s["candidates"]]) and np.allclose(chosen, s["board_centre_m"])
        P_rrd, col_rrd = got["/world/plan/candidates", s["step"]]
        assert np.allclose(P_rrd, P) and np.allclose(got["/world/plan/chosen", s["step"]][0], [chosen])
        assert col_rrd is not None and len(col_rrd) == len(P)  # one colour per candidate
        # best score is yellow (viridis top), worst purple; colours follow the scores' order
        assert tuple(colours[0]) != tuple(colours[-1]) and colours[0][1] > colours[-1][1]
    assert ("/world/plan/candidates", 0) not in got  # a survey step has no candidates (cleared)
    assert np.allclose(got["/world/plan/chosen", 0][0], [[0.5, 0.0, 0.4]])
    assert _series(ch, "/plan/sigma_mm/cam0") == {1: 1.0, 2: 0.5} and "/plan/log" in ch


def _summary_text(path) -> str:
    from rerun.chunk import RrdReader

    for ch in RrdReader(str(path)).stream():
        if ch.entity_path == "/summary":
            return ch.to_record_batch().column("TextDocument:text").to_pylist()[0][0]
    raise AssertionError("no /summary in the recording")


def test_summary_carries_each_cameras_budget_advice_and_notes(tmp_path):
    """The recording's summary says per camera what the report says: its error budget's shares, its
    advice, its intrinsics' provenance, a move during capture, the notes on it; and the cell's notes."""
    from calibgraph.report import findings
    from calibgraph.report.rerun_view import write_rrd

    res = knocked_result()  # cam0 knocked 5 mm after capture 18
    path = write_rrd(res, None, tmp_path / "cal.rrd")
    _verify(path)
    text = _summary_text(path)
    assert "## What would improve this calibration" in text and "## Notes on the whole cell" in text
    improve = text.split("## What would improve this calibration")[1].split("## Cameras")[0]
    names = list(res.cameras)
    for i, n in enumerate(names):
        c = res.cameras[n]
        sec = text.split(f"### {n}")[1].split(f"### {names[i + 1]}" if i + 1 < len(names) else "## Notes on the whole")[0]
        assert c.error_budget["advice"] in improve and f"**advice**: {c.error_budget['advice']}" in sec
        assert findings.shares_text(c.error_budget["shares"]) in sec
        assert findings.provenance_text(c, res.settings) in sec
        assert res.camera_notes(n) == [x[len("- note: "):] for x in sec.splitlines() if x.startswith("- note: ")]
    assert "moved between captures" in text.split("### cam0")[1].split("### cam1")[0]
    cell = text.split("## Notes on the whole cell")[1]
    assert all(f"- {t}" in cell for t in res.cell_notes)
