"""A dataset of rendered board views placed one by one: each capture's board pose in the camera is
chosen (distance, tilt, where in the image), and the flange pose follows from it, so the data are
consistent for the solver. For tests and benches of the detection of a whole dataset (the spec
check's first frames: a far board of small squares, a board partly out of view, a board with
markers in its white squares declared as a checkerboard), without the simulator.

The cell is eye-to-hand: camera ``cam0`` at ``T_base_cam``, the board on the flange at
``T_flange_board``; capture ``k`` has ``T_base_flange = T_base_cam @ T_cam_board[k] @
inv(T_flange_board)``. ``printed`` is the board in the images and ``declared`` the one
``dataset.yaml`` names; ``T_printed_declared`` maps the declared board's frame to the printed
one's (a ChArUco board's frame starts one square before its first corner, a checkerboard's at it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.problem import Capture
from calibgraph.core.targets import Target
from calibgraph.core.transforms import exp_so3, inv, make_T
from calibgraph.io.dataset import image_relpath, write_capture, write_header
from calibgraph.sim.board_image import board_texture, look_at_board, render_view


@dataclass(frozen=True)
class ViewPlace:
    """Where the board is in one view: ``distance_m`` in front of the camera, tilted about its x
    then y axes, rolled about the viewing axis, its centre moved ``offset_px`` in the image.
    ``visible``: (rows, cols) of inner corners left in view by an occluder (a flat grey shape, like
    an arm passing in front) that covers the rest of the board; None: the whole board in view."""

    distance_m: float
    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0
    roll_deg: float = 0.0
    offset_px: tuple = (0.0, 0.0)
    visible: tuple | None = None


@dataclass(frozen=True)
class BoardViewsTruth:
    """What the rendered dataset was made from."""

    T_base_cam: np.ndarray
    T_flange_board: np.ndarray
    T_cam_board: tuple        # per capture, the declared board's pose in the camera
    intrinsics: Intrinsics


def charuco_as_checkerboard_offset(charuco: Target) -> np.ndarray:
    """``T_printed_declared`` of a ChArUco board declared as the checkerboard of its inner corners."""
    return make_T(np.eye(3), [charuco.pitch_m, charuco.pitch_m, 0.0])


def write_board_views(root, printed: Target, declared: Target, intr: Intrinsics, places: list,
                      T_printed_declared: np.ndarray | None = None, blur_sigma_px: float = 0.7,
                      noise_sigma: float = 2.0, seed: int = 0, white_on_black: bool = False,
                      background: float = 0.45, overlay=None) -> BoardViewsTruth:
    """Render ``printed`` at every :class:`ViewPlace` of ``places`` (one capture each, camera
    ``cam0`` with intrinsics ``intr``, told exactly) and write a calibgraph dataset declaring
    ``declared`` in ``root`` (module docstring). ``white_on_black``: the board printed with ink and
    paper swapped, on a scene of reflectance ``background``; ``overlay``: ``(image, intr,
    T_cam_declared) -> image`` drawn on every frame (a capture app's drawing, :func:`draw_pose_axes`).
    Returns the truth."""
    import cv2

    root = Path(root)
    intr = replace(intr, source="exact")
    T_pd = np.eye(4) if T_printed_declared is None else np.asarray(T_printed_declared, float)
    rng = np.random.default_rng(seed)
    T_base_cam = make_T(_rot([0.3, -0.2, 0.1]), [1.2, 0.3, 0.9])
    T_flange_board = make_T(_rot([0.1, 0.2, -0.3]), [0.02, -0.03, 0.08])
    write_header(root, declared, {"cam0": intr})
    tex = board_texture(printed, 3000.0, white_on_black=white_on_black)
    poses = []
    for k, pl in enumerate(places):
        T_cam_declared = look_at_board(declared, pl.distance_m, pl.tilt_x_deg, pl.tilt_y_deg, pl.roll_deg,
                                       tuple(pl.offset_px), intr)
        poses.append(T_cam_declared)
        img = render_view(printed, intr, T_cam_declared @ inv(T_pd), blur_sigma_px=blur_sigma_px,
                          noise_sigma=noise_sigma, seed=int(rng.integers(1 << 30)), texture=tex,
                          background=background).image
        if pl.visible is not None:
            _occlude(img, declared, intr, T_cam_declared, pl.visible, rng)
        if overlay is not None:
            img = overlay(img, intr, T_cam_declared)
        rel = image_relpath("cam0", k)
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(root / rel), img)
        T_base_flange = T_base_cam @ T_cam_declared @ inv(T_flange_board)
        write_capture(root, Capture(index=k, T_base_flange=T_base_flange), {"cam0": {"image": rel}})
    return BoardViewsTruth(T_base_cam, T_flange_board, tuple(poses), intr)


def far_or_hidden_first(root, intr: Intrinsics, board: Target, seed: int = 0, square_px: float = 11.0,
                        wrong: Target | None = None) -> BoardViewsTruth:
    """The first frames of a far camera (issue 33): 10 frames alternating the board far (squares of
    ``square_px`` pixels) and near but hidden but for the squares around 3x3 of its corners, then 8
    frames of the whole board 2.2-3.2x nearer than far. ``wrong``: declared instead of ``board``."""
    rng = np.random.default_rng(seed)
    W, H = intr.width_px, intr.height_px
    far_m = intr.K[0, 0] * board.pitch_m / square_px
    far = [ViewPlace(far_m, _u(rng, 20), _u(rng, 20), _u(rng, 30), (_u(rng, 0.35 * W), _u(rng, 0.3 * H)))
           for _ in range(5)]
    hid = [ViewPlace(far_m / 3, _u(rng, 20), _u(rng, 20), _u(rng, 20), (_u(rng, 0.2 * W), _u(rng, 0.2 * H)),
                     visible=(3, 3)) for _ in range(5)]
    whole = [ViewPlace(far_m / rng.uniform(2.2, 3.2), _u(rng, 30), _u(rng, 30), _u(rng, 20),
                       (_u(rng, 0.15 * W), _u(rng, 0.15 * H))) for _ in range(8)]
    places = [v for pair in zip(far, hid) for v in pair] + whole
    return write_board_views(root, board, wrong or board, intr, places, seed=seed)


def marker_checkerboard(root, n: int = 10, seed: int = 0, dictionary: str = "DICT_5X5_100") -> BoardViewsTruth:
    """A ChArUco board of 9x12 squares of 30 mm (markers in its white squares) declared as the
    checkerboard of its 8x11 inner corners, seen by a 1928x1208 camera at 0.6-1.3 m (the KUKA
    eye-in-hand recording of issue 33, as an eye-to-hand cell)."""
    rng = np.random.default_rng(seed)
    ch = Target(kind="charuco", rows=8, cols=11, pitch_m=0.03, marker_m=0.022, dictionary=dictionary)
    cb = Target(kind="checkerboard", rows=8, cols=11, pitch_m=0.03)
    places = [ViewPlace(rng.uniform(0.6, 1.3), _u(rng, 30), _u(rng, 30), _u(rng, 20), (_u(rng, 300), _u(rng, 150)))
              for _ in range(n)]
    return write_board_views(root, ch, cb, Intrinsics.from_hfov(1928, 1208, 60.0), places,
                             T_printed_declared=charuco_as_checkerboard_offset(ch), seed=seed)


def whole_boards(root, intr: Intrinsics, board: Target, declared: Target, n: int = 12, seed: int = 1,
                 distance_m=(0.6, 1.2)) -> BoardViewsTruth:
    """``n`` frames of the whole ``board`` at ``distance_m``, ``declared`` in dataset.yaml (a wrong
    spec when they differ)."""
    rng = np.random.default_rng(seed)
    places = [ViewPlace(rng.uniform(*distance_m), _u(rng, 30), _u(rng, 30), _u(rng, 20), (_u(rng, 400), _u(rng, 200)))
              for _ in range(n)]
    return write_board_views(root, board, declared, intr, places, seed=seed)


def draw_pose_axes(img: np.ndarray, intr: Intrinsics, T_cam_board: np.ndarray, length_m: float,
                   thickness_px: int = 4, text: str | None = None, origin_m=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``img`` (grey) with the board's pose axes drawn across it as a capture app draws them (ViSP's
    ``vpDisplay::displayFrame``, OpenCV's ``drawFrameAxes``): x red, y green, z blue, ``length_m``
    long and ``thickness_px`` thick from ``origin_m`` (board frame), and ``text`` in the image's top-left
    corner; the colours come back grey as a colour capture saved grey (or read grey) shows them.
    Returns the colour image drawn on, as BGR."""
    import cv2

    bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    o = np.asarray(origin_m, float)
    ends = np.array([o, o + [length_m, 0, 0], o + [0, length_m, 0], o + [0, 0, -length_m]])
    cam = ends @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
    uv = intr.project(cam)
    shift = 4
    pt = [tuple(int(round(c * 2**shift)) for c in p) for p in uv]
    for end, colour in ((1, (0, 0, 255)), (2, (0, 255, 0)), (3, (255, 0, 0))):
        cv2.line(bgr, pt[0], pt[end], colour, int(thickness_px), cv2.LINE_AA, shift)
    if text:
        cv2.putText(bgr, text, (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (0, 255, 255), 2, cv2.LINE_AA)
    return bgr


def _u(rng, a: float) -> float:
    return rng.uniform(-a, a)


def _occlude(img: np.ndarray, declared: Target, intr: Intrinsics, T_cam_declared: np.ndarray, visible: tuple,
             rng) -> None:
    """Cover the board in ``img`` (in place) with a flat grey shape, all but the squares around its
    first ``visible`` (rows, cols) inner corners."""
    import cv2

    p = declared.pitch_m

    def polygon(x1, y1, x0=-2 * p, y0=-2 * p):
        xy = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float)
        cam = xy @ T_cam_declared[:3, :3].T + T_cam_declared[:3, 3]
        return np.round(intr.project(cam)).astype(np.int32)

    mask = np.zeros(img.shape[:2], np.uint8)
    cv2.fillConvexPoly(mask, polygon((declared.cols + 1) * p, (declared.rows + 1) * p), 1)
    cv2.fillConvexPoly(mask, polygon(visible[1] * p, visible[0] * p, -p, -p), 0)
    shade = np.clip(100 + rng.normal(0, 2, img.shape[:2]), 0, 255).astype(img.dtype)
    img[mask > 0] = shade[mask > 0]


def _rot(rotvec) -> np.ndarray:
    return exp_so3(np.asarray(rotvec, float))
