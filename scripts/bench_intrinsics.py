"""Knowing the camera: the close-range intrinsics stage's focal bias and 1-sigma against the truth,
and what the joint hand-eye solve gets from each kind of intrinsics input, per camera distance.

(a) Close-range stage, rendered sessions. Per camera model (D455 1280x800, L515 1920x1080, Kinect V2
    1920x1080 colour streams; each seed a different unit: focal +-1 %, principal point +-4 px, the
    model's typical distortion) and board (the thesis's 5x4 squares of 46 mm, the A4 7x10 squares of
    25 mm): 25 images at 0.3-0.8 m rendered through the full camera model
    (calibgraph.sim.session: render_view + the simulator's blur, noise and exposure), detected with
    calibgraph's detector and calibrated (calibgraph.solver.camera.intrinsics_session). Errors against the
    true intrinsics, error / reported 1-sigma.
(b) Joint hand-eye solve, 3 x D455 on a ring at 1.5 / 3 / 5 m, thesis board, 90 poses spread over
    +-0.4 m (and +-0.15 m at 5 m), synthetic corners (0.1 px, calibgraph.sim.synth.make_scene), FK
    noise 0.05 mm / 0.005 deg; the cameras are (a)'s D455 units. Three intrinsics inputs:
      oracle  - the true intrinsics, held (an oracle's figure: no real camera is known exactly);
      factory - a file off by a factory-class error (focal 0.6 % 1-sigma, principal point 3 px,
                k1/k2 0.01) stated `source: factory` (the solver's generic factory prior);
      session - the camera file of (a)'s rendered session of that unit, its covariance the prior.
(target) 5 m, seed 0, through the files: simulate_intrinsics_session -> `calibgraph intrinsics` per
    camera -> the camera files as priors; checks of issue 23's targets.

    python scripts/bench_intrinsics.py [--quick] [--seeds 30] [--scenes 10] [--parts a,b,target]

Writes scripts/results/bench_intrinsics.{md,json}; (b) reuses (a)'s D455 sessions from the json
when run alone.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calibgraph.cli.main import main as cli_main  # noqa: E402
from calibgraph.core.camera import INTRINSICS_VECTOR, Intrinsics, preset  # noqa: E402
from calibgraph.core.targets import a4_board_54, thesis_board  # noqa: E402
from calibgraph.core.transforms import log_so3  # noqa: E402
from calibgraph.detect.corners import detect_image  # noqa: E402
from calibgraph.io.camera_file import read_camera_file  # noqa: E402
from calibgraph.sim.session import render_session_image, simulate_intrinsics_session  # noqa: E402
from calibgraph.sim.synth import make_scene, ring_cameras  # noqa: E402
from calibgraph.sim.workcell import Realism  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402
from calibgraph.solver.camera.intrinsics_model import parameter_vector  # noqa: E402
from calibgraph.solver.camera.intrinsics_session import SessionView, calibrate_views  # noqa: E402
from calibgraph.solver.camera.session_plan import SESSION_PIXEL_SIGMA_PX, predict_session_covariance, session_poses  # noqa: E402

CAMERAS = ("d455", "l515", "kinect_v2")
# typical colour-stream distortion (k1, k2, p1, p2, k3) of each model
DISTORTION = {"d455": (-0.055, 0.065, 0.0003, -0.0004, -0.02), "l515": (0.17, -0.52, 0.0002, 0.0002, 0.47),
              "kinect_v2": (0.04, -0.035, 0.0005, -0.0003, 0.0)}
BOARDS = {"thesis_5x4_46mm": thesis_board(), "a4_7x10_25mm": a4_board_54()}
FACTORY_ERROR = dict(focal_rel=0.006, pp_px=3.0, k=0.01)
DISTANCES_M = (1.5, 3.0, 5.0)
INPUTS = ("oracle", "factory", "session")


def true_camera(model: str, seed: int) -> Intrinsics:
    """One unit of a camera model: focal +-1 %, principal point +-4 px, the model's distortion."""
    rng = np.random.default_rng(1000 + seed)
    base = preset(model)
    K = base.K.copy()
    K[0, 0] *= 1 + rng.normal(0, 0.01)
    K[1, 1] = K[0, 0] * (1 + rng.normal(0, 0.002))
    K[0, 2] += rng.normal(0, 4.0)
    K[1, 2] += rng.normal(0, 4.0)
    return Intrinsics(K=K, dist=np.array(DISTORTION[model]), width_px=base.width_px, height_px=base.height_px)


def _vec(intr) -> np.ndarray:
    return parameter_vector(intr, INTRINSICS_VECTOR)


# ---------------------------------------------------------------------------------------------
# (a) the close-range stage on rendered sessions
# ---------------------------------------------------------------------------------------------
def session_case(model: str, board: str, seed: int) -> dict:
    target = BOARDS[board]
    truth = true_camera(model, seed)
    rng = np.random.default_rng(seed)
    t0 = time.process_time()
    views, err, t_render, t_detect = [], [], 0.0, 0.0
    for k, T in enumerate(session_poses(truth, target, 25, rng=rng)):
        t1 = time.process_time()
        img = render_session_image(target, truth, T, Realism(), rng)
        t2 = time.process_time()
        det = detect_image(img, target)
        t3 = time.process_time()
        t_render += t2 - t1
        t_detect += t3 - t2
        if det.ok:
            uv = truth.project(target.points_board_m[det.ids] @ T[:3, :3].T + T[:3, 3])
            err.append(det.uv_px - uv)
            views.append(SessionView(f"view_{k:03d}", det.ids, det.uv_px))
    t4 = time.process_time()
    r = calibrate_views(views, target, truth.width_px, truth.height_px)
    t_cal = time.process_time() - t4
    e = _vec(r.intrinsics) - _vec(truth)
    sig = np.sqrt(np.diag(r.intrinsics.covariance))[:6]  # fx fy cx cy k1 k2 (the file's p1 p2 k3 follow)
    pred = predict_session_covariance(truth, target, pixel_sigma_px=r.pixel_sigma_px)
    corner_err = np.vstack(err) if err else np.zeros((0, 2))
    return {"camera": model, "board": board, "seed": seed, "views_detected": len(views),
            "views_used": len(r.views_used), "rejected": [list(x) for x in r.rejected],
            "corner_error_rms_px": float(np.sqrt(np.mean(corner_err ** 2))) if len(corner_err) else None,
            "pixel_sigma_px": r.pixel_sigma_px, "rms_px": r.rms_px, "mode_factor": r.mode_variance_ratio,
            "error": dict(zip(INTRINSICS_VECTOR, e.tolist())), "sigma": dict(zip(INTRINSICS_VECTOR, sig.tolist())),
            "z": dict(zip(INTRINSICS_VECTOR, (e / sig).tolist())),
            "sigma_fx_predicted_px": float(np.sqrt(pred[0, 0])), "warnings": list(r.warnings),
            "truth": truth.to_dict(), "estimate": r.intrinsics.to_dict(),
            "cpu_s": {"render": t_render, "detect": t_detect, "calibrate": t_cal, "total": time.process_time() - t0}}


def summarise_a(records: list) -> list:
    rows = []
    for model in CAMERAS:
        for board in BOARDS:
            rs = [r for r in records if r["camera"] == model and r["board"] == board]
            if not rs:
                continue
            fx = np.array([r["truth"]["K"][0][0] for r in rs])
            e = np.array([r["error"]["fx"] for r in rs])
            s = np.array([r["sigma"]["fx"] for r in rs])
            z = {p: np.array([r["z"][p] for r in rs]) for p in INTRINSICS_VECTOR}
            rows.append({"camera": model, "board": board, "seeds": len(rs),
                         "fx_bias_px": float(e.mean()), "fx_bias_se_px": float(e.std(ddof=1) / np.sqrt(len(e))) if len(e) > 1 else None,
                         "fx_error_rms_px": float(np.sqrt(np.mean(e ** 2))), "fx_sigma_mean_px": float(s.mean()),
                         "fx_sigma_mean_pct": float(np.mean(100 * s / fx)),
                         "fx_sigma_predicted_px": float(np.mean([r["sigma_fx_predicted_px"] for r in rs])),
                         "z_rms": {p: float(np.sqrt(np.mean(v ** 2))) for p, v in z.items()},
                         "fx_z_max": float(np.abs(z["fx"]).max()),
                         "fx_within_3sigma": int(np.sum(np.abs(z["fx"]) <= 3)),
                         "pixel_sigma_px": float(np.mean([r["pixel_sigma_px"] for r in rs])),
                         "corner_error_rms_px": float(np.mean([r["corner_error_rms_px"] for r in rs])),
                         "views_used_mean": float(np.mean([r["views_used"] for r in rs])),
                         "mode_factor_applied": int(sum(r["mode_factor"] != 1.0 for r in rs)),
                         "warnings": int(sum(bool(r["warnings"]) for r in rs)),
                         "cpu_s_per_session": {k: float(np.mean([r["cpu_s"][k] for r in rs]))
                                               for k in ("render", "detect", "calibrate")}})
    return rows


# ---------------------------------------------------------------------------------------------
# (b) the joint solve under three intrinsics inputs
# ---------------------------------------------------------------------------------------------
def factory_file(truth: Intrinsics, rng) -> Intrinsics:
    K = truth.K.copy()
    K[0, 0] *= 1 + rng.normal(0, FACTORY_ERROR["focal_rel"])
    K[1, 1] *= 1 + rng.normal(0, FACTORY_ERROR["focal_rel"])
    K[0, 2] += rng.normal(0, FACTORY_ERROR["pp_px"])
    K[1, 2] += rng.normal(0, FACTORY_ERROR["pp_px"])
    d = truth.dist.copy()
    d[:2] += rng.normal(0, FACTORY_ERROR["k"], 2)
    return Intrinsics(K=K, dist=d, width_px=truth.width_px, height_px=truth.height_px, source="factory")


def scene(distance_m: float, truths: list, seed: int, half_m: float = 0.4):
    cams = ring_cameras([distance_m] * 3, presets=("d455",), spread_deg=200, height_m=2.0)
    cams = {n: (T, truths[i]) for i, (n, (T, _)) in enumerate(cams.items())}
    return make_scene(cameras=cams, target=thesis_board(), n_poses=90, pixel_sigma_px=0.1,
                      fk_sigma_translation_m=5e-5, fk_sigma_rotation_rad=np.radians(0.005),
                      workspace_half_extent_m=(half_m,) * 3, seed=seed)


def judge(result, sc, truths: dict) -> dict:
    out = {}
    for n, c in result.cameras.items():
        Tt = sc.truth.T_ref_cam[n]
        e = np.concatenate([log_so3(c.T_ref_cam[:3, :3] @ Tt[:3, :3].T), c.T_ref_cam[:3, 3] - Tt[:3, 3]])
        z = e / np.sqrt(np.diag(c.covariance))
        d = c.intrinsics or {}
        fx = float(np.asarray(d.get("K"))[0, 0]) if d.get("K") is not None else float("nan")
        sfx = (d.get("sigma") or {}).get("fx")
        out[n] = {"t_err_mm": float(1e3 * np.linalg.norm(e[3:])), "r_err_deg": float(np.degrees(np.linalg.norm(e[:3]))),
                  "sigma_t_mm": float(np.linalg.norm(c.sigma_translation_mm)), "z": z.tolist(),
                  "z_max": float(np.abs(z).max()), "fx_err_px": fx - float(truths[n].K[0, 0]),
                  "fx_sigma_px": float(sfx) if sfx else 0.0}
    return out


def joint_case(distance_m: float, scene_seed: int, sessions: list, half_m: float = 0.4) -> list:
    truths = [Intrinsics.from_dict({**s["truth"], "source": "exact"}) for s in sessions]
    sc = scene(distance_m, truths, scene_seed, half_m)
    names = list(sc.problem.cameras)
    rng = np.random.default_rng(500 + scene_seed)
    given = {"oracle": {n: truths[i] for i, n in enumerate(names)},
             "factory": {n: factory_file(truths[i], rng) for i, n in enumerate(names)},
             "session": {n: Intrinsics.from_dict(sessions[i]["estimate"]) for i, n in enumerate(names)}}
    out = []
    for inp in INPUTS:
        t0 = time.process_time()
        r = solve(sc.problem.with_(cameras=given[inp]))
        out.append({"distance_m": distance_m, "half_extent_m": half_m, "scene": scene_seed, "input": inp,
                    "cpu_s": time.process_time() - t0, "cameras": judge(r, sc, dict(zip(names, truths))),
                    "notes": list(r.notes)})
    return out


def summarise_b(records: list) -> list:
    rows = []
    keys = sorted({(r["distance_m"], r["half_extent_m"]) for r in records})
    for d, h in keys:
        for inp in INPUTS:
            rs = [c for r in records if (r["distance_m"], r["half_extent_m"], r["input"]) == (d, h, inp)
                  for c in r["cameras"].values()]
            if not rs:
                continue
            z = np.array([c["z"] for c in rs])
            fz = np.array([c["fx_err_px"] / c["fx_sigma_px"] for c in rs if c["fx_sigma_px"] > 0])
            rows.append({"distance_m": d, "half_extent_m": h, "input": inp, "cameras": len(rs),
                         "t_err_mean_mm": float(np.mean([c["t_err_mm"] for c in rs])),
                         "t_err_max_mm": float(np.max([c["t_err_mm"] for c in rs])),
                         "r_err_max_deg": float(np.max([c["r_err_deg"] for c in rs])),
                         "sigma_t_mean_mm": float(np.mean([c["sigma_t_mm"] for c in rs])),
                         "z_rms_rotation": float(np.sqrt(np.mean(z[:, :3] ** 2))),
                         "z_rms_translation": float(np.sqrt(np.mean(z[:, 3:] ** 2))),
                         "z_max": float(np.abs(z).max()), "within_3sigma": int(np.sum(np.abs(z).max(axis=1) <= 3)),
                         "within_4sigma": int(np.sum(np.abs(z).max(axis=1) <= 4)),
                         "fx_err_rms_px": float(np.sqrt(np.mean([c["fx_err_px"] ** 2 for c in rs]))),
                         "fx_z_rms": float(np.sqrt(np.mean(fz ** 2))) if fz.size else None})
    return rows


# ---------------------------------------------------------------------------------------------
# the target, through the files
# ---------------------------------------------------------------------------------------------
def target_case(work: Path, scene_seed: int = 0) -> dict:
    truths = [true_camera("d455", 900 + i) for i in range(3)]
    sc = scene(5.0, [Intrinsics.from_dict({**t.to_dict(), "source": "exact"}) for t in truths], scene_seed)
    names = list(sc.problem.cameras)
    session = work / "SESSION"
    t0 = time.time()
    simulate_intrinsics_session(session, dict(zip(names, truths)), thesis_board(), n_views=25, seed=scene_seed)
    t_sim = time.time() - t0
    files, cli = {}, {}
    for n, t in zip(names, truths):
        out = work / f"{n}.yaml"
        t0, c0 = time.time(), time.process_time()
        rc = cli_main(["intrinsics", str(session / n), "--target", str(session / "target.yaml"), "--out", str(out),
                       "--quiet"])
        cli[n] = {"rc": rc, "wall_s": time.time() - t0, "cpu_s": time.process_time() - c0}
        files[n] = read_camera_file(out)
        e = _vec(files[n]) - _vec(t)
        s = np.sqrt(np.diag(files[n].covariance))[:6]
        cli[n].update({"fx_err_px": float(e[0]), "fx_sigma_px": float(s[0]), "fx_z": float(e[0] / s[0]),
                       "z": dict(zip(INTRINSICS_VECTOR, (e / s).tolist()))})
    rng = np.random.default_rng(77)
    plain = {n: factory_file(t, rng) for n, t in zip(names, truths)}
    res = {}
    for inp, cams in (("factory", plain), ("session", files)):
        t0 = time.process_time()
        r = solve(sc.problem.with_(cameras=cams))
        res[inp] = {"cameras": judge(r, sc, dict(zip(names, truths))), "cpu_s": time.process_time() - t0,
                    "notes": list(r.notes)}
    sess = res["session"]["cameras"]
    checks = {"intrinsics: fx within 3 sigma": all(abs(cli[n]["fx_z"]) <= 3 for n in names),
              "session prior: every camera <= 3.0 mm": all(sess[n]["t_err_mm"] <= 3.0 for n in names),
              "session prior: every camera <= 0.05 deg": all(sess[n]["r_err_deg"] <= 0.05 for n in names),
              "session prior: within 3 sigma per axis": all(sess[n]["z_max"] <= 3 for n in names),
              "plain (factory) solve: within 4 sigma per axis": all(res["factory"]["cameras"][n]["z_max"] <= 4
                                                                     for n in names)}
    return {"render_wall_s": t_sim, "intrinsics_cli": cli, "solves": res, "checks": checks}


# ---------------------------------------------------------------------------------------------
# report
# ---------------------------------------------------------------------------------------------
def _f(x, nd=2):
    return "-" if x is None else f"{x:.{nd}f}"


def markdown(doc: dict) -> str:
    runs = doc.get("runs") or {}
    made = "; ".join(f"({part}) {when}, `{cmd}`" for part, (when, cmd) in sorted(runs.items()))
    L = ["# bench_intrinsics", "", f"Made by: {made}." if made else f"Run {doc['when']}; `{doc['command']}`.", ""]
    if doc.get("a_summary"):
        L += ["## (a) Close-range stage on rendered sessions", "",
              "25 images per session at 0.3-0.8 m, rendered through the true camera (distortion included), "
              "detected by calibgraph, calibrated with k1 k2 p1 p2 k3. Each seed is another unit of the "
              "model and another session. Intrinsics assumed: none (estimated from the images; errors are "
              "against the renderer's truth).", "",
              "| camera | board | seeds | fx bias px (se) | fx error RMS px | mean 1σ fx px (%) | predicted 1σ fx px | "
              "z RMS fx / fy / cx / cy / k1 / k2 | max abs z fx | fx within 3σ | pixel σ px | corner error px | views used | "
              "CPU s render / detect / calibrate |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in doc["a_summary"]:
            z = r["z_rms"]
            c = r["cpu_s_per_session"]
            L.append(f"| {r['camera']} | {r['board']} | {r['seeds']} | {_f(r['fx_bias_px'], 3)} ({_f(r['fx_bias_se_px'], 3)}) | "
                     f"{_f(r['fx_error_rms_px'], 3)} | {_f(r['fx_sigma_mean_px'], 3)} ({_f(r['fx_sigma_mean_pct'], 3)}) | "
                     f"{_f(r['fx_sigma_predicted_px'], 3)} | "
                     f"{' / '.join(_f(z[p]) for p in INTRINSICS_VECTOR)} | {_f(r['fx_z_max'])} | "
                     f"{r['fx_within_3sigma']}/{r['seeds']} | {_f(r['pixel_sigma_px'], 3)} | {_f(r['corner_error_rms_px'], 3)} | "
                     f"{_f(r['views_used_mean'], 1)} | {_f(c['render'], 1)} / {_f(c['detect'], 1)} / {_f(c['calibrate'], 2)} |")
        allz = np.array([r["z"]["fx"] for r in doc["a"]])
        L += ["", f"Pooled over every case: fx error/σ RMS {np.sqrt(np.mean(allz ** 2)):.2f} over {allz.size} sessions "
                  f"(max |z| {np.abs(allz).max():.2f}); predicted 1σ: `predict_session_covariance` at each "
                  "session's own pixel sigma (deterministic pose set).", ""]
    if doc.get("b_summary"):
        L += ["## (b) Joint hand-eye solve, 3 × D455, thesis board, 90 poses, synthetic corners 0.1 px", "",
              "Inputs: **oracle** = the true intrinsics held (an oracle's figure); **factory** = files off by "
              f"a factory-class error (focal {100 * FACTORY_ERROR['focal_rel']:.1f} % 1σ, principal point "
              f"{FACTORY_ERROR['pp_px']:.0f} px, k1/k2 {FACTORY_ERROR['k']}) stated `source: factory` (generic prior); "
              "**session** = each unit's rendered close-range session file from (a), its covariance the prior.", "",
              "| distance m | poses ± m | intrinsics input | cameras | mean error mm | max error mm | max error deg | "
              "mean 1σ mm | z RMS rot / trans | max abs z | within 3σ | within 4σ | fx error RMS px | fx z RMS |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in doc["b_summary"]:
            L.append(f"| {r['distance_m']:g} | {r['half_extent_m']:g} | {r['input']} | {r['cameras']} | {_f(r['t_err_mean_mm'])} | "
                     f"{_f(r['t_err_max_mm'])} | {_f(r['r_err_max_deg'], 3)} | {_f(r['sigma_t_mean_mm'])} | "
                     f"{_f(r['z_rms_rotation'])} / {_f(r['z_rms_translation'])} | {_f(r['z_max'])} | "
                     f"{r['within_3sigma']}/{r['cameras']} | {r['within_4sigma']}/{r['cameras']} | "
                     f"{_f(r['fx_err_rms_px'])} | {_f(r['fx_z_rms'])} |")
        L.append("")
    t = doc.get("target")
    if t:
        L += ["## Target: 3 × D455 at 5 m, thesis board, 90 poses, through the files", "",
              "SESSION/<camera>/*.png rendered by `simulate_intrinsics_session`, each calibrated by "
              "`calibgraph intrinsics`; the joint solve with those files (session) and with factory-class "
              "files (factory, the plain solve). Hand-eye corners synthetic (0.1 px).", "",
              "| camera | intrinsics fx error px | 1σ px | z | CLI wall s | session: error mm / deg | max abs z | "
              "factory: error mm / deg | max abs z |", "|---|---|---|---|---|---|---|---|---|"]
        for n, c in t["intrinsics_cli"].items():
            s, f = t["solves"]["session"]["cameras"][n], t["solves"]["factory"]["cameras"][n]
            L.append(f"| {n} | {c['fx_err_px']:+.3f} | {c['fx_sigma_px']:.3f} | {c['fx_z']:+.2f} | {c['wall_s']:.1f} | "
                     f"{s['t_err_mm']:.2f} / {s['r_err_deg']:.3f} | {s['z_max']:.2f} | {f['t_err_mm']:.2f} / "
                     f"{f['r_err_deg']:.3f} | {f['z_max']:.2f} |")
        L += [""] + [f"- {'PASS' if ok else 'FAIL'}: {k}" for k, ok in t["checks"].items()] + [""]
    tm = doc.get("timing")
    if tm:
        L += ["## Timing", "", f"- `predict_session_covariance` (D455, thesis board, 25 views): median "
              f"{tm['predict_ms_cpu']:.1f} ms CPU the first time for a camera (the pose set), "
              f"{tm['predict_cached_ms_cpu']:.2f} ms again (cached information), over 20 calls; default corner "
              f"noise {SESSION_PIXEL_SIGMA_PX} px.", ""]
    return "\n".join(L)


def timing() -> dict:
    from calibgraph.solver.camera import session_plan

    intr = true_camera("d455", 0)
    first, again = [], []
    for _ in range(20):
        session_plan._INFO_CACHE.clear()
        t0 = time.process_time()
        predict_session_covariance(intr, thesis_board())
        t1 = time.process_time()
        predict_session_covariance(intr, thesis_board(), pixel_sigma_px=0.05)
        first.append(t1 - t0)
        again.append(time.process_time() - t1)
    return {"predict_ms_cpu": 1e3 * float(np.median(first)), "predict_cached_ms_cpu": 1e3 * float(np.median(again))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 seeds, 1 scene")
    ap.add_argument("--seeds", type=int, default=20, help="sessions per camera and board in (a)")
    ap.add_argument("--scenes", type=int, default=10, help="hand-eye scenes per distance in (b)")
    ap.add_argument("--parts", default="a,b,target")
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    args = ap.parse_args()
    seeds, scenes = (3, 1) if args.quick else (args.seeds, args.scenes)
    parts = set(args.parts.split(","))
    jpath = args.out / ("bench_intrinsics_quick.json" if args.quick else "bench_intrinsics.json")
    doc = json.loads(jpath.read_text()) if jpath.is_file() else {}
    doc.update(when=time.strftime("%Y-%m-%d %H:%M"), command="python scripts/bench_intrinsics.py " + " ".join(sys.argv[1:]))
    # each part says which invocation made it (a part not run keeps its earlier one)
    doc["runs"] = {**doc.get("runs", {}), **{p: (doc["when"], doc["command"]) for p in parts}}

    def save():
        args.out.mkdir(parents=True, exist_ok=True)
        jpath.write_text(json.dumps(doc, indent=1))
        jpath.with_suffix(".md").write_text(markdown(doc))

    if "a" in parts:
        doc["a"] = []
        for model in CAMERAS:
            for board in BOARDS:
                n = max(seeds, 3 * scenes) if (model, board) == ("d455", "thesis_5x4_46mm") else seeds
                for s in range(n):
                    rec = session_case(model, board, s)
                    doc["a"].append(rec)
                    print(f"(a) {model} {board} seed {s}: fx {rec['error']['fx']:+.3f} ± {rec['sigma']['fx']:.3f} px "
                          f"(z {rec['z']['fx']:+.2f}), pixel sigma {rec['pixel_sigma_px']:.3f}, "
                          f"{rec['views_used']} views, {rec['cpu_s']['total']:.0f} s CPU", flush=True)
                doc["a_summary"] = summarise_a(doc["a"])
                save()
    if "b" in parts:
        sess = [r for r in doc.get("a", []) if (r["camera"], r["board"]) == ("d455", "thesis_5x4_46mm")]
        sess.sort(key=lambda r: r["seed"])
        if len(sess) < 3 * scenes:
            raise SystemExit(f"(b) needs {3 * scenes} D455 thesis-board sessions from (a); run --parts a first.")
        doc["b"] = []
        for d in DISTANCES_M:
            for k in range(scenes):
                for half in ((0.4, 0.15) if d == 5.0 else (0.4,)):
                    recs = joint_case(d, k, sess[3 * k: 3 * k + 3], half)
                    doc["b"] += recs
                    for r in recs:
                        print(f"(b) {d} m ±{half} scene {k} {r['input']}: " + ", ".join(
                            f"{c['t_err_mm']:.2f} mm |z|max {c['z_max']:.1f}" for c in r["cameras"].values()), flush=True)
            doc["b_summary"] = summarise_b(doc["b"])
            save()
    if "target" in parts:
        with tempfile.TemporaryDirectory() as tmp:
            doc["target"] = target_case(Path(tmp))
        print("target:", doc["target"]["checks"], flush=True)
        save()
    doc["timing"] = timing()
    save()
    print(f"wrote {jpath} and {jpath.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
