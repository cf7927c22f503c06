"""The report's sections, each from a :class:`~calibgraph.solver.result.Result`: the verdict banner,
the summary table, one section per camera, the camera-to-camera poses, the robot's joint offsets
and the provenance (where every number comes from)."""

from __future__ import annotations

import datetime as _dt
import hashlib
import json

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import R_to_quat_xyzw
from calibgraph.core.version import __version__
from calibgraph.io.files import read_input_bytes
from calibgraph.report.exports import R_to_rpy
from calibgraph.report.markup import badge, esc, matrix, num, vec
from calibgraph.report.tolerances import DEFAULT_TOLERANCES, covariance_problem
from calibgraph.report.workspace import coverage_plot
from calibgraph.solver.result import FRAME_CONVENTION, RESULT_FORMAT, sigmas_from_cov
from calibgraph.solver.uncertainty import weakest_directions


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
            f"<li>{esc(n)}: {esc('; '.join(verdicts[n]['reasons']))}</li>" for n in failed) + "</ul>")
    return "\n".join(h)


def summary_html(result, verdicts: dict) -> str:
    """The summary table: one row per camera (pose, 1σ, reprojection, views, verdict)."""
    ref = result.ref_frame
    h = ["<h2>Summary</h2>",
         f'<table id="summary"><tr><th class="l">camera</th><th>position in {ref} (m)</th><th>roll, pitch, yaw (deg)</th>'
         "<th>1σ translation x, y, z (mm)</th><th>1σ rotation x, y, z (deg)</th><th>reproj. RMS (px)</th>"
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
                 f"<td>{vec(c.sigma_translation_mm, '.3f')}</td><td>{vec(c.sigma_rotation_deg, '.4f')}</td>"
                 f"<td>{num(c.reprojection_rms_px, '.3f')}</td><td>{num(c.reprojection_max_px, '.3f')}</td>"
                 f"<td>{num(c.views_used, '.0f')}</td><td>{num(len(c.views_rejected), '.0f')}</td>"
                 f"<td>{badge(verdicts[n]['pass'])}</td></tr>")
    h.append("</table>")
    h.append(f'<p class="note">1σ are along the {ref} frame axes (rotation: components of the rotation vector '
             f"perturbation in {ref} axes). Roll, pitch, yaw: URDF fixed-axis convention R = Rz(yaw) Ry(pitch) Rx(roll).</p>")
    return "\n".join(h)


def camera_html(result, n: str, intr, verdict: dict, residuals: dict, ws: dict) -> str:
    """One camera: pose, 1σ and weakest directions, checks, rejected views, coverage and workspace maps."""
    c = result.cameras[n]
    if not c.calibrated:
        return "\n".join([f'<div class="cam" id="cam-{esc(n)}"><h3>{esc(n)} {badge(False)}</h3>',
                          f"<p><b>Not calibrated</b>: {esc(c.why)}</p>", _rejected_views_html(c), "</div>"])
    ref, T = result.ref_frame, c.T_ref_cam
    h = [f'<div class="cam" id="cam-{esc(n)}"><h3>{esc(n)} {badge(verdict["pass"])}</h3>', '<div class="plots"><div>',
         f"<b>T_{ref}_cam</b> (maps camera optical-frame points to the {ref} frame, metres){matrix(T)}",
         f"<p>quaternion (x, y, z, w): {vec(R_to_quat_xyzw(T[:3, :3]), '.6f')}<br>roll, pitch, yaw: "
         f"{vec(np.degrees(R_to_rpy(T[:3, :3])), '.3f', 'deg')}</p>",
         f"<p>1σ translation ({ref} x, y, z): {vec(c.sigma_translation_mm, '.3f', 'mm')}<br>"
         f"1σ rotation ({ref} x, y, z): {vec(c.sigma_rotation_deg, '.4f', 'deg')}</p>"]
    if covariance_problem(c.covariance) is None:  # a covariance to draw directions from
        w = weakest_directions(T, c.covariance, ref)
        h.append(f'<p class="weakest"><b>{esc(w["summary"])}</b><br><span class="note">{esc(w["translation"]["text"])}.<br>'
                 f'{esc(w["rotation"]["text"])}.</span></p>')
    h.append("</div><div>")
    h.append('<table class="checks"><tr><th class="l">check</th><th>value</th><th>limit</th><th>result</th></tr>')
    for label, v, op, lim, ok in verdict["rows"]:
        lim_html = esc(lim) if isinstance(lim, str) else num(lim, "g")
        h.append(f'<tr><td class="l">{esc(label)}</td><td>{num(v, ".4g")}</td><td>{esc(op)} {lim_html}</td>'
                 f"<td>{badge(ok)}</td></tr>")
    h.append("</table>")
    sigma = "" if c.pixel_sigma_px is None else f" (its corners' σ {num(c.pixel_sigma_px, '.3f', ' px')} per axis)"
    h.append(f"<p>reprojection RMS {num(c.reprojection_rms_px, '.3f', ' px')}{sigma}, max "
             f"{num(c.reprojection_max_px, '.3f', ' px')}; corners used {num(c.corners_used, '.0f')}, "
             f"rejected {num(c.corners_rejected, '.0f')}<br>views used {num(c.views_used, '.0f')}, "
             f"rejected {num(len(c.views_rejected), '.0f')}</p>")
    h.append(_rejected_views_html(c))
    if intr is not None:
        h.append(f'<p class="note">intrinsics: {intr.width_px}×{intr.height_px} px, fx {intr.K[0, 0]:.1f}, fy {intr.K[1, 1]:.1f}, '
                 f"cx {intr.K[0, 2]:.1f}, cy {intr.K[1, 2]:.1f}, dist {np.round(intr.dist, 4).tolist()}</p>")
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
    """Where the numbers come from: result file and hash, versions, dataset, solver outcome and settings, tolerances."""
    rows = [
        ("result file", f"{result_path} (sha256 {_sha256(result_path)[:16]}…)" if result_path else "(given in memory)"),
        ("result format", RESULT_FORMAT),
        ("calibgraph version that solved", result.calibgraph_version),
        ("calibgraph version of this report", __version__),
        ("dataset", result.dataset or (str(ds.root) if ds is not None else "n/a")),
        ("mode / method", f"{result.mode} / {result.method}"),
        ("converged", result.converged),
        ("iterations", result.iterations),
        ("final cost", result.final_cost),
        ("pixel sigma used (px)", result.pixel_sigma_px),
        ("solve time (s)", result.solve_time_s),
        ("tolerances", f"{config}" if config is not None and not isinstance(config, dict) else
         ("given as a dict" if isinstance(config, dict) else f"defaults ({DEFAULT_TOLERANCES.name})")),
    ]
    if ds is not None:
        t = ds.target
        rows += [("dataset folder", str(ds.root)), ("captures in dataset", len(ds.captures)),
                 ("target", f"{t.kind} {t.rows}×{t.cols} points, pitch {t.pitch_m * 1e3:.1f} mm"),
                 ("dataset problems", "; ".join(f"{f}: {m}" for f, m in ds.problems) or "none")]
    if result.T_mount_board is not None:
        key = "T_flange_board" if result.mode == "eye_to_hand" else "T_base_board"
        st, sr = (sigmas_from_cov(result.mount_covariance) if result.mount_covariance is not None
                  else ([np.nan] * 3, [np.nan] * 3))
        rows.append((f"{key} (m)", f"t = {np.round(result.T_mount_board[:3, 3], 5).tolist()}; 1σ "
                     f"{np.round(st, 3).tolist()} mm, {np.round(sr, 4).tolist()} deg"))
    h = ['<table id="provenance">'] + [f'<tr><th class="l">{esc(k)}</th><td class="l">{esc(v)}</td></tr>' for k, v in rows]
    h.append("</table>")
    h.append(f"<p><b>Solver settings</b></p><pre>{esc(json.dumps(result.settings, indent=2))}</pre>")
    h.append(f"<p><b>Tolerances applied</b></p><pre>{esc(json.dumps(tol, indent=2))}</pre>")
    return "\n".join(h)


def _sha256(path) -> str:
    try:
        return hashlib.sha256(read_input_bytes(path, "result")).hexdigest()
    except InputError:
        return "unreadable"
