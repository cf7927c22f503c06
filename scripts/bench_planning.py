#!/usr/bin/env python
"""How many captures (and how much robot time) until every camera is within tolerance?

Four ways of choosing the robot poses, on simulated cells (default: three L515 at 3 m;
irregular_four: four mixed cameras at 1.5-5 m, two facing each other; top_down: one camera
looking down from 2.5 m; mixed_N: four cameras, a D455, an L515, a Kinect V2 and one more of these,
at 2-3.5 m and irregular azimuths and heights, drawn with seed N), over several seeds:

(a) active:  ``calibgraph capture --auto``'s loop (:func:`calibgraph.acquire.auto.run_auto`),
             camera placements unknown: survey included, stops at the tolerance, or early when a
             camera is out of reach (then "stopped short" with the cameras given up);
(b) planner: :func:`calibgraph.plan.planner.plan_trajectory` with the placements known (60
             poses), captures taken in order; the batch solve is repeated on growing prefixes
             (every capture from the 3rd) and the first prefix with every camera within tolerance counts;
(c) random:  random reachable, collision-free poses (board facing outwards in a random direction
             of the upper hemisphere), same prefix rule;
(d) thesis:  110 planned poses, all of them (the thesis's predefined trajectory length);
(e) planner_random: as (b) with ``select='random'``: the first poses sampled near each camera,
             the planner before its information model.

Each is run twice: with **realistic** intrinsics — the cameras report factory-class intrinsics
(``realism.reported_intrinsics`` of the cell, or focal 0.6 %, principal point 3 px, k1/k2 0.01
when the cell does not say), which the solver estimates under the factory prior — and with the
**oracle**'s: the cameras report their true intrinsics, held by the solver (``reported_intrinsics:
exact``), the figures every simulated bench gave before the simulator reported factory values.

Corners are the true projections plus 0.02 px Gaussian noise (what the batch solver estimates on
rendered frames with calibgraph's detector: 0.016 px on the demo cell, three L515 at 3 m; 0.018 px
on a D455 / L515 / Kinect V2 cell at 2.4-3 m) with the cell's robot FK error: the bench compares the choice of
poses, not the detector; the rendered path is what ``calibgraph demo --auto`` runs. Robot time is
the joint-space motion model at speed scale 0.2 (+0.5 s settling per motion, via poses included).
Every method is judged by the batch solver's 1-sigma, and the true error / 1-sigma is reported.

Usage:
    nice python scripts/bench_planning.py [--quick] [--seeds 0 1 2] [--cells default irregular_four mixed_0]
        [--methods active planner] [--intrinsics realistic oracle]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calibgraph.acquire.auto import AutoOptions, run_auto  # noqa: E402
from calibgraph.core.problem import Capture, Detection, Problem  # noqa: E402
from calibgraph.core.transforms import exp_so3, inv, log_so3, make_T, pose_error  # noqa: E402
from calibgraph.io.files import read_yaml  # noqa: E402
from calibgraph.plan.active import motion_time_s, sigma_norms  # noqa: E402
from calibgraph.plan.cell import cell_from_world_dict  # noqa: E402
from calibgraph.plan.planner import free_motion, plan_trajectory  # noqa: E402
from calibgraph.plan.survey import board_pose_facing, reach_pose, seeds_at  # noqa: E402
from calibgraph.plan.visibility import board_visibility  # noqa: E402
from calibgraph.sim.planning_world import planning_world  # noqa: E402
from calibgraph.sim.render import SimWorld  # noqa: E402
from calibgraph.sim.corner_devices import corner_devices  # noqa: E402
from calibgraph.sim.workcell import workcell_from_dict  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402

PIXEL_SIGMA_PX = 0.02
FACTORY = {"focal_rel_sigma": 0.006, "principal_point_sigma_px": 3.0, "k1_sigma": 0.01, "k2_sigma": 0.01, "seed": 11}


def mixed_cell(seed: int) -> dict:
    """A four-camera world drawn with ``seed``: a D455, an L515, a Kinect V2 and one more of these,
    2-3.5 m from the base axis at azimuths at least 35 deg apart, 0.3-1.5 m high, looking at the
    arm's reach; factory-class reported intrinsics."""
    rng = np.random.default_rng(seed)
    presets = ["d455", "l515", "kinect_v2", ["d455", "l515", "kinect_v2"][rng.integers(3)]]
    rng.shuffle(presets)
    while True:
        az = np.sort(rng.uniform(-np.pi, np.pi, 4))
        if np.diff(np.r_[az, az[0] + 2 * np.pi]).min() > np.radians(35):
            break
    cams = {}
    for i, (a, p) in enumerate(zip(az, presets)):
        d, h = rng.uniform(2.0, 3.5), rng.uniform(0.3, 1.5)
        la_r, la_a = rng.uniform(0.2, 0.5), a + rng.uniform(-0.3, 0.3)
        cams[f"cam{i}_{p}"] = {"preset": p, "position_m": [round(float(d * np.cos(a)), 3), round(float(d * np.sin(a)), 3),
                                                         round(float(h), 3)],
                               "look_at_m": [round(float(la_r * np.cos(la_a)), 3), round(float(la_r * np.sin(la_a)), 3),
                                             round(float(rng.uniform(0.3, 0.6)), 3)]}
    return {"name": f"mixed_{seed}", "board": "a4_54", "floor_z_m": -0.8, "realism": {"reported_intrinsics": dict(FACTORY)},
            "robot": {"fk_sigma_translation_m": 5.0e-5, "fk_sigma_rotation_deg": 0.005}, "cameras": cams}


def load_cell(name: str, intrinsics: str) -> tuple:
    """(world mapping, path label) of a bench cell with the cameras reporting ``intrinsics``:
    'realistic' (the cell's factory-class block, or :data:`FACTORY`) or 'oracle' (exact)."""
    if name.startswith("mixed_"):
        wd, path = mixed_cell(int(name.split("_")[1])), name
    else:
        path = str(REPO / "datasets" / "workcells" / f"{name}.yaml")
        wd = read_yaml(path, "workcell")
    realism = dict(wd.get("realism") or {})
    if intrinsics == "oracle":
        realism["reported_intrinsics"] = "exact"
    elif not isinstance(realism.get("reported_intrinsics"), dict):
        realism["reported_intrinsics"] = dict(FACTORY)
    return {**wd, "realism": realism}, path
SPEED = 0.2
DQ_MAX = AutoOptions().dq_max_rad_s
TOL = (0.5, 0.03)


def _within(cov) -> bool:
    t, r = sigma_norms(cov)
    return t <= TOL[0] and r <= TOL[1]


def _sig_mm(cov) -> float:
    return sigma_norms(cov)[0]


def _judge(res, wc) -> dict:
    out = {}
    for n in wc.camera_names:
        c = res.cameras.get(n) if res is not None else None
        if c is None:
            out[n] = None
            continue
        t, r = sigma_norms(c.covariance)
        T = wc.camera(n).T_base_cam
        e_m, e_deg = pose_error(c.T_ref_cam, T)
        # per axis (rotation about, then translation along the base axes: the covariance's convention)
        z = np.r_[log_so3(c.T_ref_cam[:3, :3] @ T[:3, :3].T), c.T_ref_cam[:3, 3] - T[:3, 3]] / np.sqrt(np.diag(c.covariance))
        out[n] = {"sigma_mm": round(t, 3), "sigma_deg": round(r, 4), "err_mm": round(e_m * 1e3, 3),
                  "err_deg": round(e_deg, 4), "err_over_sigma": round(e_m * 1e3 / t, 2),
                  "z_max": round(float(np.abs(z).max()), 2), "views": c.views_used}
    return out


def _observe(world, wc, q, rng):
    """Capture at q: reported flange pose (FK error) and the corner detections of every camera."""
    world.set_q(q)
    T_true = world.T_base_flange()
    T_rep = T_true @ make_T(exp_so3(rng.normal(scale=np.radians(wc.fk_sigma_rotation_deg), size=3)),
                            rng.normal(scale=wc.fk_sigma_translation_m, size=3))
    dets = []
    for c in wc.cameras:
        if board_visibility(world, c.name, world.T_base_board(), margin_px=2.0, max_angle_deg=70.0, min_square_px=4.0):
            T_cb = inv(c.T_base_cam) @ world.T_base_board()
            p = wc.target.points_board_m @ T_cb[:3, :3].T + T_cb[:3, 3]
            dets.append((c.name, np.arange(len(p)), c.intrinsics.project(p) + rng.normal(scale=PIXEL_SIGMA_PX, size=(len(p), 2))))
    return T_rep, dets


def _sequence_run(world, wc, qs_capture, vias_time, seed, step=1, all_at_once=False):
    """Capture along ``qs_capture``; solve prefixes every ``step`` captures until all within tolerance."""
    rng = np.random.default_rng(seed + 100)
    caps, dets = [], []
    for k, q in enumerate(qs_capture):
        T, ds = _observe(world, wc, q, rng)
        caps.append(Capture(index=k, T_base_flange=T, q_rad=np.asarray(q)))
        dets += [Detection(camera=n, capture=k, ids=i, uv_px=uv) for n, i, uv in ds]
    seen_all = last = None
    for n in (range(len(caps), len(caps) + 1) if all_at_once else range(3, len(caps) + 1, step)):
        sub = [d for d in dets if d.capture < n]
        cams = {n: intr for n, intr in wc.intrinsics().items() if sum(d.camera == n for d in sub) >= 3}  # as reported
        if len(cams) < len(wc.cameras) and not all_at_once:
            continue
        try:
            res = solve(Problem(points_board_m=wc.target.points_board_m, cameras=cams, captures=tuple(caps[:n]),
                                detections=tuple(d for d in sub if d.camera in cams)))
        except Exception:  # noqa: BLE001 - too few views for a solve yet
            continue
        last = (n, res)
        if all_at_once or all(_within(c.covariance) for c in res.cameras.values()):
            seen_all = (n, res)
            break
    if seen_all is None:
        out = {"captures": None, "robot_time_s": round(vias_time(len(caps)), 1), "cameras": {},
               "note": f"not within tolerance after {len(caps)} captures"}
        if last is not None:  # where the whole sequence got: the worst camera's 1-sigma, the true errors
            out["cameras"] = _judge(last[1], wc)
            out["note"] += f" (worst 1σ {max(_sig_mm(c.covariance) for c in last[1].cameras.values()):.2f} mm)"
        return out
    n, res = seen_all
    return {"captures": n, "robot_time_s": round(vias_time(n), 1), "converged": all(_within(c.covariance) for c in res.cameras.values()),
            "cameras": _judge(res, wc)}


def _traj_time(world, traj):
    """Cumulative robot time to reach the k-th capture pose of a trajectory (vias included)."""
    q = world.start_configuration()
    t, out = 0.0, []
    for p in traj.poses:
        t += motion_time_s(q, p.q_rad, DQ_MAX, SPEED)
        q = p.q_rad
        if p.capture:
            out.append(t)
    return out


def run_active(wd, path, seed, max_poses):
    wc = workcell_from_dict(wd, path)
    sim = SimWorld(wc)
    cell = cell_from_world_dict(wd, path)
    robot, cams, oracle = corner_devices(sim, PIXEL_SIGMA_PX, seed)
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        rep = run_auto(robot, cams, cell, planning_world(cell), Path(tmp) / "ds", detector=oracle,
                       options=AutoOptions(max_poses=max_poses, seed=seed), progress=False)
        wall = time.perf_counter() - t0
        choose = [s.get("choose_time_s") for s in rep.steps if s.get("choose_time_s") is not None]
        given_up = json.loads((Path(tmp) / "ds" / "plan_log.json").read_text()).get("out_of_reach") or {}
    return {"captures": rep.captures if rep.converged else None, "captures_used": rep.captures,
            "robot_time_s": round(rep.robot_time_s, 1), "converged": rep.converged, "cameras": _judge(rep.result, wc),
            "survey_captures": sum(s["phase"].startswith("survey") for s in rep.steps),
            "choose_s_median": round(float(np.median(choose)), 2) if choose else None,
            "choose_s_max": round(float(np.max(choose)), 2) if choose else None, "wall_s": round(wall, 1),
            "stop": rep.stop_reason, "status": rep.cameras, "out_of_reach": given_up}


def run_planner(wd, path, seed, n, select="information"):
    wc = workcell_from_dict(wd, path)
    world = SimWorld(wc)
    traj = plan_trajectory(world, n, seed=seed, select=select)
    times = _traj_time(world, traj)
    qs = [p.q_rad for p in traj.poses if p.capture]
    return _sequence_run(world, wc, qs, lambda k: times[k - 1], seed, all_at_once=(n >= 110))


def run_random(wd, path, seed, n):
    wc = workcell_from_dict(wd, path)
    world = SimWorld(wc)
    rng = np.random.default_rng(seed + 7)
    q = world.start_configuration()
    qs, times, t, tries = [], [], 0.0, 0
    while len(qs) < n and tries < 40 * n:
        tries += 1
        a = rng.uniform(-np.pi, np.pi)
        r, h = rng.uniform(0.3, 0.75), rng.uniform(0.15, 0.8)
        centre = np.array([r * np.cos(a), r * np.sin(a), h])
        d = rng.normal(size=3)
        d[2] = abs(d[2])
        d[:2] += 1.5 * centre[:2] / np.linalg.norm(centre[:2])  # outwards, somewhere in the upper hemisphere
        T_bb = board_pose_facing(centre + 3 * d / np.linalg.norm(d), centre, wc.target)
        got = reach_pose(world, T_bb, wc.T_flange_board, seeds_at(a, q, 3, rng))
        if got is None:
            continue
        motion = free_motion(world, q, got[0])
        if motion is None:
            continue
        for qq in motion:
            t += motion_time_s(q, qq, DQ_MAX, SPEED)
            q = qq
        qs.append(got[0])
        times.append(t)
    return _sequence_run(world, wc, qs, lambda k: times[k - 1], seed)


def _fmt(r):
    if r is None:
        return "-"
    if r.get("captures") is None:
        if r.get("out_of_reach"):
            return f"short at {r['captures_used']} ({', '.join(r['out_of_reach'])} out of reach)"
        if str(r.get("note", "")).startswith("InputError"):
            return "could not plan: " + r["note"].split(": ", 1)[1].split(";")[0]
        worst = _worst(r)
        return "not reached" + (f" (worst 1σ {worst} mm at the end)" if worst != "-" else "")
    return f"{r['captures']} / {r['robot_time_s']:.0f} s"


def _worst(r) -> str:
    cams = [v for v in ((r or {}).get("cameras") or {}).values() if v]
    return f"{max(v['sigma_mm'] for v in cams):.2f}" if cams else "-"


def _errors(r) -> str:
    """Per camera: true error mm (error / 1-sigma)."""
    return ", ".join(f"{n} {v['err_mm']:.2f} ({v['err_over_sigma']:.1f})" for n, v in ((r or {}).get("cameras") or {}).items()
                     if v) or "-"


def run_planner_random(wd, path, seed, n):
    return run_planner(wd, path, seed, n, select="random")


METHODS = {"active": (run_active, "max_poses"), "planner": (run_planner, "n_plan"), "random": (run_random, "n_plan"),
           "thesis_110": (run_planner, 110), "planner_random": (run_planner_random, "n_plan")}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="one seed, smaller budgets")
    ap.add_argument("--seeds", type=int, nargs="*", default=None)
    ap.add_argument("--cells", nargs="*", default=["default", "irregular_four", "top_down", "mixed_0", "mixed_1"])
    ap.add_argument("--methods", nargs="*", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--intrinsics", nargs="*", default=["realistic", "oracle"], choices=["realistic", "oracle"])
    ap.add_argument("--max-poses", type=int, default=None, help="budget of (a) (default 80, 40 with --quick)")
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    ap.add_argument("--tag", default="", help="results go to bench_planning_TAG.{md,json}")
    args = ap.parse_args(argv)
    seeds = args.seeds if args.seeds is not None else ([0] if args.quick else [0, 1, 2])
    n_plan, max_poses = (36, 40) if args.quick else (60, 80)
    max_poses = args.max_poses or max_poses
    budgets = {"max_poses": max_poses, "n_plan": n_plan}
    rows = []
    for cell_name in args.cells:
        for seed in seeds:
            row = {"cell": cell_name, "seed": seed}
            for intr in args.intrinsics:
                wd, path = load_cell(cell_name, intr)
                for method in args.methods:
                    if args.quick and method == "thesis_110":
                        continue
                    fn, n = METHODS[method]
                    t0 = time.perf_counter()
                    try:
                        got = fn(wd, path, seed, budgets.get(n, n))
                    except Exception as e:  # noqa: BLE001 - a method that cannot run on a cell is a result too
                        got = {"captures": None, "note": f"{type(e).__name__}: {e}"}
                    row[f"{method}_{intr}"] = got
                    print(f"{cell_name} seed {seed} {method} ({intr} intrinsics): {_fmt(got)} "
                          f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
            rows.append(row)
    args.out.mkdir(parents=True, exist_ok=True)
    tag = ("_quick" if args.quick else "") + (f"_{args.tag}" if args.tag else "")
    (args.out / f"bench_planning{tag}.json").write_text(json.dumps(rows, indent=1))
    md = [f"# bench_planning{tag}: captures / robot time until every camera is within {TOL[0]} mm / {TOL[1]}° (1σ)",
          "", f"Synthetic corners ({PIXEL_SIGMA_PX} px) through the MuJoCo FR3 cell; (a) placements unknown, survey included, "
          f"at most {max_poses} captures; (b)-(c) first prefix (every capture from the 3rd) within tolerance; "
          "(d) all 110 poses. **realistic**: the cameras report factory-class intrinsics, which the solver "
          "estimates under the factory prior; **oracle**: they report their true intrinsics and the solver "
          "holds them (the figures before the simulator reported factory values).", ""]
    cols = [(m, i) for m in args.methods for i in args.intrinsics if not (args.quick and m == "thesis_110")]
    head = " | ".join(f"({'abcde'[list(METHODS).index(m)]}) {m} {i}" + (": worst 1σ mm" if m == "thesis_110" else "")
                      for m, i in cols)
    md += [f"| cell | seed | {head} |", "|---|---|" + "---|" * len(cols)]
    for r in rows:
        cells = [(_worst(r.get(f"{m}_{i}")) if m == "thesis_110" else _fmt(r.get(f"{m}_{i}"))) for m, i in cols]
        md.append(f"| {r['cell']} | {r['seed']} | " + " | ".join(cells) + " |")
    if "active" in args.methods:
        md += ["", "(a) active, per camera: true error mm (error / 1σ), survey captures, choose time median / max s:", "",
               "| cell | seed | intrinsics | errors | survey | choose s |", "|---|---|---|---|---|---|"]
        for r in rows:
            for i in args.intrinsics:
                a = r.get(f"active_{i}") or {}
                md.append(f"| {r['cell']} | {r['seed']} | {i} | {_errors(a)} | {a.get('survey_captures', '-')} | "
                          f"{a.get('choose_s_median', '-')}/{a.get('choose_s_max', '-')} |")
        for r in rows:
            for i in args.intrinsics:
                a = r.get(f"active_{i}") or {}
                if a and not a.get("converged"):
                    md.append(f"\n{r['cell']} seed {r['seed']} (a) {i}: {a.get('stop', a.get('note', ''))}:")
                    md += [f"- {n}: {s}" for n, s in (a.get("status") or {}).items()]
    (args.out / f"bench_planning{tag}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
