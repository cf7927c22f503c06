"""The robot's own kinematic errors in the calibration graph: joint zero offsets.

With ``SolverOptions.kinematics = 'joint-offsets'`` the fixed forward-kinematics prior on each
flange pose F(k) is replaced by a factor between F(k) and one vector of joint offsets O(0)::

    r_k = Log( FK(q_k + o)^-1  F(k) )      whitened by the FK sigmas (rotation first, flange axes)

where ``q_k`` are the joint angles the robot reported for capture k and ``o`` the offsets (the
physical angle of joint i is ``q_i + o_i``); O(0) has a prior N(0, ``joint_offset_prior_rad``).
The rest of the graph (cameras, mount, intrinsics, board scale) is untouched.

Gauges. A joint's offset turns everything beyond it about its axis. When no joint before it
moves across the captures, that turn is a fixed rotation of the base frame, which the fixed
cameras absorb; when no joint after it moves, it is a fixed rotation of the flange, which the
board mount absorbs. So joint 1's offset (nothing before it) and the last joint's (nothing after
it but the flange) are never observable in a camera-to-base calibration: they are held at zero and
listed in ``fixed`` with the reason (the cameras' poses and the mount carry them). Any other joint
is refused with advice when the captures leave it in such a gauge (:func:`check_motion`), or when
the data barely tighten its prior (:func:`check_after_solve`). Before any of it, the recorded joint
angles must give the recorded flange poses through the model (:func:`check_recorded_angles`, the
check ``auto`` makes before it tries the offsets): angles in degrees, noisy angles or another arm
would otherwise be fitted with offsets as if they were the arm's.

Staging (``SolverOptions.kinematics_staging``): 'staged' solves the cameras first with the FK
prior inflated (``STAGE1_FK_INFLATION``), fits the offsets to those flange poses
(:func:`offsets_from_poses`), then solves everything jointly from there; 'joint' solves everything
at once from zero offsets. Both end in the same joint graph; ``scripts/bench_kinematics.py``
compares them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np

from calibgraph.core.errors import CalibgraphError, InputError, ObservabilityError
from calibgraph.core.kinematics import SerialChain, chain_from_urdf, franka_chain
from calibgraph.core.transforms import log_so3

STAGE1_FK_INFLATION = 30.0
# a joint "moves" when its angle spans at least this much over the captures (rad, ~3 degrees)
MIN_JOINT_MOTION_RAD = 0.05
# a free offset whose posterior sigma is above this fraction of its prior sigma is not determined by the data
MAX_SIGMA_FRACTION_OF_PRIOR = 0.3
# the kinematic model must map each capture's joint angles to its recorded flange pose this closely
FK_MATCH_M, FK_MATCH_RAD = 1e-3, float(np.radians(0.1))
# a revolute joint's angle in radians stays within a turn either way: larger numbers are not radians
MAX_REVOLUTE_RAD = 2.0 * np.pi
# angles read as degrees "map" when they land this many times the match tolerance from the poses
DEGREES_FIT = 10.0


@dataclass(frozen=True)
class KinematicSetup:
    """What the graph needs to estimate joint offsets.

    Attributes:
        chain: the arm's kinematic model.
        free: indices (0-based) of the joints whose offsets are variables (the entries of O(0)).
        fixed: (joint number 1-based, reason) of the offsets held at zero.
        q_rad: capture index -> reported joint angles (n,).
    """

    chain: SerialChain
    free: tuple
    fixed: tuple
    q_rad: dict

    def full(self, o_free: np.ndarray | None) -> np.ndarray:
        """All n offsets (fixed ones zero) from the free ones."""
        o = np.zeros(self.chain.n_joints)
        if o_free is not None:
            o[list(self.free)] = o_free
        return o


def load_chain(model: str) -> SerialChain:
    """'franka' / 'panda' / 'fr3' (built in) or a URDF path."""
    if model.lower() in ("franka", "panda", "fr3"):
        return franka_chain()
    if Path(model).suffix.lower() in (".urdf", ".xml") or Path(model).exists():
        return chain_from_urdf(model)
    raise InputError(f"kinematic model {model!r}: give 'franka' (Panda / FR3) or the path of the arm's URDF.")


@dataclass(frozen=True)
class AngleMapping:
    """How a kinematic model maps the captures' recorded joint angles to their recorded flange poses.

    Attributes:
        model: the model's name as given (``kinematics_model``).
        translation_m, rotation_rad: the largest departure of FK(q_k) from capture k's recorded
            flange pose over the captures (translation norm; rotation angle).
        capture: the capture of the largest departure (relative to the match tolerances).
        max_abs: the largest magnitude among the recorded angles (as recorded, "rad").
        as_degrees: (translation_m, rotation_rad) of the same departures with the angles read as degrees.
    """

    model: str
    translation_m: float
    rotation_rad: float
    capture: int
    max_abs: float
    as_degrees: tuple

    @property
    def maps(self) -> bool:
        """Every capture's angles give its recorded pose within :data:`FK_MATCH_M` / :data:`FK_MATCH_RAD`."""
        return self.translation_m <= FK_MATCH_M and self.rotation_rad <= FK_MATCH_RAD

    @property
    def degrees_fit(self) -> bool:
        """Read as degrees, the angles give the recorded poses (within :data:`DEGREES_FIT` tolerances)."""
        t, r = self.as_degrees
        return t <= DEGREES_FIT * FK_MATCH_M and r <= DEGREES_FIT * FK_MATCH_RAD

    @property
    def looks_like_degrees(self) -> bool:
        """The numbers fit degrees: read as degrees they map, or no revolute joint turns that far in radians."""
        return not self.maps and (self.degrees_fit or self.max_abs > MAX_REVOLUTE_RAD)

    def describe(self) -> str:
        """The departure in one clause, with what to do: record radians (the numbers fit degrees), or
        give the arm's URDF (another arm, noisy angles, poses of a tool frame)."""
        said = (f"the kinematic model {self.model!r} maps the recorded joint angles to flange poses up to "
                f"{1e3 * self.translation_m:.1f} mm / {np.degrees(self.rotation_rad):.2f} deg from the recorded ones "
                f"(worst: capture {self.capture})")
        if self.degrees_fit:
            t, r = self.as_degrees
            return (f"{said}; degrees? read as degrees they map to within {1e3 * t:.2f} mm / {np.degrees(r):.3f} deg: "
                    "record q_rad in radians")
        if self.max_abs > MAX_REVOLUTE_RAD:
            return (f"{said}; degrees? angles up to {self.max_abs:.1f} are more than a revolute joint turns in radians "
                    f"({MAX_REVOLUTE_RAD:.2f}): record q_rad in radians")
        return (f"{said} (another arm, angles that do not belong to the poses, or poses of a tool frame): give the "
                "arm's URDF with --kinematic-model")


def _departures(chain: SerialChain, q: np.ndarray, captures) -> tuple:
    """(translation m (N,), rotation rad (N,)) of FK(q_k) from each capture's recorded flange pose."""
    T = chain.fk(q)
    d_m = np.array([float(np.linalg.norm(c.T_base_flange[:3, 3] - Tk[:3, 3])) for Tk, c in zip(T, captures)])
    d_rad = np.array([float(np.linalg.norm(log_so3(Tk[:3, :3].T @ c.T_base_flange[:3, :3]))) for Tk, c in zip(T, captures)])
    return d_m, d_rad


def angle_mapping(chain: SerialChain, captures, model: str) -> AngleMapping:
    """The :class:`AngleMapping` of ``captures`` (each with ``q_rad`` of ``chain.n_joints`` angles)."""
    caps = list(captures)
    q = np.array([c.q_rad for c in caps], float)
    d_m, d_rad = _departures(chain, q, caps)
    g_m, g_rad = _departures(chain, np.radians(q), caps)
    worst = int(np.argmax(np.maximum(d_m / FK_MATCH_M, d_rad / FK_MATCH_RAD)))
    return AngleMapping(model, float(d_m.max()), float(d_rad.max()), caps[worst].index, float(np.abs(q).max()),
                        (float(g_m.max()), float(g_rad.max())))


def angles_mismatch(problem) -> AngleMapping | None:
    """The :class:`AngleMapping` of a problem whose captures all record as many joint angles as its
    kinematic model has joints, when those angles do not map to the recorded poses; None when they
    do, or cannot be compared (no angles, another joint count, a model that cannot be read)."""
    caps = problem.captures
    if not problem.records_joint_angles:
        return None
    try:
        chain = load_chain(problem.options.kinematics_model)
    except CalibgraphError:
        return None
    if any(c.q_rad.size != chain.n_joints for c in caps):
        return None
    m = angle_mapping(chain, caps, problem.options.kinematics_model)
    return None if m.maps else m


def require_angles(chain: SerialChain, captures, flag: str = "--estimate-kinematics") -> None:
    """Refuse (InputError) captures without joint angles, or with another number than ``chain`` has joints."""
    caps = list(captures)
    missing = [c.index for c in caps if c.q_rad is None]
    if missing:
        raise InputError(f"{flag} needs the joint angles (q_rad) of every capture; {len(missing)} of {len(caps)} "
                         f"captures have none (first: capture {missing[0]}). Record them (calibgraph capture does) or "
                         "solve without the option.")
    wrong = [c for c in caps if c.q_rad.size != chain.n_joints]
    if wrong:
        raise InputError(f"{flag}: capture {wrong[0].index} records {wrong[0].q_rad.size} joint angles, but the "
                         f"kinematic model {chain.name!r} has {chain.n_joints} joints: give the arm's URDF with "
                         "--kinematic-model.")


def check_recorded_angles(model: str, captures, flag: str = "--estimate-kinematics joint-offsets") -> None:
    """Refuse (InputError, one line) joint offsets asked for on captures whose recorded joint angles
    the kinematic model does not map to their recorded flange poses: what ``auto`` checks before it
    tries them. The offsets would be fitted to angles that do not give these poses (in degrees, say:
    every offset zero and the cameras tens of mm off; noisy angles: offsets of tens of mrad)."""
    caps = list(captures)
    chain = load_chain(model)
    require_angles(chain, caps, flag)
    m = angle_mapping(chain, caps, model)
    if not m.maps:
        raise InputError(f"{flag}: {m.describe()}. The offsets would be fitted to angles that do not give these "
                         "poses; fix the angles, or solve with --estimate-kinematics none, which uses the recorded "
                         "poses alone (nothing was written).")


def setup(problem) -> KinematicSetup | None:
    """The :class:`KinematicSetup` of a problem whose options ask for kinematics, else None.
    Refuses (InputError) captures without joint angles, eye-in-hand and 'single' method."""
    opts = problem.options
    if opts.kinematics != "joint-offsets":  # 'none', or 'auto' before it chose (kinematics_select)
        return None
    chain = load_chain(opts.kinematics_model)
    require_angles(chain, problem.captures)
    if problem.method != "joint":
        raise InputError("--estimate-kinematics is implemented for method 'joint' (one shared board mount).")
    n = chain.n_joints
    if problem.mode == "eye_to_hand":
        fixed = ((1, "a rotation of the whole arm about the base axis: the fixed cameras' poses absorb it"),
                 (n, "a rotation of the flange about its axis: the board mount's roll absorbs it"))
    else:
        fixed = ((1, "a rotation of the whole arm about the base axis: the fixed board's pose absorbs it"),
                 (n, "a rotation of the flange about its axis: the cameras' poses on the flange absorb it"))
    free = tuple(range(1, n - 1))
    return KinematicSetup(chain, free, fixed, {c.index: c.q_rad for c in problem.captures})


def check_motion(ks: KinematicSetup, captures) -> None:
    """Refuse with advice when the captures leave a free joint's offset in a gauge: no joint before it
    moves (the cameras absorb it) or none after it does (the mount absorbs it)."""
    q = np.array([ks.q_rad[k] for k in captures])
    if len(q) < 3:
        raise ObservabilityError(f"joint offsets need captures at several arm configurations; {len(q)} given.")
    span = q.max(axis=0) - q.min(axis=0)
    moving = span >= MIN_JOINT_MOTION_RAD
    for i in ks.free:
        before, after = moving[:i].any(), moving[i + 1:].any()
        if before and after:
            continue
        side = "before" if not before else "after"
        which = range(0, i) if not before else range(i + 1, len(span))
        spans = ", ".join(f"joint {j + 1} {np.degrees(span[j]):.1f} deg" for j in which)
        absorber = "the cameras' poses absorb" if not before else "the board mount absorbs"
        raise ObservabilityError(
            f"joint {i + 1}'s offset cannot be observed: no joint {side} it moves across the captures ({spans}), so its "
            f"error is a fixed rotation that {absorber}. Add captures that turn those joints by at least "
            f"{np.degrees(MIN_JOINT_MOTION_RAD):.0f} deg, or solve without --estimate-kinematics.")


def check_after_solve(ks: KinematicSetup, sigma_free: np.ndarray, prior_sigma: float, captures) -> None:
    """Refuse when a free offset's posterior sigma is hardly below its prior: the data do not determine it."""
    q = np.array([ks.q_rad[k] for k in captures])
    span = q.max(axis=0) - q.min(axis=0)
    for i, s in zip(ks.free, sigma_free):
        if s > MAX_SIGMA_FRACTION_OF_PRIOR * prior_sigma:
            raise ObservabilityError(
                f"joint {i + 1}'s offset is not determined by these captures (1-sigma {1e3 * s:.2f} mrad against a prior "
                f"of {1e3 * prior_sigma:.1f} mrad; the joint spans {np.degrees(span[i]):.1f} deg). Add captures with the "
                "joints before and after it at varied angles, or solve without --estimate-kinematics.")


def make_kinematic_factor(key_flange, key_offsets, q_rad: np.ndarray, ks: KinematicSetup, noise,
                          mode: str = "eye_to_hand") -> gtsam.CustomFactor:
    """r = Log(FK(q + o)^-1 T_base_flange) with the robot pose at ``key_flange`` (T_base_flange itself
    eye-to-hand, its inverse T_flange_base eye-in-hand, as F(k) is) and the free offsets at
    ``key_offsets``; ``noise``: the FK noise model (rotation first, flange axes)."""
    q = np.asarray(q_rad, float)
    free = list(ks.free)
    chain = ks.chain
    inverse = mode == "eye_in_hand"

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values, H):
        F = values.atPose3(key_flange)
        o = ks.full(values.atVector(key_offsets))
        T_fk, J = chain.fk_jacobian(q + o)
        E = gtsam.Pose3(T_fk).between(F.inverse() if inverse else F)
        e = gtsam.Pose3.Logmap(E)
        if H is not None:
            J_log = gtsam.Pose3.LogmapDerivative(E)
            # eye-in-hand: F Exp(x) -> F^-1 becomes Exp(-x) F^-1, so E -> E Exp(-Ad(F) x)
            H[0] = -J_log @ F.AdjointMap() if inverse else J_log
            # FK(q + o + d) = FK Exp(J d): E -> Exp(-J d) E = E Exp(-Ad(E^-1) J d)
            H[1] = -J_log @ E.inverse().AdjointMap() @ J[:, free]
        return e

    return gtsam.CustomFactor(noise, [key_flange, key_offsets], error_func)


def offsets_from_poses(ks: KinematicSetup, T_base_flange: dict, prior_sigma: float, fk_sigmas: np.ndarray,
                       iterations: int = 10) -> np.ndarray:
    """Free offsets that best explain flange poses (capture -> 4x4, e.g. from a camera-only solve):
    Gauss-Newton on the kinematic residuals with the offsets' prior (the 'kinematics' stage)."""
    caps = [k for k in T_base_flange if k in ks.q_rad]
    q = np.array([ks.q_rad[k] for k in caps])
    W = 1.0 / np.asarray(fk_sigmas, float)
    o = np.zeros(len(ks.free))
    for _ in range(iterations):
        T_fk, J = ks.chain.fk_jacobian(q + ks.full(o))
        A, b = [np.eye(len(o)) / prior_sigma], [-o / prior_sigma]
        for Tk, Jk, k in zip(T_fk, J, caps):
            e = gtsam.Pose3.Logmap(gtsam.Pose3(Tk).between(gtsam.Pose3(T_base_flange[k])))
            A.append(W[:, None] * Jk[:, list(ks.free)])
            b.append(W * e)
        step = np.linalg.lstsq(np.vstack(A), np.concatenate(b), rcond=None)[0]
        o = o + step
        if np.abs(step).max() < 1e-10:
            break
    return o


def stored_arm(result, where: str) -> tuple:
    """(the arm's kinematic model, its joint offsets (n,), the model's source) of a result that
    estimated joint offsets (its ``robot`` section): the model the solve used, else the settings', else
    the built-in Franka. InputError, prefixed ``where``, when the model cannot be read or has another
    number of joints."""
    rb = result.robot
    o = np.asarray(rb["joint_offsets_rad"], float)
    source = str(rb.get("model_source") or result.settings.get("kinematics_model") or "franka")
    try:
        chain = load_chain(source)
    except InputError as e:
        raise InputError(f"{where}: cannot read the arm's kinematic model the result was solved with ({e}); run the "
                         f"{where} where that URDF is, or solve again.") from None
    if chain.n_joints != o.size:
        raise InputError(f"{where}: the result has {o.size} joint offsets but the model {source!r} has {chain.n_joints} joints.")
    return chain, o, source


def corrected_flange_poses(ks: KinematicSetup, offsets_rad) -> dict:
    """capture -> (FK(q + offsets), its flange-frame Jacobian on the free offsets (6, n_free)): the
    flange poses as a user applies a calibration with joint offsets (the corrected arm, the reported
    angles). ``offsets_rad``: all n joints' offsets (result.json's ``robot.joint_offsets_rad``)."""
    caps = list(ks.q_rad)
    if not caps:
        return {}
    T, J = ks.chain.fk_jacobian(np.array([ks.q_rad[k] for k in caps]) + np.asarray(offsets_rad, float))
    return {k: (T[i], J[i][:, list(ks.free)]) for i, k in enumerate(caps)}


def robot_result(ks: KinematicSetup, o_free: np.ndarray, cov: np.ndarray, labels: list, prior_sigma: float,
                 staging: str) -> dict:
    """``result.json``'s ``robot`` section: offsets and their 1-sigma (all joints, fixed ones 0 with
    sigma None), the fixed joints with reasons, the correlations among the free offsets and each
    free offset's strongest correlation with another variable of the graph.

    ``cov``: joint covariance whose first ``len(free)`` rows are the offsets, the rest the variables
    named in ``labels`` (one label per row)."""
    nf = len(ks.free)
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    corr = cov / np.outer(d, d)
    o = ks.full(o_free)
    sig = [None] * ks.chain.n_joints
    for j, i in enumerate(ks.free):
        sig[i] = float(d[j])
    strongest = []
    for j, i in enumerate(ks.free):
        row = np.abs(corr[j, nf:])
        if row.size:
            m = int(np.argmax(row))
            strongest.append({"joint": i + 1, "with": labels[m], "correlation": float(corr[j, nf + m])})
    return {
        "model": ks.chain.name,
        "joint_names": list(ks.chain.joint_names),
        "joint_offsets_rad": o.tolist(),
        "joint_offsets_sigma_rad": sig,
        "estimated": [i + 1 for i in ks.free],
        "fixed": [{"joint": j, "reason": r} for j, r in ks.fixed],
        "prior_sigma_rad": prior_sigma,
        "staging": staging,
        "offset_correlations": corr[:nf, :nf].tolist(),
        "strongest_correlations": strongest,
        "convention": "physical joint angle = reported q_rad + joint_offsets_rad[i]",
    }
