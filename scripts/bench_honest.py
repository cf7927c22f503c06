"""Is the reported 1σ honest? Normalised errors (true error / reported σ, per axis) of rendered
simulated cells from 1.5 to 5 m, solved as a user would, with the intrinsics the simulated cameras
report (factory-class errors: the realistic case), or the true ones exact (an oracle), uncertain
(a calibration file), 2 % off on one camera, or the board printed at 101.6 % (true intrinsics held).

Each cell is simulated once (MuJoCo renders, cached in --work); every case re-detects the stored
images with the current detector and solves with default options. Per camera: error (mm, deg),
reported 1σ, the six normalised errors (rotation about, then translation along, the base axes:
the result's covariance convention), their RMS and max, and the solver's notes.

    MUJOCO_GL=egl python scripts/bench_honest.py [--quick] [--cells default,d455_5m] [--out scripts/results]

Target (issue "A 1σ that holds"): normalised errors with RMS <= 1.5 and none above 3.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calibgraph.core.transforms import log_so3  # noqa: E402
from calibgraph.io.ground_truth import load_ground_truth  # noqa: E402
from calibgraph.io.layouts import load_dataset  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402
from calibgraph.solver.solve.build import build_problem  # noqa: E402

# name -> (workcell builder kwargs, poses)
CELLS = {
    "kinect_1.5-3m": (dict(n_cameras=3, preset_name="kinect_v2", distances_m=[1.5, 2.2, 3.0], spread_deg=200,
                           board="a4_54"), 60),
    "default_l515_3m": (dict(n_cameras=3, preset_name="l515", distance_m=3.0, spread_deg=200, board="a4_54"), 60),
    "d455_5m_thesis": (dict(n_cameras=3, preset_name="d455", distance_m=5.0, spread_deg=200, board="thesis",
                            height_above_floor_m=2.0), 90),
}


def simulate(work: Path, name: str, quick: bool) -> Path:
    """The cell's simulated dataset (made once)."""
    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import simulate_dataset
    from calibgraph.sim.workcell import ring_workcell

    kw, n = CELLS[name]
    n = max(20, n // 2) if quick else n
    root = work / f"{name}_{n}"
    if (root / "ground_truth.json").is_file():
        return root
    shutil.rmtree(root, ignore_errors=True)
    cell = ring_workcell(name=name, seed=0, **kw)
    world = SimWorld(cell)
    # the planner's default: poses chosen by the information model, views counted down to the detector's
    # up-scaling floor (4.5 px squares) weighted by their chance of being found
    traj = plan_trajectory(world, n_poses=n, seed=0)
    simulate_dataset(cell, traj, root, world=world, progress=False)
    world.close()
    return root


def variant(src: Path, dst: Path, case: str) -> Path:
    """A copy of the dataset header as a user would state it for ``case``; images and captures are
    shared (symlinked); stored detections are dropped so the current detector runs."""
    import yaml

    # The detection cache survives a re-run (images and detector options are the same): a solver
    # change is then measured without detecting every image again.
    cache = dst / ".calibgraph_cache"
    keep = dst.parent / f".{dst.name}_cache"
    if cache.is_dir():
        shutil.rmtree(keep, ignore_errors=True)
        cache.rename(keep)
    shutil.rmtree(dst, ignore_errors=True)
    dst.mkdir(parents=True)
    if keep.is_dir():
        keep.rename(cache)
    for sub in ("images",):
        (dst / sub).symlink_to((src / sub).resolve())
    (dst / "captures").mkdir()
    for f in sorted((src / "captures").glob("*.json")):
        d = json.loads(f.read_text())
        for v in d.get("views", {}).values():
            v["detection"] = None
        (dst / "captures" / f.name).write_text(json.dumps(d))
    shutil.copy(src / "ground_truth.json", dst / "ground_truth.json")
    head = yaml.safe_load((src / "dataset.yaml").read_text())
    cams = head["cameras"]
    first = sorted(cams)[1 if len(cams) > 1 else 0]
    if case != "factory-class (as the cameras report)":
        # every other case starts from the true intrinsics (the simulated cameras report factory-class ones)
        gt = json.loads((src / "ground_truth.json").read_text())["cameras"]
        for n, c in cams.items():
            true = gt[n]["intrinsics_true"]
            c["K"], c["dist"], c["source"] = true["K"], true["dist"], "exact"
    if case in ("intrinsics exact", "factory-class (as the cameras report)"):
        pass
    elif case == "intrinsics uncertain (calibration file)":
        for c in cams.values():
            c["source"] = "calibration"
    elif case == "fx, fy +2% on one camera (stated: calibration file)":
        for c in cams.values():
            c["source"] = "calibration"
        K = np.asarray(cams[first]["K"], float)
        K[0, 0] *= 1.02
        K[1, 1] *= 1.02
        cams[first]["K"] = K.tolist()
    elif case == "fx, fy +2% on one camera (stated: factory)":
        for c in cams.values():
            c["source"] = "factory"
        K = np.asarray(cams[first]["K"], float)
        K[0, 0] *= 1.02
        K[1, 1] *= 1.02
        cams[first]["K"] = K.tolist()
    elif case == "board printed at 101.6%":  # with the true intrinsics held: the scale is what is tested
        head["target"]["pitch_m"] = float(head["target"]["pitch_m"]) / 1.016
    else:
        raise ValueError(case)
    (dst / "dataset.yaml").write_text(yaml.safe_dump(head, sort_keys=False))
    return dst


CASES = ("factory-class (as the cameras report)", "intrinsics exact", "intrinsics uncertain (calibration file)",
         "fx, fy +2% on one camera (stated: calibration file)", "fx, fy +2% on one camera (stated: factory)",
         "board printed at 101.6%")


def evaluate(root: Path) -> dict:
    gt = load_ground_truth(root)
    t0 = time.perf_counter()
    problem, _ = build_problem(load_dataset(root), progress=False)
    res = solve(problem)
    out = {"solve_s": time.perf_counter() - t0, "notes": list(res.notes), "board_scale": res.board_scale,
           "board_scale_sigma": res.board_scale_sigma, "cameras": {}}
    for n, c in res.cameras.items():
        T = gt["T_base_cam"][n]
        e = np.concatenate([log_so3(c.T_ref_cam[:3, :3] @ T[:3, :3].T), c.T_ref_cam[:3, 3] - T[:3, 3]])
        z = e / np.sqrt(np.diag(c.covariance))
        out["cameras"][n] = {"err_mm": float(np.linalg.norm(e[3:]) * 1e3), "err_deg": float(np.degrees(np.linalg.norm(e[:3]))),
                             "sigma_mm": float(np.linalg.norm(c.sigma_translation_mm)),
                             "sigma_deg": float(np.linalg.norm(c.sigma_rotation_deg)), "z": z.tolist(),
                             "views": c.views_used, "rms_px": c.reprojection_rms_px}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="half the poses")
    ap.add_argument("--cells", default=",".join(CELLS))
    ap.add_argument("--work", type=Path, default=REPO / "bench_out" / "honest")
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    args = ap.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    rows, out = [], {}
    all_z = []
    for name in args.cells.split(","):
        src = simulate(args.work, name, args.quick)
        out[name] = {}
        for case in CASES:
            r = evaluate(variant(src, args.work / "variants" / f"{src.name}_{CASES.index(case)}", case))
            out[name][case] = r
            for n, c in r["cameras"].items():
                z = np.asarray(c["z"])
                all_z.append(z)
                rows.append(f"| {name} | {case} | {n} | {c['views']} | {c['err_mm']:.3f} | {c['sigma_mm']:.3f} | "
                            f"{c['err_deg']:.4f} | {c['sigma_deg']:.4f} | {np.sqrt(np.mean(z ** 2)):.2f} | "
                            f"{np.abs(z).max():.2f} |")
            for note in r["notes"]:
                rows.append(f"| | | note: {note} | | | | | | | |")
            print("\n".join(rows[-len(r['cameras']) - len(r['notes']):]), flush=True)
    Z = np.concatenate(all_z) if all_z else np.zeros(0)
    head = ["# Is the 1σ honest? (rendered cells, default solve)", "",
            f"All cameras and cases: normalised error RMS {np.sqrt(np.mean(Z ** 2)):.2f}, max |z| {np.abs(Z).max():.2f}, "
            f"share of |z| > 3: {np.mean(np.abs(Z) > 3):.3f} ({Z.size} axes).", "",
            "| cell | case | camera | views | err mm | 1σ mm | err deg | 1σ deg | z RMS | z max |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    text = "\n".join(head + rows)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_honest.md").write_text(text + "\n")
    (args.out / "bench_honest.json").write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
