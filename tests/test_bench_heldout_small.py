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


def _old_make_splits(indices):
    """make_splits as it was before splits dealt configurations (capture by capture), for the identity below."""
    n, m = len(indices), int(round(2 * len(indices) / 3))
    out = [({indices[i] for i in p[:m]}, {indices[i] for i in p[m:]}, f"random seed {s}")
           for s in bh.SEEDS for p in [np.random.default_rng(s).permutation(n)]]
    return out + [(set(indices[1::2]), set(indices[0::2]), "train odd"), (set(indices[0::2]), set(indices[1::2]), "train even")]


def test_splits_without_revisits_are_the_capture_by_capture_splits():
    for caps in (list(range(15)), [0, 2, 3, 7, 8, 9, 11, 12, 20, 21, 22, 30, 31, 40]):
        identity = {k: k for k in caps}
        assert bh.make_splits(caps) == bh.make_splits(caps, identity) == _old_make_splits(caps)
        assert bh.loo_splits(caps[:8], identity) == [(set(caps[:8]) - {k}, {k}, f"leave out {k}") for k in caps[:8]]


def test_splits_keep_every_visit_of_a_configuration_on_one_side():
    # three sessions of the same 12 joint targets (captures 0-11, 12-23, 24-35), as the merged Franka set
    caps = list(range(36))
    config = {k: k % 12 for k in caps}
    splits = bh.make_splits(caps, config)
    assert len(splits) == len(bh.SEEDS) + 2
    for train, test, _ in splits:
        assert train | test == set(caps) and not train & test
        assert not {k % 12 for k in train} & {k % 12 for k in test}
    assert all(len(train) == 3 * 8 for train, _, lab in splits if lab.startswith("random"))  # 8 of 12 targets
    loo = bh.loo_splits(caps, config)
    assert bh.is_loo(loo) and len(loo) == 12
    assert [sorted(test) for _, test, _ in loo] == [[g, g + 12, g + 24] for g in range(12)]
