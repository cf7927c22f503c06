"""Detection on rendered images with exact truth: convention, ordering, up-scaling, filter,
bad input, and the parallel cached dataset detector."""

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from calibgraph.core.camera import Intrinsics, preset
from calibgraph.core.targets import Target, a4_board_54, rct_charuco_board, thesis_board
from calibgraph.detect.corners import ImageDetection, dataset_detector, detect_image
from calibgraph.detect.grid_filter import check_grid
from calibgraph.sim.board_image import board_texture, look_at_board, render_view


def _errors(det, rv):
    """Detected minus true pixel for the ids both have; (M, 2)."""
    where = {int(i): k for k, i in enumerate(rv.ids)}
    common = [k for k, i in enumerate(det.ids) if int(i) in where]
    assert common, "no detected id is visible in the truth"
    return np.array([det.uv_px[k] - rv.uv_px[where[int(det.ids[k])]] for k in common])


def test_render_pixel_convention_matches_opencv():
    """Rendered corners detected by OpenCV land on the projected truth: a half-pixel convention
    error would show as a 0.5 px mean offset. Measured: |mean| ~0.005 px, rms ~0.03 px."""
    intr = preset("kinect_v2")
    t = a4_board_54()
    errs = []
    for k, (tx, ty, roll) in enumerate([(0, 0, 3), (25, -10, 40), (-15, 30, 100), (10, 20, 200)]):
        rv = render_view(t, intr, look_at_board(t, 1.0, tx, ty, roll, (60, -40), intr), blur_sigma_px=0.6, seed=k)
        det = detect_image(rv.image, t, upscale=1)
        assert det.ok, det.reason
        errs.append(_errors(det, rv))
    e = np.concatenate(errs)
    assert np.abs(e.mean(0)).max() < 0.02
    assert np.sqrt((e**2).sum(1).mean()) < 0.08


def test_render_with_distortion_keeps_truth():
    intr = Intrinsics(K=np.array([[900, 0, 639.5], [0, 900, 399.5], [0, 0, 1.0]]),
                      dist=np.array([-0.12, 0.05, 0.0005, -0.0003, 0.0]), width_px=1280, height_px=800)
    t = a4_board_54()
    rv = render_view(t, intr, look_at_board(t, 0.6, 10, 15, 5, (250, 120), intr), blur_sigma_px=0.6)
    det = detect_image(rv.image, t, intrinsics=intr, upscale=1)
    assert det.ok, det.reason
    e = _errors(det, rv)
    assert np.sqrt((e**2).sum(1).mean()) < 0.1


@pytest.mark.parametrize("method", ["classic", "sb"])
@pytest.mark.parametrize("roll", [0, 90, 180, 270])
def test_checkerboard_ids_follow_the_board_when_turned(method, roll):
    """OpenCV numbers corners from whichever end it meets first (SB often from the opposite
    corner); ids must follow the board's colours instead."""
    intr = preset("d455")
    t = thesis_board()
    rv = render_view(t, intr, look_at_board(t, 1.0, 15, -20, roll + 7, (0, 0), intr), blur_sigma_px=0.7,
                     noise_sigma=1.0, seed=roll)
    det = detect_image(rv.image, t, method=method, upscale=1)
    assert det.ok, det.reason
    assert det.n_found == 12 and det.method == method
    # A flipped ordering would be off by a whole square (~30 px); SB is less precise (0.36 px seen).
    assert np.abs(_errors(det, rv)).max() < 1.0


def test_symmetric_board_is_refused_unless_allowed():
    intr = preset("l515")
    t = Target(kind="checkerboard", rows=4, cols=6, pitch_m=0.03)  # 4 + 6 even: looks the same turned 180 deg
    rv = render_view(t, intr, look_at_board(t, 1.0, 10, 0, 0, (0, 0), intr), blur_sigma_px=0.6)
    det = detect_image(rv.image, t, upscale=1)
    assert not det.ok and "180 degrees" in det.reason
    det = detect_image(rv.image, t, upscale=1, allow_symmetric=True)
    assert det.ok and "guessed" in det.reason


def test_charuco_partial_view_keeps_true_ids():
    intr = preset("l515")
    t = rct_charuco_board()
    # Board centre pushed to the image edge: about half of it is outside the frame.
    T = look_at_board(t, 0.7, 10, -15, 30, (-intr.width_px / 2 + 30, 0), intr)
    rv = render_view(t, intr, T, blur_sigma_px=0.6, noise_sigma=1.0)
    det = detect_image(rv.image, t, intrinsics=intr)
    assert det.ok, det.reason
    assert 4 <= det.n_found < t.n_points
    assert set(det.ids) <= set(rv.ids.tolist())
    assert np.sqrt((_errors(det, rv) ** 2).sum(1).mean()) < 0.15


@pytest.mark.parametrize("roll", [0, 90, 180, 270])
def test_modified_circle_grid_oriented_by_big_dot(roll):
    intr = preset("l515")
    t = Target(kind="modified_circles", rows=5, cols=7, pitch_m=0.025)
    rv = render_view(t, intr, look_at_board(t, 0.9, -10, 15, roll + 5, (0, 0), intr), blur_sigma_px=0.7, noise_sigma=1.0)
    det = detect_image(rv.image, t, upscale=1)
    assert det.ok, det.reason
    assert det.n_found == t.n_points
    assert np.abs(_errors(det, rv)).max() < 0.3


@pytest.mark.parametrize("roll", [0, 180])
def test_asymmetric_circle_grid(roll):
    intr = preset("l515")
    t = Target(kind="acircles", rows=7, cols=4, pitch_m=0.02)
    rv = render_view(t, intr, look_at_board(t, 0.8, 10, 10, roll + 5, (0, 0), intr), blur_sigma_px=0.7, noise_sigma=1.0)
    det = detect_image(rv.image, t, upscale=1)
    assert det.ok, det.reason
    assert np.abs(_errors(det, rv)).max() < 0.3


def test_far_board_needs_upscaling_and_maps_back_exactly():
    """D455-like camera, thesis board at 4 m (squares ~7 px): the classic detector (the thesis's)
    misses it in the original image; the default finds it in the x2/x3 up-scaled region and maps
    the corners back to original pixels."""
    intr = preset("d455")
    t = thesis_board()
    rv = render_view(t, intr, look_at_board(t, 4.0, 10, 15, 3, (150, 60), intr), blur_sigma_px=0.6, noise_sigma=1.0)
    plain = detect_image(rv.image, t, upscale=1, method="classic")
    assert not plain.ok
    det = detect_image(rv.image, t, upscale="auto")
    assert det.ok, det.reason
    assert det.upscale in (2, 3)
    e = _errors(det, rv)
    # A wrong back-mapping ((X / k) instead of (X + 0.5) / k - 0.5) would bias by 0.25-0.33 px.
    assert np.abs(e.mean(0)).max() < 0.08
    assert np.sqrt((e**2).sum(1).mean()) < 0.2


def test_forced_upscale_agrees_with_native_on_a_near_board():
    intr = preset("l515")
    t = thesis_board()
    rv = render_view(t, intr, look_at_board(t, 1.5, 10, 10, 0, (0, 0), intr), blur_sigma_px=0.6)
    a = detect_image(rv.image, t, upscale=1)
    b = detect_image(rv.image, t, upscale=2)
    assert a.ok and b.ok and b.upscale == 2
    assert np.abs(_errors(b, rv).mean(0)).max() < 0.03


def test_grid_filter_accepts_good_and_names_what_is_wrong():
    t = a4_board_54()
    intr = preset("l515")
    rv = render_view(t, intr, look_at_board(t, 1.0, 20, 10, 0, (0, 0), intr))
    uv = rv.uv_px
    good = check_grid(uv, t.line_ij, t.points_board_m)
    assert good.ok and good.homography_max_px < 0.01
    bent = uv.copy()
    bent[13] += [0.0, 6.0]
    r = check_grid(bent, t.line_ij, t.points_board_m)
    assert not r.ok and ("row 1" in r.reason or "column 4" in r.reason)
    swapped = uv.copy()
    swapped[[20, 21]] = swapped[[21, 20]]
    r = check_grid(swapped, t.line_ij, t.points_board_m)
    assert not r.ok
    # Collinear, evenly spaced rows but ids off by one row in one half: only the homography sees it.
    r = check_grid(uv, t.line_ij, t.points_board_m, check_lines=False)
    assert r.ok


def test_bad_images_give_clear_messages(tmp_path):
    t = thesis_board()
    (tmp_path / "empty.png").write_bytes(b"")
    (tmp_path / "text.png").write_text("not an image")
    intr = preset("d455")
    rv = render_view(t, intr, look_at_board(t, 1.0, 0, 0, 0, (0, 0), intr))
    ok_png = cv2.imencode(".png", rv.image)[1].tobytes()
    (tmp_path / "trunc.png").write_bytes(ok_png[: len(ok_png) // 3])
    cases = {"empty.png": "empty", "text.png": "cannot decode", "trunc.png": "", "missing.png": "not found"}
    for name, words in cases.items():
        det = detect_image(tmp_path / name, t)
        assert not det.ok and name in det.reason and words in det.reason
    # 16-bit and float images are converted, not refused.
    assert detect_image(rv.image.astype(np.uint16) * 64, t).ok
    assert detect_image(rv.image.astype(np.float32) / 255.0, t).ok
    bad = detect_image(rv.image.astype(np.int32), t, source="cam0/000001.png")
    assert not bad.ok and "unsupported pixel type" in bad.reason and "cam0/000001.png" in bad.reason
    # Wrong target spec: nothing found, and the message says to check the spec.
    wrong = detect_image(rv.image, Target(kind="checkerboard", rows=5, cols=8, pitch_m=0.046))
    assert not wrong.ok and "target spec" in wrong.reason


def test_detection_record_round_trips():
    d = ImageDetection(ids=[0, 1, 2, 3], uv_px=np.arange(8.0).reshape(4, 2), ok=True, n_expected=12)
    back = ImageDetection.from_dict(json.loads(json.dumps(d.to_dict())))
    assert np.array_equal(back.ids, d.ids) and np.allclose(back.uv_px, d.uv_px) and np.isnan(back.sharpness_px)


def test_dataset_detector_parallel_cached_and_reports_bad_files(tmp_path, monkeypatch):
    from calibgraph.core.problem import Capture
    from calibgraph.detect import dataset as detect_mod  # where the dataset detector looks its search up
    from calibgraph.io.dataset import image_relpath, write_capture, write_header
    from calibgraph.io.layouts import load_dataset

    t = thesis_board()
    intr = preset("d455")
    write_header(tmp_path, t, {"cam0": intr})
    tex = board_texture(t, 3000.0)
    for k in range(4):
        rv = render_view(t, intr, look_at_board(t, 1.2, 10 * k - 15, 5 * k, 20 * k, (0, 0), intr), texture=tex, seed=k)
        rel = image_relpath("cam0", k)
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        if k == 3:
            (tmp_path / rel).write_bytes(b"\x89PNG\r\n")  # truncated file
        else:
            cv2.imwrite(str(tmp_path / rel), rv.image)
        write_capture(tmp_path, Capture(index=k, T_base_flange=np.eye(4)), {"cam0": {"image": rel}})
    ds = load_dataset(tmp_path)
    det = dataset_detector(ds, workers=2, progress=False)
    got = [det(v, ds) for v in ds.views]
    assert [g is not None for g in got] == [True, True, True, False]
    assert any("000003.png" in f and "decode" in m for f, m in det.problems)
    caches = list((tmp_path / ".calibgraph_cache").glob("detections-*.json"))
    assert len(caches) == 1
    # Second run is answered from the cache: the detector must not be called again for good files.
    calls = []
    real = detect_mod.look_blind
    monkeypatch.setattr(detect_mod, "look_blind", lambda *a, **k: calls.append(a[0]) or real(*a, **k))
    det2 = dataset_detector(load_dataset(tmp_path), progress=False)
    det2.run()
    assert calls == []
    assert np.allclose(det2.results[("cam0", 1)].uv_px, det.results[("cam0", 1)].uv_px)
    problem = ds.to_problem(detector=det2)
    assert len(problem.detections) == 3


def test_wrong_spec_for_a_whole_dataset_is_said_once(tmp_path):
    from calibgraph.core.problem import Capture
    from calibgraph.io.dataset import image_relpath, write_capture, write_header
    from calibgraph.io.layouts import load_dataset

    t = thesis_board()
    intr = preset("d455")
    write_header(tmp_path, replace(t, rows=5, cols=6), {"cam0": intr})
    for k in range(2):
        rv = render_view(t, intr, look_at_board(t, 1.0, 5 * k, 0, 0, (0, 0), intr))
        rel = image_relpath("cam0", k)
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(tmp_path / rel), rv.image)
        write_capture(tmp_path, Capture(index=k, T_base_flange=np.eye(4)), {"cam0": {"image": rel}})
    det = dataset_detector(load_dataset(tmp_path), progress=False, cache=False)
    det.run()
    assert any("not found in any image" in m for _, m in det.problems)


def test_cli_detect_prints_stats_and_problems(tmp_path, capsys):
    from calibgraph.cli.main import main
    from calibgraph.core.problem import Capture
    from calibgraph.io.dataset import image_relpath, write_capture, write_header

    t = thesis_board()
    intr = preset("d455")
    write_header(tmp_path, t, {"cam0": intr})
    for k in range(3):
        rel = image_relpath("cam0", k)
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        if k == 1:
            (tmp_path / rel).write_bytes(b"")
        else:
            rv = render_view(t, intr, look_at_board(t, 1.0, 10 * k, 0, 0, (0, 0), intr), seed=k)
            cv2.imwrite(str(tmp_path / rel), rv.image)
        write_capture(tmp_path, Capture(index=k, T_base_flange=np.eye(4)), {"cam0": {"image": rel}})
    assert main(["detect", str(tmp_path), "--quiet", "--no-cache"]) == 0
    out, err = capsys.readouterr()
    row = [line for line in out.splitlines() if line.startswith("cam0")][0].split()
    assert row[1:3] == ["3", "2"]  # views, detected
    assert "000001.png" in err and "empty" in err
    assert not (tmp_path / ".calibgraph_cache").exists()


def _two_camera_board_dataset(root, declared, printed, n=6, blank_camera=None):
    """Two cameras x ``n`` captures of the ``printed`` board (rendered, 1280x800), ``declared`` in
    dataset.yaml; ``blank_camera``'s frames show no board."""
    from calibgraph.core.problem import Capture
    from calibgraph.io.dataset import image_relpath, write_capture, write_header

    intr = preset("d455")
    write_header(root, declared, {"cam0": intr, "cam1": intr})
    tex = board_texture(printed, 3000.0)
    rng = np.random.default_rng(0)
    for k in range(n):
        views = {}
        for i, cam in enumerate(("cam0", "cam1")):
            rel = image_relpath(cam, k)
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            if cam == blank_camera:
                img = np.clip(90 + rng.normal(0, 3, (800, 1280)), 0, 255).astype(np.uint8)
            else:
                T = look_at_board(printed, 0.9 + 0.1 * i, 12 * k - 30, 8 * i - 4, 25 * k, (0, 0), intr)
                img = render_view(printed, intr, T, texture=tex, seed=10 * k + i).image
            cv2.imwrite(str(root / rel), img)
            views[cam] = {"image": rel}
        write_capture(root, Capture(index=k, T_base_flange=np.eye(4)), views)


@pytest.mark.parametrize("declared", [(4, 5), (7, 10)])
def test_wrong_board_spec_is_named_in_one_line(tmp_path, capsys, declared):
    """A 6x9 board declared smaller (a grid found inside it) or larger: `calibgraph detect` and the
    dataset detector stop with one line naming the grid the images show and rows/cols."""
    from calibgraph.cli.main import main
    from calibgraph.core.errors import InputError
    from calibgraph.io.layouts import load_dataset

    printed = a4_board_54()
    _two_camera_board_dataset(tmp_path, replace(printed, rows=declared[0], cols=declared[1]), printed)
    with pytest.raises(InputError, match=r"the images show a 6x9 grid: check rows/cols"):
        dataset_detector(load_dataset(tmp_path), progress=False, cache=False, fail_fast=True).run()
    assert main(["detect", str(tmp_path), "--quiet", "--no-cache"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and f"{declared[0]}x{declared[1]}" in err[0] and "6x9" in err[0], err


def test_a_board_seen_by_one_camera_only_is_not_a_wrong_spec(tmp_path):
    """cam1 never sees the board; cam0 does: the spec is right and every frame is searched."""
    from calibgraph.io.layouts import load_dataset

    printed = a4_board_54()
    _two_camera_board_dataset(tmp_path, printed, printed, blank_camera="cam1")
    det = dataset_detector(load_dataset(tmp_path), progress=False, cache=False, fail_fast=True)
    det.run()
    assert sum(d.ok for (c, _), d in det.results.items() if c == "cam0") >= 5
    assert not any(d.ok for (c, _), d in det.results.items() if c == "cam1")
    assert len(det.results) == 12


def test_spec_check_searches_a_sample_of_unseen_frames_before_naming_no_board():
    """Frames the probe saw nothing in are deferred, not judged: once every camera's first frames are
    in and none showed the board, a sample of them is searched in full first; a board in the sample
    settles the spec, none names it wrong in one line."""
    from calibgraph.core.errors import InputError
    from calibgraph.detect.detection import failed_detection
    from calibgraph.detect.spec_check import SAMPLE_PER_CAMERA, BoardSpecCheck

    t = a4_board_54()
    unseen = failed_detection("probe saw nothing", t, deferred=True)
    board = ImageDetection(ids=np.arange(4), uv_px=np.zeros((4, 2)), ok=True)

    def first_frames(check):
        for cam in ("a", "b"):
            for k in range(5):
                check.add(cam, unseen, key=(cam, k))
        return check.judge()

    check = BoardSpecCheck(t, {"a": 5, "b": 5})
    sample = first_frames(check)
    assert len(sample) == 2 * SAMPLE_PER_CAMERA and {c for c, _ in sample} == {"a", "b"}
    assert check.searching and check.judge() == []  # waits for the sample
    for key in sample:
        check.add(key[0], board if key == sample[0] else failed_detection("nothing", t), key=key)
    assert check.judge() == [] and check.settled and not check.searching

    check = BoardSpecCheck(t, {"a": 5, "b": 5})
    sample = first_frames(check)
    for key in sample:
        check.add(key[0], failed_detection("nothing", t), key=key)
    with pytest.raises(InputError, match=r"no checkerboard of 6x9 inner corners .* in the first 5 frames of any camera"):
        check.judge()
