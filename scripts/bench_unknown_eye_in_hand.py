#!/usr/bin/env python
"""Eye-in-hand with no intrinsics given: a synthetic stand-in for the real sets of issue 23.

The issue's target: real eye-in-hand sets that ship no intrinsics (a 1928×1208 camera, 29–30
images, boards of 17×28 corners at 20 mm and 7×8 corners at 60 mm) each solve with RMS ≤ 0.5 px, and
their odd and even halves agree on ``T_flange_cam`` within 3 combined σ per axis and 10 mm. Those
recordings are not on this machine; this benchmark measures the same figures on synthetic corners
of that geometry, so that the code path (unknown intrinsics initialised from the board homographies,
estimated in the joint graph under a wide prior) is shown to meet them where the truth is known.

The cell (per seed, fresh poses and noise): one camera on the flange (1928×1208; fx = fy = 1400 px,
principal point 6 / −4 px off centre, a 6 mm-class lens with visible barrel distortion: k1 −0.12,
k2 0.06, and in the ``full`` lens also a real lens's tangential terms and third radial term, p1 4e-4,
p2 −3e-4, k3 −0.03), the board fixed on the table, 30 poses at 0.6–1.1 m from it tilted up to 35°, Gaussian
corner noise 0.2 px, robot FK error 0.1 mm / 0.01° (stated so). The solve is told only the image
size (``Intrinsics.unknown``); default flags otherwise.

Figures per board: the full solve's RMS and its error against the truth (mm, deg, per-axis
error / σ, focal error / σ); the halves (odd / even captures, each solved alone): their difference
per axis over the combined σ (sqrt(σ_odd² + σ_even²)) and in mm, and how many seeds meet the issue's
three criteria. What the synthetic stand-in does not have: real corner errors (blur, print,
lighting) and real FK error.

The solver estimates a camera of unknown intrinsics with the full k1 k2 p1 p2 k3 model. Before, it
held p1 p2 k3 at zero: on the ``full`` lens the pose then turned 0.1° at up to 14σ while the residual
RMS stayed at the noise (0.28 px) and the halves agreed, so neither criterion of the issue saw it.

    python scripts/bench_unknown_eye_in_hand.py [--seeds 20] [--out scripts/results]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calibgraph.core.camera import Intrinsics  # noqa: E402
from calibgraph.core.errors import CalibgraphError  # noqa: E402
from calibgraph.core.targets import Target  # noqa: E402
from calibgraph.core.transforms import exp_so3, log_so3, make_T  # noqa: E402
from calibgraph.sim.synthetic_corners import make_scene  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402

WIDTH, HEIGHT = 1928, 1208
BOARDS = {"17x28 at 20 mm": Target(kind="checkerboard", rows=17, cols=28, pitch_m=0.020),
          "7x8 at 60 mm": Target(kind="checkerboard", rows=7, cols=8, pitch_m=0.060)}
N_POSES = 30
PIXEL_SIGMA_PX = 0.2
FK = dict(fk_sigma_translation_m=1e-4, fk_sigma_rotation_rad=float(np.radians(0.01)))


LENSES = {"k1 k2": [-0.12, 0.06, 0.0, 0.0, 0.0], "full": [-0.12, 0.06, 4e-4, -3e-4, -0.03]}


def camera(lens: str = "k1 k2") -> Intrinsics:
    K = np.array([[1400.0, 0, WIDTH / 2 + 6.0], [0, 1400.0, HEIGHT / 2 - 4.0], [0, 0, 1]])
    return Intrinsics(K=K, dist=np.array(LENSES[lens]), width_px=WIDTH, height_px=HEIGHT, source="exact")


def error(T_est, T_true) -> np.ndarray:
    """(6,) rotation vector of R_est R_true^T (rad) and translation difference (m): the result's frame."""
    return np.concatenate([log_so3(T_est[:3, :3] @ T_true[:3, :3].T), T_est[:3, 3] - T_true[:3, 3]])


def keep_captures(problem, parity: int):
    caps = tuple(c for c in problem.captures if c.index % 2 == parity)
    idx = {c.index for c in caps}
    return problem.with_(captures=caps, detections=tuple(d for d in problem.detections if d.capture in idx))


def trial(target: Target, seed: int, lens: str = "k1 k2") -> dict:
    T_flange_cam = make_T(exp_so3([0, 0, np.pi / 2]), [0.06, 0.0, 0.04])
    sc = make_scene(cameras={"wrist": (T_flange_cam, camera(lens))}, target=target, mode="eye_in_hand", n_poses=N_POSES,
                    pixel_sigma_px=PIXEL_SIGMA_PX, seed=seed, reported_intrinsics="exact", eye_in_hand_distance_m=(0.6, 1.1),
                    **FK)
    prob = sc.problem.with_(cameras={"wrist": Intrinsics.unknown(WIDTH, HEIGHT)})
    out = {"seed": seed, "captures": len(prob.captures)}
    t0 = time.process_time()
    try:
        full = solve(prob)
        halves = [solve(keep_captures(prob, p)) for p in (1, 0)]
    except CalibgraphError as e:
        out["error"] = str(e).splitlines()[0][:200]
        return out
    out["cpu_s"] = time.process_time() - t0
    c = full.cameras["wrist"]
    e = error(c.T_ref_cam, T_flange_cam)
    s = np.sqrt(np.diag(c.covariance))
    fx_est, fx_sig = np.asarray(c.intrinsics["K"])[0, 0], c.intrinsics["sigma"]["fx"]
    out.update(rms_px=c.reprojection_rms_px, err_mm=1e3 * float(np.linalg.norm(e[3:])), err_deg=float(np.degrees(np.linalg.norm(e[:3]))),
               z=(e / s).tolist(), fx_err_px=float(fx_est - 1400.0), fx_z=float((fx_est - 1400.0) / fx_sig),
               note=any("no intrinsics were given" in x for x in full.notes))
    a, b = (h.cameras["wrist"] for h in halves)
    d = error(a.T_ref_cam, b.T_ref_cam)
    s_comb = np.sqrt(np.diag(a.covariance) + np.diag(b.covariance))
    out.update(half_rms_px=[a.reprojection_rms_px, b.reprojection_rms_px], half_diff_mm=1e3 * float(np.linalg.norm(d[3:])),
               half_diff_deg=float(np.degrees(np.linalg.norm(d[:3]))), half_z=(d / s_comb).tolist())
    out["meets"] = bool(max(out["half_rms_px"] + [out["rms_px"]]) <= 0.5 and np.max(np.abs(out["half_z"])) <= 3.0
                        and out["half_diff_mm"] <= 10.0)
    return out


def summary(name: str, rs: list) -> dict:
    ok = [r for r in rs if "error" not in r]
    z = np.array([r["z"] for r in ok])
    hz = np.array([r["half_z"] for r in ok])
    return {"board": name, "lens": rs[0].get("lens", "k1 k2") if rs else "", "seeds": len(rs),
            "refused": len(rs) - len(ok),
            "rms_px_max": max(max(r["half_rms_px"] + [r["rms_px"]]) for r in ok),
            "err_mm_median": float(np.median([r["err_mm"] for r in ok])), "err_mm_max": max(r["err_mm"] for r in ok),
            "err_deg_max": max(r["err_deg"] for r in ok), "z_rms_per_axis": np.sqrt(np.mean(z ** 2, axis=0)).tolist(),
            "z_max": float(np.abs(z).max()), "fx_z_rms": float(np.sqrt(np.mean([r["fx_z"] ** 2 for r in ok]))),
            "fx_err_px_max": max(abs(r["fx_err_px"]) for r in ok),
            "half_diff_mm_median": float(np.median([r["half_diff_mm"] for r in ok])),
            "half_diff_mm_max": max(r["half_diff_mm"] for r in ok), "half_z_rms_per_axis": np.sqrt(np.mean(hz ** 2, axis=0)).tolist(),
            "half_z_max": float(np.abs(hz).max()), "meets": sum(r["meets"] for r in ok), "noted": sum(r["note"] for r in ok),
            "cpu_s_median": float(np.median([r["cpu_s"] for r in ok]))}


def markdown(sums: list, seconds: float) -> list:
    axes = "rx ry rz x y z".split()
    lines = ["# Eye-in-hand with no intrinsics given (issue 23): a synthetic stand-in for the real sets", "",
             "Made by `scripts/bench_unknown_eye_in_hand.py` (its docstring has the cell). Intrinsics: **none given** "
             "(only the image size, 1928×1208); found from the views and estimated in the joint graph. Synthetic corners "
             f"({PIXEL_SIGMA_PX} px), {N_POSES} poses, FK error 0.1 mm / 0.01° stated so. {seconds:.0f} s wall. "
             "The real recordings are not on this machine: these are not their figures.", "",
             "Target (issue 23, real data): RMS ≤ 0.5 px; odd and even halves agree on T_flange_cam within 3 combined σ "
             "per axis and 10 mm.", "",
             "| board | lens | seeds | meet all three | RMS px max | error mm median / max | error deg max | error/σ RMS per axis "
             "(" + " ".join(axes) + ") / max | fx error/σ RMS, max |fx error| px | halves differ mm median / max | halves "
             "diff/combined σ RMS per axis / max | 'found from its views' note | CPU s per seed |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for s in sums:
        lines.append(f"| {s['board']} | {s['lens']} | {s['seeds']} ({s['refused']} refused) | {s['meets']} | {s['rms_px_max']:.3f} | "
                     f"{s['err_mm_median']:.2f} / {s['err_mm_max']:.2f} | {s['err_deg_max']:.3f} | "
                     f"{' '.join(f'{v:.2f}' for v in s['z_rms_per_axis'])} / {s['z_max']:.2f} | {s['fx_z_rms']:.2f}, "
                     f"{s['fx_err_px_max']:.2f} | {s['half_diff_mm_median']:.2f} / {s['half_diff_mm_max']:.2f} | "
                     f"{' '.join(f'{v:.2f}' for v in s['half_z_rms_per_axis'])} / {s['half_z_max']:.2f} | "
                     f"{s['noted']} of {s['seeds'] - s['refused']} | {s['cpu_s_median']:.1f} |")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    a = ap.parse_args(argv)
    t0 = time.time()
    raw, sums = {}, []
    for name, target in BOARDS.items():
        for lens in LENSES:
            rs = []
            for seed in range(a.seeds):
                r = {**trial(target, seed, lens), "lens": lens}
                rs.append(r)
                print(name, lens, seed, {k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()
                                         if k in ("rms_px", "err_mm", "err_deg", "half_diff_mm", "meets", "error")},
                      flush=True)
            raw[f"{name}, {lens}"] = rs
            sums.append(summary(name, rs))
    lines = markdown(sums, time.time() - t0)
    print("\n".join(lines))
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "bench_unknown_eye_in_hand.md").write_text("\n".join(lines) + "\n")
    (a.out / "bench_unknown_eye_in_hand.json").write_text(json.dumps({"summary": sums, "trials": raw}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
