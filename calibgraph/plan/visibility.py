"""The board-visibility model: does a camera see the whole board, large enough and unoccluded?

The geometric test :func:`board_visible` takes a camera as data (its intrinsics and a
``T_base_cam``), so it serves both the planner that knows the true placements
(:func:`board_visibility`, which reads them from the world's cell) and the autonomous loop that
only has *estimated* camera poses (:mod:`calibgraph.plan.active`).
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.transforms import inv


def board_visible(intrinsics, T_base_cam: np.ndarray, target, T_base_board: np.ndarray, margin_px: float = 12.0,
                  max_angle_deg: float = 60.0, min_square_px: float = 7.0, occluded=None) -> bool:
    """True when a camera with ``intrinsics`` at ``T_base_cam`` (4, 4) sees every point of
    ``target`` at ``T_base_board``: in front (>= 0.2 m), inside the image with ``margin_px``, the
    board facing it within ``max_angle_deg``, squares at least ``min_square_px`` wide, and, when
    ``occluded(origin_m, points_m) -> bool`` is given, no geometry on the rays to the outer
    points and the centre."""
    T_cb = inv(T_base_cam) @ T_base_board
    p_c = target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3]
    if np.any(p_c[:, 2] < 0.2):
        return False
    # the printed face looks along -z_board: the camera must be on that side
    cam_in_board = inv(T_cb)[:3, 3]
    if cam_in_board[2] >= 0:
        return False
    centre_c = p_c.mean(axis=0)
    n_c = T_cb[:3, 2]
    cosang = float(n_c @ centre_c / np.linalg.norm(centre_c))
    if cosang < np.cos(np.radians(max_angle_deg)):
        return False
    uv = intrinsics.project(p_c)
    if not np.all(intrinsics.in_image(uv, margin_px=margin_px)):
        return False
    if square_px(uv, target) < min_square_px:
        return False
    if occluded is not None and occluded(T_base_cam[:3, 3], occlusion_probes(target, T_base_board)):
        return False
    return True


def occlusion_probes(target, T_base_board: np.ndarray) -> np.ndarray:
    """Board points (base frame) whose rays the occlusion test casts: the outer points and the
    centre (a link crossing the board hides at least one of them)."""
    p = target.points_board_m[_probe_ids(target.rows, target.cols)]
    return p @ T_base_board[:3, :3].T + T_base_board[:3, 3]


def boards_visible(intrinsics, T_base_cam: np.ndarray, target, T_base_boards: np.ndarray, margin_px=12.0,
                   max_angle_deg: float = 60.0, min_square_px: float = 7.0) -> np.ndarray:
    """:func:`board_visible` without the occlusion test for many board poses at once:
    ``T_base_boards`` (M, 4, 4), ``margin_px`` a scalar or (M,). Returns (M,) booleans, the same
    answers as M calls of :func:`board_visible` (the planner's scoring runs it on its whole pool)."""
    T = np.asarray(T_base_boards, float).reshape(-1, 4, 4)
    M = len(T)
    if M == 0:
        return np.zeros(0, bool)
    margin = np.broadcast_to(np.asarray(margin_px, float), (M,))
    T_cb = inv(T_base_cam) @ T
    pts_b = target.points_board_m
    p_c = pts_b @ np.swapaxes(T_cb[:, :3, :3], 1, 2) + T_cb[:, None, :3, 3]  # (M, N, 3)
    ok = np.all(p_c[:, :, 2] >= 0.2, axis=1)
    # camera on the printed side (-z_board): z of the camera centre in board axes < 0
    cam_z_board = -(T_cb[:, :3, 2] * T_cb[:, :3, 3]).sum(axis=1)
    ok &= cam_z_board < 0
    centre_c = p_c.mean(axis=1)
    cosang = (T_cb[:, :3, 2] * centre_c).sum(axis=1) / np.linalg.norm(centre_c, axis=1)
    ok &= cosang >= np.cos(np.radians(max_angle_deg))
    idx = np.flatnonzero(ok)
    if len(idx):
        N = p_c.shape[1]
        uv = intrinsics.project(p_c[idx].reshape(-1, 3)).reshape(len(idx), N, 2)
        m = margin[idx, None]
        inside = (np.isfinite(uv).all(axis=2) & (uv[:, :, 0] >= -0.5 + m) & (uv[:, :, 1] >= -0.5 + m)
                  & (uv[:, :, 0] <= intrinsics.width_px - 0.5 - m) & (uv[:, :, 1] <= intrinsics.height_px - 0.5 - m))
        good = inside.all(axis=1)
        good &= _grid_squares_px(uv, target) >= min_square_px
        ok[idx] = good
    return ok


def boards_square_px(intrinsics, T_base_cam: np.ndarray, target, T_base_boards: np.ndarray) -> np.ndarray:
    """:func:`square_px` of the board at each of ``T_base_boards`` (M, 4, 4) seen by a camera with
    ``intrinsics`` at ``T_base_cam``: (M,) smallest spacing (px) between neighbouring grid points."""
    T_cb = inv(T_base_cam) @ np.asarray(T_base_boards, float).reshape(-1, 4, 4)
    p_c = target.points_board_m @ np.swapaxes(T_cb[:, :3, :3], 1, 2) + T_cb[:, None, :3, 3]  # (M, N, 3)
    return _grid_squares_px(intrinsics.project(p_c.reshape(-1, 3)).reshape(len(T_cb), -1, 2), target)


def _grid_squares_px(uv_px: np.ndarray, target) -> np.ndarray:
    """(M,) :func:`square_px` of M projected boards ``uv_px`` (M, N, 2)."""
    grid = np.asarray(uv_px).reshape(len(uv_px), target.rows, target.cols, 2)
    with np.errstate(invalid="ignore"):
        return np.minimum(np.linalg.norm(np.diff(grid, axis=1), axis=3).min(axis=(1, 2)),
                          np.linalg.norm(np.diff(grid, axis=2), axis=3).min(axis=(1, 2)))


def square_px(uv_px: np.ndarray, target) -> float:
    """Smallest spacing (px) between neighbouring grid points of a projected board ``uv_px`` (N, 2)."""
    grid = np.asarray(uv_px).reshape(target.rows, target.cols, 2)
    return float(min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
                     np.linalg.norm(np.diff(grid, axis=1), axis=2).min()))


def board_visibility(world, cam_name: str, T_base_board: np.ndarray, margin_px: float = 12.0,
                     max_angle_deg: float = 60.0, min_square_px: float = 7.0, check_occlusion: bool = True) -> bool:
    """True when camera ``cam_name`` of ``world.cell`` (true placement) sees every board point:
    :func:`board_visible` with the cell's camera and, optionally, ``world.occluded``."""
    spec = world.cell.camera(cam_name)
    return board_visible(spec.intrinsics, spec.T_base_cam, world.cell.target, T_base_board, margin_px, max_angle_deg,
                         min_square_px, world.occluded if check_occlusion else None)


def _probe_ids(rows: int, cols: int) -> list:
    ids = set()
    for i in (0, rows // 2, rows - 1):
        for j in (0, cols // 3, (2 * cols) // 3, cols - 1):
            ids.add(i * cols + j)
    return sorted(ids)


def visible_cameras(world, T_base_board: np.ndarray, **kw) -> tuple:
    """Cameras that see the whole board at the world's current configuration."""
    return tuple(c.name for c in world.cell.cameras if board_visibility(world, c.name, T_base_board, **kw))
