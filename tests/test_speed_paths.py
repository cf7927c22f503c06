"""Fast paths of the solve give the slow path's answer (issue 36).

The re-solve of cameras whose data reject their given intrinsics (``widen_inadequate_intrinsics``)
starts from the first solve's values and robust weights instead of screening afresh from the given
intrinsics. It must land on the same fixed point: the same estimates within 0.05 sigma, the same
1-sigma, the same notes and the same convergence, on scenes where the re-solve happens (factory-class
reported intrinsics labelled as a calibration file's), with and without views the rounds reject.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import calibgraph.solver.solve.camera_model as camera_model
from calibgraph.core.transforms import pose_error
from calibgraph.sim.synthetic_corners import make_scene, ring_cameras
from calibgraph.solver.solve.batch import solve


def _scene(n_cam: int, n_poses: int, seed: int, preset: str, pixel_sigma_px: float, corrupt: int = 0):
    sc = make_scene(cameras=ring_cameras([3.0] * n_cam, presets=(preset,)), n_poses=n_poses,
                    pixel_sigma_px=pixel_sigma_px, fk_sigma_translation_m=1e-4,
                    fk_sigma_rotation_rad=np.radians(0.01), seed=seed, workspace_half_extent_m=(0.4, 0.4, 0.4))
    p = sc.problem.with_(cameras={n: replace(c, source="calibration") for n, c in sc.problem.cameras.items()})
    if corrupt:  # a few views whose corners are off by several pixels: the rounds set them aside
        rng = np.random.default_rng(seed)
        dets = list(p.detections)
        for i in rng.choice(len(dets), corrupt, replace=False):
            d = dets[i]
            dets[i] = replace(d, uv_px=d.uv_px + rng.normal(0.0, 4.0, d.uv_px.shape))
        p = p.with_(detections=tuple(dets))
    return p


def _both(monkeypatch, problem):
    monkeypatch.setattr(camera_model, "WARM_RESOLVE", False)
    slow = solve(problem)
    monkeypatch.setattr(camera_model, "WARM_RESOLVE", True)
    fast = solve(problem)
    return slow, fast


@pytest.mark.parametrize("n_cam,n_poses,seed,preset,px,corrupt", [
    (4, 60, 1, "l515", 0.1, 0),     # issue 36's realistic case, small
    (4, 80, 2, "l515", 0.2, 4),     # another draw, noisier corners, four corrupted views
])
def test_warm_widened_resolve_gives_the_fresh_answer(monkeypatch, n_cam, n_poses, seed, preset, px, corrupt):
    slow, fast = _both(monkeypatch, _scene(n_cam, n_poses, seed, preset, px, corrupt))
    # the re-solve happened (else nothing was compared)
    assert any("the data disagree with its given" in n for n in slow.notes), slow.notes
    assert fast.notes == slow.notes
    assert fast.converged == slow.converged
    assert set(fast.calibrated) == set(slow.calibrated)
    assert {(r.camera, r.capture) for r in fast.rejected_views} == {(r.camera, r.capture) for r in slow.rejected_views}
    for n, a in slow.calibrated.items():
        b = fast.cameras[n]
        cov = a.covariance  # 6x6, GTSAM tangent order: rotation (rad), translation (m)
        d_rot_rad = np.radians(pose_error(a.T_ref_cam, b.T_ref_cam)[1])
        d_t = b.T_ref_cam[:3, 3] - a.T_ref_cam[:3, 3]
        assert np.all(np.abs(1e3 * d_t) <= 0.05 * np.asarray(a.sigma_translation_mm)), n
        assert d_rot_rad <= 0.05 * np.sqrt(np.trace(cov[:3, :3])), n
        np.testing.assert_allclose(b.sigma_translation_mm, a.sigma_translation_mm, rtol=0.01)
    assert abs(fast.board_scale - slow.board_scale) <= 0.05 * (slow.board_scale_sigma or np.inf)


def test_mode_energy_without_qr_equals_the_basis_projection():
    """The corner-noise level's projection on a view's 6 low-order modes, formed without the QR,
    equals the projection on :func:`view_mode_basis` (grids seen at any scale, scattered corners,
    corners on a line, which take the QR)."""
    from calibgraph.solver.terms.noise_model import _mode_energy, view_mode_basis

    rng = np.random.default_rng(0)
    grid = np.stack(np.meshgrid(np.arange(9.0), np.arange(6.0)), -1).reshape(-1, 2)
    cases = [grid * rng.uniform(3, 40) + rng.uniform(0, 900, 2) for _ in range(50)]
    cases += [rng.uniform(0, 1000, (int(rng.integers(6, 80)), 2)) for _ in range(50)]
    H = np.array([[0.9, 0.1, 200.0], [-0.05, 1.1, 100.0], [1e-4, 2e-4, 1.0]])  # a tilted board's image
    g = np.c_[grid, np.ones(len(grid))] @ H.T
    cases += [g[:, :2] / g[:, 2:], np.c_[np.arange(10.0), 2 * np.arange(10.0) + 1]]
    for uv in cases:
        e = rng.normal(0.0, 0.3, 2 * len(uv))
        q = view_mode_basis(uv).T @ e
        assert abs(_mode_energy(uv, e) - float(q @ q)) <= 1e-12 * float(e @ e)


def test_candidate_sigmas_by_woodbury_equal_the_full_inverse():
    """The active planner's predicted 1-sigma of each candidate, from today's covariance and the
    columns the candidate informs (Woodbury), equals the inverse of the whole information with the
    candidate's added: 16 cameras on a ring, every camera model estimated, candidates seen by 0 to 8
    cameras (one seen by none)."""
    from calibgraph.plan.information import (block_sigmas, block_sigmas_added, inv_scaled, joint_information,
                                             prior_information)

    K = 16
    sc = make_scene(cameras=ring_cameras([3.0] * K, presets=("l515",)), n_poses=60, seed=1,
                    workspace_half_extent_m=(0.4, 0.4, 0.4))
    names = list(sc.problem.cameras)
    cams = [(sc.problem.cameras[n], sc.truth.T_ref_cam[n]) for n in names]
    by_capture = {}
    for d in sc.problem.detections:
        by_capture.setdefault(d.capture, set()).add(d.camera)
    T_bf = np.array([c.T_base_flange for c in sc.problem.captures])
    seen = np.array([[n in by_capture.get(c.index, ()) for n in names] for c in sc.problem.captures])
    seen[-1] = False
    pts, free = sc.problem.target.points_board_m, [True] * K
    args = (pts, 0.1, 1e-4, np.radians(0.01))
    T_fb = sc.truth.T_mount_board
    J0 = prior_information(K, [np.eye(6) * 1e-2] * K) + joint_information(
        cams, seen[:30], T_bf[:30], T_fb, *args, free_intrinsics=free).sum(axis=0)
    infos = joint_information(cams, seen[30:], T_bf[30:], T_fb, *args, free_intrinsics=free)
    full = block_sigmas(inv_scaled(J0 + infos), K)
    fast = block_sigmas_added(J0, infos, K)
    np.testing.assert_allclose(fast, full, rtol=1e-9)
    np.testing.assert_allclose(block_sigmas_added(J0, infos, K, inv_scaled(J0)), full, rtol=1e-9)


def test_openblas_one_thread_unless_the_user_says(tmp_path):
    """``import calibgraph`` (what the CLI does first) holds OpenBLAS to one thread when the user
    did not set OPENBLAS_NUM_THREADS, and leaves the user's setting alone."""
    import os
    import subprocess
    import sys

    code = "import calibgraph, os; print(os.environ.get('OPENBLAS_NUM_THREADS'))"
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "1"
    out = subprocess.run([sys.executable, "-c", code], env=dict(env, OPENBLAS_NUM_THREADS="2"), capture_output=True,
                         text=True, check=True)
    assert out.stdout.strip() == "2"


def _solved_graph(monkeypatch, problem):
    """(graph, values) of the final graph of ``problem``'s solve (the one its marginals come from)."""
    import calibgraph.solver.fit.graph as graph_mod

    seen = []
    real = graph_mod.linearise_graph

    def spy(graph, values):
        seen.append((graph, values))
        return real(graph, values)

    monkeypatch.setattr(graph_mod, "linearise_graph", spy)
    solve(problem)
    return seen[-1]


def test_reduced_linearisation_equals_the_dense_elimination(monkeypatch):
    """The Schur reduction formed by sources and all locals at once (:func:`linearise_graph`) equals
    the dense elimination of the whole linearised system: the global information and gradient, the
    information with each source scaled (the error budget's), covariance columns with the robot
    poses' rows, and a robot pose's marginal; on a 3-camera cell whose intrinsics and board scale
    are estimated (the factory-class case, every source present)."""
    import gtsam

    from calibgraph.solver.terms.reduced import SOURCES, _source, columns, linearise_graph

    graph, values = _solved_graph(monkeypatch, _scene(3, 24, 4, "l515", 0.2))
    L = linearise_graph(graph, values)
    keys = list(values.keys())
    zero = values.zeroVectors()
    at, n = {}, 0
    for k in keys:
        at[k] = slice(n, n + zero.at(k).shape[0])
        n = at[k].stop
    lin = graph.linearize(values)
    full = {src: np.zeros((n, n)) for src in SOURCES}
    grad = np.zeros(n)
    for i in range(lin.size()):
        f = lin.at(i)
        fk = list(f.keys())
        A, b = f.jacobian()
        cols = np.concatenate([np.arange(at[k].start, at[k].stop) for k in fk])
        full[_source(fk)][np.ix_(cols, cols)] += A.T @ A
        grad[cols] -= A.T @ b
    g_rows = np.concatenate([np.arange(at[k].start, at[k].stop) for k in L.index])
    l_rows = np.setdiff1d(np.arange(n), g_rows)
    assert len(l_rows) == 6 * len(L.locals_) > 0
    assert all(np.abs(full[src]).max() > 0 for src in SOURCES)  # every source is in the graph

    def schur(H):
        Hgl = H[np.ix_(g_rows, l_rows)]
        return H[np.ix_(g_rows, g_rows)] - Hgl @ np.linalg.solve(H[np.ix_(l_rows, l_rows)], Hgl.T)

    H = sum(full.values())
    S = schur(H)
    np.testing.assert_allclose(L.S, S, rtol=1e-9, atol=1e-9 * np.abs(S).max())
    g = grad[g_rows] - H[np.ix_(g_rows, l_rows)] @ np.linalg.solve(H[np.ix_(l_rows, l_rows)], grad[l_rows])
    np.testing.assert_allclose(L.g, g, rtol=1e-7, atol=1e-7 * np.abs(g).max())
    for src in SOURCES:
        scale = {src: 1e3, "corners": 0.5} if src != "corners" else {src: 1e3}
        Ss = schur(sum(scale.get(s, 1.0) * Hs for s, Hs in full.items()))
        np.testing.assert_allclose(L.information(scale), Ss, rtol=1e-9, atol=1e-9 * np.abs(Ss).max())
    cov = np.linalg.inv(H)
    cam = next(k for k in L.index if chr(gtsam.Symbol(k).chr()) == "c")
    X = columns(L, L.S, [(cam, slice(3, 6))])
    for k in keys:
        np.testing.assert_allclose(X[k], cov[at[k], at[cam].start + 3:at[cam].start + 6], rtol=1e-6,
                                   atol=1e-6 * np.abs(cov[:, at[cam]]).max())
    loc = next(iter(L.locals_))
    np.testing.assert_allclose(L.marginals(keys).marginalCovariance(loc), cov[at[loc], at[loc]], rtol=1e-6,
                               atol=1e-9 * np.abs(cov[at[loc], at[loc]]).max())


def test_high_order_of_all_views_at_once_equals_view_by_view():
    """The corners' scatter outside each view's 6 low-order modes, formed for all views at once by
    segment sums (:func:`_high_order_all`), equals :func:`_high_order` view by view: views of a
    tilted grid, scattered corners, corners on a line (the QR), too few corners, an inactive view,
    a view with a non-finite and one with an absurd residual, some corners rejected."""
    from calibgraph.solver.terms.noise_model import _high_order, _high_order_all
    from calibgraph.solver.terms.views import View

    rng = np.random.default_rng(5)
    grid = np.stack(np.meshgrid(np.arange(8.0), np.arange(5.0)), -1).reshape(-1, 2)
    H = np.array([[0.9, 0.1, 200.0], [-0.05, 1.1, 100.0], [1e-4, 2e-4, 1.0]])
    g = np.c_[grid * 20, np.ones(len(grid))] @ H.T
    shapes = [g[:, :2] / g[:, 2:], rng.uniform(0, 1000, (30, 2)), np.c_[np.arange(12.0), 3 * np.arange(12.0) + 5],
              rng.uniform(0, 1000, (5, 2))]
    views, residuals = [], []
    for i in range(40):
        uv = shapes[i % len(shapes)] + rng.normal(0, 0.5, shapes[i % len(shapes)].shape)
        n = len(uv)
        w = np.where(rng.random(n) < 0.9, rng.uniform(0.3, 1.0, n), 0.0)
        r = rng.normal(0, 0.3, (n, 2)) + rng.normal(0, 2.0, 2)
        if i == 7:
            r[0, 0] = np.nan
        if i == 11:
            r[1, 1] = 2e5
        views.append(View(camera=f"c{i % 3}", capture=i, ids=np.arange(n), uv_px=uv, p_board_m=np.zeros((n, 3)),
                          T_ref_mount=np.eye(4), w=w, active=i != 5))
        residuals.append(r)
    pe, pn = _high_order_all(views, residuals)
    for i, (v, r) in enumerate(zip(views, residuals)):
        e_ref, n_ref = _high_order(v, r)
        assert pn[i] == n_ref, i
        assert abs(pe[i] - e_ref) <= 1e-9 * max(e_ref, 1.0), (i, pe[i], e_ref)
    assert (pn > 0).sum() >= 20 and pn[5] == pn[7] == pn[11] == 0


def test_pairwise_rotation_cosines_by_one_product_equal_the_batched_angles():
    """The initialiser's consensus between every pair of candidate rotations, cosines from one
    matrix product of the flattened rotations, equals :func:`_angle_deg` of every pair (near-
    identical, 5 deg apart give or take a little, opposite and random rotations), and so does the
    inlier set its angle limit gives."""
    from calibgraph.core.transforms import exp_so3
    from calibgraph.solver.terms.initialise import ROT_INLIER_DEG, _angle_deg, _pairwise_cos

    rng = np.random.default_rng(2)
    base = [exp_so3(rng.normal(0, 1.0, 3)) for _ in range(30)]
    axis = np.array([0.0, 0.6, 0.8])
    R = np.array(base + [b @ exp_so3(rng.normal(0, 1e-3, 3)) for b in base[:10]]
                 + [b @ exp_so3(np.radians(ROT_INLIER_DEG + d) * axis) for b, d in zip(base[:8], np.linspace(-0.2, 0.2, 8))]
                 + [b @ exp_so3(np.array([np.pi, 0, 0])) for b in base[:5]])
    c = _pairwise_cos(R)
    slow = _angle_deg(R[:, None], R[None, :])
    np.testing.assert_allclose(c, np.cos(np.radians(slow)), atol=1e-12)
    inliers = c > np.cos(np.radians(ROT_INLIER_DEG))
    assert np.array_equal(inliers, slow < ROT_INLIER_DEG)
    assert 0 < (inliers.sum() - len(R)) < len(R) ** 2 / 4


def test_mode_terms_of_views_together_equal_view_by_view():
    """The corner-noise model's per-view terms (squared residual in the 6 image modes, the total,
    the traces of the robot pose's share in the modes and overall) formed for views of equal corner
    counts together equal the view-by-view formulas (:func:`view_mode_basis` per view)."""
    from calibgraph.solver.terms.noise_model import _mode_terms, view_mode_basis
    from calibgraph.solver.terms.views import View

    rng = np.random.default_rng(9)
    per_view, cov = [], {}
    for i in range(30):
        n = (12, 20, 7)[i % 3]
        uv = rng.uniform(0, 1000, (n + 3, 2))
        keep = np.ones(n + 3, bool)
        keep[rng.choice(n + 3, 3, replace=False)] = False
        v = View(camera="c", capture=i // 2, ids=np.arange(n + 3), uv_px=uv, p_board_m=np.zeros((n + 3, 3)),
                 T_ref_mount=np.eye(4), w=keep.astype(float))
        per_view.append((v, keep, rng.normal(0, 1, 2 * n), rng.normal(0, 50, (2 * n, 6))))
        A = rng.normal(0, 1, (6, 6))
        cov[i // 2] = A @ A.T * 1e-6
    got = _mode_terms(per_view, cov)
    for (v, keep, e, H_f), row in zip(per_view, got):
        Q = view_mode_basis(v.uv_px[keep])
        Sk, G, qe = cov[v.capture], H_f.T @ Q, Q.T @ e
        ref = [qe @ qe, e @ e, np.sum(Sk * (G @ G.T)), np.sum(Sk * (H_f.T @ H_f))]
        np.testing.assert_allclose(row, ref, rtol=1e-10)


def _refine_translations_view_by_view(views_by_cam, intr_by_cam, T_ref_cam, T_mount_board, p_by_view, uv_by_view):
    """The per-view formulation of :func:`refine_translations`' normal equations (its code before
    the corners of a camera's views were taken together): (views' AtA, Atb, camera slots)."""
    import cv2

    from calibgraph.solver.terms.initialise import ROT_INLIER_DEG, _angle_deg

    RY = T_mount_board[:3, :3]
    out = []
    for s, n in enumerate(T_ref_cam):
        RZ = T_ref_cam[n][:3, :3]
        for v in views_by_cam[n]:
            err = _angle_deg(RZ @ v.R, (v.T_ref_mount[:3, :3] @ RY)[None]).min() if len(v.R) else np.inf
            if err > ROT_INLIER_DEG:
                continue
            pb, uv = p_by_view[(n, v.capture)], uv_by_view[(n, v.capture)]
            xy = cv2.undistortPoints(uv.reshape(-1, 1, 2).astype(np.float64), intr_by_cam[n].K,
                                     intr_by_cam[n].dist).reshape(-1, 2)
            RA, tA = v.T_ref_mount[:3, :3], v.T_ref_mount[:3, 3]
            q = (pb @ (RA @ RY).T + tA) @ RZ
            MY, MZ = RZ.T @ RA, -RZ.T
            G = np.vstack([np.hstack([xy[:, c, None] * MZ[2] - MZ[c], xy[:, c, None] * MY[2] - MY[c]]) for c in (0, 1)])
            b = np.concatenate([-(xy[:, c] * q[:, 2] - q[:, c]) for c in (0, 1)])
            out.append((G.T @ G, G.T @ b, s))
    return out


def test_refine_translations_all_corners_of_a_camera_at_once(monkeypatch):
    """The initialiser's translation refinement, every corner of a camera's agreeing views at once,
    forms the per-view normal equations of the view-by-view formulation (3 cameras, 20 poses, one
    camera's rotation off so that some of its views disagree) and its solve equals the one from
    those equations."""
    import calibgraph.solver.terms.initialise as ini
    from calibgraph.core.transforms import exp_so3
    from calibgraph.solver.terms.initialise import pnp_candidates, refine_translations

    sc = make_scene(cameras=ring_cameras([2.0, 3.0, 4.0], presets=("l515",)), n_poses=20, pixel_sigma_px=0.3, seed=3)
    prob = sc.problem
    views_by_cam, p_by_view, uv_by_view = {}, {}, {}
    caps = {c.index: c for c in prob.captures}
    for d in prob.detections:
        pb = prob.points_board_m[d.ids]
        R, t, rms = pnp_candidates(pb, d.uv_px, prob.cameras[d.camera])
        views_by_cam.setdefault(d.camera, []).append(
            ini.ViewCandidates(d.camera, d.capture, caps[d.capture].T_base_flange, R, t, rms))
        p_by_view[(d.camera, d.capture)], uv_by_view[(d.camera, d.capture)] = pb, d.uv_px
    T_ref_cam = {n: T.copy() for n, T in sc.truth.T_ref_cam.items()}
    off = next(iter(T_ref_cam))
    T_ref_cam[off][:3, :3] = exp_so3(np.radians([0.0, 4.0, 0.0])) @ T_ref_cam[off][:3, :3]
    args = (views_by_cam, prob.cameras, T_ref_cam, sc.truth.T_mount_board, p_by_view, uv_by_view)
    ref = _refine_translations_view_by_view(*args)
    seen = {}
    real_solve = np.linalg.solve

    def spy(N, r):
        seen.setdefault("N", N)
        return real_solve(N, r)
    monkeypatch.setattr(ini.np.linalg, "solve", spy)
    T_new, M_new = refine_translations(*args)
    monkeypatch.setattr(ini.np.linalg, "solve", real_solve)
    ns = len(T_ref_cam)
    N_ref = np.zeros((3 * ns + 3, 3 * ns + 3))
    for AtA, _, s in ref:
        idx = np.r_[3 * s:3 * s + 3, 3 * ns:3 * ns + 3]
        N_ref[np.ix_(idx, idx)] += AtA
    N = seen["N"]  # the first solve's system (with its weak pull)
    lam = 1e-9 * max(np.trace(N_ref) / len(N_ref), 1e-12)
    np.testing.assert_allclose(N, N_ref + lam * np.eye(len(N_ref)), rtol=1e-9, atol=1e-9 * np.abs(N_ref).max())
    assert 0 < len(ref) < sum(len(v) for v in views_by_cam.values())  # some views left out, most in
    for n in T_ref_cam:
        assert np.linalg.norm(T_new[n][:3, 3] - sc.truth.T_ref_cam[n][:3, 3]) < (0.2 if n == off else 0.02)


def test_views_carry_the_side_their_pnp_candidates_show():
    """The usable views carry the side of the board their best PnP pose shows (``View.facing``,
    which the mirrored-camera check reads instead of solving PnP again), equal to PnP solved anew:
    a cell with one camera's images mirrored, so both sides occur."""
    from calibgraph.core.problem import Detection
    from calibgraph.solver.terms.initialise import pnp_candidates
    from calibgraph.solver.terms.views import usable_views

    sc = make_scene(n_poses=20, pixel_sigma_px=0.3, seed=13)
    p = sc.problem
    w = p.cameras["cam1"].width_px
    p = p.with_(detections=tuple(Detection(d.camera, d.capture, d.ids, np.column_stack([w - 1 - d.uv_px[:, 0], d.uv_px[:, 1]]))
                                 if d.camera == "cam1" else d for d in p.detections))
    views, _, _ = usable_views(p)
    sides = []
    for v in views:
        R, _, _ = pnp_candidates(v.p_board_m, v.uv_px, p.cameras[v.camera])
        assert v.facing == np.sign(R[0][2, 2]), (v.camera, v.capture)
        sides.append(v.facing)
    assert min(sides) == -1.0 and max(sides) == 1.0


@pytest.mark.parametrize("loss", ["huber", "cauchy", "none"])
def test_reweight_all_views_at_once_equals_view_by_view(loss):
    """The robust weights of every active view's corners formed at once equal the per-view formula
    (each view's residuals in its own sigmas, weight 0 beyond outlier_sigmas), inactive views left
    as they were, and the largest change is the per-view one's."""
    from calibgraph.core.problem import SolverOptions
    from calibgraph.solver.fit.robust import loss_weights, reweight
    from calibgraph.solver.terms.views import View

    rng = np.random.default_rng(4)
    opts = replace(SolverOptions(), loss=loss)
    views, norms = [], []
    for i in range(25):
        n = int(rng.integers(5, 40))
        views.append(View(camera=f"c{i % 3}", capture=i, ids=np.arange(n), uv_px=np.zeros((n, 2)),
                          p_board_m=np.zeros((n, 3)), T_ref_mount=np.eye(4), w=rng.uniform(0, 1, n),
                          active=i % 7 != 3, noise_scale=rng.uniform(0.5, 2), view_noise=rng.uniform(0.5, 2)))
        norms.append(np.abs(rng.standard_cauchy(n)) * 0.3)
    out, change = reweight(views, norms, 0.25, opts)
    ref_change = 0.0
    for v, r, o in zip(views, norms, out):
        if not v.active:
            assert o is v
            continue
        rs = r / (0.25 * v.sigma_scale)
        w = loss_weights(rs, opts.loss, opts.loss_scale)
        w[rs > opts.outlier_sigmas] = 0.0
        np.testing.assert_array_equal(o.w, w)
        ref_change = max(ref_change, float(np.abs(w - v.w).max()))
    assert change == ref_change and any((o.w == 0).any() for o in out)


def test_view_evolve_equals_replace():
    """``View.evolve`` (no ``__init__``) makes the view ``dataclasses.replace`` makes, and a new ``w``
    gets its own kept-corner mask (the mask is cached per view)."""
    from calibgraph.solver.terms.views import View

    v = View(camera="c", capture=3, ids=np.arange(4), uv_px=np.zeros((4, 2)), p_board_m=np.zeros((4, 3)),
             T_ref_mount=np.eye(4), w=np.array([1.0, 0.0, 0.5, 1.0]))
    assert v.kept.tolist() == [True, False, True, True]
    for changes in ({"w": np.array([0.0, 1.0, 1.0, 0.0])}, {"noise_scale": 2.0, "view_noise": 0.5}, {"active": False}):
        a, b = v.evolve(**changes), replace(v, **changes)
        assert a == b and type(a) is View
        np.testing.assert_array_equal(a.kept, b.kept)
        assert a.sigma_scale == b.sigma_scale
    assert v.kept.tolist() == [True, False, True, True]
