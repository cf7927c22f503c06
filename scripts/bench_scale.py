"""How the batch solve scales with cameras and poses: wall time, CPU time and peak memory, by stage.

Synthetic corners (calibgraph.sim.synthetic_corners.make_scene): cameras on a 3 m ring, the A4 board,
FK noise 0.1 mm / 0.01 deg. The default is issue 36's case: L515-class cameras, 0.1 px corner noise,
workspace +-0.4 m, seed 1, solved twice per configuration:

- ``factory``: the intrinsics as the simulated cameras report them (factory-class errors, the sim's
  default), labelled ``source: calibration`` - what a user's cameras give; the data usually reject
  them and the solve re-solves with a wide prior (the realistic case);
- ``true``: the true intrinsics labelled calibration (an oracle's case: the figure is shown beside
  the realistic one, never instead of it).

Each solve runs in its own process (its peak memory is its own) and reports wall and CPU seconds,
the load average, the solver's timed stages (wall) and the CPU of its parts (start, first joint
solve, the widened-intrinsics re-solve, the moved-camera test, the error budget, assembling), and
which part dominates. Prints a table and writes scripts/results/bench_scale.{md,json}.

    python scripts/bench_scale.py                                  # 4x120, 16x480, 32x480, both cases
    python scripts/bench_scale.py --configs 16x480 --repeat 3
    python scripts/bench_scale.py --preset d455 --pixel-sigma 0.3 --workspace 0.15 --cases true   # the old bench
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "scripts" / "results"

ONE = r"""
import json, os, resource, sys, time
from dataclasses import replace
from calibgraph.core.transforms import pose_error  # calibgraph before numpy, as the CLI loads them (BLAS threads)
import numpy as np
from calibgraph.sim.synthetic_corners import make_scene, ring_cameras
import calibgraph.solver.solve.batch as batch
import calibgraph.solver.changes.moved as moved
n_cam, n_poses, seed, case, preset, px, ws = (int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4],
                                              sys.argv[5], float(sys.argv[6]), float(sys.argv[7]))
sc = make_scene(cameras=ring_cameras([3.0] * n_cam, presets=(preset,)), n_poses=n_poses, pixel_sigma_px=px,
                fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=np.radians(0.01), seed=seed,
                workspace_half_extent_m=(ws, ws, ws), **({"reported_intrinsics": "exact"} if case == "true" else {}))
p = sc.problem.with_(cameras={n: replace(c, source="calibration") for n, c in sc.problem.cameras.items()})
parts = {}
def part(mod, name, label):
    fn = getattr(mod, name)
    def wrapper(*a, **k):
        c0 = time.process_time()
        try:
            return fn(*a, **k)
        finally:
            parts[label] = parts.get(label, 0.0) + time.process_time() - c0
    setattr(mod, name, wrapper)
part(batch, "usable_views", "start")
part(batch, "initial_values", "start")
part(batch, "solve_joint", "first joint solve")
part(batch, "widen_inadequate_intrinsics", "widened-intrinsics re-solve")
part(moved, "camera_splits", "moved-camera test (inside the solves)")
part(batch, "error_budgets", "error budget")
part(batch, "_assemble", "assemble (budget included)")
rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
timings = {}
t0, c0 = time.perf_counter(), time.process_time()
r = batch.solve(p, timings=timings)
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
err = [1e3 * pose_error(c.T_ref_cam, sc.truth.T_ref_cam[n])[0] for n, c in r.cameras.items()]
z = [1e3 * pose_error(c.T_ref_cam, sc.truth.T_ref_cam[n])[0] / np.linalg.norm(c.sigma_translation_mm)
     for n, c in r.cameras.items()]
print(json.dumps({"cameras": n_cam, "poses": n_poses, "case": case, "views": len(p.detections), "wall_s": wall,
                  "cpu_s": cpu, "load": os.getloadavg()[0], "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20,
                  "rss_before_solve_gb": rss0 / 2 ** 20, "stages_s": timings, "parts_cpu_s": parts,
                  "outside_stages_wall_s": wall - sum(timings.values()), "iterations": r.iterations,
                  "converged": r.converged, "notes": len(r.notes), "err_mm_mean": float(np.mean(err)),
                  "err_mm_max": float(np.max(err)), "err_over_sigma_rms": float(np.sqrt(np.mean(np.square(z))))}))
"""


DISJOINT = ("start", "first joint solve", "widened-intrinsics re-solve", "assemble (budget included)")


def run(n_cam: int, n_poses: int, seed: int, case: str, args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", ONE, str(n_cam), str(n_poses), str(seed), case, args.preset,
                          str(args.pixel_sigma), str(args.workspace)], capture_output=True, text=True, env=env, check=False)
    if out.returncode != 0:
        return {"cameras": n_cam, "poses": n_poses, "case": case, "error": out.stderr.strip().splitlines()[-1][:300]}
    r = json.loads(out.stdout.strip().splitlines()[-1])
    parts = {k: r["parts_cpu_s"].get(k, 0.0) for k in DISJOINT}
    parts["other"] = r["cpu_s"] - sum(parts.values())
    r["dominant_part"] = max(parts, key=parts.get)
    r["dominant_stage"] = max(r["stages_s"], key=r["stages_s"].get)
    return r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--configs", nargs="*", default=["4x120", "16x480", "32x480"], help="CAMERASxPOSES")
    ap.add_argument("--cases", nargs="*", choices=("factory", "true"), default=["factory", "true"])
    ap.add_argument("--preset", default="l515")
    ap.add_argument("--pixel-sigma", type=float, default=0.1)
    ap.add_argument("--workspace", type=float, default=0.4, help="half extent of the workspace, m")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=1, help="runs per configuration (same seed); the median is shown")
    ap.add_argument("--out", type=Path, default=OUT / "bench_scale")
    args = ap.parse_args()
    rows = []
    t0, load0 = time.time(), os.getloadavg()
    for cfg in args.configs:
        n_cam, n_poses = (int(x) for x in cfg.lower().split("x"))
        for case in args.cases:
            runs = [run(n_cam, n_poses, args.seed, case, args) for _ in range(args.repeat)]
            ok = [r for r in runs if "error" not in r]
            if not ok:
                rows.append(runs[0])
                print(f"{n_cam:3d} cameras x {n_poses:4d} poses, {case}: FAILED {runs[0]['error']}", flush=True)
                continue
            best = sorted(ok, key=lambda r: r["cpu_s"])[len(ok) // 2]
            best["wall_s_all"] = [r["wall_s"] for r in ok]
            best["cpu_s_all"] = [r["cpu_s"] for r in ok]
            rows.append(best)
            print(f"{n_cam:3d} cameras x {n_poses:4d} poses ({best['views']} views), {case} intrinsics: "
                  f"{best['wall_s']:6.2f} s wall, {best['cpu_s']:6.2f} s CPU at load {best['load']:.1f}, "
                  f"{best['peak_rss_gb']:.2f} GB peak, {best['iterations']} iterations, {best['notes']} notes; "
                  f"dominant: {best['dominant_part']} / {best['dominant_stage']}; error {best['err_mm_mean']:.3f} mm "
                  f"mean, error/1σ RMS {best['err_over_sigma_rms']:.2f}", flush=True)
    lines = ["# Solve time and memory against cameras and poses", "",
             f"Synthetic corners, {args.preset.upper()}-class cameras on a 3 m ring, {args.pixel_sigma:g} px corner noise, "
             f"workspace ±{args.workspace:g} m, seed {args.seed}, FK noise 0.1 mm / 0.01 deg. Intrinsics: *factory* = as "
             "the simulated cameras report them (factory-class errors), labelled calibration (the realistic case); "
             "*true* = the true intrinsics labelled calibration (oracle, beside it). Both are estimated under the "
             f"file's prior. {platform.node()}, {os.cpu_count()} cores, load average (1/5/15 min) at the start "
             f"{load0[0]:.1f}/{load0[1]:.1f}/{load0[2]:.1f}, each run's 1-min load beside it: wall times are "
             f"inflated by the load, CPU seconds much less. {time.time() - t0:.0f} s in all. Median (by CPU) of "
             f"{args.repeat} run(s). Made by scripts/bench_scale.py.", "",
             "| cameras | poses | intrinsics | views | wall s | CPU s | load | peak GB | iterations | notes | LM s | "
             "marginals s | outside stages s | dominant (CPU part / timed stage) | error mm mean | error/1σ RMS |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['cameras']} | {r['poses']} | {r['case']} | | failed: {r['error']} |" + " |" * 11)
            continue
        st = r["stages_s"]
        lines.append(f"| {r['cameras']} | {r['poses']} | {r['case']} | {r['views']} | {r['wall_s']:.2f} | {r['cpu_s']:.2f} | "
                     f"{r['load']:.1f} | {r['peak_rss_gb']:.2f} | {r['iterations']} | {r['notes']} | {st.get('lm', 0):.2f} | "
                     f"{st.get('marginals', 0):.2f} | {r['outside_stages_wall_s']:.2f} | {r['dominant_part']} / "
                     f"{r['dominant_stage']} | {r['err_mm_mean']:.3f} | {r['err_over_sigma_rms']:.2f} |")
    lines += ["", "CPU seconds of the solve's parts (start: PnP candidates and the initialiser; the moved-camera test "
              "runs inside both solves; the budget inside assembling):", "",
              "| cameras | poses | intrinsics | " + " | ".join(DISJOINT) + " | moved-camera test | error budget | other |",
              "|---|---|---|" + "---|" * (len(DISJOINT) + 3)]
    for r in rows:
        if "error" in r:
            continue
        pc = r["parts_cpu_s"]
        other = r["cpu_s"] - sum(pc.get(k, 0.0) for k in DISJOINT)
        lines.append(f"| {r['cameras']} | {r['poses']} | {r['case']} | " +
                     " | ".join(f"{pc.get(k, 0.0):.2f}" for k in DISJOINT) +
                     f" | {pc.get('moved-camera test (inside the solves)', 0.0):.2f} | {pc.get('error budget', 0.0):.2f} "
                     f"| {other:.2f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps(rows, indent=2))
    print(f"wrote {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
