"""Printable targets: a minimal vector PDF writer (no PDF library needed).

``target_pdf(target, paper)`` draws the target at exact physical scale on an A4 or A3 page (PDF
user units are points, 1 pt = 25.4 / 72 mm, so a 46 mm square is exactly 130.394 pt; print with
"actual size" / no scaling), centred, with:

* a 100 mm ruler with millimetre ticks, a 10 mm square and the pattern's own printed size, to check
  the printed scale with a calliper or a steel rule (both axes: printers can scale them differently);
* a caption with the board's name and spec (kind, squares, corners, pitch, markers) and the board
  frame's origin and axes;

everything at least 10 mm (``MARGIN_MM``) from the sheet's edges.

Shapes are filled paths (squares as ``re``, circles as four cubic Béziers, ArUco cells merged into
horizontal runs), so the output is resolution-independent.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.io.files import atomic_write_bytes

PAPERS_MM = {"A4": (210.0, 297.0), "A3": (297.0, 420.0)}
_K = 0.5522847498  # cubic Bézier circle constant


class _Page:
    """Content stream of one page in millimetres from the page's top-left corner (y down)."""

    def __init__(self, w_mm: float, h_mm: float):
        self.w_mm, self.h_mm = w_mm, h_mm
        self.ops: list[str] = []

    def _p(self, x_mm: float, y_mm: float) -> str:
        # PDF origin is bottom-left with y up.
        return f"{x_mm * 72 / 25.4:.4f} {(self.h_mm - y_mm) * 72 / 25.4:.4f}"

    def grey(self, g: float):
        self.ops.append(f"{g:.3f} g {g:.3f} G")

    def rect(self, x_mm, y_mm, w_mm, h_mm):
        """Filled rectangle with top-left corner (x, y)."""
        x0, y0 = self._p(x_mm, y_mm + h_mm).split()
        self.ops.append(f"{x0} {y0} {w_mm * 72 / 25.4:.4f} {h_mm * 72 / 25.4:.4f} re f")

    def circle(self, cx_mm, cy_mm, r_mm):
        k = _K * r_mm
        c = [(cx_mm + r_mm, cy_mm), (cx_mm + r_mm, cy_mm - k), (cx_mm + k, cy_mm - r_mm), (cx_mm, cy_mm - r_mm),
             (cx_mm - k, cy_mm - r_mm), (cx_mm - r_mm, cy_mm - k), (cx_mm - r_mm, cy_mm), (cx_mm - r_mm, cy_mm + k),
             (cx_mm - k, cy_mm + r_mm), (cx_mm, cy_mm + r_mm), (cx_mm + k, cy_mm + r_mm), (cx_mm + r_mm, cy_mm + k),
             (cx_mm + r_mm, cy_mm)]
        s = [f"{self._p(*c[0])} m"]
        for i in range(1, 13, 3):
            s.append(f"{self._p(*c[i])} {self._p(*c[i + 1])} {self._p(*c[i + 2])} c")
        self.ops.append(" ".join(s) + " f")

    def line(self, x0, y0, x1, y1, width_mm=0.15):
        self.ops.append(f"{width_mm * 72 / 25.4:.4f} w {self._p(x0, y0)} m {self._p(x1, y1)} l S")

    def text(self, x_mm, y_mm, s: str, size_pt: float = 8.0):
        esc = s.replace("\\", "\\\\").replace("(", "\\(").replace(")", "\\)").encode("latin-1", "replace").decode("latin-1")
        self.ops.append(f"BT /F1 {size_pt:.1f} Tf {self._p(x_mm, y_mm)} Td ({esc}) Tj ET")


def _pdf_bytes(page: _Page, title: str) -> bytes:
    content = "\n".join(page.ops).encode("latin-1")
    w, h = page.w_mm * 72 / 25.4, page.h_mm * 72 / 25.4
    objs = [
        b"<< /Type /Catalog /Pages 2 0 R >>",
        b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
        (f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {w:.3f} {h:.3f}] /Contents 4 0 R "
         f"/Resources << /Font << /F1 5 0 R >> >> >>").encode(),
        b"<< /Length " + str(len(content)).encode() + b" >>\nstream\n" + content + b"\nendstream",
        b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica /Encoding /WinAnsiEncoding >>",
        ("<< /Title (" + title.replace("(", "[").replace(")", "]") + ") /Producer (calibgraph) >>").encode("latin-1", "replace"),
    ]
    out = bytearray(b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n")
    offsets = []
    for i, o in enumerate(objs, start=1):
        offsets.append(len(out))
        out += f"{i} 0 obj\n".encode() + o + b"\nendobj\n"
    xref = len(out)
    out += f"xref\n0 {len(objs) + 1}\n0000000000 65535 f \n".encode()
    for off in offsets:
        out += f"{off:010d} 00000 n \n".encode()
    out += f"trailer\n<< /Size {len(objs) + 1} /Root 1 0 R /Info {len(objs)} 0 R >>\nstartxref\n{xref}\n%%EOF\n".encode()
    return bytes(out)


# Helvetica's advance widths (1/1000 em, from its AFM) for estimating where text ends.
_HELV = {**{c: 556 for c in "abdeghnopqu0123456789L"}, **{c: 500 for c in "cksvxyzJ"}, **{c: 278 for c in " ftI.,:;/![]"},
         **{c: 222 for c in "ijl"}, "m": 833, "r": 333, "w": 722, **{c: 667 for c in "ABEKPSVXY&"},
         **{c: 722 for c in "CDHNRUw"}, **{c: 611 for c in "FTZ"}, **{c: 778 for c in "GOQ"}, "M": 833, "W": 944,
         **{c: 333 for c in "()-`"}, "*": 389, "=": 584, "+": 584, "%": 889, "'": 191, '"': 355, "_": 556, "#": 556}

MARGIN_MM = 10.0  # nothing is drawn nearer the sheet's edge (most printers' unprintable border is 3-6 mm)
RULER_MM = 100.0  # the scale checks the page carries: a ruler ...
CHECK_SQUARE_MM = 10.0  # ... and a square (docs/guide.md names both sizes)
STRIP_MM, GAP_MM = 13.0, 2.0  # the strip of the ruler, square and caption, and its gap to the pattern


def text_width_mm(s: str, size_pt: float) -> float:
    """Width of ``s`` set in Helvetica at ``size_pt`` (mm)."""
    return sum(_HELV.get(c, 667) for c in s) / 1000 * size_pt * 25.4 / 72


def _describe(t: Target) -> str:
    return t.describe()


def target_layout(target: Target, paper: str = "A4", name: str | None = None) -> dict:
    """The printed page of ``target`` as drawn: ``paper_mm`` (W, H of the sheet as printed, landscape
    for a wide pattern), ``pattern_mm`` (x0, y0, x1, y1 of the pattern from the sheet's top-left,
    y down), ``boxes`` (what, x0, y0, x1, y1: every mark of the ruler strip on the sheet, text by
    its Helvetica advance width, ascent 0.72 em and descent 0.21 em), and the content stream ``ops``."""
    paper = paper.upper()
    if paper not in PAPERS_MM:
        raise InputError(f"target print: paper must be A4 or A3, got {paper!r}.")
    x0, y0, x1, y1 = target.extent_m
    if target.kind == "modified_circles":  # page y runs down, the peer frame's y up
        y0, y1 = -y1, -y0
    pw_mm, ph_mm = (x1 - x0) * 1e3, (y1 - y0) * 1e3
    W, H = PAPERS_MM[paper]
    if pw_mm > ph_mm:
        W, H = H, W  # landscape for wide patterns
    margin, strip = MARGIN_MM, STRIP_MM + GAP_MM
    room_below = H - 2 * margin - ph_mm
    room_side = W - 2 * margin - pw_mm
    if pw_mm > W - 2 * margin or ph_mm > H - 2 * margin or max(room_below, room_side) < strip - 1e-6:
        raise InputError(
            f"target print: the pattern is {pw_mm:.0f} x {ph_mm:.0f} mm and does not fit on {paper} "
            f"({W:.0f} x {H:.0f} mm) with {margin:.0f} mm margins and a {strip:.0f} mm strip for the ruler; "
            "use --paper A3 or a smaller pitch.")
    page = _Page(W, H)
    below = room_below >= strip - 1e-6
    # Centre the pattern in the page minus the strip (below it, or to its right).
    area_w = W - 2 * margin - (0 if below else strip)
    area_h = H - 2 * margin - (strip if below else 0)
    ox = margin + (area_w - pw_mm) / 2 - x0 * 1e3
    oy = margin + (area_h - ph_mm) / 2 - y0 * 1e3
    pattern = (ox + x0 * 1e3, oy + y0 * 1e3, ox + x1 * 1e3, oy + y1 * 1e3)

    def P(x_m, y_m):
        return ox + x_m * 1e3, oy + y_m * 1e3

    page.grey(0.0)
    p = target.pitch_m
    if target.kind == "checkerboard":
        for a in range(target.rows + 1):
            for b in range(target.cols + 1):
                if (a + b) % 2 == 0:
                    x, y = P((b - 1) * p, (a - 1) * p)
                    page.rect(x, y, p * 1e3, p * 1e3)
    elif target.kind == "charuco":
        board = target.cv_charuco_board()
        ids = board.getIds().ravel()
        obj = board.getObjPoints()
        occupied = set()
        for c in obj:
            c = np.asarray(c).reshape(-1, 3)
            occupied.add((int(c[:, 1].min() // p), int(c[:, 0].min() // p)))
        for a in range(target.squares_y):
            for b in range(target.squares_x):
                if (a, b) not in occupied:
                    x, y = P(b * p, a * p)
                    page.rect(x, y, p * 1e3, p * 1e3)
        d = board.getDictionary()
        nb = d.markerSize
        for mid, c in zip(ids, obj):
            c = np.asarray(c).reshape(-1, 3)
            bits = d.generateImageMarker(int(mid), nb + 2, borderBits=1)  # one pixel per cell
            cell = target.marker_m / (nb + 2)
            mx, my = c[:, 0].min(), c[:, 1].min()
            for r in range(nb + 2):
                row = bits[r] < 128
                cidx = 0
                while cidx < nb + 2:
                    if row[cidx]:
                        e = cidx
                        while e < nb + 2 and row[e]:
                            e += 1
                        x, y = P(mx + cidx * cell, my + r * cell)
                        page.rect(x, y, (e - cidx) * cell * 1e3, cell * 1e3)
                        cidx = e
                    else:
                        cidx += 1
    else:
        pts = target.points_board_m[:, :2].copy()
        if target.kind == "modified_circles":
            pts[:, 1] = -pts[:, 1]
        r = target.circle_d_m / 2
        origin = (target.rows - 1) * target.cols if target.kind == "modified_circles" else -1
        for k, (x, y) in enumerate(pts):
            page.circle(*P(x, y), (2 * r if k == origin else r) * 1e3)
    # The ruler, the check square and the caption, in a strip of their own (local millimetres, y down,
    # 0..STRIP_MM) placed below the pattern, or along its right side turned by 90 degrees.
    L = (W if below else H) - 2 * margin
    st = _Page(L, STRIP_MM)
    boxes = []

    def text(x, y, s, size):
        st.text(x, y, s, size)
        em = size * 25.4 / 72
        boxes.append((f"text {s!r}", x, y - 0.72 * em, x + text_width_mm(s, size), y + 0.21 * em))

    st.grey(0.0)
    sq = CHECK_SQUARE_MM
    st.rect(0.0, 0.0, sq, sq)
    boxes.append(("check square", 0.0, 0.0, sq, sq))
    text(0.0, STRIP_MM - 0.6, f"{sq:g} mm", 6)
    rx, fy = sq + 4.0, 0.3
    st.line(rx, fy, rx + RULER_MM, fy, 0.2)
    for mm in range(0, int(RULER_MM) + 1):
        tick = 4.0 if mm % 10 == 0 else (2.5 if mm % 5 == 0 else 1.5)
        st.line(rx + mm, fy, rx + mm, fy + tick, 0.12)
        if mm % 10 == 0:
            text(rx + mm - text_width_mm(str(mm), 6) / 2, fy + 6.6, str(mm), 6)
    boxes.append(("ruler", rx, fy - 0.1, rx + RULER_MM, fy + 4.0))
    ex, ey = pw_mm, ph_mm
    side = rx + RULER_MM + 4.0
    text(side, 2.0, "Print at 100 % (actual size, no scaling), then measure:", 6)
    text(side, 4.6, f"the ruler: {RULER_MM:.1f} mm; the square: {sq:.1f} x {sq:.1f} mm;", 6)
    text(side, 7.2, f"the pattern: {ex:.1f} mm across, {ey:.1f} mm down.", 6)
    text(rx, 9.6, f"calibgraph {name + ': ' if name else ''}{_describe(target)}", 6.5)
    frame = ("origin at the outer top-left board corner (OpenCV CharucoBoard)" if target.kind == "charuco" else
             "origin at the big dot (bottom-left), x right, y up" if target.kind == "modified_circles" else
             "origin at the top-left inner corner/dot, x right, y down")
    text(rx, STRIP_MM - 0.6, f"Board frame: {frame}, z = x cross y; point id = cols * row + col.", 6)
    k = 72 / 25.4
    if below:
        # the strip's top at its gap below the pattern, its bottom no lower than the bottom margin
        top = min(pattern[3] + GAP_MM, H - margin - STRIP_MM)
        tx, ty = margin * k, (H - top - STRIP_MM) * k
        page.ops.append(f"q 1 0 0 1 {tx:.4f} {ty:.4f} cm")
        placed = [(w, margin + a, top + b, margin + c, top + d) for w, a, b, c, d in boxes]
    else:
        # Rotate 90 degrees counter-clockwise: strip x runs up the page from the bottom margin, its
        # top (y = 0: the square and the ruler) towards the pattern, its bottom at the right margin.
        tx, ty = (W - margin) * k, margin * k
        page.ops.append(f"q 0 1 -1 0 {tx:.4f} {ty:.4f} cm")
        x_top = W - margin - STRIP_MM
        placed = [(w, x_top + b, H - margin - c, x_top + d, H - margin - a) for w, a, b, c, d in boxes]
    page.ops.extend(st.ops)
    page.ops.append("Q")
    return {"paper_mm": (W, H), "pattern_mm": pattern, "boxes": placed, "below": below, "page": page}


def target_pdf(target: Target, paper: str = "A4", name: str | None = None) -> bytes:
    """The PDF (bytes) of ``target`` at exact scale on ``paper`` ('A4' or 'A3'), with a ruler
    (``name``: the board's name for the caption)."""
    lay = target_layout(target, paper, name)
    return _pdf_bytes(lay["page"], f"{name + ': ' if name else ''}{_describe(target)}")


def write_target_pdf(target: Target, path, paper: str = "A4", name: str | None = None) -> Path:
    """Write :func:`target_pdf` to ``path``."""
    path = Path(path)
    data = target_pdf(target, paper, name)
    atomic_write_bytes(path, data)
    return path
