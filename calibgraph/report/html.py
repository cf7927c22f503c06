"""Commissioning report: one self-contained HTML file an integrator can hand to a customer.

:func:`write_report` takes a :class:`~calibgraph.solver.output.result.Result` (``calibgraph.load_result``
reads one from result.json) and is richer when the dataset it was solved from is given: the
intrinsics, the image coverage and the residuals of a result that has none. A dataset that is not
the result's (other cameras, captures, target or corners) is refused, since the page would mix two
calibrations.

The page: the verdict banner (each camera against the tolerances of
:mod:`calibgraph.report.tolerances`), a box of what would improve the calibration (each camera's
advice), the summary table, the solver's notes on the whole cell, one section per camera
(:mod:`calibgraph.report.sections`: its error budget and advice, its notes, its intrinsics' provenance
with given -> estimated values, a move during capture, pose, checks), camera pairs, the robot's joint offsets, residual plots
(:mod:`calibgraph.report.residual_plots`), workspace uncertainty maps
(:mod:`calibgraph.report.workspace`), the convergence of an autonomous run and the provenance.
Plots are inline SVG (:mod:`calibgraph.report.svgplot`).

The exact numbers of the result are embedded in the page as JSON (``<script
id="calibgraph-result">``, the content of result.json) and every displayed number carries its
full-precision value in a ``data-value`` attribute, so a reader (or a test) can check the page
against result.json.
"""

from __future__ import annotations

import json
from pathlib import Path

from calibgraph.core.errors import InputError
from calibgraph.io.dataset import recorded_run, recorded_workcell
from calibgraph.io.files import atomic_write_text
from calibgraph.io.output_guard import with_fingerprint
from calibgraph.io.layouts import as_dataset
from calibgraph.report.convergence import convergence_section
from calibgraph.report.markup import CSS, esc
from calibgraph.report.remedies import fixes
from calibgraph.report.residual_plots import residuals_html
from calibgraph.report.residuals import compute_residuals, dataset_mismatch, observations, report_residuals
from calibgraph.report.sections import (
    banner_html,
    camera_html,
    cell_notes_html,
    improve_html,
    pairs_html,
    provenance_html,
    robot_html,
    summary_html,
)
from calibgraph.report.tolerances import camera_verdict, load_tolerances
from calibgraph.report.workspace import workspace_maps
from calibgraph.solver.output.result import as_result

__all__ = ["write_report", "report_verdicts", "load_tolerances", "compute_residuals", "observations",
           "dataset_mismatch", "residuals_section"]


def report_verdicts(result, config=None, dataset=None) -> dict:
    """camera -> ``{'pass', 'rows', 'reasons'}`` of ``result`` against the tolerances of ``config``,
    as the report states them."""
    result = as_result(result, "report")
    return _content(result, load_tolerances(config), as_dataset(dataset))["verdicts"]


def write_report(result, out_html, config=None, dataset=None, result_path=None) -> Path:
    """Write the commissioning report of ``result`` to ``out_html``; returns the path.

    Args:
        result: a :class:`~calibgraph.solver.output.result.Result` (a result dict is converted).
        out_html: output file (written atomically).
        config: tolerance YAML path or dict (see :func:`load_tolerances`); default tolerances otherwise.
        dataset: the dataset folder or :class:`calibgraph.io.dataset.Dataset` the result was solved
            from; adds intrinsics, image coverage and recomputed residuals when the result has none.
            Another dataset raises :class:`InputError` naming what differs.
        result_path: the file the result was read from (named, with its SHA-256, in the report).
    """
    result = as_result(result, "report")
    ds = as_dataset(dataset)
    if ds is not None:
        differ = dataset_mismatch(result, ds)
        if differ:
            raise InputError(f"report: {ds.root} is not the dataset this result was solved from: {'; '.join(differ)}. "
                             "Give the result's own dataset (or none).")
    tol = load_tolerances(config)
    c = _content(result, tol, ds)
    names = list(result.cameras)
    title = f"calibgraph commissioning report — {len(names)} camera{'s' if len(names) != 1 else ''}, {result.mode}"
    parts = [
        banner_html(result, title, c["verdicts"]),
        improve_html(result, c["workcell"]),
        summary_html(result, c["verdicts"]),
        cell_notes_html(result),
        "<h2>Cameras</h2>",
        *(camera_html(result, n, c["intr"][n], c["verdicts"][n], c["residuals"].get(n, {}), c["ws"]) for n in names),
        pairs_html(result),
        robot_html(result),
        residuals_html(result, c["residuals"], c["residual_source"]),
        "<h2>Uncertainty in the workspace</h2>",
        c["ws"]["html"],
        convergence_section(ds.root if ds is not None else None),
        "<h2>Provenance</h2>",
        provenance_html(result, ds, result_path, tol, config),
        f'<script type="application/json" id="calibgraph-result">{_json_for_html(result.to_dict())}</script>',
    ]
    doc = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
           f"<title>{esc(title)}</title><style>{CSS}</style></head><body>\n" + "\n".join(parts) + "\n</body></html>\n")
    atomic_write_text(out_html, with_fingerprint(doc))  # a page edited by hand is then kept when replaced
    return Path(out_html)


def residuals_section(result) -> dict:
    """The ``residuals`` section of result.json (camera -> capture -> JSON-ready record) of a
    :class:`~calibgraph.solver.output.result.Result`, for scripts that work on the file's form."""
    return as_result(result, "report").to_dict()["residuals"]


def _content(result, tol: dict, ds) -> dict:
    """What the page shows besides the result itself: intrinsics, residuals, workspace maps, verdicts
    (each with the step that fixes a failing check), and what made the dataset (``made_by``)."""
    intr = {n: c.solved_intrinsics or (ds.cameras.get(n) if ds is not None else None) for n, c in result.cameras.items()}
    residuals, source = report_residuals(result, ds)
    ws = workspace_maps(result, tol, intr)
    run = recorded_run(ds.root) if ds is not None else {}
    n_captures = len(ds.captures) if ds is not None else (len(result.T_base_flange_est) or None)
    verdicts = {}
    for n, c in result.cameras.items():
        v = camera_verdict(n, c, tol, ws["worst"].get(n))
        v["fixes"] = fixes(n, c, v, residuals.get(n), intr[n], run, n_captures)
        verdicts[n] = v
    return {"intr": intr, "residuals": residuals, "residual_source": source, "ws": ws, "verdicts": verdicts,
            "workcell": recorded_workcell(ds.root) if ds is not None else None}


def _json_for_html(d: dict) -> str:
    # "</" would end the script element early; JSON allows "\/" in strings
    return json.dumps(d, allow_nan=True).replace("</", "<\\/")
