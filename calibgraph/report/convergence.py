"""The convergence plot of an autonomous run: each camera's 1-sigma against the captures.

Reads ``plan_log.json`` (:mod:`calibgraph.acquire.auto`) and returns an HTML fragment with an
inline SVG (translation 1-sigma norm in mm after each capture pose, one series per camera, the
tolerance as a dashed line), or "" when the dataset has no plan log. The commissioning report
includes it with one line in :func:`calibgraph.report.html.write_report`::

    parts.append(convergence_section(dataset))
"""

from __future__ import annotations

import html
import json
from pathlib import Path

from calibgraph.core.errors import InputError
from calibgraph.io.files import read_input_bytes
from calibgraph.report.svgplot import colormap, scatter

PLAN_LOG_NAME = "plan_log.json"  # as written by calibgraph.acquire.auto


def convergence_series(plan_log: dict) -> dict:
    """camera -> (captures (k,), sigma_mm (k,)) after each capture pose of the log."""
    out, n = {}, 0
    for s in plan_log.get("steps", []):
        if s.get("status") not in ("captured", "no_views", "recovered"):
            continue
        n += 1
        for c, v in (s.get("achieved") or {}).items():
            if v:
                xs, ys = out.setdefault(c, ([], []))
                xs.append(n)
                ys.append(float(v[0]))
    return out


def convergence_section(dataset_dir) -> str:
    """HTML fragment with the convergence plot of ``dataset_dir/plan_log.json`` ("" without one)."""
    if dataset_dir is None:
        return ""
    p = Path(dataset_dir) / PLAN_LOG_NAME
    if not p.is_file():
        return ""
    try:
        log = json.loads(read_input_bytes(p, "plan log"))
    except (OSError, ValueError, InputError):
        return ""
    series = convergence_series(log)
    if not series:
        return ""
    tol = (log.get("options") or {}).get("tolerance_mm")
    names = sorted(series)
    svg = scatter([{"x": series[c][0], "y": series[c][1], "label": c, "color": colormap(i / max(len(names) - 1, 1)),
                    "size": 3.0} for i, c in enumerate(names)],
                  title="1σ per camera against captures (autonomous run)", xlabel="capture poses",
                  ylabel="1σ translation norm [mm]", hlines={f"tolerance {tol:g} mm": tol} if tol else None)
    stop = html.escape(str((log.get("stop") or {}).get("reason", "")))
    return f'<section><h2>Convergence</h2><p>{stop}</p>{svg}</section>'
