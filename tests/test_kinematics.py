"""The arm's kinematic model: FK against the published Franka pose, analytic Jacobians against
finite differences, URDF round trip and corrected joint origins."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from calibgraph.core.errors import InputError
from calibgraph.core.kinematics import SerialChain, chain_from_urdf, corrected_urdf, franka_chain, franka_fk

RNG = np.random.default_rng(3)
Q = RNG.uniform(-1.5, 1.5, (6, 7))


def _local(T0, T1):
    return gtsam.Pose3(T0).localCoordinates(gtsam.Pose3(T1))


def test_franka_fk_is_the_chain_and_batches():
    ch = franka_chain()
    T = ch.fk(Q)
    assert T.shape == (6, 4, 4)
    for q, Tk in zip(Q, T):
        assert np.allclose(franka_fk(q), Tk, atol=1e-14)
    # libfranka's flange at the all-zero pose: 0.088 m forward, 0.333+0.316+0.384-0.107 m up
    assert np.allclose(franka_fk(np.zeros(7))[:3, 3], [0.088, 0.0, 0.926], atol=1e-12)
    with pytest.raises(InputError):
        franka_fk(np.zeros(6))


def test_joint_jacobian_matches_finite_differences():
    # central differences with eps 1e-6 on metre/radian scales: truncation ~1e-12, rounding ~1e-10
    ch = franka_chain()
    T, J = ch.fk_jacobian(Q)
    eps = 1e-6
    for n in range(len(Q)):
        for i in range(7):
            d = np.zeros(7)
            d[i] = eps
            num = (_local(T[n], ch.fk(Q[n] + d)) - _local(T[n], ch.fk(Q[n] - d))) / (2 * eps)
            assert np.allclose(num, J[n][:, i], atol=1e-8)


def test_origin_jacobian_matches_finite_differences():
    ch = franka_chain()
    T = ch.fk(Q[:2])
    JO = ch.origin_jacobian(Q[:2])
    eps = 1e-6
    for n in range(2):
        for col in range(0, 42, 5):
            i, k = divmod(col, 6)
            d = np.zeros(6)
            d[k] = eps

            def fk(sign):
                o = ch.T_prev_origin.copy()
                o[i] = o[i] @ gtsam.Pose3.Expmap(sign * d).matrix()
                return SerialChain("x", ch.joint_names, o, ch.axes, ch.T_last_flange).fk(Q[n])

            num = (_local(T[n], fk(1)) - _local(T[n], fk(-1))) / (2 * eps)
            assert np.allclose(num, JO[n][:, col], atol=1e-8)


def test_offsets_urdf_round_trip_and_corrected_urdf(tmp_path):
    ch = franka_chain()
    o = RNG.normal(scale=0.01, size=7)
    assert np.allclose(ch.with_joint_offsets(o).fk(Q), ch.fk(Q + o), atol=1e-12)
    p = tmp_path / "arm.urdf"
    p.write_text(ch.to_urdf())
    ch2 = chain_from_urdf(p)
    assert ch2.joint_names == ch.joint_names
    # URDF text carries 10 significant digits
    assert np.allclose(ch2.fk(Q), ch.fk(Q), atol=1e-8)
    p2 = tmp_path / "fixed.urdf"
    p2.write_text(corrected_urdf(ch2, o))
    assert np.allclose(chain_from_urdf(p2).fk(Q), ch.fk(Q + o), atol=1e-8)
    p2.write_text(corrected_urdf(ch, o))
    assert np.allclose(chain_from_urdf(p2).fk(Q), ch.fk(Q + o), atol=1e-8)


def test_urdf_fixed_joints_fold_and_prismatic_is_refused(tmp_path):
    urdf = """<robot name="two"><link name="base"/><link name="a"/><link name="b"/><link name="tool"/>
      <joint name="j1" type="revolute"><parent link="base"/><child link="a"/><origin xyz="0 0 0.5"/><axis xyz="0 0 1"/></joint>
      <joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0.3 0 0" rpy="1.5707963 0 0"/><axis xyz="0 0 1"/></joint>
      <joint name="t" type="fixed"><parent link="b"/><child link="tool"/><origin xyz="0.2 0 0"/></joint></robot>"""
    p = tmp_path / "two.urdf"
    p.write_text(urdf)
    ch = chain_from_urdf(p)
    assert ch.joint_names == ("j1", "j2") and ch.flange_link == "tool"
    T = ch.fk([np.pi / 2, 0.0])
    assert np.allclose(T[:3, 3], [0.0, 0.5, 0.5], atol=1e-6)
    p.write_text(urdf.replace('name="j2" type="revolute"', 'name="j2" type="prismatic"'))
    with pytest.raises(InputError, match="prismatic"):
        chain_from_urdf(p)


def test_chain_agrees_with_pinocchio_when_installed(tmp_path):
    # an independent implementation of FK and the frame Jacobian (pinocchio's LOCAL Jacobian is
    # linear-first); the URDF carries 10 significant digits, so agreement to 1e-8
    try:
        import pinocchio as pin
    except ImportError:
        pytest.skip("pinocchio (pip 'pin') not installed: the chain is checked against finite differences only")
    ch = franka_chain()
    p = tmp_path / "fr3.urdf"
    p.write_text(ch.to_urdf())
    model = pin.buildModelFromUrdf(str(p))
    data = model.createData()
    fid = model.getFrameId(ch.flange_link)
    T, J = ch.fk_jacobian(Q)
    for q, Tk, Jk in zip(Q, T, J):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        Jp = pin.getFrameJacobian(model, data, fid, pin.ReferenceFrame.LOCAL)
        assert np.allclose(data.oMf[fid].homogeneous, Tk, atol=1e-8)
        assert np.allclose(np.vstack([Jp[3:], Jp[:3]]), Jk, atol=1e-8)
