#!/usr/bin/env python
"""Detection throughput: what a dataset's detection costs, per stage and end to end.

Stages, timed one frame at a time on one thread (median ms per frame; the per-stage numbers are
what one core spends, the end-to-end number is the wall time with both cores):

* decode: the PNG at full resolution (what the blind search read before), and reduced by 2 at
  decode time (``cv2.IMREAD_REDUCED_GRAYSCALE_2``, what the blind pass reads now);
* blind search: :func:`calibgraph.detect.blind.look_blind` on a frame without a hint (decoding
  included), split into frames with and without the board; ``probe`` is the same while the board
  spec is in doubt (the look for a chessboard of any size first);
* guided search: :func:`calibgraph.detect.guided.detect_with_hint` with the hint a pose estimate
  gives (the predicted region at full resolution; an empty frame confirmed by the quick check; a
  frame predicted far out of view not even decoded);
* fit: the photometric board fit of the found corners (:mod:`calibgraph.detect.board_fit`);
* solve: ``calibgraph solve`` again with every detection in the cache (loading, solving, writing).

End to end: ``calibgraph solve DATASET`` in a fresh process (cache cleared), wall time, CPU time and
peak memory, with the calibration against the simulator's truth (error and error/sigma; the
stand-in's dataset.yaml holds the true intrinsics) and the radial scale error of every detected
view against the exact projection of the board (``s = sum(e . r) / sum(r . r)``, as in
bench_raster). With ``--compare-tree`` the detections of another checkout (e.g. /work/main) are
made on the same data and compared view by view. A second case gives the 2-camera, 89-image
dataset a wrong board spec (a 9x6 board declared 5x4) and times how long the command takes to
refuse it.

The datasets are stand-ins made here (the real 4-camera x 251-frame recording is not on this
machine): MuJoCo renders of a 4-camera ring of 1920x1080 cameras at 1.8-3.5 m, 251 planned poses,
every camera saving a colour PNG at every pose (most frames without the board). With
``--rct`` the real industrial_calibration ChArUco set in /work/shared is timed too.

    MUJOCO_GL=egl python scripts/bench_detect_throughput.py [--poses 251] [--frames 60] [--label after]

Writes scripts/results/bench_detect_throughput_<label>.json and appends a section to
scripts/results/bench_detect_throughput.md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

# The poses of the saved figures came from the planner before it chose poses by information
# (plan_trajectory(select='random')); kept so that this script reproduces them. 'information' (today's
# default) re-measures with the planner `calibgraph sim` uses.
PLAN_SELECT = "random"
sys.path.insert(0, str(REPO))

from calibgraph.core.problem import Capture  # noqa: E402
from calibgraph.core.targets import Target  # noqa: E402
from calibgraph.io.dataset import image_relpath, write_capture, write_header  # noqa: E402

RCT = Path("/work/shared/datasets/rct_static_camera_charuco")


def render_recording(root: Path, n_cameras: int, n_poses: int, seed: int, distances_m, shared_fraction: float,
                     name: str, declared: Target | None = None, drop_last: int = 0) -> Path:
    """Render every camera at every planned pose into a calibgraph dataset (colour PNG, no stored
    detections) with ``ground_truth.json``; ``declared`` replaces the target written in
    dataset.yaml (a wrong spec); the last ``drop_last`` views are left out. Made once per folder."""
    import cv2

    from calibgraph.plan.planner import plan_trajectory
    from calibgraph.sim.render import SimWorld
    from calibgraph.sim.rendered_dataset import write_ground_truth
    from calibgraph.sim.workcell import ring_workcell

    if (root / "ground_truth.json").is_file():
        return root
    shutil.rmtree(root, ignore_errors=True)
    cell = ring_workcell(n_cameras=n_cameras, preset_name="kinect_v2", distances_m=list(distances_m),
                         spread_deg=300 if n_cameras > 2 else 90, seed=seed, name=name)
    world = SimWorld(cell)
    traj = plan_trajectory(world, n_poses=n_poses, seed=seed, shared_fraction=shared_fraction, select=PLAN_SELECT)
    write_header(root, declared or cell.target, {c.name: c.intrinsics for c in cell.cameras})
    rng = np.random.default_rng(seed)
    poses = [p for p in traj.poses if p.capture]
    n_views = len(poses) * n_cameras - drop_last
    k = 0
    for pose in poses:
        world.set_q(pose.q_rad)
        views = {}
        for cam in cell.camera_names:
            if k * n_cameras + len(views) >= n_views:
                break
            rel = image_relpath(cam, k)
            (root / rel).parent.mkdir(parents=True, exist_ok=True)
            grey = world.render(cam).astype(np.float32)
            # a colour camera's frame: a mild tint per channel, as real colour PNGs decode at 3 bytes a pixel
            tint = 1.0 + rng.normal(0, 0.04, 3)
            bgr = np.clip(grey[:, :, None] * tint[None, None, :], 0, 255).astype(np.uint8)
            cv2.imwrite(str(root / rel), bgr)
            views[cam] = {"image": rel, "stamp_s": float(k)}
        if views:
            write_capture(root, Capture(index=k, T_base_flange=world.T_base_flange(), q_rad=pose.q_rad,
                                        stamp_s=float(k)), views)
        k += 1
    write_ground_truth(root, cell, world)
    world.close()
    return root


def standin_4x251(work: Path, n_poses: int, seed: int) -> Path:
    """The stand-in of the real recording: 4 cameras x ``n_poses`` frames of 1920x1080."""
    return render_recording(work / f"standin_4x{n_poses}_{seed}", 4, n_poses, seed, [1.8, 2.5, 3.0, 3.5], 0.5,
                            "throughput")


def wrong_board_2x89(work: Path, seed: int) -> Path:
    """2 cameras, 89 images of the 9x6-corner A4 board, declared as a 5x4 (4 rows x 5 columns) board."""
    return render_recording(work / f"wrong_board_2x89_{seed}", 2, 45, seed, [1.6, 2.2], 0.6, "wrong_board",
                            declared=Target(kind="checkerboard", rows=4, cols=5, pitch_m=0.025), drop_last=1)


# -------------------------------------------------------------------------------------------------
# Per-stage timing
# -------------------------------------------------------------------------------------------------
def _ms(f, *a, **k):
    t0 = time.perf_counter()
    out = f(*a, **k)
    return 1e3 * (time.perf_counter() - t0), out


def stage_times(root: Path, n_frames: int, seed: int) -> dict:
    """Median ms per frame of each stage on ``n_frames`` frames of ``root`` (half with the board,
    half without, by the simulator's truth), one thread."""
    import cv2

    from calibgraph.core.transforms import inv
    from calibgraph.detect.blind import look_blind
    from calibgraph.detect.board_fit import refine_checkerboard
    from calibgraph.detect.corners import detect_image
    from calibgraph.detect.guided import detect_with_hint, predict_view
    from calibgraph.detect.image import Frame
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.io.layouts import load_dataset

    cv2.setNumThreads(1)
    ds = load_dataset(root)
    truth = load_ground_truth(root)
    flange = {c.index: truth["T_base_flange_true"][c.index] for c in ds.captures}
    hints, board = {}, []
    for v in ds.views:
        T_cb = inv(truth["T_base_cam"][v.camera]) @ flange[v.capture] @ truth["T_flange_board"]
        h = predict_view(ds.target, ds.cameras[v.camera], T_cb)
        hints[(v.camera, v.capture)] = h
        board.append(h.visible)
    rng = np.random.default_rng(seed)
    views = list(ds.views)
    with_b = [v for v, b in zip(views, board) if b]
    without = [v for v, b in zip(views, board) if not b]
    pick = [with_b[i] for i in rng.permutation(len(with_b))[: n_frames // 2]] + \
           [without[i] for i in rng.permutation(len(without))[: n_frames - n_frames // 2]]
    rows = {"decode_full": [], "decode_reduced2": [], "blind_board": [], "blind_empty": [], "probe_board": [],
            "probe_empty": [], "guided_board": [], "guided_empty": [], "fit": []}
    for v in pick:
        path = str(Path(ds.root) / v.image)
        data = np.fromfile(path, np.uint8)
        rows["decode_full"].append(_ms(cv2.imdecode, data, cv2.IMREAD_GRAYSCALE)[0])
        rows["decode_reduced2"].append(_ms(cv2.imdecode, data, cv2.IMREAD_REDUCED_GRAYSCALE_2)[0])
        has = hints[(v.camera, v.capture)].visible
        intr = ds.cameras[v.camera]
        ms, det = _ms(look_blind, Frame(path), ds.target, intr)
        rows["blind_board" if has else "blind_empty"].append(ms)
        rows["probe_board" if has else "probe_empty"].append(_ms(look_blind, Frame(path), ds.target, intr,
                                                                 check_spec=True)[0])
        ms, gdet = _ms(detect_with_hint, Frame(path), ds.target, intr, hints[(v.camera, v.capture)])
        rows["guided_board" if has else "guided_empty"].append(ms)
        if det.ok and ds.target.kind == "checkerboard":
            grey = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
            raw = detect_image(grey, ds.target, intrinsics=intr, refine=False)
            if raw.ok:
                rows["fit"].append(_ms(refine_checkerboard, grey, ds.target, raw.ids, raw.uv_px)[0])
    return {k: {"median_ms": float(np.median(v)) if v else None, "max_ms": float(np.max(v)) if v else None,
                "n": len(v)} for k, v in rows.items()}


# -------------------------------------------------------------------------------------------------
# End to end
# -------------------------------------------------------------------------------------------------
def end_to_end(root: Path, out_dir: Path, extra_args=(), cached: bool = False) -> dict:
    """``calibgraph solve ROOT`` in a fresh process with the detection cache cleared (kept when
    ``cached``): wall, CPU, peak memory (the largest of this process's children so far), exit code
    and the last lines it printed."""
    if not cached:
        shutil.rmtree(root / ".calibgraph_cache", ignore_errors=True)
    shutil.rmtree(out_dir, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    out_dir.mkdir(parents=True)
    proc = subprocess.run([sys.executable, "-m", "calibgraph", "solve", str(root), "--out", str(out_dir / "result.json"),
                           "--quiet",
                           *extra_args], capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(REPO)))
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall_s": wall, "cpu_s": cpu, "peak_gb": after.ru_maxrss / 1e6, "exit": proc.returncode,
            "stdout_tail": proc.stdout.strip().splitlines()[-12:], "stderr_tail": proc.stderr.strip().splitlines()[-6:]}


def accuracy(root: Path, out_dir: Path) -> dict:
    """Per camera: translation error (mm) and rotation error (deg) against the simulator's truth,
    the reported 1σ (mm) and the Mahalanobis distance² of the 6-dof error."""
    from calibgraph.core.transforms import log_so3
    from calibgraph.io.ground_truth import load_ground_truth

    res = json.loads((out_dir / "result.json").read_text())  # the file format, eye-to-hand
    truth = load_ground_truth(root)
    out = {}
    for name, cam in res["cameras"].items():
        T, Tt = np.asarray(cam["T_base_cam"], float), truth["T_base_cam"][name]
        d_rot = log_so3(T[:3, :3] @ Tt[:3, :3].T)
        d_t = T[:3, 3] - Tt[:3, 3]
        cov = np.asarray(cam["covariance"], float)
        e = np.concatenate([d_rot, d_t])
        out[name] = {"err_mm": 1e3 * float(np.linalg.norm(d_t)), "err_deg": float(np.degrees(np.linalg.norm(d_rot))),
                     "sigma_mm": 1e3 * float(np.sqrt(np.trace(cov[3:, 3:]))),
                     "mahalanobis2": float(e @ np.linalg.solve(cov, e)), "views": cam["views_used"]}
    return out


_DETECT_SNIPPET = """
import json, sys
from calibgraph.io.layouts import load_dataset
from calibgraph.solver.solve.build import build_problem
_, det = build_problem(load_dataset(sys.argv[1]), progress=False)
json.dump({f"{c}|{k}": [d.ids.tolist(), d.uv_px.tolist()] for (c, k), d in det.results.items() if d.ok},
          open(sys.argv[2], "w"))
"""


def detections_of(root: Path, tree: Path, out: Path) -> dict:
    """The views ``calibgraph solve`` detects in ``root`` with the code of ``tree`` (cache cleared):
    (camera, capture) -> (ids, uv_px), and the wall and CPU time it took."""
    shutil.rmtree(root / ".calibgraph_cache", ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", _DETECT_SNIPPET, str(root), str(out)], check=True,
                   env=dict(os.environ, PYTHONPATH=str(tree)))
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    raw = json.loads(out.read_text())
    return {(k.split("|")[0], int(k.split("|")[1])): (np.asarray(i, int), np.asarray(u, float).reshape(-1, 2))
            for k, (i, u) in raw.items()}, (wall, cpu)


def scale_errors(root: Path, dets: dict) -> dict:
    """Per detected view, the radial scale error against the exact projection of the board (the
    true intrinsics, camera, flange and board poses of ground_truth.json) and the RMS corner error."""
    from calibgraph.core.transforms import inv
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.io.layouts import load_dataset

    truth = load_ground_truth(root)
    pts = load_dataset(root).target.points_board_m
    out = {}
    for (cam, cap), (ids, uv) in dets.items():
        T = inv(truth["T_base_cam"][cam]) @ truth["T_base_flange_true"][cap] @ truth["T_flange_board"]
        p = pts[ids] @ T[:3, :3].T + T[:3, 3]
        t = truth["intrinsics_true"][cam].project(p)
        e, r = uv - t, t - t.mean(0)
        out[(cam, cap)] = (float((e * r).sum() / (r * r).sum()), float(np.sqrt((e * e).sum(1).mean())))
    return out


def _scale_summary(errs: dict) -> dict:
    s = np.array([v[0] for v in errs.values()])
    rms = np.array([v[1] for v in errs.values()])
    return {"views": len(s), "scale_mean": float(s.mean()), "scale_se": float(s.std(ddof=1) / np.sqrt(len(s))),
            "rms_px_median": float(np.median(rms))}


def compare(root: Path, work: Path, other_tree: Path) -> dict:
    """This tree's detections against ``other_tree``'s on ``root``: views found by each, the largest
    corner difference on views both found, and each side's scale error."""
    mine, t_mine = detections_of(root, REPO, work / "dets_this.json")
    other, t_other = detections_of(root, other_tree, work / "dets_other.json")
    both = sorted(set(mine) & set(other))
    diffs = [float(np.abs(mine[k][1] - other[k][1]).max()) for k in both if np.array_equal(mine[k][0], other[k][0])]
    return {"other_tree": str(other_tree), "found_this": len(mine), "found_other": len(other), "both": len(both),
            "same_ids": len(diffs), "max_abs_diff_px": max(diffs) if diffs else None,
            "median_abs_diff_px": float(np.median(diffs)) if diffs else None,
            "wall_this_s": t_mine[0], "wall_other_s": t_other[0], "cpu_this_s": t_mine[1], "cpu_other_s": t_other[1],
            "scale_this": _scale_summary(scale_errors(root, mine)),
            "scale_other": _scale_summary(scale_errors(root, other)),
            "scale_this_on_both": _scale_summary(scale_errors(root, {k: mine[k] for k in both})),
            "scale_other_on_both": _scale_summary(scale_errors(root, {k: other[k] for k in both}))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--poses", type=int, default=251)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=40, help="frames timed per stage (half with the board)")
    ap.add_argument("--label", default="after")
    ap.add_argument("--skip-stages", action="store_true")
    ap.add_argument("--rct", action="store_true", help="also time the real ChArUco set in /work/shared")
    ap.add_argument("--compare-tree", type=Path, default=None,
                    help="another checkout (e.g. /work/main) whose detections of the stand-in are compared")
    ap.add_argument("--work", type=Path, default=REPO / "bench_out" / "throughput")
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    args = ap.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "egl")
    args.work.mkdir(parents=True, exist_ok=True)
    standin = standin_4x251(args.work, args.poses, args.seed)
    wrong = wrong_board_2x89(args.work, args.seed)
    out = {"label": args.label, "poses": args.poses, "seed": args.seed, "cores": os.cpu_count()}
    if not args.skip_stages:
        out["stages"] = stage_times(standin, args.frames, args.seed)
    e2e = end_to_end(standin, args.work / "solve_standin")
    if e2e["exit"] == 0:
        e2e["accuracy"] = accuracy(standin, args.work / "solve_standin")
    out["standin"] = e2e
    out["solve_cached"] = end_to_end(standin, args.work / "solve_standin_cached", cached=True)
    if args.compare_tree is not None:
        out["compare"] = compare(standin, args.work, args.compare_tree)
    out["wrong_board"] = end_to_end(wrong, args.work / "solve_wrong")
    if args.rct and RCT.is_dir():
        tmp = args.work / "rct_copy"
        if not tmp.is_dir():
            shutil.copytree(RCT, tmp)
        out["rct"] = end_to_end(tmp, args.work / "solve_rct")
    text = report(out)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"bench_detect_throughput_{args.label}.json").write_text(json.dumps(out, indent=1))
    md = args.out / "bench_detect_throughput.md"
    md.write_text((md.read_text() if md.is_file() else "") + text + "\n")
    return 0


def report(out: dict) -> str:
    lines = [f"## {out['label']} ({out['cores']} cores, stand-in {out['poses']} poses x 4 cameras, seed {out['seed']})", ""]
    st = out.get("stages")
    if st:
        lines += ["| stage (one thread) | median ms/frame | max ms | frames |", "|---|---|---|---|"]
        for k, v in st.items():
            if v["n"]:
                lines.append(f"| {k} | {v['median_ms']:.1f} | {v['max_ms']:.1f} | {v['n']} |")
        lines.append("")
    lines += ["| end to end (`calibgraph solve`) | exit | wall s | CPU s | peak GB |", "|---|---|---|---|---|"]
    for k in ("standin", "solve_cached", "wrong_board", "rct"):
        if k in out:
            r = out[k]
            lines.append(f"| {k} | {r['exit']} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} | {r['peak_gb']:.2f} |")
    lines.append("")
    acc = out["standin"].get("accuracy")
    if acc:
        lines += ["| camera | views | err mm | err deg | 1σ mm | Mahalanobis² (6 dof) |", "|---|---|---|---|---|---|"]
        for c, a in acc.items():
            lines.append(f"| {c} | {a['views']} | {a['err_mm']:.3f} | {a['err_deg']:.4f} | {a['sigma_mm']:.3f} | "
                         f"{a['mahalanobis2']:.1f} |")
        lines.append("")
    cmp = out.get("compare")
    if cmp:
        a, b = cmp["scale_this_on_both"], cmp["scale_other_on_both"]
        lines += [f"Detections vs {cmp['other_tree']} (cache cleared, `build_problem`): views found "
                  f"{cmp['found_this']} here / {cmp['found_other']} there ({cmp['both']} both, {cmp['same_ids']} with the "
                  f"same ids; corner difference median {cmp['median_abs_diff_px']:.2g} px, max "
                  f"{cmp['max_abs_diff_px']:.2g} px); detection wall {cmp['wall_this_s']:.1f} s here / "
                  f"{cmp['wall_other_s']:.1f} s there, CPU {cmp.get('cpu_this_s', float('nan')):.1f} s here / "
                  f"{cmp.get('cpu_other_s', float('nan')):.1f} s there.", "",
                  "| radial scale error vs exact truth (views both found) | views | mean ± s.e. | median corner RMS px |",
                  "|---|---|---|---|",
                  f"| this tree | {a['views']} | {a['scale_mean']:+.1e} ± {a['scale_se']:.1e} | {a['rms_px_median']:.3f} |",
                  f"| {cmp['other_tree']} | {b['views']} | {b['scale_mean']:+.1e} ± {b['scale_se']:.1e} | "
                  f"{b['rms_px_median']:.3f} |", ""]
    wrong = out["wrong_board"]
    lines += ["wrong board spec, the command's last words: "
              + " / ".join((wrong["stderr_tail"] or wrong["stdout_tail"] or ["(none)"])[-2:]), ""]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
