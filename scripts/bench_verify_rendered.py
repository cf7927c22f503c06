"""A smaller rendered check of ``calibgraph verify`` (bench_verify.py uses synthetic corners).

The default cell (three L515 at 3 m, MuJoCo FR3, image noise and blur) is calibrated from a
rendered ``calibgraph sim`` capture of ``--cal-poses`` poses; then each trial renders a verify capture
of ``--poses`` poses planned from the stored result alone (``calibgraph.acquire.verify``: the same
path as ``calibgraph capture --verify --robot sim``), with nothing moved or one camera (round
robin) bumped by 2 mm in a random direction or 0.2 deg about a random axis, each trial with new
image noise, FK error and candidate poses. Detection is the real detector on the rendered images.

    python scripts/bench_verify_rendered.py [--trials 10] [--poses 5] [--out scripts/results]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibgraph.acquire.verify import run_verify_capture  # noqa: E402
from calibgraph.core.transforms import exp_so3, make_T  # noqa: E402
from calibgraph.io.files import read_yaml  # noqa: E402
from calibgraph.plan.cell import cell_from_world_dict  # noqa: E402
from calibgraph.sim.devices import make_devices  # noqa: E402
from calibgraph.sim.planning_world import planning_world  # noqa: E402
from calibgraph.sim.render import SimWorld  # noqa: E402
from calibgraph.sim.rendered_dataset import VisibilityGatedDetector  # noqa: E402
from calibgraph.sim.workcell import workcell_from_dict  # noqa: E402
from calibgraph.solver.output.result import load_result  # noqa: E402
from calibgraph.solver.changes.verify import chi2_isf_6  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
WORLD = REPO / "datasets" / "workcells" / "default.yaml"


def bumped(wc, name, kind, rng):
    if kind == "none":
        return wc
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    cams = []
    for c in wc.cameras:
        if c.name == name:
            T = c.T_base_cam
            T = (make_T(T[:3, :3], T[:3, 3] + 0.002 * u) if kind == "2 mm"
                 else make_T(exp_so3(u * np.radians(0.2)) @ T[:3, :3], T[:3, 3]))
            c = replace(c, T_base_cam=T)
        cams.append(c)
    return replace(wc, cameras=tuple(cams))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10, help="trials per case (nothing moved, 2 mm, 0.2 deg)")
    ap.add_argument("--poses", type=int, default=5)
    ap.add_argument("--cal-poses", type=int, default=40)
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results")
    args = ap.parse_args()
    t0 = time.time()
    tmp = Path(tempfile.mkdtemp(prefix="bench_verify_rendered_"))
    subprocess.run([sys.executable, "-m", "calibgraph.cli.main", "sim", "--workcell", str(WORLD), "--poses",
                    str(args.cal_poses), "--out", str(tmp / "cal"), "--quiet"], check=True)
    subprocess.run([sys.executable, "-m", "calibgraph.cli.main", "solve", str(tmp / "cal"), "--out",
                    str(tmp / "result.json"), "--quiet"], check=True, stdout=subprocess.DEVNULL)
    stored = load_result(tmp / "result.json")
    world_d = read_yaml(WORLD, "world")
    wc0 = workcell_from_dict(world_d, str(WORLD))
    cell = cell_from_world_dict(world_d, str(WORLD))
    pworld = planning_world(cell)
    names = wc0.camera_names
    rows = []
    for case in ("none", "2 mm", "0.2 deg"):
        for t in range(args.trials):
            k = len(rows)
            rng = np.random.default_rng(100 + k)
            victim = names[t % len(names)]
            wc = replace(bumped(wc0, victim, case, rng), seed=1000 + k)
            sim = SimWorld(wc)
            robot, cams = make_devices(sim, wc.fk_sigma_translation_m, np.radians(wc.fk_sigma_rotation_deg), wc.seed)
            rep = run_verify_capture(robot, cams, stored, cell, pworld, tmp / f"v{k}", detector=VisibilityGatedDetector(sim, None),
                                     n_poses=args.poses, seed=k, progress=False)
            sim.close()
            vr = rep.verify
            rows.append({"case": case, "victim": None if case == "none" else victim, "verdict": vr.verdict,
                         "moved": vr.moved, "m2": {n: (None if c.status == "not_seen" else c.mahalanobis2)
                                                   for n, c in vr.cameras.items()}})
            print(case, victim, vr.verdict, vr.moved, {n: None if m is None else round(m, 1) for n, m in rows[-1]["m2"].items()},
                  f"{time.time() - t0:.0f} s", file=sys.stderr, flush=True)
    thr = chi2_isf_6(1e-3)
    lines = [f"# bench_verify_rendered\n\nRendered check of `calibgraph verify` (MuJoCo default cell, three L515 at 3 m, "
             f"real detector): stored result from a rendered {args.cal_poses}-pose capture (pixel sigma "
             f"{stored.pixel_sigma_px:.3f} px); per trial a rendered verify capture of {args.poses} poses "
             f"planned from the stored result, new image noise and FK error; alpha 0.001 per camera (m2 > {thr:.1f}). "
             f"{args.trials} trials per case. Run time {time.time() - t0:.0f} s.\n",
             "| case | trials | bumped camera called moved | another camera called moved | m2 of unmoved cameras (median, max) |",
             "|---|---|---|---|---|"]
    for case in ("none", "2 mm", "0.2 deg"):
        rs = [r for r in rows if r["case"] == case]
        unmoved = [m for r in rs for n, m in r["m2"].items() if m is not None and n != r["victim"]]
        other = sum(bool(set(r["moved"]) - {r["victim"]}) for r in rs)
        det = "-" if case == "none" else f"{sum(r['victim'] in r['moved'] for r in rs)} / {len(rs)}"
        lines.append(f"| {case} | {len(rs)} | {det} | {other} / {len(rs)} | {np.median(unmoved):.1f}, {max(unmoved):.1f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_verify_rendered.md").write_text(text)
    (args.out / "bench_verify_rendered.json").write_text(json.dumps(rows, indent=1))
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
