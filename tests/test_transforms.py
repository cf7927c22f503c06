import numpy as np
import pytest

from calibgraph.core.errors import InputError
from calibgraph.core.transforms import (
    R_to_quat_xyzw,
    check_pose,
    exp_so3,
    inv,
    log_so3,
    make_T,
    pose_error,
    quat_xyzw_to_R,
)


def test_exp_log_roundtrip_including_near_pi():
    rng = np.random.default_rng(0)
    for _ in range(200):
        w = rng.normal(size=3)
        w *= rng.uniform(0, np.pi - 1e-6) / np.linalg.norm(w)
        assert np.allclose(log_so3(exp_so3(w)), w, atol=1e-6)
    w = np.array([0, 0, np.pi - 1e-9])
    assert np.isclose(np.linalg.norm(log_so3(exp_so3(w))), np.pi - 1e-9, atol=1e-6)


def test_quaternion_roundtrip_and_inverse():
    rng = np.random.default_rng(1)
    for _ in range(100):
        R = exp_so3(rng.normal(size=3))
        assert np.allclose(quat_xyzw_to_R(R_to_quat_xyzw(R)), R, atol=1e-12)
        T = make_T(R, rng.normal(size=3))
        assert np.allclose(inv(T) @ T, np.eye(4), atol=1e-12)
    assert pose_error(T, T) == pytest.approx((0.0, 0.0), abs=1e-6)


def test_check_pose_rejects_nan_and_non_orthonormal():
    T = np.eye(4)
    T[0, 3] = np.nan
    with pytest.raises(InputError, match="NaN"):
        check_pose(T, "capture 3")
    T = np.eye(4)
    T[0, 0] = 1.2
    with pytest.raises(InputError, match="not orthonormal"):
        check_pose(T, "capture 3")
    with pytest.raises(InputError, match="4x4"):
        check_pose(np.eye(3), "x")
