"""scripts/bench_heldout.py on small sets (issue 45, item 4): leave-one-out splits and the jackknife
variance they are compared with. For the mean of n values the jackknife (n - 1) / n * sum (theta_i -
theta_bar)^2 of the leave-one-out means is exactly the sample variance over n (the textbook identity),
which pins the formula and its (n - 1) / n factor."""

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import bench_heldout as bh  # noqa: E402
from calibgraph.core.transforms import exp_so3, make_T  # noqa: E402


def test_leave_one_out_splits_hold_out_each_capture_once():
    caps = [1, 2, 3, 5, 8, 13, 21, 34]
    splits = bh.loo_splits(caps)
    assert bh.is_loo(splits) and not bh.is_loo(bh.make_splits(list(range(15))))
    assert sorted(k for _, test, _ in splits for k in test) == caps
    assert all(len(test) == 1 and train == set(caps) - test for train, test, _ in splits)


def test_jackknife_of_leave_one_out_means_is_the_variance_of_the_mean():
    rng = np.random.default_rng(3)
    n = 8
    t = rng.normal(0.0, [1e-3, 2e-3, 5e-3], size=(n, 3))
    w = rng.normal(0.0, 1e-4, size=(n, 3))  # small rotations: the tangent-space mean is then the plain mean to 1e-8
    loo = [make_T(exp_so3(np.delete(w, i, 0).mean(0)), np.delete(t, i, 0).mean(0)) for i in range(n)]
    var = bh.jackknife_var(loo)
    assert np.allclose(var[3:], t.var(0, ddof=1) / n, rtol=1e-9)
    assert np.allclose(var[:3], w.var(0, ddof=1) / n, rtol=1e-3)
