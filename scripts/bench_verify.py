"""Benchmark of ``calibgraph verify``: false alarms with nothing moved, detection of a bumped camera.

Synthetic cells (calibgraph.sim.synthetic_corners: exact projection, 0.3 px Gaussian corner noise, FK noise
0.1 mm / 0.01 deg as the solver's prior says), three L515-class cameras on a ring at 3 m:

1. calibrate the cell from 40 poses (default solver: board scale estimated; the simulated
   cameras' intrinsics are 'exact');
2. per trial, bump one camera (round robin) by a translation of 0.5/1/2/5 mm in a random
   direction or a rotation of 0.05/0.1/0.2/0.5 deg about a random axis (or nothing), draw 30
   candidate board poses of the bumped cell, let :func:`calibgraph.plan.verify.choose_verify_poses`
   order them from the *stored* result, and verify with the first n = 1..6 chosen poses;
3. record each camera's m2; a trial is a false alarm when any camera is called moved with nothing
   moved, a detection when the bumped camera is called moved, and *misnamed* when another one is.

Calibrations are redrawn every ``--trials-per-cal`` trials so the stored errors vary too.

    python scripts/bench_verify.py [--quick] [--out scripts/results]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibgraph.core.transforms import exp_so3, make_T  # noqa: E402
from calibgraph.sim.synthetic_corners import make_scene, ring_cameras  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402
from calibgraph.solver.output.result import Result  # noqa: E402
from calibgraph.solver.changes.verify import chi2_isf_6, stored_model, verify  # noqa: E402
from calibgraph.plan.verify import choose_verify_poses  # noqa: E402

FK_T, FK_R = 1e-4, float(np.radians(0.01))
CASES = [("none", 0.0)] + [("mm", v) for v in (0.5, 1.0, 2.0, 5.0)] + [("deg", v) for v in (0.05, 0.1, 0.2, 0.5)]
ALPHAS = (1e-2, 1e-3, 1e-4)
N_POSES = (1, 2, 3, 4, 5, 6)


def bumped(cams, name, kind, size, rng):
    if kind == "none":
        return cams
    T, intr = cams[name]
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    if kind == "mm":
        T2 = make_T(T[:3, :3], T[:3, 3] + u * size * 1e-3)
    else:
        T2 = make_T(exp_so3(u * np.radians(size)) @ T[:3, :3], T[:3, 3])
    return {**cams, name: (T2, intr)}


def run(args):
    cams = ring_cameras([3.0] * 3, spread_deg=200)
    names = list(cams)
    rows = []  # (case, size, bumped camera, n, {camera: m2})
    stored, model, t0 = None, None, time.time()
    trial = 0
    for case, size in CASES:
        n_trials = args.null_trials if case == "none" else args.trials
        for t in range(n_trials):
            if trial % args.trials_per_cal == 0:
                cal = make_scene(cams, n_poses=40, seed=10_000 + trial, fk_sigma_translation_m=FK_T, fk_sigma_rotation_rad=FK_R)
                stored = Result.from_dict(json.loads(json.dumps(solve(cal.problem).to_dict())))  # as read back
                model = stored_model(stored)
            trial += 1
            rng = np.random.default_rng(trial)
            victim = names[t % len(names)]
            world = bumped(cams, victim, case, size, rng)
            scene = make_scene(world, n_poses=30, seed=20_000 + trial, shared_fraction=0.6, fk_sigma_translation_m=FK_T,
                               fk_sigma_rotation_rad=FK_R)
            prob = scene.problem
            caps = list(prob.captures)
            beliefs = {n: (model.intrinsics[n], model.T_base_cam[n], model.covariance[n]) for n in names}
            order, _ = choose_verify_poses([c.T_base_flange for c in caps], beliefs, model.T_flange_board,
                                           _target(), max(N_POSES), model.pixel_sigma_px, FK_T, FK_R)
            for n in N_POSES:
                keep = {caps[i].index for i in order[:n]}
                sub = prob.with_(captures=tuple(c for c in caps if c.index in keep),
                                 detections=tuple(d for d in prob.detections if d.capture in keep))
                vr = verify(sub, stored)
                rows.append({"case": case, "size": size, "victim": None if case == "none" else victim, "n": n,
                             "m2": {c: (None if vr.cameras[c].status == "not_seen" else vr.cameras[c].mahalanobis2)
                                    for c in names},
                             "verdict": vr.verdict})
        print(f"  {case} {size:g}: {n_trials} trials done ({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)
    return rows


def _target():
    from calibgraph.core.targets import a4_board_54

    return a4_board_54()


def tables(rows) -> tuple[str, dict]:
    out = {}
    lines = []
    for alpha in ALPHAS:
        thr = chi2_isf_6(alpha)
        lines.append(f"\n### alpha {alpha:g} per camera (m2 > {thr:.1f})\n")
        lines.append("| bump | " + " | ".join(f"n={n}" for n in N_POSES) + " |")
        lines.append("|---|" + "---|" * len(N_POSES))
        for case, size in CASES:
            cells = []
            for n in N_POSES:
                rs = [r for r in rows if r["case"] == case and r["size"] == size and r["n"] == n]
                flagged = [{c for c, m in r["m2"].items() if m is not None and m > thr} for r in rs]
                if case == "none":
                    rate = np.mean([bool(f) for f in flagged])
                    cells.append(f"FA {100 * rate:.1f} %")
                    out[f"alpha={alpha:g}/none/n={n}"] = {"false_alarm": rate, "trials": len(rs)}
                else:
                    det = np.mean([r["victim"] in f for r, f in zip(rs, flagged)])
                    wrong = np.mean([bool(f - {r["victim"]}) for r, f in zip(rs, flagged)])
                    cells.append(f"{100 * det:.0f} % ({100 * wrong:.0f} % other)")
                    out[f"alpha={alpha:g}/{case}={size:g}/n={n}"] = {"detected": det, "other_flagged": wrong, "trials": len(rs)}
            label = "nothing moved" if case == "none" else f"{size:g} {'mm' if case == 'mm' else 'deg'}"
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("\n### Targets (alpha 0.001 per camera)\n")
    thr = chi2_isf_6(1e-3)
    fa = {n: out[f"alpha=0.001/none/n={n}"]["false_alarm"] for n in N_POSES}
    for case, size in (("mm", 2.0), ("deg", 0.2)):
        ok = [n for n in N_POSES if out[f"alpha=0.001/{case}={size:g}/n={n}"]["detected"] >= 0.95]
        n_min = min(ok) if ok else None
        other = max(out[f"alpha=0.001/{case}={size:g}/n={n}"]["other_flagged"] for n in N_POSES)
        lines.append(f"- {size:g} {'mm' if case == 'mm' else 'deg'} bump: detected in >= 95 % from "
                     f"{n_min if n_min else 'none of 1-6'} poses (target <= 5: {'met' if n_min and n_min <= 5 else 'MISSED'}); "
                     f"another camera also called moved in at most {100 * other:.1f} % of these trials")
    worst = max(fa.values())
    lines.append(f"- false alarms with nothing moved (any of 3 cameras, m2 > {thr:.1f}): at most {100 * worst:.2f} % over "
                 f"n = 1-6 (target <= 1 %: {'met' if worst <= 0.01 else 'MISSED'})")
    return "\n".join(lines), out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a few trials per case")
    ap.add_argument("--trials", type=int, default=120, help="trials per bump case")
    ap.add_argument("--null-trials", type=int, default=300, help="trials with nothing moved (>= 200)")
    ap.add_argument("--trials-per-cal", type=int, default=10, help="trials per calibration")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    args = ap.parse_args()
    if args.quick:
        args.trials, args.null_trials = 12, 24
    t0 = time.time()
    rows = run(args)
    md, summary = tables(rows)
    head = (f"# bench_verify\n\nSynthetic corners (calibgraph.sim.synthetic_corners: exact projection plus Gaussian noise, no "
            f"rendering or detection; {args.null_trials + len(CASES[1:]) * args.trials} verifies x 6 pose counts are too "
            f"many to render on 2 cores). Three L515-class cameras at 3 m (ring, 200 deg), calibrated from 40 poses; 0.3 px "
            f"corner noise, FK noise 0.1 mm / 0.01 deg. {args.null_trials} trials with nothing moved, {args.trials} "
            f"per bump (random direction / axis, bumped camera round robin), calibration redrawn every "
            f"{args.trials_per_cal} trials. Verify poses chosen by calibgraph.plan.verify from 30 candidates of the "
            f"bumped cell, using the stored result only. Cells: detection rate of the bumped camera (share of trials "
            f"in which another camera was also called moved); 'FA': trials with any camera called moved. "
            f"Run time {time.time() - t0:.0f} s.\n")
    text = head + md + "\n"
    print(text)
    if not args.quick:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "bench_verify.md").write_text(text)
        (args.out / "bench_verify.json").write_text(json.dumps({"summary": summary, "rows": rows}))
        print(f"wrote {args.out / 'bench_verify.md'}", file=sys.stderr)


if __name__ == "__main__":
    main()
