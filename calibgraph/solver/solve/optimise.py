"""One graph optimised from a start: robust rounds, the final weighted graph, its marginals.

:func:`solve_from_start` is the path every solve takes: the robust rounds
(:mod:`calibgraph.solver.fit.robust`), then the final graph, judged on what the fit says about the
forward kinematics (:mod:`calibgraph.solver.robot.fk_check`) and about correlated corner noise
(:mod:`calibgraph.solver.terms.noise_model`), solved at the a posteriori pixel sigma, and its marginals.
:func:`solve_joint` tries every start it is given and keeps the lowest cost.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from calibgraph.core.errors import ObservabilityError
from calibgraph.core.problem import Problem
from calibgraph.solver.terms import factors_ppp
from calibgraph.solver.robot import kinematics as kin
from calibgraph.solver.camera.claims import contradicted, held_by_force
from calibgraph.solver.terms.factors import intrinsics_vector
from calibgraph.solver.robot.fk_check import (FK_COMPONENT_STEPS, RERUN_RATIO, RERUN_SIGMA, FkComponent, FkRatio,
                                              fk_variance_ratio, free_robot_ratio, high_order_level, rescaled, robot_pose_marginals, settled_components, widened)
from calibgraph.solver.robot.fk_select import cross_validated_split, jackknife_applied, jackknife_factor, jackknife_folds
from calibgraph.solver.fit.graph import (
    Estimate,
    build_graph,
    estimates_intrinsics,
    extract,
    formulation,
    intrinsics_size,
    levenberg_marquardt,
    marginals,
    reduced_marginals,
)
from calibgraph.solver.terms.initialise import pnp_candidates
from calibgraph.solver.terms.keys import B, C
from calibgraph.solver.terms.linearise import linearise
from calibgraph.solver.changes.moved import check_after_rounds
from calibgraph.solver.terms.noise_model import a_posteriori_sigma, camera_noise_scales, mode_variance_ratios, separated
from calibgraph.solver.fit.robust import Rounds, reweight, robust_rounds
from calibgraph.solver.fit.timing import timed
from calibgraph.solver.terms.views import norms_of


@dataclass(frozen=True)
class Group:
    """One solved graph: its cameras, its estimate, its views (one group in 'joint', one per
    camera in 'single') and what the solve noticed on the way."""

    names: list
    est: Estimate
    views: list
    notes: tuple = ()
    dropped: dict = field(default_factory=dict)  # camera -> why it is not calibrated (its views left the graph)
    rounds_sigma_px: float | None = None  # the pixel sigma the robust rounds settled at (``views``' weights)


def solve_from_start(problem: Problem, names: list, views: list, est0: Estimate,
                     timings: dict | None = None, warm_sigma_px: float | None = None) -> Group:
    """Robust rounds, final graph and marginals for one graph (all cameras in 'joint', one camera
    in 'single') from the values of ``est0`` (its T_ref_cam, T_mount_board, joint offsets, and which
    cameras' intrinsics get the wide prior). The corner formulation, when it fails numerically,
    falls back to the per-view graph. ``warm_sigma_px``: ``views`` carry the weights of robust rounds
    that settled at this pixel sigma (:func:`~calibgraph.solver.fit.robust.robust_rounds`)."""
    form = formulation(problem, names, len(views), est0)
    try:
        return _solve(problem, names, views, est0, form, timings, warm_sigma_px)
    except ObservabilityError:
        if form != "corner" or problem.options.formulation == "corner":
            raise
        return _solve(problem, names, views, est0, "view", timings, warm_sigma_px)


def _rounds_keeping_enough_views(problem: Problem, names: list, views: list, est: Estimate, form: str,
                                 timings: dict | None, warm_sigma_px: float | None = None):
    """The robust rounds, with every camera left with fewer usable views than it needs (after
    rejection) taken out of the graph and the rest solved again: (names, views, rounds, dropped)
    with ``dropped`` camera -> why. A camera alone in its graph is refused as before."""
    dropped, need = {}, problem.options.min_views_per_camera
    for n in list(names) if len(names) > 1 else []:
        behind = seen_from_behind(problem, [v for v in views if v.camera == n], [v for v in views if v.camera != n])
        if behind:  # no camera model explains a board seen from its back; freeing the intrinsics only hides it
            dropped[n] = (f"the images look mirrored: the board appears from behind in {behind[0]} of its {behind[1]} "
                          "views while the other cameras see its front; check the camera's flip/mirror setting")
            names = [m for m in names if m != n]
            views = [v for v in views if v.camera != n]
    while True:
        slots = {n: i for i, n in enumerate(names)}
        try:
            rounds = robust_rounds(problem, views, slots, est, form, timings, warm_sigma_px)
        except ObservabilityError as e:
            if e.camera not in names or len(names) < 2:
                raise
            dropped[e.camera] = not_calibrated_why(problem, e.camera, [v for v in views if v.camera == e.camera],
                                                   views, need, str(e))
            names = [n for n in names if n != e.camera]
            views = [v for v in views if v.camera != e.camera]
            continue
        short = [n for n in names if sum(v.active for v in rounds.views if v.camera == n) < need]
        if not short or len(short) == len(names):
            return names, views, rounds, dropped
        for n in short:
            dropped[n] = not_calibrated_why(problem, n, [v for v in rounds.views if v.camera == n], views, need)
        names = [n for n in names if n not in short]
        views = [v for v in views if v.camera not in short]
        est = replace(est, T_ref_cam={n: T for n, T in rounds.est.T_ref_cam.items() if n in names})


def not_calibrated_why(problem: Problem, name: str, mine: list, views: list, need: int, error: str = "") -> str:
    """Why camera ``name`` cannot be calibrated from what is left of its views ``mine`` (``error``:
    the solver's refusal when every view was rejected)."""
    if error:
        why = f"all {len(mine)} of its views were rejected as inconsistent with the other cameras'"
    else:
        used = [v for v in mine if v.active]
        reasons = sorted({v.reason for v in mine if not v.active and v.reason})[:2]
        why = (f"{len(mine) - len(used)} of {len(mine)} views rejected" + (f" ({'; '.join(reasons)})" if reasons else "")
               + f": {len(used)} left, at least {need} needed")
    mirrored = seen_from_behind(problem, mine, [v for v in views if v.camera != name])
    if mirrored:
        why += f"; the images look mirrored (the board appears from behind in {mirrored[0]} of {mirrored[1]} views)"
    return why


def seen_from_behind(problem: Problem, mine: list, others: list) -> tuple | None:
    """(views of ``mine`` whose board appears from behind, len(mine)) when most of them do, judged
    against the side the other cameras' views show; None otherwise. A mirrored image shows a planar
    board from its other side."""
    def side(v):
        if v.facing is not None:  # from the PnP candidates the solve started from (views.usable_views)
            return v.facing
        R, _, _ = pnp_candidates(v.p_board_m, v.uv_px, problem.cameras[v.camera])
        return np.sign(R[0][2, 2]) if len(R) else 0.0

    ref = np.sign(sum(side(v) for v in others[:50])) if others else 1.0
    flipped = sum(side(v) == -ref for v in mine)
    return (int(flipped), len(mine)) if mine and ref != 0 and flipped >= max(2, 0.7 * len(mine)) else None


def _solve(problem: Problem, names: list, views: list, est0: Estimate, form: str, timings: dict | None,
           warm_sigma_px: float | None = None) -> Group:
    est = Estimate(T_ref_cam=dict(est0.T_ref_cam), T_mount_board=est0.T_mount_board, T_ref_mount={},
                   intrinsics=dict(est0.intrinsics), wide_intrinsics=est0.wide_intrinsics,
                   free_intrinsics=est0.free_intrinsics, joint_offsets=est0.joint_offsets)
    given = views
    names, views, rounds, dropped = _rounds_keeping_enough_views(problem, names, views, est, form, timings,
                                                                 warm_sigma_px)
    slots = {n: i for i, n in enumerate(names)}
    stated = problem
    check_after_rounds(problem, given, est, rounds)  # a camera that moved during capture is split first (solver.changes.moved)
    problem, rounds = rounds_at_the_arms_accuracy(problem, rounds, slots, form, timings)
    if problem is not stated:  # judged again on the rounds at the arm's accuracy
        check_after_rounds(problem, given, est, rounds)
    notes = []
    # A claim the data contradict is named and dropped before anything shared is judged on the misfit;
    # one camera at a time, the worst first, since one wrong camera drags the others' fit.
    while wrong := contradicted(problem, rounds.views, slots, rounds.est, rounds.sigma_px):
        worst = max(wrong, key=lambda c: c.chi2)
        notes.append(worst.note(intrinsics_vector(problem.cameras[worst.camera])))
        est = replace(est, free_intrinsics=est.free_intrinsics | {worst.camera})
        form = formulation(problem, names, len(views), est)
        rounds = robust_rounds(problem, views, slots, est, form, timings)
    # what a forced option holds is judged as the default judges it, before the misfit is explained elsewhere
    notes += held_by_force(problem, rounds.views, slots, rounds.est, rounds.sigma_px)
    est = final_graph(problem, names, rounds, slots, form, timings)
    if problem is not stated:  # the FK check's figures against the accuracy the user stated
        est = replace(est, fk_ratio=against_stated(est.fk_ratio, stated.options, problem.options))
    return Group(names, est, rounds.views, tuple(notes), dropped, rounds.sigma_px)


def rounds_at_the_arms_accuracy(problem: Problem, rounds: Rounds, slots: dict, form: str, timings: dict | None):
    """(problem, rounds): as given, unless the robot poses, refitted to their views alone, depart from the
    stated FK accuracy by more than :data:`~calibgraph.solver.robot.fk_check.RERUN_RATIO` in variance
    (:func:`~calibgraph.solver.robot.fk_check.free_robot_ratio`) and the rounds' pixel sigma is more than
    :data:`~calibgraph.solver.robot.fk_check.RERUN_SIGMA` times the corners' own scatter outside the views'
    whole-board modes (:func:`~calibgraph.solver.robot.fk_check.high_order_level`; a camera that moved is split
    before this, by the move test on the rounds at the stated accuracy): then an arm millimetres off was
    just treated as
    pixel noise, and every later judgment (the pixel sigma, a moved camera, the FK check, correlated
    corner noise, the board's scale) would be made on it. The rounds are run once at FK sigmas that size
    the arm from above (the free refit's), and once more at those one Helmert step from there implies
    (never below the stated ones); the problem returned carries those sigmas (the final graph's FK check
    refines them, :func:`against_stated` reports them against the user's)."""
    o = problem.options
    if not o.fk_variance or o.kinematics == "joint-offsets" or form != "view":
        return problem, rounds
    active = [v for v in rounds.views if v.camera in rounds.est.T_ref_cam]
    if high_order_level(linearise(problem, active, rounds.est, rounds.sigma_px)) * RERUN_SIGMA ** 2 >= 1.0:
        return problem, rounds  # the pixel sigma is the corners' own: no whole-board misfit was taken for noise
    free = free_robot_ratio(problem, active, rounds.est, rounds.sigma_px)
    if free.max() <= RERUN_RATIO:
        return problem, rounds

    def at(factors):
        return problem.with_(options=replace(o, fk_sigma_rotation_rad=o.fk_sigma_rotation_rad * float(np.sqrt(factors[0])),
                                             fk_sigma_translation_m=o.fk_sigma_translation_m * float(np.sqrt(factors[1]))))

    loose = at(free)
    r1 = robust_rounds(loose, rounds.views, slots, rounds.est, form, timings, warm_sigma_px=rounds.sigma_px)
    step = fk_variance_ratio(loose, [v for v in r1.views if v.camera in r1.est.T_ref_cam], r1.est, r1.sigma_px)
    if step is None:
        return loose, r1
    implied = np.maximum(1.0, free * np.array([step.rotation.ratio, step.translation.ratio]))
    arm = at(implied)
    return arm, robust_rounds(arm, r1.views, slots, r1.est, form, timings, warm_sigma_px=r1.sigma_px)


def against_stated(ratio, stated_opts, used_opts):
    """An FkRatio judged at FK sigmas ``used_opts`` (the arm's accuracy the rounds were run at) as factors on
    ``stated_opts``' sigmas: each component's ratio and applied factor times the variance factor between
    them (a component the FK check kept is applied at the factor the rounds used)."""
    f = np.array([(used_opts.fk_sigma_rotation_rad / stated_opts.fk_sigma_rotation_rad) ** 2,
                  (used_opts.fk_sigma_translation_m / stated_opts.fk_sigma_translation_m) ** 2])

    def scaled(c, k):
        return replace(c, ratio=c.ratio * f[k], applied=c.applied * f[k], significant=True)

    if ratio is None:
        comp = [FkComponent(float(f[k]), float(f[k]), 0.0, True) for k in (0, 1)]
        return FkRatio(float(f.mean()), 0.0, True, comp[0], comp[1])
    return replace(ratio, ratio=ratio.ratio * float(f.mean()), significant=True,
                   rotation=scaled(ratio.rotation, 0), translation=scaled(ratio.translation, 1))


def _n_parameters(problem: Problem, names: list, est: Estimate) -> int:
    n_intr = sum(intrinsics_size(problem, n, est) for n in names if estimates_intrinsics(problem, n, est))
    n = 6 * (len(names) + 1) + n_intr + int(problem.options.board_scale)
    return n + (0 if est.joint_offsets is None else len(est.joint_offsets))


def _resolve(problem: Problem, views: list, slots: dict, est: Estimate, sigma: float, form: str,
             factors: dict | None, timings: dict | None):
    """(the estimate, the LM run, the graph) of the graph of ``views`` at ``sigma`` (the views'
    low-order modes weighted by ``factors``) solved from ``est``."""
    with timed(timings, "lm"):
        graph, values = build_graph(views, slots, problem, est, sigma, form, factors)
        run = levenberg_marquardt(graph, values, problem.options.max_iterations, form)
    return extract(run.values, slots, views, est, problem.cameras, form, problem), run, graph


def _fk_marginals(problem: Problem, views: list, slots: dict, est: Estimate, sigma: float, form: str,
                  factors: dict | None, timings: dict | None, solved: tuple | None = None) -> dict | None:
    """capture -> marginal covariance of F(k) in the view graph at ``est`` (the FK check's
    redundancy; :func:`calibgraph.solver.robot.fk_check.robot_pose_marginals`); None in the corner form.
    ``solved``: (that graph, its values at ``est``) when the caller has just solved it."""
    if form != "view":
        return None
    with timed(timings, "marginals"):
        graph, values = solved or build_graph(views, slots, problem, est, sigma, form, factors)
        return robot_pose_marginals(graph, values)


def _rejudge_robot(stated: Problem, slots: dict, views: list, est: Estimate, sigma: float, form: str,
                   factors: dict, timings: dict | None):
    """The robot judged again at its stated FK accuracy, on the graph whose views' low-order image
    modes carry ``factors`` (camera -> variance factor) of extra variance.

    A robot less accurate than stated and corners whose errors move whole boards both leave the
    fitted flange poses away from forward kinematics; with the FK prior freed first, every such
    departure was put on the robot. When the views, weighted for their correlated corner noise,
    no longer pull the poses further than the stated accuracy allows, the corners explain it:
    (the stated problem, its estimate, the FK ratio, the mode ratios and factors judged on it, the LM
    iterations spent). None when the robot is still off (the widened FK prior stands)."""
    est2, run, graph = _resolve(stated, views, slots, est, sigma, form, factors, timings)
    lin = linearise(stated, views, est2, sigma)
    fk2 = fk_variance_ratio(stated, views, est2, sigma, lin, factors,
                            _fk_marginals(stated, views, slots, est2, sigma, form, factors, timings,
                                          (graph, run.values)))
    if fk2 is not None and fk2.widens:
        return None
    modes = separated(mode_variance_ratios(stated, views, est2, sigma, lin),
                      mode_variance_ratios(stated, views, est2, sigma, lin, robot_free=True))
    return (stated, est2, fk2, modes, {c: m.applied for c, m in modes.items() if m.applied > 1.0},
            run.iterations)


def _translation_variance(problem: Problem, views: list, slots: dict, est: Estimate, sigma: float, form: str,
                          factors: dict | None) -> float | None:
    """The summed translation variance of every camera in the graph at ``est`` (None when it cannot be formed)."""
    graph, values = build_graph(views, slots, problem, est, sigma, form, factors or None)
    try:
        _, marg = reduced_marginals(graph, values)
        return float(sum(np.trace(marg.marginalCovariance(C(i))[3:, 3:]) for i in slots.values()))
    except (ObservabilityError, RuntimeError, np.linalg.LinAlgError):
        return None


def _unseparated(problem, stated_opts, slots, views, est, sigma, form, fk_ratio, mode_ratios, factors, unsplit,
                 timings):
    """Cameras whose views move as whole boards more than their corners scatter, where the captures
    cannot tell why (each seen once, by that camera alone: :func:`~calibgraph.solver.terms.noise_model.separated`).
    Two explanations fit alike: the robot's own error (the FK prior as the fit widened it, nothing applied to
    the corners) and correlated corner noise (the modes weighted, the robot judged again at its stated
    accuracy). Neither is claimed; the one whose cameras' 1-sigma is the larger is used, so that the
    1-sigma covers either. Returns (problem, est, fk_ratio, mode_ratios, factors, LM iterations spent);
    each such camera's ModeRatio records which was taken (``taken_as``)."""
    corner = {**factors, **{c: m.with_robot_ratio for c, m in unsplit.items()}}
    redo = _rejudge_robot(problem.with_(options=stated_opts), slots, views, est, sigma, form, corner, timings)
    robot_var = _translation_variance(problem, views, slots, est, sigma, form, factors)
    take_corner = False
    if redo is not None:
        p2, est2, fk2, modes2, _, it = redo
        corner_var = _translation_variance(p2, views, slots, est2, sigma, form, corner)
        take_corner = corner_var is not None and (robot_var is None or corner_var > robot_var)
    if take_corner:
        ratios = {c: replace(modes2.get(c, m), applied=float(corner[c]), separable=False, with_robot_ratio=m.with_robot_ratio,
                             taken_as="corner noise") if c in unsplit else modes2.get(c, m)
                  for c, m in mode_ratios.items()}
        return p2, est2, fk2, ratios, corner, it
    ratios = {c: replace(m, taken_as="robot") if c in unsplit else m for c, m in mode_ratios.items()}
    return problem, est, fk_ratio, ratios, factors, 0


def final_graph(problem: Problem, names: list, rounds: Rounds, slots: dict, form: str,
                timings: dict | None) -> Estimate:
    """The final weighted graph at the a posteriori pixel sigma (re-solved when that sigma, a wider
    FK prior or correlated corner noise moves the optimum), its cost, convergence and marginals."""
    opts = problem.options
    est, views, sigma, iterations = rounds.est, rounds.views, rounds.sigma_px, rounds.iterations
    converged = rounds.settled
    solved = None  # (graph, values) of the last solve at ``est``, when this function made one
    fold_est = None  # the FK split's cross-validation folds' estimates (fk_select), when it ran
    jackknife = None  # their jackknife record
    if opts.corner_noise == "per-view" and not opts.pixel_sigma_px:
        # each view its own noise level, now that the rounds have settled which corners and views are in
        residuals = est.residuals(views, problem.cameras)
        views, _, _ = camera_noise_scales(views, residuals, per_view=True)
        views, _ = reweight(views, norms_of(residuals), sigma, opts)  # robust weights at each view's level
        if any(v.view_noise != 1.0 for v in views):
            est, run, graph = _resolve(problem, views, slots, est, sigma, form, None, timings)
            iterations += run.iterations
            converged = converged and run.converged
            solved = (graph, run.values)
    check_modes = form == "view" and opts.view_noise_modes and not opts.pixel_sigma_px
    lin = linearise(problem, views, est, sigma) if opts.fk_variance or check_modes else None
    fk_ratio = fk_variance_ratio(problem, views, est, sigma, lin,
                                 marginal=_fk_marginals(problem, views, slots, est, sigma, form, None, timings, solved)
                                 ) if opts.fk_variance else None
    # the flange poses left the stated FK at first sight, beyond chance (p < 0.001: a widening at p < 0.05
    # alone comes in one cell of twenty with an exact robot, and would cost every such solve five more)
    departed = fk_ratio is not None and fk_ratio.widens and fk_ratio.significant
    if fk_ratio is not None and fk_ratio.widens:
        # the robot is less accurate than stated: the final graph uses the FK sigmas the fit implies,
        # and the corner-noise modes are judged on the residuals of that graph
        problem = problem.with_(options=widened(opts, fk_ratio))
        est, run, graph = _resolve(problem, views, slots, est, sigma, form, None, timings)
        iterations += run.iterations
        converged = converged and run.converged
        lin = None
        for _ in range(FK_COMPONENT_STEPS):
            # Helmert's iteration: the two components judged again at the widened sigmas, until they hold
            again = fk_variance_ratio(problem, views, est, sigma, marginal=_fk_marginals(
                problem, views, slots, est, sigma, form, None, timings, (graph, run.values)))
            if again is None or settled_components(again):
                break
            fk_ratio = rescaled(fk_ratio, again)
            problem = problem.with_(options=widened(opts, fk_ratio))
            est, run, graph = _resolve(problem, views, slots, est, sigma, form, None, timings)
            iterations += run.iterations
            converged = converged and run.converged
    mode_ratios = {}
    if check_modes:
        lin = lin or linearise(problem, views, est, sigma)
        # only the part of a camera's whole-board excess that no robot error explains is its corners' noise
        mode_ratios = separated(mode_variance_ratios(problem, views, est, sigma, lin),
                                mode_variance_ratios(problem, views, est, sigma, lin, robot_free=True))
    factors = {c: m.applied for c, m in mode_ratios.items() if m.applied > 1.0}
    unsplit = {c: m for c, m in mode_ratios.items() if m.separable is False}
    if unsplit:
        # whole boards move more than the corners scatter, and nothing in these captures tells the robot's
        # error from correlated corner noise: the 1-sigma is the larger of the two explanations'
        problem, est, fk_ratio, mode_ratios, factors, it = _unseparated(
            problem, opts, slots, views, est, sigma, form, fk_ratio, mode_ratios, factors, unsplit, timings)
        iterations += it
    elif fk_ratio is not None and fk_ratio.widens and factors:
        # Whole boards move more than the corners' scatter implies even with the robot poses freed:
        # the corners' correlated noise, not (or not only) the robot, may be why the poses departed.
        # Judge the robot again at its stated accuracy on the graph that weights those modes.
        redo = _rejudge_robot(problem.with_(options=opts), slots, views, est, sigma, form, factors, timings)
        if redo is not None:
            problem, est, fk_ratio, mode_ratios, factors, it = redo
            iterations += it

    def fold_solve(p, vs, e):  # a fold of the FK split's cross-validation or of the jackknife
        return _resolve(p, vs, slots, e, sigma, form, factors or None, None)[0]

    if fk_ratio is not None and fk_ratio.widens and form == "view":
        # rotation, translation or both: the split that predicts held-out captures from the reported FK
        with timed(timings, "fk_split"):
            chosen, fold_est = cross_validated_split(problem, opts, fk_ratio, views, est, fold_solve)
        if fold_est is not None and chosen.cross_validation["chosen"] != "both":
            problem = problem.with_(options=widened(opts, chosen))
            est, run, _ = _resolve(problem, views, slots, est, sigma, form, factors or None, timings)
            iterations += run.iterations
            converged = converged and run.converged
        fk_ratio = chosen
    whole_boards = any(m.significant or m.separable is False and m.taken_as is not None for m in mode_ratios.values())
    if (departed or whole_boards) and fold_est is None and form == "view":
        # the robot departed but its split was not cross-validated (one component widened, or the corners'
        # correlated noise explained the departure), or whole boards misfit beyond chance: the folds still say
        # whether the 1-sigma holds
        with timed(timings, "fk_jackknife"):
            fold_est = jackknife_folds(problem, views, est, fold_solve)
    if opts.pixel_sigma_px:
        sigma_post = opts.pixel_sigma_px
    else:
        active = [v for v in views if v.active]
        sigma_post = a_posteriori_sigma(active, est.residual_norms(active, problem.cameras),
                                        _n_parameters(problem, names, est), mode_ratios)
    with timed(timings, "build_graph"):
        graph, values = build_graph(views, slots, problem, est, sigma_post, form, factors)
    if abs(sigma_post - sigma) > 0.05 * sigma or any(f > 1.05 for f in factors.values()):
        # the pixel/FK balance moved enough to shift the optimum: re-solve before the marginals
        with timed(timings, "lm"):
            run = levenberg_marquardt(graph, values, opts.max_iterations, form)
        iterations += run.iterations
        converged = converged and run.converged
        values = run.values
        est = extract(values, slots, views, est, problem.cameras, form, problem)
    linear = None
    if form == "view":
        linear, marg = reduced_marginals(graph, values, timings)
        if fold_est is not None:
            # the folds' camera poses scatter more than the graph's covariance says: the robot's error
            # repeats from pose to pose; every noise of the graph takes the missing variance factor
            f, per = jackknife_factor(est, fold_est, lambda n: marg.marginalCovariance(C(slots[n])))
            applied = jackknife_applied(f, len(fold_est), fk_ratio is not None and fk_ratio.widens)
            jackknife = {"folds": len(fold_est), "jackknife_variance_factor": f, "jackknife_applied": applied,
                         "jackknife_per_camera": per}
            if fk_ratio is not None:
                fk_ratio = replace(fk_ratio, cross_validation={**(fk_ratio.cross_validation or {"folds": len(fold_est),
                                                                                               "chosen": None}),
                                                               **jackknife})
            if applied > 1.0:
                s = float(np.sqrt(applied))
                inflated = problem.with_(options=replace(problem.options,
                                                         fk_sigma_translation_m=problem.options.fk_sigma_translation_m * s,
                                                         fk_sigma_rotation_rad=problem.options.fk_sigma_rotation_rad * s))
                est, run, graph = _resolve(inflated, views, slots, est, sigma_post * s, form, factors, timings)
                iterations += run.iterations
                converged = converged and run.converged
                values = run.values
                linear, marg = reduced_marginals(graph, values, timings)
    else:
        marg = marginals(graph, values, form, timings)
    mount_cov = factors_ppp.mount_cov_body(marg, values) if form == "corner" else marg.marginalCovariance(B(0))
    return replace(est, iterations=iterations, converged=converged, cost=graph.error(values), sigma_px=sigma_post,
                   slots=slots, formulation=form, marginals=marg, mount_cov_body=mount_cov, mode_ratios=mode_ratios,
                   fk_ratio=fk_ratio, jackknife=jackknife, graph=graph, values=values, linear=linear)


def solve_joint(problem: Problem, names: list, views: list, starts: list, timings: dict | None = None) -> Group:
    """All cameras in one graph from each Estimate in ``starts``: the lowest final cost wins. Raises
    the last ObservabilityError when no start can be solved."""
    best, error = None, None
    for est0 in starts:
        try:
            g = solve_from_start(problem, names, views, est0, timings)
        except ObservabilityError as e:
            error = e
            continue
        if best is None or g.est.cost < best.est.cost:
            best = g
    if best is None:
        raise error
    return best


def solve_single(problem: Problem, name: str, views: list, est0: Estimate, timings: dict | None = None) -> Group:
    """One camera in its own graph, with its own board mount."""
    return solve_from_start(problem, [name], [v for v in views if v.camera == name], est0, timings)


def kinematics_start(problem: Problem, names: list, views: list, starts: list, ks, timings: dict | None) -> Estimate:
    """The start of a joint solve with kinematics_staging='staged': the cameras solved with the FK
    prior inflated (and no offsets), then the joint offsets that best explain the flange poses that
    solve found."""
    o = problem.options
    loose = replace(o, kinematics="none", fk_sigma_rotation_rad=o.fk_sigma_rotation_rad * kin.STAGE1_FK_INFLATION,
                    fk_sigma_translation_m=o.fk_sigma_translation_m * kin.STAGE1_FK_INFLATION)
    g1 = solve_joint(problem.with_(options=loose), names, views, starts, timings)
    fk_sigmas = np.array([o.fk_sigma_rotation_rad] * 3 + [o.fk_sigma_translation_m] * 3)
    flange = g1.est.T_ref_mount if problem.mode == "eye_to_hand" else {k: np.linalg.inv(T) for k, T in g1.est.T_ref_mount.items()}
    offsets = kin.offsets_from_poses(ks, flange, o.joint_offset_prior_rad, fk_sigmas)
    return Estimate(T_ref_cam=g1.est.T_ref_cam, T_mount_board=g1.est.T_mount_board, T_ref_mount={},
                    joint_offsets=offsets)
