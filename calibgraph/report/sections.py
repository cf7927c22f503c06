"""The report's sections, each from a :class:`~calibgraph.solver.output.result.Result`: the verdict banner,
the summary table, one section per camera, the camera-to-camera poses, the robot's joint offsets
and the provenance (where every number comes from)."""

from __future__ import annotations

import datetime as _dt
import hashlib

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import R_to_quat_xyzw
from calibgraph.core.version import __version__
from calibgraph.io.files import read_input_bytes
from calibgraph.report import findings
from calibgraph.report.exports import R_to_rpy
from calibgraph.report.markup import badge, esc, matrix, num, vec
from calibgraph.report.tolerances import CHECKS, DEFAULT_TOLERANCES, covariance_problem, sigma_norm
from calibgraph.report.workspace import coverage_plot
from calibgraph.solver.output.result import FRAME_CONVENTION, RESULT_FORMAT, intrinsics_provenance, sigmas_from_cov
from calibgraph.solver.camera.session_plan import name_workcell
from calibgraph.solver.uncertainty.workspace import weakest_directions


def banner_html(result, title: str, verdicts: dict) -> str:
    """Title, generation note and the overall verdict (FAIL when a camera fails or the solver did
    not converge), with each failing camera's reasons."""
    overall = all(v["pass"] for v in verdicts.values()) and result.converged
    why = "" if result.converged else " (the solver did not converge)"
    failed = [n for n in result.cameras if not verdicts[n]["pass"]]
    generated = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    h = [f"<h1>{esc(title)}</h1>",
         f'<p class="note">Generated {esc(generated)} by calibgraph {esc(__version__)}. '
         f"Frame convention: {esc(FRAME_CONVENTION)}</p>",
         f'<div class="banner {"pass" if overall else "fail"}" id="verdict">Overall: {"PASS" if overall else "FAIL"}'
         f'{esc(why)}' + (f" — failing: {esc(', '.join(failed))}" if failed else "") + "</div>"]
    if failed:
        h.append('<ul id="failing-reasons">' + "".join(
            f"<li>{esc(n)}: {esc('; '.join(verdicts[n]['reasons']))}{_notes_link(result, n)}"
            + ("".join(f'<br><span class="fix">To fix: {esc(_strip_name(n, f))}</span>' for f in verdicts[n].get("fixes", [])))
            + "</li>" for n in failed) + "</ul>")
        k = len(result.cell_notes)
        if k:
            h.append(f'<p class="note">The solver also left <a href="#cell-notes">{k} note{"s" if k != 1 else ""} on the '
                     "whole cell</a> (board, robot) that bear on every camera.</p>")
    return "\n".join(h)


def _strip_name(n: str, text: str) -> str:
    return text[len(n) + 2:] if text.startswith(f"{n}: ") else text


def _notes_link(result, n: str) -> str:
    """' — the solver's notes on it (k)' linking to the camera's section, when it has notes."""
    k = len(result.camera_notes(n))
    return f' — <a href="#cam-{esc(n)}">the solver\'s note{"s" if k != 1 else ""} on it ({k})</a>' if k else ""


def summary_html(result, verdicts: dict) -> str:
    """The summary table: one row per camera (pose, 1σ, reprojection, views, verdict)."""
    ref = result.ref_frame
    h = ["<h2>Summary</h2>",
         f'<table id="summary"><tr><th class="l">camera</th><th>position in {ref} (m)</th><th>roll, pitch, yaw (deg)</th>'
         "<th>1σ translation (mm): norm (x, y, z)</th><th>1σ rotation (deg): norm (x, y, z)</th><th>reproj. RMS (px)</th>"
         "<th>reproj. max (px)</th><th>views used</th><th>views rejected</th><th>verdict</th></tr>"]
    for n, c in result.cameras.items():
        if not c.calibrated:
            h.append(f'<tr data-camera="{esc(n)}"><td class="l"><a href="#cam-{esc(n)}">{esc(n)}</a></td>'
                     f'<td class="l" colspan="6">not calibrated: {esc(c.why)}</td><td>{num(c.views_used, ".0f")}</td>'
                     f"<td>{num(len(c.views_rejected), '.0f')}</td><td>{badge(False)}</td></tr>")
            continue
        T = c.T_ref_cam
        h.append(f'<tr data-camera="{esc(n)}"><td class="l"><a href="#cam-{esc(n)}">{esc(n)}</a></td>'
                 f"<td>{vec(T[:3, 3], '.4f')}</td><td>{vec(np.degrees(R_to_rpy(T[:3, :3])), '.2f')}</td>"
                 f"<td>{sigma_html(c.sigma_translation_mm, '.3f')}</td><td>{sigma_html(c.sigma_rotation_deg, '.4f')}</td>"
                 f"<td>{num(c.reprojection_rms_px, '.3f')}</td><td>{num(c.reprojection_max_px, '.3f')}</td>"
                 f"<td>{num(c.views_used, '.0f')}</td><td>{num(len(c.views_rejected), '.0f')}</td>"
                 f"<td>{badge(verdicts[n]['pass'])}</td></tr>")
    h.append("</table>")
    h.append(f'<p class="note">A camera\'s 1σ is one figure, the norm sqrt(x² + y² + z²) of its 1σ along the {ref} '
             f"frame axes (in brackets; rotation: components of the rotation vector perturbation in {ref} axes): the "
             "figure the tolerances, the error budget and capture --auto --tolerance-mm use. Roll, pitch, yaw: URDF "
             "fixed-axis convention R = Rz(yaw) Ry(pitch) Rx(roll).</p>")
    return "\n".join(h)


# a check's value, rounded to what it means (px to 0.001, a count to 1, a workspace 1σ to 0.01 mm)
CHECK_FORMATS = {"reprojection RMS (px)": ".3f", "reprojection max (px)": ".3f", "views used": ".0f",
                 "worst 1σ point error in the workspace (mm)": ".2f"}


def sigma_html(per_axis, fmt: str, unit: str = "") -> str:
    """A camera's one 1σ figure, the norm of its per-axis 1σ, with the axes beside it:
    '<b>0.719</b> (0.320, 0.614, 0.191)'."""
    return f"<b>{num(sigma_norm(per_axis), fmt)}</b>{esc(' ' + unit if unit else '')} {vec(per_axis, fmt)}"


def _weakest_html(w: dict, norm_mm: float) -> str:
    """Where a camera's 1σ lies, in words: the direction it is least sure of (the largest eigen-
    direction of its covariance, part of its 1σ norm), then the numbers."""
    t, r = w["translation"], w["rotation"]
    return (f'<p class="weakest">Of its {norm_mm:.3g} mm, most lies {esc(t["where"])}: {t["sigma"]:.3g} mm that way, '
            f'{t["sigma_min"]:.3g} mm in its best-known direction; it turns most {esc(r["where"])} '
            f'({r["sigma"]:.3g} deg).<br><span class="note">{esc(t["text"])}.<br>{esc(r["text"])}.</span></p>')


def camera_html(result, n: str, intr, verdict: dict, residuals: dict, ws: dict) -> str:
    """One camera: pose, 1σ and weakest directions, checks, rejected views, coverage and workspace maps."""
    c = result.cameras[n]
    if not c.calibrated:
        return "\n".join([f'<div class="cam" id="cam-{esc(n)}"><h3>{esc(n)} {badge(False)}</h3>',
                          f'<p class="why"><b>Not calibrated</b>: {esc(c.why)}</p>', moved_html(result, n),
                          camera_notes_html(result, n), _rejected_views_html(c), "</div>"])
    ref, T = result.ref_frame, c.T_ref_cam
    h = [f'<div class="cam" id="cam-{esc(n)}"><h3>{esc(n)} {badge(verdict["pass"])}</h3>',
         budget_html(c), moved_html(result, n), camera_notes_html(result, n), intrinsics_html(result, n, intr),
         '<div class="plots"><div>',
         f"<b>T_{ref}_cam</b> (maps camera optical-frame points to the {ref} frame, metres){matrix(T)}",
         f"<p>quaternion (x, y, z, w): {vec(R_to_quat_xyzw(T[:3, :3]), '.6f')}<br>roll, pitch, yaw: "
         f"{vec(np.degrees(R_to_rpy(T[:3, :3])), '.3f', 'deg')}</p>",
         f"<p><b>1σ translation</b>: {sigma_html(c.sigma_translation_mm, '.3f', 'mm')} (norm; {ref} x, y, z)<br>"
         f"<b>1σ rotation</b>: {sigma_html(c.sigma_rotation_deg, '.4f', 'deg')} (norm; {ref} x, y, z)</p>"]
    if covariance_problem(c.covariance) is None:  # a covariance to draw directions from
        h.append(_weakest_html(weakest_directions(T, c.covariance, ref), sigma_norm(c.sigma_translation_mm)))
    h.append("</div><div>")
    h.append('<table class="checks"><tr><th class="l">check</th><th>value</th><th>limit</th><th>result</th></tr>')
    axes = {"1σ translation (mm)": (c.sigma_translation_mm, ".3f"), "1σ rotation (deg)": (c.sigma_rotation_deg, ".4f")}
    for label, v, op, lim, ok in verdict["rows"]:
        lim_html = esc(lim) if isinstance(lim, str) else num(lim, "g")
        per_axis, fmt = axes.get(label, (None, CHECK_FORMATS.get(label, ".4g")))
        value = sigma_html(per_axis, fmt) if per_axis is not None else num(v, fmt)
        h.append(f'<tr><td class="l">{esc(label)}</td><td>{value}</td><td>{esc(op)} {lim_html}</td>'
                 f"<td>{badge(ok)}</td></tr>")
    h.append("</table>")
    sigma = "" if c.pixel_sigma_px is None else f" (its corners' σ {num(c.pixel_sigma_px, '.3f', ' px')} per axis)"
    h.append(f"<p>reprojection RMS {num(c.reprojection_rms_px, '.3f', ' px')}{sigma}, max "
             f"{num(c.reprojection_max_px, '.3f', ' px')}; corners used {num(c.corners_used, '.0f')}, "
             f"rejected {num(c.corners_rejected, '.0f')}<br>views used {num(c.views_used, '.0f')}, "
             f"rejected {num(len(c.views_rejected), '.0f')}</p>")
    h.append(_rejected_views_html(c))
    h.append("</div></div>")
    h.append('<div class="plots">')
    h.append(coverage_plot(n, residuals, intr))
    if n in ws["svg"]:
        h.append(ws["svg"][n])
    h.append("</div></div>")
    return "\n".join(h)


def _rejected_views_html(c) -> str:
    if not c.views_rejected:
        return ""
    return ('<table class="rejected"><tr><th>capture</th><th class="l">reason</th></tr>'
            + "".join(f'<tr><td>{esc(v.capture)}</td><td class="l">{esc(v.reason)}</td></tr>' for v in c.views_rejected)
            + "</table>")


def pairs_html(result) -> str:
    """The camera-to-camera poses T_a_b with their 1σ, or a note that the result has none."""
    h = ["<h2>Camera-to-camera poses</h2>"]
    if not result.pairs:
        h.append('<p class="note">No camera pairs in the result (a single camera, or method \'single\').</p>')
        return "\n".join(h)
    h.append('<table id="pairs"><tr><th class="l">pair T_a_b</th><th>translation (m)</th><th>distance (m)</th>'
             "<th>roll, pitch, yaw (deg)</th><th>1σ translation (mm, a axes)</th><th>1σ rotation (deg, a axes)</th></tr>")
    for (a, b), p in result.pairs.items():
        T = p.T_a_b
        h.append(f'<tr data-pair="{esc(f"{a}__{b}")}"><td class="l">T_{esc(a)}_{esc(b)} ({esc(a)} ← {esc(b)})</td>'
                 f'<td>{vec(T[:3, 3], ".4f")}</td>'
                 f"<td>{num(np.linalg.norm(T[:3, 3]), '.4f')}</td><td>{vec(np.degrees(R_to_rpy(T[:3, :3])), '.2f')}</td>"
                 f"<td>{vec(p.sigma_translation_mm, '.3f')}</td><td>{vec(p.sigma_rotation_deg, '.4f')}</td></tr>")
    h.append("</table>")
    h.append('<p class="note">T_a_b maps points from camera b\'s optical frame to camera a\'s; 1σ along a\'s axes.</p>')
    return "\n".join(h)


def robot_html(result) -> str:
    """The arm's estimated joint zero offsets with their 1σ, the joints held fixed and why, and the
    correlations that matter (none when the result was solved without --estimate-kinematics)."""
    rb = result.robot
    if not rb:
        return ""
    o, s = rb.get("joint_offsets_rad") or [], rb.get("joint_offsets_sigma_rad") or []
    names = rb.get("joint_names") or [f"joint{i + 1}" for i in range(len(o))]
    reasons = {int(f["joint"]): f.get("reason", "") for f in rb.get("fixed", [])}
    h = ["<h2>Robot kinematics: joint zero offsets</h2>",
         f'<p class="note">Model {esc(rb.get("model", "?"))} ({esc(rb.get("model_source", ""))}), estimated in the same '
         f"graph as the cameras ({esc(rb.get('staging', ''))}); physical joint angle = reported angle + offset. "
         f"Prior 1σ {num(1e3 * float(rb.get('prior_sigma_rad', np.nan)), '.1f')} mrad.</p>",
         '<table id="robot-offsets"><tr><th class="l">joint</th><th>offset (mrad)</th><th>1σ (mrad)</th>'
         "<th>offset / 1σ</th><th class=\"l\">status</th></tr>"]
    for i, (n, v) in enumerate(zip(names, o)):
        sg = s[i] if i < len(s) else None
        if sg is None:
            h.append(f'<tr data-joint="{i + 1}"><td class="l">{esc(n)}</td><td>0</td><td>—</td><td>—</td>'
                     f'<td class="l">held fixed: {esc(reasons.get(i + 1, ""))}</td></tr>')
        else:
            z = float(v) / float(sg)
            status = "differs from zero" if abs(z) > 3 else "consistent with zero"
            h.append(f'<tr data-joint="{i + 1}"><td class="l">{esc(n)}</td><td>{num(1e3 * float(v), "+.3f")}</td>'
                     f'<td>{num(1e3 * float(sg), ".3f")}</td><td>{num(z, "+.1f")}</td><td class="l">{status}</td></tr>')
    h.append("</table>")
    strong = rb.get("strongest_correlations") or []
    if strong:
        h.append('<table id="robot-correlations"><tr><th class="l">offset</th><th class="l">most correlated with</th>'
                 "<th>correlation</th></tr>")
        for c in strong:
            h.append(f'<tr><td class="l">joint {int(c["joint"])}</td><td class="l">{esc(c["with"])}</td>'
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


def provenance_html(result, ds, result_path, tol: dict, config) -> str:
    """Where the numbers come from: result file and hash, versions, dataset, solver outcome and
    settings, tolerances; each number rounded to what it means (the exact values are in the result
    embedded in the page)."""
    rows = [
        ("result file", f"{result_path} (sha256 {_sha256(result_path)[:16]}…)" if result_path else "(given in memory)"),
        ("result format", RESULT_FORMAT),
        ("calibgraph version that solved", result.calibgraph_version),
        ("calibgraph version of this report", __version__),
        ("dataset", result.dataset or (str(ds.root) if ds is not None else "n/a")),
        ("mode / method", f"{result.mode} / {result.method}"),
        ("converged", "yes" if result.converged else "no"),
        ("iterations", result.iterations),
        ("final cost (sum of squared whitened residuals)", _round(result.final_cost, ".1f")),
        ("pixel sigma used (px)", _round(result.pixel_sigma_px, ".4f")),
        ("solve time (s)", _round(result.solve_time_s, ".2f")),
        ("tolerances", f"{config}" if config is not None and not isinstance(config, dict) else
         ("given as a dict" if isinstance(config, dict) else f"defaults ({DEFAULT_TOLERANCES.name})")),
    ]
    rows += [(f"intrinsics of {n}", findings.provenance_text(c, result.settings)) for n, c in result.cameras.items()
             if c.intrinsics]
    if ds is not None:
        t = ds.target
        rows += [("dataset folder", str(ds.root)), ("captures in dataset", len(ds.captures)),
                 ("target", f"{t.kind} {t.rows}×{t.cols} points, pitch {t.pitch_m * 1e3:.1f} mm"),
                 ("dataset problems", "; ".join(f"{f}: {m}" for f, m in ds.problems) or "none")]
    if result.T_mount_board is not None:
        key = "T_flange_board" if result.mode == "eye_to_hand" else "T_base_board"
        st, sr = (sigmas_from_cov(result.mount_covariance) if result.mount_covariance is not None
                  else ([np.nan] * 3, [np.nan] * 3))
        t_mm = 1e3 * np.asarray(result.T_mount_board[:3, 3], float)
        rows.append((f"{key}", f"t = ({_join(t_mm, '.2f')}) mm; 1σ ({_join(st, '.3f')}) mm, ({_join(sr, '.4f')}) deg"))
    h = ['<table id="provenance">'] + [f'<tr><th class="l">{esc(k)}</th><td class="l">{esc(v)}</td></tr>' for k, v in rows]
    h.append("</table>")
    h.append(settings_html(result.settings))
    h.append(tolerances_html(tol))
    return "\n".join(h)


def _round(v, fmt: str) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "n/a" if v is None else str(v)
    return format(f, fmt) if np.isfinite(f) else "n/a"


def _join(values, fmt: str) -> str:
    return ", ".join(_round(v, fmt) for v in values)


def setting_text(key: str, v) -> str:
    """A solver setting's value as a reader wants it: units from the key's suffix, small lengths
    and angles also in mm and deg, booleans as yes/no, unset as 'estimated'/'default'."""
    if v is None:
        return "estimated" if key == "pixel_sigma_px" else "not set"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        f = float(v)
        if key.endswith("_rad"):
            return f"{np.degrees(f):.4g} deg"
        if key.endswith("_m"):
            return f"{1e3 * f:.4g} mm"
        unit = " px" if key.endswith("_px") else ""
        return f"{f:.4g}{unit}"
    if isinstance(v, (list, tuple)):
        return ", ".join(str(x) for x in v) or "none"
    if isinstance(v, dict):
        return "; ".join(f"{k}: {setting_text(str(k), x)}" for k, x in v.items()) or "none"
    return str(v)


def settings_html(settings: dict | None) -> str:
    """The solver's settings as a table (the SolverOptions names, which dataset.yaml's solver:
    section takes, and their values in readable units)."""
    if not settings:
        return '<p class="note">The result does not record the solver settings.</p>'
    rows = "".join(f'<tr><td class="l"><code>{esc(k)}</code></td><td class="l">{esc(setting_text(k, v))}</td></tr>'
                   for k, v in settings.items())
    return ('<p><b>Solver settings</b> <span class="note">(names as dataset.yaml\'s <code>solver:</code> section '
            f'takes them)</span></p><table id="settings"><tr><th class="l">setting</th><th class="l">value</th></tr>'
            f"{rows}</table>")


def tolerances_html(tol: dict) -> str:
    """The tolerances applied, as a table: each check's limit, the cameras' own limits beside it,
    and the workspace region mapped."""
    cams = sorted(tol.get("cameras") or {})
    head = "".join(f"<th>{esc(c)}</th>" for c in cams)
    rows = []
    for key, label, _get, op, *_ in CHECKS:
        lim = (tol.get("defaults") or {}).get(key)
        own = "".join(f"<td>{esc(_limit_text(tol['cameras'][c].get(key, lim), op))}</td>" for c in cams)
        rows.append(f'<tr><td class="l">{esc(label)} <span class="note"><code>{esc(key)}</code></span></td>'
                    f"<td>{esc(_limit_text(lim, op))}</td>{own}</tr>")
    ws = tol.get("workspace") or {}
    ws_text = "; ".join(f"{k} {setting_text(k, v) if not isinstance(v, (list, tuple)) else _join(v, '.3g')}"
                        for k, v in ws.items()) or "from where the board was presented, padded by 15 cm"
    return (f'<p><b>Tolerances applied</b></p><table id="tolerances"><tr><th class="l">check</th><th>limit</th>{head}'
            f"</tr>{''.join(rows)}</table><p class=\"note\">Workspace mapped: {esc(ws_text)}.</p>")


def _limit_text(lim, op: str) -> str:
    return "not checked" if lim is None else f"{op} {lim:g}" if isinstance(lim, (int, float)) else f"{op} {lim}"


def _sha256(path) -> str:
    try:
        return hashlib.sha256(read_input_bytes(path, "result")).hexdigest()
    except InputError:
        return "unreadable"


# -- what the solver knows: advice, error budget, intrinsics, moves, notes ---------------------------------
BUDGET_COLOURS = {"corners": "#1f77b4", "intrinsics": "#ff7f0e", "robot_fk": "#2ca02c", "board": "#9467bd"}
OTHER_COLOURS = ("#8c564b", "#e377c2", "#17becf", "#bcbd22", "#7f7f7f", "#d62728")


def improve_html(result, workcell=None) -> str:
    """The box at the top: what would improve this calibration, each camera's advice with its
    numbers (its 1σ now, what the remedy would bring it to; the commands naming ``workcell``, the cell
    file the dataset was captured with, where the result's advice has the placeholder), the cameras
    not calibrated and why, and how many notes the page carries. The page says each advice here only."""
    items = []
    for n, c in result.cameras.items():
        link = f'<a href="#cam-{esc(n)}">{esc(n)}</a>'
        if not c.calibrated:
            items.append(f'<li data-camera="{esc(n)}">{link}: <b>not calibrated</b> — {esc(c.why)}</li>')
        elif findings.advice(c):
            text = name_workcell(findings.advice_for(n, c), workcell)
            items.append(f'<li data-camera="{esc(n)}">{link}: <span class="advice">{esc(text)}</span></li>')
    n_notes = len(result.notes)
    if not items and not n_notes:
        return ""
    h = ['<div class="improve" id="improve"><b>What would improve this calibration</b>']
    h.append("<ul>" + "".join(items) + "</ul>" if items else
             '<p class="note">The result carries no advice (written before calibgraph gave it).</p>')
    if n_notes:
        cell = len(result.cell_notes)
        h.append(f'<p class="note">The solver left {n_notes} note{"s" if n_notes != 1 else ""}: '
                 f"{n_notes - cell} under the camera{'s' if n_notes - cell != 1 else ''} they concern, {cell} in "
                 f'<a href="#cell-notes">notes on the whole cell</a>.</p>')
    h.append("</div>")
    return "\n".join(h)


def budget_html(c) -> str:
    """The camera's error budget: a bar of shares per labelled share set, its numbers, the advice."""
    b = c.error_budget
    if not b:
        return ""
    s = findings.sigma_norm_mm(c)
    h = ['<div class="budget"><b>What its 1σ translation' + (f" of {num(s, '.3f', ' mm')}" if s is not None else "")
         + " is made of</b>"]
    for label, shares in findings.share_sets(b):
        h.append(f'<div class="shareset" data-set="{esc(label)}"><span class="setlabel">{esc(label)}</span>'
                 + _bar(shares) + "</div>")
    extra = [(lab, v, unit) for lab, v, unit in findings.budget_scalars(b) if not lab.startswith("1σ translation")]
    if extra:
        h.append('<p class="note">' + "; ".join(
            f"{esc(lab)}: " + (esc(findings.percent(v)) if unit == "share" else num(v, ".4g", f" {unit}" if unit else ""))
            for lab, v, unit in extra) + "</p>")
    for key, text in findings.budget_texts(b):
        if key == "advice":  # said once, in the box at the top
            h.append('<p class="note">What would shrink it most: its advice in <a href="#improve">What would improve '
                     "this calibration</a>.</p>")
        else:
            h.append(f'<p class="note"><b>{esc(findings.humanise(key))}:</b> {esc(text)}</p>')
    h.append("</div>")
    return "\n".join(h)


def _bar(shares: dict) -> str:
    """The shares as bars (CSS, no assets) with a legend giving each in words: one stacked bar when
    they add up to 1 (parts of the variance), else one bar per source (e.g. the fraction of the
    variance that would go were that source known exactly: these overlap, so they are not stacked)."""
    colours = {k: BUDGET_COLOURS.get(k) or OTHER_COLOURS[i % len(OTHER_COLOURS)] for i, k in enumerate(shares)}
    order = sorted(shares.items(), key=lambda kv: -kv[1])
    legend = "".join(f'<span class="key" data-source="{esc(k)}"><i style="background:{colours[k]}"></i>'
                     f'{esc(findings.source_label(k))} <span class="num" data-value="{float(v)!r}">'
                     f"{esc(findings.percent(v))}</span></span>" for k, v in order)

    def seg(k, v):
        w = min(max(100.0 * v, 0.0), 100.0)
        title = esc(f"{findings.source_label(k)} {findings.percent(v)}")
        return f'<span style="width:{w:.2f}%;background:{colours[k]}" title="{title}"></span>' if w > 0 else ""

    if abs(sum(shares.values()) - 1.0) <= 0.02:
        return f'<div class="bar">{"".join(seg(k, v) for k, v in order)}</div><div class="legend">{legend}</div>'
    bars = "".join(f'<div class="bar one">{seg(k, v)}</div>' for k, v in order)
    return f'<div class="bars">{bars}</div><div class="legend">{legend} (each of 100 %; they overlap)</div>'


def intrinsics_html(result, n: str, intr) -> str:
    """Where the camera's intrinsics came from and how they were used, with given -> estimated,
    1σ and the prior's width per parameter."""
    c = result.cameras[n]
    if not c.intrinsics:
        if intr is None:
            return ""
        return (f'<p class="note">intrinsics (from the dataset; the result does not record them): {intr.width_px}×'
                f"{intr.height_px} px, fx {intr.K[0, 0]:.1f}, fy {intr.K[1, 1]:.1f}, cx {intr.K[0, 2]:.1f}, "
                f"cy {intr.K[1, 2]:.1f}, dist {np.round(intr.dist, 4).tolist()}</p>")
    d = c.intrinsics
    p = intrinsics_provenance(c, result.settings)
    h = [f'<div class="intrinsics" data-source-given="{esc(p["given"])}" data-source-used="{esc(p["used"])}">'
         f'<b>Intrinsics</b> ({d.get("width_px")}×{d.get("height_px")} px) — '
         f'<span class="provenance">{esc(findings.provenance_text(c, result.settings))}</span>']
    rows = findings.intrinsics_rows(c)
    estimated = any(r[3] is not None for r in rows)
    if estimated:
        h.append('<table class="intr"><tr><th class="l">parameter</th><th>given</th><th>estimated</th><th>1σ</th>'
                 "<th>estimated − given</th><th>prior 1σ</th></tr>")
        for name, given, est, sg, prior in rows:
            fmt = findings.fmt(name)
            diff = "—" if given is None else num(est - given, "+" + fmt)
            h.append(f'<tr data-param="{esc(name)}"><td class="l">{esc(name)}</td>'
                     f'<td>{"—" if given is None else num(given, fmt)}</td><td>{num(est, fmt)}</td>'
                     f'<td>{num(sg, fmt)}</td><td>{diff}</td><td>{"—" if prior is None else num(prior, fmt)}</td></tr>')
        h.append("</table>")
        if p["used"] == "own-views":
            h.append('<p class="note">No intrinsics were given: they were found from its own views (the prior is '
                     "wide, around a first estimate from those views).</p>")
    else:
        h.append('<p class="note">held as given: ' + ", ".join(f"{esc(k)} {num(v, findings.fmt(k))}" for k, _g, v, _s, _p in rows)
                 + "</p>")
    h.append("</div>")
    return "\n".join(h)


def moved_html(result, n: str) -> str:
    """A camera that moved during capture: where, by how much (± 1σ), its pose before and after."""
    c = result.cameras[n]
    mv = findings.moved_summary(c)
    if mv is None:
        return ""
    ref = result.ref_frame
    rows = []
    for label, t, sg, views, missing in (("before the move", mv["t_before_m"], mv["sigma_before_mm"], mv["views_before"],
                                          "not solved (too few views)"),
                                         ("after the move (the pose reported)", mv["t_after_m"], mv["sigma_after_mm"],
                                          mv["views_after"], "not calibrated")):
        where = f'<td class="l" colspan="2">{missing}</td>' if t is None else (f"<td>{vec(t, '.4f')}</td><td>{'—' if sg is None else vec(sg, '.3f')}</td>")
        rows.append(f'<tr><td class="l">{label}</td>{where}<td>{num(views, ".0f")}</td></tr>')
    return (f'<div class="moved"><b>Moved during capture</b>, {esc(mv["where"])}: '
            f'{num(mv["displacement_mm"], ".1f")} ± {num(mv["sigma_mm"], ".1f")} mm (1σ), {num(mv["rotation_deg"], ".2f")} deg'
            f'<table class="movedt"><tr><th class="l"></th><th>position in {esc(ref)} (m)</th>'
            f"<th>1σ x, y, z (mm)</th><th>views</th></tr>{''.join(rows)}</table></div>")


def camera_notes_html(result, n: str) -> str:
    """Every note of the solver that concerns camera ``n``."""
    notes = result.camera_notes(n)
    if not notes:
        return ""
    return ('<div class="notes"><b>Notes</b><ul>' + "".join(f"<li>{note_html(t)}</li>" for t in notes) + "</ul></div>")


def note_html(text: str) -> str:
    """A solver's note: its plain sentence, then its technical detail (after 'Detail: ') set smaller."""
    plain, sep, detail = str(text).partition(" Detail: ")
    return esc(plain) + (f' <span class="detail">Detail: {esc(detail)}</span>' if sep else "")


def cell_notes_html(result) -> str:
    """The notes on the whole cell (board scale, robot forward kinematics, joint offsets)."""
    notes = result.cell_notes
    if not notes:
        return ('<h2 id="cell-notes">Notes on the whole cell</h2>\n<p class="note">None: the solver found nothing to '
                "say about the board or the robot.</p>")
    body = "<ul>" + "".join(f"<li>{note_html(t)}</li>" for t in notes) + "</ul>"
    return f'<h2 id="cell-notes">Notes on the whole cell</h2>\n<div class="notes cell">{body}</div>'
