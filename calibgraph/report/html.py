"""Commissioning report: one self-contained HTML file an integrator can hand to a customer.

:func:`write_report` works from the result dict alone (``load_result_dict(result.json)``) and is
richer when more is known. What it reads from the result (``calibgraph-result/1``, see
:mod:`calibgraph.solver.result`):

- required: ``mode``, ``cameras.<name>.T_base_cam`` (or ``T_flange_cam``) and ``covariance``
  (6x6 rotation-first), ``reprojection_rms_px``, ``reprojection_max_px``, ``views_used``,
  ``views_rejected`` [{capture, reason}];
- optional: ``camera_pairs``, ``solver`` (converged, iterations, final_cost, pixel_sigma_px,
  settings), ``dataset``, ``calibgraph_version``, ``rejected_corners`` [{camera, capture, id,
  residual_px}], ``T_flange_board``/``T_base_board``, ``robot_flange_poses_refined``;
- ``cameras.<name>.intrinsics`` {K, dist, width_px, height_px} (image size for the coverage map,
  field of view for the workspace map); else taken from the dataset;
- ``residuals`` (per-corner residuals; without it, and with a dataset, they are recomputed from
  the poses in the result)::

      "residuals": {"<camera>": {"<capture>": {"ids": [N ints], "uv_detected_px": [[u, v] x N],
                                               "residual_px": [[du, dv] x N], "rejected": bool}}}

  ``residual_px = uv_reprojected_px - uv_detected_px`` (the solver's sign: predicted minus
  measured, so the reprojected corner is ``uv_detected + residual``); ``rejected`` is true when
  the solver dropped the whole view. Individually rejected corners are the ``rejected_corners``
  entries of that camera and capture, or those flagged in the optional ``corner_rejected`` list
  (N booleans; written by ``Result.to_dict``) or with ``weight`` 0 in an optional ``weight`` list.

  :func:`residuals_section` builds this section from a :class:`calibgraph.solver.result.Result`.

Tolerances come from a YAML file (``datasets/tolerances/default.yaml`` is the default); see
:func:`load_tolerances`. Plots are inline SVG made by :mod:`calibgraph.report.svgplot`.

The exact numbers of the result are embedded in the page as JSON (``<script
id="calibgraph-result">``) and every displayed number carries its full-precision value in a
``data-value`` attribute, so a reader (or a test) can check the page against result.json.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import html
import json
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import R_to_quat_xyzw, inv
from calibgraph.core.version import __version__
from calibgraph.io.files import atomic_write_text, read_yaml
from calibgraph.io.layouts import as_dataset
from calibgraph.report import svgplot
from calibgraph.report.convergence import convergence_section
from calibgraph.report.exports import (
    R_to_rpy,
    camera_intrinsics,
    camera_pose,
    ref_frame,
)
from calibgraph.solver.uncertainty import (
    visible_mask,
    weakest_directions,
    workspace_grid,
    workspace_sigma_map,
)

DEFAULT_TOLERANCES = Path(__file__).resolve().parents[1] / "datasets" / "tolerances" / "default.yaml"

# used when the file is missing (an installed wheel has no datasets/ folder)
BUILTIN_TOLERANCES = {
    "defaults": {
        "max_sigma_translation_mm": 1.0,
        "max_sigma_rotation_deg": 0.05,
        "max_reprojection_rms_px": 0.5,
        "max_reprojection_max_px": 3.0,
        "min_views_used": 8,
        "max_workspace_sigma_mm": 2.0,
    },
    "cameras": {},
    "workspace": {},
}

CHECKS = (
    # key, label, value getter, comparison
    ("max_sigma_translation_mm", "largest 1σ translation (mm)", lambda c, w: max(c.get("sigma_translation_mm", [np.nan])), "<="),
    ("max_sigma_rotation_deg", "largest 1σ rotation (deg)", lambda c, w: max(c.get("sigma_rotation_deg", [np.nan])), "<="),
    ("max_reprojection_rms_px", "reprojection RMS (px)", lambda c, w: c.get("reprojection_rms_px", np.nan), "<="),
    ("max_reprojection_max_px", "reprojection max (px)", lambda c, w: c.get("reprojection_max_px", np.nan), "<="),
    ("min_views_used", "views used", lambda c, w: c.get("views_used", 0), ">="),
    ("max_workspace_sigma_mm", "worst 1σ point error in the workspace (mm)", lambda c, w: w, "<="),
)


# -- inputs ----------------------------------------------------------------------------------------
def load_tolerances(config=None) -> dict:
    """Tolerances: built-in defaults, overridden by ``DEFAULT_TOLERANCES`` (if present), then ``config``.

    ``config`` is a path to a YAML file or a dict with optional sections ``defaults`` (check ->
    limit), ``cameras`` (camera -> check -> limit) and ``workspace`` (``x_m``, ``y_m`` ranges,
    ``z_m`` height, ``grid_n`` cells along x; for eye-in-hand ``depth_m`` and ``lateral_m``).
    A limit of ``null`` disables that check.
    """

    tol = json.loads(json.dumps(BUILTIN_TOLERANCES))
    sources = []
    if DEFAULT_TOLERANCES.is_file():
        sources.append(DEFAULT_TOLERANCES)
    if config is not None:
        sources.append(config)
    for src in sources:
        if isinstance(src, dict):
            d = src
        else:

            d = read_yaml(src, "tolerance config (a mapping with 'defaults', 'cameras', 'workspace')", empty_ok=True)
        unknown = set(d) - {"format", "defaults", "cameras", "workspace", "description"}
        if unknown:
            raise InputError(f"{src}: unknown tolerance sections {sorted(unknown)}; use defaults, cameras, workspace.")
        known = {k for k, *_ in CHECKS}
        for k in (d.get("defaults") or {}):
            if k not in known:
                raise InputError(f"{src}: unknown tolerance {k!r}; known: {sorted(known)}.")
        tol["defaults"].update(d.get("defaults") or {})
        for cam, lim in (d.get("cameras") or {}).items():
            bad = set(lim or {}) - known
            if bad:
                raise InputError(f"{src}: camera {cam!r}: unknown tolerance(s) {sorted(bad)}; known: {sorted(known)}.")
            tol["cameras"].setdefault(str(cam), {}).update(lim or {})
        tol["workspace"].update(d.get("workspace") or {})
    return tol


def _mount_key(result: dict) -> str:
    return "T_base_board" if result.get("mode") == "eye_in_hand" else "T_flange_board"


def residuals_section(result) -> dict:
    """The ``residuals`` section of result.json from a :class:`calibgraph.solver.result.Result`
    (its ``CameraResult.residuals_px``), JSON-ready. Intended for ``Result.to_dict``."""
    out = {}
    for name, c in result.cameras.items():
        per = {}
        for cap, v in sorted((c.residuals_px or {}).items()):
            if isinstance(v, dict):
                ids, uv, r = v["ids"], v.get("uv_detected_px"), v["residual_px"]
                w, rej = v.get("weight"), bool(v.get("rejected", False))
            else:  # (ids, residual) tuple form
                ids, r = v[0], v[1]
                uv, w, rej = None, None, False
            e = {"ids": np.asarray(ids).astype(int).tolist(),
                 "uv_detected_px": None if uv is None else np.asarray(uv, float).tolist(),
                 "residual_px": np.asarray(r, float).tolist(), "rejected": rej}
            if w is not None:
                e["corner_rejected"] = (np.asarray(w, float) == 0).tolist()
            per[str(int(cap))] = e
        out[name] = per
    return out


def observations(source) -> dict:
    """Normalise a :class:`~calibgraph.core.problem.Problem`, a :class:`~calibgraph.io.dataset.Dataset` or a
    dataset folder into plain data: ``points_board_m`` (M, 3), ``cameras`` (name -> Intrinsics),
    ``T_base_flange`` (capture -> 4x4), ``views`` [(camera, capture, ids, uv_px, image path or None)]."""
    src = as_dataset(source)
    if hasattr(src, "detections"):  # Problem
        views = [(d.camera, d.capture, d.ids, d.uv_px, d.image) for d in src.detections]
        pts = src.points_board_m
    else:  # Dataset: image paths are relative to its root
        views = [(v.camera, v.capture, v.ids, v.uv_px, str(Path(src.root) / v.image) if v.image else None)
                 for v in src.views]
        pts = src.target.points_board_m
    return {"points_board_m": np.asarray(pts, float), "cameras": dict(src.cameras),
            "T_base_flange": {c.index: c.T_base_flange for c in src.captures}, "views": views,
            "mode": getattr(src, "mode", None)}


def corner_rejected_mask(view: dict, n: int) -> np.ndarray:
    """(n,) booleans: corners of one residuals entry the solver rejected (``corner_rejected`` or
    ``weight`` == 0); all False when neither is given."""
    m = np.zeros(n, bool)
    cr = view.get("corner_rejected")
    if cr is not None and len(cr) == n:
        m |= np.asarray(cr, bool)
    w = view.get("weight")
    if w is not None and len(w) == n:
        m |= np.asarray(w, float) <= 0
    return m


def compute_residuals(result: dict, source) -> dict:
    """Recompute the ``residuals`` section from the poses in ``result`` and the detections of a
    dataset (folder or :class:`~calibgraph.io.dataset.Dataset`) or :class:`~calibgraph.core.problem.Problem`.

    Uses the refined flange poses of the result when present, else the recorded ones. Returns the
    same structure as ``result['residuals']`` (views the solver rejected are flagged ``rejected``).
    """
    obs = observations(source)
    mode = result.get("mode", "eye_to_hand")
    mk = _mount_key(result)
    # the board as the solver found it printed (its scale factor; 1 in results without one)
    pts = obs["points_board_m"] * float((result.get("board_scale") or {}).get("scale") or 1.0)
    refined = {int(k): np.asarray(v, float) for k, v in (result.get("robot_flange_poses_refined") or {}).items()}
    out = {}
    for name, cam in result["cameras"].items():
        T_mount_board = np.asarray(cam.get(mk, result.get(mk)), float) if (mk in cam or mk in result) else None
        intr = camera_intrinsics(result, name, None) or obs["cameras"].get(name)
        if T_mount_board is None or intr is None:
            continue
        T_ref_cam = camera_pose(result, name)
        rej = {int(v["capture"]) for v in cam.get("views_rejected", [])}
        per = {}
        for cam_name, k, ids, uv, _img in obs["views"]:
            if cam_name != name or ids is None or len(ids) == 0 or k not in obs["T_base_flange"]:
                continue
            T_bf = refined.get(k, obs["T_base_flange"][k])
            if mode == "eye_in_hand":
                T_cam_board = inv(T_bf @ T_ref_cam) @ T_mount_board
            else:
                T_cam_board = inv(T_ref_cam) @ T_bf @ T_mount_board
            p = pts[np.asarray(ids)] @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]
            uv_pred = intr.project(p)
            per[str(k)] = {"ids": np.asarray(ids).astype(int).tolist(), "uv_detected_px": np.asarray(uv).tolist(),
                           "residual_px": (uv_pred - uv).tolist(), "rejected": k in rej}
        out[name] = per
    return out


# -- formatting --------------------------------------------------------------------------------------
def _esc(s) -> str:
    return html.escape(str(s), quote=True)


def num(v, fmt: str = ".3f", unit: str = "") -> str:
    """A number as a <span> carrying its full-precision value in ``data-value``."""
    try:
        f = float(v)
    except (TypeError, ValueError):
        return _esc(v)
    if not np.isfinite(f):
        return f'<span class="num" data-value="{f}">–</span>'
    return f'<span class="num" data-value="{f!r}">{format(f, fmt)}{_esc(unit)}</span>'


def _vec(v, fmt=".3f", unit="") -> str:
    return "(" + ", ".join(num(x, fmt) for x in v) + ")" + (f" {_esc(unit)}" if unit else "")


def _matrix(T) -> str:
    rows = "".join("<tr>" + "".join(f"<td>{num(x, '.9f')}</td>" for x in row) + "</tr>" for row in np.asarray(T))
    return f'<table class="mat">{rows}</table>'


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
"""


# -- the report ----------------------------------------------------------------------------------
def write_report(result_dict: dict, out_html, config=None, dataset=None, result_path=None) -> Path:
    """Write the commissioning report for ``result_dict`` to ``out_html``; returns the path.

    Args:
        result_dict: a result as read by :func:`calibgraph.solver.result.load_result_dict`.
        out_html: output file (written atomically).
        config: tolerance YAML path or dict (see :func:`load_tolerances`); default tolerances otherwise.
        dataset: dataset folder or :class:`calibgraph.io.dataset.Dataset`; adds intrinsics, image
            coverage and recomputed residuals when the result has none.
        result_path: the file the result was read from (named, with its SHA-256, in the report).
    """
    R = result_dict
    if not isinstance(R, dict) or "cameras" not in R or not R["cameras"]:
        raise InputError("report: the result has no cameras; is it a calibgraph result.json?")
    ds = as_dataset(dataset)
    tol = load_tolerances(config)
    ref = ref_frame(R)
    names = list(R["cameras"])
    residuals, residual_source = _residuals_and_source(R, ds)
    intr = {n: camera_intrinsics(R, n, ds) for n in names}
    cov = {n: np.asarray(R["cameras"][n]["covariance"], float) for n in names if "covariance" in R["cameras"][n]}
    poses = {n: camera_pose(R, n) for n in names}
    ws = _workspace_maps(R, tol, poses, cov, intr)
    verdicts = {n: _verdict(n, R["cameras"][n], tol, ws["worst"].get(n)) for n in names}
    title = f"calibgraph commissioning report — {len(names)} camera{'s' if len(names) != 1 else ''}, {R.get('mode', '?')}"
    parts = [
        _banner_html(R, title, names, verdicts),
        _summary_html(R, names, poses, verdicts, ref),
        "<h2>Cameras</h2>",
        *(_camera_section(n, R, poses[n], cov.get(n), intr[n], verdicts[n], residuals.get(n, {}), ref, ws) for n in names),
        _pairs_html(R),
        _robot_html(R),
        _residuals_html(R, names, residuals, residual_source),
        "<h2>Uncertainty in the workspace</h2>",
        ws["html"],
        convergence_section(ds.root if ds is not None else None),
        "<h2>Provenance</h2>",
        _provenance(R, ds, result_path, tol, config),
        f'<script type="application/json" id="calibgraph-result">{_json_for_html(R)}</script>',
    ]
    doc = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
           f"<title>{_esc(title)}</title><style>{CSS}</style></head><body>\n" + "\n".join(parts) + "\n</body></html>\n")
    atomic_write_text(out_html, doc)
    return Path(out_html)


def _residuals_and_source(R: dict, ds) -> tuple[dict, str]:
    """The per-corner residuals of the result, else recomputed from the dataset (else none); and their origin."""
    residuals = R.get("residuals")
    source = "result.json"
    if not residuals and ds is not None:
        residuals = compute_residuals(R, ds)
        source = "recomputed from the dataset's detections and the poses in the result"
    return residuals or {}, source


def _banner_html(R: dict, title: str, names: list, verdicts: dict) -> str:
    """Title, generation note and the overall verdict (FAIL when a camera fails or the solver did not converge)."""
    converged = (R.get("solver") or {}).get("converged", True)
    overall = all(v["pass"] for v in verdicts.values()) and bool(converged)
    why = "" if converged else " (the solver did not converge)"
    failed = [n for n in names if not verdicts[n]["pass"]]
    generated = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    return "\n".join([
        f"<h1>{_esc(title)}</h1>",
        f'<p class="note">Generated {_esc(generated)} by calibgraph {_esc(__version__)}. '
        f'Frame convention: {_esc(R.get("frame_convention", "T_a_b maps points from b to a"))}</p>',
        f'<div class="banner {"pass" if overall else "fail"}" id="verdict">Overall: {"PASS" if overall else "FAIL"}'
        f'{_esc(why)}' + (f" — failing: {_esc(', '.join(failed))}" if failed else "") + "</div>",
    ])


def _summary_html(R: dict, names: list, poses: dict, verdicts: dict, ref: str) -> str:
    """The summary table: one row per camera (pose, 1σ, reprojection, views, verdict)."""
    h = ["<h2>Summary</h2>",
         f'<table id="summary"><tr><th class="l">camera</th><th>position in {ref} (m)</th><th>roll, pitch, yaw (deg)</th>'
         "<th>1σ translation x, y, z (mm)</th><th>1σ rotation x, y, z (deg)</th><th>reproj. RMS (px)</th>"
         "<th>reproj. max (px)</th><th>views used</th><th>views rejected</th><th>verdict</th></tr>"]
    for n in names:
        c = R["cameras"][n]
        T = poses[n]
        h.append(f'<tr data-camera="{_esc(n)}"><td class="l"><a href="#cam-{_esc(n)}">{_esc(n)}</a></td>'
                 f"<td>{_vec(T[:3, 3], '.4f')}</td><td>{_vec(np.degrees(R_to_rpy(T[:3, :3])), '.2f')}</td>"
                 f"<td>{_vec(c.get('sigma_translation_mm', [np.nan] * 3), '.3f')}</td>"
                 f"<td>{_vec(c.get('sigma_rotation_deg', [np.nan] * 3), '.4f')}</td>"
                 f"<td>{num(c.get('reprojection_rms_px'), '.3f')}</td><td>{num(c.get('reprojection_max_px'), '.3f')}</td>"
                 f"<td>{num(c.get('views_used'), '.0f')}</td><td>{num(len(c.get('views_rejected', [])), '.0f')}</td>"
                 f"<td>{_badge(verdicts[n]['pass'])}</td></tr>")
    h.append("</table>")
    h.append(f'<p class="note">1σ are along the {ref} frame axes (rotation: components of the rotation vector '
             f"perturbation in {ref} axes). Roll, pitch, yaw: URDF fixed-axis convention R = Rz(yaw) Ry(pitch) Rx(roll).</p>")
    return "\n".join(h)


def _pairs_html(R: dict) -> str:
    """The camera-to-camera poses T_a_b with their 1σ, or a note that the result has none."""
    h = ["<h2>Camera-to-camera poses</h2>"]
    pairs = R.get("camera_pairs") or {}
    if not pairs:
        h.append('<p class="note">No camera pairs in the result (a single camera, or method \'single\').</p>')
        return "\n".join(h)
    h.append('<table id="pairs"><tr><th class="l">pair T_a_b</th><th>translation (m)</th><th>distance (m)</th>'
             "<th>roll, pitch, yaw (deg)</th><th>1σ translation (mm, a axes)</th><th>1σ rotation (deg, a axes)</th></tr>")
    for key, p in pairs.items():
        ka, kb = p.get("a"), p.get("b")
        Tk = next((k for k in p if k.startswith("T_")), None)
        if Tk is None:
            continue
        T = np.asarray(p[Tk], float)
        h.append(f'<tr data-pair="{_esc(key)}"><td class="l">{_esc(Tk)} ({_esc(ka)} ← {_esc(kb)})</td>'
                 f'<td>{_vec(T[:3, 3], ".4f")}</td>'
                 f"<td>{num(np.linalg.norm(T[:3, 3]), '.4f')}</td><td>{_vec(np.degrees(R_to_rpy(T[:3, :3])), '.2f')}</td>"
                 f"<td>{_vec(p.get('sigma_translation_mm', [np.nan] * 3), '.3f')}</td>"
                 f"<td>{_vec(p.get('sigma_rotation_deg', [np.nan] * 3), '.4f')}</td></tr>")
    h.append("</table>")
    h.append('<p class="note">T_a_b maps points from camera b\'s optical frame to camera a\'s; 1σ along a\'s axes.</p>')
    return "\n".join(h)


def _robot_html(R: dict) -> str:
    """The arm's estimated joint zero offsets with their 1σ, the joints held fixed and why, and the
    correlations that matter (none when the result was solved without --estimate-kinematics)."""
    rb = R.get("robot")
    if not rb:
        return ""
    o, s = rb.get("joint_offsets_rad") or [], rb.get("joint_offsets_sigma_rad") or []
    names = rb.get("joint_names") or [f"joint{i + 1}" for i in range(len(o))]
    reasons = {int(f["joint"]): f.get("reason", "") for f in rb.get("fixed", [])}
    h = ["<h2>Robot kinematics: joint zero offsets</h2>",
         f'<p class="note">Model {_esc(rb.get("model", "?"))} ({_esc(rb.get("model_source", ""))}), estimated in the same '
         f"graph as the cameras ({_esc(rb.get('staging', ''))}); physical joint angle = reported angle + offset. "
         f"Prior 1σ {num(1e3 * float(rb.get('prior_sigma_rad', np.nan)), '.1f')} mrad.</p>",
         '<table id="robot-offsets"><tr><th class="l">joint</th><th>offset (mrad)</th><th>1σ (mrad)</th>'
         "<th>offset / 1σ</th><th class=\"l\">status</th></tr>"]
    for i, (n, v) in enumerate(zip(names, o)):
        sg = s[i] if i < len(s) else None
        if sg is None:
            h.append(f'<tr data-joint="{i + 1}"><td class="l">{_esc(n)}</td><td>0</td><td>—</td><td>—</td>'
                     f'<td class="l">held fixed: {_esc(reasons.get(i + 1, ""))}</td></tr>')
        else:
            z = float(v) / float(sg)
            status = "differs from zero" if abs(z) > 3 else "consistent with zero"
            h.append(f'<tr data-joint="{i + 1}"><td class="l">{_esc(n)}</td><td>{num(1e3 * float(v), "+.3f")}</td>'
                     f'<td>{num(1e3 * float(sg), ".3f")}</td><td>{num(z, "+.1f")}</td><td class="l">{status}</td></tr>')
    h.append("</table>")
    strong = rb.get("strongest_correlations") or []
    if strong:
        h.append('<table id="robot-correlations"><tr><th class="l">offset</th><th class="l">most correlated with</th>'
                 "<th>correlation</th></tr>")
        for c in strong:
            h.append(f'<tr><td class="l">joint {int(c["joint"])}</td><td class="l">{_esc(c["with"])}</td>'
                     f'<td>{num(c["correlation"], "+.3f")}</td></tr>')
        h.append("</table>")
    corr = rb.get("offset_correlations")
    est = rb.get("estimated") or []
    if corr and len(corr) == len(est) and len(est) > 1:
        off = [(abs(corr[a][b]), est[a], est[b], corr[a][b]) for a in range(len(est)) for b in range(a + 1, len(est))]
        off.sort(reverse=True)
        h.append('<p class="note">Largest correlations between offsets: ' +
                 ", ".join(f"joints {a} and {b} {c:+.2f}" for _, a, b, c in off[:3]) +
                 ". <code>calibgraph export RESULT --format urdf</code> writes a corrected arm URDF and the offsets as YAML.</p>")
    return "\n".join(h)


def _residuals_html(R: dict, names: list, residuals: dict, source: str) -> str:
    """The residual plots, or how to get them (give the dataset)."""
    h = ["<h2>Residuals</h2>"]
    if residuals:
        h.append(f'<p class="note">Per-corner residuals ({_esc(source)}): residual = reprojected − detected corner.</p>')
        h.append(_residual_plots(R, names, residuals))
    else:
        h.append('<p class="note">No per-corner residuals: the result has no <code>residuals</code> section and no '
                 "dataset was given (<code>calibgraph report RESULT --dataset DIR</code> recomputes them).</p>")
    return "\n".join(h)


def _json_for_html(d: dict) -> str:
    # "</" would end the script element early; JSON allows "\/" in strings
    return json.dumps(d, allow_nan=True).replace("</", "<\\/")


def _badge(ok) -> str:
    if ok is None:
        return '<span class="na">n/a</span>'
    return '<span class="pass">PASS</span>' if ok else '<span class="fail">FAIL</span>'


def _verdict(name: str, cam: dict, tol: dict, worst_ws_mm) -> dict:
    """{'pass', 'rows': [(label, value, op, limit, ok)]}: one camera against its tolerances."""
    limits = dict(tol["defaults"])
    limits.update(tol["cameras"].get(name, {}))
    rows = []
    ok_all = True
    for key, label, get, op in CHECKS:
        lim = limits.get(key)
        if lim is None:
            continue
        v = get(cam, worst_ws_mm)
        if v is None or not np.isfinite(float(v)):
            rows.append((label, v, op, lim, None))
            continue
        ok = float(v) <= float(lim) if op == "<=" else float(v) >= float(lim)
        ok_all &= ok
        rows.append((label, v, op, lim, ok))
    return {"pass": bool(ok_all), "rows": rows}


def _camera_section(n, R, T, cov, intr, verdict, res, ref, ws) -> str:
    """One camera: pose, 1σ and weakest directions, checks, rejected views, coverage and workspace maps."""
    c = R["cameras"][n]
    h = [f'<div class="cam" id="cam-{_esc(n)}"><h3>{_esc(n)} {_badge(verdict["pass"])}</h3>']
    q = R_to_quat_xyzw(T[:3, :3])
    h.append('<div class="plots"><div>')
    h.append(f"<b>T_{ref}_cam</b> (maps camera optical-frame points to the {ref} frame, metres){_matrix(T)}")
    h.append(f"<p>quaternion (x, y, z, w): {_vec(q, '.6f')}<br>roll, pitch, yaw: "
             f"{_vec(np.degrees(R_to_rpy(T[:3, :3])), '.3f', 'deg')}</p>")
    h.append(f"<p>1σ translation ({ref} x, y, z): {_vec(c.get('sigma_translation_mm', [np.nan] * 3), '.3f', 'mm')}<br>"
             f"1σ rotation ({ref} x, y, z): {_vec(c.get('sigma_rotation_deg', [np.nan] * 3), '.4f', 'deg')}</p>")
    if cov is not None:
        w = weakest_directions(T, cov, ref)
        h.append(f'<p class="weakest"><b>{_esc(w["summary"])}</b><br><span class="note">{_esc(w["translation"]["text"])}.<br>'
                 f'{_esc(w["rotation"]["text"])}.</span></p>')
    h.append("</div><div>")
    h.append('<table class="checks"><tr><th class="l">check</th><th>value</th><th>limit</th><th>result</th></tr>')
    for label, v, op, lim, ok in verdict["rows"]:
        h.append(f'<tr><td class="l">{_esc(label)}</td><td>{num(v, ".4g")}</td><td>{_esc(op)} {num(lim, "g")}</td>'
                 f"<td>{_badge(ok)}</td></tr>")
    h.append("</table>")
    h.append(f"<p>reprojection RMS {num(c.get('reprojection_rms_px'), '.3f', ' px')}, max "
             f"{num(c.get('reprojection_max_px'), '.3f', ' px')}; corners used {num(c.get('corners_used', np.nan), '.0f')}, "
             f"rejected {num(c.get('corners_rejected', np.nan), '.0f')}<br>views used {num(c.get('views_used'), '.0f')}, "
             f"rejected {num(len(c.get('views_rejected', [])), '.0f')}</p>")
    rej = c.get("views_rejected", [])
    if rej:
        h.append('<table class="rejected"><tr><th>capture</th><th class="l">reason</th></tr>')
        for v in rej:
            h.append(f'<tr><td>{_esc(v.get("capture"))}</td><td class="l">{_esc(v.get("reason", ""))}</td></tr>')
        h.append("</table>")
    if intr is not None:
        h.append(f'<p class="note">intrinsics: {intr.width_px}×{intr.height_px} px, fx {intr.K[0, 0]:.1f}, fy {intr.K[1, 1]:.1f}, '
                 f"cx {intr.K[0, 2]:.1f}, cy {intr.K[1, 2]:.1f}, dist {np.round(intr.dist, 4).tolist()}</p>")
    h.append("</div></div>")
    # coverage + workspace map for this camera
    h.append('<div class="plots">')
    h.append(_coverage_plot(n, res, intr))
    if n in ws["svg"]:
        h.append(ws["svg"][n])
    h.append("</div></div>")
    return "\n".join(h)


def _coverage_plot(n, res, intr) -> str:
    """Heat map of where in the image the camera saw corners."""
    uv = [np.asarray(v["uv_detected_px"], float).reshape(-1, 2) for v in res.values() if v.get("uv_detected_px")]
    if not uv:
        return svgplot.empty_plot(f"{n}: image coverage", "no detections available (give --dataset)")
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
    return svgplot.heatmap(V, xe, ye, title=f"{n}: image coverage ({100 * frac:.0f}% of cells seen)", xlabel="u (px)",
                           ylabel="v (px)", cbar_label="corners", width=470, y_down=True, nan_label="no corner")


def _workspace_maps(R, tol, poses, cov, intr) -> dict:
    """Per-camera 1σ point-error maps; also the worst visible value."""
    wcfg = tol.get("workspace") or {}
    names = [n for n in poses if n in cov]
    out = {"svg": {}, "worst": {}, "html": ""}
    if not names:
        out["html"] = '<p class="note">No covariance in the result: cannot propagate uncertainty.</p>'
        return out
    n_grid = int(wcfg.get("grid_n", 24))
    maps = {}
    if R.get("mode") == "eye_in_hand":
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
        xr, yr, z = _default_workspace(R, wcfg)
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
                mk.append({"x": 0.0, "y": 0.0, "label": "robot base", "color": "#d62728"})
            t = poses[n][:3, 3]
            if xe[0] <= t[0] <= xe[-1] and ye[0] <= t[1] <= ye[-1]:
                mk.append({"x": t[0], "y": t[1], "label": n, "color": "#ff7f0e"})
            markers[n] = mk
    rows = []
    for n in names:
        m = maps[n]
        worst = float(np.nanmax(m)) if np.isfinite(m).any() else None
        best = float(np.nanmin(m)) if np.isfinite(m).any() else None
        out["worst"][n] = worst
        label = ""
        if R.get("mode") != "eye_in_hand":
            d = np.linalg.norm(poses[n][:3, 3])
            label = f" (camera {d:.1f} m from base)"
        # each camera on its own colour scale: the pattern (which way the error grows) is the point;
        # the table compares cameras
        out["svg"][n] = svgplot.heatmap(m, xe, ye, title=f"{n}: 1σ point error from pose uncertainty{label}",
                                        xlabel=xlabel, ylabel=ylabel, cbar_label="1σ mm (3D)", width=540,
                                        markers=markers.get(n), nan_label="not visible")
        rows.append(f'<tr data-camera="{_esc(n)}"><td class="l">{_esc(n)}</td><td>{num(best, ".3f")}</td>'
                    f'<td>{num(worst, ".3f")}</td><td>{num(np.isfinite(m).mean() * 100, ".0f")}</td></tr>')
    out["html"] = (
        '<p class="note">Expected localisation error caused by each camera\'s pose uncertainty alone: a point the camera '
        "measures is reported in the robot frame through T_ref_cam, so its 1σ position error is "
        "sqrt(trace(J Σ J<sup>T</sup>)), J = [−[p − t]<sub>×</sub>, I] (rotation first). It grows with the distance from the "
        f"camera through the rotation uncertainty. Maps: {_esc(where)}. Each map has its own colour scale (the table "
        "below compares cameras); the maps are shown in each camera's section above.</p>"
        '<table id="workspace"><tr><th class="l">camera</th><th>best 1σ (mm)</th><th>worst visible 1σ (mm)</th>'
        "<th>map cells visible (%)</th></tr>" + "".join(rows) + "</table>"
    )
    return out


def _edges(c):
    """Bin edges around the given bin centres."""
    c = np.asarray(c, float)
    d = np.diff(c)
    return np.concatenate([[c[0] - d[0] / 2], c[:-1] + d / 2, [c[-1] + d[-1] / 2]])


def _default_workspace(R, wcfg):
    """Workspace extent: config, else where the board was presented (+15 cm), else a Panda-sized box."""
    if "x_m" in wcfg and "y_m" in wcfg:
        return wcfg["x_m"], wcfg["y_m"], float(wcfg.get("z_m", 0.5))
    flange = [np.asarray(T, float) for T in (R.get("robot_flange_poses_refined") or {}).values()]
    T_fb = R.get("T_flange_board")
    if flange:
        if T_fb is not None:
            pts = np.array([(F @ np.asarray(T_fb, float))[:3, 3] for F in flange])
        else:
            pts = np.array([F[:3, 3] for F in flange])
        lo, hi = pts.min(0) - 0.15, pts.max(0) + 0.15
        z = float(wcfg.get("z_m", np.median(pts[:, 2])))
        return wcfg.get("x_m", [lo[0], hi[0]]), wcfg.get("y_m", [lo[1], hi[1]]), z
    return wcfg.get("x_m", [0.0, 0.9]), wcfg.get("y_m", [-0.6, 0.6]), float(wcfg.get("z_m", 0.5))


def _residual_plots(R, names, residuals) -> str:
    """Per camera: histogram of the used corners' residual norms and residual norms per capture, rejections marked."""
    rejected_corners = {}
    for rc in R.get("rejected_corners") or []:
        rejected_corners.setdefault((rc["camera"], int(rc["capture"])), set()).add(int(rc["id"]))
    sig = (R.get("solver") or {}).get("pixel_sigma_px")
    k_out = ((R.get("solver") or {}).get("settings") or {}).get("outlier_sigmas")
    thresh = float(sig) * float(k_out) if sig and k_out else None
    h = []
    for n in names:
        res = residuals.get(n) or {}
        used_norm, caps_used, out_x, out_y, rv_x, rv_y, rms_x, rms_y = [], [], [], [], [], [], [], []
        for cap, v in sorted(res.items(), key=lambda kv: int(kv[0])):
            r = np.asarray(v.get("residual_px", []), float).reshape(-1, 2)
            ids = np.asarray(v.get("ids", []), int)
            if r.size == 0:
                continue
            norm = np.linalg.norm(r, axis=1)
            k = int(cap)
            bad = np.array([i in rejected_corners.get((n, k), set()) for i in ids], bool) if ids.size == norm.size else np.zeros(norm.size, bool)
            bad |= corner_rejected_mask(v, norm.size)
            if v.get("rejected"):
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
        c = R["cameras"][n]
        vl = {f"RMS {c.get('reprojection_rms_px', float('nan')):.3f} px": c.get("reprojection_rms_px", np.nan)}
        if thresh:
            vl[f"outlier limit {thresh:.2f} px"] = thresh
        h.append('<div class="plots">')
        h.append(svgplot.histogram(used_norm, bins=30, title=f"{n}: |residual| of used corners", xlabel="|residual| (px)",
                                   width=380, vlines={k: v for k, v in vl.items() if np.isfinite(v)}))
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
                                 ylim=(0.0, top * 1.04),
                                 hlines={f"outlier limit {thresh:.2f} px": thresh} if thresh else None))
        h.append("</div>")
    return "\n".join(h)


def _provenance(R, ds, result_path, tol, config) -> str:
    """Where the numbers come from: result file and hash, versions, dataset, solver outcome and settings, tolerances."""
    s = R.get("solver") or {}
    rows = [
        ("result file", f"{result_path} (sha256 {_sha256(result_path)[:16]}…)" if result_path else "(given as a dict)"),
        ("result format", R.get("format", "?")),
        ("calibgraph version that solved", R.get("calibgraph_version", "?")),
        ("calibgraph version of this report", __version__),
        ("dataset", R.get("dataset") or (str(ds.root) if ds is not None else "n/a")),
        ("mode / method", f"{R.get('mode', '?')} / {R.get('method', '?')}"),
        ("converged", s.get("converged", "?")),
        ("iterations", s.get("iterations", "?")),
        ("final cost", s.get("final_cost", "?")),
        ("pixel sigma used (px)", s.get("pixel_sigma_px", "?")),
        ("solve time (s)", s.get("solve_time_s", "?")),
        ("tolerances", f"{config}" if config is not None and not isinstance(config, dict) else
         ("given as a dict" if isinstance(config, dict) else f"defaults ({DEFAULT_TOLERANCES.name})")),
    ]
    if ds is not None:
        t = ds.target
        rows += [("dataset folder", str(ds.root)), ("captures in dataset", len(ds.captures)),
                 ("target", f"{t.kind} {t.rows}×{t.cols} points, pitch {t.pitch_m * 1e3:.1f} mm"),
                 ("dataset problems", "; ".join(f"{f}: {m}" for f, m in ds.problems) or "none")]
    mk = _mount_key(R)
    if mk in R:
        T = np.asarray(R[mk], float)
        bm = R.get("board_mount") or {}
        rows.append((f"{mk} (m)", f"t = {np.round(T[:3, 3], 5).tolist()}; 1σ "
                     f"{np.round(bm.get('sigma_translation_mm', [np.nan] * 3), 3).tolist()} mm, "
                     f"{np.round(bm.get('sigma_rotation_deg', [np.nan] * 3), 4).tolist()} deg"))
    h = ['<table id="provenance">'] + [f'<tr><th class="l">{_esc(k)}</th><td class="l">{_esc(v)}</td></tr>' for k, v in rows]
    h.append("</table>")
    h.append(f"<p><b>Solver settings</b></p><pre>{_esc(json.dumps(s.get('settings', {}), indent=2))}</pre>")
    h.append(f"<p><b>Tolerances applied</b></p><pre>{_esc(json.dumps(tol, indent=2))}</pre>")
    return "\n".join(h)


def _sha256(path) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "unreadable"
