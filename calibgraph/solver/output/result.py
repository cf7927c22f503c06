"""What the solver returns, and its file form: ``Result.save(path)`` and ``load_result(path)``
round-trip it exactly (every number, array and note), in JSON or YAML.

``result.json`` schema (``calibgraph-result/1``), all poses 4x4 row-major, metres:

- ``format``, ``calibgraph_version`` (the version that solved), ``frame_convention``: text;
  ``T_a_b`` maps points from frame b to frame a.
- ``mode``: 'eye_to_hand' | 'eye_in_hand'; ``method``: 'joint' | 'single'; ``dataset``: where the
  data came from; ``target``: the target spec (kind, rows, cols, pitch_m, ...) when it was known.
- ``T_flange_board`` (eye-to-hand, joint) or ``T_base_board`` (eye-in-hand, joint).
- ``cameras.<name>``: ``calibrated`` (false: too few of its views survived rejection; then only
  ``why``, ``views_used`` and ``views_rejected`` follow), ``T_base_cam`` (eye-to-hand) or
  ``T_flange_cam`` (eye-in-hand),
  ``sigma_translation_mm`` (3, base/flange axes), ``sigma_rotation_deg`` (3, same axes),
  ``covariance`` (6x6, rotation first, rad and m, perturbation expressed in the reference frame
  axes: rotation vector of ``R_est R_true^T`` and camera-centre offset), ``reprojection_rms_px``,
  ``reprojection_max_px``, ``pixel_sigma_px`` (the a posteriori sigma of its corners, px per
  axis: each camera's own), ``views_used``, ``views_rejected`` (list of {capture, reason}),
  ``corners_used``, ``corners_rejected``, ``prediction`` (the expected error of a new pose's corners
  predicted from its reported FK, :mod:`calibgraph.solver.uncertainty.prediction`), ``intrinsics`` (K, dist, width_px, height_px used; their
  provenance ``source_given``, ``source_stated``, ``source_used``; with ``prior_sigma``, ``sigma`` and
  ``given`` when they were estimated), ``corner_noise``, ``error_budget`` (what the
  1-sigma is made of); ``moved`` when the camera moved during capture (the pose above is the one
  after the move): ``capture`` (first capture after it), ``last_capture_before``,
  ``views_before``/``views_after``, ``displacement_mm``, ``sigma_displacement_mm``, ``rotation_deg``,
  ``f_stat``, ``T_base_cam_before`` (``T_flange_cam_before``; null when too few views to solve it),
  ``covariance_before`` and its sigmas; in 'single' mode also the camera's own board mount.
- ``camera_pairs.<a>__<b>``: ``a``, ``b``, ``T_<a>_<b>`` with its ``sigma_translation_mm`` /
  ``sigma_rotation_deg`` and ``covariance`` (6x6, rotation first, in frame a's axes).
- ``board_mount``: covariance and sigmas of the board mount.
- ``board_scale``: {scale, sigma} of the printed board against its spec (sigma null: not estimated).
- ``solver``: converged, iterations, final cost, pixel sigma used, time, settings (the options;
  ``intrinsics_source_default``, the source of cameras whose intrinsics state none).
- ``notes``: what the solver noticed and did, one line each; ``note_cameras``: per note, the camera
  it concerns (null: the whole cell), for readers (derived from the notes, which name their camera
  first; not read back).
- ``fk_noise``: the stated FK accuracy against the fit, when it was checked.
- ``robot`` (with kinematics='joint-offsets'): ``joint_offsets_rad`` (n; physical angle = reported +
  offset), ``joint_offsets_sigma_rad`` (None for fixed joints), ``fixed`` ({joint, reason}),
  ``estimated``, ``offset_correlations``, ``strongest_correlations`` (each offset's largest
  correlation with a camera pose, the mount or the board scale), ``model``, ``staging``.
- ``rejected_views``: [{camera, capture, reason}] (the cameras' ``views_rejected`` together);
  ``rejected_corners``: [{camera, capture, id, residual_px}].
- ``robot_flange_poses_refined.<capture>``: the estimated ``T_base_flange`` of each capture.
- ``residuals.<camera>.<capture>``: ``ids``, ``uv_detected_px`` (N,2), ``residual_px`` (N,2) =
  reprojected - detected, ``weight`` (N,) the robust loss's weight of each corner, ``rejected``
  (whole view), ``corner_rejected`` (N,) booleans (weight 0).

Files written by earlier calibgraph versions lack some of these keys; they load with the defaults
of the fields (no residuals, no intrinsics, scale 1, no notes). A file of another tool or of a
newer format is refused in one line.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.core.problem import MODES, mode_frames
from calibgraph.core.targets import Target
from calibgraph.core.version import __version__, format_age
from calibgraph.io.files import atomic_write_text, read_input_bytes, read_yaml
from calibgraph.solver.output.result_values import (
    exactly_equal,
    floats,
    floats_or_none,
    mapping,
    matrix,
    number_or,
    plain_json,
    pose_matrix,
    residual_from_dict,
    residual_record,
    section,
    set_fields,
)

RESULT_FORMAT = "calibgraph-result/1"

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
    says which ('base' or 'flange'). The free-form sections (``intrinsics``, ``corner_noise``) hold
    plain JSON values, so the camera equals itself read back from its file.
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
    # within-view correlated corner noise (the solver's ModeRatio.to_dict()), when it was estimated
    corner_noise: dict | None = None
    # what the 1-sigma is made of (solver.uncertainty.budget): sigma_translation_norm_mm, shares by source, advice
    error_budget: dict | None = None
    # False when too few of its views survived rejection: no pose and no covariance then, ``why`` says why
    calibrated: bool = True
    why: str = ""
    # a camera that moved during capture (solver.changes.moved): capture (the first after the move),
    # last_capture_before, views_before, views_after, displacement_mm, sigma_displacement_mm,
    # rotation_deg, f_stat, T_before (4x4, the pose before; None when too few views to solve it),
    # covariance_before (6x6, as ``covariance``); None when it did not move
    moved: dict | None = None
    # the a posteriori sigma of this camera's corners (px, per axis): cameras differ in corner noise
    pixel_sigma_px: float | None = None
    # capture -> {"ids" (N,), "uv_detected_px" (N,2), "residual_px" (N,2), "weight" (N,), "rejected" bool}
    residuals_px: dict = field(default_factory=dict, repr=False)
    # the expected error of a new pose's corners predicted from its reported FK (solver.uncertainty.prediction):
    # expected_rms_px, expected_rms_mm, parts_px {robot, calibration, corners}, the FK sigmas used, corners
    prediction: dict | None = None

    def __post_init__(self):
        set_fields(self, T_ref_cam=floats_or_none(self.T_ref_cam), covariance=floats_or_none(self.covariance),
             reprojection_rms_px=float(self.reprojection_rms_px), reprojection_max_px=float(self.reprojection_max_px),
             views_used=int(self.views_used), views_rejected=tuple(self.views_rejected),
             corners_used=int(self.corners_used), corners_rejected=int(self.corners_rejected),
             T_mount_board=floats_or_none(self.T_mount_board),
             intrinsics=plain_json(self.intrinsics), corner_noise=plain_json(self.corner_noise),
             error_budget=plain_json(self.error_budget), calibrated=bool(self.calibrated), why=str(self.why),
             pixel_sigma_px=None if self.pixel_sigma_px is None else float(self.pixel_sigma_px),
             residuals_px={int(k): residual_record(v) for k, v in (self.residuals_px or {}).items()},
             prediction=plain_json(self.prediction))

    def __eq__(self, other):  # exact, arrays included
        return exactly_equal(self, other)

    @property
    def sigma_translation_mm(self) -> np.ndarray:
        return sigmas_from_cov(self.covariance)[0]

    @property
    def sigma_rotation_deg(self) -> np.ndarray:
        return sigmas_from_cov(self.covariance)[1]

    @property
    def solved_intrinsics(self) -> Intrinsics | None:
        """The intrinsics the camera was solved with (the estimate when they were estimated), or
        None in a result written before they were recorded."""
        return None if self.intrinsics is None else Intrinsics.from_dict(self.intrinsics)

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

    def __post_init__(self):
        set_fields(self, T_a_b=floats(self.T_a_b), covariance=floats(self.covariance))

    def __eq__(self, other):
        return exactly_equal(self, other)

    @property
    def sigma_translation_mm(self):
        return sigmas_from_cov(self.covariance)[0]

    @property
    def sigma_rotation_deg(self):
        return sigmas_from_cov(self.covariance)[1]


@dataclass(frozen=True)
class Result:
    """Solver output. ``T_mount_board`` is ``T_flange_board`` (eye-to-hand) or ``T_base_board``
    (eye-in-hand); None in 'single' mode (each camera then carries its own).

    ``Result.save`` writes it; :func:`load_result` (or :meth:`from_dict`) reads it back equal
    (``==`` compares every field exactly, arrays included)."""

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
    fk_noise: dict | None = None  # the FK prior against the fit (the solver's FkRatio.to_dict())
    calibgraph_version: str = __version__  # the version that solved
    target: dict | None = None  # the target spec solved with (Target.to_dict()), when the caller knew it

    def __post_init__(self):
        set_fields(self, T_mount_board=None if self.T_mount_board is None else floats(self.T_mount_board),
             mount_covariance=None if self.mount_covariance is None else floats(self.mount_covariance),
             converged=bool(self.converged), iterations=int(self.iterations), final_cost=float(self.final_cost),
             pixel_sigma_px=float(self.pixel_sigma_px), solve_time_s=float(self.solve_time_s),
             rejected_views=tuple(RejectedView(str(v.camera), int(v.capture), str(v.reason))
                                  for v in self.rejected_views),
             rejected_corners=tuple((str(c), int(k), int(i), float(r)) for c, k, i, r in self.rejected_corners),
             T_base_flange_est={int(k): floats(T) for k, T in (self.T_base_flange_est or {}).items()},
             settings=plain_json(dict(self.settings or {})), dataset=str(self.dataset or ""),
             board_scale=float(self.board_scale),
             board_scale_sigma=None if self.board_scale_sigma is None else float(self.board_scale_sigma),
             notes=tuple(str(n) for n in self.notes), robot=plain_json(self.robot), fk_noise=plain_json(self.fk_noise),
             calibgraph_version=str(self.calibgraph_version), target=plain_json(self.target))

    def __eq__(self, other):
        return exactly_equal(self, other)

    @property
    def calibrated(self) -> dict:
        """The cameras that were calibrated (name -> CameraResult)."""
        return {n: c for n, c in self.cameras.items() if c.calibrated}

    @property
    def not_calibrated(self) -> dict:
        """name -> why, for the cameras too few of whose views survived rejection."""
        return {n: c.why for n, c in self.cameras.items() if not c.calibrated}

    @property
    def note_cameras(self) -> tuple:
        """Per note, the camera it concerns, or None for a note on the whole cell (board, robot):
        the solver's notes on one camera begin with 'camera NAME' (:func:`note_camera`)."""
        return tuple(note_camera(n, self.cameras) for n in self.notes)

    def camera_notes(self, name: str) -> list:
        """The notes that concern camera ``name``."""
        return [n for n, c in zip(self.notes, self.note_cameras) if c == name]

    @property
    def cell_notes(self) -> list:
        """The notes on the whole cell (no one camera's)."""
        return [n for n, c in zip(self.notes, self.note_cameras) if c is None]

    @property
    def T_flange_board(self):
        return self.T_mount_board if self.mode == "eye_to_hand" else None

    @property
    def T_base_board(self):
        return self.T_mount_board if self.mode == "eye_in_hand" else None

    @property
    def ref_frame(self) -> str:
        """The frame the cameras are calibrated in: 'base' (eye-to-hand) or 'flange' (eye-in-hand)."""
        return mode_frames(self.mode).ref

    # -- serialisation --------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The result as plain JSON data (the file's content, module docstring)."""
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
            if c.pixel_sigma_px is not None:
                cams[name]["pixel_sigma_px"] = c.pixel_sigma_px
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
            if c.prediction is not None:
                cams[name]["prediction"] = c.prediction
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
            "calibgraph_version": self.calibgraph_version,
            "frame_convention": FRAME_CONVENTION,
            "mode": self.mode,
            "method": self.method,
            "dataset": self.dataset,
            **({"target": self.target} if self.target is not None else {}),
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
            "note_cameras": list(self.note_cameras),
            **({"fk_noise": self.fk_noise} if self.fk_noise is not None else {}),
            **({"robot": self.robot} if self.robot is not None else {}),
            "rejected_views": [{"camera": v.camera, "capture": v.capture, "reason": v.reason}
                               for v in self.rejected_views],
            "rejected_corners": [
                {"camera": c, "capture": k, "id": i, "residual_px": r} for (c, k, i, r) in self.rejected_corners
            ],
            "robot_flange_poses_refined": {str(k): T.tolist() for k, T in self.T_base_flange_est.items()},
            "residuals": {
                name: {
                    str(k): {
                        "ids": r["ids"].tolist(),
                        "uv_detected_px": r["uv_detected_px"].tolist(),
                        "residual_px": r["residual_px"].tolist(),
                        "weight": r["weight"].tolist(),
                        "rejected": r["rejected"],
                        "corner_rejected": (r["weight"] == 0).tolist(),
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
        """Write ``.json`` or ``.yaml``/``.yml`` (by extension) atomically; :func:`load_result`
        reads it back equal."""
        p = Path(path)
        d = self.to_dict()
        if p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            dumper = getattr(yaml, "CSafeDumper", yaml.SafeDumper)  # libyaml when present: large results write fast
            text = "# calibgraph result. " + FRAME_CONVENTION + "\n" + yaml.dump(d, Dumper=dumper, sort_keys=False)
        else:
            text = json.dumps(d, indent=2)
        atomic_write_text(p, text)
        return p

    @classmethod
    def from_dict(cls, d: dict, where: str = "result") -> "Result":
        """The Result a result dict (``to_dict``, or a file written by any calibgraph of format
        ``calibgraph-result/1``) describes. Keys an older version did not write take their
        defaults; a foreign or newer format, or a malformed entry, raises :class:`InputError`
        naming ``where`` and the entry."""
        check_result_dict(d, where)
        try:
            return _result_from_dict(d, where)
        except InputError:
            raise
        except (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError) as e:
            raise InputError(f"{where}: not a readable calibgraph result ({type(e).__name__}: {e}).") from None


def as_result(result, where: str = "result") -> Result:
    """``result`` itself when it is a :class:`Result`; a result dict (as :func:`load_result_dict`
    returns) converted with :meth:`Result.from_dict`."""
    if isinstance(result, Result):
        return result
    if isinstance(result, dict):
        return Result.from_dict(result, where)
    raise InputError(f"{where}: expected a calibgraph Result, got {type(result).__name__}.")


RESULT_NAMES = ("result.json", "result.yaml")  # what ``calibgraph solve DATASET`` writes by default, in that order


def result_path(path) -> Path:
    """The result file a user means by ``path``: the file itself, or for a folder (a dataset that
    ``calibgraph solve`` wrote its default ``result.json`` into) the result file in it; a folder with
    none is refused in one line that says how to make one."""
    p = Path(path)
    if not p.is_dir():
        return p
    for name in RESULT_NAMES:
        if (p / name).is_file():
            return p / name
    raise InputError(f"{p}: a folder with no {' or '.join(RESULT_NAMES)} in it: solve it first "
                     f"(calibgraph solve {p}) or give the result file.")


def load_result(path) -> Result:
    """Read a result.json / result.yaml written by :meth:`Result.save` (of this or an earlier
    calibgraph) as a :class:`Result`; anything else is refused in one line (:class:`InputError`)."""
    return Result.from_dict(load_result_dict(path), str(path))


def moved_from_dict(d: dict, ref_key: str, what: str) -> dict:
    """The inverse of :func:`moved_to_dict`: ``T_before`` and ``covariance_before`` as arrays, the
    derived sigmas dropped."""
    d = mapping(d, f"{what}: moved")
    out = {k: v for k, v in d.items() if k not in (f"{ref_key}_before", "covariance_before",
                                                   "sigma_translation_mm_before", "sigma_rotation_deg_before")}
    T, cov = d.get(f"{ref_key}_before"), d.get("covariance_before")
    out["T_before"] = None if T is None else pose_matrix(T, f"{what}: moved {ref_key}_before")
    out["covariance_before"] = None if cov is None else matrix(cov, (6, 6), f"{what}: moved covariance_before")
    return out


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
    """Read a result.json / result.yaml written by :meth:`Result.save` as plain data (its format
    checked; :func:`load_result` gives the :class:`Result`). Only a regular file is read (a FIFO or
    a device would block or never end)."""
    p = result_path(path)
    try:
        text = read_input_bytes(p, "result").decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{p}: not a calibgraph result file (not UTF-8 text).") from None
    try:
        if p.suffix.lower() in (".yaml", ".yml"):
            import yaml

            d = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
        else:
            d = json.loads(text)
    except Exception as e:  # noqa: BLE001 - any parse error becomes one clear line
        raise InputError(f"{p}: not a calibgraph result file ({str(e).splitlines()[0] if str(e) else e!r}).") from None
    check_result_dict(d, str(p))
    return d


def check_result_dict(d, where: str = "result") -> None:
    """Refuse in one line what is not a calibgraph result of a format this version reads."""
    if not isinstance(d, dict) or "cameras" not in d or "mode" not in d:
        raise InputError(f"{where}: not a calibgraph result file (no 'cameras'/'mode').")
    fmt = str(d.get("format", RESULT_FORMAT))
    if fmt != RESULT_FORMAT:
        if fmt.startswith("calibgraph-result/"):
            wrote = f"{d.get('calibgraph_version', '?')} wrote it"
            age = format_age(fmt, RESULT_FORMAT)
            if age == "older":
                raise InputError(f"{where}: result format {fmt!r} is older than the one this calibgraph reads "
                                 f"({RESULT_FORMAT}; {wrote}); solve its dataset again with this calibgraph "
                                 f"(calibgraph solve {d.get('dataset') or 'DATASET'}) for a result it reads.")
            if age == "newer":
                raise InputError(f"{where}: result format {fmt!r} is newer than this calibgraph ({wrote}) reads "
                                 f"({RESULT_FORMAT}); upgrade calibgraph.")
        raise InputError(f"{where}: format {fmt!r} is not a calibgraph result ({RESULT_FORMAT}).")



def note_camera(note: str, names) -> str | None:
    """The camera of ``names`` a solver note concerns: the longest name that follows its opening
    'camera ' and ends there or at a space or colon (so 'cam1' is not 'cam10', and a camera that
    moved keeps the notes its views before the move got as '<name> (before the move)'); None
    for a note on the whole cell."""
    if not note.startswith("camera "):
        return None
    rest = note[len("camera "):]
    hits = [n for n in names if rest.startswith(n) and rest[len(n):len(n) + 1] in ("", " ", ":")]
    return max(hits, key=len) if hits else None


def intrinsics_provenance(camera: CameraResult, settings: dict | None = None) -> dict:
    """Where a camera's intrinsics came from and how they were used: ``{'given', 'stated', 'used'}``
    (``source_given``, ``source_stated``, ``source_used`` of its record). A result written before
    they were recorded gives what its record and ``settings`` imply: the camera's own ``source``, else
    the solver's default; the use from ``estimated`` and ``prior``. Empty strings when unknown."""
    d, settings = camera.intrinsics or {}, settings or {}
    if "source_used" in d:
        return {"given": str(d.get("source_given") or ""), "stated": bool(d.get("source_stated")),
                "used": str(d["source_used"])}
    default = settings.get("intrinsics_source_default", settings.get("intrinsics_source")) or ""
    given = str(d.get("source") or default)
    if not d:
        used = ""
    elif not d.get("estimated"):
        used = "held"
    elif d.get("prior") in ("wide", "unknown"):
        used = "wide" if d["prior"] == "wide" else "own-views"
    else:
        used = "refine" if settings.get("intrinsics") == "estimate" else str(d.get("prior") or "")
    return {"given": given, "stated": bool(d.get("source")), "used": used}


def given_intrinsics_source(camera: CameraResult, settings: dict | None = None) -> str:
    """The source a camera's given intrinsics came with ('factory', 'calibration', 'exact',
    'unknown'; '' when the result does not say), see :func:`intrinsics_provenance`."""
    return intrinsics_provenance(camera, settings)["given"]


def solved_target(result: Result) -> Target | None:
    """The target spec ``result`` was solved with: its ``target`` section, else the spec in the
    ``dataset.yaml`` of the dataset folder it names (when that is still there), else None."""
    try:
        if result.target is not None:
            return Target.from_dict(result.target)
        head = Path(result.dataset) / "dataset.yaml" if result.dataset else None
        if head is not None and head.is_file():
            return Target.from_dict(read_yaml(head, "dataset header")["target"])
    except (CalibgraphError, KeyError, TypeError, ValueError):
        pass  # an unreadable spec is an unknown one
    return None


def target_differences(solved: Target, given: Target) -> list:
    """What differs between the target a result was solved with and a dataset's (kind, rows and
    cols, pitch beyond 0.05 %, marker size and dictionary), one phrase each."""
    out = []
    if solved.kind != given.kind:
        out.append(f"kind {given.kind} instead of {solved.kind}")
    if (solved.rows, solved.cols) != (given.rows, given.cols):
        swapped = (solved.rows, solved.cols) == (given.cols, given.rows)
        out.append(f"{given.rows}x{given.cols} points instead of {solved.rows}x{solved.cols}"
                   + (" (rows and cols swapped)" if swapped else ""))
    if abs(given.pitch_m / solved.pitch_m - 1.0) > 5e-4:
        out.append(f"pitch {given.pitch_m * 1e3:.3f} mm instead of {solved.pitch_m * 1e3:.3f} mm "
                   f"({100 * (given.pitch_m / solved.pitch_m - 1.0):+.2f} %)")
    if solved.kind == given.kind == "charuco":
        if abs(given.marker_m - solved.marker_m) > 5e-4 * solved.marker_m or given.dictionary != solved.dictionary:
            out.append("other ArUco markers (size or dictionary)")
    return out


# -- reading ------------------------------------------------------------------------------------------
def _result_from_dict(d: dict, where: str) -> Result:
    mode = d["mode"] or "eye_to_hand"
    if mode not in MODES:
        raise InputError(f"{where}: mode {mode!r} is not one of {', '.join(MODES)}.")
    frames = mode_frames(mode)
    cams_d = mapping(d["cameras"], f"{where}: cameras")
    if not cams_d:
        raise InputError(f"{where}: the result has no cameras.")
    residuals = mapping(d.get("residuals") or {}, f"{where}: residuals")
    cameras = {str(n): _camera_from_dict(str(n), mapping(c, f"{where}: camera {n!r}"), frames,
                                         mapping(residuals.get(n) or {}, f"{where}: residuals of {n!r}"), where)
               for n, c in cams_d.items()}
    pairs = {}
    for key, p in mapping(d.get("camera_pairs") or {}, f"{where}: camera_pairs").items():
        what = f"{where}: camera pair {key!r}"
        p = mapping(p, what)
        a, b = (str(p["a"]), str(p["b"])) if "a" in p and "b" in p else str(key).split("__", 1)
        pairs[(a, b)] = PairResult(a, b, pose_matrix(p.get(f"T_{a}_{b}"), f"{what}: T_{a}_{b}"),
                                   matrix(p.get("covariance"), (6, 6), f"{what}: covariance"))
    solver = mapping(d.get("solver") or {}, f"{where}: solver")
    scale = mapping(d.get("board_scale") or {}, f"{where}: board_scale")
    mount = d.get(frames.board_key)
    mount_cov = (mapping(d.get("board_mount") or {}, f"{where}: board_mount")).get("covariance")
    if "rejected_views" in d:
        rejected_views = tuple(RejectedView(str(v["camera"]), int(v["capture"]), str(v.get("reason", "")))
                               for v in d["rejected_views"] or [])
    else:  # before the list was written: the cameras' own lists, in camera order (as the solver makes it)
        rejected_views = tuple(v for c in cameras.values() for v in c.views_rejected)
    return Result(
        mode=mode, method=str(d.get("method") or "joint"), cameras=cameras,
        T_mount_board=None if mount is None else pose_matrix(mount, f"{where}: {frames.board_key}"),
        mount_covariance=None if mount is None or mount_cov is None else matrix(mount_cov, (6, 6),
                                                                                 f"{where}: board_mount covariance"),
        pairs=pairs, converged=bool(solver.get("converged", True)), iterations=int(solver.get("iterations") or 0),
        final_cost=number_or(solver.get("final_cost"), float("nan")),
        pixel_sigma_px=number_or(solver.get("pixel_sigma_px"), float("nan")),
        solve_time_s=number_or(solver.get("solve_time_s"), float("nan")),
        rejected_views=rejected_views,
        rejected_corners=tuple((str(r["camera"]), int(r["capture"]), int(r["id"]), float(r["residual_px"]))
                               for r in d.get("rejected_corners") or []),
        T_base_flange_est={int(k): pose_matrix(T, f"{where}: robot_flange_poses_refined[{k}]")
                           for k, T in mapping(d.get("robot_flange_poses_refined") or {}, where).items()},
        settings=mapping(solver.get("settings") or {}, f"{where}: solver settings"),
        dataset=str(d.get("dataset") or ""),
        board_scale=number_or(scale.get("scale"), 1.0),
        board_scale_sigma=None if scale.get("sigma") is None else float(scale["sigma"]),
        notes=tuple(str(n) for n in d.get("notes") or []), robot=section(d, "robot", where),
        fk_noise=section(d, "fk_noise", where),
        calibgraph_version=str(d.get("calibgraph_version") or "unknown"), target=section(d, "target", where),
    )


def _camera_from_dict(name: str, c: dict, frames, residuals: dict, where: str) -> CameraResult:
    what = f"{where}: camera {name!r}"
    views_rejected = tuple(RejectedView(name, int(v["capture"]), str(v.get("reason", "")))
                           for v in c.get("views_rejected") or [])
    if c.get("calibrated", True) is False:  # too few views survived: no pose, no covariance
        return CameraResult(name=name, ref_frame=frames.ref, T_ref_cam=None, covariance=None,
                            reprojection_rms_px=float("nan"), reprojection_max_px=float("nan"),
                            views_used=int(c.get("views_used") or 0), views_rejected=views_rejected, calibrated=False,
                            why=str(c.get("why") or ""),
                            moved=None if c.get("moved") is None else moved_from_dict(c["moved"], frames.camera_key, what))
    if frames.camera_key not in c:
        raise InputError(f"{what} has no {frames.camera_key} (mode {'eye_to_hand' if frames.ref == 'base' else 'eye_in_hand'}).")
    if "covariance" not in c:
        raise InputError(f"{what} has no covariance.")
    mount = c.get(frames.board_key)
    return CameraResult(
        name=name, ref_frame=frames.ref, T_ref_cam=pose_matrix(c[frames.camera_key], f"{what}: {frames.camera_key}"),
        covariance=matrix(c["covariance"], (6, 6), f"{what}: covariance"),
        reprojection_rms_px=number_or(c.get("reprojection_rms_px"), float("nan")),
        reprojection_max_px=number_or(c.get("reprojection_max_px"), float("nan")),
        views_used=int(c.get("views_used") or 0), views_rejected=views_rejected,
        corners_used=int(c.get("corners_used") or 0), corners_rejected=int(c.get("corners_rejected") or 0),
        T_mount_board=None if mount is None else pose_matrix(mount, f"{what}: {frames.board_key}"),
        intrinsics=section(c, "intrinsics", what), corner_noise=section(c, "corner_noise", what),
        error_budget=section(c, "error_budget", what),
        pixel_sigma_px=None if c.get("pixel_sigma_px") is None else number_or(c.get("pixel_sigma_px"), float("nan")),
        moved=None if c.get("moved") is None else moved_from_dict(c["moved"], frames.camera_key, what),
        residuals_px={int(k): residual_from_dict(mapping(v, f"{what}: residuals of capture {k}"))
                      for k, v in residuals.items()},
        prediction=section(c, "prediction", what),
    )
