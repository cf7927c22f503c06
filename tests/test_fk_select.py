"""The robot's error split chosen by held-out captures, and the folds' jackknife (solver/robot/fk_select.py)."""

from dataclasses import replace

import gtsam
import numpy as np
import pytest

import calibgraph.solver.robot.fk_select as fk_select
from calibgraph.core.camera import preset
from calibgraph.core.problem import Capture, Problem, SolverOptions
from calibgraph.core.transforms import make_T
from calibgraph.sim.kinematic_scene import make_kinematic_scene
from calibgraph.sim.synthetic_corners import make_scene
from calibgraph.solver.solve.batch import solve
from calibgraph.solver.solve import optimise
from calibgraph.solver.robot.fk_check import FkComponent, FkRatio, fk_note, fk_record
from calibgraph.solver.fit.graph import Estimate
from calibgraph.solver.terms.views import View


def _view(cam, k):
    return View(camera=cam, capture=k, ids=np.arange(4), p_board_m=np.zeros((4, 3)), uv_px=np.zeros((4, 2)),
                T_ref_mount=np.eye(4))


def _problem(n, revisit_every=None):
    """A problem of ``n`` captures at distinct flange poses 10 cm apart (capture k revisits capture
    k - ``revisit_every``'s pose when that is given)."""
    caps = [Capture(index=k, T_base_flange=make_T(np.eye(3), [0.4 + 0.1 * (k % revisit_every if revisit_every else k),
                                                              0.0, 0.5])) for k in range(n)]
    return Problem(points_board_m=np.c_[np.random.default_rng(0).normal(size=(4, 2)), np.zeros(4)],
                   cameras={"a": preset("l515"), "b": preset("l515")}, captures=tuple(caps), detections=())


def test_folds_need_enough_captures_and_views_per_camera():
    views = [_view("a", k) for k in range(12)]
    problem = _problem(12)
    folds = fk_select._folds(problem, views, 3)
    assert len(folds) == fk_select.FOLDS
    assert set().union(*folds) == set(range(12)) and sum(len(f) for f in folds) == 12  # disjoint, all captures
    assert fk_select._folds(problem, views[:9], 3) is None  # fewer than two captures per fold
    # camera b seen in 3 captures only: any fold holding one of them out leaves it 2 views
    assert fk_select._folds(problem, views + [_view("b", k) for k in (0, 1, 2)], 3) is None


def test_a_revisit_is_held_out_with_its_configuration():
    """36 captures of 12 configurations (three sessions of the same targets): each fold holds whole
    configurations, so no held-out capture is predicted from a visit of its own pose."""
    problem = _problem(36, revisit_every=12)
    views = [_view("a", k) for k in range(36)]
    folds = fk_select._folds(problem, views, 3)
    assert len(folds) == fk_select.FOLDS and set().union(*folds) == set(range(36))
    for fold in folds:
        assert {k % 12 for k in fold}.isdisjoint({k % 12 for k in set(range(36)) - fold})
    assert fk_select._folds(_problem(18, revisit_every=9), views[:18], 3) is None  # 9 configurations: too few


def test_one_widened_component_is_not_cross_validated():
    c = FkComponent.of(16.0 * 30, 30.0)
    kept = FkComponent(1.2, 1.0, 30.0, False)

    def never(*_):
        raise AssertionError("no fold may be solved")

    ratio = FkRatio(10.0, 60.0, True, kept, c)
    out, folds = fk_select.cross_validated_split(None, None, ratio, [], None, never)
    assert out is ratio and out.cross_validation is None and folds is None


def test_jackknife_factor_is_the_folds_scatter_over_the_covariance():
    rng = np.random.default_rng(3)
    T = gtsam.Pose3(gtsam.Rot3.RzRyRx(0.1, -0.2, 0.3), gtsam.Point3(1.0, 2.0, 3.0)).matrix()
    d = rng.normal(scale=1e-3, size=(fk_select.FOLDS, 6))
    est = Estimate(T_ref_cam={"c": T}, T_mount_board=np.eye(4), T_ref_mount={})
    folds = [replace(est, T_ref_cam={"c": gtsam.Pose3(T).retract(x).matrix()}) for x in d]
    sigma2 = 2e-7
    f, per = fk_select.jackknife_factor(est, folds, lambda n: np.eye(6) * sigma2)
    dc = d - d.mean(axis=0)
    want = (fk_select.FOLDS - 1) / fk_select.FOLDS * np.sum(dc ** 2) / (6 * sigma2)
    assert per["c"] == pytest.approx(want, rel=1e-6)
    assert f == pytest.approx(max(1.0, want), rel=1e-6)
    # the graph's covariance already covers the scatter: no factor below 1
    assert fk_select.jackknife_factor(est, folds, lambda n: np.eye(6) * 1.0)[0] == 1.0


def test_robot_as_stated_leaves_the_solve_as_it_was():
    sc = make_scene(n_poses=24, pixel_sigma_px=0.1, seed=2, reported_intrinsics="exact")
    r = solve(sc.problem)
    assert r.fk_noise is None or "cross_validation" not in r.fk_noise


@pytest.mark.parametrize("seed", [1, 2])
def test_unmodelled_joint_offsets_the_folds_make_the_sigma_more_honest(seed, monkeypatch):
    """Joint zero offsets of 0.5-2 mrad, not estimated: an error that repeats from pose to pose.
    Cross-validated and with the folds' jackknife the cameras' error / 1-sigma is closer to 1 than
    the per-pose FK model alone gives (which understates it), and the error itself no larger."""
    rng = np.random.default_rng(1000 + seed)
    offsets = np.zeros(7)
    offsets[1:6] = rng.uniform(0.5e-3, 2e-3, 5) * rng.choice([-1, 1], 5)
    sc = make_kinematic_scene(offsets, n_poses=30, seed=seed, pixel_sigma_px=0.1)[0]
    # the per-pose FK model asked for: the default would estimate the offsets (test_kinematics_auto.py)
    sc = replace(sc, problem=sc.problem.with_(options=replace(sc.problem.options, kinematics="none")))

    def errors(r):
        e = np.concatenate([1e3 * (c.T_ref_cam[:3, 3] - sc.truth.T_ref_cam[n][:3, 3]) for n, c in r.cameras.items()])
        z = np.concatenate([1e3 * (c.T_ref_cam[:3, 3] - sc.truth.T_ref_cam[n][:3, 3]) / np.asarray(c.sigma_translation_mm)
                            for n, c in r.cameras.items()])
        return float(np.sqrt(np.mean(e ** 2))), float(np.sqrt(np.mean(z ** 2)))

    r_cv = solve(sc.problem)
    cv = r_cv.fk_noise["cross_validation"]
    rms = cv["rms_px"]
    best = min(rms, key=rms.get)
    assert cv["chosen"] == (best if rms[best] < (1 - fk_select.TIE) * rms["both"] else "both")
    assert cv["jackknife_variance_factor"] > 1.0
    assert any("folds' camera poses scatter" in n for n in r_cv.notes)
    monkeypatch.setattr(fk_select, "_folds", lambda *a, **k: None)  # the path before: Helmert's split, no folds
    r_old = solve(sc.problem)
    assert "cross_validation" not in r_old.fk_noise
    (e_cv, z_cv), (e_old, z_old) = errors(r_cv), errors(r_old)
    assert z_old > 1.5  # the per-pose model understates the 1-sigma here
    assert z_cv < z_old
    assert e_cv <= e_old * 1.05


def test_chosen_split_sets_the_sigmas_the_solve_used():
    """Eye-in-hand, the arm's error all translation (0.6 mm) but stated 0.1 mm / 0.01 deg: whichever
    candidate the folds choose, the FK sigmas reported are that candidate's."""
    sc = make_scene(n_poses=30, pixel_sigma_px=0.1, fk_sigma_translation_m=6e-4, mode="eye_in_hand", seed=0,
                    reported_intrinsics="exact", options=SolverOptions())
    r = solve(sc.problem)
    f = r.fk_noise
    cv = f["cross_validation"]
    assert set(cv["rms_px"]) == {"both", "translation", "rotation"}
    stated_r, stated_t = f["stated_sigma_rotation_rad"], f["stated_sigma_translation_m"]
    if cv["chosen"] == "translation":
        assert f["used_sigma_rotation_rad"] == pytest.approx(stated_r) and f["used_sigma_translation_m"] > stated_t
    elif cv["chosen"] == "rotation":
        assert f["used_sigma_translation_m"] == pytest.approx(stated_t) and f["used_sigma_rotation_rad"] > stated_r
    else:
        assert f["used_sigma_translation_m"] > stated_t and f["used_sigma_rotation_rad"] > stated_r


def test_jackknife_alone_when_the_split_is_not_cross_validated(monkeypatch):
    """The robot departs but its split is not cross-validated (one component widened, or the corners'
    correlated noise explained the departure; here the split's folds are switched off): the folds'
    jackknife still runs on the final graph, widens the 1-sigma where the fold solves scatter beyond
    it, and says so; without it the 1-sigma is what the per-pose model gives."""
    rng = np.random.default_rng(1001)
    offsets = np.zeros(7)
    offsets[1:6] = rng.uniform(0.5e-3, 2e-3, 5) * rng.choice([-1, 1], 5)
    sc = make_kinematic_scene(offsets, n_poses=30, seed=1, pixel_sigma_px=0.1)[0]
    sc = replace(sc, problem=sc.problem.with_(options=replace(sc.problem.options, kinematics="none")))
    monkeypatch.setattr(optimise, "cross_validated_split", lambda problem, opts, ratio, *a: (ratio, None))
    r = solve(sc.problem)
    cv = r.fk_noise["cross_validation"]
    assert cv["chosen"] is None and cv["folds"] == fk_select.FOLDS and "rms_px" not in cv
    assert cv["jackknife_applied"] == cv["jackknife_variance_factor"] > 1.0  # the robot widened: the factor stands
    assert any("folds' camera poses scatter" in n for n in r.notes)
    assert not any("held-out RMS" in n for n in r.notes)
    monkeypatch.setattr(fk_select, "_folds", lambda *a, **k: None)
    r_old = solve(sc.problem)
    assert "cross_validation" not in r_old.fk_noise
    for n, c in r.cameras.items():
        # the pixel and FK noises take the factor; the intrinsics' prior does not, so a camera's 1-sigma
        # grows by up to its square root
        ratio = np.asarray(c.sigma_translation_mm) / np.asarray(r_old.cameras[n].sigma_translation_mm)
        assert np.all(ratio > 1.02) and np.all(ratio <= np.sqrt(cv["jackknife_applied"]) * 1.02)


def test_jackknife_note_and_record_with_the_robot_kept_as_stated():
    opts = SolverOptions()
    jk = {"folds": 5, "jackknife_variance_factor": 4.0, "jackknife_applied": 4.0, "jackknife_per_camera": {"a": 4.0}}
    note = fk_note(opts, None, jk)
    assert len(note) == 1 and "kept at its stated accuracy" in note[0] and "x2.00" in note[0]
    assert fk_note(opts, None, {**jk, "jackknife_variance_factor": 1.3, "jackknife_applied": 1.0}) == []
    assert fk_note(opts, None, None) == []
    rec = fk_record(opts, None, jk)
    assert rec["used_sigma_translation_m"] == rec["stated_sigma_translation_m"] == opts.fk_sigma_translation_m
    assert rec["cross_validation"]["chosen"] is None and rec["cross_validation"]["jackknife_variance_factor"] == 4.0
    assert fk_record(opts, None, None) is None
    # one component widened, no split chosen: the note gives the jackknife, not a held-out comparison
    comp = FkComponent(ratio=9.0, applied=9.0, dof=20.0, significant=True)
    kept = FkComponent(ratio=1.5, applied=1.0, dof=20.0, significant=False)
    ratio = FkRatio(4.0, 40.0, True, rotation=kept, translation=comp,
                    cross_validation={"folds": 5, "chosen": None, **jk})
    (line,) = fk_note(opts, ratio, jk)
    assert "translation 3.0x" in line and "rotation within" in line and "held-out" not in line and "x2.00" in line


def test_robot_note_offers_joint_offsets_only_where_the_captures_have_joint_angles():
    """The note's remedy for an arm less accurate than stated: --estimate-kinematics joint-offsets where
    the captures record joint angles; where they do not (RWHE-Calib's sets, poses only) it says the
    angles are needed; with the offsets estimated already it does not offer them again."""
    comp = FkComponent(ratio=9.0, applied=9.0, dof=20.0, significant=True)
    ratio = FkRatio(9.0, 40.0, True, rotation=comp, translation=comp)
    (with_q,) = fk_note(SolverOptions(kinematics="none"), ratio, None, joint_angles=True)
    (without_q,) = fk_note(SolverOptions(), ratio, None, joint_angles=False)
    (estimated,) = fk_note(SolverOptions(kinematics="joint-offsets"), ratio, None, joint_angles=True)
    (auto,) = fk_note(SolverOptions(), ratio, None, joint_angles=True)  # the default tries them: its note says how
    assert "--estimate-kinematics joint-offsets" in with_q and "q_rad" not in with_q
    assert "needs the joint angles (q_rad)" in without_q
    assert "estimated already" in estimated
    assert "see the note on them below" in auto and "--estimate-kinematics" not in auto
    assert all("--fk-sigma-mm" in n for n in (with_q, without_q, estimated, auto))


def test_jackknife_folds_not_made_with_too_few_captures():
    def never(*a):
        raise AssertionError("no fold may be solved")

    p = make_scene(n_poses=6, pixel_sigma_px=0.1, seed=0, reported_intrinsics="exact").problem
    assert fk_select.jackknife_folds(p, [_view("a", k) for k in range(5)], None, never) is None


def test_jackknife_of_a_small_set_holds_out_one_configuration_at_a_time():
    """6-9 configurations (ViSP's 8 poses): one fold each; fewer than 6: none."""
    p = _problem(8)
    folds = fk_select._folds(p, [_view("a", k) for k in range(8)], 3, small=True)
    assert sorted(len(f) for f in folds) == [1] * 8 and set().union(*folds) == set(range(8))
    assert fk_select._folds(p, [_view("a", k) for k in range(8)], 3) is None  # not for the FK split's cross-validation
    assert fk_select._folds(_problem(5), [_view("a", k) for k in range(5)], 3, small=True) is None


def test_jackknife_applied_only_beyond_chance_with_the_robot_as_stated():
    """With the robot kept at its stated accuracy a camera's factor scatters 0.4-1.7 when the per-pose
    model is right (24 dof at 5 folds): below the one-sided 5 % point (about 1.6) the 1-sigma is left
    as the graph gives it."""
    assert fk_select.jackknife_applied(1.3, 5, False) == 1.0
    assert fk_select.jackknife_applied(0.7, 5, False) == 1.0
    assert fk_select.jackknife_applied(2.0, 5, False) == 2.0
    rng = np.random.default_rng(0)  # honest folds: chi2(24)/24 applied in about 5 % of solves
    f = rng.chisquare(24, 4000) / 24
    assert 0.03 < np.mean([fk_select.jackknife_applied(x, 5, False) > 1 for x in f]) < 0.07
    # the robot's prior widened: the model is known wrong, the folds' factor stands (at least 1)
    assert fk_select.jackknife_applied(1.3, 5, True) == 1.3
    assert fk_select.jackknife_applied(0.7, 5, True) == 1.0
