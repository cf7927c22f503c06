"""Result is the boundary type: ``Result.save`` and ``calibgraph.load_result`` round-trip a real solve
exactly (every field, arrays bit for bit) in JSON and YAML; a file of an earlier calibgraph loads
with defaults; a foreign, newer or malformed one is refused in one line."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import replace
from functools import lru_cache

import numpy as np
import pytest
from helpers import fails_instead_of_hanging

import calibgraph as cg
from calibgraph.core.errors import InputError
from calibgraph.core.problem import Detection, SolverOptions
from calibgraph.sim.synthetic_corners import make_scene
from calibgraph.sim.kinematic_scene import make_kinematic_scene
from calibgraph.solver.output.result import Result, exactly_equal, load_result_dict


@lru_cache(maxsize=1)
def rich_result() -> Result:
    """A solve that fills every section an eye-to-hand joint result has: a view and three corners
    rejected, intrinsics estimated (with sigma), an FK accuracy widened by the fit (fk_noise and a
    note), board scale with its sigma, residuals, refined flange poses."""
    opts = SolverOptions(fk_sigma_translation_m=2e-4, fk_sigma_rotation_rad=2e-4)
    sc = make_scene(n_poses=24, seed=4, fk_sigma_translation_m=1e-3, fk_sigma_rotation_rad=1e-3, options=opts)
    prob = sc.problem
    dets = list(prob.detections)
    rng = np.random.default_rng(7)
    d = dets[5]
    dets[5] = Detection(d.camera, d.capture, d.ids, d.uv_px + rng.normal(scale=40.0, size=d.uv_px.shape))
    d = dets[2]
    uv = d.uv_px.copy()
    uv[[3, 10, 20]] += 25.0
    dets[2] = Detection(d.camera, d.capture, d.ids, uv)
    cams = {n: replace(i, source="calibration") for n, i in prob.cameras.items()}
    return replace(cg.solve(prob.with_(detections=tuple(dets), cameras=cams)), dataset="synthetic seed 4")


@lru_cache(maxsize=1)
def kinematic_result() -> Result:
    sc, _ = make_kinematic_scene(np.array([0.0, 1.5e-3, -1.0e-3, 2.0e-3, -0.5e-3, 1.2e-3, 0.0]), n_poses=30, seed=1)
    return cg.solve(sc.problem.with_(options=replace(sc.problem.options, kinematics="joint-offsets")))


def assert_same(a: Result, b: Result):
    """Field by field, so a failure names the field."""
    for f in dataclasses.fields(Result):
        if f.name == "cameras":
            assert a.cameras.keys() == b.cameras.keys()
            for n in a.cameras:
                for g in dataclasses.fields(a.cameras[n]):
                    assert exactly_equal(getattr(a.cameras[n], g.name), getattr(b.cameras[n], g.name)), (n, g.name)
        assert exactly_equal(getattr(a, f.name), getattr(b, f.name)), f.name
    assert a == b


def test_the_rich_result_fills_every_section():
    r = rich_result()
    assert r.rejected_views and r.rejected_corners and r.notes and r.fk_noise and r.T_base_flange_est
    assert r.board_scale_sigma is not None and r.settings and r.pairs and r.mount_covariance is not None
    for c in r.cameras.values():
        assert c.intrinsics["sigma"] and c.residuals_px and c.corner_noise
    assert any((v["weight"] < 1).any() for c in r.cameras.values() for v in c.residuals_px.values())
    assert all(np.isfinite(c.reprojection_rms_px) for c in r.cameras.values())


@pytest.mark.parametrize("ext", ["json", "yaml", "yml"])
def test_saved_result_loads_back_equal(tmp_path, ext):
    r = rich_result()
    p = r.save(tmp_path / f"result.{ext}")
    back = cg.load_result(p)
    assert_same(back, r)
    # and the file it writes again is the same file
    assert back.save(tmp_path / f"again.{ext}").read_bytes() == p.read_bytes()
    assert Result.from_dict(r.to_dict()) == r


def test_robot_section_round_trips(tmp_path):
    r = kinematic_result()
    assert r.robot and r.robot["estimated"]
    assert_same(cg.load_result(r.save(tmp_path / "r.json")), r)
    assert_same(cg.load_result(r.save(tmp_path / "r.yaml")), r)


@pytest.mark.parametrize("mode,method", [("eye_in_hand", "joint"), ("eye_to_hand", "single")])
def test_other_modes_round_trip(tmp_path, mode, method):
    r = cg.solve(make_scene(n_poses=18, seed=2, mode=mode, method=method).problem)
    if method == "single":
        assert r.T_mount_board is None and all(c.T_mount_board is not None for c in r.cameras.values())
    back = cg.load_result(r.save(tmp_path / "r.json"))
    assert_same(back, r)
    assert back.ref_frame == ("flange" if mode == "eye_in_hand" else "base")


def test_equality_sees_one_changed_number():
    r = rich_result()
    name = next(iter(r.cameras))
    T = r.cameras[name].T_ref_cam.copy()
    T[0, 3] = np.nextafter(T[0, 3], 1.0)
    other = replace(r, cameras={**r.cameras, name: replace(r.cameras[name], T_ref_cam=T)})
    assert other != r
    assert replace(r, notes=r.notes + ("x",)) != r
    assert replace(r, converged=not r.converged) != r


def _as_written_by_the_first_version(d: dict) -> dict:
    """A result dict as calibgraph wrote it before residuals, intrinsics, board scale, notes,
    kinematics, corner noise, FK noise and the top-level rejected views existed (git history of
    calibgraph/solver/output/result.py)."""
    d = json.loads(json.dumps(d))
    for k in ("residuals", "board_scale", "notes", "robot", "fk_noise", "rejected_views"):
        d.pop(k, None)
    for c in d["cameras"].values():
        c.pop("intrinsics", None)
        c.pop("corner_noise", None)
    return d


def test_an_old_result_file_loads_with_defaults(tmp_path):
    r = rich_result()
    p = tmp_path / "old.json"
    p.write_text(json.dumps(_as_written_by_the_first_version(r.to_dict())))
    old = cg.load_result(p)
    assert old.board_scale == 1.0 and old.board_scale_sigma is None and old.notes == () and old.fk_noise is None
    assert old.robot is None and old.rejected_views == r.rejected_views  # from the cameras' own lists
    for n, c in old.cameras.items():
        assert c.intrinsics is None and c.residuals_px == {} and c.corner_noise is None
        assert np.array_equal(c.T_ref_cam, r.cameras[n].T_ref_cam) and np.array_equal(c.covariance, r.cameras[n].covariance)
        assert c.views_rejected == r.cameras[n].views_rejected
    assert old.pairs == r.pairs and np.array_equal(old.T_mount_board, r.T_mount_board)
    assert (old.converged, old.iterations, old.final_cost) == (r.converged, r.iterations, r.final_cost)


def test_residuals_without_weights_take_them_from_the_rejected_flags(tmp_path):
    r = rich_result()
    d = r.to_dict()
    for per in d["residuals"].values():
        for v in per.values():
            v.pop("weight")
    back = Result.from_dict(d)
    for n, c in r.cameras.items():
        for k, v in c.residuals_px.items():
            w = back.cameras[n].residuals_px[k]["weight"]
            assert np.array_equal(w == 0, v["weight"] == 0) and set(np.unique(w)) <= {0.0, 1.0}
            assert np.array_equal(back.cameras[n].residuals_px[k]["residual_px"], v["residual_px"])


def _one_line(e: InputError) -> str:
    s = str(e)
    assert s and "\n" not in s.strip()
    return s


def _scale_column(T: list, col: int, factor: float) -> None:
    for row in T[:3]:
        row[col] *= factor


@pytest.mark.parametrize("change,said", [
    (lambda d: d.update(format="calibgraph-result/2"), ["newer than this calibgraph", "upgrade calibgraph"]),
    (lambda d: d.update(format="other-tool/1"), ["not a calibgraph result"]),
    (lambda d: d.pop("cameras"), ["not a calibgraph result"]),
    (lambda d: d.update(mode="eye_on_table"), ["mode 'eye_on_table'"]),
    (lambda d: d.update(cameras={}), ["no cameras"]),
    (lambda d: d["cameras"]["cam1"].pop("T_base_cam"), ["camera 'cam1'", "T_base_cam"]),
    (lambda d: d["cameras"]["cam1"].update(covariance=[[1.0, 2.0]]), ["camera 'cam1'", "covariance", "6x6"]),
    (lambda d: d["cameras"]["cam0"]["T_base_cam"][0].__setitem__(3, float("nan")), ["cam0", "finite"]),
    # issue 34: a pose that is not a rigid transform was exported as another pose without a word
    (lambda d: _scale_column(d["cameras"]["cam0"]["T_base_cam"], 0, 2.0), ["cam0", "T_base_cam", "not a rigid transform"]),
    (lambda d: _scale_column(d["cameras"]["cam1"]["T_base_cam"], 2, -1.0), ["cam1", "not a rigid transform", "det -1"]),
    (lambda d: d["cameras"]["cam0"]["T_base_cam"][3].__setitem__(0, 0.5), ["cam0", "not a rigid transform", "last row"]),
    (lambda d: _scale_column(d["T_flange_board"], 1, 1.01), ["T_flange_board", "not a rigid transform"]),
    (lambda d: d["T_flange_board"][1].__setitem__(3, float("inf")), ["T_flange_board", "finite"]),
    (lambda d: d["residuals"]["cam0"].update({"3": "garbage"}), ["residuals of capture 3"]),
    (lambda d: d.update(robot=[1, 2]), ["robot", "not a mapping"]),
    (lambda d: d["solver"].update(iterations="many"), ["not a readable calibgraph result"]),
])
def test_foreign_newer_or_malformed_result_is_refused_in_one_line(tmp_path, change, said):
    d = json.loads(json.dumps(rich_result().to_dict()))
    change(d)
    p = tmp_path / "r.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError) as e:
        cg.load_result(p)
    msg = _one_line(e.value)
    assert str(p) in msg
    for s in said:
        assert s in msg, msg


def test_unreadable_files_are_refused_without_blocking(tmp_path):
    with pytest.raises(InputError, match="cannot read result"):
        cg.load_result(tmp_path / "missing.json")
    with pytest.raises(InputError, match="a folder with no result.json or result.yaml in it: solve it first"):
        cg.load_result(tmp_path)  # a folder is read as the dataset solve wrote result.json into
    (tmp_path / "bin.json").write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError, match="not a calibgraph result"):
        cg.load_result(tmp_path / "bin.json")
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    with fails_instead_of_hanging(20, "load_result of a FIFO"), pytest.raises(InputError, match="not a regular file"):
        cg.load_result(fifo)


def test_load_result_dict_stays_for_outside_scripts(tmp_path):
    r = rich_result()
    p = r.save(tmp_path / "r.json")
    d = load_result_dict(p)
    assert d == json.loads(p.read_text()) and cg.load_result_dict is load_result_dict
    assert Result.from_dict(d, str(p)) == r


def test_a_camera_that_was_not_calibrated_round_trips_and_is_reported(tmp_path):
    """One camera's images mirrored leaves it not calibrated (no pose, no covariance, why): the file
    keeps that, the report fails it with its reason, the exports leave it out and say so."""
    from calibgraph.report.exports import export
    from calibgraph.report.html import write_report

    # the oracle's scene (true intrinsics held): its other cameras pass the default tolerances, so the
    # report fails cam1 alone (with factory intrinsics cam0 and cam2 fail them too)
    p = make_scene(n_poses=30, pixel_sigma_px=0.3, seed=13, reported_intrinsics="exact").problem
    flip = np.array([-1.0, 1.0]), np.array([p.cameras["cam1"].width_px - 1.0, 0.0])  # u -> width - 1 - u
    r = cg.solve(p.with_(detections=tuple(replace(d, uv_px=d.uv_px * flip[0] + flip[1]) if d.camera == "cam1" else d
                                          for d in p.detections)))
    assert not r.cameras["cam1"].calibrated and r.cameras["cam1"].why
    for ext in ("json", "yaml"):
        assert_same(cg.load_result(r.save(tmp_path / f"r.{ext}")), r)
    text = write_report(r, tmp_path / "r.html").read_text()
    assert "Overall: FAIL" in text and "failing: cam1" in text and "Not calibrated" in text
    urdfs = export(r, "urdf", tmp_path / "e")  # the xacro and the plain URDF beside it
    for p in urdfs:
        text = p.read_text()
        assert "cam1_optical_frame" not in text and "'cam1' is not in this file" in text, p
    assert sorted(q.name for q in export(r, "opencv-yaml", tmp_path / "e")) == ["cam0.yaml", "cam2.yaml"]
    from calibgraph.solver.changes.verify import verify

    vr = verify(make_scene(n_poses=6, pixel_sigma_px=0.3, seed=14, shared_fraction=0.6, reported_intrinsics="exact").problem, r)
    assert "cam1" not in vr.cameras and any("cam1 was not calibrated" in n for n in vr.notes), vr.notes


# -- provenance of the intrinsics, notes that name their camera (issue 35) ---------------------------
def _provenance_scene():
    from calibgraph.core.camera import Intrinsics

    sc = make_scene(n_poses=30, seed=4, reported_intrinsics="exact")
    cams = dict(sc.problem.cameras)
    cams["cam0"] = replace(cams["cam0"], source="factory")  # stated with the camera
    cams["cam1"] = replace(cams["cam1"], source="")  # not stated: the solver's default applies
    cams["cam2"] = Intrinsics.unknown(cams["cam2"].width_px, cams["cam2"].height_px)
    return sc.problem.with_(cameras=cams)


def test_intrinsics_provenance_per_camera(tmp_path):
    """result.json says per camera where the given intrinsics came from (stated, or the default)
    and how the solver used them, with the prior's width; the settings no longer claim one source
    for every camera; a result written before (no such keys) still says what it can."""
    from calibgraph.solver.output.result import intrinsics_provenance

    prob = _provenance_scene()
    res = cg.solve(prob)
    d = json.loads(res.save(tmp_path / "r.json").read_text())
    cams = d["cameras"]
    got = {n: (c["intrinsics"]["source_given"], c["intrinsics"]["source_stated"], c["intrinsics"]["source_used"])
           for n, c in cams.items()}
    assert got == {"cam0": ("factory", True, "factory"), "cam1": ("calibration", False, "calibration"),
                   "cam2": ("unknown", True, "own-views")}, got
    fx = {n: prob.cameras[n].K[0, 0] for n in ("cam0", "cam1")}
    assert np.isclose(cams["cam0"]["intrinsics"]["prior_sigma"]["fx"], 0.02 * fx["cam0"])  # factory: f 2 %
    assert np.isclose(cams["cam1"]["intrinsics"]["prior_sigma"]["fx"], 0.003 * fx["cam1"])  # calibration: f 0.3 %
    assert set(cams["cam2"]["intrinsics"]["prior_sigma"]) == set(cams["cam2"]["intrinsics"]["sigma"])
    settings = d["solver"]["settings"]
    assert "intrinsics_source" not in settings and settings["intrinsics_source_default"] == "calibration"
    back = cg.load_result(tmp_path / "r.json")
    assert back == res and {n: tuple(intrinsics_provenance(c, back.settings).values())
                            for n, c in back.cameras.items()} == got
    # the same cameras with the default set to factory, and held as given
    o = prob.options
    res_f = cg.solve(prob.with_(options=replace(o, intrinsics_source="factory", intrinsics="fixed")))
    used = {n: (c.intrinsics["source_given"], c.intrinsics["source_used"], "prior_sigma" in c.intrinsics)
            for n, c in res_f.cameras.items()}
    assert used == {"cam0": ("factory", "held", False), "cam1": ("factory", "held", False),
                    "cam2": ("unknown", "own-views", True)}, used
    # a result.json of an earlier calibgraph: the camera's own source, else the settings' one source
    old = json.loads(json.dumps(d))
    for c in old["cameras"].values():
        for k in ("source_given", "source_stated", "source_used", "prior_sigma"):
            c["intrinsics"].pop(k)
    old["solver"]["settings"]["intrinsics_source"] = old["solver"]["settings"].pop("intrinsics_source_default")
    old_res = Result.from_dict(old)
    assert {n: tuple(intrinsics_provenance(c, old_res.settings).values()) for n, c in old_res.cameras.items()} == got


def test_notes_name_the_camera_they_concern(tmp_path):
    from calibgraph.solver.output.result import note_camera

    names = ["cam1", "cam10", "left", "left cam"]
    assert note_camera("camera cam1: principal point cx estimated", names) == "cam1"
    assert note_camera("camera cam10: focal length", names) == "cam10"
    assert note_camera("camera cam1 moved during capture, between captures 3 and 4", names) == "cam1"
    assert note_camera("camera cam1 (before the move): focal length", names) == "cam1"
    assert note_camera("camera left cam: its residuals move whole boards", names) == "left cam"
    assert note_camera("camera left: its residuals", names) == "left"
    assert note_camera("camera cam3: unknown", names) is None
    assert note_camera("robot: the fitted flange poses depart", names) is None
    assert note_camera("the board is +0.30 % (± 0.05 %) the size", names) is None
    res = _provenance_scene_result()
    d = json.loads(res.save(tmp_path / "r.json").read_text())
    assert len(d["note_cameras"]) == len(d["notes"]) > 0
    for note, cam in zip(d["notes"], d["note_cameras"]):
        assert (cam is not None) == note.startswith("camera "), (note, cam)
        if cam is not None:
            assert note.startswith(f"camera {cam}") and note in res.camera_notes(cam)
    # cam2's intrinsics were found from its views: the solver's note on it is cam2's
    assert any("no intrinsics were given" in t for t in res.camera_notes("cam2"))


@lru_cache(maxsize=1)
def _provenance_scene_result():
    return cg.solve(_provenance_scene())


def test_intrinsics_used_under_refine_and_a_files_covariance():
    """--refine-intrinsics and intrinsics that came with a covariance (a calibration file's) are named
    as used, with the prior's width the solver applied."""
    from calibgraph.core.problem import intrinsics_prior_sigmas

    prob = make_scene(n_poses=24, seed=2, reported_intrinsics="exact").problem
    cams = dict(prob.cameras)
    c0 = cams["cam0"]
    sig = np.array([0.5, 0.5, 0.4, 0.4, 0.002, 0.004])
    cams["cam0"] = replace(c0, source="calibration", covariance=np.diag(sig ** 2))
    cams["cam1"] = replace(cams["cam1"], source="factory")
    res = cg.solve(prob.with_(cameras=cams))
    d0 = res.cameras["cam0"].intrinsics
    assert (d0["source_given"], d0["source_used"]) == ("calibration", "file-covariance")
    assert np.allclose([d0["prior_sigma"][k] for k in ("fx", "fy", "cx", "cy", "k1", "k2")], sig)
    assert res.cameras["cam1"].intrinsics["source_used"] == "factory"
    refine = prob.with_(cameras=cams, options=replace(prob.options, intrinsics="estimate"))
    res_r = cg.solve(refine)
    for n, c in res_r.cameras.items():
        d = c.intrinsics
        assert d["source_used"] == "refine", (n, d["source_used"])
        want = intrinsics_prior_sigmas(refine.cameras[n], refine.options)
        assert np.allclose([d["prior_sigma"][k] for k in ("fx", "fy", "cx", "cy", "k1", "k2")], want[:6])
