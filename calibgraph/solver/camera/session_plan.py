"""A close-range intrinsics session planned for one camera and board, and what it would give.

:func:`session_poses` is a well-spread set of hand-held board poses: distances across the range,
the board tilted by 20-45 degrees about axes that turn from view to view, and its image spread over
the whole frame so that corners reach the image's edges and corners (where distortion is seen).
Deterministic by default (a low-discrepancy sequence), randomised with a generator (the simulator's
sessions).

:func:`predict_session_covariance` is the covariance such a session would give the camera's
[fx, fy, cx, cy, k1, k2] (``INTRINSICS_VECTOR``) at a given corner noise: the information of every
view's corners with the view poses and the other distortion coefficients eliminated, exactly as
:func:`calibgraph.solver.camera.intrinsics_session.calibrate_views` computes it from real views. The error
budget uses it to say how far a session would shrink a camera's 1-sigma.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.camera import Intrinsics, undistort_normalised
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.core.transforms import exp_so3, make_T
from calibgraph.solver.camera.intrinsics_model import (
    DEFAULT_MODEL,
    intrinsics_block,
    model_parameters,
    reduced_information,
    view_jacobians,
)

GOLDEN = 0.6180339887498949
# a hand-held board's pose spread: tilt away from facing the camera, and roll about its normal
TILT_RANGE_DEG = (20.0, 45.0)
ROLL_RANGE_DEG = (-30.0, 30.0)
# corner noise a session's corners have (calibgraph's detector on sharp close-range images is
# better, 0.03-0.06 px; real images with a printed board and a hand-held exposure are about this)
SESSION_PIXEL_SIGMA_PX = 0.1
# where the first views aim, in half-image units: the four image corners, then the four edges
FIRST_AIMS = ((-1, -1), (1, 1), (1, -1), (-1, 1), (0, -1), (0, 1), (-1, 0), (1, 0))


CELL_PLACEHOLDER = "CELL.yaml"  # the workcell an advice line names when it does not know the user's


def session_command(camera: str, workcell=None) -> str:
    """The commands that make and use a close-range session of ``camera``, as advice lines name them:
    the guided live session at the camera (``calibgraph intrinsics --live``), then the solve with its
    file. ``workcell``: the user's cell file (shown relative to the working folder when inside it),
    else the placeholder ``CELL.yaml``."""
    return (f"calibgraph intrinsics --live --camera {camera} --workcell {shown_path(workcell)} --out {camera}.yaml, "
            f"then --intrinsics {camera}={camera}.yaml")


def shown_path(path) -> str:
    """A file as a command line should name it: relative to the working folder when inside it,
    else absolute; the placeholder ``CELL.yaml`` for None."""
    if path is None:
        return CELL_PLACEHOLDER
    import os

    p = os.path.abspath(str(path))
    rel = os.path.relpath(p)
    return rel if not rel.startswith("..") else p


def name_workcell(text: str, workcell) -> str:
    """An advice line with the placeholder ``--workcell CELL.yaml`` naming ``workcell`` instead (the
    file a dataset records it was captured with; None: unchanged)."""
    if workcell is None or not text:
        return text
    return text.replace(f"--workcell {CELL_PLACEHOLDER}", f"--workcell {shown_path(workcell)}")


def _halton(k: int, base: int) -> float:
    f, r = 1.0, 0.0
    while k > 0:
        f /= base
        r += f * (k % base)
        k //= base
    return r


def _outline_board_m(target: Target, per_edge: int = 6) -> np.ndarray:
    """(4 per_edge, 3) points along the edge of the printed pattern (outer squares)."""
    x0, y0, x1, y1 = target.extent_m
    s = np.linspace(0.0, 1.0, per_edge, endpoint=False)
    xs = np.concatenate([x0 + (x1 - x0) * s, np.full_like(s, x1), x1 - (x1 - x0) * s, np.full_like(s, x0)])
    ys = np.concatenate([np.full_like(s, y0), y0 + (y1 - y0) * s, np.full_like(s, y1), y1 - (y1 - y0) * s])
    return np.column_stack([xs, ys, np.zeros_like(xs)])


def _poses(Kinv: np.ndarray, aims_px: np.ndarray, dist: float, turn: np.ndarray, centre_b: np.ndarray):
    """(R (k, 3, 3), t (k, 3)) of poses with the pattern's centre ``dist`` along the pinhole ray of each
    of ``aims_px`` (k, 2), facing the camera (board x as close to the camera's x as it can be), then
    turned by ``turn``."""
    rays = np.column_stack([aims_px, np.ones(len(aims_px))]) @ Kinv.T
    z = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    x = np.column_stack([np.ones(len(z)), np.zeros(len(z)), np.zeros(len(z))]) - z[:, :1] * z
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.column_stack([z[:, 1] * x[:, 2] - z[:, 2] * x[:, 1], z[:, 2] * x[:, 0] - z[:, 0] * x[:, 2],
                         z[:, 0] * x[:, 1] - z[:, 1] * x[:, 0]])
    R = np.stack([x, y, z], axis=2) @ turn
    return R, dist * z - R @ centre_b


def _fit(intr: Intrinsics, R: np.ndarray, t: np.ndarray, outline_m: np.ndarray, margin_px: float,
         r_max: float) -> np.ndarray:
    """(k,) True where the pattern's outline lies in front of the camera, inside its field of view
    (normalised radius ``r_max``: beyond it the distortion polynomial no longer maps into the image)
    and ``margin_px`` inside the image."""
    p = np.einsum("kij,mj->kmi", R, outline_m) + t[:, None, :]
    ok = np.all(p[:, :, 2] > 0.05, axis=1) & np.all(np.hypot(p[:, :, 0], p[:, :, 1]) <= r_max * p[:, :, 2], axis=1)
    uv = intr.project(p.reshape(-1, 3)).reshape(len(p), -1, 2)
    inside = intr.in_image(uv.reshape(-1, 2), margin_px=margin_px).reshape(len(p), -1)
    return ok & np.all(inside, axis=1)


def _furthest(fits, start: np.ndarray, end: np.ndarray, n: int = 16) -> np.ndarray | None:
    """The point nearest ``end`` on the segment from ``start`` that fits (``fits``: (k, 2) -> (k,)
    bool), sampled at n points then refined between the last fit and the next sample; None when
    none fits."""
    f = np.linspace(0.0, 1.0, n)
    ok = fits(start + f[:, None] * (end - start))
    if not ok.any():
        return None
    i = int(np.nonzero(ok)[0].max())
    if i == n - 1:
        return end
    g = np.linspace(f[i], f[i + 1], n)
    ok = fits(start + g[:, None] * (end - start))
    return start + g[int(np.nonzero(ok)[0].max()) if ok.any() else 0] * (end - start)


def session_poses(intr: Intrinsics, target: Target, n_views: int = 25, distance_range_m=(0.3, 0.8),
                  tilt_range_deg=TILT_RANGE_DEG, margin_px: float = 8.0, rng=None) -> list:
    """``n_views`` board poses ``T_cam_board`` (4, 4) of a close-range session.

    View k aims the pattern's centre at a point spread over the image (edges favoured), at a
    distance (to the pattern's centre) across ``distance_range_m``, facing the camera and tilted by
    ``tilt_range_deg`` about an axis turned by the golden angle from the previous view's, rolled by
    up to 30 degrees; the first eight views aim at the image's corners and edges. A pose whose
    pattern would leave the image is brought back towards the centre only as far as needed for the
    whole pattern to lie ``margin_px`` inside (and moved away when it fits nowhere). ``rng`` (a numpy Generator)
    draws these instead of the deterministic sequence.
    """
    if intr.width_px <= 0 or intr.height_px <= 0:
        raise InputError("session poses: the camera needs its image size (width_px, height_px).")
    d_lo, d_hi = (float(v) for v in distance_range_m)
    if not (0 < d_lo <= d_hi):
        raise InputError(f"session poses: distance range must be 0 < near <= far, got {distance_range_m}.")
    centre_b = np.append(np.mean(np.reshape(target.extent_m, (2, 2)), axis=0), 0.0)
    half = np.array([(intr.width_px - 1) / 2.0, (intr.height_px - 1) / 2.0])
    outline = _outline_board_m(target)
    Kinv = np.linalg.inv(intr.K)
    # the field of view as a normalised radius: the image corners' rays
    frame = np.array([[-0.5, -0.5], [intr.width_px - 0.5, -0.5], [-0.5, intr.height_px - 0.5],
                      [intr.width_px - 0.5, intr.height_px - 0.5]])
    r_max = float(np.max(np.hypot(*undistort_normalised(intr, frame).T)))
    poses = []
    for k in range(int(n_views)):
        if rng is None:
            f_d, f_t, f_r = (k * GOLDEN + 0.5) % 1.0, (k * 0.7548776662 + 0.25) % 1.0, (k * 0.5698402910) % 1.0
            aim = np.array([_halton(k + 1, 2), _halton(k + 1, 3)]) * 2.0 - 1.0
            psi = k * 2.399963229728653
        else:
            f_d, f_t, f_r = rng.uniform(size=3)
            aim = rng.uniform(-1.0, 1.0, size=2)
            psi = rng.uniform(0.0, 2 * np.pi)
        if k < len(FIRST_AIMS):
            # the image corners and edges first, where distortion shows: from the far half of the
            # range, less tilted and square to the image, so that the board's outer corners go
            # into the image's
            aim = np.array(FIRST_AIMS[k], float)
            f_d, f_t, f_r = 0.5 + 0.5 * f_d, 0.5 * f_t, 0.5
        aim = np.sign(aim) * np.sqrt(np.abs(aim))  # towards the edges
        dist = d_lo + (d_hi - d_lo) * f_d
        tilt = np.radians(tilt_range_deg[0] + (tilt_range_deg[1] - tilt_range_deg[0]) * f_t)
        roll = np.radians(ROLL_RANGE_DEG[0] + (ROLL_RANGE_DEG[1] - ROLL_RANGE_DEG[0]) * f_r)
        turn = exp_so3(tilt * np.array([np.cos(psi), np.sin(psi), 0.0])) @ exp_so3([0.0, 0.0, roll])
        aim_px = intr.K[:2, 2] + aim * half
        for _ in range(40):
            # as far towards the aim as the whole pattern fits, then along each image axis alone;
            # stepping back while it fits nowhere
            fits = lambda a: _fit(intr, *_poses(Kinv, a, dist, turn, centre_b), outline, margin_px, r_max)  # noqa: E731
            at = _furthest(fits, intr.K[:2, 2], aim_px)
            if at is not None:
                break
            dist *= 1.1
        else:
            at = intr.K[:2, 2]
        for axis in (0, 1):
            far = at.copy()
            far[axis] = aim_px[axis]
            moved = _furthest(fits, at, far) if far[axis] != at[axis] else at
            at = at if moved is None else moved  # the pattern fits nowhere along this axis: stay
        R, t = _poses(Kinv, at[None], dist, turn, centre_b)
        T = make_T(R[0], t[0])
        poses.append(T)
    return poses


def predict_session_covariance(intrinsics: Intrinsics, target: Target, n_views: int = 25,
                               distance_range_m=(0.3, 0.8), pixel_sigma_px: float = SESSION_PIXEL_SIGMA_PX,
                               model: str = DEFAULT_MODEL, size: int = 6) -> np.ndarray:
    """(size, size) covariance of [fx, fy, cx, cy, k1, k2] (then p1, p2, k3 as ``size`` 8 or 9
    asks: the joint graph's vector for a camera file with them) that a close-range session of ``n_views`` images
    of ``target`` (:func:`session_poses`, deterministic) would give this camera, with corners of
    independent noise ``pixel_sigma_px`` per axis, the view poses and the model's other distortion
    coefficients (``model``, default k1 k2 p1 p2 k3) marginalised out.

    A prediction at the camera's current values: it assumes the whole board is seen in every view
    and ignores bad views, which a real session rejects. 10-40 ms the first time for a camera and
    board (the pose set), then cached.
    """
    if not pixel_sigma_px > 0:
        raise InputError(f"predict_session_covariance: pixel_sigma_px must be > 0, got {pixel_sigma_px}.")
    names = model_parameters(model)
    # units of one camera model differ by tenths of a percent in focal length and a few pixels in
    # principal point, which moves the prediction by about as little: they share one computation
    # (focal to 1 %, principal point to 8 px, distortion to 0.01)
    K = intrinsics.K
    rounded = (round(float(np.log(K[0, 0]) / 0.01)), round(float(np.log(K[1, 1]) / 0.01)),
               round(float(K[0, 2] / 8.0)), round(float(K[1, 2] / 8.0)),
               tuple(round(float(c) / 0.01) for c in intrinsics.dist))
    key = (rounded, intrinsics.width_px, intrinsics.height_px,
           target.spec_hash(), int(n_views), tuple(float(d) for d in distance_range_m), model)
    info = _INFO_CACHE.get(key)
    if info is None:
        pts = target.points_board_m
        blocks = []
        for T in session_poses(intrinsics, target, n_views, distance_range_m):
            _, A, B = view_jacobians(intrinsics, names, pts, T)
            blocks.append((A, B))
        info = reduced_information(blocks)
        if len(_INFO_CACHE) >= 64:
            _INFO_CACHE.pop(next(iter(_INFO_CACHE)))
        _INFO_CACHE[key] = info
    cov = np.linalg.inv(info) * pixel_sigma_px ** 2
    return intrinsics_block(0.5 * (cov + cov.T), names, size)


# (camera, target, session) -> information of the intrinsics per unit corner variance: the error
# budget asks for the same cameras again at every solve
_INFO_CACHE: dict = {}
