"""A result against a known truth (a simulated dataset's ``ground_truth.json``): is each camera's
error inside what its 1-sigma says?

Per calibrated camera, with the error in the result's own convention (rotation vector of
``R_est R_true^T`` and position offset, reference-frame axes, rotation first: the order and axes of
its 6x6 ``covariance``):

- the true error: translation (mm, the norm of the offset) and rotation (deg);
- the 1-sigma norm: sqrt of the trace of the translation covariance (the norm of the per-axis 1-sigma);
- error / 1-sigma: the two norms' ratio (around 1 when the 1-sigma is honest; a ratio, not a test);
- Mahalanobis^2 = d^T C^-1 d over all six components, chi-square with 6 dof when the covariance is
  right, and its p = P(chi2_6 > m2): a camera is **outside** when p < alpha (default 0.001, the
  false-alarm rate of a camera whose 1-sigma is honest, as ``verify``'s).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import log_so3
from calibgraph.solver.changes.verify import chi2_isf_6, chi2_sf_6

__all__ = ["TruthRow", "check_against_truth", "format_truth_table", "ALPHA"]

ALPHA = 0.001


@dataclass(frozen=True)
class TruthRow:
    """One camera against the truth (``status``: 'inside', 'outside', 'not calibrated', 'no truth')."""

    name: str
    status: str
    error_mm: float = float("nan")
    error_deg: float = float("nan")
    sigma_norm_mm: float = float("nan")
    sigma_rot_norm_deg: float = float("nan")
    error_over_sigma: float = float("nan")
    mahalanobis2: float = float("nan")
    p_value: float = float("nan")
    fx_given_pct: float | None = None  # the fx the camera was given, against the true fx (%)
    fx_solved_pct: float | None = None  # the fx it was solved with, against the true fx (%)
    fx_sigma_pct: float | None = None  # the solved fx's 1-sigma, % of the true fx
    why: str = ""

    def to_dict(self) -> dict:
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in self.__dict__.items()}


def pose_delta(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """[rotation vector of R_est R_true^T, t_est - t_true]: the covariance's order and axes."""
    return np.concatenate([log_so3(T_est[:3, :3] @ T_true[:3, :3].T), T_est[:3, 3] - T_true[:3, 3]])


def _fx(c, intr_true):
    rec = c.intrinsics or {}
    if intr_true is None or "K" not in rec:
        return None, None, None
    fx_true = float(intr_true.K[0, 0])
    fx_solved = float(np.asarray(rec["K"], float)[0][0])
    fx_given = (rec.get("given") or {}).get("fx", fx_solved)
    s = (rec.get("sigma") or {}).get("fx")
    return (100 * (float(fx_given) / fx_true - 1), 100 * (fx_solved / fx_true - 1),
            None if s is None else 100 * float(s) / fx_true)


def check_against_truth(result, truth: dict, alpha: float = ALPHA) -> list:
    """Each camera of ``result`` (a Result) against ``truth`` (:func:`calibgraph.io.ground_truth.load_ground_truth`):
    a list of :class:`TruthRow`, in the result's camera order."""
    if not (0.0 < alpha < 1.0):
        raise InputError(f"--alpha {alpha}: a probability between 0 and 1 (e.g. 0.001).")
    raw = truth.get("raw") or {}
    gt_mode = raw.get("mode", "eye_to_hand")
    if result.mode != gt_mode:
        raise InputError(f"the result is {result.mode} and the ground truth {gt_mode}: not the same cell.")
    if result.mode != "eye_to_hand":
        raise InputError("calibgraph check compares eye-to-hand results (T_base_cam) with a ground truth; "
                         f"this result is {result.mode}.")
    known = truth["T_base_cam"]
    if not set(result.cameras) & set(known):
        raise InputError(f"no camera of the result ({', '.join(result.cameras)}) is in the ground truth "
                         f"({', '.join(known)}): not the same cell.")
    rows = []
    for n, c in result.cameras.items():
        if not c.calibrated:
            rows.append(TruthRow(n, "not calibrated", why=c.why))
            continue
        if n not in known:
            rows.append(TruthRow(n, "no truth", why="the ground truth has no such camera"))
            continue
        d = pose_delta(c.T_ref_cam, known[n])
        C = np.asarray(c.covariance, float)
        try:
            m2 = float(d @ np.linalg.solve(C, d))
        except np.linalg.LinAlgError:
            m2 = float("inf")
        if not np.isfinite(m2) or m2 < 0:
            m2 = float("inf")
        p = chi2_sf_6(m2) if np.isfinite(m2) else 0.0
        s_mm = float(np.linalg.norm(c.sigma_translation_mm))
        e_mm = float(np.linalg.norm(d[3:]) * 1e3)
        fg, fs, fsig = _fx(c, truth.get("intrinsics_true", {}).get(n))
        rows.append(TruthRow(n, "outside" if p < alpha else "inside", error_mm=e_mm,
                             error_deg=float(np.degrees(np.linalg.norm(d[:3]))), sigma_norm_mm=s_mm,
                             sigma_rot_norm_deg=float(np.linalg.norm(c.sigma_rotation_deg)),
                             error_over_sigma=e_mm / s_mm if s_mm > 0 else float("inf"), mahalanobis2=m2, p_value=p,
                             fx_given_pct=fg, fx_solved_pct=fs, fx_sigma_pct=fsig))
    return rows


def _pct(x, digits=2) -> str:
    return "—" if x is None else f"{x:+.{digits}f} %"


def format_truth_table(rows: list, alpha: float = ALPHA) -> str:
    """The table ``calibgraph check`` prints, with its column key and the verdict line."""
    w = max([6] + [len(r.name) for r in rows])
    lines = [f"{'camera':{w}s} {'err mm':>7s} {'err deg':>8s} {'1σ mm':>7s} {'err/1σ':>7s} {'M²(6)':>7s} {'p':>8s}  "
             f"{'fx given → solved, vs truth':>30s}  verdict"]
    for r in rows:
        if r.status in ("not calibrated", "no truth"):
            lines.append(f"{r.name:{w}s} {r.status.upper()}: {r.why}")
            continue
        fx = "" if r.fx_solved_pct is None else (
            f"{_pct(r.fx_given_pct)} → {_pct(r.fx_solved_pct, 3)}" + ("" if r.fx_sigma_pct is None else f" ± {r.fx_sigma_pct:.3f} %"))
        lines.append(f"{r.name:{w}s} {r.error_mm:7.3f} {r.error_deg:8.4f} {r.sigma_norm_mm:7.3f} {r.error_over_sigma:7.2f} "
                     f"{r.mahalanobis2:7.2f} {r.p_value:8.3g}  {fx:>30s}  {r.status}")
    lines += [
        "err mm, err deg: the true translation and rotation error; 1σ mm: the norm of the per-axis translation 1σ "
        "(sqrt of the covariance's trace);",
        "err/1σ: the error's norm over the 1σ norm (around 1 when the 1σ is honest); M²(6): the squared Mahalanobis "
        "distance of the 6-dof error under the result's covariance, chi-square with 6 dof (mean 6) when it is right;",
        f"p: P(chi2_6 > M²); a camera is outside when p < {alpha:g} (M² > {chi2_isf_6(alpha):.1f}).",
    ]
    lines.append(verdict_line(rows, alpha))
    return "\n".join(lines)


def verdict_line(rows: list, alpha: float = ALPHA) -> str:
    """'verdict: PASS ...' or 'verdict: FAIL ...' with the worst error / 1σ."""
    solved = [r for r in rows if r.status in ("inside", "outside")]
    bad = [r for r in rows if r.status != "inside"]
    worst = max(solved, key=lambda r: r.error_over_sigma, default=None)
    w = "" if worst is None else (f"worst error/1σ {worst.error_over_sigma:.2f} ({worst.name}: {worst.error_mm:.3f} mm "
                                  f"against a 1σ norm of {worst.sigma_norm_mm:.3f} mm)")
    if not bad:
        return f"verdict: PASS: every camera's true error is within its covariance (chi-square p >= {alpha:g}); {w}"
    why = ", ".join(f"{r.name} {r.status}" + (f" (M² {r.mahalanobis2:.1f}, p {r.p_value:.2g})" if r.status == "outside" else "")
                    for r in bad)
    return f"verdict: FAIL: {why}" + (f"; {w}" if w else "")
