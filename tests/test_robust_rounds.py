"""The robust rounds' view level (solver/fit/robust.py): a view on the 50 % cut that is set aside and
re-admitted in turn ends the rounds, set aside, instead of leaving them unsettled."""

from dataclasses import replace

import calibgraph.solver.fit.robust as robust
from calibgraph.sim.synthetic_corners import make_scene
from calibgraph.solver.solve.batch import solve


def test_a_view_flipping_on_the_cut_is_set_aside_and_the_rounds_settle(monkeypatch):
    sc = make_scene(n_poses=16, pixel_sigma_px=0.1, seed=3, reported_intrinsics="exact")
    r0 = solve(sc.problem)
    assert r0.converged
    cam = next(iter(r0.cameras))
    k = sorted({d.capture for d in sc.problem.detections if d.camera == cam})[5]
    real = robust.readmit_or_reject
    calls = {"n": 0}

    def flipping(views, norms, sigma_px, opts):
        # the real judgement, except that view (cam, k) straddles the cut: out, in, out, ... each round
        out, changed = real(views, norms, sigma_px, opts)
        calls["n"] += 1
        i = next((i for i, v in enumerate(out) if (v.camera, v.capture) == (cam, k)), None)
        if i is None:
            return out, changed
        was = views[i].active
        out[i] = replace(out[i], active=not was, reason="flip" if was else "")
        return out, True

    monkeypatch.setattr(robust, "readmit_or_reject", flipping)
    r = solve(sc.problem)
    assert calls["n"] > 0
    assert r.converged  # before: MAX_VIEW_ROUNDS of flipping and "did not converge"
    why = [rv.reason for rv in r.rejected_views if (rv.camera, rv.capture) == (cam, k)]
    assert why and "on the cut" in why[0]
    # one view of sixteen out: the cameras move by a fraction of their 1-sigma
    for n, c in r.cameras.items():
        d = abs(c.T_ref_cam[:3, 3] - r0.cameras[n].T_ref_cam[:3, 3]) * 1e3
        assert (d < 1.0 * r0.cameras[n].sigma_translation_mm).all()
