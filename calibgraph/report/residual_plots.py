"""The report's residual section: per camera, the histogram of the used corners' residuals and the
residuals per capture with the rejected corners and views marked."""

from __future__ import annotations

import numpy as np

from calibgraph.report import svgplot
from calibgraph.report.markup import esc


def residuals_html(result, residuals: dict, source: str) -> str:
    """The residual plots of ``result``'s cameras, or how to get them (give the dataset)."""
    h = ["<h2>Residuals</h2>"]
    if any(residuals.values()):
        h.append(f'<p class="note">Per-corner residuals ({esc(source)}): residual = reprojected − detected corner.</p>')
        h += [_camera_plots(result, n, residuals[n]) for n in result.calibrated if residuals.get(n)]
    else:
        h.append('<p class="note">No per-corner residuals: the result has no <code>residuals</code> section and no '
                 "dataset was given (<code>calibgraph report RESULT --dataset DIR</code> recomputes them).</p>")
    return "\n".join(h)


def _camera_plots(result, n: str, res: dict) -> str:
    """Histogram of the used corners' residual norms and residual norms per capture, rejections marked."""
    k_out = result.settings.get("outlier_sigmas")
    sig = result.pixel_sigma_px
    thresh = float(sig) * float(k_out) if k_out and np.isfinite(sig) and sig > 0 else None
    used_norm, caps_used, out_x, out_y, rv_x, rv_y, rms_x, rms_y = [], [], [], [], [], [], [], []
    for k, v in sorted(res.items()):
        r = np.asarray(v["residual_px"], float).reshape(-1, 2)
        if r.size == 0:
            continue
        norm = np.linalg.norm(r, axis=1)
        bad = np.asarray(v["weight"]) == 0
        if v["rejected"]:
            rv_x += [k] * norm.size
            rv_y += norm.tolist()
            continue
        used_norm += norm[~bad].tolist()
        caps_used += [k] * int((~bad).sum())
        out_x += [k] * int(bad.sum())
        out_y += norm[bad].tolist()
        if (~bad).any():
            rms_x.append(k)
            rms_y.append(float(np.sqrt(np.mean(norm[~bad] ** 2))))
    rms = result.cameras[n].reprojection_rms_px
    vl = {f"RMS {rms:.3f} px": rms}
    if thresh:
        vl[f"outlier limit {thresh:.2f} px"] = thresh
    h = ['<div class="plots">',
         svgplot.histogram(used_norm, bins=30, title=f"{n}: |residual| of used corners", xlabel="|residual| (px)",
                           width=380, vlines={k: v for k, v in vl.items() if np.isfinite(v)})]
    series = [
        {"x": caps_used, "y": used_norm, "label": "corner (used)", "color": "#9aa9b8", "size": 1.6, "opacity": 0.6},
        {"x": rms_x, "y": rms_y, "label": "view RMS", "color": svgplot.BLUE, "size": 3.0},
        {"x": out_x, "y": out_y, "label": "rejected corner", "color": svgplot.RED, "marker": "x", "size": 3.5},
        {"x": rv_x, "y": rv_y, "label": "rejected view", "color": svgplot.ORANGE, "marker": "s", "size": 2.2},
    ]
    # far outliers would squash the used corners into a flat line: clip the axis and pin them to its top
    typical = np.percentile(used_norm, 99.5) if used_norm else 1.0
    top = max(typical * 1.6, (thresh or 0) * 1.25, 1e-3)
    clipped = 0
    for s in series:
        y = np.asarray(s["y"], float)
        clipped += int((y > top).sum())
        s["y"] = np.minimum(y, top)
    title = f"{n}: residual per view (capture)"
    if clipped:
        title += f" — {clipped} point(s) above {top:.2f} px drawn at the top edge"
    h.append(svgplot.scatter(series, title=title, xlabel="capture", ylabel="|residual| (px)", width=640,
                             ylim=(0.0, top * 1.04), hlines={f"outlier limit {thresh:.2f} px": thresh} if thresh else None))
    h.append("</div>")
    return "\n".join(h)
