"""Worker of scripts/bench_detect_prints.py --real: detects the real sets with the calibgraph of the tree
given (argv: TREE OUT.json SHARED_DATASETS TMP), cold (fresh copies, no detection cache), and writes every
detection (ids, corners) with the CPU and wall seconds of each set. Not a test, not a module."""

import glob
import json
import os
import shutil
import sys
import tempfile
import time

tree, out, shared, tmp = sys.argv[1:5]
sys.path.insert(0, tree)

import numpy as np  # noqa: E402

import calibgraph  # noqa: E402

assert calibgraph.__file__.startswith(os.path.realpath(tree)) or calibgraph.__file__.startswith(tree), calibgraph.__file__
from calibgraph.core.targets import Target  # noqa: E402
from calibgraph.detect.dataset import dataset_detector  # noqa: E402
from calibgraph.detect.search import detect_image  # noqa: E402
from calibgraph.io.layouts import load_dataset  # noqa: E402
from calibgraph.detect.guided_dataset import GuidedDatasetDetector  # noqa: E402
from calibgraph.solver.solve.batch import solve  # noqa: E402

res = {}


def rec(d):
    return {"ok": bool(d.ok), "ids": [int(i) for i in d.ids], "uv": np.round(d.uv_px, 6).tolist()}


def timed(name, fn):
    t0, c0 = time.perf_counter(), time.process_time()
    r = fn()
    res[name] = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0, "dets": r}


def copy(name):
    d = tempfile.mkdtemp(prefix="snap_", dir=tmp)
    shutil.copytree(f"{shared}/{name}", f"{d}/{name}")
    return f"{d}/{name}"


for name, pitch, pat in (("visp_eye_in_hand_2022", 0.0262, "image-*.png"),
                         ("visp_eye_in_hand_2025", 0.0236, "franka_image-*.png")):
    files = sorted(glob.glob(f"{shared}/{name}/{pat}"))
    if files:
        t = Target(kind="checkerboard", rows=6, cols=9, pitch_m=pitch)
        timed(name, lambda: {os.path.basename(f): rec(detect_image(f, t)) for f in files})
if os.path.isdir(f"{shared}/rct_static_camera_charuco"):
    ds = load_dataset(copy("rct_static_camera_charuco"))
    timed("rct_charuco_blind", lambda: {f"{k[0]}/{k[1]}": rec(v) for k, v in
                                        dataset_detector(ds, cache=False, progress=False, fail_fast=True).run().items()})
if os.path.isdir(f"{shared}/mchec_medium_workcell"):
    ds = load_dataset(copy("mchec_medium_workcell"))
    timed("mchec_guided (solve's detection)", lambda: {f"{k[0]}/{k[1]}": rec(v) for k, v in
                                                      GuidedDatasetDetector(ds, progress=False, cache=False, coarse_solve=solve).run().items()})
    ds = load_dataset(copy("mchec_medium_workcell"))
    views = {(v.camera, v.capture) for v in ds.views if v.capture % 25 == 0}
    timed("mchec_blind every 25th capture", lambda: {f"{k[0]}/{k[1]}": rec(v) for k, v in dataset_detector(
        ds, cache=False, progress=False, fail_fast=True, views=views).run().items()})
with open(out, "w") as f:
    json.dump(res, f)
