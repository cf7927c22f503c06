"""Observability checks: refuse motions that leave a parameter undetermined, with advice.

Before solving (cheap, on the robot poses): every camera needs enough views; the board mount
needs rotations about at least two distinct axes (a single rotation axis leaves the translation
along it unobservable; pure translation leaves the mount's rotation-translation coupling and
every camera's translation undetermined). In 'single' mode each camera must satisfy that on its
own views; in 'joint' mode the union of views determines the shared mount, and a camera then
needs only enough views of its own.

After solving: a camera whose marginal 1-sigma is enormous is reported, named, with the weakest
direction, instead of a singular-matrix traceback.
"""

from __future__ import annotations

import numpy as np

from calibgraph.core.errors import ObservabilityError
from calibgraph.solver.terms.initialise import rotation_spread_deg

MIN_ROTATION_DEG = 2.0
MIN_SECOND_AXIS_DEG = 1.0
MAX_SIGMA_TRANSLATION_M = 0.5
MAX_SIGMA_ROTATION_RAD = np.radians(20.0)


def _motion_problem(A_list) -> str | None:
    s1, s2 = rotation_spread_deg(A_list)
    if s1 < MIN_ROTATION_DEG:
        return (f"the robot poses barely rotate the board (spread {s1:.2f} deg): pure translation leaves the "
                "board mount and the camera translation unobservable; add poses that tilt the flange by "
                "15-40 deg about at least two different axes")
    if s2 < MIN_SECOND_AXIS_DEG:
        return (f"the robot poses rotate about a single axis only (spread {s1:.1f} deg about it, {s2:.2f} deg "
                "about any other): the translation along that axis is unobservable; add poses that tilt the "
                "flange about a second, different axis")
    return None


def too_few_views(n: int, need: int, frame_word: str = "board", detected: int | None = None) -> str:
    """Why ``n`` usable views cannot calibrate a camera ('' when they can), worded to follow 'camera X '
    (``detected``: its detections, usable or not, when more than ``n``)."""
    if n == 0 and detected:
        return (f"has none of its {detected} view(s) of the {frame_word} usable (too few corners, or no pose "
                "explains them: corners degenerate or ids wrong); check its detections and intrinsics.")
    if n == 0:
        return (f"never saw the {frame_word} (0 usable detections): check it is connected and pointed at the "
                "workspace, add poses that present the board to it, or remove it from the dataset.")
    if n < need:
        return (f"saw the {frame_word} in {n} capture(s)" + (f" ({detected - n} more view(s) unusable)" if detected
                                                             and detected > n else "")
                + f"; at least {need} with varied tilt are needed.")
    return ""


def check_before_solve(problem, views_by_cam: dict, frame_word: str = "board") -> None:
    """Raise ObservabilityError naming the camera and the missing motion.

    views_by_cam: camera name -> list of capture indices with a usable detection.
    """
    opts = problem.options
    caps = problem.capture_by_index
    detected = {}
    for d in problem.detections:
        detected[d.camera] = detected.get(d.camera, 0) + 1
    for name in problem.cameras:
        n = len(views_by_cam.get(name, []))
        why = too_few_views(n, opts.min_views_per_camera, frame_word, detected.get(name, 0))
        if why:
            raise ObservabilityError(f"camera {name!r} {why}", camera=name)
    if problem.method == "single":
        for name, idx in views_by_cam.items():
            msg = _motion_problem([caps[k].T_base_flange for k in idx])
            if msg:
                raise ObservabilityError(f"camera {name!r}: {msg}.")
    else:
        all_idx = sorted({k for idx in views_by_cam.values() for k in idx})
        msg = _motion_problem([caps[k].T_base_flange for k in all_idx])
        if msg:
            raise ObservabilityError(f"board mount: {msg}.")


def check_after_solve(name: str, cov: np.ndarray, what: str = "camera") -> None:
    """Raise if a 6x6 (rotation-first) marginal is too wide to be a calibration."""
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    if not np.all(np.isfinite(d)) or d[3:].max() > MAX_SIGMA_TRANSLATION_M or d[:3].max() > MAX_SIGMA_ROTATION_RAD:
        w, V = np.linalg.eigh(cov[3:, 3:])
        axis = V[:, -1]
        raise ObservabilityError(
            f"{what} {name!r} is not determined by the data: 1-sigma up to {d[3:].max() * 1e3:.0f} mm / "
            f"{np.degrees(d[:3].max()):.1f} deg, weakest along base axis {np.round(axis, 2).tolist()}; add views of it "
            "with the board tilted about different axes and at different positions."
        )
