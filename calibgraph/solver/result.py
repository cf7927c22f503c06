"""What the solver returns, and its JSON/YAML form.

``result.json`` schema (``calibgraph-result/1``), all poses 4x4 row-major, metres:

- ``frame_convention``: text; ``T_a_b`` maps points from frame b to frame a.
- ``mode``: 'eye_to_hand' | 'eye_in_hand'; ``method``: 'joint' | 'single'.
- ``T_flange_board`` (eye-to-hand, joint) or ``T_base_board`` (eye-in-hand, joint).
- ``cameras.<name>``: ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand),
  ``sigma_translation_mm`` (3, base/flange axes), ``sigma_rotation_deg`` (3, same axes),
  ``covariance`` (6x6, rotation first, rad and m, perturbation expressed in the reference frame
  axes: rotation vector of ``R_est R_true^T`` and camera-centre offset), ``reprojection_rms_px``,
  ``reprojection_max_px``, ``views_used``, ``views_rejected`` (list of {capture, reason}),
  ``corners_used``, ``corners_rejected``, ``intrinsics`` (K, dist, width_px, height_px used);
  ``moved`` when the camera moved during capture (the pose above is the one after the move):
  ``capture`` (first capture after it), ``last_capture_before``, ``views_before``/``views_after``,
  ``displacement_mm``, ``sigma_displacement_mm``, ``rotation_deg``, ``f_stat``, ``T_base_cam_before``
  (``T_flange_cam_before``; null when too few views to solve it), ``covariance_before`` and its sigmas;
  in 'single' mode also the camera's own board mount.
- ``camera_pairs.<a>__<b>``: ``T_a_b`` with its ``sigma_translation_mm`` / ``sigma_rotation_deg``
  and ``covariance`` (6x6, rotation first, in frame a's axes).
- ``board_mount``: covariance and sigmas of the board mount.
- ``solver``: converged, iterations, final cost, pixel sigma used, time, settings.
- ``robot`` (with kinematics='joint-offsets'): ``joint_offsets_rad`` (n; physical angle = reported +
  offset), ``joint_offsets_sigma_rad`` (None for fixed joints), ``fixed`` ({joint, reason}),
  ``estimated``, ``offset_correlations``, ``strongest_correlations`` (each offset's largest
  correlation with a camera pose, the mount or the board scale), ``model``, ``staging``.
- ``residuals.<camera>.<capture>``: ``ids``, ``uv_detected_px`` (N,2), ``residual_px`` (N,2) =
  reprojected - detected, ``rejected`` (whole view), ``corner_rejected`` (N,) booleans.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.problem import mode_frames
from calibgraph.core.version import __version__
from calibgraph.io.files import atomic_write_text

FRAME_CONVENTION = (
    "T_a_b maps points from frame b to frame a: p_a = T_a_b @ p_b (4x4 homogeneous, metres). "
    "Camera frames are OpenCV optical frames (x right, y down, z forward). Covariances are 6x6, "
    "rotation first (rad) then translation (m), perturbations expressed in the axes of the "
    "reference frame named first in the pose (base for T_base_cam, flange for T_flange_cam)."
)


def sigmas_from_cov(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sigma_translation_mm (3,), sigma_rotation_deg (3,)) from a rotation-first 6x6 covariance
    (NaN for none: a camera that was not calibrated)."""
    if cov is None:
        return np.full(3, np.nan), np.full(3, np.nan)
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    return d[3:] * 1e3, np.degrees(d[:3])


@dataclass(frozen=True)
class RejectedView:
    camera: str
    capture: int
    reason: str


@dataclass(frozen=True)
class CameraResult:
    """Calibration of one camera.

    ``T_ref_cam`` is ``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand); ``ref_frame``
    says which ('base' or 'flange').
    """

    name: str
    ref_frame: str
    T_ref_cam: np.ndarray
    covariance: np.ndarray
    reprojection_rms_px: float
    reprojection_max_px: float
    views_used: int
    views_rejected: tuple = ()
    corners_used: int = 0
    corners_rejected: int = 0
    T_mount_board: np.ndarray | None = None  # own board mount in 'single' mode
    intrinsics: dict | None = None  # Intrinsics.to_dict() of the camera the result was solved with
    # within-view correlated corner noise (solver.batch.ModeRatio.to_dict()), when it was estimated
    corner_noise: dict | None = None
    # what the 1-sigma is made of (solver.budget): sigma_translation_norm_mm, shares by source, advice
    error_budget: dict | None = None
    # False when too few of its views survived rejection: no pose and no covariance then, ``why`` says why
    calibrated: bool = True
    why: str = ""
    # a camera that moved during capture (solver.moved): capture (the first after the move),
    # last_capture_before, views_before, views_after, displacement_mm, sigma_displacement_mm,
    # rotation_deg, f_stat, T_before (4x4, the pose before; None when too few views to solve it),
    # covariance_before (6x6, as ``covariance``); None when it did not move
    moved: dict | None = None
    # capture -> {"ids" (N,), "uv_detected_px" (N,2), "residual_px" (N,2), "weight" (N,), "rejected" bool}
    residuals_px: dict = field(default_factory=dict, repr=False)

    @property
    def sigma_translation_mm(self) -> np.ndarray:
        return sigmas_from_cov(self.covariance)[0]

    @property
    def sigma_rotation_deg(self) -> np.ndarray:
        return sigmas_from_cov(self.covariance)[1]

    @property
    def T_base_cam(self) -> np.ndarray:
        if self.ref_frame != "base":
            raise AttributeError("eye-in-hand result: use T_flange_cam")
        return self.T_ref_cam

    @property
    def T_flange_cam(self) -> np.ndarray:
        if self.ref_frame != "flange":
            raise AttributeError("eye-to-hand result: use T_base_cam")
        return self.T_ref_cam


@dataclass(frozen=True)
class PairResult:
    a: str
    b: str
    T_a_b: np.ndarray
    covariance: np.ndarray

    @property
    def sigma_translation_mm(self):
        return sigmas_from_cov(self.covariance)[0]

    @property
    def sigma_rotation_deg(self):
        return sigmas_from_cov(self.covariance)[1]


@dataclass(frozen=True)
class Result:
    """Solver output. ``T_mount_board`` is ``T_flange_board`` (eye-to-hand) or ``T_base_board``
    (eye-in-hand); None in 'single' mode (each camera then carries its own)."""

    mode: str
    method: str
    cameras: dict
    T_mount_board: np.ndarray | None
    mount_covariance: np.ndarray | None
    pairs: dict
    converged: bool
    iterations: int
    final_cost: float
    pixel_sigma_px: float
    solve_time_s: float
    rejected_views: tuple = ()
    rejected_corners: tuple = ()  # (camera, capture, corner id, residual px)
    T_base_flange_est: dict = field(default_factory=dict, repr=False)  # capture -> refined flange pose
    settings: dict = field(default_factory=dict)
    dataset: str = ""
    board_scale: float = 1.0  # estimated scale of the printed board against its spec (1 when not estimated)
    board_scale_sigma: float | None = None  # its 1-sigma (None when not estimated)
    notes: tuple = ()  # what the solver noticed and did, one line each (inadequate intrinsics, board scale)
    robot: dict | None = None  # estimated joint offsets (kinematics='joint-offsets'), see the module docstring
    fk_noise: dict | None = None  # the FK prior against the fit (solver.batch.FkRatio.to_dict())

    @property
    def calibrated(self) -> dict:
        """The cameras that were calibrated (name -> CameraResult)."""
        return {n: c for n, c in self.cameras.items() if c.calibrated}

    @property
    def not_calibrated(self) -> dict:
        """name -> why, for the cameras too few of whose views survived rejection."""
        return {n: c.why for n, c in self.cameras.items() if not c.calibrated}

    @property
    def T_flange_board(self):
        return self.T_mount_board if self.mode == "eye_to_hand" else None

    @property
    def T_base_board(self):
        return self.T_mount_board if self.mode == "eye_in_hand" else None

    # -- serialisation --------------------------------------------------------------------------
    def to_dict(self) -> dict:

        frames = mode_frames(self.mode)
        ref_key, mount_key = frames.camera_key, frames.board_key
        cams = {}
        for name, c in self.cameras.items():
            if not c.calibrated:
                cams[name] = {"calibrated": False, "why": c.why, "views_used": c.views_used,
                              "views_rejected": [{"capture": v.capture, "reason": v.reason} for v in c.views_rejected]}
                if c.moved is not None:
                    cams[name]["moved"] = moved_to_dict(c.moved, ref_key)
                continue
            st, sr = sigmas_from_cov(c.covariance)
            cams[name] = {
                "calibrated": True,
                ref_key: c.T_ref_cam.tolist(),
                "sigma_translation_mm": st.tolist(),
                "sigma_rotation_deg": sr.tolist(),
                "covariance": c.covariance.tolist(),
                "reprojection_rms_px": c.reprojection_rms_px,
                "reprojection_max_px": c.reprojection_max_px,
                "views_used": c.views_used,
                "views_rejected": [{"capture": v.capture, "reason": v.reason} for v in c.views_rejected],
                "corners_used": c.corners_used,
                "corners_rejected": c.corners_rejected,
            }
            if c.T_mount_board is not None:
                cams[name][mount_key] = c.T_mount_board.tolist()
            if c.intrinsics is not None:
                cams[name]["intrinsics"] = c.intrinsics
            if c.corner_noise is not None:
                cams[name]["corner_noise"] = c.corner_noise
            if c.error_budget is not None:
                cams[name]["error_budget"] = c.error_budget
            if c.moved is not None:
                cams[name]["moved"] = moved_to_dict(c.moved, ref_key)
        pairs = {}
        for (a, b), p in self.pairs.items():
            st, sr = sigmas_from_cov(p.covariance)
            pairs[f"{a}__{b}"] = {
                f"T_{a}_{b}": p.T_a_b.tolist(),
                "a": a,
                "b": b,
                "sigma_translation_mm": st.tolist(),
                "sigma_rotation_deg": sr.tolist(),
                "covariance": p.covariance.tolist(),
            }
        d = {
            "format": RESULT_FORMAT,
            "calibgraph_version": __version__,
            "frame_convention": FRAME_CONVENTION,
            "mode": self.mode,
            "method": self.method,
            "dataset": self.dataset,
            "cameras": cams,
            "camera_pairs": pairs,
            "solver": {
                "converged": self.converged,
                "iterations": self.iterations,
                "final_cost": self.final_cost,
                "pixel_sigma_px": self.pixel_sigma_px,
                "solve_time_s": self.solve_time_s,
                "settings": self.settings,
            },
            "board_scale": {"scale": self.board_scale, "sigma": self.board_scale_sigma},
            "notes": list(self.notes),
            **({"fk_noise": self.fk_noise} if self.fk_noise is not None else {}),
            **({"robot": self.robot} if self.robot is not None else {}),
            "rejected_corners": [
                {"camera": c, "capture": k, "id": i, "residual_px": r} for (c, k, i, r) in self.rejected_corners
            ],
            "robot_flange_poses_refined": {str(k): T.tolist() for k, T in self.T_base_flange_est.items()},
            "residuals": {
                name: {
                    str(k): {
                        "ids": np.asarray(r["ids"]).astype(int).tolist(),
                        "uv_detected_px": np.round(np.asarray(r["uv_detected_px"]), 4).tolist(),
                        "residual_px": np.round(np.asarray(r["residual_px"]), 5).tolist(),
                        "rejected": bool(r["rejected"]),
                        "corner_rejected": (np.asarray(r["weight"]) == 0).tolist(),
                    }
                    for k, r in c.residuals_px.items()
                }
                for name, c in self.cameras.items() if c.calibrated
            },
        }
        if self.T_mount_board is not None:
            d[mount_key] = self.T_mount_board.tolist()
            if self.mount_covariance is not None:
                st, sr = sigmas_from_cov(self.mount_covariance)
                d["board_mount"] = {
                    "covariance": self.mount_covariance.tolist(),
                    "sigma_translation_mm": st.tolist(),
                    "sigma_rotation_deg": sr.tolist(),
                }
        return d

    def save(self, path) -> Path:
        """Write ``.json`` or ``.yaml``/``.yml`` (by extension) atomically."""
        p = Path(path)
        d = self.to_dict()
        if p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            text = yaml.safe_dump(d, sort_keys=False)
        else:
            text = json.dumps(d, indent=2)
        atomic_write_text(p, text)
        return p


RESULT_FORMAT = "calibgraph-result/1"


def moved_to_dict(moved: dict, ref_key: str) -> dict:
    """``cameras.<name>.moved`` of result.json: ``T_before`` named as the pose is (``T_base_cam_before``)."""
    out = {k: v.item() if isinstance(v, np.generic) else v for k, v in moved.items()
           if k not in ("T_before", "covariance_before")}
    T, cov = moved.get("T_before"), moved.get("covariance_before")
    out[f"{ref_key}_before"] = None if T is None else np.asarray(T).tolist()
    out["covariance_before"] = None if cov is None else np.asarray(cov).tolist()
    if T is not None and cov is not None:
        st, sr = sigmas_from_cov(np.asarray(cov))
        out["sigma_translation_mm_before"], out["sigma_rotation_deg_before"] = st.tolist(), sr.tolist()
    return out


def load_result_dict(path) -> dict:
    """Read a result.json / result.yaml written by :meth:`Result.save`."""

    p = Path(path)
    try:
        text = p.read_text()
    except OSError as e:
        raise InputError(f"{p}: cannot read result: {e}") from None
    try:
        if p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            d = yaml.safe_load(text)
        else:
            d = json.loads(text)
    except Exception as e:  # noqa: BLE001 - any parse error becomes one clear line
        raise InputError(f"{p}: not a calibgraph result file ({e}).") from None
    if not isinstance(d, dict) or "cameras" not in d or "mode" not in d:
        raise InputError(f"{p}: not a calibgraph result file (no 'cameras'/'mode').")
    fmt = str(d.get("format", RESULT_FORMAT))
    if fmt != RESULT_FORMAT:
        if fmt.startswith("calibgraph-result/"):
            raise InputError(f"{p}: result format {fmt!r} is newer than this calibgraph "
                             f"({d.get('calibgraph_version', '?')} wrote it) reads ({RESULT_FORMAT}); upgrade calibgraph.")
        raise InputError(f"{p}: format {fmt!r} is not a calibgraph result ({RESULT_FORMAT}).")
    return d
