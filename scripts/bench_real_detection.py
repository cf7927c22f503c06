#!/usr/bin/env python
"""Detection on real board images: calibgraph against OpenCV's own detectors, image by image.

Sets (each skipped with a printed reason when its data is absent):

* ``rct_charuco``: ../shared/datasets/rct_static_camera_charuco (industrial_calibration's ChArUco set,
  AVT 1600x1200, 16 images, 5x7 squares DICT_6X6_250);
* ``mchec``: ../shared/datasets/mchec_medium_workcell (MC-HEC's 4 x 251 rendered-cell frames of 1920x1080,
  a 4x3-corner checkerboard of 50 mm, mostly without the board; every ``--mchec-stride``-th capture);
* ``ic_wrist_10x10``, ``ic_noise_10x10``: industrial_calibration's examples/data (a wrist camera's 15
  views of a 10x10 modified circle grid, 640x480; one image of the same kind), extracted from the
  fetched mirror (``--ic-repo``, a bare git directory) or read from ``--ic-data`` (its examples/data);
* ``opencv_left``, ``opencv_right``: OpenCV's samples/data/left*.jpg, right*.jpg (640x480, 9x6 inner
  corners; square 25 mm as their left_intrinsics.yml says), from ``--opencv-samples`` (default: Debian's
  opencv-doc examples/data, or a fetched opencv/opencv mirror);
* ``opencv_extra``: testdata/cv/cameracalibration of a fetched opencv/opencv_extra mirror
  (``--opencv-extra``): too large to fetch here (1.5 GB), so skipped unless given.

Per image: the board found (or not) by calibgraph (``detect_image``, defaults), OpenCV's classic
detector (findChessboardCorners with adaptive threshold, normalisation and the fast check, then
cornerSubPix), SB (findChessboardCornersSB, exhaustive + accuracy) and, where the board is one, OpenCV's
CharucoDetector (>= 4 corners) or findCirclesGrid (symmetric grid, then with clustering); the time of
each; and whether a found board is a false detection: its points' RMS residual against the best
homography of the planar grid, after the best single radial (division-model) term about the image
centre, above 1 px (real corners here fit to 0.05-0.8 px; one corner put on the wrong square costs
several px), or, on a ChArUco board (a known correspondence: the markers' ids), a checkerboard
detector's grid that misses by more than 1 px a corner the ids place (a grid of another part of
the board). For single-camera sets ``calibgraph intrinsics`` is run on the images: images used, RMS,
fx and its 1-sigma (no truth: OpenCV's shipped left_intrinsics.yml is shown beside it as a reference).

Usage: nice -n 10 python scripts/bench_real_detection.py [--sets a,b] [--shared DIR] [--ic-repo GITDIR]
       [--ic-data DIR] [--opencv-samples DIR] [--opencv-extra DIR] [--mchec-stride N] [--work DIR] [--out DIR]
Writes OUT/bench_real_detection.{json,md} (OUT defaults to scripts/results).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from calibgraph.core.camera import Intrinsics  # noqa: E402
from calibgraph.core.targets import Target  # noqa: E402
from calibgraph.detect.search import detect_image  # noqa: E402

FALSE_RMS_PX = 1.0
ALL_SETS = ("rct_charuco", "mchec", "ic_wrist_10x10", "ic_noise_10x10", "opencv_left", "opencv_right", "opencv_extra",
            "rwhe_kuka_1", "rwhe_kuka_2", "rwhe_kuka_3")
RWHE_MIRROR = Path("/work/.mirror/ihtishamaliktk+RWHE-Calib/repo")
# RWHE-Calib's boards: (rows, cols) inner corners and the square (getSquareSize4dataset.m), as bench_heldout.py uses them
# (kuka_3's board has 9 x 12 squares with ArUco markers in its white squares: 8 x 11 inner corners)
RWHE_BOARDS = {"kuka_1": (17, 28, 0.020), "kuka_2": (17, 24, 0.015), "kuka_3": (8, 11, 0.060)}
IC_MIRROR = Path("/work/.mirror/ros-industrial+industrial_calibration/repo")
OPENCV_MIRROR = Path("/work/.mirror/opencv+opencv/repo")
OPENCV_EXTRA_MIRROR = Path("/work/.mirror/opencv+opencv_extra/repo")
DEBIAN_OPENCV_SAMPLES = Path("/usr/share/doc/opencv-doc/examples/data")
LEFT_INTRINSICS_FX = None  # read from left_intrinsics.yml when present


# ---------------------------------------------------------------- data sets

def _extract(git_dir: Path, prefix: str, dest: Path) -> Path | None:
    """Files under ``prefix`` of a bare git mirror's HEAD written below ``dest`` (once)."""
    if not (git_dir / "HEAD").is_file():
        return None
    out = dest / prefix
    if out.is_dir() and any(out.rglob("*")):
        return out
    names = subprocess.run(["git", "--git-dir", str(git_dir), "ls-tree", "-r", "--name-only", "HEAD", prefix],
                           capture_output=True, text=True, check=True).stdout.split()
    for n in names:
        p = dest / n
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(subprocess.run(["git", "--git-dir", str(git_dir), "show", f"HEAD:{n}"], capture_output=True,
                                     check=True).stdout)
    return out if names else None


def _dataset_set(name, root, stride=1):
    from calibgraph.io.layouts import load_dataset

    ds = load_dataset(root)
    caps = sorted({v.capture for v in ds.views})[::stride]
    keep = set(caps)
    items = [(Path(ds.root) / v.image, ds.cameras.get(v.camera), v.camera) for v in ds.views
             if v.image and v.capture in keep]
    return dict(name=name, target=ds.target, items=items, single=len(ds.cameras) == 1, root=str(root))


def load_sets(args) -> tuple:
    sets, skipped = [], {}
    wanted = args.sets.split(",") if args.sets else ALL_SETS
    shared = Path(args.shared)
    work = Path(args.work)
    if "rct_charuco" in wanted:
        root = shared / "datasets" / "rct_static_camera_charuco"
        if (root / "cal_data.yaml").is_file():
            sets.append(_dataset_set("rct_charuco", root))
        else:
            skipped["rct_charuco"] = f"{root} is missing"
    if "mchec" in wanted:
        root = shared / "datasets" / "mchec_medium_workcell"
        if root.is_dir():
            s = _dataset_set("mchec", root, args.mchec_stride)
            s["note"] = f"every {args.mchec_stride}-th capture of 251, 4 cameras"
            sets.append(s)
        else:
            skipped["mchec"] = f"{root} is missing"
    ic = Path(args.ic_data) if args.ic_data else _extract(Path(args.ic_repo), "examples/data", work / "ic")
    for name, sub in (("ic_wrist_10x10", "test_set_10x10"), ("ic_noise_10x10", "noise_qualification")):
        if name not in wanted:
            continue
        if ic is None or not (ic / sub).is_dir():
            skipped[name] = f"no industrial_calibration examples/data (fetch ros-industrial/industrial_calibration: {args.ic_repo})"
            continue
        if name == "ic_wrist_10x10":
            sets.append(_dataset_set(name, ic / sub))
        else:
            import yaml

            from calibgraph.io.peer_rct import rct_target

            cfg = yaml.safe_load((ic / sub / "cal_data.yaml").read_text())
            imgs = sorted({(ic / sub / d["image"]) for d in cfg["data"]})
            K = np.array([[cfg["intrinsics"]["fx"], 0, cfg["intrinsics"]["cx"]], [0, cfg["intrinsics"]["fy"],
                                                                                 cfg["intrinsics"]["cy"]], [0, 0, 1.0]])
            intr = Intrinsics(K=K, dist=np.zeros(5), width_px=640, height_px=480)
            sets.append(dict(name=name, target=rct_target(cfg["target_finder"]), items=[(p, intr, "camera") for p in imgs],
                             single=False, root=str(ic / sub), note="one image (the set repeats it)"))
    samples = None
    for cand in ([Path(args.opencv_samples)] if args.opencv_samples else []) + [DEBIAN_OPENCV_SAMPLES]:
        if (cand / "left01.jpg").is_file():
            samples = cand
            break
    if samples is None:
        samples = _extract(OPENCV_MIRROR, "samples/data", work / "opencv")
    for name, side in (("opencv_left", "left"), ("opencv_right", "right")):
        if name not in wanted:
            continue
        imgs = sorted(samples.glob(f"{side}[0-9][0-9].jpg")) if samples else []
        if not imgs:
            skipped[name] = ("no OpenCV samples/data (apt-get install opencv-doc, or --opencv-samples DIR; "
                             "opencv/opencv is too large to fetch here)")
            continue
        t = Target(kind="checkerboard", rows=6, cols=9, pitch_m=0.025)
        sets.append(dict(name=name, target=t, items=[(p, None, side) for p in imgs], single=True, root=str(samples)))
    if "opencv_extra" in wanted:
        extra = Path(args.opencv_extra) if args.opencv_extra else _extract(OPENCV_EXTRA_MIRROR,
                                                                         "testdata/cv/cameracalibration", work / "cvx")
        skipped["opencv_extra"] = ("opencv/opencv_extra is not here (1.5 GB: over the fetch limit); its "
                                   "checkerboard_marker_*.png are not measured" if extra is None else
                                   f"{extra}: no spec table for its images in this bench yet")
    for name in (n for n in wanted if n.startswith("rwhe_")):
        kuka = name[len("rwhe_"):]
        root = _extract(Path(args.rwhe_repo), f"Datasets/{kuka}", work / "rwhe") if kuka in RWHE_BOARDS else None
        imgs = sorted(p for p in root.iterdir() if p.suffix.lower() in (".png", ".bmp", ".jpg")) if root else []
        if not imgs:
            skipped[name] = f"no RWHE-Calib Datasets/{kuka} (fetch ihtishamaliktk/RWHE-Calib: {args.rwhe_repo})"
            continue
        rows, cols, pitch = RWHE_BOARDS[kuka]
        t = Target(kind="checkerboard", rows=rows, cols=cols, pitch_m=pitch)
        sets.append(dict(name=name, target=t, items=[(p, None, kuka) for p in imgs], single=True, root=str(root),
                         note="a KUKA arm's eye-in-hand camera, 1928x1208, no intrinsics given"))
    return sets, skipped, samples


# ---------------------------------------------------------------- detectors

def plane_rms(uv: np.ndarray, P: np.ndarray, shape) -> float:
    """RMS residual (px) of the best homography from board points to pixels after the best single
    radial division-model term about the image centre (focal length ~ the image width)."""
    h, w = shape[:2]
    c, f = np.array([(w - 1) / 2, (h - 1) / 2]), float(w)
    best = np.inf
    for lam in np.linspace(-0.6, 0.6, 61):
        x = (uv - c) / f
        u = c + f * x / (1.0 + lam * np.sum(x * x, axis=1, keepdims=True))
        H, _ = cv2.findHomography(P[:, :2], u, 0)
        if H is None:
            continue
        q = np.column_stack([P[:, :2], np.ones(len(P))]) @ H.T
        r = np.sqrt(np.mean(np.sum((q[:, :2] / q[:, 2:3] - u) ** 2, axis=1)))
        best = min(best, float(r))
    return best


def _grid_points(rows, cols, pitch=1.0, acircles=False):
    i, j = np.divmod(np.arange(rows * cols), cols)
    x = (2 * j + i % 2) if acircles else j
    return np.column_stack([x * pitch, i * pitch, np.zeros(rows * cols)]).astype(float)


def run_detectors(grey, target: Target, intr):
    """{detector: dict(found, n, time_s, plane_rms_px)} for one image."""
    out = {}
    t0 = time.perf_counter()
    d = detect_image(grey, target, intr)
    rec = dict(found=bool(d.ok), n=int(d.n_found if d.ok else 0), time_s=time.perf_counter() - t0,
               why="" if d.ok else d.reason[:160])
    if d.ok:
        rec["plane_rms_px"] = plane_rms(d.uv_px, target.points_board_m[d.ids], grey.shape)
        rec["upscale"] = int(d.upscale)
    out["calibgraph"] = rec
    uv_cg = d.uv_px if d.ok else None
    if target.kind in ("checkerboard", "charuco"):
        size = (target.cols, target.rows)
        P = [_grid_points(target.rows, target.cols), _grid_points(target.cols, target.rows)]
        t0 = time.perf_counter()
        flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        ok, c = cv2.findChessboardCorners(grey, size, flags=flags)
        if ok:
            c = cv2.cornerSubPix(grey, c, (5, 5), (-1, -1), (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 1e-3))
        out["classic"] = _rec(ok, c, P, grey, time.perf_counter() - t0, uv_cg)
        t0 = time.perf_counter()
        ok, c = cv2.findChessboardCornersSB(grey, size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
                                            | cv2.CALIB_CB_NORMALIZE_IMAGE)
        out["sb"] = _rec(ok, c, P, grey, time.perf_counter() - t0, uv_cg)
    if target.kind == "charuco":
        t0 = time.perf_counter()
        det = cv2.aruco.CharucoDetector(target.cv_charuco_board())
        cc, cid, _, _ = det.detectBoard(grey)
        ok = cid is not None and len(cid) >= 4
        rec = dict(found=bool(ok), n=int(0 if cid is None else len(cid)), time_s=time.perf_counter() - t0)
        if ok:
            ids = np.asarray(cid).reshape(-1)
            rec["plane_rms_px"] = plane_rms(np.asarray(cc, float).reshape(-1, 2), target.points_board_m[ids], grey.shape)
        out["charuco"] = rec
    if target.kind in ("circles", "acircles", "modified_circles"):
        acirc = target.kind == "acircles"
        flags = cv2.CALIB_CB_ASYMMETRIC_GRID if acirc else cv2.CALIB_CB_SYMMETRIC_GRID
        t0 = time.perf_counter()
        ok, c = cv2.findCirclesGrid(grey, (target.cols, target.rows), flags=flags)
        if not ok:
            ok, c = cv2.findCirclesGrid(grey, (target.cols, target.rows), flags=flags | cv2.CALIB_CB_CLUSTERING)
        P = [_grid_points(target.rows, target.cols, acircles=acirc)]
        if not acirc:
            P.append(_grid_points(target.cols, target.rows))
        out["circles"] = _rec(ok, c, P, grey,
                              time.perf_counter() - t0, uv_cg)
    return out


def _rec(ok, c, layouts, grey, dt, uv_cg):
    """One OpenCV detector's record; ``layouts``: the board points in each order OpenCV may return
    the grid in (row by row along either side: SB often takes the other one)."""
    rec = dict(found=bool(ok), n=int(len(layouts[0]) if ok else 0), time_s=dt)
    if ok:
        uv = np.asarray(c, float).reshape(-1, 2)
        rec["plane_rms_px"] = min(plane_rms(uv, P, grey.shape) for P in layouts)
        if uv_cg is not None and len(uv_cg):
            # the same corners? each of calibgraph's corners' distance to this detector's nearest
            d = np.linalg.norm(uv_cg[:, None] - uv[None], axis=-1).min(axis=1)
            rec["vs_calibgraph_px"] = float(np.median(d))
            rec["vs_calibgraph_max_px"] = float(d.max())
    return rec


def is_false(rec: dict, kind: str) -> bool:
    """A found board off the plane (``FALSE_RMS_PX``) or, on a ChArUco board, whose grid misses a
    corner the markers' ids place (a checkerboard detector's grid of another part of the board)."""
    if rec.get("plane_rms_px", 0.0) > FALSE_RMS_PX:
        return True
    return kind == "charuco" and rec.get("vs_calibgraph_max_px", 0.0) > FALSE_RMS_PX


# ---------------------------------------------------------------- intrinsics

def run_intrinsics(s, work: Path) -> dict:
    """``calibgraph intrinsics`` on the set's images (symlinked into a fresh folder)."""
    import yaml

    d = work / f"intr_{s['name']}"
    imgs = d / "images"
    imgs.mkdir(parents=True, exist_ok=True)
    for p, _, _ in s["items"]:
        link = imgs / p.name
        if not link.exists():
            link.symlink_to(p.resolve())
    (d / "target.yaml").write_text(yaml.safe_dump({"target": s["target"].to_dict()}))
    out = d / "camera.yaml"
    if out.exists():
        out.unlink()
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "calibgraph", "intrinsics", str(imgs), "--target", str(d / "target.yaml"),
                           "--out", str(out)], capture_output=True, text=True, cwd=str(REPO), timeout=3600)
    rec = dict(exit=proc.returncode, time_s=time.perf_counter() - t0, line=(proc.stdout.strip().splitlines() or [""])[-1],
               stderr=proc.stderr.strip()[-400:])
    for ln in proc.stdout.splitlines():
        if ln.strip().startswith("fx "):
            rec["fx_line"] = ln.strip()
    if proc.returncode == 0 and out.is_file():
        cam = yaml.safe_load(out.read_text())
        rec["camera_file"] = cam
    return rec


# ---------------------------------------------------------------- report

def summarise(records: list, kind: str) -> dict:
    dets = sorted({k for r in records for k in r["detectors"]})
    out = {"images": len(records)}
    for k in dets:
        rs = [r["detectors"][k] for r in records if k in r["detectors"]]
        found = [x for x in rs if x["found"]]
        false = [x for x in found if is_false(x, kind)]
        out[k] = dict(found=len(found), false=len(false), points=int(sum(x["n"] for x in found)),
                      median_time_s=float(np.median([x["time_s"] for x in rs])) if rs else None,
                      max_time_s=float(max(x["time_s"] for x in rs)) if rs else None,
                      median_plane_rms_px=float(np.median([x["plane_rms_px"] for x in found])) if found else None,
                      max_plane_rms_px=float(max(x["plane_rms_px"] for x in found)) if found else None,
                      median_vs_calibgraph_px=(float(np.median([x["vs_calibgraph_px"] for x in found
                                                                 if "vs_calibgraph_px" in x]))
                                               if any("vs_calibgraph_px" in x for x in found) else None))
    return out


def markdown(result: dict) -> str:
    L = ["# Real-image detection: calibgraph against OpenCV's detectors", "",
         f"Made by `{result['invocation']}` ({result['date']}, OpenCV {result['opencv']}, a shared 2-core machine: "
         "times are indicative). A found board is a *false detection* when its points' RMS residual against the best "
         f"homography of the planar grid, after one radial term about the image centre, exceeds {FALSE_RMS_PX} px, or "
         "(ChArUco boards) when a checkerboard detector's grid misses a corner the markers' ids place by more than that. "
         "`vs cg` is the median distance of calibgraph's corners to that detector's nearest one where both found "
         "the board (calibgraph refines corners by its board fit, so a few tenths of a pixel are expected).", ""]
    if result.get("findings"):
        L += ["## Findings", ""] + [f"- {f}" for f in result["findings"]] + [""]
    for name, s in result["sets"].items():
        L += [f"## {name}", "", f"{s['description']}" + (f" (measured by `{s['merged_from']}`)" if s.get("merged_from")
                                                        else ""), ""]
        summ = s["summary"]
        L += ["| detector | boards found | of images | false | points | median time [s] | max time [s] | "
              "median / max plane RMS [px] | vs cg [px] |", "|---|---|---|---|---|---|---|---|---|"]
        for k, v in summ.items():
            if k == "images":
                continue
            f = (lambda x, p=3: "-" if x is None else f"{x:.{p}f}")
            L.append(f"| {k} | {v['found']} | {summ['images']} | {v['false']} | {v['points']} | {f(v['median_time_s'])} | "
                     f"{f(v['max_time_s'])} | {f(v['median_plane_rms_px'])} / {f(v['max_plane_rms_px'])} | "
                     f"{f(v['median_vs_calibgraph_px'])} |")
        kind = s.get("kind", "")
        for valid in (True, False):
            missed = [r for r in s["images"] if r["detectors"] and not r["detectors"]["calibgraph"]["found"]
                      and any(v["found"] and is_false(v, kind) != valid for k, v in r["detectors"].items()
                              if k != "calibgraph")]
            what = "a board (not a false detection)" if valid else "only a false detection"
            L += ["", f"Images where an OpenCV detector found {what} and calibgraph found none: {len(missed)}"
                  + ("" if not missed else ": " + "; ".join(
                      f"{r['camera']}/{Path(r['image']).name} ("
                      + ", ".join(f"{k} {v.get('plane_rms_px', 0):.2f} px" for k, v in r["detectors"].items()
                                  if v["found"]) + f"; calibgraph: {r['detectors']['calibgraph']['why'][:90]})"
                      for r in missed[:12]))]
        if "intrinsics" in s:
            i = s["intrinsics"]
            L += ["", f"`calibgraph intrinsics` (exit {i['exit']}, {i['time_s']:.0f} s): {i['line']}"]
            if "fx_line" in i:
                L.append(f"  {i['fx_line']}")
            if s.get("reference"):
                L.append(f"  reference (not truth): {s['reference']}")
        L.append("")
    if result["skipped"]:
        L += ["## Not measured", ""] + [f"- {k}: {v}" for k, v in result["skipped"].items()] + [""]
    return "\n".join(L)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="", help=f"comma-separated subset of {','.join(ALL_SETS)}")
    ap.add_argument("--shared", default=str(REPO.parent / "shared"))
    ap.add_argument("--ic-repo", default=str(IC_MIRROR), help="bare git directory of industrial_calibration")
    ap.add_argument("--ic-data", default="", help="industrial_calibration's examples/data folder (instead of the mirror)")
    ap.add_argument("--rwhe-repo", default=str(RWHE_MIRROR), help="bare git directory of RWHE-Calib")
    ap.add_argument("--opencv-samples", default="", help="OpenCV's samples/data folder (left01.jpg ...)")
    ap.add_argument("--opencv-extra", default="", help="opencv_extra's testdata/cv/cameracalibration folder")
    ap.add_argument("--mchec-stride", type=int, default=4, help="every n-th capture of the MC-HEC recording")
    ap.add_argument("--no-intrinsics", action="store_true")
    ap.add_argument("--merge", default="", help="a previous run's JSON whose sets this run does not measure are kept")
    ap.add_argument("--work", default="/tmp/calibgraph_bench_real")
    ap.add_argument("--out", default=str(REPO / "scripts" / "results"))
    ap.add_argument("--from-json", default="", help="only rewrite the Markdown of a saved JSON (and its notes)")
    args = ap.parse_args()
    if args.from_json:
        result = json.loads(Path(args.from_json).read_text())
        Path(args.from_json).with_suffix(".md").write_text(markdown(result))
        return
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    sets, skipped, samples = load_sets(args)
    for k, v in skipped.items():
        print(f"skipped {k}: {v}", flush=True)
    result = dict(invocation="python scripts/bench_real_detection.py " + " ".join(sys.argv[1:]),
                  date=time.strftime("%Y-%m-%d"), opencv=cv2.__version__, sets={}, skipped=skipped)
    for s in sets:
        t = s["target"]
        desc = (f"{len(s['items'])} images from {s['root']}; target {t.kind} {t.rows}x{t.cols} points, pitch "
                f"{t.pitch_m * 1e3:g} mm" + (f" ({s['note']})" if s.get("note") else ""))
        print(f"{s['name']}: {desc}", flush=True)
        recs = []
        for k, (path, intr, cam) in enumerate(s["items"]):
            grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if grey is None:
                recs.append(dict(image=str(path), camera=cam, unreadable=True, detectors={}))
                continue
            dets = run_detectors(grey, t, intr)
            recs.append(dict(image=str(path), camera=cam, detectors=dets))
            if (k + 1) % 20 == 0:
                print(f"  {k + 1}/{len(s['items'])}", flush=True)
        entry = dict(description=desc, kind=t.kind, summary=summarise([r for r in recs if r["detectors"]], t.kind),
                     images=recs)
        if s["single"] and not args.no_intrinsics:
            entry["intrinsics"] = run_intrinsics(s, work)
            if s["name"] == "opencv_left" and samples is not None and (samples / "left_intrinsics.yml").is_file():
                fs = cv2.FileStorage(str(samples / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
                K = fs.getNode("camera_matrix").mat()
                entry["reference"] = (f"OpenCV's shipped left_intrinsics.yml (its own calibration of 13 of these "
                                      f"images, aspect ratio fixed): fx {K[0, 0]:.2f}, cx {K[0, 2]:.2f}, cy {K[1, 2]:.2f}")
        result["sets"][s["name"]] = entry
        for k, v in entry["summary"].items():
            if k != "images":
                print(f"  {k}: {v['found']}/{entry['summary']['images']} found, {v['false']} false, "
                      f"median {v['median_time_s']:.3f} s", flush=True)
        if "intrinsics" in entry:
            print(f"  intrinsics: {entry['intrinsics']['line']}", flush=True)
    if args.merge:
        old = json.loads(Path(args.merge).read_text())
        for name, entry in old["sets"].items():
            if name not in result["sets"]:
                result["sets"][name] = dict(entry, merged_from=old.get("invocation", args.merge))
                result["skipped"].pop(name, None)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "bench_real_detection"
    (out / f"{stem}.json").write_text(json.dumps(result, indent=1, default=str))
    (out / f"{stem}.md").write_text(markdown(result))
    print(f"wrote {out / stem}.md and .json")


if __name__ == "__main__":
    main()
