#!/usr/bin/env python
"""Detection on boards as prints and captures show them (issues 45-47): white on black, with a capture
app's drawings over them, and the time a wrong or unusable spec takes to be refused.

Sections (all images rendered by calibgraph.sim at 1920x1200, 60 deg horizontal field, blur 0.8 px,
noise 2 grey levels unless said, the board 0.8-1.4 m away tilted up to 30 deg; exact truth):

* ``prints``: every kind (checkerboard 6x9, ChArUco 6x9 DICT_5X5_100, symmetric 5x7 circles with
  allow_symmetric, asymmetric 7x11, modified 7x9) as printed, the image inverted, printed white on black
  on a light or a dark scene, and (asymmetric grid) white on black at noise 6: found, found inverted,
  every point, max error against the truth, time. With ``--compare-tree`` one view of each is also run
  by the other tree, in its own process, stopped after ``--compare-timeout`` s.
* ``overlays``: pose axes drawn from the board's origin (3, 5 and 8 px lines, and a text), checkerboard,
  ChArUco and the two circle grids: found, points lost, of those the ones not under a line (within
  0.75 pitch of it), max error of the points kept.
* ``refusals``: `calibgraph` commands in a fresh process, wall time to the exit and the error line: the
  real RCT ChArUco images given to ``intrinsics`` as the 6x4 checkerboard (when ../shared has them); a
  6x9 board with its right third covered in every frame; a plain 6x9 checkerboard declared ChArUco; a
  6x9 board declared 7x10; and, found, 8 noisy white-on-black asymmetric-grid frames (``intrinsics``).
* ``real`` (``--real``): the real sets (ViSP 2022/2025, RCT ChArUco blind, MC-HEC guided as ``solve``
  detects it and blind on every 25th capture) detected cold (a fresh copy, no cache) by this tree and
  the other: views found, ids and corners compared, CPU and wall seconds.

    nice -n 10 python scripts/bench_detect_prints.py [--seeds 3] [--compare-tree /tmp/base] [--real]

Writes scripts/results/bench_detect_prints.json and .md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calibgraph.core.camera import Intrinsics  # noqa: E402
from calibgraph.core.targets import Target  # noqa: E402
from calibgraph.detect.search import detect_image  # noqa: E402
from calibgraph.sim.board_image import board_texture, look_at_board, render_view  # noqa: E402
from calibgraph.sim.board_views import ViewPlace, draw_pose_axes, write_board_views  # noqa: E402

OUT = REPO / "scripts" / "results"
INTR = Intrinsics.from_hfov(1920, 1200, 60.0)
KINDS = {
    "checkerboard": Target(kind="checkerboard", rows=6, cols=9, pitch_m=0.03),
    "charuco": Target(kind="charuco", rows=6, cols=9, pitch_m=0.03, marker_m=0.022, dictionary="DICT_5X5_100"),
    "circles": Target(kind="circles", rows=5, cols=7, pitch_m=0.03),
    "acircles": Target(kind="acircles", rows=7, cols=11, pitch_m=0.02),
    "modified_circles": Target(kind="modified_circles", rows=7, cols=9, pitch_m=0.03),
}
MODES = ("normal", "inverted", "wob_light", "wob_dark", "wob_light_noisy")
SHARED = REPO.parent / "shared" / "datasets"

WORKER = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
from calibgraph.core.targets import Target
from calibgraph.detect.search import detect_image
job = json.loads(sys.argv[2])
t0 = time.perf_counter()
d = detect_image(job["image"], Target.from_dict(job["target"]), allow_symmetric=job["sym"])
print(json.dumps({"ok": bool(d.ok), "ids": d.ids.tolist(), "uv": d.uv_px.tolist(), "time_s": time.perf_counter() - t0,
                  "reason": d.reason}))
"""


def view(target, seed, mode, size=(0.8, 1.4)):
    rng = np.random.default_rng(seed)
    T = look_at_board(target, rng.uniform(*size), *rng.uniform(-30, 30, 2), rng.uniform(-20, 20),
                      tuple(rng.uniform(-300, 300, 2)), INTR)
    wob = mode.startswith("wob")
    tex = board_texture(target, 8000.0 / 0.45, white_on_black=wob)
    rv = render_view(target, INTR, T, blur_sigma_px=1.2 if "noisy" in mode else 0.8,
                     noise_sigma=6.0 if "noisy" in mode else 2.0, seed=seed, texture=tex,
                     background=0.1 if mode == "wob_dark" else 0.85 if wob else 0.45)
    img = 255 - rv.image if mode == "inverted" else rv.image
    return img, rv, T


def score(det_ids, det_uv, rv) -> float:
    truth = dict(zip(rv.ids.tolist(), rv.uv_px))
    return float(max(np.linalg.norm(truth[int(i)] - np.asarray(u)) for i, u in zip(det_ids, det_uv))) if len(det_ids) \
        else float("nan")


def other_tree(tree: Path, image: Path, target: Target, sym: bool, timeout: float) -> dict:
    job = json.dumps({"image": str(image), "target": target.to_dict(), "sym": sym})
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, "-c", WORKER, str(tree), job], capture_output=True, text=True,
                           timeout=timeout)
        r = json.loads(p.stdout.strip().splitlines()[-1])
    except subprocess.TimeoutExpired:
        return {"ok": False, "ids": [], "uv": [], "time_s": time.perf_counter() - t0,
                "reason": f"stopped after {timeout:g} s"}
    return r


def prints(args, tmp: Path) -> list:
    rows = []
    for kind, t in KINDS.items():
        for mode in MODES:
            if mode == "wob_light_noisy" and kind != "acircles":
                continue
            for seed in range(args.seeds):
                img, rv, _ = view(t, 100 + seed, mode, (1.6, 2.2) if "noisy" in mode else (0.8, 1.4))
                t0 = time.perf_counter()
                d = detect_image(img, t, allow_symmetric=t.is_symmetric)
                r = dict(section="prints", kind=kind, mode=mode, seed=seed, tree="this", ok=bool(d.ok),
                         inverted=bool(d.inverted), n=int(d.n_found), n_truth=int(len(rv.ids)),
                         max_err_px=round(score(d.ids, d.uv_px, rv), 3) if d.ok else None,
                         time_s=round(time.perf_counter() - t0, 2), reason=d.reason[:120])
                rows.append(r)
                print(json.dumps(r), flush=True)
                if args.compare_tree and seed == 0:
                    f = tmp / f"{kind}_{mode}.png"
                    cv2.imwrite(str(f), img)
                    o = other_tree(args.compare_tree, f, t, t.is_symmetric, args.compare_timeout)
                    r2 = dict(r, tree=args.compare_tree.name, ok=o["ok"], inverted=None, n=len(o["ids"]),
                              max_err_px=round(score(o["ids"], o["uv"], rv), 3) if o["ok"] else None,
                              time_s=round(o["time_s"], 2), reason=o["reason"][:120])
                    rows.append(r2)
                    print(json.dumps(r2), flush=True)
    return rows


def overlays(args) -> list:
    rows = []
    for kind in ("checkerboard", "charuco", "acircles", "modified_circles"):
        t = KINDS[kind]
        for thick in (3, 5, 8):
            for seed in range(args.seeds + 1):
                img, rv, T = view(t, 200 + seed, "normal")
                x0, _, x1, _ = t.extent_m
                L = 0.6 * (x1 - x0)
                grey = cv2.cvtColor(draw_pose_axes(img, INTR, T, L, thick, f"pose {seed}: t = [0.12 -0.03 0.95] m"),
                                    cv2.COLOR_BGR2GRAY)
                e = INTR.project(np.array([[0, 0, 0], [L, 0, 0], [0, L, 0], [0, 0, -L]], float) @ T[:3, :3].T + T[:3, 3])

                def dist(p, a, b):
                    ab = b - a
                    s = np.clip(((p - a) @ ab) / (ab @ ab), 0, 1)
                    return np.linalg.norm(p - (a + s[:, None] * ab), axis=1)
                d_line = np.min([dist(rv.uv_px, e[0], e[k]) for k in (1, 2, 3)], axis=0)
                t0 = time.perf_counter()
                d = detect_image(grey, t)
                pitch = float(np.median(np.linalg.norm(np.diff(rv.uv_px[:t.cols], axis=0), axis=1)))
                under = {int(i) for i, dl in zip(rv.ids, d_line) if dl < 0.75 * pitch}
                lost = set(rv.ids.tolist()) - set(d.ids.tolist()) if d.ok else set(rv.ids.tolist())
                r = dict(section="overlays", kind=kind, thickness_px=thick, seed=seed, ok=bool(d.ok), n=int(d.n_found),
                         n_truth=int(len(rv.ids)), under=len(under), lost=len(lost), lost_not_under=len(lost - under),
                         max_err_px=round(score(d.ids, d.uv_px, rv), 3) if d.ok else None,
                         time_s=round(time.perf_counter() - t0, 2), reason=d.reason[:120])
                rows.append(r)
                print(json.dumps(r), flush=True)
    return rows


def _cmd(tree: Path, argv: list, timeout: float) -> dict:
    import os

    t0 = time.perf_counter()
    env = dict(os.environ, PYTHONPATH=str(tree))
    try:
        p = subprocess.run([sys.executable, "-c", "import sys; from calibgraph.cli.main import main; sys.exit(main())",
                            *map(str, argv)], capture_output=True, text=True, timeout=timeout, env=env)
        err = [ln for ln in (p.stderr + p.stdout).splitlines() if "error:" in ln or ln.startswith("wrote ")]
        return dict(rc=p.returncode, wall_s=round(time.perf_counter() - t0, 1), said=(err[-1] if err else "")[:400])
    except subprocess.TimeoutExpired:
        return dict(rc=None, wall_s=round(time.perf_counter() - t0, 1), said=f"stopped after {timeout:g} s")


def refusals(args, tmp: Path) -> list:
    intr = Intrinsics.from_hfov(1280, 720, 60.0)
    rng = np.random.default_rng(3)

    def places(n=10, visible=None):
        return [ViewPlace(rng.uniform(0.5, 0.8), rng.uniform(-25, 25), rng.uniform(-25, 25), rng.uniform(-15, 15),
                          (rng.uniform(-150, 150), rng.uniform(-80, 80)), visible=visible) for _ in range(n)]
    cb = Target(kind="checkerboard", rows=6, cols=9, pitch_m=0.025)
    ch = Target(kind="charuco", rows=6, cols=9, pitch_m=0.025, marker_m=0.018, dictionary="DICT_4X4_50")
    cases = {}
    write_board_views(tmp / "covered", cb, cb, intr, places(visible=(6, 6)))
    cases["covered right third, 6x9 declared (detect)"] = ["detect", tmp / "covered", "--no-cache"]
    write_board_views(tmp / "plain", cb, ch, intr, places())
    cases["plain 6x9 checkerboard declared ChArUco (detect)"] = ["detect", tmp / "plain", "--no-cache"]
    write_board_views(tmp / "wrong", cb, Target(kind="checkerboard", rows=7, cols=10, pitch_m=0.025),
                      Intrinsics.from_hfov(1920, 1080, 60.0), places(12))
    cases["6x9 board declared 7x10 (detect)"] = ["detect", tmp / "wrong", "--no-cache"]
    ac = KINDS["acircles"]
    r2 = np.random.default_rng(1)
    write_board_views(tmp / "acwob", ac, ac, INTR,
                      [ViewPlace(r2.uniform(1.6, 2.2), r2.uniform(-30, 30), r2.uniform(-30, 30), r2.uniform(-20, 20),
                                 (r2.uniform(-300, 300), r2.uniform(-200, 200))) for _ in range(8)],
                      blur_sigma_px=1.2, noise_sigma=6.0, white_on_black=True, background=0.85)
    (tmp / "ac.yaml").write_text("target: {kind: acircles, rows: 7, cols: 11, pitch_m: 0.02}\n")
    cases["8 noisy white-on-black 7x11 asymmetric grids (intrinsics: found)"] = [
        "intrinsics", tmp / "acwob" / "images" / "cam0", "--target", tmp / "ac.yaml", "--out", tmp / "ac_cam.yaml",
        "--quiet"]
    if (SHARED / "rct_static_camera_charuco" / "images").is_dir():
        shutil.copytree(SHARED / "rct_static_camera_charuco", tmp / "rct")
        (tmp / "cb64.yaml").write_text("target: {kind: checkerboard, rows: 6, cols: 4, pitch_m: 0.036195}\n")
        cases["real RCT ChArUco images as the 6x4 checkerboard (intrinsics)"] = [
            "intrinsics", tmp / "rct" / "images", "--target", tmp / "cb64.yaml", "--out", tmp / "cb64_cam.yaml", "--quiet"]
    rows = []
    for case, argv in cases.items():
        for tree in [REPO] + ([args.compare_tree] if args.compare_tree else []):
            for p in (tmp / "covered", tmp / "plain", tmp / "wrong", tmp / "acwob"):
                shutil.rmtree(p / ".calibgraph_cache", ignore_errors=True)
            r = dict(section="refusals", case=case, tree="this" if tree == REPO else tree.name,
                     **_cmd(tree, argv, None if tree == REPO else args.compare_timeout_cmd))
            rows.append(r)
            print(json.dumps(r), flush=True)
    return rows


SNAP = REPO / "scripts" / "_snapshot_detections.py"


def real(args, tmp: Path) -> list:
    rows = []
    for tree in [REPO] + ([args.compare_tree] if args.compare_tree else []):
        out = tmp / f"snap_{'this' if tree == REPO else tree.name}.json"
        subprocess.run([sys.executable, str(SNAP), str(tree), str(out), str(SHARED), str(tmp)], check=True)
        rows.append((tree, json.loads(out.read_text())))
    res = []
    this = rows[0][1]
    other = rows[1][1] if len(rows) > 1 else None
    for name, r in this.items():
        row = dict(section="real", set=name, found=sum(d["ok"] for d in r["dets"].values()), views=len(r["dets"]),
                   cpu_s=round(r["cpu_s"], 1), wall_s=round(r["wall_s"], 1))
        if other and name in other:
            o = other[name]["dets"]
            same_ok = sum(o.get(k, {}).get("ok") == d["ok"] for k, d in r["dets"].items())
            same_ids = sum(d["ok"] and o.get(k, {}).get("ok") and o[k]["ids"] == d["ids"] for k, d in r["dets"].items())
            diff = [float(np.abs(np.array(d["uv"]) - np.array(o[k]["uv"])).max()) for k, d in r["dets"].items()
                    if d["ok"] and o.get(k, {}).get("ok") and o[k]["ids"] == d["ids"] and d["ids"]]
            row.update(other_found=sum(v["ok"] for v in o.values()), same_found=same_ok, same_ids=same_ids,
                       max_corner_diff_px=max(diff) if diff else 0.0, other_cpu_s=round(other[name]["cpu_s"], 1),
                       other_wall_s=round(other[name]["wall_s"], 1))
        res.append(row)
        print(json.dumps(row), flush=True)
    return res


def write(rows, args):
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "bench_detect_prints.json").write_text(json.dumps(rows, indent=1))
    other = args.compare_tree.name if args.compare_tree else None
    L = ["# bench_detect_prints", "",
         f"`python scripts/bench_detect_prints.py --seeds {args.seeds}"
         f"{f' --compare-tree {args.compare_tree}' if other else ''}{' --real' if args.real else ''}` "
         f"({time.strftime('%Y-%m-%d')}; 2 cores shared with other work: wall times are inflated, CPU seconds less so). "
         "Rendered 1920x1200 views, exact truth (module docstring of the script).", ""]
    pr = [r for r in rows if r["section"] == "prints"]
    if pr:
        L += ["## White on black: found, and how well", "",
              "| kind | print | tree | found | found inverted | all points | max error px | time s (mean / max) |",
              "|---|---|---|---|---|---|---|---|"]
        for kind in KINDS:
            for mode in MODES:
                for tree in ("this", other):
                    g = [r for r in pr if r["kind"] == kind and r["mode"] == mode and r["tree"] == tree]
                    if not g:
                        continue
                    errs = [r["max_err_px"] for r in g if r["max_err_px"] is not None]
                    ts = [r["time_s"] for r in g]
                    inv = "" if tree != "this" else f"{sum(r['inverted'] for r in g)}/{len(g)}"
                    L.append(f"| {kind} | {mode} | {tree} | {sum(r['ok'] for r in g)}/{len(g)} | {inv} | "
                             f"{sum(r['ok'] and r['n'] == r['n_truth'] for r in g)}/{len(g)} | "
                             f"{max(errs):.3f} | {np.mean(ts):.2f} / {max(ts):.2f} |" if errs else
                             f"| {kind} | {mode} | {tree} | 0/{len(g)} | {inv} | 0/{len(g)} | - | "
                             f"{np.mean(ts):.2f} / {max(ts):.2f} ({g[0]['reason'][:60]}) |")
        L.append("")
    ov = [r for r in rows if r["section"] == "overlays"]
    if ov:
        L += ["## Pose axes drawn over the board", "",
              "| kind | line px | views | found | points under a line (mean) | lost (mean) | lost not under a line "
              "| max error of the points kept px | refusal (when not found) |", "|---|---|---|---|---|---|---|---|---|"]
        for kind in ("checkerboard", "charuco", "acircles", "modified_circles"):
            for th in (3, 5, 8):
                g = [r for r in ov if r["kind"] == kind and r["thickness_px"] == th]
                f = [r for r in g if r["ok"]]
                errs = [r["max_err_px"] for r in f]
                why = next((r["reason"][:70] for r in g if not r["ok"]), "")
                L.append(f"| {kind} | {th} | {len(g)} | {len(f)} | {np.mean([r['under'] for r in g]):.1f} | "
                         f"{np.mean([r['lost'] for r in f]) if f else float('nan'):.1f} | "
                         f"{sum(r['lost_not_under'] for r in f)} | {max(errs) if errs else float('nan'):.3f} | {why} |")
        L.append("")
    rf = [r for r in rows if r["section"] == "refusals"]
    if rf:
        L += ["## Time to the answer (`calibgraph` in a fresh process)", "", "| case | tree | exit | wall s | last line |",
              "|---|---|---|---|---|"]
        for r in rf:
            L.append(f"| {r['case']} | {r['tree']} | {r['rc']} | {r['wall_s']} | {r['said'].replace('|', '/')} |")
        L.append("")
    rl = [r for r in rows if r["section"] == "real"]
    if rl:
        L += ["## Real sets, cold: this tree against the other", "",
              "| set | views | found here / there | same found | same ids | max corner difference px | CPU s here / there "
              "| wall s here / there |", "|---|---|---|---|---|---|---|---|"]
        for r in rl:
            L.append(f"| {r['set']} | {r['views']} | {r['found']} / {r.get('other_found', '-')} | {r.get('same_found', '-')} | "
                     f"{r.get('same_ids', '-')} | {r.get('max_corner_diff_px', '-')} | {r['cpu_s']} / {r.get('other_cpu_s', '-')} "
                     f"| {r['wall_s']} / {r.get('other_wall_s', '-')} |")
        L.append("")
    (OUT / "bench_detect_prints.md").write_text("\n".join(L) + "\n")
    print("\n".join(L))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--compare-tree", type=Path, default=None, help="another checkout (e.g. a git archive of main)")
    ap.add_argument("--compare-timeout", type=float, default=60.0, help="per image, for the other tree")
    ap.add_argument("--compare-timeout-cmd", type=float, default=180.0, help="per command, for the other tree")
    ap.add_argument("--sections", default="prints,overlays,refusals")
    ap.add_argument("--real", action="store_true", help="also the real sets (a few CPU minutes per tree)")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for sec in args.sections.split(","):
            if sec == "prints":
                rows += prints(args, tmp)
            elif sec == "overlays":
                rows += overlays(args)
            elif sec == "refusals":
                rows += refusals(args, tmp)
        if args.real:
            rows += real(args, tmp)
    write(rows, args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
