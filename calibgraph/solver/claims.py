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
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from calibgraph.core.problem import Problem, intrinsics_source
from calibgraph.solver.factors import intrinsics_vector
from calibgraph.solver.graph import Estimate, build_graph
from calibgraph.solver.keys import K
from calibgraph.solver.noise_model import mode_variance_ratios
from calibgraph.solver.reduced import linearise_graph

CHI2_6_999 = 22.46
FOCAL_REL = 0.002
PRINCIPAL_PX = 2.0
DISTORTION = 0.02


@dataclass(frozen=True)
class Contradiction:
    """A camera whose intrinsics, declared exact, the views reject."""

    camera: str
    chi2: float
    change: np.ndarray  # (6,) the change of [fx, fy, cx, cy, k1, k2] the data ask for

    def note(self, given: np.ndarray) -> str:
        d = self.change
        return (f"camera {self.camera}: its intrinsics are declared exact, but its views contradict them (likelihood-ratio "
                f"chi-square {self.chi2:.0f} on 6 dof; the data ask for fx {100 * d[0] / given[0]:+.2f} %, "
                f"fy {100 * d[1] / given[1]:+.2f} %, cx {d[2]:+.1f} px, cy {d[3]:+.1f} px, k1 {d[4]:+.3f}, "
                f"k2 {d[5]:+.3f}): solved with them freed under a wide prior (estimates and 1-sigma in the result); "
                "fix the camera's intrinsics file or calibrate it (calibgraph intrinsics)")


def exact_claims(problem: Problem, names) -> list:
    """The cameras whose intrinsics are declared exact and held (intrinsics='auto')."""
    if problem.options.intrinsics != "auto":
        return []
    return [n for n in names if problem.cameras[n].known and intrinsics_source(problem.cameras[n], problem.options) == "exact"]


def contradicted(problem: Problem, views: list, slots: dict, est: Estimate, sigma_px: float) -> list:
    """The :class:`Contradiction` s among the exact claims of the graph's cameras at ``est``.

    Each claim is tested by how much freeing that camera's intrinsics alone lowers the linearised
    cost beyond what re-fitting everything else does (twice that is the chi-square, 6 dof), in one
    linearisation of the graph with every claimed camera's intrinsics as variables, reduced to its
    global variables. The residuals are whitened with the views' own noise model, estimated even
    when the final graph is told to ignore it: correlated corner noise moves whole boards at random
    from view to view, a wrong camera model moves them all alike."""
    claimed = [n for n in exact_claims(problem, slots) if n not in est.free_intrinsics]
    if not claimed:
        return []
    modes = mode_variance_ratios(problem, views, est, sigma_px)
    factors = {c: m.applied for c, m in modes.items() if m.applied > 1.0}
    free = replace(est, free_intrinsics=est.free_intrinsics | frozenset(claimed))
    graph, values = build_graph(views, slots, problem, free, sigma_px, "view", factors)
    lin = linearise_graph(graph, values)
    claimed_keys = {K(slots[n]) for n in claimed}
    nuisance = [k for k in lin.index if k not in claimed_keys]
    held = lin.step_gain(nuisance)
    out = []
    for n in claimed:
        key = K(slots[n])
        chi2 = 2.0 * (lin.step_gain(nuisance + [key]) - held)
        change = lin.step(nuisance + [key])[key]
        given = intrinsics_vector(problem.cameras[n])
        large = (np.any(np.abs(change[:2] / given[:2]) > FOCAL_REL) or np.any(np.abs(change[2:4]) > PRINCIPAL_PX)
                 or np.any(np.abs(change[4:]) > DISTORTION))
        if chi2 > CHI2_6_999 and large:
            out.append(Contradiction(n, chi2, change))
    return out
