"""Tiny dependency-free SVG plots for the commissioning report.

Each function returns an ``<svg>`` element as a string that can be inlined in HTML, so the
report is one self-contained file with no plotting library (matplotlib is not a dependency).
Plots: histogram, scatter (with per-point colours and markers), heat map with a colour bar.
Coordinates are data units; every plot has labelled axes with "nice" ticks.
"""

from __future__ import annotations

import html
import math

import numpy as np

# viridis, sampled at 9 stops (perceptually uniform, colour-blind safe)
_VIRIDIS = [
    (68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 144, 141),
    (39, 173, 129), (92, 200, 99), (170, 220, 50), (253, 231, 37),
]

BLUE = "#1f77b4"
RED = "#d62728"
ORANGE = "#ff7f0e"


def colormap(x: float) -> str:
    """Viridis colour of x in [0, 1] as '#rrggbb'."""
    if not np.isfinite(x):
        return "#dddddd"
    x = min(max(float(x), 0.0), 1.0) * (len(_VIRIDIS) - 1)
    i = min(int(x), len(_VIRIDIS) - 2)
    f = x - i
    c = [round(a + (b - a) * f) for a, b in zip(_VIRIDIS[i], _VIRIDIS[i + 1])]
    return "#%02x%02x%02x" % tuple(c)


def nice_ticks(lo: float, hi: float, n: int = 5) -> list:
    """About n round tick values covering [lo, hi]."""
    if not (np.isfinite(lo) and np.isfinite(hi)):
        return []
    if hi - lo <= 1e-9 * max(abs(lo), abs(hi)):  # empty or within rounding: a step that small never advances
        hi = lo + (abs(lo) if lo else 1.0)
    raw = (hi - lo) / max(n, 1)
    mag = 10 ** math.floor(math.log10(raw))
    step = min((s * mag for s in (1, 2, 2.5, 5, 10) if s * mag >= raw), default=10 * mag)
    start = math.ceil(lo / step - 1e-9) * step
    ticks = []
    v = start
    while v <= hi + 1e-9 * step:
        ticks.append(round(v, 12))
        v += step
    return ticks


def _fmt(v: float) -> str:
    if v == 0:
        return "0"
    a = abs(v)
    if a >= 1e5 or a < 0.01:
        return f"{v:.2g}"
    return f"{v:.4g}"


def _esc(s) -> str:
    return html.escape(str(s), quote=True)


class _Axes:
    """Maps data to pixel coordinates inside a plot frame and draws axes."""

    def __init__(self, width, height, xlim, ylim, left=62, right=16, top=30, bottom=44, y_down=False):
        self.w, self.h = width, height
        self.l, self.r, self.t, self.b = left, right, top, bottom
        self.xlim = xlim
        self.ylim = ylim
        self.y_down = y_down  # image coordinates: v grows downwards
        self.parts = []

    def X(self, x):
        x0, x1 = self.xlim
        return self.l + (x - x0) / ((x1 - x0) or 1) * (self.w - self.l - self.r)

    def Y(self, y):
        y0, y1 = self.ylim
        f = (y - y0) / ((y1 - y0) or 1)
        if self.y_down:
            return self.t + f * (self.h - self.t - self.b)
        return self.h - self.b - f * (self.h - self.t - self.b)

    def frame(self, title, xlabel, ylabel):
        p = self.parts
        pw, ph = self.w - self.l - self.r, self.h - self.t - self.b
        p.append(f'<rect x="{self.l}" y="{self.t}" width="{pw}" height="{ph}" fill="none" stroke="#333"/>')
        for v in nice_ticks(*self.xlim):
            x = self.X(v)
            p.append(f'<line x1="{x:.1f}" y1="{self.h - self.b}" x2="{x:.1f}" y2="{self.h - self.b + 4}" stroke="#333"/>')
            p.append(f'<text x="{x:.1f}" y="{self.h - self.b + 16}" text-anchor="middle">{_fmt(v)}</text>')
        for v in nice_ticks(*self.ylim):
            y = self.Y(v)
            p.append(f'<line x1="{self.l - 4}" y1="{y:.1f}" x2="{self.l}" y2="{y:.1f}" stroke="#333"/>')
            p.append(f'<text x="{self.l - 6}" y="{y + 4:.1f}" text-anchor="end">{_fmt(v)}</text>')
        p.append(f'<text x="{self.l + pw / 2:.1f}" y="{self.h - 8}" text-anchor="middle">{_esc(xlabel)}</text>')
        p.append(f'<text x="14" y="{self.t + ph / 2:.1f}" text-anchor="middle" '
                 f'transform="rotate(-90 14 {self.t + ph / 2:.1f})">{_esc(ylabel)}</text>')
        p.append(f'<text x="{self.w / 2:.1f}" y="18" text-anchor="middle" font-weight="bold">{_esc(title)}</text>')

    def svg(self, extra_width=0):
        body = "\n".join(self.parts)
        return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{self.w + extra_width}" height="{self.h}" '
                f'viewBox="0 0 {self.w + extra_width} {self.h}" font-family="sans-serif" font-size="11">\n{body}\n</svg>')


def histogram(values, bins: int = 30, title: str = "", xlabel: str = "", ylabel: str = "count",
              width: int = 420, height: int = 260, color: str = BLUE, vlines: dict | None = None) -> str:
    """Histogram of ``values``; ``vlines`` = {label: x} draws labelled vertical markers (e.g. RMS)."""
    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return empty_plot(title, "no data", width, height)
    lo, hi = float(v.min()), float(v.max())
    if vlines:
        hi = max([hi] + [float(x) for x in vlines.values()])
    lo = min(lo, 0.0) if lo >= 0 else lo
    if hi <= lo:
        hi = lo + 1.0
    counts, edges = np.histogram(v, bins=bins, range=(lo, hi))
    ax = _Axes(width, height, (lo, hi), (0, max(1, counts.max()) * 1.08))
    for c, e0, e1 in zip(counts, edges[:-1], edges[1:]):
        if c:
            x0, x1, y = ax.X(e0), ax.X(e1), ax.Y(c)
            ax.parts.append(f'<rect x="{x0:.1f}" y="{y:.1f}" width="{max(x1 - x0 - 0.5, 0.5):.1f}" '
                            f'height="{ax.Y(0) - y:.1f}" fill="{color}"/>')
    for i, (label, x) in enumerate((vlines or {}).items()):
        px = ax.X(float(x))
        col = RED if i else ORANGE
        ax.parts.append(f'<line x1="{px:.1f}" y1="{ax.t}" x2="{px:.1f}" y2="{ax.h - ax.b}" stroke="{col}" stroke-dasharray="4 3"/>')
        right = px > ax.l + 0.6 * (ax.w - ax.l - ax.r)
        anchor, dx = ("end", -3) if right else ("start", 3)
        ax.parts.append(f'<text x="{px + dx:.1f}" y="{ax.t + 12 + 12 * i}" text-anchor="{anchor}" fill="{col}">{_esc(label)}</text>')
    ax.frame(title, xlabel, ylabel)
    return ax.svg()


def scatter(series: list, title: str = "", xlabel: str = "", ylabel: str = "", width: int = 860,
            height: int = 280, xlim=None, ylim=None, y_down: bool = False, hlines: dict | None = None,
            legend: bool = True, aspect_equal: bool = False, rect=None) -> str:
    """Scatter plot of several series.

    ``series``: list of dicts with keys x, y (arrays), label, color, marker ('o' dot, 'x' cross,
    's' square), size (px radius), opacity. ``rect`` = (x0, y0, x1, y1) draws a reference
    rectangle (e.g. the image border). ``y_down`` flips the y axis (image coordinates).
    """
    xs = np.concatenate([np.asarray(s["x"], float).ravel() for s in series] or [np.zeros(0)])
    ys = np.concatenate([np.asarray(s["y"], float).ravel() for s in series] or [np.zeros(0)])
    fin = np.isfinite(xs) & np.isfinite(ys)
    if xlim is None:
        xlim = (float(xs[fin].min()), float(xs[fin].max())) if fin.any() else (0.0, 1.0)
        pad = 0.03 * ((xlim[1] - xlim[0]) or 1)
        xlim = (xlim[0] - pad, xlim[1] + pad)
    if ylim is None:
        hi = float(ys[fin].max()) if fin.any() else 1.0
        lo = min(0.0, float(ys[fin].min())) if fin.any() else 0.0
        if hlines:
            hi = max([hi] + [float(v) for v in hlines.values()])
        ylim = (lo, hi * 1.08 if hi > 0 else 1.0)
    if aspect_equal:
        # keep data aspect ratio by shrinking the plot height
        dx, dy = xlim[1] - xlim[0], ylim[1] - ylim[0]
        height = int(30 + 44 + (width - 62 - 16) * dy / dx)
    labels = [s for s in series if s.get("label")] if legend else []
    # the legend stands right of the frame, off the data
    legend_w = 12 + 7 * max((len(str(s["label"])) for s in labels), default=0) + 22 if labels else 0
    ax = _Axes(width, height, xlim, ylim, y_down=y_down, right=16 + legend_w)
    if rect is not None:
        x0, y0, x1, y1 = rect
        X0, X1 = sorted((ax.X(x0), ax.X(x1)))
        Y0, Y1 = sorted((ax.Y(y0), ax.Y(y1)))
        ax.parts.append(f'<rect x="{X0:.1f}" y="{Y0:.1f}" width="{X1 - X0:.1f}" height="{Y1 - Y0:.1f}" '
                        f'fill="#f7f7f7" stroke="#888" stroke-dasharray="3 2"/>')
    for label, yv in (hlines or {}).items():
        py = ax.Y(float(yv))
        ax.parts.append(f'<line x1="{ax.l}" y1="{py:.1f}" x2="{ax.w - ax.r}" y2="{py:.1f}" stroke="{RED}" stroke-dasharray="4 3"/>')
        ax.parts.append(f'<text x="{ax.l + 4}" y="{py - 4:.1f}" fill="{RED}">{_esc(label)}</text>')
    for s in series:
        col = s.get("color", BLUE)
        r = float(s.get("size", 2.0))
        op = float(s.get("opacity", 0.8))
        mk = s.get("marker", "o")
        out = []
        for x, y in zip(np.asarray(s["x"], float).ravel(), np.asarray(s["y"], float).ravel()):
            if not (np.isfinite(x) and np.isfinite(y)):
                continue
            X, Y = ax.X(x), ax.Y(y)
            if mk == "x":
                out.append(f"M{X - r:.1f},{Y - r:.1f}L{X + r:.1f},{Y + r:.1f}M{X - r:.1f},{Y + r:.1f}L{X + r:.1f},{Y - r:.1f}")
            elif mk == "s":
                out.append(f'<rect x="{X - r:.1f}" y="{Y - r:.1f}" width="{2 * r:.1f}" height="{2 * r:.1f}"/>')
            else:
                out.append(f'<circle cx="{X:.1f}" cy="{Y:.1f}" r="{r:.1f}"/>')
        if mk == "x":
            ax.parts.append(f'<path d="{"".join(out)}" stroke="{col}" stroke-width="1.6" fill="none" opacity="{op}"/>')
        else:
            ax.parts.append(f'<g fill="{col}" opacity="{op}">{"".join(out)}</g>')
    y = ax.t + 12
    for s in labels:  # each series' own marker, as the plot draws it
        x = ax.w - ax.r + 16
        ax.parts.append(marker_glyph(x, y - 4, s.get("marker", "o"), s.get("color", BLUE), 3.5)
                        + f'<text x="{x + 9}" y="{y}">{_esc(s["label"])}</text>')
        y += 15
    ax.frame(title, xlabel, ylabel)
    return ax.svg()


def marker_glyph(x: float, y: float, marker: str, color: str, r: float) -> str:
    """One marker at (x, y) px: 'x' a cross, 's' a square, else a dot (a legend's key)."""
    if marker == "x":
        return (f'<path d="M{x - r:.1f},{y - r:.1f}L{x + r:.1f},{y + r:.1f}M{x - r:.1f},{y + r:.1f}L{x + r:.1f},{y - r:.1f}" '
                f'stroke="{color}" stroke-width="1.6" fill="none"/>')
    if marker == "s":
        return f'<rect x="{x - r:.1f}" y="{y - r:.1f}" width="{2 * r:.1f}" height="{2 * r:.1f}" fill="{color}"/>'
    return f'<circle cx="{x:.1f}" cy="{y:.1f}" r="{r:.1f}" fill="{color}"/>'


def heatmap(values, x_edges, y_edges, title: str = "", xlabel: str = "", ylabel: str = "",
            cbar_label: str = "", width: int = 420, height: int | None = None, vmin=None, vmax=None,
            y_down: bool = False, annotate: bool = False, markers: list | None = None,
            nan_label: str = "not visible") -> str:
    """Heat map of ``values`` (ny, nx) over cell edges; NaN cells are drawn light grey.

    ``markers``: list of dicts {x, y, label, color, dir} drawn on top (e.g. camera or robot base; see
    :func:`_marker`).
    Keeps the data aspect ratio when ``height`` is None.
    """
    V = np.asarray(values, float)
    xe = np.asarray(x_edges, float)
    ye = np.asarray(y_edges, float)
    fin = np.isfinite(V)
    lo = float(np.nanmin(V)) if vmin is None and fin.any() else (vmin if vmin is not None else 0.0)
    hi = float(np.nanmax(V)) if vmax is None and fin.any() else (vmax if vmax is not None else 1.0)
    if hi - lo <= 1e-9 * max(abs(lo), abs(hi)):  # a constant map (within rounding)
        hi = lo + (abs(lo) * 0.1 or 1.0)
    cbw = 90
    plot_w = width - cbw
    if height is None:
        height = int(30 + 44 + (plot_w - 62 - 16) * (ye[-1] - ye[0]) / (xe[-1] - xe[0]))
        height = max(160, min(height, 700))
    ax = _Axes(plot_w, height, (xe[0], xe[-1]), (ye[0], ye[-1]), y_down=y_down)
    for i in range(V.shape[0]):
        for j in range(V.shape[1]):
            x0, x1 = ax.X(xe[j]), ax.X(xe[j + 1])
            y0, y1 = sorted((ax.Y(ye[i]), ax.Y(ye[i + 1])))
            v = V[i, j]
            col = colormap((v - lo) / (hi - lo)) if np.isfinite(v) else "#e4e4e4"
            ax.parts.append(f'<rect x="{x0:.1f}" y="{y0:.1f}" width="{x1 - x0 + 0.3:.1f}" height="{y1 - y0 + 0.3:.1f}" fill="{col}"/>')
            if annotate and np.isfinite(v):
                tc = "#fff" if (v - lo) / (hi - lo) < 0.6 else "#000"
                ax.parts.append(f'<text x="{(x0 + x1) / 2:.1f}" y="{(y0 + y1) / 2 + 3:.1f}" text-anchor="middle" '
                                f'font-size="8" fill="{tc}">{_fmt(v)}</text>')
    for m in markers or []:
        ax.parts.append(_marker(ax, m, xe, ye))
    ax.frame(title, xlabel, ylabel)
    # colour bar
    bx, by, bh = plot_w + 10, ax.t, height - ax.t - ax.b
    n = 40
    for k in range(n):
        col = colormap((k + 0.5) / n)
        y = by + bh - (k + 1) * bh / n
        ax.parts.append(f'<rect x="{bx}" y="{y:.1f}" width="14" height="{bh / n + 0.5:.1f}" fill="{col}"/>')
    ax.parts.append(f'<rect x="{bx}" y="{by}" width="14" height="{bh}" fill="none" stroke="#333"/>')
    for v in nice_ticks(lo, hi, 4):
        y = by + bh - (v - lo) / (hi - lo) * bh
        ax.parts.append(f'<text x="{bx + 18}" y="{y + 4:.1f}">{_fmt(v)}</text>')
    ax.parts.append(f'<text x="{bx}" y="{by - 6}" font-size="10">{_esc(cbar_label)}</text>')
    if not fin.all():
        ax.parts.append(f'<rect x="{bx}" y="{by + bh + 8}" width="14" height="10" fill="#e4e4e4" stroke="#333"/>'
                        f'<text x="{bx + 18}" y="{by + bh + 17}" font-size="9">{_esc(nan_label)}</text>')
    return ax.svg(extra_width=cbw)


def _marker(ax, m: dict, xe, ye) -> str:
    """A heat map's marker {x, y, label, color, dir (dx, dy) optional}: a dot with its label in dark
    text on a white halo (readable on any colour of the map); one outside the map is drawn on its
    border, where the line from the map's centre to it leaves, as a diamond; ``dir``: an arrow that
    way (a camera's viewing direction)."""
    x, y = float(m["x"]), float(m["y"])
    inside = xe[0] <= x <= xe[-1] and ye[0] <= y <= ye[-1]
    if not inside:
        cx, cy = (xe[0] + xe[-1]) / 2, (ye[0] + ye[-1]) / 2
        dx, dy = x - cx, y - cy
        f = min(((xe[-1] if dx > 0 else xe[0]) - cx) / dx if dx else np.inf,
                ((ye[-1] if dy > 0 else ye[0]) - cy) / dy if dy else np.inf)
        x, y = cx + f * dx, cy + f * dy
    X, Y = ax.X(x), ax.Y(y)
    col = m.get("color", RED)
    out = []
    d = m.get("dir")
    if d is not None and np.hypot(*d) > 1e-6:
        ux, uy = ax.X(x + d[0]) - X, ax.Y(y + d[1]) - Y
        k = 30.0 / (np.hypot(ux, uy) or 1.0)
        ex, ey = X + k * ux, Y + k * uy
        hx, hy = -k * ux / 30.0, -k * uy / 30.0  # unit vector back along the arrow
        px, py = -hy, hx
        out.append(f'<line x1="{X:.1f}" y1="{Y:.1f}" x2="{ex:.1f}" y2="{ey:.1f}" stroke="#111" stroke-width="2"/>'
                   f'<path d="M{ex:.1f},{ey:.1f}L{ex + 7 * hx + 4 * px:.1f},{ey + 7 * hy + 4 * py:.1f}'
                   f'L{ex + 7 * hx - 4 * px:.1f},{ey + 7 * hy - 4 * py:.1f}Z" fill="#111"/>')
    if inside:
        out.append(f'<circle cx="{X:.1f}" cy="{Y:.1f}" r="5" fill="{col}" stroke="#fff" stroke-width="1.5"/>')
    else:
        out.append(f'<path d="M{X:.1f},{Y - 7:.1f}L{X + 7:.1f},{Y:.1f}L{X:.1f},{Y + 7:.1f}L{X - 7:.1f},{Y:.1f}Z" '
                   f'fill="{col}" stroke="#fff" stroke-width="1.5"/>')
    right = X > ax.l + 0.6 * (ax.w - ax.l - ax.r)
    tx, anchor = (X - 9, "end") if right else (X + 9, "start")
    ty = min(max(Y + 4, ax.t + 12), ax.h - ax.b - 4)
    out.append(f'<text x="{tx:.1f}" y="{ty:.1f}" text-anchor="{anchor}" fill="#111" font-weight="bold" '
               f'stroke="#fff" stroke-width="3" paint-order="stroke">{_esc(m.get("label", ""))}</text>')
    return "".join(out)


def empty_plot(title: str, message: str, width: int = 420, height: int = 120) -> str:
    """A framed placeholder saying why a plot is missing."""
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" font-family="sans-serif" '
            f'font-size="12"><rect x="1" y="1" width="{width - 2}" height="{height - 2}" fill="#fafafa" stroke="#bbb"/>'
            f'<text x="{width / 2}" y="20" text-anchor="middle" font-weight="bold">{_esc(title)}</text>'
            f'<text x="{width / 2}" y="{height / 2 + 8}" text-anchor="middle" fill="#777">{_esc(message)}</text></svg>')
