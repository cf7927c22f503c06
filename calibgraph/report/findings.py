"""What the solver knows about each camera, as the report and the rerun summary say it.

Per camera: the error budget's share sets (every labelled set the budget carries, read generically
so a budget with more sets shows them all), its advice, the notes that concern it, the intrinsics'
provenance (the source they came with, how the solver used them) with the given -> estimated values,
their 1-sigma and the prior's width, and a move during capture. Besides: the notes on the whole
cell (board, robot). Plain data and text here; :mod:`calibgraph.report.sections` renders it as HTML,
:mod:`calibgraph.report.rerun_view` as Markdown.
"""

from __future__ import annotations

from numbers import Real

import numpy as np

from calibgraph.core.camera import INTRINSICS_FULL, Intrinsics
from calibgraph.solver.solve.camera_model import INTRINSICS_USES
from calibgraph.solver.terms.factors import intrinsics_vector
from calibgraph.solver.output.result import intrinsics_provenance, sigmas_from_cov

# the budget's sources, in words
SOURCE_LABELS = {"corners": "corner noise", "intrinsics": "intrinsics", "robot_fk": "robot forward kinematics",
                 "board": "board scale"}
# the budget's single numbers, in words (others show their key)
SCALAR_LABELS = {"sigma_translation_norm_mm": ("1σ translation, norm of x, y, z", "mm"),
                 "own_intrinsics_share": ("of it from this camera's own intrinsics prior", "share")}
# a share set's label when the budget gives none ("shares": the sources of noise of solver.uncertainty.budget)
SET_LABELS = {"shares": "by noise source"}
SOURCE_GIVEN = {"factory": "factory values (device or datasheet)", "calibration": "a calibration file",
                "exact": "values declared exact", "unknown": "none (only the image size)"}

# what a camera file named in the result holds, by its source
FILE_KINDS = {"factory": "factory values", "calibration": "calibrated values",
              "exact": "values declared exact"}


def _is_shares(v) -> bool:
    return isinstance(v, dict) and bool(v) and all(isinstance(x, Real) and not isinstance(x, bool) for x in v.values())


def humanise(key: str) -> str:
    return str(key).replace("_", " ")


def share_sets(budget: dict | None) -> list:
    """[(label, {source: share})] of every share set in an ``error_budget`` entry: each entry that
    maps names to numbers (``shares``, ``shares_by_parameter``, ...), and each set of an entry that
    maps labels to such maps; labelled from the budget's ``share_labels`` when it has them."""
    budget = budget or {}
    given = budget.get("share_labels") if isinstance(budget.get("share_labels"), dict) else {}
    out = []
    for key, v in budget.items():
        if key == "share_labels":
            continue
        if _is_shares(v):
            label = str(given.get(key) or SET_LABELS.get(key) or humanise(key).replace("shares ", "")).strip()
            # one wording for shares that add up: the console's (results before it said "sums to 1")
            out.append((label.replace("(sums to 1)", "(sums to 100 %)"), {str(k): float(x) for k, x in v.items()}))
        elif isinstance(v, dict) and v and all(_is_shares(x) for x in v.values()):
            out += [(str(lab), {str(k): float(x) for k, x in x_.items()}) for lab, x_ in v.items()]
    return out


def budget_scalars(budget: dict | None) -> list:
    """[(label, value, unit)] of the budget's single numbers (its 1σ norm and the like)."""
    out = []
    for key, v in (budget or {}).items():
        if isinstance(v, Real) and not isinstance(v, bool):
            label, unit = SCALAR_LABELS.get(key, (humanise(key), ""))
            out.append((label, float(v), unit))
    return out


def budget_texts(budget: dict | None) -> list:
    """[(key, text)] of the budget's text entries (the advice, and any other)."""
    return [(k, v) for k, v in (budget or {}).items() if isinstance(v, str) and v]


def source_label(key: str) -> str:
    return SOURCE_LABELS.get(key, humanise(key))


def shares_text(shares: dict) -> str:
    """'corner noise 54 %, robot forward kinematics 45 %, ...', largest first."""
    return ", ".join(f"{source_label(k)} {percent(v)}" for k, v in sorted(shares.items(), key=lambda kv: -kv[1]))


def percent(v: float) -> str:
    v = 100.0 * float(v)
    return f"{v:.0f} %" if abs(v) >= 10 else f"{v:.1f} %" if abs(v) >= 0.1 else "< 0.1 %" if v > 0 else "0 %"


def advice(c) -> str:
    """The camera's advice line ('' when its result has none)."""
    return str((c.error_budget or {}).get("advice") or "")


def sigma_norm_mm(c) -> float | None:
    v = (c.error_budget or {}).get("sigma_translation_norm_mm")
    return float(v) if isinstance(v, Real) else None


def provenance_text(c, settings: dict | None) -> str:
    """One line: where the camera's intrinsics came from and how the solver used them."""
    p = intrinsics_provenance(c, settings)
    if not p["given"] and not p["used"]:
        return "source not recorded in this result"
    f = (c.intrinsics or {}).get("file")
    given = ("source: " + (f"the camera file {f} (given with --intrinsics)" if f else
                           SOURCE_GIVEN.get(p["given"], p["given"] or "not recorded")))
    if f:
        kind = FILE_KINDS.get(p["given"], "")
        given += f": {kind}" if kind else ""
    elif p["given"] and p["given"] != "unknown":
        given += (", as stated with the camera" if p["stated"] else
                  ", the solver's default (--intrinsics-source): the camera's intrinsics did not say")
    if p["used"] == "own-views":
        return f"{given}; found from its own views"
    return f"{given}; used: {INTRINSICS_USES.get(p['used'], p['used'] or 'not recorded')}"


def advice_for(n: str, c) -> str:
    """The camera's advice without its leading 'NAME: ' (for a list that names the camera)."""
    a = advice(c)
    return a[len(n) + 2:] if a.startswith(f"{n}: ") else a


def intrinsics_rows(c) -> list:
    """[(name, given, estimated, 1σ, prior 1σ)] of the camera's intrinsics: every estimated
    parameter (None where the result does not say: given of a camera of unknown intrinsics, the
    prior's width in a result written before it was recorded); for intrinsics held as given, fx fy
    cx cy and the distortion terms that are not zero (estimated = given, no 1σ)."""
    d = c.intrinsics or {}
    if not d.get("K"):
        return []
    values = dict(zip(INTRINSICS_FULL, intrinsics_vector(Intrinsics.from_dict(d), len(INTRINSICS_FULL)).tolist()))
    sigma, given, prior = d.get("sigma") or {}, d.get("given") or {}, d.get("prior_sigma") or {}
    if sigma:
        names = [n for n in INTRINSICS_FULL if n in sigma]
        unknown = d.get("prior") == "unknown" or intrinsics_provenance(c).get("used") == "own-views"
        return [(n, None if unknown else given.get(n), values[n], sigma[n], prior.get(n)) for n in names]
    names = [n for n in INTRINSICS_FULL if n in ("fx", "fy", "cx", "cy") or abs(values[n]) > 0]
    return [(n, values[n], values[n], None, None) for n in names]


def fmt(name: str) -> str:
    """The format of an intrinsics parameter's value: px to 0.01, distortion to 1e-5."""
    return ".2f" if name in ("fx", "fy", "cx", "cy") else ".5f"


def moved_summary(c) -> dict | None:
    """A camera that moved during capture: {'where', 'displacement_mm', 'sigma_mm', 'rotation_deg',
    'views_before', 'views_after', 't_before_m', 't_after_m', 'sigma_before_mm', 'sigma_after_mm' (per
    axis; None: not solved), 'text'} (None when it did not move)."""
    m = c.moved
    if not m:
        return None
    before = m.get("T_before")
    out = {"where": f"between captures {m.get('last_capture_before')} and {m.get('capture')}",
           "displacement_mm": float(m.get("displacement_mm", np.nan)),
           "sigma_mm": float(m.get("sigma_displacement_mm", np.nan)),
           "rotation_deg": float(m.get("rotation_deg", np.nan)),
           "views_before": m.get("views_before"), "views_after": m.get("views_after"),
           "t_before_m": None if before is None else np.asarray(before, float)[:3, 3],
           "t_after_m": None if c.T_ref_cam is None else np.asarray(c.T_ref_cam, float)[:3, 3],
           "sigma_before_mm": None if m.get("covariance_before") is None else
           sigmas_from_cov(np.asarray(m["covariance_before"], float))[0],
           "sigma_after_mm": None if c.covariance is None else c.sigma_translation_mm}
    out["text"] = (f"moved {out['where']}: {out['displacement_mm']:.1f} ± {out['sigma_mm']:.1f} mm (1σ), "
                   f"{out['rotation_deg']:.2f} deg; {out['views_before']} views before, {out['views_after']} after; "
                   + ("the pose reported is the one after the move" if c.calibrated else "not calibrated after it"))
    return out


def camera_markdown(result, n: str) -> list:
    """Markdown lines on one camera: budget, advice, intrinsics provenance, move, notes (the rerun
    summary's)."""
    c = result.cameras[n]
    lines = [f"### {n}" + ("" if c.calibrated else " — NOT calibrated"), ""]
    if not c.calibrated:
        lines.append(f"- why: {c.why}")
    s = sigma_norm_mm(c)
    for label, shares in share_sets(c.error_budget):
        lines.append(f"- error budget ({label})" + (f" of its {s:.2f} mm 1σ" if s is not None else "")
                     + f": {shares_text(shares)}")
    if advice(c):
        lines.append(f"- **advice**: {advice(c)}")
    if c.intrinsics:
        lines.append(f"- intrinsics: {provenance_text(c, result.settings)}")
        rows = intrinsics_rows(c)
        est = [f"{k} {v:{fmt(k)}} ± {sg:{fmt(k)}}" for k, _g, v, sg, _p in rows if sg is not None]
        if est:
            lines.append("  - estimated: " + ", ".join(est))
    mv = moved_summary(c)
    if mv:
        lines.append(f"- {mv['text']}")
    lines += [f"- note: {t}" for t in result.camera_notes(n)]
    return lines + [""]


def summary_markdown(result) -> list:
    """The findings part of the rerun summary: what would improve the calibration, each camera's
    findings, the notes on the whole cell."""
    lines = ["## What would improve this calibration", ""]
    for n, c in result.cameras.items():
        if not c.calibrated:
            lines.append(f"- {n}: not calibrated — {c.why}")
        elif advice(c):
            lines.append(f"- {advice(c)}")
    lines += ["", "## Cameras", ""]
    for n in result.cameras:
        lines += camera_markdown(result, n)
    cell = result.cell_notes
    lines += ["## Notes on the whole cell", ""] + ([f"- {t}" for t in cell] if cell else ["- none"])
    return lines
