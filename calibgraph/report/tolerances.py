"""The commissioning checks: each camera of a :class:`~calibgraph.solver.output.result.Result` against the
tolerances of a YAML file (``datasets/tolerances/default.yaml`` by default), and the checks that do
not depend on a tolerance: a camera whose covariance is not a covariance (zero, not finite, not
positive definite) cannot pass, whatever its 1σ says.

A camera's 1σ is one figure per camera, everywhere calibgraph states one: the norm of its per-axis
1σ, ``sqrt(sx² + sy² + sz²)`` (the square root of the trace of its translation covariance; likewise
for the rotation). ``max_sigma_translation_mm`` and ``max_sigma_rotation_deg`` limit that norm, as
``capture --auto --tolerance-mm/--tolerance-deg`` and the error budget's 1σ do. (Files written
before said "largest axis" in a comment: the keys are read the same way, now against the norm, which
is at least the largest axis and at most sqrt(3) times it.)
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.io.files import read_yaml
from calibgraph.io.shipped import resolve_shipped, shipped_root


def _default_tolerances() -> Path:
    try:
        return shipped_root() / "tolerances" / "default.yaml"
    except InputError:
        return Path("datasets/tolerances/default.yaml")  # an installation without its shipped files: the built-ins


# the shipped file (the clone's datasets/tolerances/default.yaml, or the wheel's copy of it)
DEFAULT_TOLERANCES = _default_tolerances()

# used when the file is missing
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
    # key, label, value of a CameraResult (and the worst workspace 1σ), comparison
    ("max_sigma_translation_mm", "1σ translation (mm)", lambda c, w: sigma_norm(c.sigma_translation_mm), "<="),
    ("max_sigma_rotation_deg", "1σ rotation (deg)", lambda c, w: sigma_norm(c.sigma_rotation_deg), "<="),
    ("max_reprojection_rms_px", "reprojection RMS (px)", lambda c, w: c.reprojection_rms_px, "<="),
    ("max_reprojection_max_px", "reprojection max (px)", lambda c, w: c.reprojection_max_px, "<="),
    ("min_views_used", "views used", lambda c, w: c.views_used, ">="),
    ("max_workspace_sigma_mm", "worst 1σ point error in the workspace (mm)", lambda c, w: w, "<="),
)


def sigma_norm(per_axis) -> float:
    """The one 1σ figure of a camera: the norm of its per-axis 1σ (x, y, z)."""
    return float(np.linalg.norm(np.asarray(per_axis, float)))


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
            src = resolve_shipped(src, "tolerances")  # a shipped name or datasets/tolerances/... from any folder
            d = read_yaml(src, "tolerance config (a mapping with 'defaults', 'cameras', 'workspace')", empty_ok=True)
        unknown = set(d) - {"format", "defaults", "cameras", "workspace", "description"}
        if unknown:
            raise InputError(f"{src}: unknown tolerance section(s) {', '.join(map(str, sorted(unknown)))}; use defaults, "
                             "cameras, workspace.")
        known = {k for k, *_ in CHECKS}
        for k in (d.get("defaults") or {}):
            if k not in known:
                raise InputError(f"{src}: unknown tolerance {k!r}; known: {', '.join(sorted(known))}.")
        tol["defaults"].update(d.get("defaults") or {})
        for cam, lim in (d.get("cameras") or {}).items():
            bad = set(lim or {}) - known
            if bad:
                raise InputError(f"{src}: camera {cam!r}: unknown tolerance(s) {', '.join(map(str, sorted(bad)))}; known: "
                                 f"{', '.join(sorted(known))}.")
            tol["cameras"].setdefault(str(cam), {}).update(lim or {})
        tol["workspace"].update(d.get("workspace") or {})
    return tol


def covariance_problem(cov) -> str | None:
    """Why ``cov`` (6x6) is not a usable covariance — not finite, not symmetric, zero, or not
    positive definite — or None when it is one."""
    C = np.asarray(cov, float)
    if C.shape != (6, 6) or not np.all(np.isfinite(C)):
        return "covariance is not a finite 6x6 matrix"
    scale = float(np.abs(C).max())
    if scale == 0.0:
        return "covariance is zero (no uncertainty stated: not a solver's output)"
    if np.abs(C - C.T).max() > 1e-9 * scale:
        return "covariance is not symmetric"
    eig = np.linalg.eigvalsh(0.5 * (C + C.T))
    if eig.min() <= 1e-12 * eig.max():
        return f"covariance is not positive definite (smallest eigenvalue {eig.min():.3g})"
    return None


def camera_verdict(name: str, cam, tol: dict, worst_ws_mm) -> dict:
    """One :class:`~calibgraph.solver.output.result.CameraResult` against its tolerances:
    ``{'pass', 'rows': [(label, value, op, limit, ok)], 'reasons': [why it fails], 'failed': [(key,
    value, limit)] of the failing checks}`` (key: the tolerance's, 'covariance' or 'calibrated'). A
    row with ``ok`` None could not be evaluated (a value that is not a number)."""
    if not cam.calibrated:
        return {"pass": False, "rows": [], "reasons": [f"not calibrated: {cam.why}"],
                "failed": [("calibrated", False, True)]}
    limits = dict(tol["defaults"])
    limits.update(tol["cameras"].get(name, {}))
    rows, reasons, failed = [], [], []
    bad_cov = covariance_problem(cam.covariance)
    rows.append(("covariance", bad_cov or "positive definite", "is", "positive definite", bad_cov is None))
    if bad_cov:
        reasons.append(bad_cov)
        failed.append(("covariance", bad_cov, "positive definite"))
    for key, label, get, op in CHECKS:
        lim = limits.get(key)
        if lim is None:
            continue
        v = get(cam, worst_ws_mm)
        if v is None or not np.isfinite(float(v)):
            rows.append((label, v, op, lim, None))
            continue
        ok = float(v) <= float(lim) if op == "<=" else float(v) >= float(lim)
        if not ok:
            reasons.append(f"{label} {float(v):.4g} not {op} {lim:g}")
            failed.append((key, float(v), lim))
        rows.append((label, v, op, lim, ok))
    return {"pass": not reasons, "rows": rows, "reasons": reasons, "failed": failed}
