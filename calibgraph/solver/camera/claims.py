"""Intrinsics declared exact, tested against the views.

A camera whose intrinsics are declared exact is held at them. When they are wrong, the misfit
shows in its corners, and a solve that holds them explains it away elsewhere: as correlated corner
noise, a less accurate robot, a printed board of another size. So before any of that is judged,
each such camera's claim is tested by the linearised likelihood ratio of freeing its six
intrinsics (chi-square, 6 dof, under the claim); the Gauss-Newton step on them is the change the
data ask for. A claim is rejected when the statistic is
significant (p < 0.001) and the change is of a size a calibration file would not carry
(``FOCAL_REL``, ``PRINCIPAL_PX``, ``DISTORTION``); the camera is then solved with its intrinsics
freed under a wide prior.

What a forced option holds is tested the same way (:func:`held_by_force`): the intrinsics of
``--fixed-intrinsics`` and the declared board size of ``--fixed-board-scale``. The user's choice
is honoured (they stay held), but what the default would have said is said: that the views reject
the intrinsics (the same statistic and sizes), or ask for a board of another size (the Gauss-Newton
step on the scale beyond 3 sigma, as the default's board note).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.core.problem import Problem, intrinsics_source
from calibgraph.solver.terms.factors import intrinsics_vector
from calibgraph.solver.fit.graph import Estimate, build_graph
from calibgraph.solver.terms.keys import K, S
from calibgraph.solver.terms.noise_model import mode_variance_ratios
from calibgraph.solver.terms.reduced import linearise_graph

CHI2_6_999 = 22.46
BOARD_SCALE_SIGMAS = 3.0  # the default's board note: a scale this many sigma from 1
FOCAL_REL = 0.002
PRINCIPAL_PX = 2.0
DISTORTION = 0.02


@dataclass(frozen=True)
class Contradiction:
    """A camera whose intrinsics, declared exact, the views reject."""

    camera: str
    chi2: float
    change: np.ndarray  # (6,) the change of [fx, fy, cx, cy, k1, k2] the data ask for

    def _evidence(self, given: np.ndarray) -> str:
        """The test and the change the data ask for, as the notes say them."""
        d = self.change
        return (f"likelihood-ratio chi-square {self.chi2:.0f} on 6 dof; the data ask for fx {100 * d[0] / given[0]:+.2f} %, "
                f"fy {100 * d[1] / given[1]:+.2f} %, cx {d[2]:+.1f} px, cy {d[3]:+.1f} px, k1 {d[4]:+.3f}, k2 {d[5]:+.3f}")

    def note(self, given: np.ndarray) -> str:
        return (f"camera {self.camera}: its intrinsics are declared exact, but its views contradict them "
                f"({self._evidence(given)}): solved with them freed under a wide prior (estimates and 1-sigma in the "
                "result); fix the camera's intrinsics file or calibrate it (calibgraph intrinsics)")

    def held_note(self, given: np.ndarray) -> str:
        """The note of intrinsics held by --fixed-intrinsics that the views reject (they stay held)."""
        return (f"camera {self.camera}: --fixed-intrinsics holds its given intrinsics, but its views reject them "
                f"({self._evidence(given)}): its pose and 1-sigma are conditional on intrinsics the data contradict "
                "(what other notes say of whole boards moving or of the robot may be their doing); without "
                "--fixed-intrinsics they are estimated")


def exact_claims(problem: Problem, names) -> list:
    """The cameras whose intrinsics are declared exact and held (intrinsics='auto')."""
    if problem.options.intrinsics != "auto":
        return []
    return [n for n in names if problem.cameras[n].known and intrinsics_source(problem.cameras[n], problem.options) == "exact"]


def _linearised(problem: Problem, views: list, slots: dict, est: Estimate, sigma_px: float, free: list,
                scale: bool = False):
    """The graph at ``est`` with the intrinsics of the cameras ``free`` as variables under the wide
    prior (and, with ``scale``, the board's scale under its prior), linearised and reduced to its
    global variables. The residuals are whitened with the views' own noise model, estimated even
    when the final graph is told to ignore it: correlated corner noise moves whole boards at random
    from view to view, a wrong camera model moves them all alike."""
    modes = mode_variance_ratios(problem, views, est, sigma_px)
    factors = {c: m.applied for c, m in modes.items() if m.applied > 1.0}
    if scale:
        problem = problem.with_(options=replace(problem.options, board_scale=True))
    free_est = replace(est, free_intrinsics=est.free_intrinsics | frozenset(free))
    graph, values = build_graph(views, slots, problem, free_est, sigma_px, "view", factors)
    return linearise_graph(graph, values)


def _tested(problem: Problem, lin, slots: dict, names: list) -> list:
    """The :class:`Contradiction` s among ``names`` (their K keys variables of ``lin``): each
    camera's intrinsics freed alone, every other variable of ``lin`` re-fitted."""
    tested = {K(slots[n]) for n in names}
    nuisance = [k for k in lin.index if k not in tested]
    base = lin.step_gain(nuisance) if nuisance else 0.0
    out = []
    for n in names:
        key = K(slots[n])
        chi2 = 2.0 * (lin.step_gain(nuisance + [key]) - base)
        change = lin.step(nuisance + [key])[key]
        given = intrinsics_vector(problem.cameras[n])
        large = (np.any(np.abs(change[:2] / given[:2]) > FOCAL_REL) or np.any(np.abs(change[2:4]) > PRINCIPAL_PX)
                 or np.any(np.abs(change[4:]) > DISTORTION))
        if chi2 > CHI2_6_999 and large:
            out.append(Contradiction(n, chi2, change))
    return out


def contradicted(problem: Problem, views: list, slots: dict, est: Estimate, sigma_px: float) -> list:
    """The :class:`Contradiction` s among the exact claims of the graph's cameras at ``est``.

    Each claim is tested by how much freeing that camera's intrinsics alone lowers the linearised
    cost beyond what re-fitting everything else does (twice that is the chi-square, 6 dof), in one
    linearisation of the graph with every claimed camera's intrinsics as variables, reduced to its
    global variables (:func:`_linearised`)."""
    claimed = [n for n in exact_claims(problem, slots) if n not in est.free_intrinsics]
    if not claimed:
        return []
    return _tested(problem, _linearised(problem, views, slots, est, sigma_px, claimed), slots, claimed)


def held_by_force(problem: Problem, views: list, slots: dict, est: Estimate, sigma_px: float) -> list:
    """Notes on what ``--fixed-intrinsics`` / ``--fixed-board-scale`` hold and the views at ``est``
    reject (module docstring): the held intrinsics tested as exact claims are, the declared board
    size by the step the data ask of the scale. Each is tested with everything else free, the other
    forced hold too: what the default, which holds neither, would say."""
    o = problem.options
    held = [n for n in slots if o.intrinsics == "fixed" and problem.cameras[n].known and n not in est.free_intrinsics]
    scale = not o.board_scale
    if not held and not scale:
        return []
    lin = _linearised(problem, views, slots, est, sigma_px, held, scale)
    notes = [c.held_note(intrinsics_vector(problem.cameras[c.camera]))
             for c in _tested(problem, lin, slots, held)]
    if scale and S(0) in lin.index:  # the Gauss-Newton step of everything, and the scale's 1-sigma then
        step = float(lin.step(list(lin.index))[S(0)][0])
        at = lin.index[S(0)].start
        sigma = float(np.sqrt(lin.covariance[at, at]))
        if abs(step) > BOARD_SCALE_SIGMAS * sigma:
            who = f"camera {next(iter(slots))}: its views" if problem.method == "single" else "the views"
            notes.append(f"{who} ask for the board at {100 * step:+.2f} % (± {100 * sigma:.2f} %) of the size the "
                         "target spec declares, but --fixed-board-scale holds the declared size: the poses and 1-sigma "
                         "are conditional on it (a misprint, or the arm's kinematic errors, which scale the board's "
                         "apparent size too; measure the board with a ruler; without --fixed-board-scale its scale is "
                         "estimated)")
    return notes
