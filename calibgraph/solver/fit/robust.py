"""Robustness at corner level: iteratively re-weighted least squares and view rejection.

Each LM run holds the corners' weights fixed (so the cost LM sees is consistent); in between, the
weights follow a Huber (or Cauchy) loss on each corner's residual norm in pixel sigmas, corners
beyond ``outlier_sigmas`` get weight 0 and are listed, and views that lose most of their corners
leave the graph with a reason (and come back when they fit again). Every function here returns new
views; none edits the ones it is given.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.solver.fit.graph import Estimate, build_graph, extract, levenberg_marquardt
from calibgraph.solver.terms.noise_model import camera_noise_scales, robust_pixel_sigma
from calibgraph.solver.fit.timing import timed
from calibgraph.solver.terms.views import MIN_CORNERS_PER_VIEW, norms_of

MAX_WEIGHT_ROUNDS = 6  # LM runs with re-weighting in between, per view-level round
SETTLED_RMS_WEIGHT_CHANGE = 0.01  # corner weights whose RMS change is below this have settled
SETTLED_FLIPPING = (2, 0.005)  # or: at most this many corners (count, fraction of all) still change by over 0.05
MAX_VIEW_ROUNDS = 4  # rounds of view rejection / re-admission


@dataclass(frozen=True)
class Rounds:
    """What the robust rounds leave: the estimate, the views with their weights, the pixel sigma."""

    est: Estimate
    views: list
    sigma_px: float
    iterations: int
    settled: bool  # the weights, the pixel sigma and the set of views stopped changing, and the last LM run converged
    norms: list = None  # residual norms (px) of ``views`` at ``est``


def loss_weights(r_sigma: np.ndarray, loss: str, scale: float) -> np.ndarray:
    """IRLS weights for residual norms expressed in sigmas."""
    if loss == "none":
        return np.ones_like(r_sigma)
    if loss == "huber":
        return np.where(r_sigma <= scale, 1.0, scale / np.maximum(r_sigma, 1e-12))
    return 1.0 / (1.0 + (r_sigma / scale) ** 2)


def screen_at_start(problem: Problem, views: list, est: Estimate) -> tuple[list, float]:
    """(views, starting pixel sigma): every view at full weight, the views grossly off at the start
    set aside (so that a few corrupted views cannot drag the first solve)."""
    fresh = [replace(v, w=np.ones(len(v.ids)), active=True, reason="") for v in views]
    init_rms = np.array([np.sqrt(np.mean(r ** 2)) for r in est.residual_norms(fresh, problem.cameras)])
    thr0 = max(10.0 * np.median(init_rms), 15.0)
    out = [v if r <= thr0 else replace(v, active=False,
                                       reason=f"inconsistent with the other views at initialisation (rms {r:.1f} px)")
           for v, r in zip(fresh, init_rms)]
    sigma = problem.options.pixel_sigma_px or max(float(np.median(init_rms[init_rms <= thr0])), 0.5)
    return out, sigma


def reweight(views: list, norms: list, sigma_px: float, opts) -> tuple[list, float]:
    """(views with new robust weights for the active ones (0 beyond outlier_sigmas), the largest change)."""
    act = [i for i, v in enumerate(views) if v.active]
    if not act:
        return list(views), 0.0
    # every active view's corners at once, each in its own view's sigmas
    r = np.concatenate([norms[i] / (sigma_px * views[i].sigma_scale) for i in act])
    w = loss_weights(r, opts.loss, opts.loss_scale)
    w[r > opts.outlier_sigmas] = 0.0
    old = np.concatenate([views[i].w for i in act])
    change = float(np.abs(w - old).max()) if len(w) else 0.0
    out = list(views)
    ends = np.cumsum([len(views[i].w) for i in act])
    for i, part in zip(act, np.split(w, ends[:-1])):
        out[i] = views[i].evolve(w=part)
    return out, change


def _weights_settled(before: list, after: list) -> bool:
    """The active views' corner weights changed little: their RMS change is below
    ``SETTLED_RMS_WEIGHT_CHANGE``, or only a few corners (``SETTLED_FLIPPING``) still change by over
    0.05 - on a small dataset one corner flipping across the outlier cut moves the RMS over the limit
    while the estimate no longer moves."""
    d = [a.w - b.w for b, a in zip(before, after) if b.active]
    if not d:
        return True
    d = np.concatenate(d)
    count, fraction = SETTLED_FLIPPING
    return bool(np.sqrt(np.mean(d ** 2)) < SETTLED_RMS_WEIGHT_CHANGE
                or np.count_nonzero(np.abs(d) > 0.05) <= max(count, fraction * d.size))


def weighted_solves(problem: Problem, views: list, slots: dict, est: Estimate, sigma: float, form: str,
                    timings: dict | None) -> Rounds:
    """LM runs with fixed corner weights, re-weighted in between, until the weights and the pixel
    sigma settle (at most MAX_WEIGHT_ROUNDS runs)."""
    opts = problem.options
    iterations, settled, norms = 0, False, None
    for _ in range(MAX_WEIGHT_ROUNDS):
        with timed(timings, "build_graph"):
            graph, values = build_graph(views, slots, problem, est, sigma, form)
        with timed(timings, "lm"):
            run = levenberg_marquardt(graph, values, opts.max_iterations, form)
        iterations += run.iterations
        est = extract(run.values, slots, views, est, problem.cameras, form, problem)
        residuals = est.residuals(views, problem.cameras)
        norms = norms_of(residuals)
        scale_change = 0.0
        if not opts.pixel_sigma_px and opts.corner_noise != "one":
            # per camera only here: a view's own level is set in the final graph (solver.solve.optimise), after
            # the rounds have cut outliers and the move test has run at its camera's level, since a
            # view that misfits (a knocked camera's) would otherwise look merely noisy and stay in
            views, scale_change, _ = camera_noise_scales(views, residuals, per_view=False)
        active = [(v, r) for v, r in zip(views, norms) if v.active]
        sigma_new = opts.pixel_sigma_px or robust_pixel_sigma(*zip(*active))
        old = views
        views, change = reweight(views, norms, sigma_new, opts)
        level_settled = abs(sigma_new - sigma) < 0.02 * sigma and scale_change < 0.02
        weights_settled = level_settled and change < 0.05
        # settled also when only a few corners straddling the loss's knee still flip their weight
        # (the largest change stays above 0.05 round after round while the estimate no longer moves)
        settled = (weights_settled or (level_settled and _weights_settled(old, views))) \
            and run.converged
        sigma = sigma_new
        if weights_settled:
            break
    return Rounds(est, views, sigma, iterations, settled, norms)


def readmit_or_reject(views: list, norms: list, sigma_px: float, opts) -> tuple[list, bool]:
    """View level: (views with those that lost most of their corners set aside and the set-aside ones
    that fit now re-admitted, True when any view changed)."""
    out, changed = [], False
    for v, res in zip(views, norms):
        # judged at its camera's level: a view whose corners mostly miss by 5 of its camera's sigmas
        # is off, however noisy it looks on its own
        r = res / (sigma_px * v.noise_scale)
        kept = r <= opts.outlier_sigmas
        ok = kept.mean() >= 0.5 and kept.sum() >= MIN_CORNERS_PER_VIEW
        if v.active and not ok:
            v = replace(v, active=False, reason=f"{(~kept).sum()} of {len(kept)} corners beyond {opts.outlier_sigmas:g} "
                                                f"sigma (median residual {np.median(res):.2f} px)")
            changed = True
        elif not v.active and ok:
            v = replace(v, active=True, reason="", w=np.where(kept, loss_weights(r, opts.loss, opts.loss_scale), 0.0))
            changed = True
        out.append(v)
    return out, changed


def robust_rounds(problem: Problem, views: list, slots: dict, est: Estimate, form: str,
                  timings: dict | None, warm_sigma_px: float | None = None) -> Rounds:
    """Screening, then weighted solves and view-level rejection until the set of views settles.

    ``warm_sigma_px``: the views come from rounds that settled on a nearby problem (their weights,
    noise scales and set-aside views kept, re-admitted when they fit) and this was their pixel sigma:
    no screening, the weighted solves start from there (the same fixed point, fewer LM runs)."""
    if warm_sigma_px is None:
        views, sigma = screen_at_start(problem, views, est)
    else:
        sigma = problem.options.pixel_sigma_px or warm_sigma_px
    iterations = 0
    seen = [_active_set(views)]
    for _ in range(MAX_VIEW_ROUNDS):
        rounds = weighted_solves(problem, views, slots, est, sigma, form, timings)
        iterations += rounds.iterations
        est, sigma = rounds.est, rounds.sigma_px
        views, changed = readmit_or_reject(rounds.views, rounds.norms, sigma, problem.options)
        if not changed:
            return Rounds(est, views, sigma, iterations, rounds.settled, rounds.norms)
        now = _active_set(views)
        if now in seen:
            # the set of views came back to one it had: a view on the 50 % cut is set aside with the
            # estimate that fits it worse and re-admitted with the other, round after round. Such a
            # view is left out (its fit is borderline either way) and the rest solved once more.
            cycle = seen[seen.index(now):]
            flippers = set().union(*cycle) - set.intersection(*map(set, cycle))
            views = [replace(v, active=False, reason="on the cut: set aside and re-admitted in turn from round to "
                                                     "round (more than half its corners beyond "
                                                     f"{problem.options.outlier_sigmas:g} sigma with it in)")
                     if (v.camera, v.capture) in flippers else v for v in views]
            rounds = weighted_solves(problem, views, slots, est, sigma, form, timings)
            return Rounds(rounds.est, rounds.views, rounds.sigma_px, iterations + rounds.iterations, rounds.settled,
                          rounds.norms)
        seen.append(now)
    return Rounds(est, views, sigma, iterations, False, est.residual_norms(views, problem.cameras))


def _active_set(views: list) -> frozenset:
    return frozenset((v.camera, v.capture) for v in views if v.active)
