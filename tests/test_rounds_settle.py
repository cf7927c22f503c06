"""When the robust rounds count as settled: a few corners straddling the loss's knee flip their
weight from round to round on rendered far cells (the largest change stayed at 0.06 after the last
round on a third of the rendered 5 m D455 and 3 m L515 solves, which then reported 'did not
converge'), while the estimate no longer moves. The rounds settle on the RMS change of the weights;
many corners still changing is still not settled."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest

import calibgraph.solver.fit.robust as robust
from calibgraph.sim.synthetic_corners import make_scene
from calibgraph.solver.solve.batch import solve


def _flipping(monkeypatch, fraction: float):
    """Make ``fraction`` of all corners (the first of each view, in view order) flip their robust
    weight by 0.1 at each re-weighting."""
    real = robust.reweight
    rounds = itertools.count()

    def reweight(views, norms, sigma_px, opts):
        out, change = real(views, norms, sigma_px, opts)
        dw = 0.1 * (next(rounds) % 2)
        left = int(np.ceil(fraction * sum(v.w.size for v in out if v.active)))
        flipped = []
        for v in out:
            if v.active and left:
                w = v.w.copy()
                n = min(left, int(np.ceil(0.5 * w.size)))
                w[:n] = np.clip(w[:n] - dw, 0.0, 1.0)
                left -= n
                v = replace(v, w=w)
            flipped.append(v)
        return flipped, max(change, 0.1)

    monkeypatch.setattr(robust, "reweight", reweight)


@pytest.mark.parametrize("fraction, settled", [(0.002, True), (0.4, False)])
def test_a_few_flipping_weights_do_not_unsettle_the_rounds(monkeypatch, fraction, settled):
    sc = make_scene(n_poses=20, pixel_sigma_px=0.1, seed=3, reported_intrinsics="exact")
    _flipping(monkeypatch, fraction)
    r = solve(sc.problem)
    assert r.converged is settled


def test_one_corner_flipping_across_the_outlier_cut_does_not_unsettle_a_small_solve(monkeypatch):
    """A 2-camera, 12-pose rendered demo reported 'did not converge': one corner crossed the 5-sigma
    cut each round (weight ~0.5 <-> 0, an RMS change of 0.02 over its few hundred corners) while the
    estimate no longer moved. A few corners flipping is settled; many flipping by as much is not."""
    real = robust.reweight
    rounds = itertools.count()

    def flip(n_corners):
        def reweight(views, norms, sigma_px, opts):
            out, change = real(views, norms, sigma_px, opts)
            dw = 0.5 * (next(rounds) % 2)
            left, flipped = n_corners, []
            for v in out:
                if v.active and left:
                    w = v.w.copy()
                    k = min(left, w.size)
                    w[:k] = np.clip(w[:k] - dw, 0.0, 1.0)
                    left -= k
                    v = replace(v, w=w)
                flipped.append(v)
            return flipped, max(change, 0.5)
        return reweight

    sc = make_scene(n_poses=8, pixel_sigma_px=0.1, seed=3, reported_intrinsics="exact")
    monkeypatch.setattr(robust, "reweight", flip(1))
    assert solve(sc.problem).converged
    monkeypatch.setattr(robust, "reweight", flip(60))
    assert not solve(sc.problem).converged
