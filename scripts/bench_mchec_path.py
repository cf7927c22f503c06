"""The whole path of ``calibgraph solve DIR`` on the MC-HEC recording, stage by stage, cold.

The dataset (../shared/datasets/mchec_medium_workcell: 4 cameras x 251 frames of 1920x1080, mostly
without the board) is copied into a temporary folder first, so the detection cache, the lock and the
result land there (never in ../shared) and every run starts without a cache. Each run is its own
process (its peak memory is its own) and does what ``calibgraph solve DIR --quiet`` does: read the
dataset, detect (survey, guided and blind search, board fit, coarse solves), build the problem, solve
(the moved-camera test around the solve, the widened-intrinsics re-solve, the error budget), write
the result and the summary.

Every stage is timed in wall seconds and CPU seconds (the process's, so the detection's worker
threads count), with the load average beside it. ``--profile`` runs once more under cProfile with
one profiler per thread timed by the thread's CPU clock, and lists where the detection's CPU goes,
per function (so the next cut is named). Writes scripts/results/bench_mchec_path.{md,json}.

    nice -n 10 python scripts/bench_mchec_path.py --profile
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
DATA = ROOT.parent / "shared" / "datasets" / "mchec_medium_workcell"

ONE = r"""
import cProfile, io, json, os, pstats, resource, shutil, sys, tempfile, threading, time
from pathlib import Path

src, profile = Path(sys.argv[1]), sys.argv[2] == "1"
T = {}          # stage -> [wall s, CPU s, calls]
stack = []

def clock():
    return time.perf_counter(), time.process_time()

def timed(stage, fn):
    def wrapper(*a, **k):
        name = stage if not stack else f"{stack[0]} > {stage}"
        stack.append(stage)
        w0, c0 = clock()
        try:
            return fn(*a, **k)
        finally:
            w1, c1 = clock()
            stack.pop()
            row = T.setdefault(name, [0.0, 0.0, 0])
            row[0] += w1 - w0; row[1] += c1 - c0; row[2] += 1
    return wrapper

import calibgraph.solver.solve.batch as batch
import calibgraph.detect.guided_dataset as build
import calibgraph.io.layouts as layouts
import calibgraph.cli.solve as cli_solve
from calibgraph.solver.fit import timing

# solve = moved-camera test around solve_once; solve_once = start + optimise + widen + assemble
batch.solve_once = timed("solve_once (start, LM, marginals)", batch.solve_once)
batch.widen_inadequate_intrinsics = timed("widened-intrinsics re-solve", batch.widen_inadequate_intrinsics)
batch.error_budgets = timed("error budget", batch.error_budgets)
build._GuidedRun._coarse_solve = timed("coarse solves", build._GuidedRun._coarse_solve)

profs = []
if profile:
    lock = threading.Lock()
    local = threading.local()
    work = build._GuidedRun._work
    def profiled_work(*a, **k):
        p = getattr(local, "p", None)
        if p is None:
            p = local.p = cProfile.Profile(time.thread_time)
            with lock:
                profs.append(p)
        p.enable()
        try:
            return work(*a, **k)
        finally:
            p.disable()
    build._GuidedRun._work = profiled_work
    main_prof = cProfile.Profile(time.thread_time)

tmp = Path(tempfile.mkdtemp(prefix="bench_mchec_"))
try:
    ds_dir = tmp / src.name
    shutil.copytree(src, ds_dir)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    W0, C0 = clock()
    if profile:
        main_prof.enable()
    stages = []
    def stage(name, fn):
        w0, c0 = clock()
        out = fn()
        w1, c1 = clock()
        stages.append([name, w1 - w0, c1 - c0, os.getloadavg()[0]])
        return out
    ds = stage("read dataset", lambda: layouts.load_dataset(ds_dir))
    from calibgraph.cli.main import build_parser
    opts = cli_solve.solver_options(build_parser().parse_args(["solve", str(ds_dir), "--quiet"]), ds)
    det = stage("detect (decode, probe, blind + guided search, board fit, coarse solves)",
                lambda: build.GuidedDatasetDetector(ds, progress=False, method="joint", options=opts, coarse_solve=batch.solve).run())
    # build_problem's own detector is the one just run: the problem from the same detections
    gdet = build.GuidedDatasetDetector(ds, progress=False, method="joint", options=opts, coarse_solve=batch.solve)
    gdet.results, gdet._done = det, True
    problem = stage("problem from the detections", lambda: ds.to_problem(method="joint", options=opts, detector=gdet))
    sol_t = {}
    result = stage("solve (moved-camera test, solve, widen, budget)", lambda: batch.solve(problem, timings=sol_t))
    def write():
        result.save(tmp / "result.json")
        cli_solve.format_summary(result)
    stage("write result + summary", write)
    W1, C1 = clock()
    if profile:
        main_prof.disable()
    n_ok = sum(1 for d in det.values() if d.ok)
    out = {"stages": stages, "total_wall_s": W1 - W0, "total_cpu_s": C1 - C0,
           "peak_rss_gb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2 ** 20,
           "rss_before_gb": rss0 / 2 ** 20, "wrapped": T, "solver_stages_wall_s": sol_t,
           "views_searched": len(det), "views_detected": n_ok,
           "detected_per_camera": {c: sum(1 for (cc, _), d in det.items() if cc == c and d.ok) for c in ds.cameras},
           "iterations": result.iterations, "converged": result.converged, "notes": list(result.notes),
           "T_ref_cam": {n: c.T_ref_cam.tolist() for n, c in result.calibrated.items()},
           "sigma_translation_mm": {n: list(map(float, c.sigma_translation_mm)) for n, c in result.calibrated.items()},
           "cache_hits": 0}
    if profile:
        s = pstats.Stats(main_prof)
        for p in profs:
            s.add(p)
        stats = s.stats
        rows = []
        for (f, line, fn), (cc, nc, tt, ct, callers) in stats.items():
            ours = "/calibgraph/" in f and "site-packages" not in f
            rows.append({"function": f"{Path(f).parent.name}/{Path(f).name}:{line}:{fn}" if line else fn,
                         "calls": nc, "self_cpu_s": tt, "cum_cpu_s": ct, "ours": ours or not line})
        out["profile_top_self"] = sorted(rows, key=lambda r: -r["self_cpu_s"])[:30]
        out["profile_top_cum"] = [r for r in sorted(rows, key=lambda r: -r["cum_cpu_s"]) if r["ours"]][:45]
        out["profile_total_cpu_s"] = sum(r["self_cpu_s"] for r in rows)
        out["profile_threads"] = len(profs) + 1
    print(json.dumps(out))
finally:
    shutil.rmtree(tmp, ignore_errors=True)
"""


def run(profile: bool) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", ONE, str(DATA), "1" if profile else "0"], capture_output=True,
                         text=True, env=env, check=False)
    if out.returncode != 0:
        raise SystemExit(f"bench_mchec_path: the run failed: {out.stderr.strip().splitlines()[-1][:400]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


DECODE = r"""
import json, sys, time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
import cv2

files = sorted(p for p in Path(sys.argv[1]).rglob("*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
w0, c0 = time.perf_counter(), time.process_time()
with ThreadPoolExecutor(int(sys.argv[2])) as pool:
    n = sum(1 for img in pool.map(lambda f: cv2.imread(str(f), cv2.IMREAD_UNCHANGED), files) if img is not None)
print(json.dumps({"frames": n, "wall_s": time.perf_counter() - w0, "cpu_s": time.process_time() - c0}))
"""


def decode_floor(threads: int) -> dict:
    """Decoding every image of the recording once, ``threads`` at a time (OpenCV releases the GIL while it
    decodes): the floor no solve that reads every frame can beat on this machine."""
    out = subprocess.run([sys.executable, "-c", DECODE, str(DATA), str(threads)], capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def table(r: dict, label: str) -> list:
    lines = [f"### {label}", "",
             f"Total {r['total_wall_s']:.1f} s wall, {r['total_cpu_s']:.1f} CPU-s, peak {r['peak_rss_gb']:.2f} GB; "
             f"{r['views_detected']} of {r['views_searched']} views detected "
             f"({', '.join(f'{c} {n}' for c, n in r['detected_per_camera'].items())}); {r['iterations']} iterations, "
             f"converged {r['converged']}.", "",
             "| stage | wall s | CPU s | load (1 min) at its end |", "|---|---|---|---|"]
    for name, w, c, load in r["stages"]:
        lines.append(f"| {name} | {w:.2f} | {c:.2f} | {load:.1f} |")
    lines += ["", "Inside those stages (wall s / CPU s / calls; `A > B` is B called inside A):", "",
              "| part | wall s | CPU s | calls |", "|---|---|---|---|"]
    for name, (w, c, n) in sorted(r["wrapped"].items()):
        lines.append(f"| {name} | {w:.2f} | {c:.2f} | {n} |")
    lines += ["", "Solver stages (wall s, `solve(timings=)`, the coarse solves' excluded): " +
              ", ".join(f"{k} {v:.2f}" for k, v in r["solver_stages_wall_s"].items()), ""]
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", action="store_true", help="also run once under cProfile (per-thread CPU clock)")
    ap.add_argument("--runs", type=int, default=1, help="timed runs (each cold)")
    ap.add_argument("--out", type=Path, default=OUT / "bench_mchec_path")
    args = ap.parse_args()
    if not DATA.is_dir():
        print(f"bench_mchec_path: {DATA} is absent; nothing to time", file=sys.stderr)
        return 2
    t0, load0 = time.time(), os.getloadavg()
    runs = []
    for i in range(args.runs):
        runs.append(run(False))
        r = runs[-1]
        print(f"run {i + 1}: {r['total_wall_s']:.1f} s wall, {r['total_cpu_s']:.1f} CPU-s, {r['peak_rss_gb']:.2f} GB, "
              f"load {os.getloadavg()[0]:.1f}", flush=True)
        for name, w, c, load in r["stages"]:
            print(f"  {name:75s} {w:7.2f} s wall {c:7.2f} CPU-s", flush=True)
    floor = decode_floor(os.cpu_count() or 1)
    ratio = min(r["total_wall_s"] for r in runs) / floor["wall_s"]
    print(f"decode floor: {floor['frames']} frames in {floor['wall_s']:.1f} s wall ({floor['cpu_s']:.1f} CPU-s) on "
          f"{os.cpu_count()} threads; cold solve / decode floor = {ratio:.2f} (issue 45 item 7 asks <= 1.6)", flush=True)
    prof = run(True) if args.profile else None
    lines = ["# `calibgraph solve DIR` on the MC-HEC recording, stage by stage, cold", "",
             f"{DATA.name}: 4 cameras x 251 frames of 1920x1080, copied to a temporary folder (no detection cache). "
             f"{platform.node()}, {os.cpu_count()} cores, load average (1/5/15 min) {load0[0]:.1f}/{load0[1]:.1f}/"
             f"{load0[2]:.1f} at the start, {os.getloadavg()[0]:.1f} at the end; wall times are inflated by the "
             f"load, CPU seconds much less. {time.time() - t0:.0f} s in all. Made by scripts/bench_mchec_path.py.", "",
             f"**Cold solve / decode floor: {ratio:.2f}** (the fastest timed run's wall time over the wall time of "
             f"decoding every frame once, {floor['frames']} frames in {floor['wall_s']:.1f} s on {os.cpu_count()} threads, "
             f"{floor['cpu_s']:.1f} CPU-s, measured in this run; issue 45 item 7 asks at most 1.6).", ""]
    for i, r in enumerate(runs):
        lines += table(r, f"Timed run {i + 1} (no profiler)")
    if prof is not None:
        lines += table(prof, "Run under cProfile (per-thread CPU clock; the profiler inflates Python-heavy code)")
        lines += [f"Where the CPU goes, {prof['profile_threads']} threads' profiles merged (the main thread's and each "
                  "detection worker's), by self time:", "", "| function | calls | self CPU s | cum CPU s |",
                  "|---|---|---|---|"]
        lines += [f"| `{x['function']}` | {x['calls']} | {x['self_cpu_s']:.2f} | {x['cum_cpu_s']:.2f} |"
                  for x in prof["profile_top_self"][:25]]
        lines += ["", f"calibgraph's functions and built-ins (OpenCV's, GTSAM's) by cumulative CPU, of "
                  f"{prof['profile_total_cpu_s']:.1f} CPU-s profiled (a caller includes its callees; "
                  "worker threads' and the main thread's added):", "", "| function | calls | self CPU s | cum CPU s |",
                  "|---|---|---|---|"]
        lines += [f"| `{x['function']}` | {x['calls']} | {x['self_cpu_s']:.2f} | {x['cum_cpu_s']:.2f} |"
                  for x in prof["profile_top_cum"]]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    args.out.with_suffix(".json").write_text(json.dumps({"load_start": load0, "runs": runs, "decode_floor": floor,
                                                         "solve_over_floor": ratio, "profile": prof},
                                                        indent=1))
    print(f"wrote {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
