"""The report's maps: where in each image a camera saw corners (coverage), and how far a point
measured by the camera can be off in the robot frame because of the camera's pose uncertainty
alone (the workspace 1σ map, :func:`calibgraph.solver.uncertainty.workspace.workspace_sigma_map`)."""

from __future__ import annotations

import numpy as np

from calibgraph.report import svgplot
from calibgraph.report.markup import esc, num
from calibgraph.solver.uncertainty.workspace import visible_mask, workspace_grid, workspace_sigma_map


def coverage_plot(name: str, residuals: dict, intr) -> str:
    """Heat map of where in the image camera ``name`` saw corners (its residual records)."""
    uv = [np.asarray(v["uv_detected_px"], float).reshape(-1, 2) for v in residuals.values()
          if v.get("uv_detected_px") is not None and len(v["uv_detected_px"])]
    if not uv:
        return svgplot.empty_plot(f"{name}: image coverage", "no detections available (give --dataset)")
    uv = np.concatenate(uv)
    if intr is not None and intr.width_px > 0:
        W, H = intr.width_px, intr.height_px
    else:
        W, H = float(np.ceil(uv[:, 0].max())), float(np.ceil(uv[:, 1].max()))
    nx = 16
    ny = max(2, int(round(nx * H / W)))
    xe = np.linspace(-0.5, W - 0.5, nx + 1)
    ye = np.linspace(-0.5, H - 0.5, ny + 1)
    counts, _, _ = np.histogram2d(uv[:, 1], uv[:, 0], bins=(ye, xe))
    frac = float((counts > 0).mean())
    V = np.where(counts > 0, counts, np.nan)
    return svgplot.heatmap(V, xe, ye, title=f"{name}: image coverage ({100 * frac:.0f}% of cells seen)", xlabel="u (px)",
                           ylabel="v (px)", cbar_label="corners", width=470, y_down=True, nan_label="no corner")


def workspace_maps(result, tol: dict, intr: dict) -> dict:
    """Per-camera 1σ point-error maps of ``result``: ``{'svg': camera -> plot, 'worst': camera ->
    worst visible 1σ (mm) or None, 'html': the explanation and the comparison table}``."""
    wcfg = tol.get("workspace") or {}
    poses = {n: c.T_ref_cam for n, c in result.calibrated.items()}
    cov = {n: c.covariance for n, c in result.calibrated.items()}
    names = list(poses)
    out = {"svg": {}, "worst": {}, "html": ""}
    n_grid = int(wcfg.get("grid_n", 24))
    maps = {}
    if result.mode == "eye_in_hand":
        depth = wcfg.get("depth_m", [0.15, 1.0])
        lat = wcfg.get("lateral_m", [-0.4, 0.4])
        xs = np.linspace(lat[0], lat[1], n_grid)
        zs = np.linspace(depth[0], depth[1], n_grid)
        X, Z = np.meshgrid(xs, zs)
        for n in names:
            T = poses[n]
            p_cam = np.stack([X, np.zeros_like(X), Z], -1)
            p_ref = p_cam @ T[:3, :3].T + T[:3, 3]
            m = workspace_sigma_map(T, cov[n], p_ref)
            if intr[n] is not None:
                m = np.where(visible_mask(T, intr[n], p_ref), m, np.nan)
            maps[n] = m
        xe, ye = _edges(xs), _edges(zs)
        xlabel, ylabel = "camera x (m)", "depth, camera z (m)"
        where = ("points in the camera's horizontal plane (camera x–z), in front of it, expressed in the flange frame; "
                 "grey = outside the image")
        markers = {n: [{"x": 0.0, "y": depth[0], "label": "camera"}] for n in names}
    else:
        xr, yr, z = _default_workspace(result, wcfg)
        xs, ys, P = workspace_grid(xr, yr, z, n=n_grid)
        for n in names:
            m = workspace_sigma_map(poses[n], cov[n], P)
            if intr[n] is not None:
                m = np.where(visible_mask(poses[n], intr[n], P), m, np.nan)
            maps[n] = m
        xe, ye = _edges(xs), _edges(ys)
        xlabel, ylabel = "base x (m)", "base y (m)"
        where = (f"top view of the workspace at height z = {z:.2f} m in the robot base frame "
                 f"(x {xr[0]:.2f}…{xr[1]:.2f} m, y {yr[0]:.2f}…{yr[1]:.2f} m); grey = outside the camera's image")
        markers = {}
        for n in names:
            mk = []
            if xe[0] <= 0 <= xe[-1] and ye[0] <= 0 <= ye[-1]:
                mk.append({"x": 0.0, "y": 0.0, "label": "robot base", "color": "#ffffff"})
            mk.append(camera_marker(n, poses[n], xe, ye))
            markers[n] = mk
        where += ("; the camera is drawn where it stands (on the map's edge, as a diamond, when it stands beyond "
                  "it), with an arrow the way it looks")
    rows = []
    for n in names:
        m = maps[n]
        worst = float(np.nanmax(m)) if np.isfinite(m).any() else None
        best = float(np.nanmin(m)) if np.isfinite(m).any() else None
        out["worst"][n] = worst
        label = ""
        if result.mode != "eye_in_hand":
            label = f" (camera {np.linalg.norm(poses[n][:3, 3]):.1f} m from base)"
        # each camera on its own colour scale: the pattern (which way the error grows) is the point;
        # the table compares cameras
        out["svg"][n] = svgplot.heatmap(m, xe, ye, title=f"{n}: 1σ point error from pose uncertainty{label}",
                                        xlabel=xlabel, ylabel=ylabel, cbar_label="1σ mm (3D)", width=540,
                                        markers=markers.get(n), nan_label="not visible")
        rows.append(f'<tr data-camera="{esc(n)}"><td class="l">{esc(n)}</td><td>{num(best, ".3f")}</td>'
                    f'<td>{num(worst, ".3f")}</td><td>{num(np.isfinite(m).mean() * 100, ".0f")}</td></tr>')
    out["html"] = (
        '<p class="note">Expected localisation error caused by each camera\'s pose uncertainty alone: a point the camera '
        "measures is reported in the robot frame through T_ref_cam, so its 1σ position error is "
        "sqrt(trace(J Σ J<sup>T</sup>)), J = [−[p − t]<sub>×</sub>, I] (rotation first). It grows with the distance from the "
        f"camera through the rotation uncertainty. Maps: {esc(where)}. Each map has its own colour scale (the table "
        "below compares cameras); the maps are shown in each camera's section above.</p>"
        '<table id="workspace"><tr><th class="l">camera</th><th>best 1σ (mm)</th><th>worst visible 1σ (mm)</th>'
        "<th>map cells visible (%)</th></tr>" + "".join(rows) + "</table>"
    )
    return out


def camera_marker(n: str, T_base_cam, xe, ye) -> dict:
    """The workspace map's marker of camera ``n``: where it stands (x, y in the base frame) and the
    way it looks (its optical axis, projected on the map), labelled with its distance when it stands
    beyond the map and drawn on its edge."""
    T = np.asarray(T_base_cam, float)
    t, z = T[:3, 3], T[:3, 2]
    inside = xe[0] <= t[0] <= xe[-1] and ye[0] <= t[1] <= ye[-1]
    centre = np.array([(xe[0] + xe[-1]) / 2, (ye[0] + ye[-1]) / 2])
    label = n if inside else f"{n}, {np.linalg.norm(t[:2] - centre):.1f} m off the map"
    if np.hypot(z[0], z[1]) < 0.2:
        label += " (looking down)"
    return {"x": float(t[0]), "y": float(t[1]), "label": label, "color": "#ff7f0e",
            "dir": (float(z[0]), float(z[1])) if np.hypot(z[0], z[1]) >= 0.2 else None}


def _edges(c):
    """Bin edges around the given bin centres."""
    c = np.asarray(c, float)
    d = np.diff(c)
    return np.concatenate([[c[0] - d[0] / 2], c[:-1] + d / 2, [c[-1] + d[-1] / 2]])


def _default_workspace(result, wcfg):
    """Workspace extent: config, else where the board was presented (+15 cm), else a Panda-sized box."""
    if "x_m" in wcfg and "y_m" in wcfg:
        return wcfg["x_m"], wcfg["y_m"], float(wcfg.get("z_m", 0.5))
    flange = list(result.T_base_flange_est.values())
    T_fb = result.T_flange_board
    if flange:
        if T_fb is not None:
            pts = np.array([(F @ T_fb)[:3, 3] for F in flange])
        else:
            pts = np.array([F[:3, 3] for F in flange])
        lo, hi = pts.min(0) - 0.15, pts.max(0) + 0.15
        z = float(wcfg.get("z_m", np.median(pts[:, 2])))
        return wcfg.get("x_m", [lo[0], hi[0]]), wcfg.get("y_m", [lo[1], hi[1]]), z
    return wcfg.get("x_m", [0.0, 0.9]), wcfg.get("y_m", [-0.6, 0.6]), float(wcfg.get("z_m", 0.5))
