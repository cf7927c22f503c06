"""A simulated close-range intrinsics session: hand-held images of the board, per camera, with truth.

:func:`simulate_intrinsics_session` writes what ``calibgraph intrinsics`` reads::

    SESSION/target.yaml                 target: {kind, rows, cols, pitch_m}
    SESSION/<camera>/view_000.png ...   N images of the board at 0.3-0.8 m, tilted, spread over the image
    SESSION/ground_truth.json           per camera: the true intrinsics and every image's T_cam_board

Poses come from :func:`calibgraph.solver.camera.session_plan.session_poses` drawn at random (the
corner and edge views first). Images are rendered by :func:`calibgraph.sim.board_image.render_view`
(the planar board through the full camera model, distortion included, 4x4 sub-pixel samples; no
OpenGL needed), then degraded by the simulator's sensor model (:func:`calibgraph.sim.render.degrade`:
exposure, defocus and motion blur, read and shot noise) with the exposure varied per image as a
hand-held session's auto-exposure does. ``render`` may replace the renderer (same signature as
``render_view`` for a noise-free image).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.io.files import atomic_write_png, atomic_write_text, output_folder, read_input_bytes
from calibgraph.sim.board_image import render_view
from calibgraph.sim.render import degrade
from calibgraph.sim.workcell import Realism
from calibgraph.solver.camera.session_plan import session_poses

TRUTH_FORMAT = "calibgraph-intrinsics-session-truth/1"
EXPOSURE_RANGE = (0.8, 1.15)  # per-image gain of a hand-held session's auto-exposure


@dataclass(frozen=True)
class SessionTruth:
    """What a simulated session was made of: ``intrinsics`` (camera -> true :class:`Intrinsics`),
    ``T_cam_board`` (camera -> image file name -> (4, 4) pose), ``folder`` (the session)."""

    folder: Path
    intrinsics: dict
    T_cam_board: dict


def render_session_image(target: Target, intr: Intrinsics, T_cam_board: np.ndarray, realism: Realism, rng,
                         render=render_view) -> np.ndarray:
    """One (H, W) uint8 session image: the board rendered noise-free (16-bit, so the sensor model
    quantises once), then degraded with ``realism`` at a random exposure in ``EXPOSURE_RANGE``."""
    view = render(target, intr, T_cam_board, bit_depth=16, seed=None)
    ideal = view.image.astype(np.float32) / 257.0
    gain = float(rng.uniform(*EXPOSURE_RANGE))
    return degrade(ideal, replace(realism, exposure=realism.exposure * gain, distortion=False), rng)


def simulate_intrinsics_session(out_dir, cameras: dict, target: Target, n_views: int = 25,
                                distance_range_m=(0.3, 0.8), realism: Realism | None = None, seed: int = 0,
                                progress=None, render=render_view) -> SessionTruth:
    """Write a simulated close-range session for every camera (module docstring).

    Args:
        out_dir: a new (or empty) folder.
        cameras: camera name -> its TRUE :class:`Intrinsics` (image size, K, distortion).
        target: the board.
        n_views: images per camera.
        distance_range_m: board distances (to the pattern's centre).
        realism: the sensor model (default: the simulator's, ``Realism()``).
        seed: seeds the poses, exposures and noise.
        progress: optional callable(str) told of each camera.
        render: the noise-free renderer (``render_view``'s signature).
    Returns:
        :class:`SessionTruth`.
    """
    out = output_folder(out_dir, "session folder", empty=True)
    if not cameras:
        raise InputError("simulate_intrinsics_session: no cameras given.")
    if n_views < 1:
        raise InputError(f"simulate_intrinsics_session: n_views must be >= 1, got {n_views}.")
    realism = realism or Realism()
    rng = np.random.default_rng(seed)
    import yaml

    atomic_write_text(out / "target.yaml", "# the board of this simulated intrinsics session\n"
                      + yaml.safe_dump({"target": target.to_dict()}, sort_keys=False))
    poses_by_cam = {}
    for name, intr in cameras.items():
        if intr.width_px <= 0 or intr.height_px <= 0:
            raise InputError(f"simulate_intrinsics_session: camera {name!r} needs its image size.")
        if progress:
            progress(f"{name}: rendering {n_views} images ({intr.width_px}x{intr.height_px})")
        poses = session_poses(intr, target, n_views, distance_range_m, rng=rng)
        poses_by_cam[name] = {}
        for k, T in enumerate(poses):
            img = render_session_image(target, intr, T, realism, rng, render)
            fname = f"view_{k:03d}.png"
            atomic_write_png(out / name / fname, img)
            poses_by_cam[name][fname] = T
    gt = {"format": TRUTH_FORMAT,
          "frame_convention": "T_cam_board maps board-frame points into the OpenCV camera frame",
          "target": target.to_dict(),
          "realism": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(realism).items()},
          "exposure_range": list(EXPOSURE_RANGE), "seed": int(seed),
          "cameras": {n: {"intrinsics": cameras[n].to_dict(),
                          "T_cam_board": {f: T.tolist() for f, T in poses_by_cam[n].items()}} for n in cameras}}
    atomic_write_text(out / "ground_truth.json", json.dumps(gt, indent=1))
    return SessionTruth(folder=out, intrinsics=dict(cameras), T_cam_board=poses_by_cam)


def load_session_truth(folder) -> SessionTruth:
    """The :class:`SessionTruth` of a session written by :func:`simulate_intrinsics_session`."""
    p = Path(folder) / "ground_truth.json"
    try:
        d = json.loads(read_input_bytes(p, "session ground truth"))
    except (OSError, ValueError) as e:
        raise InputError(f"{p}: cannot read the session's ground truth: {e}") from None
    if d.get("format") != TRUTH_FORMAT:
        raise InputError(f"{p}: not a simulated intrinsics session's ground truth (format {d.get('format')!r}).")
    cams = d["cameras"]
    return SessionTruth(folder=Path(folder), intrinsics={n: Intrinsics.from_dict(c["intrinsics"]) for n, c in cams.items()},
                        T_cam_board={n: {f: np.asarray(T, float) for f, T in c["T_cam_board"].items()}
                                     for n, c in cams.items()})
