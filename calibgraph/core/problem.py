"""The calibration problem: what the solver is given.

A :class:`Problem` is plain data: the target points, each camera's intrinsics, the robot
captures (flange poses from forward kinematics) and the corner detections. It is validated on
construction, so the solver can trust it; every refusal names the camera and capture at fault.

Modes:
    eye_to_hand: cameras fixed in the cell, board on the flange. Unknowns ``T_base_cam[c]``
        and ``T_flange_board``.
    eye_in_hand: cameras on the flange, board fixed in the cell. Unknowns ``T_flange_cam[c]``
        and ``T_base_board``.
Methods:
    joint: all cameras share one board mount (the thesis's multi-camera method).
    single: every camera gets its own board mount and is solved alone (the thesis's single-camera
        method, kept for comparison).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Mapping

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.transforms import check_pose

MODES = ("eye_to_hand", "eye_in_hand")


@dataclass(frozen=True)
class ModeFrames:
    """The frame names of a calibration mode.

    Eye-to-hand: fixed cameras in the robot base frame, the board on the flange (``T_base_cam``,
    ``T_flange_board``). Eye-in-hand: cameras on the flange, the board fixed in the base frame
    (``T_flange_cam``, ``T_base_board``).
    """

    ref: str  # the frame the cameras are fixed in: 'base' or 'flange'
    mount: str  # the frame the board is fixed in: 'flange' or 'base'

    @property
    def camera_key(self) -> str:
        """``T_base_cam`` or ``T_flange_cam``."""
        return f"T_{self.ref}_cam"

    @property
    def board_key(self) -> str:
        """``T_flange_board`` or ``T_base_board``."""
        return f"T_{self.mount}_board"


def mode_frames(mode: str | None) -> ModeFrames:
    """The :class:`ModeFrames` of ``mode`` (``None``, as in old result files, means eye-to-hand)."""
    mode = mode or "eye_to_hand"
    if mode not in MODES:
        raise InputError(f"mode must be one of {MODES}, got {mode!r}.")
    return ModeFrames("base", "flange") if mode == "eye_to_hand" else ModeFrames("flange", "base")


METHODS = ("joint", "single")
LOSSES = ("huber", "cauchy", "none")
INTRINSICS_MODES = ("auto", "estimate", "fixed")
# the robot error model: chosen by the held-out captures, the per-pose FK prior, or joint zero offsets
KINEMATICS_MODES = ("auto", "none", "joint-offsets")
# 1-sigma of given intrinsics by source: (focal, relative; principal point, fraction of the image
# width; k1 and k2). Factory values of RGB-D cameras are often 1-2 % off in focal length; a proper
# calibration file is good to a few tenths of a percent.
INTRINSICS_PRIORS = {"factory": (0.02, 0.01, 0.05), "calibration": (0.003, 0.002, 0.01)}
# the prior of intrinsics found inadequate by their residuals, or of a camera whose intrinsics are
# unknown (around the values found from its views): wide, only keeping the problem well posed
WIDE_INTRINSICS_PRIOR = (0.10, 0.05, 0.5)
# a camera whose intrinsics are unknown is solved with the full k1 k2 p1 p2 k3 model (as `calibgraph
# intrinsics` calibrates): real lenses' tangential terms are a few 1e-4, and left out they turned an
# eye-in-hand camera by 0.1 deg at 14 sigma with a residual RMS no different (bench_unknown_eye_in_hand)
WIDE_TANGENTIAL_SIGMA = 0.01


def intrinsics_source(intr: Intrinsics, options: "SolverOptions") -> str:
    """Where a camera's given intrinsics come from: its own ``source``, else the options' default."""
    return intr.source or options.intrinsics_source


def intrinsics_estimated(intr: Intrinsics, options: "SolverOptions") -> bool:
    """True when the solver treats this camera's intrinsics as unknowns (with a prior); always for
    a camera whose intrinsics are unknown."""
    if not intr.known:
        return True
    if options.intrinsics == "fixed":
        return False
    return options.intrinsics == "estimate" or intrinsics_source(intr, options) != "exact"


def uses_file_covariance(intr: Intrinsics, options: "SolverOptions", wide: bool = False) -> bool:
    """True when a camera's prior is the covariance its intrinsics came with (a calibration file's)."""
    return intr.covariance is not None and not wide and intr.known and options.intrinsics == "auto"


def intrinsics_prior_covariance(intr: Intrinsics, options: "SolverOptions", wide: bool = False) -> np.ndarray:
    """Covariance of the prior on a camera's intrinsics vector: the covariance its intrinsics came
    with (a calibration file's: over [fx, fy, cx, cy, k1, k2] and, when it covers them, [p1, p2
    [, k3]]), else the diagonal width of its source over [fx, fy, cx, cy, k1, k2]. Its size is the
    size of the vector the solver estimates."""
    if uses_file_covariance(intr, options, wide):
        return intr.covariance
    return np.diag(intrinsics_prior_sigmas(intr, options, wide) ** 2)


def intrinsics_prior_sigmas(intr: Intrinsics, options: "SolverOptions", wide: bool = False) -> np.ndarray:
    """1-sigma of the prior on a camera's intrinsics vector (see ``SolverOptions.intrinsics`` and
    :func:`intrinsics_prior_covariance`), without the correlations of a calibration file's covariance."""
    if uses_file_covariance(intr, options, wide):
        return np.sqrt(np.diag(intr.covariance))
    if options.intrinsics == "estimate" and intr.known:
        return np.array([options.intrinsics_sigma_px] * 4 + [options.distortion_sigma] * 2)
    wide = wide or not intr.known
    f_rel, c_frac, k = WIDE_INTRINSICS_PRIOR if wide else INTRINSICS_PRIORS[intrinsics_source(intr, options)]
    fx, fy = intr.K[0, 0], intr.K[1, 1]
    c = c_frac * max(intr.width_px, 1)
    if not intr.known:  # [fx, fy, cx, cy, k1, k2, p1, p2, k3]
        return np.array([f_rel * fx, f_rel * fy, c, c, k, k, WIDE_TANGENTIAL_SIGMA, WIDE_TANGENTIAL_SIGMA, k])
    return np.array([f_rel * fx, f_rel * fy, c, c, k, k])


@dataclass(frozen=True)
class Capture:
    """One robot pose at which the cameras grabbed frames.

    Attributes:
        index: capture id, unique within a dataset.
        T_base_flange: (4, 4) flange pose in the robot base frame from forward kinematics.
        q_rad: (n,) joint angles when known.
        stamp_s: time the robot had settled, seconds (any epoch).
    """

    index: int
    T_base_flange: np.ndarray
    q_rad: np.ndarray | None = None
    stamp_s: float | None = None

    def __post_init__(self):
        object.__setattr__(self, "index", int(self.index))
        object.__setattr__(self, "T_base_flange", check_pose(self.T_base_flange, f"capture {self.index}: T_base_flange"))
        if self.q_rad is not None:
            q = np.asarray(self.q_rad, float).reshape(-1)
            if not np.all(np.isfinite(q)):
                raise InputError(f"capture {self.index}: joint angles contain NaN/inf.")
            object.__setattr__(self, "q_rad", q)


@dataclass(frozen=True)
class Detection:
    """Target points seen by one camera in one capture.

    Attributes:
        camera: camera name.
        capture: index of the :class:`Capture`.
        ids: (N,) target point ids (rows of ``Problem.points_board_m``).
        uv_px: (N, 2) sub-pixel image coordinates, OpenCV convention (pixel centres at integers).
        image: path of the source image, when there is one (for reports and viewers).
    """

    camera: str
    capture: int
    ids: np.ndarray
    uv_px: np.ndarray
    image: str | None = None

    def __post_init__(self):
        ids = np.asarray(self.ids).reshape(-1)
        uv = np.asarray(self.uv_px, float)
        where = f"camera {self.camera!r}, capture {self.capture}"
        if uv.ndim != 2 or uv.shape[1] != 2:
            raise InputError(f"{where}: uv_px must have shape (N, 2), got {uv.shape}.")
        if ids.shape[0] != uv.shape[0]:
            raise InputError(f"{where}: {ids.shape[0]} corner ids but {uv.shape[0]} pixel coordinates.")
        if ids.size and not np.issubdtype(ids.dtype, np.integer):
            if not np.all(np.equal(np.mod(ids, 1), 0)):
                raise InputError(f"{where}: corner ids must be integers.")
        ids = ids.astype(int)
        if not np.all(np.isfinite(uv)):
            raise InputError(f"{where}: pixel coordinates contain NaN/inf.")
        if len(np.unique(ids)) != ids.size:
            raise InputError(f"{where}: duplicate corner ids.")
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "uv_px", uv)
        object.__setattr__(self, "capture", int(self.capture))


@dataclass(frozen=True)
class CliFlag:
    """The command-line flag of a :class:`SolverOptions` field, declared on the field (its
    ``metadata["flag"]``) so that the flags of ``calibgraph solve`` are generated from the options
    and cannot drift from them. Fields without one are set in dataset.yaml's ``solver`` section.

    Attributes:
        name: the flag, e.g. ``'--fk-sigma-mm'``.
        help: its help text.
        type: the type of the flag's value (float, str); None for a switch (given or not).
        choices: the values allowed, when there is a fixed set.
        scale: option = flag value * scale (the flag's unit to SI: mm -> m 1e-3, deg -> rad pi/180).
        positive: only values > 0 are meaningful (a zero sigma is refused, not taken for "unset").
        const: the option's value when a switch is given.
    """

    name: str
    help: str
    type: type | None = None
    choices: tuple = ()
    scale: float = 1.0
    positive: bool = False
    const: object = None

    def option_value(self, value):
        """The option's value for the flag's (parsed) ``value``."""
        if self.type is None:
            return self.const
        return value * self.scale if self.scale != 1.0 else value


CORNER_NOISE = ("per-view", "per-camera", "one")


def _flag(default, flag: CliFlag | None = None):
    """A SolverOptions field with its command-line flag (None: dataset.yaml's solver section only)."""
    return field(default=default, metadata={"flag": flag})


def option_flags() -> dict:
    """SolverOptions field name -> its :class:`CliFlag`, for the fields that have one, in field order."""
    return {f.name: f.metadata["flag"] for f in fields(SolverOptions) if f.metadata.get("flag") is not None}


@dataclass(frozen=True)
class SolverOptions:
    """Knobs of the solver; defaults suit a Panda-class arm and factory intrinsics.

    Attributes:
        fk_sigma_translation_m, fk_sigma_rotation_rad: 1-sigma of the forward-kinematics prior on
            each flange pose (Panda class: 0.1 mm, 0.01 deg).
        pixel_sigma_px: assumed corner noise. ``None`` estimates it from the residuals (a
            posteriori variance factor), which is what the covariances are then scaled with.
        loss: corner-level robust loss, 'huber' (default), 'cauchy' or 'none'.
        loss_scale: threshold of the loss on a corner's residual *norm*, in units of the per-axis
            pixel sigma. 2.45 keeps 95% of Gaussian corners at full weight (a 2-D residual norm
            exceeds 1.345 sigma 40% of the time, so the 1-D Huber constant would downweight inliers).
        outlier_sigmas: corners whose residual exceeds this many sigmas after the robust solve
            are rejected and listed; views losing most corners are rejected as a whole.
        min_views_per_camera: below this a camera is refused with an observability error.
        max_iterations: LM iterations per solve.
        intrinsics: how the given intrinsics are treated. 'auto' (default): as uncertain — fx, fy,
            cx, cy, k1, k2 of every camera are estimated under a prior whose width depends on
            ``intrinsics_source``, so each camera's covariance is marginal over them; a camera whose
            residuals show the intrinsics to be inadequate (large, radial) is re-solved with a wide
            prior and the result says so. 'estimate': always the wide prior
            (``intrinsics_sigma_px``, ``distortion_sigma``). 'fixed': taken as exact (the
            covariance is then conditional on them).
        intrinsics_source: where the given intrinsics come from when a camera's ``Intrinsics.source``
            does not say, setting their prior (1-sigma): 'factory' (device or datasheet values: f 2 %,
            principal point 1 % of the width, k1, k2 0.05), 'calibration' (the default; a camera
            calibration file: f 0.3 %, principal point 0.2 % of the width, k1, k2 0.01), 'exact'
            (held fixed, as a simulation's own cameras are).
        refine_intrinsics: True means ``intrinsics='estimate'`` (the ``--refine-intrinsics`` flag sets it).
        board_scale: estimate a scale factor of the printed board (printer scaling) under a prior of
            ``board_scale_sigma``, shared by all views; False takes the declared pitch as exact.
        formulation: 'view' (one vectorised CustomFactor per view, any OpenCV distortion),
            'corner' (one C++ ProjectionFactorPPP per corner, Cal3DS2 distortion only) or 'auto'
            (corner when every camera fits Cal3DS2 and the graph has at least 1000 views, else
            view). ``refine_intrinsics`` always uses view. Both give the same estimate.
        kinematics: 'auto' (default), 'none' or 'joint-offsets'. 'none': the FK prior on each flange
            pose. 'joint-offsets': the flange poses follow from the reported joint angles plus
            estimated joint zero offsets (:mod:`calibgraph.solver.robot.kinematics`; needs ``q_rad`` in every
            capture). 'auto': 'none', and where the arm departs from its stated FK accuracy and every
            capture records joint angles that the kinematic model maps to the recorded flange poses
            (eye-to-hand, method joint), both are cross-validated and the one predicting held-out
            captures clearly better is used (:mod:`calibgraph.solver.robot.kinematics_select`).
        kinematics_model: the arm's kinematic model: 'franka' (Panda / FR3, built in) or a URDF path.
        joint_offset_prior_rad: 1-sigma prior of each estimated joint offset.
        kinematics_staging: 'staged' (cameras with an inflated FK prior, then offsets, then all
            jointly) or 'joint' (all at once).
        view_noise_modes: model corner errors that are correlated within a view (see
            :func:`calibgraph.solver.terms.noise_model.mode_variance_ratios`): per camera, the variance of each
            view's low-order image modes (shift, rotation, scale, shear of the board) is estimated
            against the rest of the residuals and, where larger, weighted and propagated as such
            (view formulation). False treats every corner as independent.
        corner_noise: whose pixel sigma a corner has (see
            :func:`calibgraph.solver.terms.noise_model.camera_noise_scales`): 'per-view' (default: each
            camera its own, each view its own level shrunk towards its camera's), 'per-camera', or
            'one' (a single sigma for every corner). Ignored when ``pixel_sigma_px`` is stated.
        fk_variance: compare the fitted robot poses with the FK prior (see
            :func:`calibgraph.solver.robot.fk_check.fk_variance_ratio`) and, when they depart from it more
            than the stated FK sigmas allow (p < 0.05), solve with the sigmas the fit implies and say so.

    Every field can be set in dataset.yaml's ``solver`` section (by its name, SI units); those with a
    :class:`CliFlag` in their metadata also by that flag, which wins (see :func:`option_flags`).
    """

    fk_sigma_translation_m: float = _flag(1e-4, CliFlag(
        "--fk-sigma-mm", "forward-kinematics translation 1-sigma, mm", float, scale=1e-3, positive=True))
    fk_sigma_rotation_rad: float = _flag(float(np.radians(0.01)), CliFlag(
        "--fk-sigma-deg", "forward-kinematics rotation 1-sigma, deg", float, scale=np.pi / 180.0, positive=True))
    pixel_sigma_px: float | None = _flag(None, CliFlag(
        "--pixel-sigma", "corner noise in px (default: estimated)", float, positive=True))
    loss: str = _flag("huber", CliFlag("--loss", "corner-level robust loss", str, choices=LOSSES))
    loss_scale: float = _flag(2.45)
    outlier_sigmas: float = _flag(5.0)
    min_views_per_camera: int = _flag(3)
    max_iterations: int = _flag(100)
    intrinsics: str = _flag("auto", CliFlag(
        "--fixed-intrinsics", "take the given intrinsics as exact (the 1-sigma is then conditional on them)",
        const="fixed"))
    intrinsics_source: str = _flag("calibration", CliFlag(
        "--intrinsics-source", "where the given intrinsics come from when dataset.yaml does not say: their prior "
        "(calibration: f 0.3 %, factory: f 2 %; default calibration)", str, choices=("calibration", "factory", "exact")))
    refine_intrinsics: bool = _flag(False, CliFlag(
        "--refine-intrinsics", "estimate fx, fy, cx, cy, k1, k2 of every camera under a fixed prior (5 px, 0.1) around "
        "the given values", const=True))
    intrinsics_sigma_px: float = _flag(5.0)
    distortion_sigma: float = _flag(0.1)
    board_scale: bool = _flag(True, CliFlag(
        "--fixed-board-scale", "take the target's declared size as exact (default: estimate a printer scale factor)",
        const=False))
    board_scale_sigma: float = _flag(0.02)
    formulation: str = _flag("auto")
    kinematics: str = _flag("auto", CliFlag(
        "--estimate-kinematics", "joint-offsets: estimate the arm's joint zero offsets in the same graph (needs q_rad "
        "in every capture; eye-to-hand, method joint); result.json gains a 'robot' section. none: the per-pose FK "
        "prior only. auto (default): none, unless the arm departs from its FK, the captures record joint angles and "
        "the offsets predict held-out captures clearly better (5-fold cross-validation)", str,
        choices=KINEMATICS_MODES))
    kinematics_model: str = _flag("franka", CliFlag(
        "--kinematic-model", "the arm's kinematic model for --estimate-kinematics: franka (Panda / FR3, default) or a "
        "URDF path", str))
    joint_offset_prior_rad: float = _flag(0.01)
    kinematics_staging: str = _flag("joint", CliFlag(
        "--kinematics-staging", "joint: all variables at once (default, see scripts/results/bench_kinematics.md); "
        "staged: cameras with an inflated FK prior, then the offsets, then everything", str, choices=("joint", "staged")))
    view_noise_modes: bool = _flag(True)
    corner_noise: str = _flag("per-view")
    fk_variance: bool = _flag(True)
    # the arm's repeatability: how far apart two visits of one configuration (the same joint target reached
    # again) put the flange; None: the stated FK sigmas (the solve pins them there before any is widened)
    fk_repeat_translation_m: float | None = _flag(None)
    fk_repeat_rotation_rad: float | None = _flag(None)

    def __post_init__(self):
        if self.corner_noise not in CORNER_NOISE:
            raise InputError(f"solver: corner_noise must be one of {CORNER_NOISE}, got {self.corner_noise!r}.")
        if self.loss not in LOSSES:
            raise InputError(f"solver: loss must be one of {LOSSES}, got {self.loss!r}.")
        for name in ("fk_sigma_translation_m", "fk_sigma_rotation_rad", "loss_scale", "outlier_sigmas"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"solver: {name} must be positive, got {v}.")
        if self.intrinsics not in INTRINSICS_MODES:
            raise InputError(f"solver: intrinsics must be one of {INTRINSICS_MODES}, got {self.intrinsics!r}.")
        if self.intrinsics_source not in (*INTRINSICS_PRIORS, "exact"):
            raise InputError(f"solver: intrinsics_source must be one of {(*INTRINSICS_PRIORS, 'exact')}, "
                             f"got {self.intrinsics_source!r}.")
        if self.refine_intrinsics:
            object.__setattr__(self, "intrinsics", "estimate")
        if not (np.isfinite(self.board_scale_sigma) and self.board_scale_sigma > 0):
            raise InputError(f"solver: board_scale_sigma must be positive, got {self.board_scale_sigma}.")
        if self.formulation not in ("auto", "view", "corner"):
            raise InputError(f"solver: formulation must be 'auto', 'view' or 'corner', got {self.formulation!r}.")
        if self.kinematics not in KINEMATICS_MODES:
            raise InputError(f"solver: kinematics must be one of {KINEMATICS_MODES}, got {self.kinematics!r}.")
        if self.kinematics_staging not in ("staged", "joint"):
            raise InputError(f"solver: kinematics_staging must be 'staged' or 'joint', got {self.kinematics_staging!r}.")
        if not (np.isfinite(self.joint_offset_prior_rad) and self.joint_offset_prior_rad > 0):
            raise InputError(f"solver: joint_offset_prior_rad must be positive, got {self.joint_offset_prior_rad}.")
        if self.pixel_sigma_px is not None and not (self.pixel_sigma_px > 0):
            raise InputError("solver: pixel_sigma_px must be positive or None.")


# A capture revisits an earlier capture's configuration (the same joint target, reached again) when its
# reported joint angles are this close to that one's, every joint (or, where a capture records none,
# its reported flange pose this close). A real arm's absolute error repeats with its configuration, so
# the two share it: a revisit is not a second draw of the robot's error. Calibration poses differ by
# centimetres and degrees; a revisit repeats its target to the arm's repeatability (0.1 mm for a Panda), or
# nearly (a Franka's three sessions of 12 joint targets: 0.05-0.12 deg apart, 0.5-1.4 mm at the flange).
REVISIT_Q_RAD = 3e-3
REVISIT_POSITION_M = 2e-3
REVISIT_ROTATION_RAD = float(np.radians(0.2))


_CONFIGURATIONS: dict = {}  # id(captures tuple) -> (the tuple, its configuration_of): Problem.with_ keeps the tuple


def configuration_of(captures) -> dict:
    """capture index -> the index of the first capture (in index order) at its configuration: itself,
    unless it revisits an earlier capture's joint target (:data:`REVISIT_Q_RAD`, every joint, where every
    capture records the same number of joint angles; else the flange pose, :data:`REVISIT_POSITION_M` and
    :data:`REVISIT_ROTATION_RAD`)."""
    caps = sorted(captures, key=lambda c: c.index)
    if not caps:
        return {}
    sizes = {None if c.q_rad is None else np.asarray(c.q_rad).size for c in caps}
    by_q = None not in sizes and len(sizes) == 1
    X = (np.array([np.asarray(c.q_rad, float).reshape(-1) for c in caps]) if by_q
         else np.array([np.asarray(c.T_base_flange, float)[:3, 3] for c in caps]))
    R = None if by_q else np.array([np.asarray(c.T_base_flange, float)[:3, :3] for c in caps])
    out, leaders = {}, np.empty(len(caps), int)
    n_lead = 0
    for i, c in enumerate(caps):
        g = c.index
        if n_lead:
            L = leaders[:n_lead]
            if by_q:
                near = L[np.max(np.abs(X[L] - X[i]), axis=1) <= REVISIT_Q_RAD]
            else:
                near = L[np.linalg.norm(X[L] - X[i], axis=1) <= REVISIT_POSITION_M]
                cos = (np.einsum("nji,ji->n", R[near], R[i]) - 1.0) / 2.0  # trace(R_j^T R_i): the angle between
                near = near[np.arccos(np.clip(cos, -1.0, 1.0)) <= REVISIT_ROTATION_RAD]
            if near.size:
                g = caps[int(near[0])].index
        out[c.index] = g
        if g == c.index:
            leaders[n_lead] = i
            n_lead += 1
    return out


def with_repeatability(options: "SolverOptions") -> "SolverOptions":
    """``options`` with the arm's repeatability pinned (the stated FK sigmas where not given), so that a
    later widening of the FK prior (the arm's absolute accuracy) leaves it as stated."""
    from dataclasses import replace
    return replace(options,
                   fk_repeat_translation_m=options.fk_repeat_translation_m or options.fk_sigma_translation_m,
                   fk_repeat_rotation_rad=options.fk_repeat_rotation_rad or options.fk_sigma_rotation_rad)


def configuration_folds(captures, folds: int) -> list:
    """``folds`` sets of capture indices for cross-validation: the configurations (not the captures) dealt
    in order, each fold holding every capture of its configurations, so that no fold is predicted from a
    visit of its own joint targets. Fewer folds (down to none) when there are fewer configurations."""
    config = configuration_of(captures)
    leaders = sorted(set(config.values()))
    sets = [set(leaders[i::folds]) for i in range(min(folds, len(leaders)))]
    return [{k for k, g in config.items() if g in s} for s in sets]


@dataclass(frozen=True)
class Problem:
    """Everything the solver needs.

    Attributes:
        points_board_m: (M, 3) target points in the board frame; detection ids index its rows.
        cameras: name -> :class:`Intrinsics`.
        captures: robot captures (unique indices).
        detections: per camera and capture.
        mode: 'eye_to_hand' or 'eye_in_hand'.
        method: 'joint' or 'single'.
        options: :class:`SolverOptions`.
        target: the :class:`~calibgraph.core.targets.Target` the points come from, when known (the
            error budget's advice then predicts a close-range session with that board).
    """

    points_board_m: np.ndarray
    cameras: Mapping[str, Intrinsics]
    captures: tuple
    detections: tuple
    mode: str = "eye_to_hand"
    method: str = "joint"
    options: SolverOptions = field(default_factory=SolverOptions)
    target: object = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        pts = np.asarray(self.points_board_m, float)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 4 or not np.all(np.isfinite(pts)):
            raise InputError(f"points_board_m must be a finite (M >= 4, 3) array, got shape {pts.shape}.")
        object.__setattr__(self, "points_board_m", pts)
        if self.mode not in MODES:
            raise InputError(f"mode must be one of {MODES}, got {self.mode!r}.")
        if self.method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {self.method!r}.")
        if not self.cameras:
            raise InputError("no cameras given.")
        for name, intr in self.cameras.items():
            if not isinstance(intr, Intrinsics):
                raise InputError(f"camera {name!r}: intrinsics must be an Intrinsics object.")
        caps = tuple(self.captures)
        dets = tuple(self.detections)
        object.__setattr__(self, "captures", caps)
        object.__setattr__(self, "detections", dets)
        idx = [c.index for c in caps]
        if len(set(idx)) != len(idx):
            twice = sorted({k for k in idx if idx.count(k) > 1})
            raise InputError(f"capture indices must be unique: {', '.join(map(str, twice))} "
                             f"{'appears' if len(twice) == 1 else 'appear'} more than once.")
        known = set(idx)
        seen = set()
        for d in dets:
            if d.camera not in self.cameras:
                raise InputError(
                    f"detection for unknown camera {d.camera!r} (capture {d.capture}); "
                    f"known cameras: {', '.join(sorted(self.cameras))}."
                )
            if d.capture not in known:
                raise InputError(f"camera {d.camera!r}: detection refers to capture {d.capture}, which has no robot pose.")
            if (d.camera, d.capture) in seen:
                raise InputError(f"camera {d.camera!r}: two detections for capture {d.capture}.")
            seen.add((d.camera, d.capture))
            if d.ids.size and (d.ids.min() < 0 or d.ids.max() >= pts.shape[0]):
                raise InputError(
                    f"camera {d.camera!r}, capture {d.capture}: corner id {int(d.ids.max())} is not on the target "
                    f"(ids 0..{pts.shape[0] - 1}); check the target spec (rows, cols) matches the board."
                )

    # -- convenience ------------------------------------------------------------------------------
    @property
    def capture_by_index(self) -> dict:
        return {c.index: c for c in self.captures}

    @property
    def records_joint_angles(self) -> bool:
        """Every capture records its joint angles (what joint zero offsets need)."""
        return bool(self.captures) and all(c.q_rad is not None for c in self.captures)

    @property
    def configurations(self) -> dict:
        """capture index -> the first capture at its configuration (:func:`configuration_of`; computed
        once for the captures, which :meth:`with_` passes on)."""
        hit = _CONFIGURATIONS.get(id(self.captures))
        if hit is None or hit[0] is not self.captures:
            if len(_CONFIGURATIONS) > 16:
                _CONFIGURATIONS.clear()
            hit = _CONFIGURATIONS[id(self.captures)] = (self.captures, configuration_of(self.captures))
        return hit[1]

    @property
    def revisits(self) -> bool:
        """Some capture revisits an earlier one's configuration."""
        return any(k != g for k, g in self.configurations.items())

    def detections_of(self, camera: str) -> list:
        return [d for d in self.detections if d.camera == camera]

    def with_(self, **changes) -> "Problem":
        """A copy with some fields replaced (the problem itself stays frozen)."""
        from dataclasses import replace

        return replace(self, **changes)
