#!/usr/bin/env python
"""Real hand-eye data, held out (issue 38): predict unseen robot poses, calibgraph against OpenCV.

Sets (each from a public repository, fetched as a bare git snapshot; a set whose images are absent
is listed as skipped, with the reason):

* RWHE-Calib ``Datasets/kuka_1``, ``kuka_2``, ``kuka_3`` (``ihtishamaliktk/RWHE-Calib``): a KUKA arm,
  eye-in-hand, no intrinsics given; square sizes from ``getSquareSize4dataset.m`` (20, 15, 60 mm),
  the boards' corner counts from the images (calib.io boards: 17 x 28, 17 x 24 and 7 x 8 inner
  corners); ``RobotPosesVec.txt`` holds one row-major ``T_base_flange`` per image, metres.
* industrial_calibration ``examples/data/test_set_10x10`` (eye-in-hand, a 10 x 10 modified circle
  grid, a Kinect-class 640 x 480 camera) and ``test_set_charuco`` (eye-to-hand, 16 poses; the same
  files as ``../shared/datasets/rct_static_camera_charuco``), read by calibgraph's RCT reader with
  the intrinsics the files give (calibgraph's defaults decide how far it trusts them).
* the MC-HEC recording (``../shared/datasets/mchec_medium_workcell``: four fixed cameras, a Franka arm
  holding a 3 x 4-corner board, 251 captures; copied into the work folder): one record per camera.
  calibgraph solves the four cameras jointly on each split's train captures (the split is of that
  camera's captures; every camera's views of those captures are used) and is scored on that
  camera's test views; the OpenCV methods calibrate that camera alone from its own train views.

Protocol per set: the captures in index order; 5 random splits (``numpy.random.default_rng(seed)``,
seeds 0-4, 2/3 train, 1/3 test) and odd/even (train on the odd positions and test on the even, and
the reverse): 7 splits. Every method calibrates on the train captures' detected corners only (the
same corners for all: calibgraph's detector). The test images' corners are then predicted from the
*reported* robot poses (``T_cam_board = inv(X) inv(P_k) T_mount_board``, with ``P_k = T_base_flange``
eye-in-hand and its inverse eye-to-hand) and scored against the detected corners: the held-out RMS
(root mean square of the 2-D residual's length, px) and the same in mm at the board (each corner's
miss times its depth over the focal length: the miss at the board's distance, across the line of
sight, as calibgraph's expected figure is stated).

Configurations: where captures revisit a joint target (``Problem.configurations``: the same joint
angles, or where none are recorded the same flange pose, within the arm's repeatability), the splits
deal configurations, not captures: every visit of a target goes to the same side, so that no held-out
capture is predicted from a revisit of its own pose (a real arm's error repeats with its configuration).
N and m below then count configurations; a set without revisits is split exactly as capture by capture.

Methods: ``calibgraph`` (the solver with its defaults; unknown intrinsics estimated in the joint
graph where the set gives none), OpenCV 4.x ``calibrateHandEye`` TSAI, PARK, HORAUD, ANDREFF,
DANIILIDIS and ``calibrateRobotWorldHandEye`` SHAH, LI, each with intrinsics from ``calibrateCamera``
on the train images (k1 k2 p1 p2 k3) and that call's board poses. The hand-eye methods do not
estimate the board's mount: it is the chordal mean over the train captures of ``P_k X T_cam_board[k]``;
SHAH and LI estimate it. OpenCV 4 runs in a separate venv (``scripts/_cv4_worker.py``, as
``bench_solver.py`` does).

Hand-eye spread and calibgraph's 1-sigma: the 5 random train sets overlap (any two share about 2/3
of their captures), so the spread of their estimates understates the scatter of independent train
sets of the same size. For an estimate that behaves like a mean over the m = 2N/3 train captures of
N, the variance across random subsets of m is sigma_m^2 (N - m) / (N - 1) (the finite-population
correction), so the random splits' spread is compared with the stated 1-sigma times
sqrt((N - m) / (N - 1)). The odd/even halves are disjoint: their difference has variance
2 sigma_half^2, and sigma_half^2 (N/2) / m is sigma_m^2. The two estimates of sigma_m^2 are pooled
with their degrees of freedom (4 and 1); the ratio stated / observed per axis is then reported. With
5 degrees of freedom a ratio's own scatter is about 30 %: one set's ratio says little, the pattern over
sets and axes says more.

Small sets (fewer than ``SMALL_SET`` = 12 configurations with the board, at least 5 captures; ViSP's samples have 8):
2/3-1/3 splits would train on 5 captures, so they are held out one at a time instead (leave-one-out,
n splits, train n - 1, test the one left out). The held-out RMS per method is then the mean over the
n splits, and calibgraph minus the best peer is paired over them with the SE sd / sqrt(n) (the test
captures are disjoint, so the n differences are nearly independent). The split scatter is the
jackknife's: with theta_i the hand-eye pose solved without capture i and theta_bar their mean
(``mean_pose``), per axis

    var_jack = (n - 1) / n * sum_i (theta_i - theta_bar)^2

(the deviations as :func:`deviation`, rotation vector and translation), which estimates the variance
of the estimate from all n captures; the all-capture solve's stated 1-sigma (and its redrawn part) is
set beside sqrt(var_jack) as stated / observed, per axis and pooled over the six (1 / sqrt(mean(
var_jack / stated^2))), with about n - 1 dof per axis (the jackknife of a smooth estimator behaves
like a sample variance of n - 1 dof; it tends to overstate the variance a little, never to hide it).
The spread column is the same jackknife standard error (its translation and rotation norms). The
protocol for sets of 12 captures or more is the one above, unchanged.

Also per set: the fit RMS (calibgraph solved on all captures, its predictions from the reported
poses scored on the same captures: the floor the robot's own error sets), calibgraph's expected
held-out error (result.json ``prediction`` from the all-capture solve: what the held-out test would
say without test data), and each OpenCV method's all-capture hand-eye pose against calibgraph's.

    python scripts/bench_heldout.py [--sets kuka_1,...] [--out scripts/results] [--cv4-python PY]
                                    [--rwhe GITDIR] [--ic GITDIR] [--work DIR] [--tag NAME]
                                    [--dataset NAME=PATH ...] [--sim-seeds 1,2,...]

ViSP's two eye-in-hand samples in ``../shared/datasets`` are the sets ``visp_2022`` and ``visp_2025``, read
by calibgraph's ViSP layout reader from a copy (its ``camera.xml`` device intrinsics; the 2022 folder names
no board, so the copy gets a ``target.yaml`` with ViSP's tutorial board, 9 x 6 inner corners of 26.2 mm;
the 2025 one has ViSP's ``chessboard-data.txt``). Any dataset folder calibgraph reads can be added with ``--dataset NAME=PATH`` (``--sets ''`` for it
alone). Where every capture records joint angles (eye-to-hand), calibgraph also runs with
``--estimate-kinematics joint-offsets`` (row "calibgraph joint-offsets"), its test corners predicted
from the reported joint angles through the arm with the estimated offsets.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import yaml
from scipy.special import digamma
from scipy.stats import chi2

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "scripts"))

from bench_solver import CV_METHODS, ensure_cv4_python, run_opencv  # noqa: E402
from calibgraph.core.camera import Intrinsics  # noqa: E402
from calibgraph.core.errors import CalibgraphError  # noqa: E402
from calibgraph.core.problem import SolverOptions  # noqa: E402
from calibgraph.detect.search import detect_image  # noqa: E402
from calibgraph.core.transforms import inv, log_so3, make_T, project_to_so3  # noqa: E402
from calibgraph.io.dataset import write_problem  # noqa: E402
from calibgraph.io.layouts import load_dataset  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402
from calibgraph.solver.solve.build import build_problem  # noqa: E402
from calibgraph.solver.robot.kinematics import corrected_flange_poses  # noqa: E402
from calibgraph.solver.robot.kinematics import setup as kin_setup  # noqa: E402
from calibgraph.solver.uncertainty.prediction import predicted_uv  # noqa: E402
from calibgraph.sim.kinematic_scene import make_kinematic_scene  # noqa: E402
from calibgraph.sim.synthetic_corners import make_scene  # noqa: E402

MIRROR = Path("/work/.mirror")
RWHE = {  # name -> (folder, rows, cols, pitch_m)
    "kuka_1": ("kuka_1", 17, 28, 0.020),
    "kuka_2": ("kuka_2", 17, 24, 0.015),
    "kuka_3": ("kuka_3", 8, 11, 0.060),  # 9 x 12 squares, ArUco markers in the white ones (not 7 x 8)
}
IC = {"ic_10x10": "test_set_10x10", "ic_charuco": "test_set_charuco"}
SHARED = {"mchec": "mchec_medium_workcell"}  # multi-camera sets in ../shared/datasets: one record per camera
# ViSP's hand-eye folders in ../shared/datasets, read as they are (a copy); the board for a folder that names none
VISP = {"visp_2022": ("visp_eye_in_hand_2022", {"kind": "checkerboard", "rows": 6, "cols": 9, "pitch_m": 0.0262}),
        "visp_2025": ("visp_eye_in_hand_2025", None)}
SMALL_SET = 12  # fewer configurations with the board: leave-one-out (module docstring)
MIN_CAPTURES = 5
SEEDS = (0, 1, 2, 3, 4)
# calibgraph with its defaults; where every capture records joint angles (eye-to-hand) also with
# --estimate-kinematics joint-offsets, applied as a user then applies it (the corrected arm, the reported angles)
CG_METHODS = ("calibgraph", "calibgraph joint-offsets")
METHODS = CG_METHODS + CV_METHODS


# ---------------------------------------------------------------------------------------------
# data
# ---------------------------------------------------------------------------------------------
def _git(git_dir: Path, *args) -> bytes:
    return subprocess.run(["git", "--git-dir", str(git_dir), *args], check=True, capture_output=True).stdout


def extract(git_dir: Path, prefix: str, dest: Path) -> str:
    """Copy ``prefix`` of the snapshot's HEAD into ``dest`` (once); '' or why it could not."""
    if (dest / ".complete").exists():
        return ""
    if not git_dir.exists():
        return f"no snapshot at {git_dir} (fetch the repository first)"
    names = _git(git_dir, "ls-tree", "-r", "--name-only", "HEAD", prefix).decode().split("\n")
    missing = []
    for name in filter(None, names):
        out = dest / name[len(prefix):].lstrip("/")
        out.parent.mkdir(parents=True, exist_ok=True)
        r = subprocess.run(["git", "--git-dir", str(git_dir), "show", f"HEAD:{name}"], capture_output=True)
        if r.returncode != 0:
            missing.append(name)
            continue
        out.write_bytes(r.stdout)
    if missing:
        return f"{len(missing)} files absent from the snapshot (first: {missing[0]})"
    (dest / ".complete").write_text(_git(git_dir, "rev-parse", "HEAD").decode())
    return ""


def rwhe_dataset(raw: Path, dest: Path, rows: int, cols: int, pitch_m: float) -> Path:
    """A calibgraph dataset (eye-in-hand, unknown intrinsics) of one RWHE-Calib folder."""
    if (dest / "dataset.yaml").exists():
        return dest
    images = sorted(p for p in raw.iterdir() if p.suffix.lower() in (".png", ".bmp"))
    poses = np.loadtxt(raw / "RobotPosesVec.txt").reshape(-1, 4, 4)
    if len(poses) != len(images):
        raise SystemExit(f"{raw}: {len(poses)} poses for {len(images)} images")
    h, w = cv2.imread(str(images[0]), cv2.IMREAD_GRAYSCALE).shape
    (dest / "captures").mkdir(parents=True, exist_ok=True)
    (dest / "images" / "cam").mkdir(parents=True, exist_ok=True)
    for k, (img, T) in enumerate(zip(images, poses)):
        link = dest / "images" / "cam" / img.name
        if not link.exists():
            link.symlink_to(img.resolve())
        cap = {"index": k, "T_base_flange": T.tolist(), "q_rad": None,
               "views": {"cam": {"image": f"images/cam/{img.name}", "detection": None}}}
        (dest / "captures" / f"{k:06d}.json").write_text(json.dumps(cap))
    head = {"format": "calibgraph-dataset/1", "mode": "eye_in_hand", "units": {"length": "m", "angle": "rad", "pixel": "px"},
            "target": {"kind": "checkerboard", "rows": rows, "cols": cols, "pitch_m": pitch_m},
            "cameras": {"cam": {"width_px": int(w), "height_px": int(h)}}}
    (dest / "dataset.yaml").write_text(yaml.safe_dump(head, sort_keys=False))
    return dest


def prepare(name: str, args, work: Path):
    """(dataset folder, '') or (None, why the set is skipped)."""
    if name in RWHE:
        folder, rows, cols, pitch = RWHE[name]
        raw = work / "raw" / "rwhe" / folder
        why = extract(args.rwhe, f"Datasets/{folder}", raw)
        return (None, why) if why else (rwhe_dataset(raw, work / "sets" / name, rows, cols, pitch), "")
    dest = work / "sets" / name
    if name in VISP:
        folder, board = VISP[name]
        src = REPO.parent / "shared" / "datasets" / folder
        if not src.exists():
            return None, f"{src} is not here"
        if not dest.exists():  # a copy: the solve writes its detection cache into the dataset's top folder
            shutil.copytree(src, dest)
            if board is not None and not (dest / "target.yaml").exists():  # the side file the layout reads
                (dest / "target.yaml").write_text(yaml.safe_dump({"target": board}, sort_keys=False))
        return dest, ""
    if name in SHARED:
        src = REPO.parent / "shared" / "datasets" / SHARED[name]
        if not src.exists():
            return None, f"{src} is not here"
        if not dest.exists():  # a copy: the solve may write its detection cache beside the dataset
            shutil.copytree(src, dest)
        return dest, ""
    why = extract(args.ic, f"examples/data/{IC[name]}", dest)
    return (None, why) if why else (dest, "")


# ---------------------------------------------------------------------------------------------
# geometry
# ---------------------------------------------------------------------------------------------
def mean_pose(Ts) -> np.ndarray:
    """Chordal mean rotation and mean translation."""
    Ts = np.asarray(Ts)
    return make_T(project_to_so3(Ts[:, :3, :3].sum(axis=0)), Ts[:, :3, 3].mean(axis=0))


def deviation(T, T_ref) -> np.ndarray:
    """(6,) rotation vector of R R_ref^T (rad), translation difference (m): the result's axes."""
    return np.concatenate([log_so3(T[:3, :3] @ T_ref[:3, :3].T), T[:3, 3] - T_ref[:3, 3]])


def robot_factor(T_base_flange: np.ndarray, mode: str) -> np.ndarray:
    """P_k with T_mount_board = P_k X T_cam_board[k]."""
    return T_base_flange if mode == "eye_in_hand" else inv(T_base_flange)


def score(model: dict, problem, test: set) -> dict:
    """Held-out residuals of the test captures' detections under ``model`` (X, mount, intr, scale)."""
    X, M, intr, scale = model["X"], model["mount"], model["intr"], model.get("scale", 1.0)
    caps = {c.index: c for c in problem.captures}
    applied = model.get("T_bf") or {}  # with joint offsets: FK(q + offsets) of the reported angles
    px, mm = [], []
    for d in problem.detections:
        if d.capture not in test:
            continue
        T_bf = applied.get(d.capture, caps[d.capture].T_base_flange)
        uv, pc = predicted_uv(X, T_bf, M, problem.mode, intr, problem.points_board_m[d.ids] * scale)
        e = uv - d.uv_px
        px.append(np.hypot(e[:, 0], e[:, 1]))
        mm.append(px[-1] * 1e3 * pc[:, 2] / intr.K[0, 0])
    px, mm = np.concatenate(px), np.concatenate(mm)
    return {"rms_px": float(np.sqrt(np.mean(px ** 2))), "rms_mm": float(np.sqrt(np.mean(mm ** 2))), "corners": int(len(px))}


# ---------------------------------------------------------------------------------------------
# methods
# ---------------------------------------------------------------------------------------------
def subset(problem, keep: set):
    return problem.with_(captures=tuple(c for c in problem.captures if c.index in keep),
                         detections=tuple(d for d in problem.detections if d.capture in keep))


def calibgraph_fits(problem, solved: dict | None = None) -> dict:
    """method -> fit(camera, train) -> that camera's model (:func:`camera_model`), raising
    CalibgraphError: "calibgraph" with its defaults and, where every capture records joint angles
    (eye-to-hand), "calibgraph joint-offsets" (``--estimate-kinematics joint-offsets``). One solve per
    method and train set, shared by the cameras. ``solved``: the (method, frozenset(train)) -> Result
    (or CalibgraphError) cache to fill and reuse (a caller's own solve of a train set, or one to read)."""
    variants = {"calibgraph": problem}
    if problem.mode == "eye_to_hand" and problem.records_joint_angles:
        variants["calibgraph joint-offsets"] = problem.with_(options=replace(problem.options, kinematics="joint-offsets"))
    solved = {} if solved is None else solved

    def fit_of(meth, p):
        def fit(cam, train):
            key = (meth, frozenset(train))
            if key not in solved:
                try:
                    solved[key] = solve(subset(p, train))
                except CalibgraphError as e:
                    solved[key] = e
            r = solved[key]
            if isinstance(r, CalibgraphError):
                raise r
            return camera_model(r, cam, [x for x in r.notes if not x.startswith("camera ") or x.startswith(f"camera {cam}:")],
                                p)
        return fit

    return {meth: fit_of(meth, p) for meth, p in variants.items()}


def camera_model(r, name: str, notes: list, problem=None) -> dict:
    """Camera ``name`` of result ``r`` as the bench uses it; CalibgraphError when it is not calibrated.
    With joint offsets estimated (``r.robot``), ``T_bf``: each capture of ``problem`` at FK(q + offsets)."""
    cam = r.cameras[name]
    if not cam.calibrated:
        raise CalibgraphError(f"not calibrated: {cam.why}")
    T_bf = None
    if problem is not None and r.robot and r.robot.get("joint_offsets_rad") is not None:
        # the default ('auto') may have chosen the offsets: the arm set up as the offset model has it
        poses = corrected_flange_poses(kin_setup(problem.with_(options=replace(problem.options, kinematics="joint-offsets"))),
                                       r.robot["joint_offsets_rad"])
        T_bf = {k: T for k, (T, _) in poses.items()}
    return {"X": cam.T_ref_cam, "mount": r.T_mount_board, "intr": cam.solved_intrinsics, "scale": r.board_scale, "T_bf": T_bf,
            "cov": cam.covariance, "cov_redrawn": redrawn_covariance(cam),
            "rms_fit_px": cam.reprojection_rms_px, "fk_noise": r.fk_noise,
            "prediction": cam.prediction, "notes": notes}


def redrawn_covariance(cam) -> np.ndarray:
    """The part of a camera's covariance a new set of captures redraws: the corners' and the robot's
    noise (``error_budget.covariance_by_noise_source``); the intrinsics' and the board's priors' parts
    are shared by every split and cannot show in their scatter."""
    parts = (cam.error_budget or {}).get("covariance_by_noise_source") or {}
    if not parts:
        return cam.covariance
    return np.asarray(parts["corners"]) + np.asarray(parts["robot_fk"])


def opencv_inputs(problem, train: set) -> tuple:
    """(intrinsics, A, B, P): calibrateCamera on the train detections; A = inv(P_k) for the worker."""
    dets = sorted((d for d in problem.detections if d.capture in train and len(d.ids) >= 6), key=lambda d: d.capture)
    cam = next(iter(problem.cameras.values()))
    obj = [problem.points_board_m[d.ids].astype(np.float32) for d in dets]
    img = [d.uv_px.astype(np.float32) for d in dets]
    _, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, (cam.width_px, cam.height_px), None, None)
    intr = Intrinsics(K=K, dist=dist.ravel()[:5], width_px=cam.width_px, height_px=cam.height_px, source="exact")
    caps = {c.index: c for c in problem.captures}
    P = np.array([robot_factor(caps[d.capture].T_base_flange, problem.mode) for d in dets])
    B = np.array([make_T(cv2.Rodrigues(rv)[0], tv.ravel()) for rv, tv in zip(rvecs, tvecs)])
    return intr, np.array([inv(p) for p in P]), B, P


def opencv_models(py: str, problem, splits: list) -> tuple[list, str]:
    """Per split: {method: model} for the seven OpenCV methods."""
    inputs = [opencv_inputs(problem, train) for train, _ in splits]
    res, version = run_opencv(py, [(A, B) for _, A, B, _ in inputs])
    out = []
    for (intr, _A, B, P), r in zip(inputs, res):
        models = {}
        for m in CV_METHODS:
            X = r[m]
            if not np.all(np.isfinite(X)):
                continue
            M = r.get(f"{m}_mount")
            if M is None:
                M = mean_pose([p @ X @ b for p, b in zip(P, B)])
            models[m] = {"X": X, "mount": M, "intr": intr}
        out.append(models)
    return out, version


# ---------------------------------------------------------------------------------------------
# the bench
# ---------------------------------------------------------------------------------------------
def units(indices: list, config: dict | None = None) -> list:
    """The split units of the captures ``indices``: [(first capture, its captures)] in index order, one per
    configuration (``config``: capture -> the first capture at its joint target, ``Problem.configurations``),
    so that every visit of a joint target goes to the same side of a split and no held-out capture is
    predicted from a revisit of its own pose. Without ``config`` (or without revisits) each capture alone."""
    groups = {}
    for k in sorted(indices):
        groups.setdefault((config or {}).get(k, k), []).append(k)
    return sorted(groups.items())


def make_splits(indices: list, config: dict | None = None) -> list:
    """[(train, test, label)]: 5 random 2/3-1/3 splits and the odd/even halves both ways, of the
    configurations (:func:`units`; the captures themselves where none is revisited)."""
    u = units(indices, config)
    n = len(u)
    m = int(round(2 * n / 3))

    def caps(idx):
        return {k for i in idx for k in u[i][1]}

    out = []
    for s in SEEDS:
        perm = np.random.default_rng(s).permutation(n)
        out.append((caps(perm[:m]), caps(perm[m:]), f"random seed {s}"))
    odd, even = caps(range(1, n, 2)), caps(range(0, n, 2))
    out += [(odd, even, "train odd"), (even, odd, "train even")]
    return out


def loo_splits(indices: list, config: dict | None = None) -> list:
    """[(train, test, label)]: each configuration (:func:`units`; each capture where none is revisited)
    held out once (leave-one-out), for sets of fewer than SMALL_SET configurations."""
    return [(set(indices) - set(g), set(g), f"leave out {k}" if len(g) == 1 else
             f"leave out {k} (configuration of captures {', '.join(map(str, g))})") for k, g in units(indices, config)]


def is_loo(splits: list) -> bool:
    return bool(splits) and all(lab.startswith("leave out ") for _, _, lab in splits)


def jackknife_var(Xs: list) -> np.ndarray:
    """(6,) the jackknife variance (n - 1) / n * sum (theta_i - theta_bar)^2 of the leave-one-out
    estimates ``Xs`` (rad^2, m^2): the variance of the estimate from all n captures."""
    n = len(Xs)
    ref = mean_pose(Xs)
    dev = np.array([deviation(X, ref) for X in Xs])
    return (n - 1) / n * np.sum(dev ** 2, axis=0)


def jackknife_sigma(models: list, full: dict, cov: str) -> dict:
    """:func:`sigma_ratio`'s record for leave-one-out: the all-capture solve's stated 1-sigma (``cov``:
    ``"cov"`` or ``"cov_redrawn"``) against the jackknife's sqrt(var_jack) of the n leave-one-out solves."""
    var = jackknife_var([mod["X"] for mod in models])
    stated = np.sqrt(np.diag(full[cov]))
    return {"observed_sigma_m": np.sqrt(var).tolist(), "stated_sigma_m": stated.tolist(),
            "ratio": (stated / np.sqrt(var)).tolist(), "ratio_pooled": float(1.0 / np.sqrt(np.mean(var / stated ** 2))),
            "dof": len(models) - 1, "protocol": "jackknife"}


def jackknife_spread(Xs: list) -> dict:
    """:func:`spread`'s keys for leave-one-out: the jackknife standard error of the all-capture estimate."""
    var = jackknife_var(Xs)
    return {"sd_per_axis": np.sqrt(var).tolist(), "rms_translation_mm": 1e3 * float(np.sqrt(var[3:].sum())),
            "rms_rotation_deg": float(np.degrees(np.sqrt(var[:3].sum()))), "protocol": "jackknife"}


def sigma_ratio(X_random: list, X_halves: list, sig_random: np.ndarray, sig_halves: np.ndarray, n: int, m: int) -> dict:
    """Stated 1-sigma over the observed split-to-split scatter per axis, the overlap accounted for
    (module docstring). ``sig_*``: stated sigmas (6,) (rad, m), the RMS over the solves."""
    ref = mean_pose(X_random)
    dev = np.array([deviation(X, ref) for X in X_random])
    var_random = dev.var(axis=0, ddof=1) / ((n - m) / (n - 1))  # -> sigma_m^2
    d = deviation(X_halves[0], X_halves[1])
    var_halves = d ** 2 / 2.0 * (n / 2) / m  # -> sigma_m^2
    dof_r, dof_h = len(X_random) - 1, 1
    pooled = (dof_r * var_random + dof_h * var_halves) / (dof_r + dof_h)
    stated = np.sqrt((dof_r * sig_random ** 2 + dof_h * sig_halves ** 2 * (n / 2) / m) / (dof_r + dof_h))
    # all six axes pooled: the RMS of the observed scatter in units of the stated 1-sigma (about 6 x 5 dof)
    pooled_ratio = 1.0 / np.sqrt(np.mean(pooled / stated ** 2))
    return {"observed_sigma_m": np.sqrt(pooled).tolist(), "stated_sigma_m": stated.tolist(),
            "ratio": (stated / np.sqrt(pooled)).tolist(), "ratio_pooled": float(pooled_ratio), "ratio_random_only":
                (sig_random / np.sqrt(var_random)).tolist(), "dof": dof_r + dof_h}


def split_sigma(models: list, rand: list, halves: list, n: int, m: int, cov: str) -> dict:
    """:func:`sigma_ratio` of the models' ``cov`` (``"cov"``: the stated covariance; ``"cov_redrawn"``:
    its part the splits can show)."""
    def sig(idx):
        return np.sqrt(np.mean([np.diag(models[i][cov]) for i in idx], axis=0))
    return sigma_ratio([models[i]["X"] for i in rand], [models[i]["X"] for i in halves], sig(rand), sig(halves), n, m)


def spread(X_random: list) -> dict:
    ref = mean_pose(X_random)
    dev = np.array([deviation(X, ref) for X in X_random])
    return {"sd_per_axis": dev.std(axis=0, ddof=1).tolist(),
            "rms_translation_mm": 1e3 * float(np.sqrt(np.mean(np.sum(dev[:, 3:] ** 2, axis=1)))),
            "rms_rotation_deg": float(np.degrees(np.sqrt(np.mean(np.sum(dev[:, :3] ** 2, axis=1)))))}


def each_image(ds):
    """The Problem of ``ds`` with every image searched on its own by calibgraph's image detector
    (``detect_image``), for a set the dataset-level detection refuses (its early board-spec check)."""
    def detect(view, dataset):
        grey = cv2.imread(str(dataset.root / view.image), cv2.IMREAD_GRAYSCALE)
        intr = dataset.cameras.get(view.camera)
        d = detect_image(grey, dataset.target, intr if intr is not None and intr.known else None)
        return (d.ids, d.uv_px) if d.ok and len(d.ids) >= 6 else None

    return ds.to_problem(method="joint", options=SolverOptions(), detector=detect)


def _outer_square(grey, uv, rows: int, cols: int, corner: int) -> float:
    """Grey level of the square diagonally outside corner 0 (corner=0) or the last corner (-1)."""
    g = uv.reshape(rows, cols, 2)
    if corner:
        g = g[::-1, ::-1]
    c = g[0, 0] - 0.5 * (g[0, 1] - g[0, 0]) - 0.5 * (g[1, 0] - g[0, 0])
    x, y = int(round(c[0])), int(round(c[1]))
    return float(grey[np.clip(y, 0, grey.shape[0] - 1), np.clip(x, 0, grey.shape[1] - 1)])


def opencv_sb(ds):
    """The Problem of ``ds`` with OpenCV's SB chessboard detector's corners (a board of rows x cols
    inner corners with an odd and an even number of squares: corner 0 is put at the darker of the two
    outer corner squares, which fixes the 180-degree ambiguity the same way in every view)."""
    t = ds.target

    def detect(view, dataset):
        grey = cv2.imread(str(dataset.root / view.image), cv2.IMREAD_GRAYSCALE)
        ok, c = cv2.findChessboardCornersSB(grey, (t.cols, t.rows), flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        if not ok:
            return None
        uv = c.reshape(-1, 2).astype(float)
        if _outer_square(grey, uv, t.rows, t.cols, 0) > _outer_square(grey, uv, t.rows, t.cols, -1):
            uv = uv[::-1].copy()
        return np.arange(len(uv)), uv

    return ds.to_problem(method="joint", options=SolverOptions(), detector=detect)


DEFAULT_DETECTION = "calibgraph's dataset detection (as `calibgraph solve` runs it)"


def run_set(name: str, folder: Path, py: str | None, target=None, solved: dict | None = None) -> dict:
    """The bench on a one-camera set (``target``: the board of a layout that names none, as --target)."""
    ds = load_dataset(folder, target=target)
    problem, detection, _ = detect_set(name, ds)
    return evaluate_set(name, problem, py, detection, ds, solved)


def evaluate_set(name: str, problem, py: str | None, detection: str, ds, solved: dict | None = None) -> dict:
    """:func:`evaluate` of a one-camera ``problem`` with calibgraph's fits (``solved``: their cache)."""
    cam = next(iter(problem.cameras))
    return evaluate(name, problem, py, {m: (lambda train, f=f: f(cam, train))
                                        for m, f in calibgraph_fits(problem, solved).items()}, detection, ds)


def detect_set(name: str, ds) -> tuple:
    """(problem, how its corners were found, '' or the line `calibgraph solve` refuses the set with): the
    dataset detection as `calibgraph solve` runs it; where it refuses, calibgraph's image detector on each
    image alone, and OpenCV's SB chessboard detector where that finds too few."""
    detection, refused = DEFAULT_DETECTION, ""
    try:
        problem, _ = build_problem(ds, "joint", SolverOptions(), progress=False)
    except CalibgraphError as e:
        refused = str(e).splitlines()[0]
        print(f"[{name}] dataset detection refused ({str(e).splitlines()[0]}); each image on its own", flush=True)
        problem = each_image(ds)
        detection = (f"calibgraph's image detector on each image alone (`calibgraph solve` refuses the set: "
                     f"{str(e).splitlines()[0]})")
        if len({d.capture for d in problem.detections}) < 9 and ds.target.kind == "checkerboard" \
                and (ds.target.rows + ds.target.cols) % 2 == 1:
            found = len({d.capture for d in problem.detections})
            print(f"[{name}] {found} boards found that way; OpenCV's SB detector instead", flush=True)
            problem = opencv_sb(ds)
            detection = (f"OpenCV's findChessboardCornersSB (calibgraph refuses the set: {str(e).splitlines()[0]}; its "
                         f"image detector alone finds {found} of {len(ds.captures)} boards), the same corners for "
                         f"every method")
    return problem, detection, refused


def run_multicam(name: str, folder: Path, py: str | None, target=None, solved: dict | None = None) -> list:
    """One record per camera of a multi-camera set: calibgraph solves all cameras jointly on each
    split's train captures (every camera's views of them) and is scored on that camera's test
    views; the OpenCV methods calibrate that camera alone from its own train views."""
    ds = load_dataset(folder, target=target)
    problem, _ = build_problem(ds, "joint", SolverOptions(), progress=False)
    return evaluate_multicam(name, problem, py, ds, solved)


def evaluate_multicam(name: str, problem, py: str | None, ds, solved: dict | None = None) -> list:
    """:func:`run_multicam`'s records of a multi-camera ``problem`` (``solved``: the fits' cache)."""
    fits = calibgraph_fits(problem, solved)
    out = []
    for cam in problem.cameras:
        own = problem.with_(cameras={cam: problem.cameras[cam]},
                            detections=tuple(d for d in problem.detections if d.camera == cam))
        detection = (f"calibgraph's dataset detection (as `calibgraph solve` runs it); calibgraph solves the "
                     f"{len(problem.cameras)} cameras jointly on each split's train captures, the OpenCV methods this "
                     f"camera alone")
        out.append(evaluate(f"{name} {cam}", own, py, {m: (lambda train, f=f, cam=cam: f(cam, train))
                                                        for m, f in fits.items()}, detection, ds))
    return out


def evaluate(name: str, problem, py: str | None, fits: dict, detection: str, ds) -> dict:
    """The bench on one camera's detections (``problem``: that camera's); ``fits``: calibgraph method ->
    fit(train) giving its model (:func:`camera_model`'s keys) or raising CalibgraphError ("calibgraph"
    always)."""
    t0 = time.time()
    detected = sorted({d.capture for d in problem.detections})
    problem = subset(problem, set(detected))
    n = len(detected)
    if n < MIN_CAPTURES:
        return {"set": name, "skipped": f"{n} of {len(ds.captures)} images with the board found by {detection}: too few"}
    # the split units are the configurations: a revisit of a joint target goes with it (identical splits without)
    config = problem.configurations
    n_units = len(units(detected, config))
    splits = make_splits(detected, config) if n_units >= SMALL_SET else loo_splits(detected, config)
    m = len(splits[0][0])
    m_units = len(units(splits[0][0], config))
    out = {"set": name, "mode": problem.mode, "captures": len(ds.captures), "detected": n, "train": m, "detection": detection,
           "configurations": n_units, "train_configurations": m_units,
           "intrinsics_given": next(iter(problem.cameras.values())).known,
           "joint_angles": any(c.q_rad is not None for c in ds.captures), "splits": []}
    if is_loo(splits):
        out["protocol"] = "leave-one-out"
    print(f"[{name}] {n} captures detected of {len(ds.captures)}, mode {problem.mode}", flush=True)
    cgs = {meth: [] for meth in fits}
    for train, test, label in splits:
        for meth, fit in fits.items():
            try:
                cgs[meth].append(fit(train))
            except CalibgraphError as e:
                cgs[meth].append({"error": str(e).splitlines()[0]})
    cg = cgs["calibgraph"]
    cv_models, version = opencv_models(py, problem, [(tr, te) for tr, te, _ in splits]) if py else ([{}] * len(splits), "")
    out["cv2_version"] = version
    for i, ((train, test, label), c, cv) in enumerate(zip(splits, cg, cv_models)):
        row = {"label": label, "test": sorted(test)}
        models = dict(cv)
        for meth in fits:
            if "error" not in cgs[meth][i]:
                models[meth] = cgs[meth][i]
            else:
                row[f"{meth}_error".replace(" ", "_")] = cgs[meth][i]["error"]
        if "error" not in c:
            row["calibgraph_fk_noise"] = c["fk_noise"]
            row["calibgraph_prediction"] = c["prediction"]
        row["scores"] = {meth: score(mod, problem, test) for meth, mod in models.items()}
        out["splits"].append(row)
        print(f"[{name}] {label}: " + ", ".join(f"{k} {v['rms_px']:.2f}" for k, v in row["scores"].items()), flush=True)
    # the all-capture fit: floor, expected error, cross-method differences
    full = fits["calibgraph"](set(detected))
    out["fit_all"] = {"rms_px_predicted_same_captures": score(full, problem, set(detected)),
                      "prediction": full["prediction"], "fk_noise": full["fk_noise"], "notes": full["notes"],
                      "sigma": np.sqrt(np.diag(full["cov"])).tolist()}
    if py:
        cv_full, _ = opencv_models(py, problem, [(set(detected), set())])
        out["cross_method"] = {meth: {"deviation": deviation(mod["X"], full["X"]).tolist(),
                                      "z": (deviation(mod["X"], full["X"]) / np.sqrt(np.diag(full["cov"]))).tolist()}
                               for meth, mod in cv_full[0].items()}
    if is_loo(splits):
        out.update(loo_sigma(cgs, cv_models, full))
        out["seconds"] = time.time() - t0
        return out
    # spread and sigma
    rand = [i for i, (_, _, lab) in enumerate(splits) if lab.startswith("random")]
    halves = [i for i, (_, _, lab) in enumerate(splits) if lab.startswith("train ")]
    out["spread"] = {}
    per_method_X = {meth: [] for meth in METHODS}
    for i, cv in enumerate(cv_models):
        for meth in METHODS:
            mod = cgs[meth][i] if meth in cgs else cv.get(meth)
            per_method_X[meth].append(None if mod is None or "error" in mod else mod["X"])
    for meth, Xs in per_method_X.items():
        if all(Xs[i] is not None for i in rand):
            out["spread"][meth] = spread([Xs[i] for i in rand])
    if all("error" not in cg[i] for i in rand + halves):
        out["calibgraph_sigma"] = split_sigma(cg, rand, halves, n_units, m_units, "cov")
        out["calibgraph_sigma_redrawn"] = split_sigma(cg, rand, halves, n_units, m_units, "cov_redrawn")
    out["seconds"] = time.time() - t0
    return out


def loo_sigma(cgs: dict, cv_models: list, full: dict) -> dict:
    """Leave-one-out's spread (per method, :func:`jackknife_spread`) and calibgraph's stated / observed
    (:func:`jackknife_sigma`), over every split (a failed split leaves the method out)."""
    out = {"spread": {}}
    for meth in METHODS:
        Xs = [(cgs[meth][i] if meth in cgs else cv.get(meth)) for i, cv in enumerate(cv_models)]
        if all(x is not None and "error" not in x for x in Xs):
            out["spread"][meth] = jackknife_spread([x["X"] for x in Xs])
    cg = cgs["calibgraph"]
    if all("error" not in c for c in cg):
        out["calibgraph_sigma"] = jackknife_sigma(cg, full, "cov")
        out["calibgraph_sigma_redrawn"] = jackknife_sigma(cg, full, "cov_redrawn")
    return out


# ---------------------------------------------------------------------------------------------
# the protocol on simulated cells with a truth
# ---------------------------------------------------------------------------------------------
SIM_CASES = {
    "iid": "per-pose FK noise at the stated 0.1 mm / 0.01 deg, independent from pose to pose (the solver's model)",
    "offsets": "joint zero offsets of 0.5-2 mrad on joints 2-6, not estimated (an error that repeats from pose to "
               "pose, as a real arm's does); the robot's FK stated at 0.1 mm / 0.01 deg",
    "offsets_estimated": "the same cells solved with `--estimate-kinematics joint-offsets` (their captures record the "
                         "joint angles)",
}


def sim_scene(case: str, seed: int):
    """A 3-camera eye-to-hand cell (the simulator's default: 1.5, 3 and 5 m), 30 captures, 0.1 px corners,
    factory-class intrinsics reported."""
    if case == "iid":
        return make_scene(n_poses=30, pixel_sigma_px=0.1, fk_sigma_translation_m=1e-4,
                          fk_sigma_rotation_rad=float(np.radians(0.01)), seed=seed)
    rng = np.random.default_rng(1000 + seed)
    offsets = np.zeros(7)
    offsets[1:6] = rng.uniform(0.5e-3, 2e-3, 5) * rng.choice([-1, 1], 5)
    sc = make_kinematic_scene(offsets, n_poses=30, seed=seed, pixel_sigma_px=0.1)[0]
    # "offsets": the per-pose FK model, the offsets unmodelled (not left to the default's choice)
    kinematics = "joint-offsets" if case == "offsets_estimated" else "none"
    return replace(sc, problem=sc.problem.with_(options=replace(sc.problem.options, kinematics=kinematics)))


def write_offsets_set(seed: int, root: Path) -> Path:
    """The "offsets" case's cell of ``seed`` (:func:`sim_scene`) written as the dataset folder ``root``
    (its detections stored, its captures with the reported joint angles)."""
    if not root.exists():
        write_problem(root, sim_scene("offsets", seed).problem)
    return root


def sim_control(seeds: list) -> list:
    """The split protocol (:func:`make_splits`, :func:`split_sigma`) on simulated cells, where each train
    solve's error against the truth can be set beside it: per case, seed and camera, the stated 1-sigma
    and its redrawn part over the split scatter, and error / stated 1-sigma against the truth (RMS over
    the 7 train solves), per axis."""
    out = []
    for case in SIM_CASES:
        for seed in seeds:
            sc = sim_scene(case, seed)
            caps = sorted({d.capture for d in sc.problem.detections})
            splits = make_splits(caps)
            n, m = len(caps), len(splits[0][0])
            try:
                rs = [solve(subset(sc.problem, train)) for train, _, _ in splits]
            except CalibgraphError as e:  # said, not hidden: the seed is left out of the case
                print(f"[sim {case} seed {seed}] a split was refused: {str(e).splitlines()[0]}", flush=True)
                continue
            rand = [i for i, (_, _, lab) in enumerate(splits) if lab.startswith("random")]
            halves = [i for i, (_, _, lab) in enumerate(splits) if lab.startswith("train ")]
            for name in sc.problem.cameras:
                try:
                    models = [camera_model(r, name, []) for r in rs]
                except (CalibgraphError, KeyError):
                    continue
                z = np.array([deviation(mod["X"], sc.truth.T_ref_cam[name]) / np.sqrt(np.diag(mod["cov"])) for mod in models])
                out.append({"case": case, "seed": seed, "camera": name,
                            "stated": split_sigma(models, rand, halves, n, m, "cov"),
                            "redrawn": split_sigma(models, rand, halves, n, m, "cov_redrawn"),
                            "truth_z_rms": np.sqrt(np.mean(z ** 2, axis=0)).tolist()})
            print(f"[sim {case} seed {seed}] done", flush=True)
    return out


def sim_markdown(recs: list) -> list:
    if not recs:
        return []
    # an honest 1-sigma's stated / observed with 5 dof: its geometric mean is exp(-E[log(chi2_5 / 5)] / 2)
    honest_geo = float(np.exp(-0.5 * (digamma(2.5) + np.log(2.0 / 5.0))))
    L = ["## The protocol on simulated cells with a truth (control)", "",
         "The same splits and overlap correction on simulated 3-camera eye-to-hand cells (30 captures, 0.1 px corners, "
         "factory-class intrinsics reported and estimated), where each train solve's error against the truth can be set "
         "beside the split scatter. Per axis, the geometric mean over cameras and seeds of stated / observed (the "
         "split scatter), of its redrawn part / observed, and the RMS over every train solve of error / stated 1-sigma "
         f"against the truth (honest: 1). With 5 dof an honest 1-sigma's stated / observed has a geometric mean of "
         f"{honest_geo:.2f}, not 1.", ""]
    for case, label in SIM_CASES.items():
        rs = [r for r in recs if r["case"] == case]
        if not rs:
            continue
        geo = lambda key: np.exp(np.mean(np.log([r[key]["ratio"] for r in rs]), axis=0))  # noqa: E731
        z = np.sqrt(np.mean(np.square([r["truth_z_rms"] for r in rs]), axis=0))
        L += [f"**{label}** ({len(rs)} cameras, seeds {sorted({r['seed'] for r in rs})}):", "",
              "| | " + " | ".join(AXES) + " |", "|---" * 7 + "|",
              "| stated / split scatter | " + " | ".join(f"{x:.2f}" for x in geo("stated")) + " |",
              "| redrawn part / split scatter | " + " | ".join(f"{x:.2f}" for x in geo("redrawn")) + " |",
              "| error / stated, against the truth | " + " | ".join(f"{x:.2f}" for x in z) + " |", ""]
    return L


# ---------------------------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------------------------
AXES = ("rx", "ry", "rz", "x", "y", "z")


# with an honest 1-sigma, stated / observed is 1 / sqrt(chi2_dof / dof): its 95 % range over the six axes pooled
# (6 x dof) and how often one axis falls outside [0.6, 1.6] (dof 5 for the split protocol, n - 1 for leave-one-out)
def honest_pooled(dof: int) -> tuple:
    """The 95 % range of an honest 1-sigma's pooled stated / observed over six axes of ``dof`` each."""
    k = 6 * dof
    return 1.0 / np.sqrt(chi2.ppf(0.975, k) / k), 1.0 / np.sqrt(chi2.ppf(0.025, k) / k)


def honest_axis_outside(dof: int) -> float:
    """How often one axis's stated / observed (``dof``) of an honest 1-sigma falls outside [0.6, 1.6]."""
    return float(chi2.sf(dof / 0.6 ** 2, dof) + chi2.cdf(dof / 1.6 ** 2, dof))



def table(rec: dict) -> list:
    meths = [m for m in METHODS if all(m in s["scores"] for s in rec["splits"])]
    cg = [s["scores"].get("calibgraph", {}).get("rms_px") for s in rec["splits"]]
    loo = rec.get("protocol") == "leave-one-out"
    spread_head = (f"hand-eye jackknife SE ({len(rec['splits'])} leave-one-out), mm / deg" if loo else
                   "hand-eye spread (5 random), mm / deg")
    L = [f"| method | held-out RMS, px (mean of {len(rec['splits'])} splits) | per split, px | mm at the board | "
         f"calibgraph better on | {spread_head} |",
         "|---|---|---|---|---|---|"]
    best_peer = None
    for meth in meths:
        px = [s["scores"][meth]["rms_px"] for s in rec["splits"]]
        mm = [s["scores"][meth]["rms_mm"] for s in rec["splits"]]
        sp = rec["spread"].get(meth, {})
        better = "" if meth in CG_METHODS or None in cg else \
            f"{sum(a <= b for a, b in zip(cg, px))} of {len(px)}"
        L.append(f"| {meth} | **{np.mean(px):.3f}** | {' '.join(f'{x:.2f}' for x in px)} | {np.mean(mm):.3f} | {better} | "
                 f"{sp.get('rms_translation_mm', float('nan')):.2f} / {sp.get('rms_rotation_deg', float('nan')):.3f} |")
        if meth not in CG_METHODS and (best_peer is None or np.mean(px) < best_peer[1]):
            best_peer = (meth, float(np.mean(px)))
    rec["best_peer"] = best_peer
    return L


SCALE = np.array([np.degrees(1)] * 3 + [1e3] * 3)  # rad, m -> deg, mm


def sigma_table(s: dict, r: dict | None) -> list:
    """The stated 1-sigma (``s``) and its redrawn part (``r``, may be None) against the split scatter."""
    stated, obs = np.array(s["stated_sigma_m"]), np.array(s["observed_sigma_m"])
    if s.get("protocol") == "jackknife":
        first = ("calibgraph's stated 1-sigma of the all-capture solve against the jackknife's estimate of its scatter "
                 f"from the {s['dof'] + 1} leave-one-out solves ((n - 1) / n * sum (theta_i - theta_bar)^2, about "
                 f"{s['dof']} dof), per axis (rot deg, trans mm). ")
    else:
        first = ("calibgraph's stated 1-sigma of a train-set solve against the split-to-split scatter (overlap "
                 f"corrected, pooled over the random splits and the halves, {s['dof']} dof), per axis (rot deg, trans mm). ")
    lo, hi = honest_pooled(s["dof"])
    L = [first + "*Redrawn* is the part of the 1-sigma a new set of captures redraws (the corners' and the robot's noise, "
         "`error_budget.covariance_by_noise_source`): the intrinsics' and the board scale's priors are the same in "
         "every split and cannot show in their scatter.", "",
         "| | " + " | ".join(AXES) + " | pooled |", "|---" * 8 + "|",
         "| stated | " + " | ".join(f"{x:.4f}" for x in stated * SCALE) + " | |"]
    if r:
        L.append("| redrawn part | " + " | ".join(f"{x:.4f}" for x in np.array(r["stated_sigma_m"]) * SCALE) + " | |")
    L += ["| observed | " + " | ".join(f"{x:.4f}" for x in obs * SCALE) + " | |",
          "| stated / observed | " + " | ".join(f"{x:.2f}" for x in s["ratio"]) + f" | **{s['ratio_pooled']:.2f}** |"]
    if r:
        L.append("| redrawn / observed | " + " | ".join(f"{x:.2f}" for x in r["ratio"]) + f" | **{r['ratio_pooled']:.2f}** |")
    L += ["", f"Pooled: the observed scatter's RMS in stated 1-sigma over the six axes (about {6 * s['dof']} dof); an "
          f"honest 1-sigma lands in {lo:.2f}-{hi:.2f} 95 % of the time, one axis alone "
          f"({s['dof']} dof) outside [0.6, 1.6] {100 * honest_axis_outside(s['dof']):.0f} % of the time. Whether the split scatter is "
          "the measure to meet where the arm's error repeats from pose to pose: the simulated control below."]
    return L


def markdown(results: list, meta: dict) -> str:
    simulated = any(str(r.get("set", "")).startswith("sim_") for r in results)
    L = ["# Held-out prediction on " + ("hand-eye sets (sets named sim_... are simulated, with a truth)" if simulated
                                         else "real hand-eye sets") + " (issue 38)", "",
         f"Made by `python scripts/bench_heldout.py {meta['argv']}` at commit {meta['commit']} "
         f"({meta['date']}); OpenCV {meta.get('cv2_version') or '(not run)'} in a separate venv for the peers.",
         "", "Protocol, split overlap correction and methods: the script's docstring. RMS is of the 2-D residual's "
         "length. calibgraph runs with its defaults (unknown intrinsics estimated where the set gives none); the "
         "OpenCV methods with intrinsics from `calibrateCamera` on the same train corners. Where every capture records "
         "joint angles (eye-to-hand), `calibgraph joint-offsets` is calibgraph with `--estimate-kinematics "
         "joint-offsets`, its test corners predicted from the reported joint angles through the arm with the "
         "estimated offsets (as a user applies it); sets without joint angles have no such row.", ""]
    for rec in results:
        if "skipped" in rec:
            L += [f"## {rec['set']}: skipped", "", rec["skipped"], ""]
            continue
        loo = ", leave-one-out" if rec.get("protocol") == "leave-one-out" else ""
        L += [f"## {rec['set']} ({rec['mode']}, {rec['detected']} captures with the board of {rec['captures']}, "
              f"train {rec['train']}{loo}; intrinsics {'given' if rec['intrinsics_given'] else 'unknown'})", ""]
        L += [f"Corners: {rec['detection']}.", ""] + table(rec)
        fa = rec["fit_all"]
        L += ["", f"- Fit on all captures, its predictions from the reported poses scored on the same captures: "
                  f"{fa['rms_px_predicted_same_captures']['rms_px']:.3f} px, "
                  f"{fa['rms_px_predicted_same_captures']['rms_mm']:.3f} mm (the floor the robot's own error sets)."]
        p = fa.get("prediction")
        exp = [s["calibgraph_prediction"] for s in rec["splits"] if s.get("calibgraph_prediction")]
        if p and exp:
            got_px = [s["scores"]["calibgraph"]["rms_px"] for s in rec["splits"]]
            got_mm = [s["scores"]["calibgraph"]["rms_mm"] for s in rec["splits"]]
            L.append(f"- calibgraph's expected held-out error (`prediction`, no test data), RMS over the {len(exp)} train solves: "
                     f"{np.sqrt(np.mean([e['expected_rms_px'] ** 2 for e in exp])):.3f} px, "
                     f"{np.sqrt(np.mean([e['expected_rms_mm'] ** 2 for e in exp])):.3f} mm at the board; measured "
                     f"{np.sqrt(np.mean(np.square(got_px))):.3f} px / {np.sqrt(np.mean(np.square(got_mm))):.3f} mm "
                     f"(the all-capture solve expects {p['expected_rms_px']:.3f} px, {p['expected_rms_mm']:.3f} mm).")
        fk = fa.get("fk_noise")
        if fk:
            L.append(f"- FK accuracy the all-capture solve used: {1e3 * fk['used_sigma_translation_m']:.3f} mm, "
                     f"{np.degrees(fk['used_sigma_rotation_rad']):.4f} deg (stated {1e3 * fk['stated_sigma_translation_m']:.3f} "
                     f"mm, {np.degrees(fk['stated_sigma_rotation_rad']):.4f} deg).")
        cvs = [(s.get("calibgraph_fk_noise") or {}).get("cross_validation") for s in rec["splits"]]
        if any(cvs):
            chosen = [("not run" if not c else c["chosen"] or "(jackknife only)") for c in cvs]
            jk = [c.get("jackknife_variance_factor", 1.0) for c in cvs if c]
            L.append(f"- The robot's error split the held-out captures chose (`fk_noise.cross_validation`), per train "
                     f"split: {', '.join(chosen)}; the folds' jackknife variance factor {min(jk):.2f}-{max(jk):.2f}.")
        if rec.get("best_peer"):
            cgm = np.mean([s["scores"]["calibgraph"]["rms_px"] for s in rec["splits"]])
            # paired over the splits (each split's test captures scored by both): the difference's mean and
            # standard error, the splits' overlap ignored (it makes the SE an underestimate, if anything)
            d = np.array([s["scores"]["calibgraph"]["rms_px"] - s["scores"][rec["best_peer"][0]]["rms_px"]
                          for s in rec["splits"]])
            se = float(d.std(ddof=1) / np.sqrt(len(d)))
            L.append(f"- Best peer {rec['best_peer'][0]} {rec['best_peer'][1]:.3f} px; calibgraph {cgm:.3f} px "
                     f"({'at least as good' if cgm <= rec['best_peer'][1] + 1e-9 else 'WORSE'}); calibgraph minus "
                     f"{rec['best_peer'][0]}, paired over the {len(d)} splits: {d.mean():+.3f} +- {se:.3f} px (1 SE).")
        ko = [s_["scores"].get("calibgraph joint-offsets", {}).get("rms_px") for s_ in rec["splits"]]
        refused = [s_["calibgraph_joint-offsets_error"] for s_ in rec["splits"] if "calibgraph_joint-offsets_error" in s_]
        if refused:
            L.append(f"- calibgraph joint-offsets refused on {len(refused)} of {len(ko)} train splits (first: {refused[0]}).")
        elif all(x is not None for x in ko):
            d = np.array(ko) - np.array([s_["scores"]["calibgraph"]["rms_px"] for s_ in rec["splits"]])
            L.append(f"- calibgraph joint-offsets {np.mean(ko):.3f} px (predicted from the reported joint angles); minus "
                     f"calibgraph with its defaults, paired over the {len(d)} splits: {d.mean():+.3f} +- "
                     f"{d.std(ddof=1) / np.sqrt(len(d)):.3f} px (1 SE).")
        s = rec.get("calibgraph_sigma")
        if s:
            L += [""] + sigma_table(s, rec.get("calibgraph_sigma_redrawn"))
        cm = rec.get("cross_method")
        if cm:
            L += ["", "Each OpenCV method's all-capture hand-eye pose minus calibgraph's (rot deg, trans mm; "
                  "in calibgraph's 1-sigma in brackets):", "", "| method | " + " | ".join(AXES) + " |", "|---" * 7 + "|"]
            for meth, v in cm.items():
                d = np.array(v["deviation"]) * np.array([np.degrees(1)] * 3 + [1e3] * 3)
                L.append(f"| {meth} | " + " | ".join(f"{a:.3f} ({z:+.1f})" for a, z in zip(d, v["z"])) + " |")
        L.append("")
    L += sim_markdown(meta.get("sim_control") or [])
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sets", default="kuka_1,kuka_2,kuka_3,ic_10x10,ic_charuco,mchec,visp_2022,visp_2025")
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    ap.add_argument("--work", type=Path, default=Path("/tmp/bench_heldout"), help="extracted sets and the OpenCV venv")
    ap.add_argument("--rwhe", type=Path, default=MIRROR / "ihtishamaliktk+RWHE-Calib" / "repo")
    ap.add_argument("--ic", type=Path, default=MIRROR / "ros-industrial+industrial_calibration" / "repo")
    ap.add_argument("--cv4-python", default=None)
    ap.add_argument("--tag", default="", help="suffix of the result files (bench_heldout_TAG.md)")
    ap.add_argument("--dataset", action="append", default=[], metavar="NAME=PATH",
                    help="also any dataset folder calibgraph reads (its layouts), copied into --work first; repeatable")
    ap.add_argument("--sim-joint-offsets", default="", metavar="SEEDS",
                    help="also simulated eye-to-hand sets whose arm has joint zero offsets and whose captures record "
                         "joint angles (seeds, comma-separated): the joint-offset row on a set with a truth")
    ap.add_argument("--sim-seeds", default="1,2,3,4,5,6,7,8,9", help="seeds of the simulated control ('' to skip it)")
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    py, why = ensure_cv4_python(args.work, args.cv4_python)
    if py is None:
        print(f"OpenCV peers skipped: {why}", file=sys.stderr)
    results = []
    specs = list(args.dataset)
    for seed in [int(x) for x in args.sim_joint_offsets.split(",") if x.strip()]:
        name = f"sim_joint_offsets_seed{seed}"  # written where the loop below looks for its copy: not copied again
        specs.append(f"{name}={write_offsets_set(seed, args.work / 'sets' / f'dataset_{name}')}")
    for spec in specs:
        name, _, path = spec.partition("=")
        src = Path(path or name)
        if not src.is_dir():
            results.append({"set": name, "skipped": f"{src} is not a dataset folder"})
            continue
        dest = args.work / "sets" / f"dataset_{name}"
        if not dest.exists():  # a copy: the solve writes its detection cache beside the dataset, never into the user's
            shutil.copytree(src, dest)
        try:
            multi = len(load_dataset(dest).cameras) > 1
            results += run_multicam(name, dest, py) if multi else [run_set(name, dest, py)]
        except CalibgraphError as e:
            results.append({"set": name, "skipped": f"calibgraph refused the set: {str(e).splitlines()[0]}"})
    for name in [x for x in args.sets.split(",") if x]:
        folder, skip = prepare(name, args, args.work)
        if folder is None:
            results.append({"set": name, "skipped": skip})
            continue
        try:
            if name in SHARED:
                results += run_multicam(name, folder, py)
            else:
                results.append(run_set(name, folder, py))
        except CalibgraphError as e:  # e.g. calibgraph's detector refuses the set: said, not hidden
            results.append({"set": name, "skipped": f"calibgraph refused the set: {str(e).splitlines()[0]}"})
    sim = sim_control([int(x) for x in args.sim_seeds.split(",") if x.strip()])
    commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    if subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no", "--", ".",
                       ":!scripts/results"], capture_output=True, text=True).stdout.strip():  # code, not earlier figures
        commit += " (with uncommitted changes)"
    meta = {"argv": shlex.join(sys.argv[1:]), "commit": commit, "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "cv2_version": next((r.get("cv2_version") for r in results if r.get("cv2_version")), ""), "sim_control": sim}
    md = markdown(results, meta)
    stem = "bench_heldout" + (f"_{args.tag}" if args.tag else "")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"{stem}.md").write_text(md)
    (args.out / f"{stem}.json").write_text(json.dumps({"meta": meta, "sets": results}, indent=1, default=float))
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
