#!/usr/bin/env python
"""Benchmark of the calibgraph solver: accuracy vs the Cramer-Rao bound, OpenCV 4.x baselines, run times.

Monte Carlo on seeded synthetic eye-to-hand workcells (:func:`calibgraph.sim.synthetic_corners.make_scene`): three
fixed cameras on a ring at 1.5 / 3 / 5 m, D455-like or L515-like intrinsics, the thesis's board
(5 x 4 squares of 46 mm -> 12 corners) or a 7 x 10 board of 25 mm squares (54 corners), 20 or 110
robot poses, corner noise 0.1 / 0.3 / 1 px, forward-kinematics noise 0 or Panda-class
(0.1 mm / 0.01 deg per flange pose). For every configuration it reports, over all cameras and trials:

* translation / rotation error of ``T_base_cam`` vs truth (median, 95th percentile);
* the Cramer-Rao bound (:func:`calibgraph.solver.uncertainty.covariance.crlb`, inverse Fisher information at the truth with
  the true pixel sigma): ``sqrt(trace)`` of the translation and rotation blocks;
* error / CRLB = pooled RMS error / RMS CRLB sigma (1.0 = efficient estimator), and the solver's
  own reported sigma checked the same way (error / reported sigma, 1.0 = honest covariance);
* gross failures: an estimate off by more than 10x its CRLB sigma, or by more than 5 cm or 2 deg,
  or a solve that raised;
* solve time (``Result.solve_time_s``: initialisation + robust LM + marginals).

OpenCV baselines: ``calibrateHandEye`` (TSAI, PARK, HORAUD, ANDREFF, DANIILIDIS) and
``calibrateRobotWorldHandEye`` (SHAH, LI) exist only in OpenCV 4.x; calibgraph runs on OpenCV 5, so
the script creates (once) a separate venv ``OUT/.venv-cv4`` with ``opencv-python-headless<5`` and
runs ``scripts/_cv4_worker.py`` in it. Each camera is calibrated alone from the same data: the
reported robot poses and a per-view ``cv2.solvePnP`` (default iterative flag, as a user would call
it). The eye-to-hand argument conventions are checked on noise-free data before any number is used.

Timings: LM + marginals for 3 cameras x 110 poses x 54 corners (with a breakdown by stage),
16 cameras x 1000 poses (full run only), and iSAM2 ``IncrementalSolver.add_capture`` per capture.

Usage::

    python scripts/bench_solver.py --quick          # < 2 min
    python scripts/bench_solver.py                  # full run, ~20 min on 2 cores
    python scripts/bench_solver.py --out DIR --trials 10 --no-opencv

Writes ``OUT/bench_solver.json`` (every per-camera record) and ``OUT/bench_solver.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from calibgraph.core.errors import CalibgraphError  # noqa: E402
from calibgraph.core.problem import SolverOptions  # noqa: E402
from calibgraph.core.targets import a4_board_54, thesis_board  # noqa: E402
from calibgraph.core.transforms import inv, make_T, pose_error  # noqa: E402
from calibgraph.sim.synthetic_corners import Scene, make_scene, ring_cameras  # noqa: E402
from calibgraph.solver.solve.batch import STAGES, solve  # noqa: E402
from calibgraph.solver.uncertainty.covariance import crlb  # noqa: E402
from calibgraph.solver.fit.graph import Estimate, build_graph, levenberg_marquardt  # noqa: E402
from calibgraph.solver.terms.views import prepare_views  # noqa: E402
from calibgraph.solver.terms.keys import C  # noqa: E402

DISTANCES_M = (1.5, 3.0, 5.0)
PRESETS = ("d455", "l515")
BOARDS = {"thesis_46mm_12pt": thesis_board, "a4_25mm_54pt": a4_board_54}
POSES = (20, 110)
PIXEL_SIGMAS_PX = (0.1, 0.3, 1.0)
FK_LEVELS = {"0": (0.0, 0.0), "panda": (1e-4, float(np.radians(0.01)))}
# configuration i, trial t uses seed + SEED_STRIDE * i + t: independent scenes per configuration (with one
# seed for all, the three pixel-noise levels would share geometry and noise pattern and the pooled
# ratio would have a third of the samples it seems to have)
SEED_STRIDE = 100
GROSS_CRLB_FACTOR = 10.0
GROSS_T_M = 0.05
GROSS_R_DEG = 2.0
CV_METHODS = ("TSAI", "PARK", "HORAUD", "ANDREFF", "DANIILIDIS", "SHAH", "LI")
WORKER = Path(__file__).resolve().parent / "_cv4_worker.py"
# bars of issue 2
BAR_CRLB_RATIO = 1.10
BAR_OPENCV_FACTOR = 10.0
BAR_3CAM_S = 1.0
BAR_16CAM_S = 30.0
BAR_ISAM_S = 0.020


@dataclass(frozen=True)
class Config:
    preset: str
    board: str
    n_poses: int
    pixel_sigma_px: float
    fk: str

    @property
    def label(self) -> str:
        return f"{self.preset}/{self.board}/{self.n_poses}p/{self.pixel_sigma_px:g}px/fk={self.fk}"


# ---------------------------------------------------------------------------------------------
# scenes and one trial
# ---------------------------------------------------------------------------------------------
FORMULATION = None  # None = the engine's default; else SolverOptions.formulation ('view', 'corner', 'auto')


def _with_formulation(problem, formulation):
    """The problem with ``options.formulation`` replaced (when the engine has that option)."""
    if formulation is None:
        return problem
    if "formulation" not in SolverOptions.__dataclass_fields__:
        raise SystemExit("this calibgraph has no SolverOptions.formulation; drop --formulation")
    return dataclasses.replace(problem, options=dataclasses.replace(problem.options, formulation=formulation))


def _scene(cfg: Config, seed: int, cameras=None, formulation="default"):
    fk_t, fk_r = FK_LEVELS[cfg.fk]
    cams = cameras or ring_cameras(list(DISTANCES_M), presets=(cfg.preset,))
    sc = make_scene(cameras=cams, target=BOARDS[cfg.board](), n_poses=cfg.n_poses,
                    pixel_sigma_px=cfg.pixel_sigma_px, fk_sigma_translation_m=fk_t,
                    fk_sigma_rotation_rad=fk_r, seed=seed)
    form = FORMULATION if formulation == "default" else formulation
    # The CRLB below is the pose model's with the board's declared size; the solver's default also
    # estimates a board scale factor (the synthetic cameras' intrinsics are 'exact', held fixed):
    # hold the scale too, so the bench measures what it always measured.
    problem = dataclasses.replace(sc.problem, options=dataclasses.replace(sc.problem.options, board_scale=False))
    return Scene(_with_formulation(problem, form), sc.truth)


def _sqrt_trace(cov: np.ndarray) -> tuple[float, float]:
    """(translation sigma m, rotation sigma deg) as sqrt of the block traces of a rotation-first 6x6."""
    return float(np.sqrt(np.trace(cov[3:, 3:]))), float(np.degrees(np.sqrt(np.trace(cov[:3, :3]))))


def _gross_kinds(err_t_m, err_r_deg, crlb_t_m, crlb_r_deg) -> tuple[bool, bool]:
    """(relative, absolute): error > 10x CRLB sigma (or the solve raised), error > 5 cm / 2 deg.

    The two are kept apart because at 1 px with the 12-corner board at 5 m the CRLB sigma itself
    is a few cm: there an 'absolute' failure is the bound, not the estimator."""
    if not (np.isfinite(err_t_m) and np.isfinite(err_r_deg)):
        return True, True
    rel = bool(err_t_m > GROSS_CRLB_FACTOR * crlb_t_m or err_r_deg > GROSS_CRLB_FACTOR * crlb_r_deg)
    ab = bool(err_t_m > GROSS_T_M or err_r_deg > GROSS_R_DEG)
    return rel, ab


def _is_gross(err_t_m, err_r_deg, crlb_t_m, crlb_r_deg) -> bool:
    """The issue's definition: either kind."""
    return any(_gross_kinds(err_t_m, err_r_deg, crlb_t_m, crlb_r_deg))


def _pnp_T_cam_board(p_board_m, uv_px, intr) -> np.ndarray:
    """What a user would feed OpenCV's hand-eye: cv2.solvePnP with its default (iterative) flag."""
    ok, rvec, tvec = cv2.solvePnP(np.ascontiguousarray(p_board_m, np.float64).reshape(-1, 1, 3),
                                  np.ascontiguousarray(uv_px, np.float64).reshape(-1, 1, 2), intr.K, intr.dist)
    if not ok:
        return np.full((4, 4), np.nan)
    R, _ = cv2.Rodrigues(rvec)
    return make_T(R, np.asarray(tvec, float).reshape(3))


def _opencv_jobs(scene, exact_poses: bool = False, oracle: bool = False) -> dict:
    """name -> (A (n,4,4) reported T_base_flange, B (n,4,4) T_cam_board) per camera.

    ``oracle`` drops the views whose PnP rotation is > 3 deg off the truth (the planar-ambiguity
    flips), using knowledge no user has: an upper bound on what OpenCV's closed forms can do.
    """
    prob, truth = scene.problem, scene.truth
    caps = {c.index: c.T_base_flange for c in prob.captures}
    out = {}
    for name, intr in prob.cameras.items():
        A, B = [], []
        for d in prob.detections:
            if d.camera != name:
                continue
            A.append(caps[d.capture])
            T_true = inv(truth.T_ref_cam[name]) @ truth.T_base_flange_true[d.capture] @ truth.T_mount_board
            if exact_poses:
                B.append(T_true)
            else:
                B.append(_pnp_T_cam_board(prob.points_board_m[d.ids], d.uv_px, intr))
                if oracle and not (pose_error(B[-1], T_true)[1] < 3.0):
                    A.pop()
                    B.pop()
        out[name] = (np.array(A).reshape(-1, 4, 4), np.array(B).reshape(-1, 4, 4))
    return out


def mle_from_truth(problem, truth, pixel_sigma_px) -> dict | None:
    """Reference estimator: plain least squares (known pixel sigma, no robust loss, no view screening)
    started at the truth. Its error vs the CRLB says how far the *problem* is from the bound in small
    samples (nonlinearity); solve() vs this says how much the solver's own machinery costs. Built
    from the solver's internal API (calibgraph.solver.fit.graph); None when the LM run fails."""
    views, _ = prepare_views(problem)
    names = list(problem.cameras)
    slots = {n: i for i, n in enumerate(names)}
    est = Estimate(T_ref_cam=dict(truth.T_ref_cam), T_mount_board=truth.T_mount_board,
                   T_ref_mount=dict(truth.T_base_flange_true))
    try:
        graph, values = build_graph(views, slots, problem, est, pixel_sigma_px)
        out = levenberg_marquardt(graph, values, 100).values
    except CalibgraphError:  # optional diagnostic: a singular graph costs this column, not the trial
        return None
    return {n: out.atPose3(C(i)).matrix() for n, i in slots.items()}


def run_trial(cfg: Config, seed: int, with_opencv: bool) -> dict:
    scene = _scene(cfg, seed)
    prob, truth = scene.problem, scene.truth
    bound = crlb(prob, truth.T_ref_cam, truth.T_mount_board, cfg.pixel_sigma_px, truth.T_base_flange_true)
    error, result, solve_time_s = "", None, float("nan")
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        result = solve(prob)
        solve_time_s = result.solve_time_s
    except Exception as e:  # noqa: BLE001 - a raising solve is a gross failure; keep its message
        error = f"{type(e).__name__}: {str(e).splitlines()[0][:300] if str(e) else ''}"
        if not isinstance(e, CalibgraphError):
            error = "NOT A CalibgraphError (engine bug) " + error
        solve_time_s = time.perf_counter() - t0
    solve_cpu_s = time.process_time() - c0
    mle = mle_from_truth(prob, truth, cfg.pixel_sigma_px) if cfg.fk == "0" else None
    cams = []
    for i, name in enumerate(prob.cameras):
        crlb_t, crlb_r = _sqrt_trace(bound[name])
        rec = {"camera": name, "distance_m": DISTANCES_M[i], "crlb_t_m": crlb_t, "crlb_r_deg": crlb_r,
               "views": sum(1 for d in prob.detections if d.camera == name)}
        if result is not None:
            cr = result.cameras[name]
            et, er = pose_error(cr.T_ref_cam, truth.T_ref_cam[name])
            st, sr = _sqrt_trace(cr.covariance)
            rec.update(err_t_m=et, err_r_deg=er, sigma_t_m=st, sigma_r_deg=sr, views_used=cr.views_used,
                       reprojection_rms_px=cr.reprojection_rms_px)
        else:
            rec.update(err_t_m=float("inf"), err_r_deg=float("inf"), sigma_t_m=float("nan"),
                       sigma_r_deg=float("nan"), views_used=0, reprojection_rms_px=float("nan"))
        rec["gross_rel"], rec["gross_abs"] = _gross_kinds(rec["err_t_m"], rec["err_r_deg"], crlb_t, crlb_r)
        rec["gross"] = rec["gross_rel"] or rec["gross_abs"]
        # an absolute failure the bound predicts: the CRLB sigma is already > 1/3 of the 5 cm / 2 deg limit
        rec["gross_abs_crlb_limited"] = bool(rec["gross_abs"] and not rec["gross_rel"]
                                             and (crlb_t > GROSS_T_M / 3 or crlb_r > GROSS_R_DEG / 3))
        if mle is not None:
            rec["mle_err_t_m"], rec["mle_err_r_deg"] = pose_error(mle[name], truth.T_ref_cam[name])
        cams.append(rec)
    used = (result.settings or {}).get("formulation_used") if result is not None else None
    out = {"config": asdict(cfg), "seed": seed, "solve_time_s": solve_time_s, "solve_cpu_s": solve_cpu_s, "error": error,
           "formulation_used": used,
           "n_views": len(prob.detections), "cameras": cams}
    if with_opencv:
        out["_jobs"] = _opencv_jobs(scene)
        out["_jobs_oracle"] = _opencv_jobs(scene, oracle=True)
        out["_truth"] = {n: truth.T_ref_cam[n] for n in prob.cameras}
    return out


# ---------------------------------------------------------------------------------------------
# OpenCV 4.x in its own venv
# ---------------------------------------------------------------------------------------------
def ensure_cv4_python(out_dir: Path, override: str | None) -> tuple[str | None, str]:
    """Path of a python with opencv 4.x (venv created once under OUT), or (None, reason)."""
    check = "import cv2, sys; sys.exit(0 if cv2.__version__.startswith('4.') and hasattr(cv2, 'calibrateRobotWorldHandEye') else 1)"
    if override:
        ok = subprocess.run([override, "-c", check], capture_output=True).returncode == 0
        return (override, "") if ok else (None, f"{override} has no OpenCV 4.x with hand-eye functions")
    venv = out_dir / ".venv-cv4"
    py = venv / "bin" / "python"
    if py.exists() and subprocess.run([str(py), "-c", check], capture_output=True).returncode == 0:
        return str(py), ""
    print(f"creating {venv} with opencv-python-headless<5 (once) ...", file=sys.stderr, flush=True)
    r = subprocess.run([sys.executable, "-m", "venv", "--clear", str(venv)], capture_output=True, text=True)
    if r.returncode != 0:
        return None, f"python -m venv failed: {r.stderr.strip()[-300:]}"
    r = subprocess.run([str(py), "-m", "pip", "install", "-q", "opencv-python-headless<5", "numpy"],
                       capture_output=True, text=True)
    if r.returncode != 0 or subprocess.run([str(py), "-c", check], capture_output=True).returncode != 0:
        return None, f"pip could not install opencv-python-headless<5: {r.stderr.strip()[-300:]}"
    return str(py), ""


def run_opencv(py: str, jobs: list) -> tuple[list, str]:
    """jobs: list of (A, B). Returns (list of {method: T_base_cam, and the robot-world methods'
    '{method}_mount'}, cv2 version)."""
    with tempfile.TemporaryDirectory() as tmp:
        fin, fout = Path(tmp) / "in.npz", Path(tmp) / "out.npz"
        arrays = {}
        for j, (A, B) in enumerate(jobs):
            arrays[f"j{j}_A"], arrays[f"j{j}_B"] = A, B
        np.savez(fin, **arrays)
        r = subprocess.run([py, str(WORKER), str(fin), str(fout)], capture_output=True, text=True)
        if r.returncode != 0:
            raise RuntimeError(f"OpenCV 4 worker failed: {r.stderr.strip()[-500:]}")
        data = np.load(fout)
        out = [{k[len(f"j{j}_"):]: data[k] for k in data.files if k.startswith(f"j{j}_")} for j in range(len(jobs))]
        return out, str(data["cv2_version"])


def opencv_convention_check(py: str) -> dict:
    """Noise-free scene: exact board poses must give ~0 error for every method (else the
    eye-to-hand argument convention is wrong); noise-free PnP poses are reported too."""
    cfg = Config("d455", "a4_25mm_54pt", 40, 0.0, "0")
    scene = _scene(cfg, seed=123)
    out = {}
    for kind, exact in (("exact_poses", True), ("pnp_noise_free", False)):
        jobs = _opencv_jobs(scene, exact_poses=exact)
        names = list(jobs)
        res, _ = run_opencv(py, [jobs[n] for n in names])
        worst = {}
        for m in CV_METHODS:
            errs = [pose_error(r[m], scene.truth.T_ref_cam[n]) for n, r in zip(names, res)]
            worst[m] = (max(e[0] for e in errs), max(e[1] for e in errs))
        out[kind] = {m: {"max_err_t_m": w[0], "max_err_r_deg": w[1]} for m, w in worst.items()}
    bad = [m for m, w in out["exact_poses"].items() if not (w["max_err_t_m"] < 1e-6 and w["max_err_r_deg"] < 1e-4)]
    out["passed"] = not bad
    out["failed_methods"] = bad
    return out


# ---------------------------------------------------------------------------------------------
# statistics
# ---------------------------------------------------------------------------------------------
def _rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")


def _pct(x, q) -> float:
    x = np.asarray(x, float)
    return float(np.percentile(x, q)) if x.size else float("nan")


def summarize(recs: list) -> dict:
    """Statistics over per-camera records (successful solves for errors; failures counted)."""
    ok = [r for r in recs if np.isfinite(r["err_t_m"])]
    et = np.array([r["err_t_m"] for r in ok])
    er = np.array([r["err_r_deg"] for r in ok])
    ct = np.array([r["crlb_t_m"] for r in ok])
    cr = np.array([r["crlb_r_deg"] for r in ok])
    st = np.array([r["sigma_t_m"] for r in ok])
    sr = np.array([r["sigma_r_deg"] for r in ok])
    return {
        "n_estimates": len(recs),
        "n_solver_failures": len(recs) - len(ok),
        "n_gross": int(sum(r["gross"] for r in recs)),
        "n_gross_rel": int(sum(r["gross_rel"] for r in recs)),
        "n_gross_abs": int(sum(r["gross_abs"] for r in recs)),
        "n_gross_abs_crlb_limited": int(sum(r["gross_abs_crlb_limited"] for r in recs)),
        "err_t_mm_median": 1e3 * _pct(et, 50), "err_t_mm_p95": 1e3 * _pct(et, 95),
        "err_r_deg_median": _pct(er, 50), "err_r_deg_p95": _pct(er, 95),
        "crlb_t_mm_rms": 1e3 * _rms(ct), "crlb_r_deg_rms": _rms(cr),
        # pooled RMS error / RMS CRLB (the definition) ...
        "ratio_t": _rms(et) / _rms(ct) if ok else float("nan"),
        "ratio_r": _rms(er) / _rms(cr) if ok else float("nan"),
        # ... and normalised per estimate, so 1.5 m and 5 m cameras weigh the same
        "ratio_t_normalised": _rms(et / ct) if ok else float("nan"),
        "ratio_r_normalised": _rms(er / cr) if ok else float("nan"),
        # is the solver's reported covariance honest? (error / reported sigma, 1.0 = yes)
        "err_over_reported_sigma_t": _rms(et / st) if ok else float("nan"),
        "err_over_reported_sigma_r": _rms(er / sr) if ok else float("nan"),
        **_mle_stats(ok),
    }


def _mle_stats(ok: list) -> dict:
    m = [r for r in ok if "mle_err_t_m" in r]
    if not m:
        return {"mle_ratio_t": float("nan"), "mle_ratio_r": float("nan"), "solve_over_mle_t": float("nan"),
                "solve_over_mle_r": float("nan")}
    g = lambda k: np.array([r[k] for r in m])  # noqa: E731
    return {"mle_ratio_t": _rms(g("mle_err_t_m")) / _rms(g("crlb_t_m")),
            "mle_ratio_r": _rms(g("mle_err_r_deg")) / _rms(g("crlb_r_deg")),
            "solve_over_mle_t": _rms(g("err_t_m")) / _rms(g("mle_err_t_m")),
            "solve_over_mle_r": _rms(g("err_r_deg")) / _rms(g("mle_err_r_deg"))}


def _ratio_ci95(e: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """Bootstrap 95% interval of RMS(e)/RMS(c) over estimates (seeded)."""
    rng = np.random.default_rng(0)
    n = len(e)
    if n < 2:
        return float("nan"), float("nan")
    vals = []
    for _ in range(2000):
        i = rng.integers(0, n, n)
        vals.append(_rms(e[i]) / _rms(c[i]))
    return float(np.percentile(vals, 2.5)), float(np.percentile(vals, 97.5))


# ---------------------------------------------------------------------------------------------
# timings
# ---------------------------------------------------------------------------------------------
def time_batch(cfg: Config, repeats: int, seed: int, n_cams: int = 3, formulation="default") -> dict:
    if n_cams == 3:
        scene = _scene(cfg, seed, formulation=formulation)
    else:
        d = [DISTANCES_M[i % 3] for i in range(n_cams)]
        scene = _scene(cfg, seed, cameras=ring_cameras(d, presets=(cfg.preset,)), formulation=formulation)
    prob = scene.problem
    runs = []
    for _ in range(repeats):
        c0 = time.process_time()
        timings = {}
        res = solve(prob, timings=timings)  # the solver times its own stages (solver.solve.batch.STAGES)
        cpu = time.process_time() - c0
        stages = {k: timings.get(k, 0.0) for k in STAGES}
        stages["other"] = res.solve_time_s - sum(stages.values())
        runs.append({"solve_time_s": res.solve_time_s, "cpu_time_s": cpu, "iterations": res.iterations, "stages_s": stages,
                     "loadavg_1min": os.getloadavg()[0]})
    errs = {n: pose_error(c.T_ref_cam, scene.truth.T_ref_cam[n]) for n, c in res.cameras.items()}
    times = [r["solve_time_s"] for r in runs]
    return {"config": asdict(cfg), "formulation": (res.settings or {}).get("formulation_used", "view (engine without the option)"),
            "n_cameras": len(prob.cameras), "n_captures": len(prob.captures),
            "n_views": len(prob.detections), "n_corners": int(sum(len(d.ids) for d in prob.detections)),
            "solve_time_s_min": min(times), "solve_time_s_median": float(np.median(times)),
            "cpu_time_s_median": float(np.median([r["cpu_time_s"] for r in runs])), "runs": runs,
            "max_err_t_mm": 1e3 * max(e[0] for e in errs.values()), "max_err_r_deg": max(e[1] for e in errs.values())}


def _safe(f, *a, **k) -> dict:
    """Run a timing; an engine exception becomes a reported failure instead of losing the run."""
    try:
        return f(*a, **k)
    except Exception as e:  # noqa: BLE001
        return {"skipped": f"raised {type(e).__name__}: {str(e).splitlines()[0][:300] if str(e) else ''}"}


def time_incremental(cfg: Config, seed: int) -> dict:
    try:
        from calibgraph.solver.solve.incremental import IncrementalSolver
    except ImportError as e:
        return {"status": f"pending: calibgraph.solver.solve.incremental not importable ({e})"}
    scene = _scene(cfg, seed)
    prob, truth = scene.problem, scene.truth
    by_cap = {}
    for d in prob.detections:
        by_cap.setdefault(d.capture, []).append(d)
    out = {"status": "ok", "config": asdict(cfg), "n_captures": len(prob.captures)}
    for with_cov in (True, False):
        try:
            inc = IncrementalSolver(prob.points_board_m, dict(prob.cameras), options=prob.options,
                                    pixel_sigma_px=cfg.pixel_sigma_px, with_covariance=with_cov)
            times, cpus, init_at, est = [], [], None, None
            for cap in prob.captures:
                t0, c0 = time.perf_counter(), time.process_time()
                est = inc.add_capture(cap, by_cap.get(cap.index, []))
                dt, dc = time.perf_counter() - t0, time.process_time() - c0
                if est.T_mount_board is not None and init_at is None:
                    init_at = cap.index
                    out.setdefault("init_time_s", dt)
                elif init_at is not None:
                    times.append(dt)
                    cpus.append(dc)
        except Exception as e:  # noqa: BLE001 - report whatever the work-in-progress module raises
            out[f"with_covariance={with_cov}"] = {"status": f"error: {type(e).__name__}: {e}"}
            continue
        t = np.array(times)
        errs = {n: pose_error(c.T_ref_cam, truth.T_ref_cam[n]) for n, c in est.cameras.items()}
        out[f"with_covariance={with_cov}"] = {
            "status": "ok", "initialised_at_capture": init_at, "n_timed": len(t),
            "median_ms": 1e3 * float(np.median(t)) if t.size else float("nan"),
            "p95_ms": 1e3 * _pct(t, 95), "max_ms": 1e3 * float(t.max()) if t.size else float("nan"),
            "cpu_median_ms": 1e3 * _pct(cpus, 50), "cpu_p95_ms": 1e3 * _pct(cpus, 95),
            "cameras_ready": sorted(est.cameras), "gated": len(est.gated),
            "final_err_t_mm": {n: 1e3 * e[0] for n, e in errs.items()},
            "final_err_r_deg": {n: e[1] for n, e in errs.items()},
        }
    return out


# ---------------------------------------------------------------------------------------------
# markdown
# ---------------------------------------------------------------------------------------------
def _f(x, fmt="{:.3g}") -> str:
    if x is None or (isinstance(x, float) and not np.isfinite(x)):
        return "–" if x is None or np.isnan(x) else "inf"
    return fmt.format(x)


def to_markdown(report: dict) -> str:
    L = []
    meta = report["meta"]
    L.append("# calibgraph solver benchmark")
    L.append("")
    L.append(f"Run {meta['started_utc']} ({'quick' if meta['quick'] else 'full'}), {meta['trials']} trials per "
             f"configuration, 3 cameras at {'/'.join(f'{d:g}' for d in DISTANCES_M)} m, seeds {meta['seeds']}; "
             f"wall time {meta['wall_time_s']:.0f} s on a shared 2-core machine (1-min load average "
             f"{meta['loadavg_1min_start_end'][0]:.1f} at start, {meta['loadavg_1min_start_end'][1]:.1f} at end: wall "
             f"times are inflated by other jobs; CPU times are given too). git {meta['git']} at start{' (' + meta['git_at_end'] + ' at end)' if meta.get('git_at_end', meta['git']) != meta['git'] else ''}"
             f"{' with uncommitted engine edits in ' + ', '.join(meta['engine_uncommitted']) if meta['engine_uncommitted'] else ''}. "
             f"Solver formulation: {meta['formulation_requested']} (used: {', '.join(meta['formulations_used'])}).")
    L.append("Errors are over every camera of every trial; the CRLB is sqrt(trace) of the 3x3 translation / rotation "
             "block of the Cramer-Rao covariance at the truth. Ratio = RMS error / RMS CRLB sigma "
             "(norm.: RMS of error/CRLB per estimate). MLE ratio = the same for a reference maximum-likelihood fit "
             "(plain least squares with the true pixel sigma, started at the truth; FK 0 only): how far the problem "
             "itself is from the bound at this sample size. solve/MLE = RMS error of solve() / RMS error of that fit. "
             "err/σ̂ = RMS of error / the solver's own reported sigma. "
             f"Gross = error > {GROSS_CRLB_FACTOR:g}x CRLB sigma, > {GROSS_T_M * 100:g} cm or > {GROSS_R_DEG:g} deg, or the "
             f"solve raised; shown as total (relative: > {GROSS_CRLB_FACTOR:g}x CRLB or raised / absolute: > "
             f"{GROSS_T_M * 100:g} cm or {GROSS_R_DEG:g} deg).")
    L.append("")
    L.append("## Bars (issue 2)")
    L.append("")
    L.append("| bar | measured | met |")
    L.append("|---|---|---|")
    for b in report["bars"]:
        L.append(f"| {b['bar']} | {b['measured']} | {b['met']} |")
    L.append("")
    L.append("## Accuracy vs Cramer-Rao bound")
    L.append("")
    L.append("| preset | board | poses | px | FK | est. | t err med / p95 mm | r err med / p95 deg | CRLB t mm | "
             "CRLB r deg | ratio t (norm.) | ratio r (norm.) | MLE ratio t, r | err/σ̂ t, r | gross | solve s med / max |")
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for row in report["configs"]:
        c, s = row["config"], row["stats"]
        L.append(
            f"| {c['preset']} | {c['board']} | {c['n_poses']} | {c['pixel_sigma_px']:g} | {c['fk']} | {s['n_estimates']} | "
            f"{_f(s['err_t_mm_median'])} / {_f(s['err_t_mm_p95'])} | {_f(s['err_r_deg_median'])} / {_f(s['err_r_deg_p95'])} | "
            f"{_f(s['crlb_t_mm_rms'])} | {_f(s['crlb_r_deg_rms'])} | {_f(s['ratio_t'], '{:.2f}')} ({_f(s['ratio_t_normalised'], '{:.2f}')}) | "
            f"{_f(s['ratio_r'], '{:.2f}')} ({_f(s['ratio_r_normalised'], '{:.2f}')}) | "
            f"{_f(s['mle_ratio_t'], '{:.2f}')}, {_f(s['mle_ratio_r'], '{:.2f}')} | "
            f"{_f(s['err_over_reported_sigma_t'], '{:.2f}')}, {_f(s['err_over_reported_sigma_r'], '{:.2f}')} | "
            f"{s['n_gross']} ({s['n_gross_rel']} / {s['n_gross_abs']}){' ' + str(s['n_solver_failures']) + ' raised' if s['n_solver_failures'] else ''} | "
            f"{_f(row['solve_time_s_median'], '{:.2f}')} / {_f(row['solve_time_s_max'], '{:.2f}')} |")
    L.append("")
    p = report["pooled"]
    L.append("Pooled over configurations:")
    L.append("")
    L.append("| subset | est. | ratio t [95% CI] | ratio r [95% CI] | norm. t | norm. r | MLE ratio t, r | solve/MLE t, r | err/σ̂ t, r | gross |")
    L.append("|---|---|---|---|---|---|---|---|---|---|")
    for key, s in p.items():
        L.append(f"| {key} | {s['n_estimates']} | {_f(s['ratio_t'], '{:.3f}')} [{_f(s['ratio_t_ci95'][0], '{:.3f}')}, "
                 f"{_f(s['ratio_t_ci95'][1], '{:.3f}')}] | {_f(s['ratio_r'], '{:.3f}')} [{_f(s['ratio_r_ci95'][0], '{:.3f}')}, "
                 f"{_f(s['ratio_r_ci95'][1], '{:.3f}')}] | {_f(s['ratio_t_normalised'], '{:.3f}')} | "
                 f"{_f(s['ratio_r_normalised'], '{:.3f}')} | {_f(s['mle_ratio_t'], '{:.3f}')}, {_f(s['mle_ratio_r'], '{:.3f}')} | "
                 f"{_f(s['solve_over_mle_t'], '{:.3f}')}, {_f(s['solve_over_mle_r'], '{:.3f}')} | "
                 f"{_f(s['err_over_reported_sigma_t'], '{:.2f}')}, "
                 f"{_f(s['err_over_reported_sigma_r'], '{:.2f}')} | {s['n_gross']} ({s['n_gross_rel']} / {s['n_gross_abs']}) |")
    if report.get("failures"):
        L.append("")
        L.append(f"Gross failures / solver errors (first 15 of {len(report['failures'])}; relative ones first):")
        L.append("")
        for f in report["failures"][:15]:
            L.append(f"- {f}")
    L.append("")
    cv = report.get("opencv", {})
    L.append("## OpenCV 4.x baselines (each camera alone, cv2.solvePnP per view)")
    L.append("")
    if cv.get("status") != "ok":
        L.append(f"Skipped: {cv.get('status')}")
    else:
        chk = cv["convention_check"]
        L.append(f"OpenCV {cv['cv2_version']} in a separate venv. Convention check on noise-free data (exact board "
                 f"poses): {'passed' if chk['passed'] else 'FAILED ' + str(chk['failed_methods'])}; worst error "
                 f"{max(v['max_err_t_m'] for v in chk['exact_poses'].values()):.1e} m / "
                 f"{max(v['max_err_r_deg'] for v in chk['exact_poses'].values()):.1e} deg (noise-free PnP: "
                 f"{max(v['max_err_t_m'] for v in chk['pnp_noise_free'].values()):.1e} m).")
        L.append("")
        L.append("Camera at 3 m, 0.3 px: median translation error mm (gross-failure %) per method; calibgraph "
                 "(joint, all cameras) for comparison; factor = best OpenCV median / calibgraph median. 'Oracle' = "
                 "OpenCV fed only the views whose PnP pose is not a planar-ambiguity flip (> 3 deg off, decided "
                 "with the truth: not achievable by a user; an upper bound on the closed forms).")
        L.append("")
        L.append("| preset | board | poses | FK | calibgraph | " + " | ".join(CV_METHODS)
                 + " | best | factor t | factor r | oracle best | oracle factor t, r |")
        L.append("|---|---|---|---|---|" + "---|" * len(CV_METHODS) + "---|---|---|---|---|")
        for row in cv["at_3m_0.3px"]:
            c = row["config"]
            cells = [f"{_f(row['methods'][m]['err_t_mm_median'])} ({100 * row['methods'][m]['gross_rate']:.0f}%)"
                     for m in CV_METHODS]
            L.append(f"| {c['preset']} | {c['board']} | {c['n_poses']} | {c['fk']} | "
                     f"{_f(row['calibgraph']['err_t_mm_median'])} ({100 * row['calibgraph']['gross_rate']:.0f}%) | "
                     + " | ".join(cells) + f" | {row['best_t']} | {_f(row['factor_t'], '{:.1f}')} | {_f(row['factor_r'], '{:.1f}')} | "
                     f"{row['oracle_best_t']} {_f(row['oracle_methods'][row['oracle_best_t']]['err_t_mm_median'])} | "
                     f"{_f(row['oracle_factor_t'], '{:.1f}')}, {_f(row['oracle_factor_r'], '{:.1f}')} |")
        L.append("")
        L.append("Pooled over every configuration and camera (all distances, noise levels): median error and gross-failure rate.")
        L.append("")
        L.append("| method | est. | t err median mm | r err median deg | gross % | raised % |")
        L.append("|---|---|---|---|---|---|")
        for m, s in cv["pooled"].items():
            L.append(f"| {m} | {s['n']} | {_f(s['err_t_mm_median'])} | {_f(s['err_r_deg_median'])} | "
                     f"{100 * s['gross_rate']:.1f} | {100 * s['nan_rate']:.1f} |")
    L.append("")
    L.append("## Run times")
    L.append("")
    for key in [k for k in report["timing"] if k.startswith("batch_")]:
        t = report["timing"].get(key)
        if not t:
            continue
        if "skipped" in t:
            L.append(f"- {key}: skipped ({t['skipped']})")
            continue
        st = {k: np.median([r["stages_s"][k] for r in t["runs"]]) for k in t["runs"][0]["stages_s"]}
        L.append(f"- {key} (formulation {t['formulation']}): {t['n_cameras']} cameras, {t['n_captures']} captures, {t['n_views']} views, "
                 f"{t['n_corners']} corners: solve {t['solve_time_s_median']:.2f} s wall median (min {t['solve_time_s_min']:.2f} s, "
                 f"{len(t['runs'])} runs; process CPU {t['cpu_time_s_median']:.2f} s; 1-min load average "
                 f"{t['runs'][-1]['loadavg_1min']:.1f} on 2 cores). Stages (median wall s): "
                 + ", ".join(f"{k.strip('_')} {v:.2f}" for k, v in st.items())
                 + f". Max error {t['max_err_t_mm']:.2f} mm / {t['max_err_r_deg']:.3f} deg.")
    inc = report["timing"].get("incremental", {})
    if inc.get("status") != "ok":
        L.append(f"- iSAM2 incremental: {inc.get('status')}")
    else:
        for k in ("with_covariance=True", "with_covariance=False"):
            v = inc.get(k, {})
            if v.get("status") != "ok":
                L.append(f"- iSAM2 add_capture ({k}): {v.get('status')}")
                continue
            L.append(f"- iSAM2 add_capture ({k}), 3 cameras, {inc['n_captures']} captures: median {v['median_ms']:.1f} ms, "
                     f"p95 {v['p95_ms']:.1f} ms, max {v['max_ms']:.1f} ms (CPU median {v['cpu_median_ms']:.1f} ms, "
                     f"p95 {v['cpu_p95_ms']:.1f} ms) over {v['n_timed']} captures after "
                     f"initialisation at capture {v['initialised_at_capture']} (that one took {1e3 * inc.get('init_time_s', float('nan')):.0f} ms); "
                     f"final error " + ", ".join(f"{n} {e:.2f} mm" for n, e in sorted(v['final_err_t_mm'].items()))
                     + f"; {v['gated']} views gated.")
    L.append("")
    return "\n".join(L)


# ---------------------------------------------------------------------------------------------
# main
# ---------------------------------------------------------------------------------------------
def _configs(quick: bool) -> list:
    if quick:
        return [Config("d455", b, n, 0.3, "0") for b in BOARDS for n in POSES]
    return [Config(p, b, n, s, fk) for p, b, n, s, fk in
            itertools.product(PRESETS, BOARDS, POSES, PIXEL_SIGMAS_PX, FK_LEVELS)]


def _git_rev() -> str:
    r = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return r.stdout.strip() or "unknown"


def _engine_dirty() -> list:
    """Engine files with uncommitted edits at run time (the numbers describe the working tree)."""
    r = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--", "calibgraph"], capture_output=True, text=True)
    return [ln[3:] for ln in r.stdout.splitlines() if ln.strip()]


def _pooled(recs: list) -> dict:
    s = summarize(recs)
    ok = [r for r in recs if np.isfinite(r["err_t_m"])]
    for a, b, key in (("err_t_m", "crlb_t_m", "ratio_t_ci95"), ("err_r_deg", "crlb_r_deg", "ratio_r_ci95")):
        s[key] = _ratio_ci95(np.array([r[a] for r in ok]), np.array([r[b] for r in ok]))
    return s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(REPO / "bench_out"), help="output directory (default bench_out/)")
    ap.add_argument("--quick", action="store_true", help="small run (< 2 min)")
    ap.add_argument("--trials", type=int, default=None, help="trials per configuration (default 10, quick 2)")
    ap.add_argument("--seed", type=int, default=1000, help="base scene seed (configuration i, trial t: seed + 100 i + t)")
    ap.add_argument("--no-opencv", action="store_true", help="skip the OpenCV 4.x baselines")
    ap.add_argument("--cv4-python", default=None, help="python interpreter with opencv<5 (default: create OUT/.venv-cv4)")
    ap.add_argument("--skip-16cam", action="store_true", help="skip the 16-camera x 1000-pose timing")
    ap.add_argument("--both-16cam", action="store_true", help="time the 16-camera cell with both formulations")
    ap.add_argument("--formulation", default=None, choices=("view", "corner", "auto"),
                    help="force SolverOptions.formulation in the Monte Carlo (default: the engine's default)")
    args = ap.parse_args(argv)
    global FORMULATION
    FORMULATION = args.formulation
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    trials = args.trials or (2 if args.quick else 10)
    if not 1 <= trials <= SEED_STRIDE:
        ap.error(f"--trials must be in 1..{SEED_STRIDE}")
    t_start = time.perf_counter()
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    load_start = os.getloadavg()[0]
    dirty_start = _engine_dirty()
    git_start = _git_rev()  # the engine modules are imported once, so this is the code that ran

    cv_py, cv_reason = (None, "disabled with --no-opencv")
    if not args.no_opencv:
        cv_py, cv_reason = ensure_cv4_python(out_dir, args.cv4_python)
        if cv_py is None:
            print(f"OpenCV comparison skipped: {cv_reason}", file=sys.stderr)

    configs = _configs(args.quick)
    rows, all_trials, jobs, job_meta = [], [], [], []
    for ci, cfg in enumerate(configs):
        trial_recs = []
        for t in range(trials):
            tr = run_trial(cfg, args.seed + SEED_STRIDE * ci + t, with_opencv=cv_py is not None)
            if cv_py is not None:
                for kind in ("opencv", "opencv_oracle"):
                    key = "_jobs" if kind == "opencv" else "_jobs_oracle"
                    for i, (name, (A, B)) in enumerate(tr.pop(key).items()):
                        jobs.append((A, B))
                        job_meta.append((kind, len(all_trials), i, name, tr["_truth"][name], len(A)))
                tr.pop("_truth")
            all_trials.append(tr)
            trial_recs.append(tr)
        recs = [c for tr in trial_recs for c in tr["cameras"]]
        times = [tr["solve_time_s"] for tr in trial_recs]
        row = {"config": asdict(cfg), "stats": summarize(recs), "solve_time_s_median": float(np.median(times)),
               "solve_time_s_max": float(np.max(times)), "n_views_median": float(np.median([tr["n_views"] for tr in trial_recs]))}
        rows.append(row)
        s = row["stats"]
        print(f"[{ci + 1}/{len(configs)}] {cfg.label}: t {s['err_t_mm_median']:.3f} mm, r {s['err_r_deg_median']:.4f} deg, "
              f"ratio t {s['ratio_t']:.2f} r {s['ratio_r']:.2f}, gross {s['n_gross']}, "
              f"solve {row['solve_time_s_median']:.2f} s ({time.perf_counter() - t_start:.0f} s elapsed)",
              file=sys.stderr, flush=True)

    all_recs = [(tr, c) for tr in all_trials for c in tr["cameras"]]
    pooled = {
        "FK 0 (bar)": _pooled([c for tr, c in all_recs if tr["config"]["fk"] == "0"]),
        "FK Panda": _pooled([c for tr, c in all_recs if tr["config"]["fk"] == "panda"]),
    }
    for n in POSES:
        pooled[f"FK 0, {n} poses"] = _pooled([c for tr, c in all_recs if tr["config"]["fk"] == "0"
                                              and tr["config"]["n_poses"] == n])
    for b in BOARDS:
        pooled[f"FK 0, {b}"] = _pooled([c for tr, c in all_recs if tr["config"]["fk"] == "0" and tr["config"]["board"] == b])
    failures = []
    # estimator failures first, then absolute-limit misses the bound does not explain, then the rest
    order = sorted(all_recs, key=lambda x: (not x[1]["gross_rel"], x[1]["gross_abs_crlb_limited"]))
    for tr, c in order:
        if c["gross"]:
            cfg = Config(**tr["config"])
            kind = "relative" if c["gross_rel"] else ("absolute, CRLB-limited" if c["gross_abs_crlb_limited"] else "absolute")
            failures.append(f"[{kind}] {cfg.label} seed {tr['seed']} {c['camera']} ({c['distance_m']:g} m): err "
                            f"{1e3 * c['err_t_m']:.2f} mm / {c['err_r_deg']:.3f} deg vs CRLB {1e3 * c['crlb_t_m']:.2f} mm / "
                            f"{c['crlb_r_deg']:.4f} deg{' — ' + tr['error'] if tr['error'] else ''}")

    # ---- OpenCV
    opencv = {"status": cv_reason or "not run"}
    if cv_py is not None:
        print(f"OpenCV 4.x: {len(jobs)} camera calibrations x {len(CV_METHODS)} methods ...", file=sys.stderr, flush=True)
        try:
            chk = opencv_convention_check(cv_py)
            if not chk["passed"]:
                raise RuntimeError(f"eye-to-hand convention check failed for {chk['failed_methods']}: {chk}")
            res, version = run_opencv(cv_py, jobs)
            per = {m: [] for m in CV_METHODS}  # plain OpenCV: (trial, camera idx, err_t, err_r, gross)
            for tr in all_trials:
                tr["opencv"], tr["opencv_oracle"] = {}, {}
            for (kind, ti, ci_, name, T_true, n_views), r in zip(job_meta, res):
                crec = all_trials[ti]["cameras"][ci_]
                for m in CV_METHODS:
                    ok = np.all(np.isfinite(r[m])) and n_views >= 3
                    et, er = pose_error(r[m], T_true) if ok else (float("inf"), float("inf"))
                    g = _is_gross(et, er, crec["crlb_t_m"], crec["crlb_r_deg"])
                    all_trials[ti][kind].setdefault(name, {})[m] = {"err_t_m": et, "err_r_deg": er, "gross": g,
                                                                     "views": n_views}
                    if kind == "opencv":
                        per[m].append((ti, ci_, et, er, g))

            def med(vals):
                v = np.asarray(vals, float)
                return float(np.median(v)) if v.size else float("nan")

            def method_stats(trs, kind, cam):
                meth = {}
                for m in CV_METHODS:
                    v = [tr[kind][cam][m] for tr in trs]
                    meth[m] = {"err_t_mm_median": 1e3 * med([x["err_t_m"] for x in v]),
                               "err_r_deg_median": med([x["err_r_deg"] for x in v]),
                               "gross_rate": float(np.mean([x["gross"] for x in v]))}
                bt = min(CV_METHODS, key=lambda m: meth[m]["err_t_mm_median"])
                br = min(CV_METHODS, key=lambda m: meth[m]["err_r_deg_median"])
                return meth, bt, br

            def cg_stats(trs):
                cam3 = [tr["cameras"][1] for tr in trs]
                return {"err_t_mm_median": 1e3 * med([c["err_t_m"] for c in cam3]),
                        "err_r_deg_median": med([c["err_r_deg"] for c in cam3]),
                        "gross_rate": float(np.mean([c["gross"] for c in cam3]))}

            at3 = []
            for row in rows:
                cfg = row["config"]
                if cfg["pixel_sigma_px"] != 0.3:
                    continue
                trs = [tr for tr in all_trials if tr["config"] == cfg]
                cg = cg_stats(trs)
                meth, bt, br = method_stats(trs, "opencv", "cam1")
                ometh, obt, obr = method_stats(trs, "opencv_oracle", "cam1")
                at3.append({"config": cfg, "calibgraph": cg, "methods": meth, "best_t": bt, "best_r": br,
                            "factor_t": meth[bt]["err_t_mm_median"] / cg["err_t_mm_median"],
                            "factor_r": meth[br]["err_r_deg_median"] / cg["err_r_deg_median"],
                            "oracle_methods": ometh, "oracle_best_t": obt,
                            "oracle_factor_t": ometh[obt]["err_t_mm_median"] / cg["err_t_mm_median"],
                            "oracle_factor_r": ometh[obr]["err_r_deg_median"] / cg["err_r_deg_median"]})
            # pooled over all 0.3 px configurations, camera at 3 m (the bar)
            sel = [tr for tr in all_trials if tr["config"]["pixel_sigma_px"] == 0.3]
            cg = cg_stats(sel)
            meth, bt, br = method_stats(sel, "opencv", "cam1")
            ometh, obt, obr = method_stats(sel, "opencv_oracle", "cam1")
            pooled_cv = {}
            for m in CV_METHODS:
                v = per[m]
                pooled_cv[m] = {"n": len(v), "err_t_mm_median": 1e3 * med([x[2] for x in v if np.isfinite(x[2])]),
                                "err_r_deg_median": med([x[3] for x in v if np.isfinite(x[3])]),
                                "gross_rate": float(np.mean([x[4] for x in v])),
                                "nan_rate": float(np.mean([not np.isfinite(x[2]) for x in v]))}
            cgr = [c for _, c in all_recs]
            pooled_cv["calibgraph (joint)"] = {
                "n": len(cgr), "err_t_mm_median": 1e3 * med([c["err_t_m"] for c in cgr if np.isfinite(c["err_t_m"])]),
                "err_r_deg_median": med([c["err_r_deg"] for c in cgr if np.isfinite(c["err_r_deg"])]),
                "gross_rate": float(np.mean([c["gross"] for c in cgr])),
                "nan_rate": float(np.mean([not np.isfinite(c["err_t_m"]) for c in cgr]))}
            opencv = {"status": "ok", "cv2_version": version, "convention_check": chk, "at_3m_0.3px": at3,
                      "pooled": pooled_cv,
                      "bar_pooled": {"calibgraph_err_t_mm_median": cg["err_t_mm_median"],
                                     "calibgraph_err_r_deg_median": cg["err_r_deg_median"],
                                     "best_t_method": bt, "best_t_mm_median": meth[bt]["err_t_mm_median"],
                                     "best_r_method": br, "best_r_deg_median": meth[br]["err_r_deg_median"],
                                     "factor_t": meth[bt]["err_t_mm_median"] / cg["err_t_mm_median"],
                                     "factor_r": meth[br]["err_r_deg_median"] / cg["err_r_deg_median"],
                                     "oracle_best_t_method": obt, "oracle_best_t_mm_median": ometh[obt]["err_t_mm_median"],
                                     "oracle_factor_t": ometh[obt]["err_t_mm_median"] / cg["err_t_mm_median"],
                                     "oracle_best_r_method": obr, "oracle_best_r_deg_median": ometh[obr]["err_r_deg_median"],
                                     "oracle_factor_r": ometh[obr]["err_r_deg_median"] / cg["err_r_deg_median"],
                                     "n_trials": len(sel)}}
        except Exception as e:  # noqa: BLE001 - keep the solver numbers even when the baseline breaks
            opencv = {"status": f"failed: {type(e).__name__}: {e}"}
            print(f"OpenCV comparison failed: {e}", file=sys.stderr)

    # ---- timings
    print("timing 3 cameras x 110 poses x 54 corners ...", file=sys.stderr, flush=True)
    cfg3 = Config("d455", "a4_25mm_54pt", 110, 0.3, "panda")
    timing = {"batch_3cam": _safe(time_batch, cfg3, repeats=3, seed=7)}
    has_forms = "formulation" in SolverOptions.__dataclass_fields__
    if has_forms:
        # the issue asks for both formulations to be measured; the bar uses the default above
        for form in ("view", "corner"):
            if form != timing["batch_3cam"].get("formulation"):
                timing[f"batch_3cam_{form}"] = _safe(time_batch, cfg3, repeats=2, seed=7, formulation=form)
    if args.quick or args.skip_16cam:
        timing["batch_16cam"] = {"skipped": "--quick" if args.quick else "--skip-16cam"}
    else:
        print("timing 16 cameras x 1000 poses ...", file=sys.stderr, flush=True)
        cfg16 = Config("d455", "a4_25mm_54pt", 1000, 0.3, "panda")
        timing["batch_16cam"] = _safe(time_batch, cfg16, repeats=1, seed=8, n_cams=16)
        if has_forms and args.both_16cam:
            for form in ("view", "corner"):
                if form != timing["batch_16cam"].get("formulation"):
                    timing[f"batch_16cam_{form}"] = _safe(time_batch, cfg16, repeats=1, seed=8, n_cams=16, formulation=form)
    print("timing iSAM2 add_capture ...", file=sys.stderr, flush=True)
    timing["incremental"] = time_incremental(Config("d455", "a4_25mm_54pt", 110, 0.3, "panda"), seed=9)

    # ---- bars
    bars = []
    p0 = pooled["FK 0 (bar)"]
    ok_ratio = p0["ratio_t"] <= BAR_CRLB_RATIO and p0["ratio_r"] <= BAR_CRLB_RATIO
    n_gross_all = sum(r["stats"]["n_gross"] for r in rows)
    n_rel_all = sum(r["stats"]["n_gross_rel"] for r in rows)
    n_abs_all = sum(r["stats"]["n_gross_abs"] for r in rows)
    n_abs_lim = sum(r["stats"]["n_gross_abs_crlb_limited"] for r in rows)
    n_gross_fk0 = p0["n_gross"]
    bars.append({"bar": f"error/CRLB <= {BAR_CRLB_RATIO} pooled (FK 0)",
                 "measured": f"t {p0['ratio_t']:.3f} [{p0['ratio_t_ci95'][0]:.3f}, {p0['ratio_t_ci95'][1]:.3f}], "
                             f"r {p0['ratio_r']:.3f} [{p0['ratio_r_ci95'][0]:.3f}, {p0['ratio_r_ci95'][1]:.3f}] "
                             f"(normalised t {p0['ratio_t_normalised']:.3f}, r {p0['ratio_r_normalised']:.3f}); "
                             f"{p0['n_estimates']} estimates",
                 "met": "yes" if ok_ratio else "no"})
    bars.append({"bar": "zero gross failures",
                 "measured": f"{n_gross_all} of {sum(r['stats']['n_estimates'] for r in rows)} estimates ({n_gross_fk0} with FK 0): "
                             f"{n_rel_all} beyond {GROSS_CRLB_FACTOR:g}x CRLB or raised; {n_abs_all} beyond "
                             f"{GROSS_T_M * 100:g} cm / {GROSS_R_DEG:g} deg, of which {n_abs_lim} where the CRLB sigma itself "
                             f"exceeds a third of that limit (1 px, 12-corner board, 5 m)",
                 "met": "yes" if n_gross_all == 0 else "no"})
    if opencv.get("status") == "ok":
        bp = opencv["bar_pooled"]
        worst_t = min(r["factor_t"] for r in opencv["at_3m_0.3px"])
        worst_r = min(r["factor_r"] for r in opencv["at_3m_0.3px"])
        met = bp["factor_t"] >= BAR_OPENCV_FACTOR and bp["factor_r"] >= BAR_OPENCV_FACTOR
        met_all = worst_t >= BAR_OPENCV_FACTOR and worst_r >= BAR_OPENCV_FACTOR
        bars.append({"bar": f">= {BAR_OPENCV_FACTOR:g}x lower median error than the best OpenCV method (3 m, 0.3 px)",
                     "measured": f"pooled over {bp['n_trials']} trials: t {bp['factor_t']:.1f}x (best {bp['best_t_method']} "
                                 f"{bp['best_t_mm_median']:.2f} mm vs {bp['calibgraph_err_t_mm_median']:.3f} mm), r "
                                 f"{bp['factor_r']:.1f}x (best {bp['best_r_method']} {bp['best_r_deg_median']:.3f} deg vs "
                                 f"{bp['calibgraph_err_r_deg_median']:.4f} deg); worst configuration t {worst_t:.1f}x, r {worst_r:.1f}x; "
                                 f"vs OpenCV with oracle flip removal: t {bp['oracle_factor_t']:.1f}x ({bp['oracle_best_t_method']}), "
                                 f"r {bp['oracle_factor_r']:.1f}x ({bp['oracle_best_r_method']})",
                     "met": ("yes" if met_all else "pooled yes, not in every configuration") if met else "no"})
    else:
        bars.append({"bar": f">= {BAR_OPENCV_FACTOR:g}x lower median error than the best OpenCV method (3 m, 0.3 px)",
                     "measured": f"not measured: {opencv.get('status')}", "met": "unknown"})
    b3 = timing["batch_3cam"]
    if "skipped" in b3:
        b3 = {"solve_time_s_median": float("inf"), "cpu_time_s_median": float("nan"), "runs": [], "n_views": 0}
    bars.append({"bar": f"LM + marginals, 3 cameras x 110 poses x 54 corners < {BAR_3CAM_S:g} s",
                 "measured": f"{b3['solve_time_s_median']:.2f} s wall / {b3['cpu_time_s_median']:.2f} s CPU, median of "
                             f"{len(b3['runs'])} ({b3['n_views']} views; whole solve() incl. initialisation)",
                 "met": "yes" if b3["solve_time_s_median"] < BAR_3CAM_S else "no"})
    b16 = timing["batch_16cam"]
    if "skipped" in b16:
        bars.append({"bar": f"16 cameras x 1000 poses < {BAR_16CAM_S:g} s", "measured": f"skipped ({b16['skipped']})",
                     "met": "unknown"})
    else:
        bars.append({"bar": f"16 cameras x 1000 poses < {BAR_16CAM_S:g} s",
                     "measured": f"{b16['solve_time_s_median']:.1f} s wall / {b16['cpu_time_s_median']:.1f} s CPU "
                                 f"({b16['n_captures']} captures, {b16['n_views']} views, {b16['n_corners']} corners)",
                     "met": "yes" if b16["solve_time_s_median"] < BAR_16CAM_S else "no"})
    inc = timing["incremental"]
    v = inc.get("with_covariance=True", {})
    if inc.get("status") == "ok" and v.get("status") == "ok":
        bars.append({"bar": f"iSAM2 update < {1e3 * BAR_ISAM_S:g} ms per capture (3 cameras)",
                     "measured": f"median {v['median_ms']:.1f} ms, p95 {v['p95_ms']:.1f} ms, max {v['max_ms']:.1f} ms "
                                 f"(with covariance); without: median {inc.get('with_covariance=False', {}).get('median_ms', float('nan')):.1f} ms",
                     "met": "yes" if v["p95_ms"] < 1e3 * BAR_ISAM_S else ("median only" if v["median_ms"] < 1e3 * BAR_ISAM_S else "no")})
    else:
        bars.append({"bar": f"iSAM2 update < {1e3 * BAR_ISAM_S:g} ms per capture (3 cameras)",
                     "measured": inc.get("status") if inc.get("status") != "ok" else v.get("status"), "met": "unknown"})

    report = {
        "meta": {"started_utc": started, "quick": args.quick, "trials": trials,
                 "seeds": f"{args.seed} + {SEED_STRIDE} x configuration index + trial (0..{trials - 1})", "wall_time_s": time.perf_counter() - t_start,
                 "git": git_start, "git_at_end": _git_rev(), "engine_uncommitted": sorted(set(dirty_start) | set(_engine_dirty())),
                 "engine_uncommitted_start_end": [dirty_start, _engine_dirty()], "loadavg_1min_start_end": [load_start, os.getloadavg()[0]],
                 "formulation_requested": args.formulation or "engine default",
                 "formulations_used": sorted({str(tr.get("formulation_used")) for tr in all_trials}), "python": sys.version.split()[0], "opencv_main": cv2.__version__,
                 "gross_definition": f"err > {GROSS_CRLB_FACTOR}x CRLB sigma or > {GROSS_T_M} m or > {GROSS_R_DEG} deg or solve raised"},
        "bars": bars, "configs": rows, "pooled": pooled, "failures": failures, "opencv": opencv, "timing": timing,
        "trials": all_trials,
    }
    md = to_markdown(report)
    (out_dir / "bench_solver.md").write_text(md)
    (out_dir / "bench_solver.json").write_text(json.dumps(_finite(report), indent=1, default=_json_default,
                                                          allow_nan=False))
    print(md)
    print(f"wrote {out_dir / 'bench_solver.json'} and {out_dir / 'bench_solver.md'}", file=sys.stderr)
    return 0


def _finite(o):
    """Strict JSON: non-finite floats (failed estimates) become null."""
    if isinstance(o, dict):
        return {str(k): _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, np.integer):
        return int(o)
    return o


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(type(o))


if __name__ == "__main__":
    sys.exit(main())
