#!/usr/bin/env python
"""The guided live intrinsics session (``calibgraph intrinsics --live``, issues 37 and 47) on the simulated hand-held board.

Per seed, a :class:`calibgraph.sim.handheld.HandheldBoardCamera` feeds
:func:`calibgraph.acquire.live_session.run_live_session` with its default goal (what the error budget's
advice assumes: a 25-view session at the corner noise the session measures, capped at 0.1 px; set by the
first calibration). Two users hold the board:

- ``guided``: does what the hints say (moves to the hinted pose, reached as a person would: centre off by
  3 % / 4 % of the distance, orientation by 4 deg, 1-sigma; holds until the frame is taken), as the
  ``calibgraph intrinsics --live`` of a simulated cell plays it;
- ``random``: ignores the hints (a random walk over planned poses at 0.3-1 m).

Cameras: ``cell`` is the default workcell's cam0 exactly as the command opens it (an L515 1920x1080,
factory-class intrinsics reported, the workcell's sensor model, 10 frames a second; seed 1 is the
command's own draw); ``small`` (a D455 at
half resolution, 640x400, with distortion) and ``l515`` (1920x1080 with distortion) report factory-class
intrinsics (focal length 0.6 % off, no distortion), at 5 frames a second. Printed and saved per seed: frames
read, views taken and used, the goal and the notes that set it, fx 1-sigma reached, the true fx / fy / cx /
cy errors and error / 1-sigma, wall and CPU time, the simulated clock, and which calibgraph ran (its
folder and commit). ``--user random`` runs on a calibgraph from before the guided user too (its hand
ignored the hints), so a page of the session before a change is made with the same script::

    git worktree add --detach /tmp/before ea9dc88
    PYTHONPATH=/tmp/before python scripts/bench_live_intrinsics.py --user random --name bench_live_intrinsics_cell_ea9dc88

    python scripts/bench_live_intrinsics.py [--camera cell|small|l515] [--user guided|random|both] [--seeds 3]
        [--max-frames 1200] [--out scripts/results] [--name STEM]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import calibgraph
from calibgraph.acquire.live_session import run_live_session
from calibgraph.core.camera import Intrinsics, preset
from calibgraph.plan.cell import board_by_name
from calibgraph.sim.handheld import HandheldBoardCamera

REPO = Path(__file__).resolve().parents[1]


def device(kind: str, seed: int, guided: bool):
    """(camera device, true intrinsics, board, fps)."""
    if kind == "cell":
        from calibgraph.acquire.workcell import read_workcell
        from calibgraph.sim.workcell import workcell_from_dict

        spec = read_workcell(REPO / "datasets" / "workcells" / "default.yaml")
        cell = workcell_from_dict(spec.sim_world(), spec.where)
        true = cell.camera("cam0").intrinsics
        # seed 1 is the command's own session (the cell's seed and the camera's name), seed k the cell's seed + k - 1
        cam = HandheldBoardCamera("cam0", true, cell.target, reported=cell.reported_intrinsics("cam0"),
                                  realism=cell.realism, seed=_cell_seed(cell.seed + seed - 1), **_user(guided))
        return cam, true, cell.target, 10.0
    p = preset("d455" if kind == "small" else "l515")
    K = p.K.copy()
    if kind == "small":
        K[:2] *= 0.5
    w, h = (640, 400) if kind == "small" else (p.width_px, p.height_px)
    true = Intrinsics(K=K, dist=np.array([0.05, -0.08, 0.0004, -0.0003, 0.02]), width_px=w, height_px=h)
    reported = replace(true, K=true.K @ np.diag([1.006, 1.006, 1.0]), dist=np.zeros(5), source="factory")
    board = board_by_name("a4_54")
    return HandheldBoardCamera("cam", true, board, reported=reported, fps=5.0, seed=seed, **_user(guided)), \
        true, board, 5.0


def _cell_seed(seed: int) -> int:
    """cam0's hand-held board seed in a cell seeded ``seed``, as ``intrinsics --live`` draws it (issue 46: each
    camera its own); a calibgraph from before that gave every camera the cell's seed."""
    try:
        from calibgraph.sim.handheld import camera_seed
    except ImportError:
        return seed
    return camera_seed(seed, "cam0")


def _user(guided: bool) -> dict:
    """The hand's keyword: none for the random user, which is every calibgraph's hand before the guided one."""
    return {"follows_hints": True} if guided else {}


def source() -> str:
    """Which calibgraph ran: its folder and the commit there (with '+changes' when its tree differs)."""
    where = Path(calibgraph.__file__).resolve().parents[1]
    try:
        rev = subprocess.run(["git", "-C", str(where), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain", "--", "calibgraph"],
                               capture_output=True, text=True, check=True).stdout.strip()
        return f"{where} at {rev}{'+changes' if dirty else ''}"
    except (OSError, subprocess.CalledProcessError):
        return f"{where} (not a git checkout)"


def run(kind: str, seed: int, guided: bool, max_frames: int) -> dict:
    cam, true, board, fps = device(kind, seed, guided)
    t0, c0 = time.time(), time.process_time()
    o = run_live_session(cam, board, max_frames=max_frames)
    row = {"seed": seed, "user": "guided" if guided else "random", "reason": o.reason, "frames": o.frames,
           "sim_clock_s": round(o.frames / fps, 1), "views_taken": len(o.views), "goal_px": o.goal_px,
           "notes": list(getattr(o, "notes", [])), "wall_s": round(time.time() - t0, 1), "cpu_s": round(time.process_time() - c0, 1),
           "load_average": round(os.getloadavg()[0], 1)}
    r = o.result
    if r is not None:
        row.update(views_used=len(r.views_used), pixel_sigma_px=r.pixel_sigma_px)
        for name, (i, j) in {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}.items():
            err = float(r.intrinsics.K[i, j] - true.K[i, j])
            row[name] = {"sigma_px": r.sigma[name], "error_px": err, "error_over_sigma": err / r.sigma[name]}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--camera", choices=("cell", "small", "l515"), default="cell")
    ap.add_argument("--user", choices=("guided", "random", "both"), default="both")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--random-seeds", type=int, default=None, help="seeds of the random user (default --seeds)")
    ap.add_argument("--max-frames", type=int, default=1200)
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    ap.add_argument("--name", default=None, help="the pages' file stem (default bench_live_intrinsics_CAMERA)")
    a = ap.parse_args()
    users = [True, False] if a.user == "both" else [a.user == "guided"]
    rows = []
    for guided in users:
        n = a.seeds if guided or a.random_seeds is None else a.random_seeds
        for seed in range(1, n + 1):
            row = run(a.camera, seed, guided, a.max_frames)
            rows.append(row)
            fx = row.get("fx", {})
            print(f"{row['user']} seed {seed}: {row['reason']}; {row['frames']} frames ({row['sim_clock_s']} s of the "
                  f"simulated clock), {row['views_taken']} views, goal {row['goal_px']:.4f} px, fx 1-sigma "
                  f"{fx.get('sigma_px', float('nan')):.4f} px, error {fx.get('error_px', float('nan')):+.4f} px "
                  f"({fx.get('error_over_sigma', float('nan')):+.2f} sigma), {row['wall_s']} s wall, {row['cpu_s']} s "
                  f"CPU, load {row['load_average']}", flush=True)
    summary = {"camera": a.camera, "calibgraph": source(), "date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()), "rows": rows}
    for user in ("guided", "random"):
        z = np.array([[r[n]["error_over_sigma"] for n in ("fx", "fy", "cx", "cy")] for r in rows
                      if "fx" in r and r["user"] == user])
        if len(z):
            summary[f"rms_error_over_sigma_fx_fy_cx_cy_{user}"] = np.sqrt(np.mean(z ** 2, axis=0)).tolist()
    a.out.mkdir(parents=True, exist_ok=True)
    stem = a.out / (a.name or f"bench_live_intrinsics_{a.camera}")
    stem.with_suffix(".json").write_text(json.dumps(summary, indent=1))
    what = {"cell": "the default workcell's cam0 as `calibgraph intrinsics --live --camera cam0 --workcell "
                    "datasets/workcells/default.yaml` opens it (L515 1920x1080, factory-class report, 10 frames/s)",
            "small": "a D455 at 640x400 with distortion, reporting factory-class intrinsics (fx +0.6 %, no distortion), "
                     "5 frames/s",
            "l515": "an L515 at 1920x1080 with distortion, reporting factory-class intrinsics (fx +0.6 %, no distortion), "
                    "5 frames/s"}[a.camera]
    lines = [f"# Live intrinsics session on the simulated hand-held board ({a.camera})", "",
             f"{summary['date_utc']} UTC on 2 shared cores (load average per row), calibgraph from "
             f"{summary['calibgraph']}; {what}; the default goal, as that calibgraph "
             "sets it (since issue 47: the advice's 25-view session at the corner noise the first calibration "
             "measures, set once). `guided`: a user who does what "
             "the hints say; `random`: one who ignores them.", "",
             "| user | seed | end | frames (sim s) | views taken / used | goal px | fx 1σ px | fx err px | "
             "err/1σ fx, fy, cx, cy | wall s | CPU s | load |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        head = f"| {r['user']} | {r['seed']} | {r['reason']} | {r['frames']} ({r['sim_clock_s']}) |"
        if "fx" not in r:
            lines.append(f"{head} {r['views_taken']} / - | {r['goal_px']:.4f} | - | - | - | {r['wall_s']} | {r['cpu_s']} | "
                         f"{r['load_average']} |")
            continue
        zs = ", ".join(f"{r[n]['error_over_sigma']:+.2f}" for n in ("fx", "fy", "cx", "cy"))
        lines.append(f"{head} {r['views_taken']} / {r['views_used']} | {r['goal_px']:.4f} | {r['fx']['sigma_px']:.4f} | "
                     f"{r['fx']['error_px']:+.4f} | {zs} | {r['wall_s']} | {r['cpu_s']} | {r['load_average']} |")
    for user in ("guided", "random"):
        mine = [r for r in rows if r["user"] == user]
        if not mine:
            continue
        views, wall, cpu = ([r[k] for r in mine] for k in ("views_taken", "wall_s", "cpu_s"))
        lines += ["", f"{user}: goal met in {sum(r['reason'] == 'goal met' for r in mine)} of {len(mine)}; views taken "
                      f"{min(views)}-{max(views)} (median {np.median(views):g}); wall {min(wall)}-{max(wall)} s, CPU "
                      f"{min(cpu)}-{max(cpu)} s."]
        v = summary.get(f"rms_error_over_sigma_fx_fy_cx_cy_{user}")
        if v:
            lines += ["", f"RMS error / 1σ, {user} (fx, fy, cx, cy): " + ", ".join(f"{x:.2f}" for x in v)]
    notes = sorted({n for r in rows for n in r["notes"]})
    if notes:
        lines += ["", "Lines said once (the goal set by the first calibration, and any change):", ""]
        lines += [f"- seed {r['seed']} ({r['user']}): " + "; ".join(r["notes"]) for r in rows if r["notes"]]
    stem.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print(f"wrote {stem}.json and {stem}.md")


if __name__ == "__main__":
    main()
