"""A camera knocked during capture (issue 26 part 1): named on one line, solved as two poses (the
one after the move reported as the camera's, the one before with its covariance in ``moved``), and
the other cameras and the shared parameters not dragged; no move reported on still cells, with FK
noise and with corner noise correlated within each view.

Tolerances: an estimate is "at" a pose when every axis of its translation error is within 3 of its
reported 1-sigma (and its rotation error within 3 of the 1-sigma norm); the untouched cameras must
also stay where the solve of the same cell without the knock puts them, within a third of its
1-sigma or 0.3 mm (the knock must not drag them), and the knock must add no note about the robot's
accuracy or the board's print scale to what the solve of the still cell says."""

import dataclasses
import json
from types import SimpleNamespace

import numpy as np
import pytest

from calibgraph.core.errors import CalibgraphError
from calibgraph.core.transforms import pose_error
from calibgraph.sim.synthetic_corners import bump_camera, correlate_corner_noise, make_scene, ring_cameras
from calibgraph.solver.solve.batch import solve
from calibgraph.solver.solve.batch import solve_once
from calibgraph.solver.changes.moved import find_moves_live

FK = dict(fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=np.radians(0.01))  # 0.1 mm, 0.01 deg


def _at(cam, T_true, k=3.0):
    err = np.abs(1e3 * (cam.T_ref_cam[:3, 3] - T_true[:3, 3]))
    _, e_deg = pose_error(cam.T_ref_cam, T_true)
    return bool(np.all(err <= k * cam.sigma_translation_mm) and e_deg <= k * np.linalg.norm(cam.sigma_rotation_deg))


def _moved_notes(res):
    return [x for x in res.notes if "moved" in x]


def _check_knock(scene, prob, res, victim, T_after, at, clean=None):
    caps = sorted(d.capture for d in scene.problem.detections if d.camera == victim)
    notes = _moved_notes(res)
    assert len(notes) == 1 and notes[0].startswith(f"camera {victim} moved"), res.notes
    before, after = max(c for c in caps if c < at), min(c for c in caps if c >= at)
    assert f"between captures {before} and {after}" in notes[0]
    def robot_notes(r):  # what the solve says about the robot
        return [x.split(":")[0] for x in r.notes if x.startswith("robot:")]

    assert robot_notes(res) == (robot_notes(clean) if clean is not None else []), res.notes
    if clean is not None:
        # the knock does not drag the board's scale (compared as numbers: a 'printed at' note flips
        # when the clean estimate sits at its 3-sigma threshold, as seed 4's does at 2.95-3.05)
        assert abs(res.board_scale - clean.board_scale) < clean.board_scale_sigma, (res.board_scale, clean.board_scale)
    else:
        assert not any("printed at" in x for x in res.notes), res.notes
    cam = res.cameras[victim]
    assert cam.moved["capture"] == after and cam.moved["last_capture_before"] == before
    n_after = sum(1 for c in caps if c >= after)
    if n_after < prob.options.min_views_per_camera:  # too few to solve it as it now stands: said, not guessed
        assert not cam.calibrated and f"moved after capture {before}? only {n_after} view" in cam.why
    else:
        assert _at(cam, T_after), pose_error(cam.T_ref_cam, T_after)
        assert cam.views_used == n_after
    if cam.moved["T_before"] is not None:  # the pose before the move, with its own 1-sigma
        from calibgraph.solver.output.result import CameraResult

        before_cam = CameraResult(victim, cam.ref_frame, cam.moved["T_before"], cam.moved["covariance_before"], 0, 0, 0)
        assert _at(before_cam, scene.truth.T_ref_cam[victim])
    for name in scene.truth.T_ref_cam:
        if name == victim:
            continue
        assert _at(res.cameras[name], scene.truth.T_ref_cam[name]), name
        if clean is not None:
            d_m, _ = pose_error(res.cameras[name].T_ref_cam, clean.cameras[name].T_ref_cam)
            limit_mm = max(0.3, np.linalg.norm(clean.cameras[name].sigma_translation_mm) / 3)
            assert 1e3 * d_m <= limit_mm, (name, 1e3 * d_m)


@pytest.mark.parametrize("knock", ["5 mm", "0.2 deg"])
def test_knocked_after_capture_18_of_36_is_named_and_split(knock):
    """The issue's target: 3 cameras, 36 poses, one camera moved after capture 18."""
    scene = make_scene(n_poses=36, seed=0, **FK)
    shift, rot = (0.005, 0.0) if knock == "5 mm" else (0.0, 0.2)
    prob, T_after = bump_camera(scene, "cam0", 18, shift, rot_deg=rot, seed=0)
    res = solve(prob)
    _check_knock(scene, prob, res, "cam0", T_after, 18, clean=solve(scene.problem))
    m = res.cameras["cam0"].moved
    true_mm = 1e3 * np.linalg.norm(T_after[:3, 3] - scene.truth.T_ref_cam["cam0"][:3, 3])
    assert abs(m["displacement_mm"] - true_mm) <= 3 * m["sigma_displacement_mm"] + 0.3, (m["displacement_mm"], true_mm)


@pytest.mark.parametrize("victim", ["cam0", "cam1", "cam2"])
def test_the_knocked_camera_is_named_when_every_camera_sees_every_pose(victim):
    """With every view shared, the other cameras see the robot poses the knocked camera pulls on;
    the test must still name the camera that moved (was: the wrong one in 3 of 6 seeds)."""
    scene = make_scene(cameras=ring_cameras([1.5, 2.0, 2.5], spread_deg=60), tilt_deg=20, n_poses=36, seed=3, **FK)
    assert all(sum(d.capture == k for d in scene.problem.detections) == 3 for k in range(36))
    prob, T_after = bump_camera(scene, victim, 18, 0.005, seed=3)
    _check_knock(scene, prob, solve(prob), victim, T_after, 18)


@pytest.mark.parametrize("case", ["20 mm half-way", "20 mm at 20 %", "1 deg at 80 %"])
def test_large_knocks_are_named_not_rejected(case):
    """A 20 mm knock used to end in 'all views rejected ... check its intrinsics'."""
    shift, rot, at = {"20 mm half-way": (0.02, 0.0, 18), "20 mm at 20 %": (0.02, 0.0, 7),
                      "1 deg at 80 %": (0.0, 1.0, 29)}[case]
    scene = make_scene(n_poses=36, seed=4, **FK)
    prob, T_after = bump_camera(scene, "cam1", at, shift, rot_deg=rot, seed=4)
    _check_knock(scene, prob, solve(prob), "cam1", T_after, at, clean=solve(scene.problem))


def test_knock_with_correlated_corner_noise_is_named():
    scene = make_scene(n_poses=36, seed=5, **FK)
    prob, T_after = bump_camera(scene, "cam0", 18, 0.005, seed=5)
    prob = correlate_corner_noise(prob, 5.0, seed=5)
    res = solve(prob)
    notes = _moved_notes(res)
    assert len(notes) == 1 and notes[0].startswith("camera cam0 moved"), res.notes
    assert _at(res.cameras["cam0"], T_after)


@pytest.mark.parametrize("seed", range(4))
def test_no_move_reported_on_a_still_cell(seed):
    """FK noise 0.1 mm / 0.01 deg (seeds 0, 1) or 1 mm / 0.03 deg stated as such (2), and corner noise
    correlated within each view at 10x the corner variance (1, 3): nothing is said, nothing set aside."""
    fk = dict(fk_sigma_translation_m=1e-3, fk_sigma_rotation_rad=5e-4) if seed == 2 else FK
    scene = make_scene(n_poses=36, seed=20 + seed, **fk)
    prob = correlate_corner_noise(scene.problem, 10.0, seed) if seed % 2 else scene.problem
    res = solve(prob)
    assert not _moved_notes(res), res.notes
    assert all(c.moved is None for c in res.cameras.values())
    assert not [rv for rv in res.rejected_views if "move" in rv.reason]


def test_too_few_views_after_the_move_leave_the_camera_not_calibrated_and_say_why():
    scene = make_scene(n_poses=30, seed=1, **FK)
    caps = sorted(d.capture for d in scene.problem.detections if d.camera == "cam0")
    prob, _ = bump_camera(scene, "cam0", caps[-2], 0.02, seed=1)
    res = solve(prob)
    cam = res.cameras["cam0"]
    assert not cam.calibrated and "moved during capture" in cam.why and "only 2 views after" in cam.why
    assert cam.moved["views_after"] == 2 and cam.moved["T_before"] is not None
    assert _at(type(cam)("cam0", "base", cam.moved["T_before"], cam.moved["covariance_before"], 0, 0, 0),
               scene.truth.T_ref_cam["cam0"])
    notes = _moved_notes(res)
    assert len(notes) == 1 and notes[0].startswith("camera cam0 moved") and "cannot be calibrated" in notes[0]
    for name in ("cam1", "cam2"):
        assert _at(res.cameras[name], scene.truth.T_ref_cam[name])


def test_moved_in_result_json(tmp_path):
    scene = make_scene(n_poses=36, seed=0, **FK)
    prob, _ = bump_camera(scene, "cam0", 18, 0.005, seed=0)
    res = solve(prob)
    d = json.loads(res.save(tmp_path / "r.json").read_text())
    m = d["cameras"]["cam0"]["moved"]
    assert m["capture"] == res.cameras["cam0"].moved["capture"]
    assert np.asarray(m["T_base_cam_before"]).shape == (4, 4) and np.asarray(m["covariance_before"]).shape == (6, 6)
    assert set(d["cameras"]) == {"cam0", "cam1", "cam2"} and all("before" not in k for k in d["camera_pairs"])
    assert "moved" not in d["cameras"]["cam1"]
    import yaml

    moved = res.to_dict()["cameras"]["cam0"]["moved"]  # plain types: result.yaml can hold it
    assert yaml.safe_load(yaml.safe_dump(moved))["capture"] == m["capture"]


def test_solve_once_does_not_look_for_moves():
    """The test runs in ``solve`` only; ``solve_once`` is the plain solve."""
    scene = make_scene(n_poses=36, seed=0, **FK)
    prob, _ = bump_camera(scene, "cam0", 18, 0.005, seed=0)
    assert not _moved_notes(solve_once(prob))


def test_live_test_against_a_stored_result():
    """``find_moves_live``: the fresh views of a cell judged against its calibration (verify, capture)."""
    scene = make_scene(n_poses=36, seed=6, **FK)
    stored = solve(scene.problem)
    prob, _ = bump_camera(scene, "cam2", 18, 0.005, seed=6)
    moves = find_moves_live(prob, stored)
    assert [m.camera for m in moves] == ["cam2"] and moves[0].first_after >= 18 > moves[0].last_before
    assert find_moves_live(scene.problem, stored) == []
    # a live estimate (what IncrementalSolver.add_capture returns): poses and mount, no pixel sigma
    live = SimpleNamespace(cameras={n: SimpleNamespace(T_ref_cam=c.T_ref_cam) for n, c in stored.cameras.items()},
                           T_mount_board=stored.T_mount_board)
    assert [m.camera for m in find_moves_live(prob, live)] == ["cam2"]
    assert find_moves_live(scene.problem, live) == []
    stored_json = json.loads(json.dumps(stored.to_dict()))  # result.json, as verify reads it
    assert [m.camera for m in find_moves_live(prob, stored_json)] == ["cam2"]
    assert find_moves_live(scene.problem, stored_json) == []


def test_absurd_intrinsics_do_not_crash_the_test():
    """fx = fy = 1e9 gave a cv2.error traceback from the old moved-camera test."""
    scene = make_scene(n_poses=24, seed=0, **FK)
    cams = {}
    for n, c in scene.problem.cameras.items():
        K = c.K.copy()
        K[0, 0] = K[1, 1] = 1e9
        cams[n] = dataclasses.replace(c, K=K)
    prob = scene.problem.with_(cameras=cams)
    stored = solve(scene.problem)
    assert find_moves_live(prob, stored) == []
    try:
        solve(prob)
    except CalibgraphError as e:
        assert "\n" not in str(e).strip() or len(str(e)) < 2000


def test_an_initial_guess_without_the_pose_before_the_move():
    """``solve(..., initial=...)`` names the cameras of the dataset; the split adds one it cannot name."""
    scene = make_scene(n_poses=36, seed=0, **FK)
    prob, T_after = bump_camera(scene, "cam0", 18, 0.005, seed=0)
    res = solve(prob, initial={"T_ref_cam": dict(scene.truth.T_ref_cam), "T_mount_board": scene.truth.T_mount_board})
    assert [x.split()[1] for x in _moved_notes(res)] == ["cam0"] and _at(res.cameras["cam0"], T_after)


@pytest.mark.parametrize("shift", [0.02, 0.005])
def test_a_move_before_the_last_view_is_not_answered_with_the_old_pose(shift):
    """Issue 34: a camera knocked before its last view (one view after the move): that view used to be
    dropped as an outlier and the old pose reported, 21 mm from where the camera stands at 6.6 sigma.
    One view cannot be told from one bad view, so the camera is not calibrated, asking 'moved after
    capture k?'; its pose before, from the views before, is kept in ``moved``."""
    scene = make_scene(n_poses=36, seed=11, **FK)
    caps = sorted({d.capture for d in scene.problem.detections if d.camera == "cam2"})
    prob, _ = bump_camera(scene, "cam2", caps[-1], shift, seed=11)
    res = solve(prob)
    cam = res.cameras["cam2"]
    assert not cam.calibrated and cam.T_ref_cam is None, cam
    assert f"moved after capture {caps[-2]}? only 1 view after (capture {caps[-1]})" in cam.why, cam.why
    assert cam.moved["views_after"] == 1 and cam.moved["views_before"] == len(caps) - 1
    assert _at(type(cam)("cam2", "base", cam.moved["T_before"], cam.moved["covariance_before"], 0, 0, 0),
               scene.truth.T_ref_cam["cam2"])
    for name in ("cam0", "cam1"):
        assert _at(res.cameras[name], scene.truth.T_ref_cam[name]), name


def test_a_camera_moved_and_moved_back_is_named_with_the_span():
    """Issue 34: a camera knocked and put back 6 views later: its views in between used to be dropped
    as outliers without a word. Now the move is named with both cuts, those views are set aside with
    the reason, and the camera is calibrated from the views before and after the span."""
    scene = make_scene(n_poses=36, seed=12, **FK)
    caps = sorted({d.capture for d in scene.problem.detections if d.camera == "cam0"})
    prob, _ = bump_camera(scene, "cam0", caps[4], 0.01, seed=12, back_at_capture=caps[10])
    res = solve(prob)
    notes = _moved_notes(res)
    assert len(notes) == 1, res.notes
    assert notes[0].startswith(f"camera cam0 moved during capture, between captures {caps[3]} and {caps[4]} and back "
                               f"between captures {caps[9]} and {caps[10]}"), notes[0]
    cam = res.cameras["cam0"]
    assert cam.calibrated and _at(cam, scene.truth.T_ref_cam["cam0"])
    assert cam.views_used == len(caps) - 6
    assert sorted(rv.capture for rv in cam.views_rejected if "while it was moved" in rv.reason) == caps[4:10]
    m = cam.moved
    assert (m["capture"], m["back_capture"], m["views_while_moved"]) == (caps[4], caps[10], 6)
    assert abs(m["displacement_mm"] - 10.0) <= 3 * m["sigma_displacement_mm"] + 0.5, m
    for name in ("cam1", "cam2"):
        assert _at(res.cameras[name], scene.truth.T_ref_cam[name]), name


def test_one_bad_view_in_the_middle_is_not_a_move():
    """A single view off in the middle of the capture (a bad detection, not a move: the views after it
    agree with those before) is an outlier, not a move and back."""
    scene = make_scene(n_poses=36, seed=13, **FK)
    caps = sorted({d.capture for d in scene.problem.detections if d.camera == "cam1"})
    prob, _ = bump_camera(scene, "cam1", caps[5], 0.02, seed=13, back_at_capture=caps[6])
    res = solve(prob)
    assert not _moved_notes(res), res.notes
    assert res.cameras["cam1"].calibrated and _at(res.cameras["cam1"], scene.truth.T_ref_cam["cam1"])


@pytest.mark.parametrize("seed", [11, 14])
def test_a_noisy_last_view_is_not_a_move(seed):
    """The camera's last view with its corners scattered 5x the others' (a blurred, edge-on or badly
    fitted board, not a move: the camera stands still). The move test weighs each view at the
    scatter of its corners about its own best pose, so that view's pose is not read as a move before
    it and the camera is calibrated; a knocked camera's views fit their own pose and keep their weight
    (test_a_move_before_the_last_view_is_not_answered_with_the_old_pose). Before, that one noisy view
    left the camera not calibrated ('moved after capture k?')."""
    scene = make_scene(n_poses=36, seed=seed, **FK)
    caps = sorted({d.capture for d in scene.problem.detections if d.camera == "cam2"})
    rng = np.random.default_rng(seed)
    dets = tuple(dataclasses.replace(d, uv_px=d.uv_px + rng.normal(scale=1.5, size=d.uv_px.shape))
                 if (d.camera, d.capture) == ("cam2", caps[-1]) else d for d in scene.problem.detections)
    res = solve(scene.problem.with_(detections=dets))
    assert not _moved_notes(res), res.notes
    assert all(c.calibrated for c in res.cameras.values())
    assert _at(res.cameras["cam2"], scene.truth.T_ref_cam["cam2"])


def test_a_still_camera_sharing_the_knocked_ones_captures_is_not_named():
    """Every camera sees every pose; cam2 turned by 0.2 deg half-way. cam2's views after the knock pull the
    robot poses of the captures they share, and cam1, tested against those poses, showed a move too, at a
    higher F: it was split first and named as moved (bench_moved, shared layout, one trial in six; two
    of the rendered cell's knocks). Of several cameras showing a move, the one whose views, left out of
    the robot poses, take the others' moves away is split first: only cam2 is named."""
    seed = 50052
    scene = make_scene(cameras=ring_cameras([1.5, 2.0, 2.5], spread_deg=60), tilt_deg=20, n_poses=36, seed=seed,
                       reported_intrinsics="factory", **FK)
    prob, T_after = bump_camera(scene, "cam2", 18, 0.0, rot_deg=0.2, seed=seed)
    res = solve(prob)
    assert [x.split()[1] for x in _moved_notes(res)] == ["cam2"], res.notes
    assert _at(res.cameras["cam2"], T_after)
    for name in ("cam0", "cam1"):
        assert res.cameras[name].calibrated and not res.cameras[name].moved
