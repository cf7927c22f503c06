"""Guided detection: a recording in which every camera captures at every robot pose (most frames
without the board) detects, guided by a survey's coarse solve, the same views as a blind search,
confirms the empty frames empty, and solves to the same calibration."""

from dataclasses import replace

import numpy as np
import pytest

from calibgraph.core.camera import Intrinsics
from calibgraph.core.targets import a4_board_54
from calibgraph.core.transforms import inv
from calibgraph.io.dataset import image_relpath, write_capture, write_header
from calibgraph.io.layouts import load_dataset
from calibgraph.sim.board_image import board_texture, render_view
from calibgraph.sim.synthetic_corners import make_scene, ring_cameras
from calibgraph.solver.solve.batch import solve
from calibgraph.detect.guided_dataset import (
    GUIDED_MIN_VIEWS,
    GuidedDatasetDetector,
)
from calibgraph.solver.solve.build import build_problem


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """4 cameras x 28 captures, 640x480; a view shows the board only when the synthetic scene says
    the camera sees it, else an empty frame (a smooth gradient with noise)."""
    import cv2

    root = tmp_path_factory.mktemp("rec")
    intr = replace(Intrinsics.from_hfov(640, 480, 45.0), source="exact")  # the renderer's own camera
    cams = {n: (T, intr) for n, (T, _) in ring_cameras([1.3, 1.5, 1.7, 1.9], spread_deg=300).items()}
    sc = make_scene(cameras=cams, n_poses=28, pixel_sigma_px=0.0, seed=3, shared_fraction=0.0, max_view_angle_deg=55.0)
    board = a4_board_54()
    tex = board_texture(board, 4.0 / 0.0004)
    seen = {(d.camera, d.capture) for d in sc.problem.detections}
    truth = {}
    write_header(root, board, {n: intr for n in cams})
    rng = np.random.default_rng(0)
    for cap in sc.problem.captures:
        views = {}
        for n in cams:
            rel = image_relpath(n, cap.index)
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            if (n, cap.index) in seen:
                T_cb = inv(sc.truth.T_ref_cam[n]) @ sc.truth.T_base_flange_true[cap.index] @ sc.truth.T_mount_board
                rv = render_view(board, intr, T_cb, blur_sigma_px=0.5, noise_sigma=1.5, seed=cap.index, texture=tex)
                img = rv.image
                truth[(n, cap.index)] = dict(zip(rv.ids.tolist(), rv.uv_px))
            else:
                yy, xx = np.mgrid[0:480, 0:640]
                img = np.clip(60 + 0.2 * xx + 0.1 * yy + rng.normal(0, 3, (480, 640)), 0, 255).astype(np.uint8)
            cv2.imwrite(str(root / rel), img)
            views[n] = {"image": rel}
        write_capture(root, cap, views)
    return root, seen, truth


def test_guided_finds_what_blind_finds_and_solves_the_same(recording, monkeypatch):
    import calibgraph.detect.guided_dataset as build

    monkeypatch.setattr(build, "SURVEY_CAPTURES", 16)  # a small recording: survey 16 of its 28 captures
    root, seen, truth = recording
    ds = load_dataset(root)
    assert len(ds.views) >= GUIDED_MIN_VIEWS
    p_blind, det_blind = build_problem(ds, progress=False, guided=False)
    p_guided, det_guided = build_problem(load_dataset(root), progress=False, guided=True)
    assert isinstance(det_guided, GuidedDatasetDetector)
    found_blind = {k for k, d in det_blind.results.items() if d.ok}
    found_guided = {k for k, d in det_guided.results.items() if d.ok}
    # the recording is what it claims (a few steeply tilted synthetic views are not found at all)
    assert found_blind <= seen and len(found_blind) >= 0.9 * len(seen)
    assert found_guided >= found_blind  # guided may find more: small boards get the right up-scaling
    # every view the survey's estimate called empty is one without the board
    empty = {k for k, h in det_guided.hints.items() if not h.visible}
    assert empty and not (empty & seen), det_guided.notes
    # guided corners are as good as blind ones: per view, RMS error against the rendered truth
    # (the two may take different detector paths, e.g. full resolution vs an up-scaled region)
    def rms(d):
        t = truth[(d.camera, d.capture)]
        return float(np.sqrt(np.mean([np.sum((uv - t[i]) ** 2) for i, uv in zip(d.ids, d.uv_px)])))

    e_blind = {(d.camera, d.capture): rms(d) for d in p_blind.detections}
    e_guided = {(d.camera, d.capture): rms(d) for d in p_guided.detections}
    assert np.mean(list(e_guided.values())) <= np.mean(list(e_blind.values())) + 0.01
    assert max(e_guided.values()) < 0.3, max(e_guided.items(), key=lambda kv: kv[1])
    p_guided = p_guided.with_(detections=tuple(d for d in p_guided.detections if (d.camera, d.capture) in e_blind))
    ra, rb = solve(p_blind), solve(p_guided)
    for n, c in ra.cameras.items():
        d_mm = 1e3 * np.linalg.norm(c.T_ref_cam[:3, 3] - rb.cameras[n].T_ref_cam[:3, 3])
        assert d_mm < 0.1 * np.linalg.norm(c.sigma_translation_mm), (n, d_mm)
    assert any("guided detection" in n for n in det_guided.notes)


def _variant(root, dest, target=None, blank_camera=None):
    """A copy of the recording with ``target`` declared in dataset.yaml instead of the printed board,
    or with every image of ``blank_camera`` replaced by an empty frame."""
    import shutil

    import cv2
    import yaml

    shutil.copytree(root, dest, ignore=shutil.ignore_patterns(".calibgraph_cache"))
    if target is not None:
        head = yaml.safe_load((dest / "dataset.yaml").read_text())
        head["target"] = target.to_dict()
        (dest / "dataset.yaml").write_text(yaml.safe_dump(head, sort_keys=False))
    if blank_camera is not None:
        rng = np.random.default_rng(1)
        yy, xx = np.mgrid[0:480, 0:640]
        for f in sorted((dest / "images" / blank_camera).glob("*.png")):
            cv2.imwrite(str(f), np.clip(60 + 0.2 * xx + 0.1 * yy + rng.normal(0, 3, (480, 640)), 0, 255).astype(np.uint8))
    return dest


def test_wrong_board_spec_stops_on_the_first_frames_naming_rows_and_cols(recording, tmp_path, capsys, monkeypatch):
    """The recording's board has 6x9 inner corners; declared 4x5 (same pitch), `calibgraph solve`
    exits non-zero with one line naming the grid the images show, after the survey's first frames
    (not after searching every frame, as it did)."""
    import calibgraph.detect.guided_dataset as build
    from calibgraph.cli.main import main
    from calibgraph.core.targets import Target

    root, _, _ = recording
    wrong = _variant(root, tmp_path / "wrong", target=Target(kind="checkerboard", rows=4, cols=5, pitch_m=0.025))
    looked = []
    real = build.look_blind
    monkeypatch.setattr(build, "look_blind", lambda frame, *a, **k: looked.append(frame.name) or real(frame, *a, **k))
    assert main(["solve", str(wrong), "--quiet"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1, err
    assert "no checkerboard of 4x5 inner corners" in err[0] and "6x9 grid" in err[0] and "rows/cols" in err[0], err[0]
    n_views = len(load_dataset(wrong).views)
    assert 0 < len(looked) <= n_views // 2, (len(looked), n_views)


def test_a_camera_that_never_sees_the_board_is_not_a_wrong_spec(recording, tmp_path):
    """One camera's frames are all empty: the others find the board, so the spec is right and the
    detector runs to the end (the camera without views is the solver's business)."""
    root, seen, _ = recording
    blank = _variant(root, tmp_path / "blank", blank_camera="cam2")
    det = GuidedDatasetDetector(load_dataset(blank), progress=False, coarse_solve=solve)
    det.run()
    found = {k for k, d in det.results.items() if d.ok}
    assert not any(c == "cam2" for c, _ in found)
    assert {c for c, _ in found} == {c for c, _ in seen} - {"cam2"}
    assert len(det.results) == len(load_dataset(blank).views)
