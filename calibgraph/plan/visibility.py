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
    pts_b = target.points_board_m
    T_cb = inv(T_base_cam) @ T_base_board
    p_c = pts_b @ T_cb[:3, :3].T + T_cb[:3, 3]
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
    if occluded is not None:
        # outer points and the centre: a link crossing the board hides at least one of them
        p_base = pts_b @ T_base_board[:3, :3].T + T_base_board[:3, 3]
        if occluded(T_base_cam[:3, 3], p_base[_probe_ids(target.rows, target.cols)]):
            return False
    return True


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
