"""A board held at its declared pitch (the robot's error and a misprint cannot be told apart) is
predicted at new poses as the held graph predicts them: the scale's prior enters ``prediction`` with
its own Jacobian (the board's points move with the scale as the poses do), not as a spread of the
poses alone, which overstated the expected held-out error 1.6x here and 3-10x on real sets
(leo038: 20.3 px expected where held-out poses miss by 3 px)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from calibgraph.sim.arm_error import arm_error_scene
from calibgraph.solver.solve.batch import solve
from calibgraph.solver.solve.camera_model import HeldScaleMarginals

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from bench_claims import held_out  # noqa: E402


class _Inner:
    def __init__(self, cov: dict):
        self.cov = cov

    def marginalCovariance(self, k):  # noqa: N802
        return self.cov[k]

    def has(self, k):
        return k in self.cov

    def joint(self, keys):
        from scipy.linalg import block_diag
        return block_diag(*[self.cov[k] for k in keys])


def test_the_scale_row_is_the_prior_and_the_poses_move_with_it():
    rng = np.random.default_rng(0)
    cov = {1: np.diag(rng.uniform(1, 2, 6)), 2: np.diag(rng.uniform(1, 2, 6)), 3: np.diag(rng.uniform(1, 2, 4))}
    b = {1: rng.normal(size=6), 2: rng.normal(size=6)}
    m = HeldScaleMarginals(_Inner(cov), b, 0.02)
    J = m.joint_with_scale([1, 2, 3], at=2)
    assert J.shape == (17, 17)
    assert J[12, 12] == pytest.approx(0.02 ** 2)
    np.testing.assert_allclose(J[12, :12], 0.02 ** 2 * np.r_[b[1], b[2]])
    np.testing.assert_allclose(J[12, 13:], 0.0)
    keep = np.r_[0:12, 13:17]
    np.testing.assert_allclose(J[np.ix_(keep, keep)], m.joint([1, 2, 3]))
    np.testing.assert_allclose(J, J.T)
    assert np.all(np.linalg.eigvalsh(J) > -1e-12)


@pytest.mark.slow
def test_held_scale_prediction_matches_held_out_poses():
    """An FR3 off by twice the simulator's default link and zero errors, eye-in-hand, 12 configurations, the
    board printed at 102 %: the seeds whose solve holds the scale. The expected held-out RMS (prediction)
    against the measured one of 8 new configurations, pooled: 1.01 with the scale's own Jacobian, 0.60
    with the poses' spread alone (seeds 0, 1, 4). Bounds [0.7, 1.5]: the 95 % range of a ratio of RMS over
    ~24 configurations' boards, which move together (each a repeating arm error)."""
    meas, exp = [], []
    for seed in range(8):
        sc, truth = arm_error_scene(mode="eye_in_hand", n_configs=12, board_scale=1.02, arm_scale=2.0,
                                    test_configs=8, seed=seed)
        r = solve(sc.problem)
        if not any("cannot tell a misprint" in n for n in r.notes):
            continue
        m, e = held_out(r, truth.test, "eye_in_hand")
        meas += m
        exp += e
        if len(meas) == 3:
            break
    assert len(meas) == 3, "fewer than 3 of 8 seeds held the board's scale"
    ratio = float(np.sqrt(np.mean(np.square(meas))) / np.sqrt(np.mean(np.square(exp))))
    assert 0.7 <= ratio <= 1.5, (ratio, meas, exp)
