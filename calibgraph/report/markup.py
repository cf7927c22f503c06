"""HTML building blocks of the report: escaped text, numbers that carry their full-precision value
(``data-value``, so a reader or a test can check the page against result.json), vectors,
matrices, pass/fail badges and the page's style sheet."""

from __future__ import annotations

import html

import numpy as np


def esc(s) -> str:
    return html.escape(str(s), quote=True)


def num(v, fmt: str = ".3f", unit: str = "") -> str:
    """A number as a <span> carrying its full-precision value in ``data-value`` (text as it is)."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return esc(v)
    if not np.isfinite(f):
        return f'<span class="num" data-value="{f}">–</span>'
    return f'<span class="num" data-value="{f!r}">{format(f, fmt)}{esc(unit)}</span>'


def vec(v, fmt=".3f", unit="") -> str:
    return "(" + ", ".join(num(x, fmt) for x in v) + ")" + (f" {esc(unit)}" if unit else "")


def matrix(T) -> str:
    rows = "".join("<tr>" + "".join(f"<td>{num(x, '.9f')}</td>" for x in row) + "</tr>" for row in np.asarray(T))
    return f'<table class="mat">{rows}</table>'


def badge(ok) -> str:
    if ok is None:
        return '<span class="na">n/a</span>'
    return '<span class="pass">PASS</span>' if ok else '<span class="fail">FAIL</span>'


CSS = """
body{font-family:system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:24px auto;max-width:1180px;color:#222;padding:0 16px}
h1{margin-bottom:4px} h2{border-bottom:2px solid #ddd;padding-bottom:4px;margin-top:36px}
table{border-collapse:collapse;margin:8px 0} td,th{border:1px solid #ccc;padding:3px 7px;font-size:13px;text-align:right}
th{background:#f0f0f0} td.l,th.l{text-align:left}
table.mat td{border:none;padding:1px 8px;font-family:monospace;font-size:12px}
.pass{color:#fff;background:#2a8a3a;padding:2px 8px;border-radius:4px;font-weight:bold}
.fail{color:#fff;background:#c62828;padding:2px 8px;border-radius:4px;font-weight:bold}
.na{color:#555;background:#e0e0e0;padding:2px 8px;border-radius:4px}
.banner{font-size:20px;margin:12px 0;padding:10px;border-radius:6px}
.banner.pass{display:block} .banner.fail{display:block}
.plots{display:flex;flex-wrap:wrap;gap:12px;align-items:flex-start}
.note{color:#555;font-size:13px} .cam{border:1px solid #ddd;border-radius:6px;padding:8px 14px;margin:14px 0}
code{background:#f4f4f4;padding:0 3px}
.improve{border:2px solid #1f77b4;background:#f3f8fd;border-radius:6px;padding:8px 14px;margin:12px 0}
.improve ul{margin:6px 0;padding-left:20px} .improve li{margin:3px 0} .improve .advice{background:none;padding:0}
.budget,.intrinsics,.notes,.moved{margin:8px 0 10px}
.shareset{display:flex;align-items:center;gap:10px;margin:4px 0;flex-wrap:wrap}
.setlabel{min-width:120px;font-size:13px;color:#555}
.bar{display:flex;width:360px;height:16px;border:1px solid #999;border-radius:3px;overflow:hidden;background:#eee}
.bar span{display:block;height:100%}
.bars{display:flex;flex-direction:column;gap:2px} .bar.one{height:7px}
.bar span,.legend i,.pass,.fail,.banner{-webkit-print-color-adjust:exact;print-color-adjust:exact}
.legend{font-size:13px} .legend .key{margin-right:12px;white-space:nowrap}
.legend i{display:inline-block;width:10px;height:10px;margin-right:4px;vertical-align:middle}
.advice{background:#fff8e1;padding:2px 4px} p.advice{margin:6px 0;padding:4px 8px;border-left:4px solid #f9a825}
.notes ul{margin:4px 0;padding-left:20px} .notes li{font-size:13px;margin:3px 0}
.notes.cell{border-left:4px solid #c62828;padding-left:8px}
.moved{border-left:4px solid #c62828;padding-left:8px} .why{color:#c62828}
.provenance{font-size:14px} .fix{color:#333;font-size:14px}
.notes .detail{display:block;color:#666;font-size:12px}
"""
