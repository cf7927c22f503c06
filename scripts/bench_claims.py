#!/usr/bin/env python
"""Claims the data back (issue 45): on arms whose error repeats with their configuration, how often does
calibgraph claim what is not there (a camera moved, the board misprinted, the intrinsics rejected,
correlated corner noise), how often does it still claim what is (a 5 mm move, a 2 % misprint), and
does its 1-sigma cover the truth and its ``prediction`` what held-out poses show?

Cells (``calibgraph.sim.arm_error.arm_error_scene``, synthetic corners): an FR3 whose link origins and
joint zeros are off (1.3-2 mm of absolute error at the flange by default, ``--arm-scale`` times that),
the same for every visit of a joint target; eye-in-hand (one D455-class camera on the flange, the
A4 board on the table 0.3-0.6 m away) and eye-to-hand (two L515-class cameras at 1.5 and 2.5 m);
8, 12 and 36 captures: ``8``, ``12`` distinct joint targets, ``36`` as 3 sessions of the same 12
targets (a calibration re-run with the same joint targets, the case of issue 45's merged Franka
sessions), and ``36d``, 36 distinct targets. Corners with 0.2 px noise; the cameras report
factory-class intrinsics (estimated, none held at the truth); the FK accuracy stated is the
Panda-class 0.1 mm / 0.01 deg, which the arm does not meet.

Cases: ``none`` (no move, no misprint: every claim of a move, a misprint, rejected intrinsics or
correlated corner noise is false), ``move`` (the first camera knocked by 5 mm, 0.0 deg, half-way
through the captures: a move named is right), ``misprint`` (the board printed at 102 %: a misprint
named is right). Per cell: the claims' counts, the solves that did not converge, each camera's
Mahalanobis^2 of its position error against the truth (3 dof; fraction above the 99.9 % point
16.27), and the held-out RMS of 8 more joint targets (each captured once, predicted from their
reported FK as a user applies the calibration) against the result's expected ``prediction``.

    python scripts/bench_claims.py [--seeds 100] [--cells eye_in_hand:8,...] [--cases none,move,misprint]
                                   [--arm-scale 1] [--tag NAME] [--jobs 2]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calibgraph.core.errors import CalibgraphError  # noqa: E402
from calibgraph.sim.arm_error import arm_error_scene  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402
from calibgraph.solver.uncertainty.prediction import predicted_uv  # noqa: E402

CELLS = ("eye_in_hand:8", "eye_in_hand:12", "eye_in_hand:36", "eye_in_hand:36d",
         "eye_to_hand:8", "eye_to_hand:12", "eye_to_hand:36", "eye_to_hand:36d")
CASES = ("none", "move", "misprint")
CHI2_3_999 = 16.27
N_TEST = 8
MOVE_M = 0.005
MISPRINT = 1.02


def claims(result) -> dict:
    """What a result claims, from its records and notes."""
    notes = " | ".join(result.notes)
    cams = result.cameras.values()
    return {
        "moved": any(c.moved for c in cams) or "moved during capture" in notes or "moved after capture" in notes,
        "misprint": "printed at" in notes,
        "intrinsics_rejected": ("data disagree with its given" in notes) or ("contradict them" in notes),
        "corner_noise": any("residuals move whole boards" in n and "p < 0.05 but not" not in n for n in result.notes),
        "not_converged": not result.converged,
        "not_calibrated": sum(not c.calibrated for c in cams),
    }


def held_out(result, test, mode: str) -> tuple[list, list]:
    """(per camera: measured held-out RMS px over the test captures, expected_rms_px)."""
    meas, exp = [], []
    caps = test.capture_by_index
    flange = {k: cap.T_base_flange for k, cap in caps.items()}
    offsets = (result.robot or {}).get("joint_offsets_rad")
    if offsets is not None:
        # joint offsets estimated: a user applies the calibration through the corrected arm and the reported
        # joint angles, as the result's prediction (predicted_from 'joint angles') assumes
        from dataclasses import replace

        from calibgraph.solver.robot import kinematics as kin
        ks = kin.setup(test.with_(options=replace(test.options, kinematics="joint-offsets")))
        flange = {k: T for k, (T, _) in kin.corrected_flange_poses(ks, offsets).items()}
    for name, c in result.cameras.items():
        if not c.calibrated or not c.prediction:
            continue
        from calibgraph.core.camera import Intrinsics
        intr = Intrinsics.from_dict(c.intrinsics) if c.intrinsics else test.cameras[name]
        sse, n = 0.0, 0
        for d in test.detections:
            if d.camera != name:
                continue
            uv, _ = predicted_uv(c.T_ref_cam, flange[d.capture], result.T_mount_board, mode, intr,
                                 test.points_board_m[d.ids] * result.board_scale)
            sse += float(np.sum((uv - d.uv_px) ** 2))
            n += len(d.ids)
        if n:
            meas.append(float(np.sqrt(sse / n)))
            exp.append(float(c.prediction["expected_rms_px"]))
    return meas, exp


def one(cell: str, case: str, seed: int, arm_scale: float) -> dict:
    mode, size = cell.split(":")
    distinct = size.endswith("d")
    n = int(size.rstrip("d"))
    sessions = 3 if (n == 36 and not distinct) else 1
    n_configs = n // sessions
    kw = {}
    if case == "move":
        kw["move"] = (n // 2, MOVE_M, 0.0)
    if case == "misprint":
        kw["board_scale"] = MISPRINT
    try:
        scene, arm = arm_error_scene(mode=mode, n_configs=n_configs, sessions=sessions, arm_scale=arm_scale,
                                     test_configs=N_TEST, seed=seed, **kw)
    except ValueError as e:
        return {"cell": cell, "case": case, "seed": seed, "error": f"scene: {e}"}
    t0 = time.process_time()
    try:
        r = solve(scene.problem)
    except CalibgraphError as e:
        return {"cell": cell, "case": case, "seed": seed, "error": f"refused: {str(e)[:200]}",
                "captures": len(scene.problem.captures)}
    cpu = time.process_time() - t0
    m2 = {}
    for name, c in r.cameras.items():
        if c.calibrated:
            d = c.T_ref_cam[:3, 3] - scene.truth.T_ref_cam[name][:3, 3]
            m2[name] = float(d @ np.linalg.solve(c.covariance[3:, 3:], d))
    meas, exp = held_out(r, arm.test, mode) if arm.test is not None else ([], [])
    return {"cell": cell, "case": case, "seed": seed, "captures": len(scene.problem.captures),
            "arm_rms_mm": arm.rms_error_mm, "claims": claims(r), "m2": m2, "held_out_px": meas,
            "expected_px": exp, "cpu_s": cpu, "board_scale": r.board_scale}


def _commit() -> str:
    try:
        return subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True).stdout.strip() + (" (dirty)" if subprocess.run(
            ["git", "-C", str(REPO), "status", "--porcelain", "calibgraph"], capture_output=True,
            text=True).stdout.strip() else "")
    except OSError:
        return "?"


def summarise(rows: list) -> dict:
    out = {}
    for r in rows:
        key = (r["cell"], r["case"])
        s = out.setdefault(key, {"n": 0, "errors": 0, "moved": 0, "misprint": 0, "intrinsics_rejected": 0,
                                 "corner_noise": 0, "not_converged": 0, "not_calibrated": 0, "m2": [],
                                 "held": [], "exp": [], "cpu": [], "arm": []})
        s["n"] += 1
        if "error" in r:
            s["errors"] += 1
            continue
        for k in ("moved", "misprint", "intrinsics_rejected", "corner_noise", "not_converged"):
            s[k] += int(bool(r["claims"][k]))
        s["not_calibrated"] += int(r["claims"]["not_calibrated"] > 0)
        s["m2"] += list(r["m2"].values())
        s["held"] += r["held_out_px"]
        s["exp"] += r["expected_px"]
        s["cpu"].append(r["cpu_s"])
        s["arm"].append(r["arm_rms_mm"])
    return out


def page(rows: list, args, wall: float) -> str:
    S = summarise(rows)
    lines = [f"# Claims the data back, on arms whose error repeats with the configuration (issue 45){args.tag_title}",
             "",
             f"Made by `python scripts/bench_claims.py {' '.join(sys.argv[1:])}` at commit {_commit()} "
             f"({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}); {wall:.0f} s wall; arm scale {args.arm_scale} "
             "(the true arm's link and zero errors in units of the simulator's defaults). Protocol: the script's docstring. "
             "Intrinsics: factory-class reported and estimated (none held at the truth).",
             "",
             "Claims are counted per solve (a solve claiming it for any camera counts once). In case `none` every move, "
             "misprint, rejected intrinsics and corner-noise claim is false; in `move` a move named is right (the 5 mm "
             "knock); in `misprint` a misprint named is right (printed at 102 %). M2: each calibrated camera's position "
             "error against the truth, Mahalanobis^2 in its stated covariance (3 dof): the mean should be about 3 and "
             "about 1 in 1000 above 16.27. Held-out: 8 more joint targets of the same arm, predicted from their reported "
             "FK; measured / expected is the RMS over cameras and seeds of the measured held-out RMS over the "
             "`prediction` expected RMS.",
             "",
             "| cell | case | solves | arm error mm RMS | moved | misprint | intrinsics rejected | corner noise | not converged | "
             "a camera not calibrated | refused | M2 mean | M2 > 16.27 | held-out measured / expected | CPU s per solve |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for (cell, case), s in sorted(S.items(), key=lambda kv: (CELLS.index(kv[0][0]) if kv[0][0] in CELLS else 99,
                                                           CASES.index(kv[0][1]))):
        ok = s["n"] - s["errors"]
        m2 = np.array(s["m2"])
        ratio = (np.sqrt(np.mean((np.array(s["held"]) / np.array(s["exp"])) ** 2)) if s["held"] else float("nan"))
        lines.append(f"| {cell} | {case} | {ok} | {np.mean(s['arm']) if s['arm'] else float('nan'):.2f} | {s['moved']} | "
                     f"{s['misprint']} | {s['intrinsics_rejected']} | {s['corner_noise']} | {s['not_converged']} | "
                     f"{s['not_calibrated']} | {s['errors']} | {m2.mean() if len(m2) else float('nan'):.2f} | "
                     f"{int((m2 > CHI2_3_999).sum())} of {len(m2)} | {ratio:.2f} | "
                     f"{np.mean(s['cpu']) if s['cpu'] else float('nan'):.2f} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--cells", default=",".join(CELLS))
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--arm-scale", type=float, default=1.0)
    ap.add_argument("--tag", default="")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default=str(REPO / "scripts" / "results"))
    args = ap.parse_args()
    args.tag_title = f" ({args.tag})" if args.tag else ""
    jobs = [(c, k, s, args.arm_scale) for c in args.cells.split(",") for k in args.cases.split(",")
            for s in range(args.seeds)]
    t0 = time.time()
    rows = []
    with ProcessPoolExecutor(max_workers=args.jobs) as ex:
        for r in ex.map(_one_star, jobs, chunksize=4):
            rows.append(r)
    wall = time.time() - t0
    text = page(rows, args, wall)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    name = "bench_claims" + (f"_{args.tag}" if args.tag else "")
    (out / f"{name}.md").write_text(text)
    (out / f"{name}.json").write_text(json.dumps({"argv": sys.argv[1:], "rows": rows}, indent=1))
    print(text)
    return 0


def _one_star(a):
    return one(*a)


if __name__ == "__main__":
    sys.exit(main())
