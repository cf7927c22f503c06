"""Covariance propagation to workspace points and weakest directions in words."""

import numpy as np

from calibgraph.core.camera import preset
from calibgraph.core.transforms import exp_so3, look_at, make_T
from calibgraph.solver.uncertainty.workspace import (
    point_covariance,
    point_sigma_mm,
    visible_mask,
    weakest_directions,
    workspace_grid,
    workspace_sigma_map,
)


def _cam():
    return look_at([1.5, 0.4, 1.6], [0.45, 0.0, 0.6])


def test_point_covariance_matches_monte_carlo():
    """J Sigma J^T against sampling the perturbation model R' = exp(dtheta) R, t' = t + dt."""
    rng = np.random.default_rng(3)
    T = _cam()
    A = rng.normal(size=(6, 6))
    cov = A @ A.T * 1e-7 + np.diag([1e-7] * 3 + [1e-7] * 3)
    p_ref = np.array([0.5, -0.1, 0.4])
    p_cam = np.linalg.solve(T, np.append(p_ref, 1))[:3]
    L = np.linalg.cholesky(cov)
    xs = rng.normal(size=(20000, 6)) @ L.T
    pts = np.array([exp_so3(x[:3]) @ T[:3, :3] @ p_cam + T[:3, 3] + x[3:] for x in xs])
    emp = np.cov(pts.T)
    C = point_covariance(T, cov, p_ref)
    # 20000 samples: relative standard error of a variance ~ sqrt(2/20000) = 1 %
    assert np.allclose(emp, C, rtol=0.05, atol=0.05 * np.abs(C).max())


def test_pure_translation_and_rotation_about_the_ray():
    T = _cam()
    cov_t = np.diag([0, 0, 0, 1e-6, 4e-6, 9e-6])  # 1, 2, 3 mm
    s = point_sigma_mm(T, cov_t, np.array([[0.3, 0.2, 0.1], [1.0, 1.0, 1.0]]))
    assert np.allclose(s, np.sqrt(14.0))
    # rotation only about the viewing axis (expressed in base axes): points on that axis do not move
    z_base = T[:3, 2]
    cov_r = np.zeros((6, 6))
    cov_r[:3, :3] = np.outer(z_base, z_base) * np.radians(0.1) ** 2
    on_axis = T[:3, 3] + 1.2 * z_base
    assert point_sigma_mm(T, cov_r, on_axis) < 1e-9
    # ... and a point 1 m off the axis moves by 1 m * 0.1 deg = 1.745 mm
    off = on_axis + 1.0 * T[:3, 0]
    assert np.isclose(point_sigma_mm(T, cov_r, off), 1000 * np.radians(0.1), rtol=1e-9)


def test_workspace_map_grows_with_distance_under_rotation_noise():
    T = _cam()
    cov = np.diag([np.radians(0.05) ** 2] * 3 + [1e-8] * 3)
    xs, ys, P = workspace_grid((0.0, 0.9), (-0.5, 0.5), 0.5, n=10)
    m = workspace_sigma_map(T, cov, P)
    assert m.shape == P.shape[:2]
    d = np.linalg.norm(P - T[:3, 3], axis=-1)
    assert np.argmax(m) == np.argmax(d) and np.argmin(m) == np.argmin(d)


def test_visible_mask():
    T = _cam()
    intr = preset("l515")
    pts = np.array([[0.45, 0.0, 0.6], [3.0, 0.4, 1.6], [0.45, 3.0, 0.6]])
    assert visible_mask(T, intr, pts).tolist() == [True, False, False]


def test_weakest_direction_in_words_names_depth():
    T = make_T(exp_so3([0.3, -0.2, 0.5]), [1.0, 0.5, 1.5])
    R = T[:3, :3]
    # 2 mm along the camera's z (depth), 0.2 mm across; rotation weakest about the camera y axis
    cov_t_cam = np.diag([0.2e-3, 0.2e-3, 2e-3]) ** 2
    cov_r_cam = np.diag([np.radians(0.01), np.radians(0.05), np.radians(0.01)]) ** 2
    cov = np.zeros((6, 6))
    cov[3:, 3:] = R @ cov_t_cam @ R.T
    cov[:3, :3] = R @ cov_r_cam @ R.T
    w = weakest_directions(T, cov)
    assert w["translation"]["cam_axis"] == 2 and np.isclose(w["translation"]["sigma"], 2.0)
    assert "depth" in w["translation"]["text"] and "2 mm" in w["translation"]["text"]
    assert w["rotation"]["cam_axis"] == 1 and np.isclose(w["rotation"]["sigma"], 0.05)
    assert "pan" in w["summary"]
    assert np.allclose(np.abs(w["translation"]["direction_ref"]), np.abs(R[:, 2]))
