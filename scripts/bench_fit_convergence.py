"""Does the photometric board fit converge on the MC-HEC recording's boards? (issue 36)

The board fit (calibgraph/detect/board_fit.py) runs Levenberg-Marquardt for at most 20 iterations
per batch of corners. This bench detects the MC-HEC recording (../shared/datasets/
mchec_medium_workcell, copied to a temporary folder: no cache, nothing written to ../shared) as
``calibgraph solve`` does, keeps the inputs of about one board fit in ``--every`` (the grey frame, the
detector's corners; chosen by the corners, so the same boards every run), and refits them:

- how many LM runs stop at the cap (model evaluations per run: the start, the photometry and one per
  iteration);
- how far the corners the fit keeps move when the cap is 5, 10, 15, 30 or 60 instead of 20 (RMS over
  the corners refined under both caps), how many are refined, and the CPU time a board.

A fit that has converged gives the same corners whatever the cap past convergence. ``--solve``
also runs the whole path (detection and the solve, as ``calibgraph solve``) with the cap at 20 and at
30 and compares the views detected and each camera's pose (change / its 1-sigma). Writes
scripts/results/bench_fit_convergence.{md,json}.

    nice -n 10 python scripts/bench_fit_convergence.py --solve
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "scripts" / "results"
DATA = ROOT.parent / "shared" / "datasets" / "mchec_medium_workcell"
CAP = 20


def run_path(refine, solve: bool = False):
    """(detections, the solve's result or None) of a cold run of the recording (``calibgraph
    solve``'s path) with ``refine`` as the search's checkerboard fit."""
    import calibgraph.cli.solve as cli_solve
    import calibgraph.detect.search as search
    import calibgraph.io.layouts as layouts
    import calibgraph.solver.solve.batch as batch
    import calibgraph.detect.guided_dataset as build
    from calibgraph.cli.main import build_parser

    real = search.refine_checkerboard
    search.refine_checkerboard = refine
    tmp = Path(tempfile.mkdtemp(prefix="bench_fit_"))
    try:
        ds_dir = tmp / DATA.name
        shutil.copytree(DATA, ds_dir)
        ds = layouts.load_dataset(ds_dir)
        opts = cli_solve.solver_options(build_parser().parse_args(["solve", str(ds_dir), "--quiet"]), ds)
        det = build.GuidedDatasetDetector(ds, progress=False, method="joint", options=opts, coarse_solve=batch.solve)
        results = det.run()
        return results, batch.solve(ds.to_problem(method="joint", options=opts, detector=det)) if solve else None
    finally:
        search.refine_checkerboard = real
        shutil.rmtree(tmp, ignore_errors=True)


def solve_with_cap(cap: int):
    """(detections, result) of the recording, cold, with the board fit's iteration cap at ``cap``."""
    import functools

    import calibgraph.detect.board_fit as board_fit

    return run_path(functools.partial(board_fit.refine_checkerboard, max_iterations=cap), solve=True)


def compare_solves(a, b) -> list:
    """Per camera: translation change / its 1-sigma (largest axis) and rotation change / the smallest
    rotation 1-sigma, b against a (a's sigmas)."""
    rows = []
    for name, ca in a.calibrated.items():
        cb = b.calibrated.get(name)
        if cb is None or ca.T_ref_cam is None or cb.T_ref_cam is None:
            continue
        dt_mm = 1000.0 * (cb.T_ref_cam[:3, 3] - ca.T_ref_cam[:3, 3])
        dR = ca.T_ref_cam[:3, :3].T @ cb.T_ref_cam[:3, :3]
        ang = float(np.degrees(np.arccos(np.clip((np.trace(dR) - 1.0) / 2.0, -1.0, 1.0))))
        st, sr = np.asarray(ca.sigma_translation_mm), np.asarray(ca.sigma_rotation_deg)
        rows.append({"camera": name, "dt_mm": dt_mm.round(4).tolist(), "dt_over_sigma": float(np.max(np.abs(dt_mm) / st)),
                     "drot_deg": ang, "drot_over_sigma": ang / float(sr.min()),
                     "sigma_translation_mm": st.round(3).tolist(), "sigma_rotation_deg": sr.round(4).tolist()})
    return rows


def capture(every: int) -> list:
    """The inputs of about one in ``every`` board fits of a cold detection of the recording."""
    import threading

    import calibgraph.detect.board_fit as board_fit

    kept, lock = [], threading.Lock()

    def spy(grey, target, ids, uv, *a, **k):
        # one fit in ``every``, chosen by its detector corners (the same boards whatever order the
        # detection's threads finish in)
        if int(round(1000.0 * float(np.abs(uv).sum()))) % every == 0:
            with lock:
                kept.append((grey.copy(), target, np.array(ids), np.array(uv)))
        return board_fit.refine_checkerboard(grey, target, ids, uv, *a, **k)

    run_path(spy)
    return sorted(kept, key=lambda b: float(np.abs(b[3]).sum()))


def main() -> int:
    import calibgraph.detect.board_fit as board_fit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", type=int, default=6, help="keep about one board fit in n")
    ap.add_argument("--solve", action="store_true", help="also solve the recording with the cap at 20 and at 30")
    args = ap.parse_args()
    if not DATA.is_dir():
        print(f"bench_fit_convergence: {DATA} is absent; nothing to measure", file=sys.stderr)
        return 2
    t0, load0 = time.time(), os.getloadavg()
    boards = capture(args.every)
    # LM runs and their model evaluations at the cap
    evals, runs = [], []
    real_model, real_fit = board_fit._model, board_fit._fit_corners

    def count_model(*a, **k):
        evals[-1] += 1
        return real_model(*a, **k)

    def count_fit(*a, **k):
        evals.append(0)
        out = real_fit(*a, **k)
        runs.append(evals[-1])
        return out

    board_fit._model, board_fit._fit_corners = count_model, count_fit
    try:
        for grey, target, ids, uv in boards:
            board_fit.refine_checkerboard(grey, target, ids, uv, max_iterations=CAP)
    finally:
        board_fit._model, board_fit._fit_corners = real_model, real_fit
    at_cap = sum(e >= CAP + 2 for e in runs)
    fits = {}
    for cap in (CAP, 5, 10, 15, 30, 60):
        c0 = time.process_time()
        fits[cap] = [board_fit.refine_checkerboard(g, t, i, u, max_iterations=cap) for g, t, i, u in boards]
        fits[cap] = (fits[cap], 1000 * (time.process_time() - c0) / len(boards))
    ref = fits[CAP][0]
    rows = []
    for cap, (out, ms) in fits.items():
        both = np.concatenate([o.refined & r.refined for o, r in zip(out, ref)])
        d = np.concatenate([np.linalg.norm(o.uv_px - r.uv_px, axis=1) for o, r in zip(out, ref)])[both]
        rows.append({"cap": cap, "ms_per_board": ms, "refined": int(sum(o.refined.sum() for o in out)),
                     "rms_vs_20_px": float(np.sqrt(np.mean(d ** 2))) if d.size else float("nan"),
                     "max_vs_20_px": float(d.max()) if d.size else float("nan")})
    n_corners = int(sum(len(r.uv_px) for r in ref))
    lines = ["# The board fit's convergence on the MC-HEC recording's boards", "",
             f"{platform.node()}, {os.cpu_count()} cores, load average {load0[0]:.1f}/{load0[1]:.1f}/{load0[2]:.1f} at "
             f"the start, {os.getloadavg()[0]:.1f} at the end; {time.time() - t0:.0f} s. {len(boards)} boards (about one "
             f"board fit in {args.every} of a cold detection of mchec_medium_workcell, chosen by its detector corners), "
             f"{n_corners} corners. Made by "
             "scripts/bench_fit_convergence.py.", "",
             f"LM runs (first fits and second starts of the corners that failed): {len(runs)}; stopped at the "
             f"{CAP}-iteration cap: {at_cap}.", "",
             f"| iteration cap | CPU ms a board | corners refined | RMS move vs cap {CAP}, px | max move, px |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['cap']} | {r['ms_per_board']:.1f} | {r['refined']} | {r['rms_vs_20_px']:.4f} | {r['max_vs_20_px']:.3f} |"
              for r in rows]
    lines += ["", "(moves over the corners refined under both caps; a converged fit would give 0 past convergence)", ""]
    solves = None
    if args.solve:
        (d20, r20), (d30, r30) = solve_with_cap(CAP), solve_with_cap(30)
        solves = {"views_20": sum(d.ok for d in d20.values()), "views_30": sum(d.ok for d in d30.values()),
                  "views_differ": sum(d20[k].ok != d30[k].ok for k in d20), "cameras": compare_solves(r20, r30)}
        lines += [f"The whole path (detection and solve, cold) with the cap at 30 instead of {CAP}: "
                  f"{solves['views_30']} views detected against {solves['views_20']} ({solves['views_differ']} "
                  "views differ in found / not found); each camera's pose moves by:", "",
                  "| camera | translation change, mm | / its 1-sigma (largest axis) | rotation change, deg | "
                  "/ smallest axis's 1-sigma (bounds the per-axis ratio) |", "|---|---|---|---|---|"]
        lines += [f"| {c['camera']} | {c['dt_mm']} | {c['dt_over_sigma']:.2f} | {c['drot_deg']:.4f} | "
                  f"{c['drot_over_sigma']:.2f} |" for c in solves["cameras"]]
        lines += ["", "An iteration cap is not a change a converged fit would notice: the recording's estimates "
                  "carry the fit's stopping point at this level.", ""]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_fit_convergence.md").write_text("\n".join(lines))
    (OUT / "bench_fit_convergence.json").write_text(json.dumps(
        {"load_start": load0, "boards": len(boards), "corners": n_corners, "lm_runs": len(runs), "at_cap": at_cap,
         "evaluations_per_run": runs, "caps": rows, "solves": solves}, indent=1))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
