"""Rigid transforms as 4x4 homogeneous numpy arrays.

Convention (used everywhere in calibgraph): ``T_a_b`` maps points from frame ``b`` into frame
``a``: ``p_a = T_a_b @ p_b``. Hence ``T_a_c = T_a_b @ T_b_c`` and ``inv(T_a_b) = T_b_a``.
Rotation vectors are axis * angle in radians; quaternions are stored ``xyzw`` unless a name says
otherwise. Tangent vectors follow GTSAM's Pose3 order: ``[rotation (3), translation (3)]``.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.errors import InputError


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Homogeneous 4x4 from a 3x3 rotation and a 3-vector translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, float).reshape(3)
    return T


def inv(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (exact, no general matrix inverse)."""
    R = T[:3, :3]
    return make_T(R.T, -R.T @ T[:3, 3])


def skew(v: np.ndarray) -> np.ndarray:
    """3x3 cross-product matrix: skew(a) @ b == cross(a, b)."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def exp_so3(w: np.ndarray) -> np.ndarray:
    """Rotation matrix from a rotation vector (rad), Rodrigues' formula."""
    w = np.asarray(w, float)
    theta = np.linalg.norm(w)
    if theta < 1e-12:
        return np.eye(3) + skew(w)
    k = w / theta
    K = skew(k)
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def log_so3(R: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of a rotation matrix; robust near 0 and pi."""
    cos_theta = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_theta)
    if theta < 1e-7:
        return np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    if np.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes; take the axis from the symmetric part.
        B = (R + np.eye(3)) / 2.0
        i = int(np.argmax(np.diag(B)))
        axis = B[:, i] / np.sqrt(max(B[i, i], 1e-300))
        axis /= np.linalg.norm(axis)
        return axis * theta
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return w * theta / (2.0 * np.sin(theta))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Closest rotation matrix (Frobenius norm) to a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rotation_angle_deg(R: np.ndarray) -> float:
    """Angle of a rotation matrix in degrees."""
    return float(np.degrees(np.linalg.norm(log_so3(R))))


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(translation error in m, rotation error in deg) between two poses of the same frame pair."""
    dt = float(np.linalg.norm(T_est[:3, 3] - T_true[:3, 3]))
    dR = rotation_angle_deg(T_est[:3, :3].T @ T_true[:3, :3])
    return dt, dR


def quat_xyzw_to_R(q_xyzw) -> np.ndarray:
    """Rotation matrix from a quaternion (x, y, z, w); the quaternion is normalised first."""
    x, y, z, w = np.asarray(q_xyzw, float) / np.linalg.norm(q_xyzw)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def R_to_quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) with w >= 0 from a rotation matrix."""
    m = R
    tr = np.trace(m)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def look_at(eye_m, target_m, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of an OpenCV camera (x right, y down, z forward) at ``eye`` looking at ``target``."""
    eye = np.asarray(eye_m, float)
    z = np.asarray(target_m, float) - eye
    z /= np.linalg.norm(z)
    up = np.asarray(up, float)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.column_stack([x, y, z]), eye)


def board_facing(eye_m, centre_m, tilt_rotvec=(0.0, 0.0, 0.0), roll_rad: float = 0.0, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_base_board`` of a board at ``centre_m`` whose printed face (-z) looks at ``eye_m``.

    Unperturbed, board z points from the eye to the centre and board x is horizontal (x = z × up,
    as :func:`look_at` builds a camera): the sheet hangs upright, y pointing down. The board is
    then tilted by ``tilt_rotvec`` (rotation vector in board axes, rad) and turned by ``roll_rad``
    about its own z. The board frame's origin is placed at ``centre_m``: to centre the pattern
    rather than its first point, right-multiply by ``make_T(np.eye(3), -centre_board_m)``.
    """
    R = look_at(eye_m, centre_m, up)[:3, :3] @ exp_so3(tilt_rotvec) @ exp_so3([0.0, 0.0, roll_rad])
    return make_T(R, centre_m)


def check_pose(T, what: str, tol: float = 1e-4) -> np.ndarray:
    """Validate a 4x4 rigid transform; raise InputError naming ``what`` if it is not one.

    Accepts near-orthonormal rotations (as read from text files with few digits) and returns
    the pose with its rotation re-orthonormalised.
    """
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4):
        raise InputError(f"{what}: expected a 4x4 pose matrix, got shape {T.shape}.")
    if not np.all(np.isfinite(T)):
        raise InputError(f"{what}: pose contains NaN or infinite values; re-record or drop this capture.")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise InputError(f"{what}: last row of the pose must be [0, 0, 0, 1], got {T[3].tolist()}.")
    R = T[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    if err > tol or np.linalg.det(R) < 0:
        raise InputError(
            f"{what}: rotation is not orthonormal (|R^T R - I| = {err:.2e}, det = {np.linalg.det(R):.3f}); "
            "check the pose units and the quaternion order (calibgraph reads x, y, z, w)."
        )
    return make_T(project_to_so3(R), T[:3, 3])
