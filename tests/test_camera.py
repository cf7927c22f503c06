import cv2
import numpy as np

from calibgraph.core.camera import Intrinsics


def test_projection_matches_opencv_and_jacobian_is_exact():
    rng = np.random.default_rng(0)
    intr = Intrinsics(K=np.array([[900, 0.0, 640], [0, 905, 400], [0, 0, 1.0]]),
                      dist=np.array([0.1, -0.2, 0.001, -0.002, 0.05, 0.01, 0.02, -0.01]), width_px=1280, height_px=800)
    P = rng.uniform(-0.5, 0.5, size=(50, 3)) + [0, 0, 2.0]
    uv, J = intr.project(P, with_jacobian=True)
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), intr.K, intr.dist)
    assert np.abs(uv - ref[:, 0]).max() < 1e-9
    eps = 1e-6
    Jn = np.stack([(intr.project(P + eps * e) - intr.project(P - eps * e)) / (2 * eps) for e in np.eye(3)], -1)
    assert np.abs(J - Jn).max() < 1e-5


def test_skew_term_in_jacobian():
    # OpenCV's projectPoints ignores skew; our model keeps it, so check it against finite differences only.
    intr = Intrinsics(K=np.array([[900, 2.0, 640], [0, 905, 400], [0, 0, 1.0]]), dist=np.array([0.1, -0.2, 0, 0, 0]))
    P = np.array([[0.1, -0.2, 1.5], [0.3, 0.2, 2.0]])
    uv, J = intr.project(P, with_jacobian=True)
    eps = 1e-6
    Jn = np.stack([(intr.project(P + eps * e) - intr.project(P - eps * e)) / (2 * eps) for e in np.eye(3)], -1)
    assert np.abs(J - Jn).max() < 1e-5
