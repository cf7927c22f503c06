"""calibgraph's built-in renderer: the workcell's images without any system OpenGL library.

MuJoCo loads, compiles and moves a model without OpenGL; only its renderer needs libEGL or
libOSMesa. Where neither loads, :class:`Rasteriser` draws the same scene from the same model and
state:

- **visibility** by ray casting (``mujoco.mj_multiRay``, one ray through every pixel centre, or
  through every sub-pixel with ``Realism.supersample``) against the rendered geometry — the arm's
  visual meshes, the stands, the floor and the board — so the robot hides the board exactly where
  its geometry does;
- **the board** from the scene's own texture (:func:`calibgraph.sim.scene.board_texture`, the
  image MuJoCo maps on the board's printed face) by exact plane-to-image homography, sampled at
  4 x 4 sub-pixels per pixel from a box-filtered mipmap whose texels are no coarser than the
  sub-pixel spacing, and box-averaged over each pixel: the pixel's light-collecting area, so the
  square edges (hence the corners) are where the geometry puts them;
- **shading** as MuJoCo's renderer lights the scene: the headlight (ambient + diffuse along the
  camera axis) and the model's lights (diffuse, spot cone and exponent), on each material's
  colour; the sky is black.

The camera is MuJoCo's: principal point at ((W - 1) / 2, (H - 1) / 2), focal length from the
camera's vertical field of view, pinhole. Exposure, lens distortion, blur and noise are applied
afterwards by :func:`calibgraph.sim.render.degrade`, exactly as for a MuJoCo render.
"""

from __future__ import annotations

import numpy as np

from calibgraph.sim.scene import board_texture

# Rendered geom groups (MuJoCo's default visibility): 0, 1, 2; group 3 holds collision-only geoms.
RENDERED_GROUPS = np.array([1, 1, 1, 0, 0, 0], np.uint8)
BOARD_SUBSAMPLES = 4  # per pixel and axis, for the board's texture
TILE = 4  # samples between the first, coarse rays
MAX_MIP_LEVEL = 6  # the sheet is a multiple of 64 texels: levels up to 6 average whole blocks


class Rasteriser:
    """Render a :class:`calibgraph.sim.render.SimWorld` camera without OpenGL (module docstring)."""

    def __init__(self, world):
        self.world = world
        m = world.model
        self.mj = world.mujoco
        self.board_geom = m.geom("board_geom").id
        tex = board_texture(world.cell.target)
        self.tex = tex
        level = tex.image[..., 0].astype(np.float32) / 255.0
        self.mips = [level]
        for _ in range(MAX_MIP_LEVEL):
            h, w = level.shape
            level = level.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))
            self.mips.append(level)
        # colour of every geom: its material's, else its own (MuJoCo's rule)
        rgba = np.where((m.geom_matid >= 0)[:, None], m.mat_rgba[np.maximum(m.geom_matid, 0)], m.geom_rgba)
        self.colour = np.vstack([rgba[:, :3], np.zeros((1, 3))]).astype(np.float32)  # row -1: sky (no hit)
        self._rays = {}

    # -- camera ----------------------------------------------------------------------------------------
    def camera(self, name: str, w: int, h: int):
        """(K (3, 3), T_base_cam (4, 4)) of MuJoCo's camera ``name`` at the current state: OpenCV
        optical frame and the pinhole MuJoCo renders with at w x h."""
        m, d = self.world.model, self.world.data
        cid = m.camera(name).id
        f = 0.5 * h / np.tan(np.radians(m.cam_fovy[cid]) / 2)
        K = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
        T = np.eye(4)
        T[:3, :3] = d.cam_xmat[cid].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
        T[:3, 3] = d.cam_xpos[cid]
        return K, T

    def _camera_rays(self, K: np.ndarray, w: int, h: int, s: int) -> np.ndarray:
        """Unit ray directions (h s, w s, 3), camera frame, through the centres of s x s sub-pixels."""
        key = (K.tobytes(), w, h, s)
        if key not in self._rays:
            u = (np.arange(w * s) + 0.5) / s - 0.5
            v = (np.arange(h * s) + 0.5) / s - 0.5
            x = (u - K[0, 2]) / K[0, 0]
            y = (v - K[1, 2]) / K[1, 1]
            r = np.empty((h * s, w * s, 3))
            r[..., 0] = x[None, :]
            r[..., 1] = y[:, None]
            r[..., 2] = 1.0
            r /= np.linalg.norm(r, axis=2, keepdims=True)
            self._rays = {key: r}  # one size at a time: a cell's cameras rarely differ, and it is large
        return self._rays[key]

    # -- rendering -------------------------------------------------------------------------------------
    def render(self, name: str, w: int, h: int, s: int = 1) -> np.ndarray:
        """RGB (h, w, 3) uint8 of camera ``name`` at the world's current state; ``s``: sub-pixel
        rays per pixel and axis (area-averaged, as MuJoCo renders with ``Realism.supersample``).

        Rays are cast on a grid every ``TILE`` samples first; a tile whose four corner rays meet
        the same geom (not the board) is shaded by interpolating their light, every other tile
        and the whole region where the board can be gets one ray per sample (MuJoCo's renderer
        does not antialias silhouettes either). A feature thinner than a tile that falls between
        corner rays away from the board can be missed; the board and whatever hides it cannot.
        """
        import cv2

        K, T = self.camera(name, w, h)
        R, o = T[:3, :3], T[:3, 3]
        Ws, Hs = w * s, h * s
        rays_c = self._camera_rays(K, w, h, s)
        B = TILE
        # coarse rays at samples (B i, B j), one node past the last sample so every tile is closed
        ny, nx = (Hs - 1) // B + 2, (Ws - 1) // B + 2
        cy, cx = np.minimum(np.arange(ny) * B, Hs - 1), np.minimum(np.arange(nx) * B, Ws - 1)
        gid_n, light_n, _, _ = self._cast(o, rays_c[cy][:, cx].reshape(-1, 3) @ R.T, R[:, 2])
        gid_n, light_n = gid_n.reshape(ny, nx), light_n.reshape(ny, nx)
        g00, g01, g10, g11 = gid_n[:-1, :-1], gid_n[:-1, 1:], gid_n[1:, :-1], gid_n[1:, 1:]
        mixed = (g00 != g01) | (g00 != g10) | (g00 != g11) | (g00 == self.board_geom)
        fine = np.repeat(np.repeat(mixed, B, axis=0), B, axis=1)[:Hs, :Ws]
        T_base_board = self.world.T_base_board()
        T_cam_board = np.linalg.solve(T, T_base_board)
        box = self._sheet_box(K, T_cam_board, w, h)  # pixels
        if box is not None:
            u_lo, v_lo, u_hi, v_hi = box
            fine[v_lo * s:(v_hi + 1) * s, u_lo * s:(u_hi + 1) * s] = True
        # smooth tiles: the corner nodes' colour and light (one geom: bilinear in the light alone)
        node = np.ascontiguousarray(self.colour[gid_n] * light_n[..., None])
        rgb = cv2.warpAffine(node, np.array([[1.0 / B, 0, 0], [0, 1.0 / B, 0]]), (Ws, Hs),
                             flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
        # the rest: a ray per sample
        idx = np.flatnonzero(fine)
        if idx.size:
            dirs = rays_c.reshape(-1, 3)[idx] @ R.T
            gid, lt, nrm, _ = self._cast(o, dirs, R[:, 2])
            col = self.colour[gid] * lt[:, None]
            front = (gid == self.board_geom) & (nrm @ T_base_board[:3, 2] < 0)  # printed face: normal -z_board
            if front.any():
                refl = self._board_reflectance(K, T_cam_board, w, h, box)
                k = idx[front]
                col[front] *= refl[(k // Ws) // s, (k % Ws) // s][:, None]
            rgb.reshape(-1, 3)[idx] = col
        if s > 1:
            rgb = rgb.reshape(h, s, w, s, 3).mean(axis=(1, 3))
        return cv2.convertScaleAbs(rgb, alpha=255.0)  # saturating round to uint8

    def _cast(self, o: np.ndarray, dirs: np.ndarray, cam_z: np.ndarray):
        """(geom id (N,), light (N,) float32, normal (N, 3), distance (N,)) of rays from ``o``
        along unit ``dirs`` (N, 3), base frame; geom -1 and light 0 where a ray meets nothing."""
        n = dirs.shape[0]
        gid = np.empty(n, np.int32)
        dist = np.empty(n)
        nrm = np.empty(3 * n)
        self.mj.mj_multiRay(self.world.model, self.world.data, np.asarray(o, float).copy(),
                            np.ascontiguousarray(dirs, dtype=float).reshape(-1), RENDERED_GROUPS, 1, -1, gid, dist, nrm, n, 1e3)
        nrm = nrm.reshape(-1, 3)
        light = np.zeros(n, np.float32)
        hit = gid >= 0
        if hit.any():
            light[hit] = self._shade(o + dist[hit, None] * dirs[hit], nrm[hit], dirs[hit], cam_z)
        return gid, light, nrm, dist

    def _shade(self, p: np.ndarray, nrm: np.ndarray, dirs: np.ndarray, cam_z: np.ndarray) -> np.ndarray:
        """Light reaching points ``p`` (N, 3) with normals ``nrm`` seen along ``dirs``: MuJoCo's
        headlight (a directional light along the camera axis) and the model's lights, two-sided."""
        m, d = self.world.model, self.world.data
        nrm = np.where((np.einsum("ij,ij->i", nrm, dirs) > 0)[:, None], -nrm, nrm)  # face the camera
        hl = m.vis.headlight
        light = float(hl.ambient[0]) + float(hl.diffuse[0]) * np.maximum(nrm @ -cam_z, 0.0) if hl.active else np.zeros(len(p))
        for k in range(m.nlight):
            if not m.light_active[k]:
                continue
            if m.light_type[k] == self.mj.mjtLightType.mjLIGHT_DIRECTIONAL:
                L = np.broadcast_to(-d.light_xdir[k], p.shape)
                spot = 1.0
            else:
                L = d.light_xpos[k] - p
                dist = np.linalg.norm(L, axis=1)
                L = L / dist[:, None]
                cos_s = -L @ d.light_xdir[k]
                spot = np.where(cos_s >= np.cos(np.radians(m.light_cutoff[k])), np.maximum(cos_s, 0) ** m.light_exponent[k], 0.0)
                att = m.light_attenuation[k]
                spot = spot / (att[0] + att[1] * dist + att[2] * dist**2)
            light = light + float(m.light_ambient[k][0]) + float(m.light_diffuse[k][0]) * spot * np.maximum(
                np.einsum("ij,ij->i", nrm, L), 0.0)
        return np.clip(light, 0.0, 1.0).astype(np.float32)

    def _sheet_box(self, K: np.ndarray, T_cam_board: np.ndarray, w: int, h: int):
        """(u_lo, v_lo, u_hi, v_hi) pixels the printed sheet can cover (the whole image when it
        reaches behind the camera), or None when it is outside the image."""
        tex = self.tex
        R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
        x0, y0 = tex.x0_m, tex.y0_m
        x1, y1 = x0 + tex.width_m, y0 + tex.height_m
        sheet = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]]) @ R.T + t
        if np.all(sheet[:, 2] <= 0):
            return None
        if np.any(sheet[:, 2] < 1e-3):
            return 0, 0, w - 1, h - 1
        uv = sheet[:, :2] / sheet[:, 2:] * K[[0, 1], [0, 1]] + K[:2, 2]
        u_lo, v_lo = max(0, int(np.floor(uv[:, 0].min())) - 1), max(0, int(np.floor(uv[:, 1].min())) - 1)
        u_hi, v_hi = min(w - 1, int(np.ceil(uv[:, 0].max())) + 1), min(h - 1, int(np.ceil(uv[:, 1].max())) + 1)
        return (u_lo, v_lo, u_hi, v_hi) if u_hi >= u_lo and v_hi >= v_lo else None

    def _board_reflectance(self, K: np.ndarray, T_cam_board: np.ndarray, w: int, h: int, box) -> np.ndarray:
        """(h, w) float32: the printed sheet's reflectance averaged over each pixel of ``box`` (4 x 4
        samples of the mipmap level whose texels are no finer than needed and no coarser than the
        samples); 1 elsewhere."""
        import cv2

        tex, S = self.tex, BOARD_SUBSAMPLES
        out = np.ones((h, w), np.float32)
        if box is None:
            return out
        u_lo, v_lo, u_hi, v_hi = box
        R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
        # sample spacing on the sheet where it is nearest, in level-0 texels -> the mip level at or below it
        corners = np.array([[tex.x0_m, tex.y0_m], [tex.x0_m + tex.width_m, tex.y0_m + tex.height_m]])
        z_near = max(float(min((R[2, 0] * x + R[2, 1] * y + t[2]) for x in corners[:, 0] for y in corners[:, 1])), 1e-3)
        spacing = z_near / (max(K[0, 0], K[1, 1]) * S) / tex.texel_m
        L = int(np.clip(np.floor(np.log2(max(spacing, 1.0))), 0, MAX_MIP_LEVEL))
        texel = tex.texel_m * 2**L
        A = np.array([[1 / texel, 0, -tex.x0_m / texel - 0.5], [0, 1 / texel, -tex.y0_m / texel - 0.5], [0, 0, 1.0]])
        nu, nv = u_hi - u_lo + 1, v_hi - v_lo + 1
        M_img_ss = np.array([[1.0 / S, 0, u_lo + 0.5 / S - 0.5], [0, 1.0 / S, v_lo + 0.5 / S - 0.5], [0, 0, 1]])
        H_img_board = K @ np.column_stack([R[:, 0], R[:, 1], t])
        M = A @ np.linalg.inv(H_img_board) @ M_img_ss
        samp = cv2.warpPerspective(self.mips[L], M, (nu * S, nv * S), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_REPLICATE)
        out[v_lo:v_hi + 1, u_lo:u_hi + 1] = samp.reshape(nv, S, nu, S).mean(axis=(1, 3))
        return out
