"""Render images of a calibration target seen by a camera, with exact ground-truth pixels.

Used by the detection benchmark and tests (and by anyone who needs a synthetic image whose
corner positions are known exactly).

How an image is made (``render_view``):

1. The target is painted into a *texture* (``board_texture``): a high-resolution raster of the
   printed sheet whose pixel ``(c, r)`` covers board-frame ``[x0 + c / ppm, x0 + (c + 1) / ppm]``
   (and likewise in y), i.e. OpenCV's convention that pixel centres sit at integer coordinates.
   Square edges fall on texel boundaries, so the texture is an exact area-coverage raster.
2. For every camera pixel in the target's bounding box, ``supersample x supersample`` sample points
   are placed at the centres of equal sub-pixels (pixel ``(u, v)`` spans ``[u - 0.5, u + 0.5]``).
   Each sample is back-projected through the full OpenCV camera model and intersected with the
   board plane (without distortion this is one exact homography warp; with distortion the
   back-projection is computed at pixel centres and interpolated to the samples), and looks up
   the texture bilinearly.
   The texture resolution matches the sample spacing, so bilinear lookup acts as a small symmetric
   prefilter: edges are not shifted, only softened by a fraction of a pixel.
3. The samples of each pixel are averaged (box filter = a pixel's light-collecting area), then
   exposure, optical blur (Gaussian, ``blur_sigma_px``), noise and 8-bit quantisation are applied.

Ground truth is ``Intrinsics.project(T_cam_board @ p_board)`` for the target points — exactly the
model the solver uses, so a detector that reproduces it has no bias. The tests check this
convention by detecting rendered images with OpenCV and comparing with the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.camera import Intrinsics, undistort_normalised
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.core.transforms import exp_so3, make_T


@dataclass(frozen=True)
class Texture:
    """A raster of the printed target.

    Attributes:
        image: (H, W) float32 reflectance in [0, 1] (0 black ink, 1 paper).
        A_tex_board: (3, 3) affine map from board-frame (x, y, 1) metres to texture pixels.
        ppm: texels per metre.
    """

    image: np.ndarray
    A_tex_board: np.ndarray
    ppm: float


def board_texture(target: Target, ppm: float, margin_m: float | None = None, white_on_black: bool = False) -> Texture:
    """Paint ``target`` at ``ppm`` texels per metre with a white paper margin around the pattern
    (default: one pitch, the quiet zone detectors need). ``white_on_black``: the sheet printed with
    ink and paper swapped (white squares, markers or dots on a black sheet, its margin black too)."""
    import cv2

    ppm = float(ppm)
    if margin_m is None:
        margin_m = target.pitch_m
    # Snap ppm so the pitch is an integer number of texels: edges of squares then fall exactly
    # on texel boundaries and the texture needs no anti-aliasing.
    # (ChArUco: OpenCV draws a marker's bits only with several texels each, whatever the density.)
    n_pitch = max(64 if target.kind == "charuco" else 2, int(round(target.pitch_m * ppm)))
    pat = None
    if target.kind == "charuco":
        # OpenCV's generateImage fails its own ROI check at some sizes (e.g. 130, 200, 270 texels
        # a square on a 7x5 board with 0.74 markers): the next size up serves as well.
        board = target.cv_charuco_board()
        for n in range(n_pitch, n_pitch + 8):
            try:
                pat = board.generateImage((target.squares_x * n, target.squares_y * n), marginSize=0, borderBits=1)
            except cv2.error:
                continue
            n_pitch = n
            break
        if pat is None:
            raise InputError(f"render: OpenCV cannot draw this ChArUco board at {n_pitch} texels a square.")
    ppm = n_pitch / target.pitch_m
    n_margin = int(np.ceil(margin_m * ppm))
    x0, y0, x1, y1 = target.extent_m
    # Extent in whole texels (pitch multiples for boards of squares).
    W = int(round((x1 - x0) * ppm)) + 2 * n_margin
    H = int(round((y1 - y0) * ppm)) + 2 * n_margin
    if W * H > 80e6:
        raise InputError(f"render: texture of {W}x{H} texels is too large; lower the supersampling.")
    img = np.ones((H, W), np.float32)
    flip_y = target.kind == "modified_circles"  # peer frame: y up the page
    # Texture column of board x: c = (x - x0) * ppm + n_margin - 0.5 (pixel centres at integers).
    A = np.array([[ppm, 0.0, -x0 * ppm + n_margin - 0.5], [0.0, ppm, -y0 * ppm + n_margin - 0.5], [0, 0, 1.0]])
    if flip_y:
        A = np.array([[ppm, 0.0, -x0 * ppm + n_margin - 0.5], [0.0, -ppm, y1 * ppm + n_margin - 0.5], [0, 0, 1.0]])

    if target.kind == "checkerboard":
        for a in range(target.rows + 1):
            for b in range(target.cols + 1):
                if (a + b) % 2 == 0:
                    r0 = n_margin + a * n_pitch
                    c0 = n_margin + b * n_pitch
                    img[r0 : r0 + n_pitch, c0 : c0 + n_pitch] = 0.0
    elif target.kind == "charuco":
        w, h = target.squares_x * n_pitch, target.squares_y * n_pitch
        img[n_margin : n_margin + h, n_margin : n_margin + w] = pat.astype(np.float32) / 255.0
    else:
        # Circles: draw on an 8-bit canvas with anti-aliased, sub-texel (1/256) centres.
        canvas = np.full((H, W), 255, np.uint8)
        shift = 8
        pts = target.points_board_m
        uv = (A @ np.column_stack([pts[:, 0], pts[:, 1], np.ones(len(pts))]).T).T[:, :2]
        r_tex = 0.5 * target.circle_d_m * ppm
        for k, (c, r) in enumerate(uv):
            rad = r_tex * (2.0 if (target.kind == "modified_circles" and k == (target.rows - 1) * target.cols) else 1.0)
            cv2.circle(canvas, (int(round(c * 2**shift)), int(round(r * 2**shift))), int(round(rad * 2**shift)), 0,
                       thickness=-1, lineType=cv2.LINE_AA, shift=shift)
        img = canvas.astype(np.float32) / 255.0
    if white_on_black:
        img = 1.0 - img
    return Texture(image=img, A_tex_board=A, ppm=ppm)


@dataclass(frozen=True)
class RenderedView:
    """A rendered image and its exact truth.

    Attributes:
        image: (H, W) uint8 (or uint16 with ``bit_depth=16``) grey image.
        ids: (N,) ids of target points that project inside the image, facing the camera.
        uv_px: (N, 2) their exact pixel positions (OpenCV convention).
        T_cam_board: (4, 4) pose used.
    """

    image: np.ndarray
    ids: np.ndarray
    uv_px: np.ndarray
    T_cam_board: np.ndarray


# the last texture render_view painted, by what makes it (target, texels a square, margin): a hand-held
# session's frames of one hold need the same one (painting a 1080p board's costs ~25 ms)
_LAST_TEXTURE: dict = {}


def _texture_for(target: Target, ppm: float) -> Texture:
    """``board_texture(target, ppm)``, the last one again when it would be the same raster."""
    n_pitch = max(64 if target.kind == "charuco" else 2, int(round(target.pitch_m * float(ppm))))
    key = (target.spec_hash(), n_pitch)
    if target.kind != "charuco" and key in _LAST_TEXTURE:
        return _LAST_TEXTURE[key]
    tex = board_texture(target, ppm)
    tex.image.setflags(write=False)
    _LAST_TEXTURE.clear()
    _LAST_TEXTURE[key] = tex
    return tex


def _box_mean(samp: np.ndarray, nv: int, nu: int, S: int) -> np.ndarray:
    """The mean of every S x S block of sub-pixel samples: OpenCV's area resize at S = 4 (bitwise the same
    as numpy's mean there, 3-4x faster; tests/test_sim.py checks it on renders), numpy's mean otherwise."""
    if S == 4:
        import cv2

        return cv2.resize(samp, (nu, nv), interpolation=cv2.INTER_AREA)
    return samp.reshape(nv, S, nu, S).mean(axis=(1, 3))


def _normalised_rays(intr: Intrinsics, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return undistort_normalised(intr, np.column_stack([u, v]))


def render_view(target: Target, intr: Intrinsics, T_cam_board: np.ndarray, *, blur_sigma_px: float = 0.0,
                noise_sigma: float = 0.0, exposure: float = 1.0, black_level: float = 20.0,
                white_level: float = 220.0, background: float = 0.45, supersample: int = 4,
                bit_depth: int = 8, seed: int | None = 0, texture: Texture | None = None) -> RenderedView:
    """Render the target as seen by a camera.

    Args:
        target: the target.
        intr: camera intrinsics (width/height required).
        T_cam_board: (4, 4) board pose in the camera frame (OpenCV camera: z forward).
        blur_sigma_px: Gaussian optical blur, pixels.
        noise_sigma: additive Gaussian noise, grey levels (of 255).
        exposure: multiplies the light (1 = paper at ``white_level``).
        black_level, white_level: grey value of ink and paper at exposure 1.
        background: reflectance of the scene behind the board.
        supersample: samples per pixel along each axis.
        bit_depth: 8 or 16 (16 scales grey levels by 257).
        seed: noise seed.
        texture: a precomputed ``board_texture`` (reused across views for speed).
    Returns:
        :class:`RenderedView`.
    """
    import cv2

    T = np.asarray(T_cam_board, float)
    if T.shape != (4, 4):
        raise InputError("render: T_cam_board must be 4x4.")
    W, H = intr.width_px, intr.height_px
    if W <= 0 or H <= 0:
        raise InputError("render: intrinsics need width_px and height_px.")
    S = int(supersample)
    R, t = T[:3, :3], T[:3, 3]
    n = R[:, 2]  # board normal in the camera frame
    x0, y0, x1, y1 = target.extent_m
    m = target.pitch_m
    corners_b = np.array([[x0 - m, y0 - m, 0], [x1 + m, y0 - m, 0], [x1 + m, y1 + m, 0], [x0 - m, y1 + m, 0]])
    corners_c = corners_b @ R.T + t
    img = np.full((H, W), background, np.float32)
    if np.all(corners_c[:, 2] > 1e-3):
        # The board's image footprint; distortion can bend edges outwards, so pad generously.
        uvc = intr.project(corners_c)
        pad = 4 + int(0.05 * max(np.ptp(uvc[:, 0]), np.ptp(uvc[:, 1])))
        u_lo = int(max(0, np.floor(uvc[:, 0].min()) - pad))
        u_hi = int(min(W - 1, np.ceil(uvc[:, 0].max()) + pad))
        v_lo = int(max(0, np.floor(uvc[:, 1].min()) - pad))
        v_hi = int(min(H - 1, np.ceil(uvc[:, 1].max()) + pad))
        if u_hi > u_lo and v_hi > v_lo:
            if texture is None:
                # Texels as dense as the sub-pixel samples where the board is nearest.
                z_min = max(corners_c[:, 2].min(), 1e-3)
                dens = S * max(intr.K[0, 0], intr.K[1, 1]) / z_min
                dens = min(dens, 8000.0 / max(x1 - x0 + 2 * m, y1 - y0 + 2 * m))
                texture = _texture_for(target, dens)
            nu, nv = u_hi - u_lo + 1, v_hi - v_lo + 1
            # Sub-pixel sample (X, Y) of the region sits at image (u_lo + (X + 0.5) / S - 0.5, ...).
            M_img_ss = np.array([[1.0 / S, 0, u_lo + 0.5 / S - 0.5], [0, 1.0 / S, v_lo + 0.5 / S - 0.5], [0, 0, 1]])
            if not np.any(intr.dist8):
                # Pinhole: image <- board is the homography K [r1 r2 t]; one exact warp does it.
                H_img_board = intr.K @ np.column_stack([R[:, 0], R[:, 1], t])
                M = texture.A_tex_board @ np.linalg.inv(H_img_board) @ M_img_ss
                samp = cv2.warpPerspective(texture.image, M, (nu * S, nv * S), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                           borderMode=cv2.BORDER_CONSTANT, borderValue=float(background))
            else:
                # The image -> texture map is smooth: evaluate it at pixel centres, then let
                # cv2.resize (which samples source (X + 0.5) / S - 0.5, exactly the sub-pixel
                # sample positions) interpolate it bilinearly; 1/S^2 of the undistortion work.
                uu, vv = np.meshgrid(np.arange(u_lo, u_hi + 1, dtype=float), np.arange(v_lo, v_hi + 1, dtype=float))
                xy = _normalised_rays(intr, uu.ravel(), vv.ravel())
                # Ray (x, y, 1) meets the board plane n . (p - t) = 0 at lam = n.t / n.ray; the board
                # point is R^T (lam ray - t); then board -> texture by the affine A.
                denom = xy @ n[:2] + n[2]
                lam = (n @ t) / np.where(np.abs(denom) > 1e-12, denom, np.nan)
                pb_x = (lam * xy[:, 0] - t[0]) * R[0, 0] + (lam * xy[:, 1] - t[1]) * R[1, 0] + (lam - t[2]) * R[2, 0]
                pb_y = (lam * xy[:, 0] - t[0]) * R[0, 1] + (lam * xy[:, 1] - t[1]) * R[1, 1] + (lam - t[2]) * R[2, 1]
                A = texture.A_tex_board
                good = np.isfinite(lam) & (lam > 0)
                mx = np.where(good, A[0, 0] * pb_x + A[0, 1] * pb_y + A[0, 2], -1e4).reshape(uu.shape)
                my = np.where(good, A[1, 0] * pb_x + A[1, 1] * pb_y + A[1, 2], -1e4).reshape(uu.shape)
                mapx = cv2.resize(mx, (nu * S, nv * S), interpolation=cv2.INTER_LINEAR).astype(np.float32)
                mapy = cv2.resize(my, (nu * S, nv * S), interpolation=cv2.INTER_LINEAR).astype(np.float32)
                samp = cv2.remap(texture.image, mapx, mapy, cv2.INTER_LINEAR,
                                 borderMode=cv2.BORDER_CONSTANT, borderValue=float(background))
            # Samples that miss the sheet see the background; the sheet edge is a real edge too.
            block = _box_mean(samp, nv, nu, S)
            img[v_lo : v_hi + 1, u_lo : u_hi + 1] = block
    grey = black_level + (white_level - black_level) * img
    grey = grey * float(exposure)
    if blur_sigma_px > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), float(blur_sigma_px))
    if noise_sigma > 0:
        rng = np.random.default_rng(seed)
        grey = grey + rng.normal(0.0, noise_sigma, grey.shape).astype(np.float32)
    if bit_depth == 16:
        out = np.clip(np.round(grey * 257.0), 0, 65535).astype(np.uint16)
    elif bit_depth == 8:
        out = np.clip(np.round(grey), 0, 255).astype(np.uint8)
    else:
        raise InputError("render: bit_depth must be 8 or 16.")
    # Truth: points in front of the camera, on the visible side of the board, inside the image.
    p_c = target.points_board_m @ R.T + t
    uv = intr.project(p_c)
    facing = (n @ t) > 0 if target.kind != "modified_circles" else (n @ t) < 0
    ok = intr.in_image(uv, margin_px=0.0) & (p_c[:, 2] > 0)
    if not facing:
        ok[:] = False
    ids = np.nonzero(ok)[0]
    return RenderedView(image=out, ids=ids, uv_px=uv[ids], T_cam_board=T)


def look_at_board(target: Target, distance_m: float, tilt_x_deg: float = 0.0, tilt_y_deg: float = 0.0,
                  roll_deg: float = 0.0, offset_px: tuple = (0.0, 0.0), intr: Intrinsics | None = None) -> np.ndarray:
    """``T_cam_board`` placing the pattern's centre ``distance_m`` in front of the camera, facing
    it (printed side towards the camera), turned by ``roll_deg`` about the viewing axis and tilted
    about the board's x then y axes; ``offset_px`` moves the centre in the image (needs ``intr``)."""

    x0, y0, x1, y1 = target.extent_m
    centre_b = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    # Facing: board z points away from the camera (+z camera) for boards whose z goes into the
    # sheet; the modified circle grid's z comes out of the sheet, so it is turned about x.
    R0 = np.eye(3) if target.kind != "modified_circles" else np.diag([1.0, -1.0, -1.0])
    R = exp_so3(np.radians(roll_deg) * np.array([0, 0, 1.0])) @ R0 @ exp_so3(np.radians(tilt_x_deg) * np.array([1.0, 0, 0])) \
        @ exp_so3(np.radians(tilt_y_deg) * np.array([0, 1.0, 0]))
    c = np.array([0.0, 0.0, distance_m])
    if intr is not None and any(offset_px):
        c[0] = offset_px[0] * distance_m / intr.K[0, 0]
        c[1] = offset_px[1] * distance_m / intr.K[1, 1]
    t = c - R @ centre_b
    return make_T(R, t)
