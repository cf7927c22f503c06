"""The view factors' Jacobian on a camera's intrinsics vector, of every size the solver builds:
[fx, fy, cx, cy, k1, k2] and, for a calibration file whose covariance covers them, [p1, p2] and k3
(issue 23: a file's tangential and third radial coefficients are estimated under its covariance,
not held as if exact). Checked against central differences of the factors' own error."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from calibgraph.core.camera import Intrinsics
from calibgraph.core.transforms import exp_so3, make_T
from calibgraph.solver.terms.factors import ViewTerm, intrinsics_vector, make_calibration_factor, make_capture_factors
from calibgraph.solver.terms.keys import B, C, F, K, S


def _cell(n_intr: int):
    """One view of a 6x5 board (40 mm pitch) about 1 m in front of a skewed, strongly distorted camera."""
    intr = Intrinsics(np.array([[900.0, 0.4, 655.0], [0, 905.0, 362.0], [0, 0, 1]]),
                      np.array([0.09, -0.21, 0.0012, -0.0008, 0.05]), 1280, 720, "calibration")
    gx, gy = np.meshgrid(np.arange(6) * 0.04, np.arange(5) * 0.04)
    p_board = np.column_stack([gx.ravel() - 0.1, gy.ravel() - 0.08, np.zeros(gx.size)])
    T_ref_cam = make_T(exp_so3(np.array([0.1, -0.2, 0.05])), np.array([0.02, -0.01, 0.0]))
    T_ref_mount = make_T(exp_so3(np.array([-0.05, 0.15, 0.1])), np.array([0.05, 0.03, 0.9]))
    T_mount_board = make_T(exp_so3(np.array([0.2, 0.1, -0.1])), np.array([0.01, 0.0, 0.05]))
    T_cam_board = np.linalg.inv(T_ref_cam) @ T_ref_mount @ T_mount_board
    pc = p_board @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    uv = intr.project(pc) + np.random.default_rng(1).normal(scale=0.3, size=(len(p_board), 2))
    values = gtsam.Values()
    values.insert(C(0), gtsam.Pose3(T_ref_cam))
    values.insert(F(0), gtsam.Pose3(T_ref_mount))
    values.insert(B(0), gtsam.Pose3(T_mount_board))
    values.insert(S(0), np.array([1.0]))
    # the estimate a little off the given values, so that every column is exercised away from them
    k = intrinsics_vector(intr, n_intr) + np.r_[[3.0, -2.0, 1.5, -1.0], [0.01, -0.02, 4e-4, -3e-4, 0.01][:n_intr - 4]]
    values.insert(K(0), k)
    return intr, p_board, uv, values


def _numeric(factor, values, key, n):
    out = np.zeros((len(factor.unwhitenedError(values)), n))
    x0 = values.atVector(key)
    for j in range(n):
        h = 1e-6 * max(1.0, abs(x0[j]))
        vp, vm = gtsam.Values(values), gtsam.Values(values)
        d = np.zeros(n)
        d[j] = h
        vp.update(key, x0 + d)
        vm.update(key, x0 - d)
        out[:, j] = (factor.unwhitenedError(vp) - factor.unwhitenedError(vm)) / (2 * h)
    return out


@pytest.mark.parametrize("n_intr", [6, 8, 9])
def test_intrinsics_jacobian_matches_finite_differences(n_intr):
    intr, p_board, uv, values = _cell(n_intr)
    sqrt_w = np.full(len(p_board), 1 / 0.3)
    single = make_calibration_factor(C(0), F(0), B(0), p_board, uv, intr, sqrt_w, key_intr=K(0), key_scale=S(0))
    term = ViewTerm(C(0), K(0), intr, p_board, uv, sqrt_w, n_intr=n_intr)
    (capture,) = make_capture_factors(F(0), B(0), S(0), [term])
    for factor, col in ((single, 3), (capture, 4)):  # keys: cam, robot, mount, K, S / robot, mount, S, cam, K
        J = factor.linearize(values).jacobian()[0]
        widths = [6, 6, 6, n_intr, 1] if factor is single else [6, 6, 1, 6, n_intr]
        start = sum(widths[:col])
        analytic = J[:, start:start + n_intr]
        numeric = _numeric(factor, values, K(0), n_intr)
        scale = np.abs(numeric).max(axis=0)
        assert np.allclose(analytic, numeric, atol=1e-5 * scale.max(), rtol=1e-4), \
            np.abs(analytic - numeric).max(axis=0) / scale
        # and the error itself is the camera model with those coefficients
        e = factor.unwhitenedError(values)
        model = intr.with_pinhole(values.atVector(K(0)))
        T_cb = (np.linalg.inv(values.atPose3(C(0)).matrix()) @ values.atPose3(F(0)).matrix()
                @ values.atPose3(B(0)).matrix())
        expect = ((model.project(p_board @ T_cb[:3, :3].T + T_cb[:3, 3]) - uv) * sqrt_w[:, None]).ravel()
        assert np.allclose(e, expect, atol=1e-9)


def test_all_captures_in_one_pass_equal_the_per_view_factor(monkeypatch):
    """The view factors of many captures made in one vectorised pass (:func:`make_view_factors`, in
    chunks of whole views) give each view's residual and Jacobian blocks of the per-view reference
    factor (:func:`make_calibration_factor`), whitened modes applied by hand: 3 cameras (one with its
    intrinsics held, one estimating 6, one 8 coefficients), 7 captures, views of different corner
    counts, two of them with whitened low-order modes, chunks of 50 corners (views straddle none)."""
    import calibgraph.solver.terms.factors as factors
    from calibgraph.solver.terms.factors import make_view_factors
    from calibgraph.solver.terms.noise_model import view_mode_basis

    monkeypatch.setattr(factors, "CHUNK_CORNERS", 50)
    rng = np.random.default_rng(3)
    intr, p_board, _, _ = _cell(6)
    values = gtsam.Values()
    T_ref_cam = [make_T(exp_so3(rng.normal(0, 0.1, 3)), rng.normal(0, 0.05, 3)) for _ in range(3)]
    for c, T in enumerate(T_ref_cam):
        values.insert(C(c), gtsam.Pose3(T))
    n_intr = {1: 6, 2: 8}
    for c, n in n_intr.items():
        values.insert(K(c), intrinsics_vector(intr, n) + np.r_[[2.0, -1.0, 0.5, 1.0], rng.normal(0, 1e-3, n - 4)])
    T_mount_board = make_T(exp_so3(np.array([0.2, 0.1, -0.1])), np.array([0.01, 0.0, 0.05]))
    values.insert(B(0), gtsam.Pose3(T_mount_board))
    values.insert(S(0), np.array([1.003]))
    captures, expected = [], []
    for k in range(7):
        T_ref_mount = make_T(exp_so3(rng.normal(0, 0.1, 3)), np.array([0.05, 0.03, 0.9]) + rng.normal(0, 0.02, 3))
        values.insert(F(k), gtsam.Pose3(T_ref_mount))
        terms = []
        for c in range(3):
            keep = rng.random(len(p_board)) < 0.8
            T_cb = np.linalg.inv(T_ref_cam[c]) @ T_ref_mount @ T_mount_board
            uv = intr.project(p_board[keep] @ T_cb[:3, :3].T + T_cb[:3, 3]) + rng.normal(0, 0.3, (keep.sum(), 2))
            sqrt_w = rng.uniform(0.5, 1.0, keep.sum()) / 0.3
            f = 2.5 if (k, c) in ((1, 0), (4, 2)) else 1.0
            modes = view_mode_basis(uv) if f > 1.0 else None
            key_intr = K(c) if c in n_intr else None
            terms.append(ViewTerm(C(c), key_intr, intr, p_board[keep], uv, sqrt_w, modes, f, n_intr.get(c, 6)))
            ref = make_calibration_factor(C(c), F(k), B(0), p_board[keep], uv, intr, sqrt_w, key_intr=key_intr,
                                          key_scale=S(0))
            expected.append((ref, modes, f))
        captures.append((F(k), terms))
    made = make_view_factors(B(0), S(0), captures)
    assert len(made) == len(expected) == 21
    for factor, (ref, modes, f) in zip(made, expected):
        A, b = factor.linearize(values).jacobian()
        A_ref, b_ref = ref.linearize(values).jacobian()
        if modes is not None:  # the reference whitened by hand: I - (1 - f^-1/2) Q Q^T
            W = np.eye(len(b_ref)) - (1 - f ** -0.5) * modes @ modes.T
            A_ref, b_ref = W @ A_ref, W @ b_ref
        np.testing.assert_allclose(b, b_ref, rtol=1e-9, atol=1e-9)
        cols = {}
        start = 0
        for key in factor.keys():
            cols[key] = slice(start, start + (n_intr.get(gtsam.Symbol(key).index(), 6)
                                              if chr(gtsam.Symbol(key).chr()) == "k" else 1 if key == S(0) else 6))
            start = cols[key].stop
        start = 0
        for key in ref.keys():
            n = cols[key].stop - cols[key].start
            np.testing.assert_allclose(A[:, cols[key]], A_ref[:, start:start + n], rtol=1e-7,
                                       atol=1e-7 * np.abs(A_ref[:, start:start + n]).max())
            start += n
    # the pass is redone whenever any key a view depends on differs from the last pass's values
    for key in (F(3), B(0), S(0), C(1), K(2), K(1)):
        moved = gtsam.Values(values)
        if key == S(0):
            moved.update(key, np.array([1.01]))
        elif chr(gtsam.Symbol(key).chr()) == "k":
            moved.update(key, values.atVector(key) + 1e-3)
        else:
            moved.update(key, values.atPose3(key).retract(np.full(6, 1e-3)))
        for factor, (ref, modes, f) in zip(made, expected):
            e, e_ref = factor.unwhitenedError(moved), ref.unwhitenedError(moved)
            if modes is not None:
                e_ref = e_ref - (1 - f ** -0.5) * modes @ (modes.T @ e_ref)
            np.testing.assert_allclose(e, e_ref, rtol=1e-9, atol=1e-9)
        for factor, (ref, modes, f) in zip(made, expected):  # and back at the first values
            e_ref = ref.unwhitenedError(values)
            if modes is not None:
                e_ref = e_ref - (1 - f ** -0.5) * modes @ (modes.T @ e_ref)
            np.testing.assert_allclose(factor.unwhitenedError(values), e_ref, rtol=1e-9, atol=1e-9)
