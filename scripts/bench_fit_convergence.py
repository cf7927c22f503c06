"""Does the photometric board fit converge on the MC-HEC recording's boards? (issue 36)

The board fit (calibgraph/detect/board_fit.py) runs Levenberg-Marquardt for at most 20 iterations
per batch of corners. This bench detects the MC-HEC recording (../shared/datasets/
mchec_medium_workcell, copied to a temporary folder: no cache, nothing written to ../shared) as
``calibgraph solve`` does, keeps the inputs of every ``--every``-th board fit (the grey frame, the
detector's corners), and refits them:

- how many LM runs stop at the cap (model evaluations per run: the start, the photometry and one per
  iteration);
- how far the corners the fit keeps move when the cap is 5, 10, 15, 30 or 60 instead of 20 (RMS over
  the corners refined under both caps), how many are refined, and the CPU time a board.

A fit that has converged gives the same corners whatever the cap past convergence. Writes
scripts/results/bench_fit_convergence.{md,json}.

    nice -n 10 python scripts/bench_fit_convergence.py
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


def capture(every: int) -> list:
    """The inputs of every ``every``-th board fit of a cold detection of the recording."""
    import threading

    import calibgraph.cli.solve as cli_solve
    import calibgraph.detect.search as search
    import calibgraph.io.layouts as layouts
    import calibgraph.solver.build as build
    from calibgraph.cli.main import build_parser

    kept, lock, n = [], threading.Lock(), [0]
    real = search.refine_checkerboard

    def spy(grey, target, ids, uv, *a, **k):
        with lock:
            n[0] += 1
            if n[0] % every == 0:
                kept.append((grey.copy(), target, np.array(ids), np.array(uv)))
        return real(grey, target, ids, uv, *a, **k)

    search.refine_checkerboard = spy
    tmp = Path(tempfile.mkdtemp(prefix="bench_fit_"))
    try:
        ds_dir = tmp / DATA.name
        shutil.copytree(DATA, ds_dir)
        ds = layouts.load_dataset(ds_dir)
        opts = cli_solve.solver_options(build_parser().parse_args(["solve", str(ds_dir), "--quiet"]), ds)
        build.GuidedDatasetDetector(ds, progress=False, method="joint", options=opts).run()
    finally:
        search.refine_checkerboard = real
        shutil.rmtree(tmp, ignore_errors=True)
    return kept


def main() -> int:
    import calibgraph.detect.board_fit as board_fit

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--every", type=int, default=6, help="keep every n-th board fit")
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
             f"the start, {os.getloadavg()[0]:.1f} at the end; {time.time() - t0:.0f} s. {len(boards)} boards (every "
             f"{args.every}th board fit of a cold detection of mchec_medium_workcell), {n_corners} corners. Made by "
             "scripts/bench_fit_convergence.py.", "",
             f"LM runs (first fits and second starts of the corners that failed): {len(runs)}; stopped at the "
             f"{CAP}-iteration cap: {at_cap}.", "",
             f"| iteration cap | CPU ms a board | corners refined | RMS move vs cap {CAP}, px | max move, px |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['cap']} | {r['ms_per_board']:.1f} | {r['refined']} | {r['rms_vs_20_px']:.4f} | {r['max_vs_20_px']:.3f} |"
              for r in rows]
    lines += ["", "(moves over the corners refined under both caps; a converged fit would give 0 past convergence)", ""]
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_fit_convergence.md").write_text("\n".join(lines))
    (OUT / "bench_fit_convergence.json").write_text(json.dumps(
        {"load_start": load0, "boards": len(boards), "corners": n_corners, "lm_runs": len(runs), "at_cap": at_cap,
         "evaluations_per_run": runs, "caps": rows}, indent=1))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
