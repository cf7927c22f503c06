#!/usr/bin/env python
"""Reproduce the thesis's simulated protocol (chapter 6) on calibgraph's rendered workcell.

Tables 6.1 / 6.2 (§6.1.2): three cameras around the robot at an average distance d from the
robot base axis (1.5 .. 3.0 m), 1.6 m above the floor, the thesis board (5 x 4 squares of 46 mm),
110 poses; single-camera vs multi-camera calibration; translation error of T_W^Ci (base -> camera)
and T_Ci^Cj in mm, reprojection error (eq. 6.1, RMS of corner residual norms) in px.

§6.3: three D455-like cameras (1280 x 800, HFOV 90) at 1.5 .. 3.0 m, detection on the original
images vs with region up-scaling (bicubic, the thesis's "resize" trick): reprojection error per
camera, "-" where the camera could not be calibrated (too few detected views).

Extra bar: the A4 54-corner board (7 x 10 squares of 25 mm) on L515 cameras at 3 m, <= 0.5 mm and
0.03 deg per camera. Run over several seeds (``--a4-seeds``) and two protocols: "per_camera"
(3 x 110 poses, so each camera sees the board ~110 times, over a wide workspace) and "shared"
(the thesis's 110 poses shared by the three cameras, ~37 views each, default workspace).

Everything runs through the real pipeline: MuJoCo renders with sensor noise and blur, the
acquisition state machine detects corners on the fly, the GTSAM solver calibrates; errors are
against the simulator's ground truth. Our cameras are the Kinect V2 preset (1920 x 1080, HFOV
84.1) for Tables 6.1/6.2 - the thesis does not name the Gazebo camera model.

Usage:
    python scripts/bench_thesis.py [--quick] [--out bench_out/thesis]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

# The poses of the saved figures came from the planner before it chose poses by information
# (plan_trajectory(select='random')); kept so that this script reproduces them. 'information' (today's
# default) re-measures with the planner `calibgraph sim` uses.
PLAN_SELECT = "random"
sys.path.insert(0, str(REPO))

# Thesis Table 6.1 (single) and 6.2 (multi): distance -> [T_C1C2, T_C1C3, T_C2C3, T_WC1, T_WC2, T_WC3 (mm), err1, err2, err3 (px)]
THESIS_SINGLE = {
    1.5: [2.35, 2.61, 3.27, 0.52, 0.66, 0.32, 0.12, 0.22, 0.09],
    1.6: [2.42, 2.81, 3.62, 0.48, 0.61, 0.49, 0.15, 0.35, 0.12],
    1.7: [2.51, 3.25, 3.75, 0.98, 0.77, 0.55, 0.55, 0.57, 0.32],
    1.8: [2.68, 3.49, 4.12, 1.23, 0.68, 0.63, 0.76, 0.87, 0.32],
    1.9: [2.97, 3.64, 3.94, 1.12, 0.85, 0.68, 0.79, 0.82, 0.56],
    2.0: [3.12, 3.85, 4.05, 1.25, 0.98, 0.75, 0.78, 0.85, 0.63],
    2.2: [3.04, 3.95, 4.53, 0.09, 1.12, 0.92, 0.82, 0.91, 0.69],
    2.4: [3.53, 3.86, 4.78, 1.68, 1.25, 1.18, 0.93, 0.91, 0.78],
    2.6: [3.86, 4.53, 4.93, 1.57, 1.34, 1.38, 1.23, 1.12, 0.89],
    2.8: [4.22, 4.82, 5.21, 2.34, 1.49, 1.45, 1.65, 1.58, 1.21],
    3.0: [4.89, 5.32, 5.31, 2.17, 1.56, 1.90, 1.75, 1.67, 1.35],
}
THESIS_MULTI = {
    1.5: [2.35, 2.32, 2.45, 0.52, 0.69, 0.38, 0.12, 0.24, 0.09],
    1.6: [2.42, 2.73, 3.21, 0.49, 0.61, 0.43, 0.15, 0.32, 0.12],
    1.7: [2.51, 2.95, 3.43, 0.78, 0.79, 0.63, 0.46, 0.39, 0.24],
    1.8: [2.68, 3.23, 4.12, 1.23, 0.73, 0.67, 0.76, 0.65, 0.32],
    1.9: [2.92, 3.54, 4.03, 1.25, 0.82, 0.68, 0.79, 0.77, 0.56],
    2.0: [3.12, 3.65, 4.05, 1.28, 0.98, 0.75, 0.81, 0.85, 0.63],
    2.2: [3.14, 3.79, 4.46, 1.32, 1.07, 0.91, 0.85, 0.88, 0.67],
    2.4: [3.43, 3.93, 4.62, 1.56, 1.15, 1.12, 0.95, 0.91, 0.75],
    2.6: [3.76, 4.23, 4.83, 1.57, 1.31, 1.28, 1.21, 1.10, 0.93],
    2.8: [4.12, 4.76, 5.12, 2.16, 1.43, 1.38, 1.65, 1.42, 1.19],
    3.0: [4.76, 5.21, 5.27, 2.19, 1.56, 1.85, 1.79, 1.73, 1.28],
}
# Table 6.1's T_W^C1 at 2.2 m (0.09 mm) breaks the column's trend and its Table 6.2 twin (1.32 mm).
SUSPECTED_TYPO = (2.2, "single", 3)
# §6.3 table: distance -> original [Err1..3] (None = failed), resized [Err1..3]
THESIS_RESIZE = {
    1.5: ([0.17, 0.22, 0.20], [0.16, 0.18, 0.22]),
    1.6: ([0.22, 0.29, 0.29], [0.22, 0.28, 0.21]),
    1.7: ([0.78, 0.71, 0.89], [0.32, 0.43, 0.29]),
    1.8: ([0.86, 1.22, 0.98], [0.29, 0.45, 0.33]),
    1.9: ([0.99, 1.35, 1.42], [0.45, 0.39, 0.38]),
    2.0: ([1.26, 1.55, 1.78], [0.36, 0.42, 0.48]),
    2.2: ([2.35, 3.56, 2.98], [0.55, 0.62, 0.73]),
    2.4: ([None] * 3, [0.62, 0.71, 0.69]),
    2.6: ([None] * 3, [0.68, 0.75, 0.82]),
    2.8: ([None] * 3, [0.65, 0.81, 0.79]),
    3.0: ([None] * 3, [0.83, 0.93, 0.88]),
}
# Planner workspace for the A4 bar (the planner's defaults, stated): the board centre 0.30-0.75 m from the base axis, 0.15-0.80 m
# high, tilted up to 50 deg. Spreading the board over more depth and height decouples each camera's
# lateral position from its yaw (measured on synthetic corners, 0.06 px, 110 poses: 1-sigma norm
# 0.32 -> 0.25 mm).
A4_WIDE = {"radius_m": (0.30, 0.75), "height_m": (0.15, 0.80), "tilt_deg": 50.0}
# Tables 6.1/6.2 and §6.3 keep a compact volume like the thesis's hand-written trajectory (and the
# planner's defaults before they were widened), so the comparison is like for like.
THESIS_WORKSPACE = {"radius_m": (0.38, 0.62), "height_m": (0.25, 0.70), "tilt_deg": 35.0}
PAIRS = (("cam0", "cam1"), ("cam0", "cam2"), ("cam1", "cam2"))
CAMS = ("cam0", "cam1", "cam2")


def simulate(distance_m, preset, board, n_poses, seed, work: Path, spread_deg, plan_kw=None):
    """Render and capture one cell; returns (dataset dir, ground truth, seconds)."""
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import simulate_dataset
    from calibgraph.sim.workcell import ring_workcell

    t0 = time.monotonic()
    cell = ring_workcell(n_cameras=3, distance_m=distance_m, preset_name=preset, board=board, spread_deg=spread_deg,
                         name=f"thesis_{preset}_{distance_m:.1f}", seed=seed)
    world = SimWorld(cell)
    traj = plan_trajectory(world, n_poses, seed=seed, **{"select": PLAN_SELECT, **(plan_kw or {})})
    ds = work / f"{preset}_{board}_{distance_m:.1f}m_{n_poses}poses_s{seed}"
    if ds.exists():
        shutil.rmtree(ds)
    simulate_dataset(cell, traj, ds, world=world, progress=False)
    world.close()
    return ds, load_ground_truth(ds), time.monotonic() - t0


def solve_and_score(problem, gt):
    """Solve; return per-camera/pair errors or the reason it failed."""
    from calibgraph.core.errors import CalibgraphError
    from calibgraph.core.transforms import inv, pose_error
    from calibgraph.solver.solve.batch import solve

    try:
        res = solve(problem)
    except CalibgraphError as e:
        return {"failed": str(e)}
    except Exception as e:  # a solver crash is a finding of the benchmark: record it, go on
        return {"failed": f"solver crashed: {type(e).__name__}: {e}"}
    out = {"cameras": {}, "pairs": {}}
    est = {}
    for c in CAMS:
        if c not in res.cameras:
            out["cameras"][c] = None
            continue
        cr = res.cameras[c]
        est[c] = cr.T_base_cam
        e_m, e_deg = pose_error(cr.T_base_cam, gt["T_base_cam"][c])
        out["cameras"][c] = {"t_err_mm": e_m * 1e3, "r_err_deg": e_deg, "reproj_rms_px": cr.reprojection_rms_px,
                             "sigma_t_mm": float(np.linalg.norm(cr.sigma_translation_mm)),
                             "sigma_r_deg": float(np.linalg.norm(cr.sigma_rotation_deg)), "views": cr.views_used}
    for a, b in PAIRS:
        if a in est and b in est:
            T = inv(est[a]) @ est[b]
            T_true = inv(gt["T_base_cam"][a]) @ gt["T_base_cam"][b]
            out["pairs"][f"{a}__{b}"] = {"t_err_mm": pose_error(T, T_true)[0] * 1e3}
    return out


def row_values(score):
    """[T_C1C2, T_C1C3, T_C2C3, T_WC1, T_WC2, T_WC3, err1, err2, err3] or Nones."""
    if "failed" in score:
        return [None] * 9
    v = [score["pairs"].get(f"{a}__{b}", {}).get("t_err_mm") for a, b in PAIRS]
    v += [(score["cameras"][c] or {}).get("t_err_mm") for c in CAMS]
    v += [(score["cameras"][c] or {}).get("reproj_rms_px") for c in CAMS]
    return v


def cell_values(row, method):
    """(mean, min, max) per column over the seeds of one table row (a merged report holds a list
    of scores per method, a single run one score); None where no seed has a value."""
    scores = row[method] if isinstance(row[method], list) else [row[method]]
    cols = list(zip(*[row_values(sc) for sc in scores]))
    out = []
    for c in cols:
        v = [x for x in c if x is not None]
        out.append((float(np.mean(v)), min(v), max(v)) if v else (None, None, None))
    return out


def fmt(x, nd=2):
    return "-" if x is None else f"{x:.{nd}f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="3.0 m only, 24 poses (~80 s on an idle 2-core machine)")
    ap.add_argument("--out", type=Path, default=REPO / "bench_out" / "thesis")
    ap.add_argument("--poses", type=int, default=None, help="poses per cell (default 110, quick 24)")
    ap.add_argument("--distances", type=float, nargs="*", default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--a4-seeds", type=int, nargs="*", default=None, help="seeds of the A4 54-corner runs (default 0 1 2 3 4, quick 0)")
    ap.add_argument("--keep", action="store_true", help="keep the rendered datasets under OUT/datasets")
    ap.add_argument("--merge", type=Path, nargs="*", default=None,
                    help="combine the bench_thesis.json of earlier runs (e.g. one per seed) into OUT: table "
                         "cells become the mean over seeds, the bars are judged on the means")
    ap.add_argument("--skip", nargs="*", default=(), choices=("tables", "resize", "a4"), help="parts to skip")
    args = ap.parse_args(argv)
    if args.merge:
        return merge(args.merge, args.out)
    from calibgraph.core.problem import SolverOptions
    from calibgraph.detect.corners import detect_image
    from calibgraph.io.layouts import load_dataset

    n_poses = args.poses or (24 if args.quick else 110)
    args.a4_seeds = args.a4_seeds if args.a4_seeds else ([0] if args.quick else [0, 1, 2, 3, 4])
    dists = args.distances or ([3.0] if args.quick else sorted(THESIS_SINGLE))
    args.out.mkdir(parents=True, exist_ok=True)
    work = args.out / "datasets" if args.keep else Path(tempfile.mkdtemp(prefix="bench_thesis_"))
    work.mkdir(parents=True, exist_ok=True)
    report = {"protocol": {"poses": n_poses, "distances_m": dists, "seed": args.seed, "quick": args.quick,
                           "cell": "3 cameras around the robot (azimuths -100, 0, +100 deg), 1.6 m above the floor",
                           "tables_camera": "kinect_v2", "resize_camera": "d455"},
              "tables": {}, "resize": {}, "a4_54_l515_3m": None}
    t_all = time.monotonic()
    opts = SolverOptions(fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=float(np.radians(0.01)))

    def log(s):
        print(s, flush=True)

    def save(final=False):
        report["elapsed_s"] = time.monotonic() - t_all
        report["complete"] = final
        report["bars"] = bars(report)
        (args.out / "bench_thesis.json").write_text(json.dumps(report, indent=1, default=float))
        (args.out / "bench_thesis.md").write_text(markdown(report))

    try:
        for d in dists:
            if "tables" not in args.skip:
                ds_dir, gt, t_sim = simulate(d, "kinect_v2", "thesis", n_poses, args.seed, work, 200.0, THESIS_WORKSPACE)
                ds = load_dataset(ds_dir)
                row = {"sim_s": t_sim}
                for method in ("single", "joint"):
                    t0 = time.monotonic()
                    row[method] = solve_and_score(ds.to_problem(method=method, options=opts), gt)
                    row[method]["solve_s"] = time.monotonic() - t0
                report["tables"][f"{d:.1f}"] = row
                save()
                log(f"tables d={d:.1f} m: single {[fmt(x) for x in row_values(row['single'])]} | "
                    f"joint {[fmt(x) for x in row_values(row['joint'])]} ({t_sim:.0f} s sim)")
                if not args.keep:
                    shutil.rmtree(ds_dir, ignore_errors=True)
            if "resize" not in args.skip:
                ds_dir, gt, t_sim = simulate(d, "d455", "thesis", n_poses, args.seed, work, 90.0, THESIS_WORKSPACE)
                ds = load_dataset(ds_dir)
                entry = {"sim_s": t_sim}
                for label, upscale in (("original", 1), ("resized", "auto")):
                    def det(view, dataset, upscale=upscale):
                        r = detect_image(str(dataset.root / view.image), dataset.target, dataset.cameras[view.camera],
                                         upscale=upscale)
                        return (r.ids, r.uv_px) if r.ok else None

                    from dataclasses import replace

                    fresh = replace(ds, views=tuple(replace(v, ids=None, uv_px=None) for v in ds.views))
                    prob = fresh.to_problem(method="joint", options=opts, detector=det)
                    sc = solve_and_score(prob, gt)
                    sc["views_detected"] = {c: len(prob.detections_of(c)) for c in CAMS}
                    entry[label] = sc
                report["resize"][f"{d:.1f}"] = entry
                save()
                log(f"resize d={d:.1f} m: original {[fmt(x) for x in row_values(entry['original'])[6:]]} "
                    f"views {entry['original']['views_detected']} | resized {[fmt(x) for x in row_values(entry['resized'])[6:]]} "
                    f"views {entry['resized']['views_detected']}")
                if not args.keep:
                    shutil.rmtree(ds_dir, ignore_errors=True)
        if "a4" not in args.skip:
            # The bar is per camera, so the protocol is stated per camera: the board is shown to each
            # camera ~110 times (3 x 110 poses; poses aimed between two cameras count for both), over
            # a wide workspace. The thesis protocol (110 poses shared by the three cameras, default
            # workspace) runs too, for comparison. Several seeds: one seed's error is one draw.
            runs = {"per_camera": (3 * n_poses, A4_WIDE), "shared": (n_poses, THESIS_WORKSPACE)}
            report["a4_54_l515_3m"] = {"seeds": list(args.a4_seeds), "protocols": {}}
            for label, (n_a4, plan_kw) in runs.items():
                rows = []
                for seed in args.a4_seeds:
                    ds_dir, gt, t_sim = simulate(3.0, "l515", "a4_54", n_a4, seed, work, 200.0, plan_kw)
                    sc = solve_and_score(load_dataset(ds_dir).to_problem(method="joint", options=opts), gt)
                    sc.update(seed=seed, poses=n_a4, sim_s=t_sim)
                    rows.append(sc)
                    report["a4_54_l515_3m"]["protocols"][label] = {"poses": n_a4, "plan": plan_kw, "runs": rows}
                    save()
                    log(f"a4_54 L515 3 m [{label}, {n_a4} poses, seed {seed}]: {sc.get('failed', '')}" + ", ".join(
                        f"{c} {sc['cameras'][c]['t_err_mm']:.3f} mm / {sc['cameras'][c]['r_err_deg']:.4f} deg"
                        for c in CAMS if sc.get("cameras", {}).get(c)))
                    if not args.keep:
                        shutil.rmtree(ds_dir, ignore_errors=True)
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    save(final=True)
    print(markdown(report))
    print(f"wrote {args.out / 'bench_thesis.json'} and {args.out / 'bench_thesis.md'} ({report['elapsed_s']:.0f} s)")
    return 0


def merge(dirs, out: Path) -> int:
    """Combine earlier runs: tables per seed (cells averaged), the last run's resize and A4 parts."""
    runs = [json.loads((Path(d) / "bench_thesis.json").read_text()) for d in dirs]
    merged = {"protocol": dict(runs[0]["protocol"]), "tables": {}, "resize": {}, "a4_54_l515_3m": None,
              "merged_from": [str(d) for d in dirs]}
    seeds = []
    for r in runs:
        if r["tables"]:
            seeds.append(r["protocol"]["seed"])
            for d, row in r["tables"].items():
                m = merged["tables"].setdefault(d, {"single": [], "joint": []})
                m["single"].append(row["single"])
                m["joint"].append(row["joint"])
        if r["resize"]:
            merged["resize"] = r["resize"]
        if r.get("a4_54_l515_3m"):
            merged["a4_54_l515_3m"] = r["a4_54_l515_3m"]
    merged["tables"] = dict(sorted(merged["tables"].items(), key=lambda kv: float(kv[0])))
    merged["protocol"]["seeds"] = seeds
    merged["protocol"]["seed"] = seeds[0] if seeds else runs[0]["protocol"]["seed"]
    merged["bars"] = bars(merged)
    merged["elapsed_s"] = sum(r.get("elapsed_s", 0.0) for r in runs)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_thesis.json").write_text(json.dumps(merged, indent=1, default=float))
    (out / "bench_thesis.md").write_text(markdown(merged))
    print(markdown(merged))
    print(f"wrote {out / 'bench_thesis.json'} and {out / 'bench_thesis.md'}")
    return 0


def bars(report) -> dict:
    """The issue's acceptance bars, evaluated."""
    out = {}
    worst = []
    for d, row in report["tables"].items():
        for method, thesis in (("single", THESIS_SINGLE), ("joint", THESIS_MULTI)):
            ours = [m for m, _, _ in cell_values(row, method)]
            th = thesis[float(d)]
            for k, (o, t) in enumerate(zip(ours, th)):
                worst.append({"distance_m": float(d), "method": method, "column": k, "ours": o, "thesis": t,
                              "ratio": None if o is None else o / t})
    ratios = [w for w in worst if w["ratio"] is not None]
    over = [w for w in ratios if w["ratio"] > 0.5]
    out["half_of_thesis"] = {
        "pose_columns_ok": all(w["ratio"] <= 0.5 for w in ratios if w["column"] < 6) and bool(ratios),
        # Table 6.1 gives 0.09 mm for T_W^C1 at 2.2 m between 1.25 (2.0 m) and 1.68 (2.4 m), and
        # Table 6.2 gives 1.32 for the same cell; every other single/multi pair of the T_W^Ci columns
        # differs by at most 0.20 mm.
        # Reported both with and without that cell.
        "pose_columns_ok_without_suspected_typo": all(
            w["ratio"] <= 0.5 for w in ratios if w["column"] < 6 and (w["distance_m"], w["method"], w["column"]) != SUSPECTED_TYPO)
        and bool(ratios),
        "cells_over_half": over,
        "reprojection_columns_ok": all(w["ratio"] <= 0.5 for w in ratios if w["column"] >= 6) and bool(ratios),
        "missing": sum(w["ratio"] is None for w in worst),
        "worst": sorted(ratios, key=lambda w: -w["ratio"])[:5],
    }
    r3 = report["resize"].get("3.0")
    if r3:
        cams = r3["resized"].get("cameras", {})
        out["d455_3m_calibrates"] = bool(cams) and all(cams.get(c) and cams[c]["t_err_mm"] < 5.0 for c in CAMS)
    a4 = (report.get("a4_54_l515_3m") or {}).get("protocols", {})
    for label, proto in a4.items():
        cams = [r["cameras"].get(c) for r in proto["runs"] if "cameras" in r for c in CAMS]
        failed = sum("cameras" not in r for r in proto["runs"]) + sum(v is None for v in cams)
        ok = [v for v in cams if v]
        out[f"a4_54_3m_{label}"] = {
            "camera_runs": len(cams), "failed": failed,
            "within_0.5mm_0.03deg": sum(v["t_err_mm"] <= 0.5 and v["r_err_deg"] <= 0.03 for v in ok),
            "max_t_err_mm": max((v["t_err_mm"] for v in ok), default=None),
            "max_r_err_deg": max((v["r_err_deg"] for v in ok), default=None),
            "mean_t_err_mm": float(np.mean([v["t_err_mm"] for v in ok])) if ok else None,
            "mean_sigma_t_mm": float(np.mean([v["sigma_t_mm"] for v in ok])) if ok else None,
        }
    return out


def markdown(report) -> str:
    L = ["# calibgraph vs the thesis's simulated protocol (chapter 6)", "",
         f"Poses per cell: {report['protocol']['poses']}; seed {report['protocol']['seed']}; "
         f"{report['protocol']['cell']}; rendered MuJoCo images (sensor noise 2 DN + shot noise, 0.6 px blur), "
         "corners detected by calibgraph.detect.corners, solved by calibgraph's GTSAM graph; errors vs simulator truth.", ""]
    cols = ["T_C1C2", "T_C1C3", "T_C2C3", "T_W^C1", "T_W^C2", "T_W^C3", "err1", "err2", "err3"]
    for method, thesis, title in (("single", THESIS_SINGLE, "Table 6.1 (single-camera)"),
                                  ("joint", THESIS_MULTI, "Table 6.2 (multi-camera)")):
        if not report["tables"]:
            break
        seeds = report["protocol"].get("seeds")
        L += [f"## {title}: ours / thesis (translation errors mm, reprojection px)"
              + (f"; ours = mean (min–max) over seeds {seeds}" if seeds and len(seeds) > 1 else ""), "",
              "| d [m] | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
        for d, row in report["tables"].items():
            ours = cell_values(row, method)
            th = thesis[float(d)]
            multi = isinstance(row[method], list) and len(row[method]) > 1
            L.append(f"| {d} | " + " | ".join(
                f"{fmt(m, 3)}" + (f" ({fmt(lo, 2)}–{fmt(hi, 2)})" if multi and k < 6 and m is not None else "") + f" / {t:.2f}"
                for k, ((m, lo, hi), t) in enumerate(zip(ours, th))) + " |")
        L.append("")
    if report["resize"]:
        L += ["## §6.3: D455 cameras, original vs up-scaled detection (reprojection px; views detected)", "",
              "| d [m] | ours original err1/2/3 | thesis original | ours resized err1/2/3 | thesis resized | "
              "ours resized T_W^C err mm (1/2/3) |", "|---|---|---|---|---|---|"]
        for d, e in report["resize"].items():
            o = row_values(e["original"])
            r = row_values(e["resized"])
            tho, thr = THESIS_RESIZE[float(d)]
            L.append(f"| {d} | {' / '.join(fmt(x, 3) for x in o[6:])} ({'/'.join(str(v) for v in e['original']['views_detected'].values())} views) | "
                     f"{' / '.join(fmt(x) for x in tho)} | {' / '.join(fmt(x, 3) for x in r[6:])} "
                     f"({'/'.join(str(v) for v in e['resized']['views_detected'].values())} views) | {' / '.join(fmt(x) for x in thr)} | "
                     f"{' / '.join(fmt(x, 3) for x in r[3:6])} |")
        L.append("")
    a4 = (report.get("a4_54_l515_3m") or {}).get("protocols", {})
    for label, proto in a4.items():
        L += [f"## A4 54-corner board, 3 x L515 at 3 m (joint): {label}, {proto['poses']} poses, planner {proto['plan'] or 'defaults'}",
              "", "| seed | camera | t err mm | r err deg | 1σ t mm (norm) | 1σ r deg (norm) | reproj px | views |",
              "|---|---|---|---|---|---|---|---|"]
        for r in proto["runs"]:
            if "cameras" not in r:
                L.append(f"| {r['seed']} | - | failed: {r['failed']} | | | | | |")
                continue
            for c, v in r["cameras"].items():
                if v:
                    L.append(f"| {r['seed']} | {c} | {v['t_err_mm']:.3f} | {v['r_err_deg']:.4f} | {v['sigma_t_mm']:.3f} | "
                             f"{v['sigma_r_deg']:.4f} | {v['reproj_rms_px']:.3f} | {v['views']} |")
        L.append("")
    if not report.get("complete", True):
        L += ["**Partial run** (the benchmark was still running or was interrupted when this was written).", ""]
    L += ["## Bars", "", "```", json.dumps(report["bars"], indent=1, default=float), "```", ""]
    return "\n".join(L)


if __name__ == "__main__":
    sys.exit(main())
