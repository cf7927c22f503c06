"""What a pose covariance means where it matters: in the workspace, and in words.

The solver reports each camera pose ``T_ref_cam`` (``ref`` = base for eye-to-hand, flange for
eye-in-hand) with a 6x6 covariance, rotation first (rad) then translation (m), whose
perturbation is expressed in the *reference frame's axes* (see :mod:`calibgraph.solver.output.result`)::

    R_est = exp([dtheta]x) R_true,    t_est = t_true + dt

A point ``p_cam`` fixed in the camera frame (something the camera localises) is reported in the
reference frame at ``p = R p_cam + t``. Under the perturbation above

    dp = dtheta x (p - t) + dt = [-[p - t]x , I] [dtheta; dt]

so its covariance in the reference frame is ``J Sigma J^T`` with ``J = [-[p - t]x, I]``. That is
the part of a point's localisation error caused by the extrinsic calibration alone (the camera's
own depth/pixel noise comes on top). It grows linearly with the distance from the camera centre
through the rotation uncertainty: a 0.02 deg rotation sigma is 0.35 mm at 1 m.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.transforms import skew


def point_jacobian(p_ref_m: np.ndarray, t_ref_cam_m: np.ndarray) -> np.ndarray:
    """d(point in ref frame) / d([dtheta, dt]) for points fixed in the camera.

    Args:
        p_ref_m: (N, 3) or (3,) points in the reference frame.
        t_ref_cam_m: (3,) camera centre in the reference frame.
    Returns:
        (N, 3, 6) Jacobians (or (3, 6) for a single point).
    """
    p = np.asarray(p_ref_m, float)
    single = p.ndim == 1
    P = p.reshape(-1, 3) - np.asarray(t_ref_cam_m, float).reshape(1, 3)
    J = np.zeros((P.shape[0], 3, 6))
    for i, d in enumerate(P):
        J[i, :, :3] = -skew(d)
        J[i, :, 3:] = np.eye(3)
    return J[0] if single else J


def point_covariance(T_ref_cam: np.ndarray, cov6: np.ndarray, p_ref_m: np.ndarray) -> np.ndarray:
    """Covariance (m^2) in the reference frame of points fixed in the camera, from the pose covariance.

    Args:
        T_ref_cam: (4, 4) camera pose.
        cov6: (6, 6) rotation-first covariance in the reference frame's axes.
        p_ref_m: (N, 3) or (3,) points in the reference frame.
    Returns:
        (N, 3, 3) or (3, 3).
    """
    cov6 = np.asarray(cov6, float)
    J = point_jacobian(p_ref_m, np.asarray(T_ref_cam, float)[:3, 3])
    return J @ cov6 @ np.swapaxes(J, -1, -2)


def point_sigma_mm(T_ref_cam: np.ndarray, cov6: np.ndarray, p_ref_m: np.ndarray, kind: str = "rms") -> np.ndarray:
    """1-sigma position error (mm) of points fixed in the camera, expressed in the reference frame.

    ``kind``: 'rms' = sqrt(trace) (3D RMS error), 'max' = sqrt of the largest eigenvalue (error
    along the worst direction).
    """
    C = point_covariance(T_ref_cam, cov6, p_ref_m)
    if kind == "rms":
        v = np.trace(C, axis1=-2, axis2=-1)
    elif kind == "max":
        v = np.linalg.eigvalsh(C)[..., -1]
    else:
        raise ValueError(f"kind must be 'rms' or 'max', got {kind!r}")
    return np.sqrt(np.clip(v, 0, None)) * 1e3


def workspace_grid(x_range_m, y_range_m, z_m: float, n: int = 24):
    """A top-view grid of the workspace: (xs (nx,), ys (ny,), points (ny, nx, 3))."""
    xs = np.linspace(float(x_range_m[0]), float(x_range_m[1]), n)
    span = float(y_range_m[1]) - float(y_range_m[0])
    ny = max(2, int(round(n * span / max(float(x_range_m[1]) - float(x_range_m[0]), 1e-9))))
    ys = np.linspace(float(y_range_m[0]), float(y_range_m[1]), ny)
    X, Y = np.meshgrid(xs, ys)
    P = np.stack([X, Y, np.full_like(X, float(z_m))], axis=-1)
    return xs, ys, P


def workspace_sigma_map(T_ref_cam, cov6, points_m: np.ndarray, kind: str = "rms") -> np.ndarray:
    """1-sigma error (mm) at every point of a (..., 3) grid; same leading shape as the grid."""
    pts = np.asarray(points_m, float)
    return point_sigma_mm(T_ref_cam, cov6, pts.reshape(-1, 3), kind=kind).reshape(pts.shape[:-1])


def visible_mask(T_ref_cam, intrinsics, points_m: np.ndarray, min_depth_m: float = 0.05) -> np.ndarray:
    """Boolean mask of grid points the camera can see (in front of it and inside the image)."""
    pts = np.asarray(points_m, float)
    P = pts.reshape(-1, 3)
    T = np.asarray(T_ref_cam, float)
    p_cam = (P - T[:3, 3]) @ T[:3, :3]  # R^T (p - t) for every row
    ok = p_cam[:, 2] > min_depth_m
    if intrinsics is not None and intrinsics.width_px > 0 and intrinsics.height_px > 0:
        uv = np.full((P.shape[0], 2), np.nan)
        if ok.any():
            uv[ok] = intrinsics.project(p_cam[ok])
        ok &= intrinsics.in_image(uv)
    return ok.reshape(pts.shape[:-1])


# -- weakest directions in words ----------------------------------------------------------------
_CAM_AXES = (
    ("camera x", "across the image (camera x, left-right)"),
    ("camera y", "across the image (camera y, up-down)"),
    ("camera z", "along the camera's viewing axis (depth)"),
)
_ROT_AXES = (
    "about the camera's x axis (tilt up/down)",
    "about the camera's y axis (pan left/right)",
    "about the camera's viewing axis (roll)",
)


def _axis_phrase(v_ref: np.ndarray, ref_frame: str) -> str:
    """Name the nearest reference axis of a unit vector, e.g. 'base -z (78 deg from camera z)'."""
    i = int(np.argmax(np.abs(v_ref)))
    sign = "+" if v_ref[i] >= 0 else "-"
    return f"{ref_frame} {sign}{'xyz'[i]}"


def weakest_directions(T_ref_cam: np.ndarray, cov6: np.ndarray, ref_frame: str = "base") -> dict:
    """Eigen-decomposition of the translation and rotation blocks, described in words.

    Returns a dict with, for 'translation' and 'rotation': ``sigma`` (mm or deg, the largest
    1-sigma), ``sigma_min``, ``direction_ref`` (unit vector in the reference frame's axes),
    ``direction_cam`` (same in camera axes), ``cam_axis`` (0, 1, 2: nearest camera axis),
    ``alignment`` (|cos| with that axis), ``where`` (that axis in words) and ``text``; plus ``summary``
    (one sentence).
    """
    T = np.asarray(T_ref_cam, float)
    C = np.asarray(cov6, float)
    R = T[:3, :3]
    out = {}
    for key, block, scale, unit in (("translation", C[3:, 3:], 1e3, "mm"), ("rotation", C[:3, :3], np.degrees(1.0), "deg")):
        w, V = np.linalg.eigh(0.5 * (block + block.T))
        w = np.clip(w, 0, None)
        v = V[:, -1]
        v_cam = R.T @ v
        # sign is arbitrary for an eigenvector: make the dominant camera component positive
        if v_cam[int(np.argmax(np.abs(v_cam)))] < 0:
            v, v_cam = -v, -v_cam
        ax = int(np.argmax(np.abs(v_cam)))
        align = float(abs(v_cam[ax]))
        sig = float(np.sqrt(w[-1]) * scale)
        sig_min = float(np.sqrt(w[0]) * scale)
        if key == "translation":
            where = _CAM_AXES[ax][1]
        else:
            where = _ROT_AXES[ax]
        angle = float(np.degrees(np.arccos(min(1.0, align))))
        qual = "" if align > 0.95 else f" (mixed: {angle:.0f} deg off that axis)"
        text = (f"weakest {key}: {sig:.3g} {unit} {where}{qual}, i.e. along {_axis_phrase(v, ref_frame)}; "
                f"best-determined direction: {sig_min:.3g} {unit}")
        out[key] = dict(sigma=sig, sigma_min=sig_min, unit=unit, direction_ref=v.tolist(), where=where,
                        direction_cam=v_cam.tolist(), cam_axis=ax, alignment=align, text=text)
    t, r = out["translation"], out["rotation"]
    out["summary"] = (f"Weakest: {t['sigma']:.3g} mm {_CAM_AXES[t['cam_axis']][1]}; "
                      f"{r['sigma']:.3g} deg {_ROT_AXES[r['cam_axis']]}.")
    return out
