#!/usr/bin/env python
"""Public real hand-eye sets, each written as a ``calibgraph-dataset/1`` folder (issue 45, item 8).

The data layer of ``scripts/bench_real_corpus.py``: one record per set (where it comes from, the
robot, the mode, the camera, the board as calibgraph counts it, the poses, whether joint angles are
recorded, any published hand-eye result) and a converter that writes the set into a work folder
(images copied, ``dataset.yaml``, ``captures/NNNNNN.json`` with ``T_base_flange`` in metres and
``q_rad`` where the arm model was verified against the recorded poses). Nothing is written into the
snapshots (``/work/.mirror/OWNER+NAME/repo``, bare git: read with ``git show REV:PATH``) nor into
``../shared``; the sets' data and code are never committed.

    python scripts/real_sets.py list                      # name, available?, why not
    python scripts/real_sets.py show NAME                 # the record
    python scripts/real_sets.py write NAME --out DIR      # the dataset folder (DIR must be new or empty)

Each converter's pose convention (direction, units, rotation parameters, row/column order) was
checked by solving the written folder with ``calibgraph solve`` (reprojection RMS of a few px at most
and a plausible hand-eye translation; the wrong direction or unit gives tens of px or a refusal):
the measured figures are in ``VERIFIED`` below and in ``/work/data/real/CATALOG.md``.

Sets in ``../shared/datasets`` that a layout reader of calibgraph reads (MC-HEC, RCT) are written by
reading them with :func:`calibgraph.io.layouts.load_dataset` and writing the same captures as a
calibgraph dataset (images copied); the two ViSP samples are listed only: the ViSP layout reader
(``calibgraph/io/peer_visp.py``) reads them where they are.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from calibgraph.core.camera import Intrinsics  # noqa: E402
from calibgraph.core.problem import Capture  # noqa: E402
from calibgraph.core.targets import Target  # noqa: E402
from calibgraph.io.dataset import write_capture, write_header  # noqa: E402

MIRROR = Path("/work/.mirror")
SHARED = REPO.parent / "shared" / "datasets"  # /work/wt/shared -> /work/shared; /work/main/../shared
MARKER = ".real_sets.json"  # written last: the folder is complete and made by this script
FORBIDDEN = (MIRROR, Path("/work/shared"))


class SetError(Exception):
    """One line saying why a set cannot be written (the CLI prints it and exits 2)."""


# ---------------------------------------------------------------------------------------------
# records
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RealSet:
    """One public real hand-eye set.

    ``repo`` is GitHub's owner/name ('' for a set that lives only in ../shared); ``commit`` the
    revision the data is read at (None: the snapshot's HEAD); ``path`` the folder in the repository
    (or in ../shared/datasets). ``target`` is a calibgraph target spec (rows/cols count points,
    docs/formats.md). ``reference`` is a published hand-eye result converted to calibgraph's frames
    (``T_flange_cam`` eye-in-hand, ``T_base_cam`` eye-to-hand, metres) with its source, or None.
    ``writer`` is None for a set listed but not converted here (``why_listed`` says why).
    """

    name: str
    repo: str
    commit: str | None
    path: str
    licence: str
    robot: str
    mode: str
    camera: str
    image_size: tuple
    target: dict
    n_poses: int
    joint_angles: bool
    reference: dict | None = None
    writer: Callable | None = None
    notes: str = ""
    why_listed: str = ""
    group: str = ""  # sets that are sessions of one rig share a group
    intrinsics: str = ""  # what the dataset.yaml gives: 'none (unknown)', 'factory', 'calibration'

    @property
    def git_dir(self) -> Path:
        return MIRROR / self.repo.replace("/", "+") / "repo"

    def as_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("name", "repo", "commit", "path", "licence", "robot", "mode", "camera",
                                          "image_size", "target", "n_poses", "joint_angles", "reference", "notes",
                                          "why_listed", "group", "intrinsics")}
        d["image_size"] = list(self.image_size)
        return d


# ---------------------------------------------------------------------------------------------
# git snapshot access (bare snapshots, no work tree)
# ---------------------------------------------------------------------------------------------
def _git(git_dir: Path, *args) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "--git-dir", str(git_dir), *args], capture_output=True)


def git_show(git_dir: Path, rev: str, path: str) -> bytes:
    r = _git(git_dir, "show", f"{rev}:{path}")
    if r.returncode != 0:
        raise SetError(f"{git_dir}: {rev}:{path} is not in the snapshot ({r.stderr.decode().strip()[:120]})")
    return r.stdout


def git_ls(git_dir: Path, rev: str, prefix: str) -> list:
    r = _git(git_dir, "ls-tree", "-r", "--name-only", rev, prefix)
    if r.returncode != 0:
        raise SetError(f"{git_dir}: cannot list {rev}:{prefix} ({r.stderr.decode().strip()[:120]})")
    return [n for n in r.stdout.decode().split("\n") if n]


def git_head(git_dir: Path) -> str:
    r = _git(git_dir, "rev-parse", "HEAD")
    return r.stdout.decode().strip() if r.returncode == 0 else ""


def extract(git_dir: Path, prefix: str, dest: Path, rev: str = "HEAD") -> str:
    """Copy ``prefix`` of the snapshot at ``rev`` into ``dest`` (once: a ``.complete`` file marks it
    done); '' or why it could not (no snapshot, files absent from it: over 4 MiB or LFS)."""
    if (dest / ".complete").exists():
        return ""
    if not git_dir.exists():
        return f"no snapshot at {git_dir} (fetch the repository first)"
    try:
        names = git_ls(git_dir, rev, prefix)
    except SetError as e:
        return str(e)
    if not names:
        return f"{git_dir}: nothing under {rev}:{prefix}"
    missing = []
    for name in names:
        out = dest / name[len(prefix):].lstrip("/")
        out.parent.mkdir(parents=True, exist_ok=True)
        r = _git(git_dir, "show", f"{rev}:{name}")
        if r.returncode != 0:
            missing.append(name)
            continue
        out.write_bytes(r.stdout)
    if missing:
        return f"{len(missing)} files absent from the snapshot (first: {missing[0]})"
    (dest / ".complete").write_text(git_head(git_dir) if rev == "HEAD" else rev)
    return ""


# ---------------------------------------------------------------------------------------------
# writing a dataset folder
# ---------------------------------------------------------------------------------------------
def _check_out(out: Path, name: str) -> bool:
    """True when ``out`` already holds this set, complete (nothing to do). Refuses a folder inside
    the snapshots or ../shared, and a non-empty folder this script did not finish for this set."""
    out = Path(out)
    r = out.resolve()
    for f in FORBIDDEN:
        if r == f.resolve() or f.resolve() in r.parents:
            raise SetError(f"{out}: inside {f}; write the set into a work folder (e.g. /work/data/real/{name})")
    if not out.exists():
        return False
    if not out.is_dir():
        raise SetError(f"{out}: is a file; give a new or empty folder")
    marker = out / MARKER
    if marker.exists():
        try:
            made = json.loads(marker.read_text())
        except (OSError, ValueError):
            made = {}
        if made.get("set") == name:
            return True
        raise SetError(f"{out}: holds the set {made.get('set')!r}, not {name!r}; give another --out")
    if any(out.iterdir()):
        raise SetError(f"{out}: not empty and not a finished copy of {name!r}; give a new or empty folder "
                       "(a half-written copy of this script can be removed)")
    return False


class _Out:
    """Writes one calibgraph-dataset/1 folder: header first, then per capture its images and its
    capture file (the capture file last, as calibgraph capture does), the marker at the end."""

    def __init__(self, out: Path, rs: RealSet, target: Target, cameras: dict, mode: str, extra: dict | None = None):
        self.out, self.rs = Path(out), rs
        self.out.mkdir(parents=True, exist_ok=True)
        src = {"converter": "scripts/real_sets.py", "set": rs.name, "repo": rs.repo, "path": rs.path,
               "commit": rs.commit or (git_head(rs.git_dir) if rs.repo else ""), "licence": rs.licence}
        write_header(self.out, target, cameras, mode=mode, extra={"source": {**src, **(extra or {})}})
        self.n = 0

    def capture(self, index: int, T_base_flange: np.ndarray, images: dict, q_rad=None, detections: dict | None = None):
        """``images``: camera -> (bytes or a Path to copy, file extension)."""
        T = np.asarray(T_base_flange, float)
        if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise SetError(f"{self.rs.name}: capture {index}: not a 4x4 homogeneous pose")
        R = T[:3, :3]
        if abs(np.linalg.det(R) - 1) > 1e-4 or np.abs(R.T @ R - np.eye(3)).max() > 1e-4:
            raise SetError(f"{self.rs.name}: capture {index}: rotation not orthonormal (det {np.linalg.det(R):.6f})")
        views = {}
        for cam, (data, ext) in images.items():
            rel = f"images/{cam}/{index:06d}.{ext}"
            p = self.out / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            if isinstance(data, (bytes, bytearray)):
                p.write_bytes(data)
            else:
                shutil.copyfile(data, p)
            det = (detections or {}).get(cam)
            views[cam] = {"image": rel, "ids": None if det is None else det[0], "uv_px": None if det is None else det[1]}
        q = None if q_rad is None else np.asarray(q_rad, float)
        write_capture(self.out, Capture(index=int(index), T_base_flange=T, q_rad=q), views)
        self.n += 1

    def finish(self) -> Path:
        (self.out / MARKER).write_text(json.dumps({"set": self.rs.name, "captures": self.n}) + "\n")
        return self.out


def _pose(R, t_m) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, float)
    T[:3, 3] = np.asarray(t_m, float).ravel()
    return T


def _orthonormal(R) -> np.ndarray:
    """The nearest rotation (files printed with 6 decimals are orthonormal to ~1e-6 only)."""
    U, _, Vt = np.linalg.svd(np.asarray(R, float))
    R2 = U @ Vt
    if np.linalg.det(R2) < 0:
        U[:, -1] *= -1
        R2 = U @ Vt
    return R2


def _rotvec(rv) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(rv, float).ravel()).as_matrix()


def _euler(seq: str, angles, degrees: bool) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler(seq, np.asarray(angles, float).ravel(), degrees=degrees).as_matrix()


def _image_size(data: bytes) -> tuple:
    import cv2

    im = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    if im is None:
        raise SetError("an image of the set cannot be decoded")
    return int(im.shape[1]), int(im.shape[0])


def _need_snapshot(rs: RealSet) -> str:
    if not rs.git_dir.exists():
        return f"no snapshot at {rs.git_dir} (fetch github:{rs.repo} first)"
    rev = rs.commit or "HEAD"
    if _git(rs.git_dir, "cat-file", "-e", f"{rev}^{{commit}}").returncode != 0:
        return f"{rs.git_dir}: revision {rev} not in the snapshot"
    return ""


# ---------------------------------------------------------------------------------------------
# converters
# ---------------------------------------------------------------------------------------------
def _write_rwhe(rs: RealSet, out: Path) -> Path:
    """RWHE-Calib ``Datasets/kuka_N``: images 01.png.. and ``RobotPosesVec.txt``, one row-major
    ``T_base_flange`` (metres) per image, in file-name order; no intrinsics given."""
    rev = rs.commit or "HEAD"
    names = sorted(n for n in git_ls(rs.git_dir, rev, rs.path) if n.lower().endswith((".png", ".bmp")))
    poses = np.loadtxt(git_show(rs.git_dir, rev, f"{rs.path}/RobotPosesVec.txt").decode().splitlines()).reshape(-1, 4, 4)
    if len(poses) != len(names):
        raise SetError(f"{rs.name}: {len(poses)} poses for {len(names)} images")
    first = git_show(rs.git_dir, rev, names[0])
    w, h = _image_size(first)
    o = _Out(out, rs, Target.from_dict(rs.target), {"cam": Intrinsics.unknown(w, h)}, rs.mode)
    for k, (name, T) in enumerate(zip(names, poses)):
        data = first if k == 0 else git_show(rs.git_dir, rev, name)
        o.capture(k, _pose(_orthonormal(T[:3, :3]), T[:3, 3]), {"cam": (data, name.rsplit(".", 1)[1].lower())})
    return o.finish()


def _from_dataset(rs: RealSet, src: Path, out: Path) -> Path:
    """Any folder calibgraph's layout readers read (RCT, MC-HEC, ...), written as calibgraph-dataset/1:
    the same captures, intrinsics, target and mode; images copied; stored detections kept."""
    from calibgraph.io.layouts import load_dataset

    ds = load_dataset(src)
    o = _Out(out, rs, ds.target, dict(ds.cameras), ds.mode, extra={"read_by": "calibgraph.io.layouts.load_dataset"})
    by_cap = {}
    for v in ds.views:
        by_cap.setdefault(v.capture, []).append(v)
    for c in ds.captures:
        images, dets = {}, {}
        for v in by_cap.get(c.index, []):
            if v.image is None:
                continue
            p = Path(ds.root) / v.image
            images[v.camera] = (p, p.suffix.lstrip(".").lower() or "png")
            if v.ids is not None:
                dets[v.camera] = (v.ids, v.uv_px)
        o.capture(c.index, c.T_base_flange, images, q_rad=c.q_rad, detections=dets)
    if ds.solver:
        pass  # the peers' readers give no solver section; kept out on purpose (the defaults are what is measured)
    return o.finish()


def _write_ic(rs: RealSet, out: Path) -> Path:
    """industrial_calibration ``examples/data/<set>``: extracted to a temporary folder, read by
    calibgraph's RCT reader (the intrinsics the files give), written as a calibgraph dataset."""
    with tempfile.TemporaryDirectory(prefix=f"real_sets_{rs.name}_") as tmp:
        why = extract(rs.git_dir, rs.path, Path(tmp) / "raw", rev=rs.commit or "HEAD")
        if why:
            raise SetError(f"{rs.name}: {why}")
        return _from_dataset(rs, Path(tmp) / "raw", out)


def _write_shared(rs: RealSet, out: Path) -> Path:
    src = SHARED / rs.path
    if not src.exists():
        raise SetError(f"{rs.name}: {src} is not here")
    return _from_dataset(rs, src, out)


# Franka: libfranka's O_T_EE includes the hand's F_T_EE (the Franka Hand default: 0.1034 m along z,
# -45 deg about z); FK(q) of calibgraph's Franka model gives the flange F. Checked on all 36 poses:
# inv(FK(q)) @ O_T_EE equals this transform to 1e-4 mm / 1e-3 deg (VERIFIED).
F_T_EE_FRANKA_HAND = _pose(_euler("z", [-45.0], True), [0.0, 0.0, 0.1034])
FRANKA_SESSIONS = {  # session -> commit whose data/captured-data holds its 12 images and poses
    1: "9c23a7dad73855c755eacc914d10f98251d6d904",  # "manual data capture complete"
    2: "0e97c31cd22c8833ba688616df2fab1f99b81114",  # "faster auto mode" (also f909a5e)
    3: "0b9fe295adc20d3a147957f7d496f707aef46a32",  # "fine tuned verification"
}


def _franka_captures(rs: RealSet, session: int):
    from calibgraph.core.kinematics import franka_fk

    rev = FRANKA_SESSIONS[session]
    root = "data/captured-data"
    poses = sorted({n.split("/")[2] for n in git_ls(rs.git_dir, rev, root) if n.endswith("image.png")})
    for name in poses:
        d = json.loads(git_show(rs.git_dir, rev, f"{root}/{name}/data.json"))
        O_T_EE = np.asarray(d["O_T_EE"], float).reshape(4, 4)  # stored row by row (capture_data.py), not libfranka's column-major
        T = O_T_EE @ np.linalg.inv(F_T_EE_FRANKA_HAND)
        q = np.asarray(d["joint_pose"], float)
        D = np.linalg.inv(franka_fk(q)) @ T
        if np.linalg.norm(D[:3, 3]) > 1e-5 or np.abs(D[:3, :3] - np.eye(3)).max() > 1e-4:
            raise SetError(f"{rs.name}: {name}: FK(q) departs from the recorded flange pose by "
                           f"{np.linalg.norm(D[:3, 3]) * 1e3:.3f} mm; the arm model does not fit")
        img = git_show(rs.git_dir, rev, f"{root}/{name}/image.png")
        yield name, _pose(_orthonormal(T[:3, :3]), T[:3, 3]), q, img, d


def _write_franka(rs: RealSet, out: Path) -> Path:
    """kvasios/franka-handeye ``data/captured-data/pose_NN/{image.png,data.json}`` at the session's
    commit (the images were removed later): ``O_T_EE`` (16 numbers, row-major as the capture script
    writes them, metres), ``joint_pose`` (7, rad), the RealSense factory intrinsics."""
    sessions = [int(s) for s in rs.path.split(":", 1)[1].split(",")]
    o = None
    k = 0
    for s in sessions:
        for name, T, q, img, d in _franka_captures(rs, s):
            if o is None:
                K = np.asarray(d["camera_intrinsics"], float)
                w, h = _image_size(img)
                cam = Intrinsics(K=K, dist=np.asarray(d["dist_coeffs"], float), width_px=w, height_px=h, source="factory")
                o = _Out(out, rs, Target.from_dict(rs.target), {"cam": cam}, rs.mode,
                         extra={"sessions": {str(s): FRANKA_SESSIONS[s] for s in sessions}})
            o.capture(k, T, {"cam": (img, "png")}, q_rad=q)
            k += 1
    return o.finish()


def _open3dv_pose(txt: bytes) -> np.ndarray:
    """Open3DV pos<i>.txt: Rx Ry Rz (deg, scipy 'xyz' = extrinsic x then y then z, R = Rz Ry Rx), X Y Z (mm)."""
    v = np.array([float(x) for x in txt.decode().split()])
    return _pose(_euler("xyz", v[:3], True), v[3:6] / 1000.0)


def _opencv_circles(img: bytes, t: dict):
    """OpenCV's asymmetric-grid centres (on the inverted image when the dots are white on black), in
    OpenCV's order, which is calibgraph's acircles order (point (i, j) at pitch (2j + i % 2, i))."""
    import cv2

    g = cv2.imdecode(np.frombuffer(img, np.uint8), cv2.IMREAD_GRAYSCALE)
    for im in (g, 255 - g):
        ok, c = cv2.findCirclesGrid(im, (int(t["cols"]), int(t["rows"])), flags=cv2.CALIB_CB_ASYMMETRIC_GRID)
        if ok:
            return np.arange(int(t["rows"]) * int(t["cols"])), c.reshape(-1, 2).astype(float)
    return None


def _write_open3dv(rs: RealSet, out: Path, corners: str = "none") -> Path:
    """Open3DV/EyeInHand_calibration ``input_EyeInHand`` / ``input_EyeToHand``: pos<i>.bmp (the
    depth .tiff is not needed), pos<i>.txt (the flange pose), param.txt (K, then k1 k2 p1 p2 k3 of the
    camera; the projector's follow). ``corners='opencv'`` also stores OpenCV's circle centres as each
    view's detection (calibgraph then does not detect): to check the poses' convention with calibgraph's
    solver while its detector cannot read white-on-black grids; never to measure calibgraph's detection."""
    rev = rs.commit or "HEAD"
    p = np.array([float(x) for x in git_show(rs.git_dir, rev, f"{rs.path}/param.txt").decode().split()])
    K = np.array([[p[0], p[1], p[2]], [p[3], p[4], p[5]], [0, 0, 1.0]])
    dist = p[9:14]
    names = sorted((n for n in git_ls(rs.git_dir, rev, rs.path) if n.endswith(".bmp")),
                   key=lambda n: int(n.rsplit("pos", 1)[1].split(".")[0]))
    o = None
    for k, name in enumerate(names):
        img = git_show(rs.git_dir, rev, name)
        if o is None:
            w, h = _image_size(img)
            o = _Out(out, rs, Target.from_dict(rs.target), {"cam": Intrinsics(K=K, dist=dist, width_px=w, height_px=h,
                                                                               source="calibration")}, rs.mode)
        T = _open3dv_pose(git_show(rs.git_dir, rev, name[:-4] + ".txt"))
        det = _opencv_circles(img, rs.target) if corners == "opencv" else None
        o.capture(k, T, {"cam": (img, "bmp")}, detections={"cam": det} if det is not None else None)
    return o.finish()


def _write_leo038(rs: RealSet, out: Path) -> Path:
    """leo038/hand_eye_calibrate ``collect_data``: images<i>.jpg and poses.txt (one line per image,
    x,y,z (m), rx,ry,rz (rad) with R = Rz Ry Rx, as hand_eye_calibrate.py composes them)."""
    rev = rs.commit or "HEAD"
    lines = [ln for ln in git_show(rs.git_dir, rev, f"{rs.path}/poses.txt").decode().splitlines() if ln.strip()]
    o = None
    for k, ln in enumerate(lines):
        v = [float(x) for x in ln.split(",")]
        img = git_show(rs.git_dir, rev, f"{rs.path}/images{k}.jpg")
        if o is None:
            w, h = _image_size(img)
            o = _Out(out, rs, Target.from_dict(rs.target), {"cam": Intrinsics.unknown(w, h)}, rs.mode)
        o.capture(k, _pose(_euler("ZYX", v[5:2:-1], False), v[:3]), {"cam": (img, "jpg")})
    return o.finish()


def _write_diana(rs: RealSet, out: Path) -> Path:
    """xiaoBOSS97/handeye_calibration ``eye2hand_camN/img_M``: img<i>.png (i from 1, in number order,
    as handeye_calibration.py sorts them) and pose.npy rows [x y z (m), rotation vector (rad)] of the
    flange in the base; the camera's intrinsics from camera_intrinsics/*.npy where the folder has them."""
    import io

    rev = rs.commit or "HEAD"
    base, sessions = rs.path.rsplit("/", 1)
    pairs = []
    for sess in sessions.split(","):  # 'img_2,img_3,img_4': sessions merged in that order
        folder = f"{base}/{sess}"
        poses = np.load(io.BytesIO(git_show(rs.git_dir, rev, f"{folder}/pose.npy")))
        names = sorted((n for n in git_ls(rs.git_dir, rev, folder) if n.endswith(".png")),
                       key=lambda n: int(n.rsplit("/img", 1)[1].split(".")[0]))
        if len(names) != len(poses):
            raise SetError(f"{rs.name}: {folder}: {len(poses)} poses for {len(names)} images")
        pairs += list(zip(names, poses))
    cam_dir = base + "/camera_intrinsic"
    o = None
    for k, (name, v) in enumerate(pairs):
        img = git_show(rs.git_dir, rev, name)
        if o is None:
            w, h = _image_size(img)
            try:
                K = np.load(io.BytesIO(git_show(rs.git_dir, rev, f"{cam_dir}/cameraMatrix.npy")))
                dist = np.load(io.BytesIO(git_show(rs.git_dir, rev, f"{cam_dir}/dist.npy"))).ravel()
                cam = Intrinsics(K=K, dist=dist, width_px=w, height_px=h, source="calibration")
            except SetError:
                cam = Intrinsics.unknown(w, h)
            o = _Out(out, rs, Target.from_dict(rs.target), {"cam": cam}, rs.mode)
        o.capture(k, _pose(_rotvec(v[3:6]), v[:3]), {"cam": (img, "png")})
    return o.finish()


def _write_doosan(rs: RealSet, out: Path) -> Path:
    """jpjp210202/...Doosan-A0509... ``data``: images/img_NNN.png (26 and 27 absent), poses/pose_NNN.txt
    (RoboDK's robot.Pose(): 4x4 row-major, millimetres), camera_intrinsics.npz (cameraMatrix, distCoeffs)."""
    import io

    rev = rs.commit or "HEAD"
    z = np.load(io.BytesIO(git_show(rs.git_dir, rev, f"{rs.path}/camera_intrinsics.npz")))
    names = sorted(n for n in git_ls(rs.git_dir, rev, f"{rs.path}/images") if n.endswith(".png"))
    o = None
    for name in names:
        i = int(name.rsplit("_", 1)[1].split(".")[0])
        T = np.loadtxt(io.BytesIO(git_show(rs.git_dir, rev, f"{rs.path}/poses/pose_{i:03d}.txt")))
        img = git_show(rs.git_dir, rev, name)
        if o is None:
            w, h = _image_size(img)
            cam = Intrinsics(K=z["cameraMatrix"], dist=z["distCoeffs"].ravel(), width_px=w, height_px=h,
                             source="calibration")
            o = _Out(out, rs, Target.from_dict(rs.target), {"cam": cam}, rs.mode)
        o.capture(i, _pose(_orthonormal(T[:3, :3]), T[:3, 3] / 1000.0), {"cam": (img, "png")})
    return o.finish()


def _write_sthandeye(rs: RealSet, out: Path) -> Path:
    """koide3/st_handeye_graph ``calibration_data/<folder>`` (the 2023 commits of its history):
    ``NNN_image.jpg`` with ``NNN_pose.csv`` (calib_a, calib_b) or ``NNN.csv`` (2023 sessions), a 4x4
    hand pose, whitespace-separated, metres; the ROS camera_info YAML beside the folder."""
    import yaml

    rev = rs.commit or "HEAD"
    folder = rs.path
    info_name = {"calibration_data/calib_a": "camera_info.yaml", "calibration_data/calib_b": "camera_info.yaml"}.get(
        folder, folder.rsplit("/", 1)[1] + "_camera_info.yaml")
    info = yaml.safe_load(git_show(rs.git_dir, rev, f"calibration_data/{info_name}"))
    K = np.asarray(info["camera_matrix"]["data"], float).reshape(3, 3)
    dist = np.asarray(info["distortion_coefficients"]["data"], float)
    files = git_ls(rs.git_dir, rev, folder)
    ids = sorted({n.rsplit("/", 1)[1][:3] for n in files if n.endswith("_image.jpg")})
    o = _Out(out, rs, Target.from_dict(rs.target), {"cam": Intrinsics(
        K=K, dist=dist, width_px=int(info["image_width"]), height_px=int(info["image_height"]),
        source="factory" if not np.any(dist) else "calibration")}, rs.mode)
    for i in ids:
        pose = f"{folder}/{i}_pose.csv" if f"{folder}/{i}_pose.csv" in files else f"{folder}/{i}.csv"
        T = np.loadtxt(git_show(rs.git_dir, rev, pose).decode().splitlines())
        o.capture(int(i), _pose(_orthonormal(T[:3, :3]), T[:3, 3]),
                  {"cam": (git_show(rs.git_dir, rev, f"{folder}/{i}_image.jpg"), "jpg")})
    return o.finish()


# ---------------------------------------------------------------------------------------------
# the catalog
# ---------------------------------------------------------------------------------------------
def _franka_reference() -> dict:
    # session 3's own result (data/hand-eye-calibration-output/calibration_result.json at 0b9fe29):
    # "T_cam_gripper", which compute_calibration.py fills from cv2.calibrateHandEye's R_cam2gripper,
    # t_cam2gripper (TSAI): the camera in the EE frame. calibgraph's T_flange_cam = F_T_EE @ T_EE_cam.
    T_EE_cam = np.array([[-0.029637543915555176, -0.9988137813756863, -0.03863477869298661, 0.048888889483454136],
                         [0.9995597538049146, -0.029561863555240486, -0.002528793506730534, 0.008261407180641327],
                         [0.001383677748566823, -0.038692717107278146, 0.9992501984381811, -0.03861366656366333],
                         [0.0, 0.0, 0.0, 1.0]])
    T = F_T_EE_FRANKA_HAND @ T_EE_cam
    T[:3, :3] = _orthonormal(T[:3, :3])
    return {"T_flange_cam": T.round(9).tolist(), "method": "OpenCV calibrateHandEye TSAI on session 3's 12 poses",
            "source": "kvasios/franka-handeye@0b9fe295 data/hand-eye-calibration-output/calibration_result.json "
                      "(T_cam_gripper = T_EE_cam, composed with F_T_EE of the Franka Hand)",
            "caveat": "sessions 1-2's committed results were computed from the poses transposed (the script at "
                      "9c23a7d read O_T_EE as column-major) and are not references"}


def _diana_reference() -> dict:
    T = [[0.7970567495204657, -0.5276100865851356, 0.29381649813700994, 0.07859204259363001],
         [-0.6000728673490627, -0.6372236546251244, 0.4835892553166111, -0.9593985913526044],
         [-0.06791974613721688, -0.5617593884572166, -0.824507912372483, 0.9423926616996707], [0.0, 0.0, 0.0, 1.0]]
    return {"T_base_cam": T, "method": "OpenCV calibrateHandEye TSAI (main.py: img_4's 20 poses)",
            "source": "xiaoBOSS97/handeye_calibration eye2hand_cam1/H_cam2base.npy (cam2base = T_base_cam)"}


def _doosan_reference() -> dict:
    return {"T_flange_cam_rotation_only": [[0.053316, 0.998049, -0.032491], [-0.998464, 0.052791, -0.016811],
                                           [-0.015063, 0.033337, 0.999331]],
            "translation_mm_hand_measured": [80.0, -15.0, -45.0],
            "source": "data/handeye_T_tool_cam.txt; '4. Updated Calibration.py' keeps TSAI's rotation and overrides "
                      "the translation with ruler offsets, so only the rotation is a solved result"}


def _sets() -> list:
    S = []
    rwhe = ("ihtishamaliktk/RWHE-Calib", "none stated (README asks to cite Ali et al., Sensors 2019)")
    for n, rows, cols, pitch, note in (
            ("kuka_1", 17, 28, 0.020, "calib.io checkerboard 18 x 29 squares"),
            ("kuka_2", 17, 24, 0.015, "calib.io checkerboard 18 x 25 squares"),
            ("kuka_3", 8, 11, 0.060, "9 x 12 squares with ArUco markers in the white ones (read as a checkerboard)")):
        size = (1920, 1200) if n == "kuka_2" else (1928, 1208)
        S.append(RealSet(f"rwhe_{n}", rwhe[0], None, f"Datasets/{n}", rwhe[1], "KUKA (RWHE-Calib)", "eye_in_hand",
                         f"{size[0]} x {size[1]} mono", size,
                         {"kind": "checkerboard", "rows": rows, "cols": cols, "pitch_m": pitch},
                         {"kuka_1": 30, "kuka_2": 28, "kuka_3": 29}.get(n, 0), False, None, _write_rwhe,
                         notes=f"{note}; square sizes from getSquareSize4dataset.m; no intrinsics given",
                         group="rwhe", intrinsics="none (unknown)"))
    ic = ("ros-industrial/industrial_calibration", "Apache-2.0")
    S.append(RealSet("ic_10x10", ic[0], None, "examples/data/test_set_10x10", ic[1], "industrial_calibration example",
                     "eye_in_hand", "640 x 480 (Kinect class)", (640, 480),
                     {"kind": "modified_circles", "rows": 10, "cols": 10, "pitch_m": 0.0254, "circle_diameter_m": 0.0105},
                     15, False, None, _write_ic, notes="read by calibgraph's RCT reader; the intrinsics the files give",
                     group="ic", intrinsics="calibration (cal_data.yaml)"))
    S.append(RealSet("ic_charuco", ic[0], None, "examples/data/test_set_charuco", ic[1], "industrial_calibration example",
                     "eye_to_hand", "1600 x 1200", (1600, 1200),
                     {"kind": "charuco", "rows": 6, "cols": 4, "pitch_m": 0.036195, "marker_m": 0.018256,
                      "dictionary": "DICT_6X6_250", "legacy_charuco": True}, 16, False, None, _write_ic,
                     notes="the same files as ../shared/datasets/rct_static_camera_charuco", group="ic",
                     intrinsics="calibration (cal_data.yaml)"))
    S.append(RealSet("mchec_medium_workcell", "", None, "mchec_medium_workcell",
                     "Apache-2.0 (MC-HEC, davidea97/Multi-Camera-Hand-Eye-Calibration@6bbc900)",
                     "Franka (MC-HEC's medium workcell)", "eye_to_hand", "4 fixed cameras, 1920 x 1080", (1920, 1080),
                     {"kind": "checkerboard", "rows": 3, "cols": 4, "pitch_m": 0.05}, 251, False, None, _write_shared,
                     notes="../shared; read by calibgraph's MC-HEC reader (CalibrationInfo.yaml: 4 rows x 3 columns "
                           "as MC-HEC counts them, 3 x 4 points as calibgraph's reader writes them, 50 mm); README_SOURCE.txt calls it a SIMULATED (rendered) workcell of the MC-HEC authors; "
                           "its GT/ held back", group="mchec", intrinsics="calibration (intrinsic_pars_file.yaml)"))
    S.append(RealSet("rct_static_camera_charuco", "", None, "rct_static_camera_charuco",
                     "Apache-2.0 (industrial_calibration's example data)", "industrial_calibration example",
                     "eye_to_hand", "1600 x 1200", (1600, 1200),
                     {"kind": "charuco", "rows": 6, "cols": 4, "pitch_m": 0.036195, "marker_m": 0.018256,
                      "dictionary": "DICT_6X6_250", "legacy_charuco": True}, 16, False, None, _write_shared,
                     notes="../shared; read by calibgraph's RCT reader; same files as ic_charuco", group="ic",
                     intrinsics="calibration (cal_data.yaml)"))
    for n, poses in (("visp_eye_in_hand_2022", 8), ("visp_eye_in_hand_2025", 8)):
        S.append(RealSet(n, "", None, n, "see ../shared/datasets/" + n, "Franka Panda (ViSP sample)", "eye_in_hand",
                         "RealSense (ViSP sample)", (0, 0), {}, poses, False, None, None,
                         why_listed="read by the ViSP layout reader (calibgraph/io/peer_visp.py) where it is; "
                                    "no converter here", group="visp"))
    fr = ("kvasios/franka-handeye", "MIT (pyproject.toml / setup.py)")
    target_fr = {"kind": "charuco", "rows": 6, "cols": 4, "pitch_m": 0.034, "marker_m": 0.028, "dictionary": "DICT_6X6_250"}
    for s in (1, 2, 3):
        S.append(RealSet(f"franka_handeye_s{s}", fr[0], FRANKA_SESSIONS[s], f"data/captured-data:{s}", fr[1],
                         "Franka (Panda or FR3; libfranka O_T_EE with the Franka Hand)", "eye_in_hand",
                         "Intel RealSense colour 1280 x 720", (1280, 720), target_fr, 12, True,
                         _franka_reference() if s == 3 else None, _write_franka,
                         notes="ChArUco 5 x 7 squares (34 mm, 28 mm DICT_6X6_250 markers); the same 12 joint targets "
                               "(config/joint_poses.yaml) in each session; FK(q) of calibgraph's Franka model times "
                               "the Franka Hand's F_T_EE reproduces O_T_EE",
                         group="franka_handeye", intrinsics="factory (RealSense)"))
    S.append(RealSet("franka_handeye_all", fr[0], FRANKA_SESSIONS[3], "data/captured-data:1,2,3", fr[1],
                     "Franka (Panda or FR3)", "eye_in_hand", "Intel RealSense colour 1280 x 720", (1280, 720),
                     target_fr, 36, True, _franka_reference(), _write_franka,
                     notes="the three sessions merged in order (captures 0-11, 12-23, 24-35): the same camera and "
                           "board, repeated joint targets", group="franka_handeye", intrinsics="factory (RealSense)"))
    o3 = ("Open3DV/EyeInHand_calibration", "none stated (no LICENSE file)")
    S.append(RealSet("open3dv_eye_in_hand", o3[0], None, "input_EyeInHand", o3[1], "unknown arm (Yaskawa-style Rx Ry Rz)",
                     "eye_in_hand", "Open3DV Xema structured-light camera, 1920 x 1200 mono", (1920, 1200),
                     {"kind": "acircles", "rows": 11, "cols": 7, "pitch_m": 0.010, "circle_diameter_m": 0.0085},
                     8, False, None, _write_open3dv,
                     notes="asymmetric circle grid printed WHITE ON BLACK, 7 x 11 (cv2 (7, 11), 20 mm between "
                           "circles of a row, rows 10 mm apart; dot diameter ~8.5 mm measured from the images); "
                           "calib_utils.py inverts the image for findCirclesGrid",
                     group="open3dv", intrinsics="calibration (param.txt)"))
    S.append(RealSet("open3dv_eye_to_hand", o3[0], None, "input_EyeToHand", o3[1], "unknown arm", "eye_to_hand",
                     "Open3DV camera, 1022 x 768 mono", (1022, 768),
                     {"kind": "acircles", "rows": 11, "cols": 7, "pitch_m": 0.020, "circle_diameter_m": 0.016},
                     5, False, None, _write_open3dv,
                     notes="white-on-black asymmetric grid, 40 mm between circles of a row; param.txt gives K and "
                           "zero distortion; only 5 poses", group="open3dv", intrinsics="calibration (param.txt)"))
    S.append(RealSet("leo038_eye_in_hand", "leo038/hand_eye_calibrate", None, "collect_data",
                     "none stated (no LICENSE file)", "unknown arm", "eye_in_hand", "1280 x 960 colour", (1280, 960),
                     {"kind": "checkerboard", "rows": 8, "cols": 11, "pitch_m": 0.020}, 20, False, None, _write_leo038,
                     notes="the images show an 11 x 8-corner board (12 x 9 squares) although hand_eye_calibrate.py "
                           "says 9 x 6 corners of 35 mm: the square size is NOT known (20 mm assumed, an A4 print); "
                           "the hand-eye translation scales with it, so calibgraph's board-scale estimate is the "
                           "only measure of it", group="leo038", intrinsics="none (unknown)"))
    dia = ("xiaoBOSS97/handeye_calibration", "none stated (no LICENSE file)")
    for cam, sess, n in (("cam1", 1, 20), ("cam1", 2, 47), ("cam1", 3, 14), ("cam1", 4, 20), ("cam2", 1, 22)):
        S.append(RealSet(f"diana_{cam}_s{sess}", dia[0], None, f"eye2hand_{cam}/img_{sess}", dia[1],
                         "Agile Robots Diana (DianaApi)", "eye_to_hand", "640 x 480 colour", (640, 480),
                         {"kind": "checkerboard", "rows": 6, "cols": 9, "pitch_m": 0.040}, n, False,
                         _diana_reference() if (cam, sess) == ("cam1", 4) else None, _write_diana,
                         notes="9 x 6 corners of 40 mm (main.py); img_2 was also used for the intrinsics; the camera "
                               "may have been moved between sessions (not said)" if cam == "cam1" else
                               "the second camera; no intrinsics file (unknown)",
                         group="diana", intrinsics="calibration (cameraMatrix.npy)" if cam == "cam1" else "none (unknown)"))
    S.append(RealSet("diana_cam1_s2_s4", dia[0], None, "eye2hand_cam1/img_2,img_3,img_4", dia[1],
                     "Agile Robots Diana (DianaApi)", "eye_to_hand", "640 x 480 colour", (640, 480),
                     {"kind": "checkerboard", "rows": 6, "cols": 9, "pitch_m": 0.040}, 81, False, _diana_reference(),
                     _write_diana, notes="sessions img_2, img_3, img_4 of camera 1 merged in that order (captures "
                     "0-46, 47-60, 61-80): solved alone they agree on T_base_cam within ~7 mm (VERIFIED); a "
                     "multi-session set of one fixed camera", group="diana", intrinsics="calibration (cameraMatrix.npy)"))
    S.append(RealSet("doosan_a0509", "jpjp210202/Hand-Eye-Calibration-Doosan-A0509-IntelRealSenseA457-ChArUco", None,
                     "data", "MIT", "Doosan A0509 (RoboDK robot.Pose())", "eye_in_hand",
                     "Intel RealSense D435 colour 1280 x 720", (1280, 720),
                     {"kind": "charuco", "rows": 4, "cols": 6, "pitch_m": 0.030, "marker_m": 0.022, "dictionary": "DICT_4X4_50"},
                     31, False, _doosan_reference(), _write_doosan,
                     notes="calib.io ChArUco 7 x 5 squares, 30 mm, 22 mm DICT_4X4_50 markers (the capture script "
                           "says 21 mm; the print and README 22 mm); the capture app DREW ON THE IMAGES (marker "
                           "outlines, ids, corner marks, axes, a text line); 31 poses",
                     group="doosan", intrinsics="calibration (camera_intrinsics.npz)"))
    st = ("koide3/st_handeye_graph", "none stated (no LICENSE file)")
    st_rev = "afb6dd969a92a688985d878f2e04bbea518769c5"  # hollydinkel's 2023 commits in the snapshot's history
    for n, folder, poses, size, target, note in (
            ("sthandeye_calib_a", "calib_a", 22, (1280, 720),
             {"kind": "checkerboard", "rows": 9, "cols": 11, "pitch_m": 0.0202},
             "checkerboard 9 x 11 inner corners, 20.2 mm (src/calibrate.cpp); camera_info.yaml"),
            ("sthandeye_calib_b", "calib_b", 19, (1280, 720),
             {"kind": "checkerboard", "rows": 9, "cols": 11, "pitch_m": 0.0202},
             "same camera and board as calib_a, another session"),
            ("sthandeye_20231006", "20231006", 7, (640, 480),
             {"kind": "charuco", "rows": 6, "cols": 4, "pitch_m": 0.024, "marker_m": 0.018, "dictionary": "DICT_4X4_250"},
             "ChArUco CharucoBoard::create(5, 7, 24 mm, 18 mm, DICT_4X4_250) (src/calibrate_charuco.cpp); "
             "NNN_joints.txt holds 6 small numbers (not joint angles of a pose; not used); zero distortion given")):
        S.append(RealSet(n, st[0], st_rev, f"calibration_data/{folder}", st[1], "unknown arm (st_handeye_graph users)",
                         "eye_in_hand", f"{size[0]} x {size[1]} colour", size, target, poses, False, None,
                         _write_sthandeye, notes=note, group="sthandeye", intrinsics="calibration (camera_info.yaml)"))
    S.append(RealSet("gitglob_ur_eye_in_hand", "gitglob/eye_in_hand_calibration", "50d50d2", "images",
                     "none stated (no LICENSE file)", "UR (freedrive.py), TCP pose as rotation vector + m", "eye_in_hand",
                     "RealSense 1280 x 720", (1280, 720), {}, 41, False, None, None,
                     why_listed="ChArUco 7 x 5 on a custom random dictionary (aruco.Dictionary_create(17, 5, seed 42)): "
                                "calibgraph reads predefined dictionaries only", group="gitglob"))
    S.append(RealSet("ethz_hand_eye_calibration", "ethz-asl/hand_eye_calibration", None, "datasets",
                     "not checked (not converted)", "Tango devices vs Vicon (pose streams)", "eye_in_hand", "none", (0, 0),
                     {}, 1, False, None, None,
                     why_listed="pose streams only (CSV), no images: the image data is on ETH's Research Collection",
                     group="ethz"))
    return S


SETS = {s.name: s for s in _sets()}

# What each converter's output gave (real_sets.py verify / crosscheck, calibgraph at ea9dc88 with its
# defaults, OpenCV 4.14): views used, reprojection RMS, the hand-eye translation (T_flange_cam eye-in-hand,
# T_base_cam eye-to-hand, mm) and, from OpenCV on its own detections, PARK's translation and the AX = XB
# residual with the poses as written against inverted (the convention check). /work/data/real/CATALOG.md
# has calibgraph's notes per set.
VERIFIED = {
    "rwhe_kuka_1": "30 views, rms 0.107 px, t (257, 33, -104) mm; OpenCV PARK t (259, 33, -104) mm, AX=XB 0.08 deg as written vs 61.2 inverted",
    "rwhe_kuka_2": "28 views, rms 0.136 px, t (28, -104, -78) mm; OpenCV PARK t (14, -108, -82) mm, AX=XB 0.07 deg as written vs 54.9 inverted",
    "rwhe_kuka_3": "29 views, rms 0.081 px, t (254, 34, -105) mm (within 4 mm of kuka_1's); OpenCV's SB detector finds none of these ArUco-filled boards",
    "ic_10x10": "15 views, rms 0.546 px, t (-84, 22, 93) mm",
    "ic_charuco": "16 views, rms 0.537 px, t (-19, 1265, 289) mm; OpenCV PARK t (-31, 1269, 279) mm, AX=XB 1.78 deg as written vs 115.5 inverted",
    "mchec_medium_workcell": "camera1: 67 views, rms 0.113 px, t (-1190, 1899, 1154) mm; camera2: 116 views, rms 0.117 px, t (1766, 2059, 1155) mm; camera3: 117 views, rms 0.126 px, t (1898, -1907, 1155) mm; camera4: 83 views, rms 0.11 px, t (-1046, -2031, 1153) mm",
    "rct_static_camera_charuco": "16 views, rms 0.537 px, t (-19, 1265, 289) mm",
    "franka_handeye_s1": "12 views, rms 3.51 px, t (51, -32, 69) mm; OpenCV PARK t (40, -30, 67) mm, AX=XB 0.81 deg as written vs 78.4 inverted",
    "franka_handeye_s2": "12 views, rms 3.551 px, t (51, -32, 69) mm; OpenCV PARK t (40, -29, 66) mm, AX=XB 0.83 deg as written vs 78.5 inverted",
    "franka_handeye_s3": "12 views, rms 3.582 px, t (51, -33, 67) mm, 11.8 mm / 0.82 deg from the published result; OpenCV PARK t (40, -29, 65) mm (the published TSAI: 40, -29, 65), AX=XB 0.70 deg as written vs 78.5 inverted",
    "franka_handeye_all": "13 views, rms 4.016 px, t (44, -34, 66) mm, 6.1 mm / 1.46 deg from the published result; OpenCV PARK t (39, -29, 66) mm, AX=XB 1.60 deg as written vs 76.2 inverted",
    "open3dv_eye_in_hand": "calibgraph detection stopped by hand after 11 min on the first of 8 images (no message); OpenCV PARK t (220, 69, -178) mm, AX=XB 0.06 deg as written vs 37.9 inverted; with OpenCV's circle centres stored (--corners opencv): 8/8 views, rms 0.027 px, t (221, 68, -177) mm",
    "open3dv_eye_to_hand": "calibgraph refused: no acircles of 11x7 points (as dataset.yaml declares) in the first 5 frames of the camera: check the target spec (kind, rows, cols) in dataset.yaml ag; OpenCV PARK t (910, 116, 1351) mm, AX=XB 0.14 deg as written vs 48.6 inverted; with OpenCV's circle centres stored (--corners opencv): 5/5 views, rms 0.047 px, t (907, 116, 1344) mm",
    "leo038_eye_in_hand": "20 views, rms 0.233 px, t (-40, 60, 18) mm; OpenCV PARK t (-43, 66, 10) mm, AX=XB 0.33 deg as written vs 37.9 inverted",
    "diana_cam1_s1": "calibgraph refused: board mount: the robot poses barely rotate the board (spread 0.00 deg): pure translation leaves the board mount and the camera translation unobservabl; OpenCV: degenerate too (pure translations)",
    "diana_cam1_s2": "20 of 47 views (27 rejected whole: 54 of 54 corners beyond 5 sigma), rms 0.072 px, t (74, -961, 943) mm; OpenCV PARK t (75, -967, 935) mm, AX=XB 0.85 deg as written vs 29.0 inverted",
    "diana_cam1_s3": "13 of 14 views, rms 0.175 px, t (82, -961, 941) mm; OpenCV PARK t (80, -960, 947) mm, AX=XB 0.95 deg as written vs 95.6 inverted",
    "diana_cam1_s4": "17 views, rms 0.084 px, t (81, -962, 938) mm, 5.8 mm / 0.15 deg from the published result; a move claimed between captures 1 and 2 (3.6 mm); OpenCV PARK t (75, -953, 949) mm, AX=XB 0.53 deg as written vs 54.2 inverted",
    "diana_cam2_s1": "19 views, rms 0.074 px, t (963, -115, 1033) mm; OpenCV PARK t (958, -111, 1030) mm, AX=XB 0.99 deg as written vs 74.2 inverted",
    "doosan_a0509": "3 of 31 views (the overlays), rms 2.524 px, t (-24, 95, -13) mm, 4.10 deg from the published rotation; OpenCV's CharucoDetector finds 2 of 31 boards; from the repo's own board poses (boardpose_NNN.npz): PARK t (-18, 32, -12) mm, AX=XB 0.61 deg as written vs 64.7 inverted",
    "sthandeye_calib_a": "calibgraph refused: no checkerboard of 9x11 inner corners (as dataset.yaml declares) in the first 19 frames of the camera; the images show a 9x9 grid: check rows/cols of ; OpenCV PARK t (-30, -42, 68) mm, AX=XB 0.99 deg as written vs 23.6 inverted",
    "sthandeye_calib_b": "calibgraph refused: no checkerboard of 9x11 inner corners (as dataset.yaml declares) in the first 16 frames of the camera; the images show a 9x10 grid: check rows/cols of; OpenCV PARK t (-33, -39, 70) mm, AX=XB 0.58 deg as written vs 110.0 inverted",
    "sthandeye_20231006": "7 views, rms 0.551 px, t (20, 32, -42) mm; WARNING: the solver did not converge (24 iterations): the estimates m; OpenCV PARK t (21, 45, -62) mm, AX=XB 2.66 deg as written vs 9.7 inverted",
    "diana_cam1_s2_s4": "50 of 81 views, rms 0.262 px, t (79, -962, 942) mm, 2.5 mm / 0.26 deg from the published result",
}


def in_place(name: str) -> Path | None:
    """The folder calibgraph reads as it is for a set listed without a converter (the ViSP samples in
    ../shared, read by the ViSP layout reader), when it is here; else None."""
    rs = SETS[name]
    if rs.writer is None and not rs.repo and (SHARED / rs.path).exists():
        return SHARED / rs.path
    return None


def availability(rs: RealSet) -> str:
    """'' when the set can be written here, else why not (one line)."""
    if rs.writer is None:
        return rs.why_listed or "listed only"
    if rs.writer is _write_shared:
        return "" if (SHARED / rs.path).exists() else f"{SHARED / rs.path} is not here"
    return _need_snapshot(rs)


def write(name: str, out, corners: str = "none") -> Path:
    """Write the set ``name`` as a calibgraph-dataset/1 folder at ``out`` (new or empty; a finished copy
    of the same set is returned as it is). ``corners='opencv'`` (circle-grid sets only) stores OpenCV's
    detections in the capture files, for checking the pose convention where calibgraph's detector fails."""
    if name not in SETS:
        raise SetError(f"no set {name!r}; `python scripts/real_sets.py list` names them")
    rs = SETS[name]
    why = availability(rs)
    if why:
        raise SetError(f"{name}: {why}")
    out = Path(out)
    if corners != "none":
        if rs.writer is not _write_open3dv:
            raise SetError(f"{name}: --corners opencv is offered for the circle-grid sets (open3dv_*) only")
        if _check_out(out, name):
            return out
        return rs.writer(rs, out, corners=corners)
    if _check_out(out, name):
        return out
    return rs.writer(rs, out)


# ---------------------------------------------------------------------------------------------
# verification: solve the written folder with calibgraph's CLI and summarise
# ---------------------------------------------------------------------------------------------
def _reference_T(rs: RealSet):
    ref = rs.reference or {}
    for k in ("T_flange_cam", "T_base_cam"):
        if k in ref:
            return np.asarray(ref[k], float), None
    if "T_flange_cam_rotation_only" in ref:
        return None, np.asarray(ref["T_flange_cam_rotation_only"], float)
    return None, None


def solve(ds: Path, result: Path, *flags, timeout_s: float = 1800.0) -> tuple:
    """``calibgraph solve DS --out RESULT FLAGS`` with this checkout's calibgraph; (exit code, output)."""
    import os

    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-c", "import sys; from calibgraph.cli import main; sys.exit(main())",
           "solve", str(ds), "--out", str(result), *flags]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return None, f"timed out after {timeout_s:.0f} s"
    return r.returncode, r.stdout + r.stderr


def summarise(rs: RealSet, result: Path, code, output: str) -> dict:
    """Per camera: views used/given, RMS, the hand-eye translation (mm) and 1-sigma, the distance to
    the published reference where there is one; the notes and warnings calibgraph gave."""
    s = {"exit": code, "warnings": [ln.strip() for ln in output.splitlines() if "WARNING" in ln][:10]}
    if not Path(result).exists():
        s["error"] = [ln for ln in output.splitlines() if ln.strip()][-3:]
        return s
    r = json.loads(Path(result).read_text())
    s["calibgraph_version"] = r.get("calibgraph_version")
    s["notes"] = r.get("notes", [])
    s["board_scale"] = r.get("board_scale")
    T_ref, R_ref = _reference_T(rs)
    cams = {}
    for name, c in r.get("cameras", {}).items():
        if not c.get("calibrated"):
            cams[name] = {"calibrated": False, "why": c.get("why"), "views_used": c.get("views_used")}
            continue
        T = np.asarray(c.get("T_flange_cam") or c.get("T_base_cam"), float)
        d = {"views_used": c.get("views_used"), "views_rejected": len(c.get("views_rejected") or []),
             "rms_px": round(float(c["reprojection_rms_px"]), 3),
             "t_mm": [round(1e3 * x, 1) for x in T[:3, 3]],
             "sigma_t_mm": [round(float(x), 2) for x in c["sigma_translation_mm"]],
             "expected_heldout_px": (c.get("prediction") or {}).get("expected_rms_px"),
             "intrinsics_used": (c.get("intrinsics") or {}).get("source_used")}
        if T_ref is not None:
            d["ref_t_mm"] = [round(1e3 * x, 1) for x in T_ref[:3, 3]]
            d["to_ref_mm"] = round(float(1e3 * np.linalg.norm(T[:3, 3] - T_ref[:3, 3])), 2)
            R_ref = T_ref[:3, :3]
        if R_ref is not None:
            from scipy.spatial.transform import Rotation

            D = _orthonormal(T[:3, :3]) @ _orthonormal(R_ref).T
            d["to_ref_deg"] = round(float(np.degrees(Rotation.from_matrix(D).magnitude())), 3)
        cams[name] = d
    s["cameras"] = cams
    return s


def verify(name: str, work: Path, *flags) -> dict:
    """Write ``name`` under ``work/sets/NAME`` (once) and solve it into ``work/results/NAME.json``."""
    ds = write(name, Path(work) / "sets" / name)
    res = Path(work) / "results" / f"{name}.json"
    res.parent.mkdir(parents=True, exist_ok=True)
    code, out = solve(ds, res, *flags)
    (res.with_suffix(".log")).write_text(out)
    return summarise(SETS[name], res, code, out)


def crosscheck(name: str, work: Path, cv4_python: str | None = None) -> dict:
    """OpenCV 4's view of the written set (``scripts/_real_sets_cv4_check.py``): its own detections,
    calibrateHandEye TSAI and PARK on the poses as written and inverted, and each one's AX = XB
    residual. The OpenCV 4 venv is made once under ``work`` (as bench_solver.py makes it)."""
    import yaml

    sys.path.insert(0, str(REPO / "scripts"))
    from bench_solver import ensure_cv4_python

    ds = write(name, Path(work) / "sets" / name)
    py, why = ensure_cv4_python(Path(work), cv4_python)
    if py is None:
        raise SetError(f"no OpenCV 4 python: {why}")
    head = yaml.safe_load((ds / "dataset.yaml").read_text())
    if len(head["cameras"]) != 1:
        raise SetError(f"{name}: the cross-check handles one camera, the set has {len(head['cameras'])}")
    cam_name, cam = next(iter(head["cameras"].items()))
    views = []
    for f in sorted((ds / "captures").glob("*.json")):
        c = json.loads(f.read_text())
        v = (c.get("views") or {}).get(cam_name)
        if v and v.get("image"):
            views.append({"image": str(ds / v["image"]), "T_base_flange": c["T_base_flange"]})
    known = cam.get("K") is not None and cam.get("source") != "unknown"
    job = {"mode": head["mode"], "target": head["target"], "K": cam.get("K") if known else None,
           "dist": cam.get("dist") or (cam.get("distortion") or {}).get("coefficients") or [],
           "size": [cam["width_px"], cam["height_px"]], "views": views}
    with tempfile.TemporaryDirectory() as tmp:
        jf = Path(tmp) / "job.json"
        jf.write_text(json.dumps(job))
        r = subprocess.run([py, str(REPO / "scripts" / "_real_sets_cv4_check.py"), str(jf)], capture_output=True,
                           text=True)
    if r.returncode != 0:
        raise SetError(f"{name}: the OpenCV cross-check failed: {r.stderr.strip()[-300:]}")
    return json.loads(r.stdout)


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------
def _cmd_list() -> int:
    rows = [("name", "available", "mode", "poses", "q", "why not")]
    for rs in SETS.values():
        why = availability(rs)
        rows.append((rs.name, "no" if why else "yes", rs.mode, str(rs.n_poses), "yes" if rs.joint_angles else "",
                     why))
    w = [max(len(r[i]) for r in rows) for i in range(5)]
    for r in rows:
        print("  ".join(c.ljust(w[i]) for i, c in enumerate(r[:5])) + "  " + r[5])
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="every set: available here, and why not")
    p = sub.add_parser("show", help="a set's record as JSON")
    p.add_argument("name")
    p = sub.add_parser("write", help="write a set as a calibgraph-dataset/1 folder")
    p.add_argument("name")
    p.add_argument("--out", type=Path, required=True, help="a new or empty folder (not in the snapshots or ../shared)")
    p.add_argument("--corners", choices=("none", "opencv"), default="none",
                   help="opencv: store OpenCV's circle centres as detections (open3dv_* only; a convention check)")
    p = sub.add_parser("verify", help="write sets under WORK/sets and solve them with calibgraph (WORK/results)")
    p.add_argument("names", nargs="*", help="default: every available set")
    p.add_argument("--work", type=Path, default=Path("/work/data/real"))
    p.add_argument("--flag", action="append", default=[], help="a flag passed to calibgraph solve (repeatable)")
    p = sub.add_parser("crosscheck", help="OpenCV 4's hand-eye on the written set, poses as written and inverted")
    p.add_argument("names", nargs="*", help="default: every available set of one camera")
    p.add_argument("--work", type=Path, default=Path("/work/data/real"))
    p.add_argument("--cv4-python", default=None)
    a = ap.parse_args(argv)
    try:
        if a.cmd == "list":
            return _cmd_list()
        if a.cmd == "show":
            if a.name not in SETS:
                raise SetError(f"no set {a.name!r}; `python scripts/real_sets.py list` names them")
            d = SETS[a.name].as_dict()
            d["available"] = availability(SETS[a.name]) or "yes"
            d["verified"] = VERIFIED.get(a.name)
            print(json.dumps(d, indent=1))
            return 0
        if a.cmd == "crosscheck":
            for n in a.names or [n for n, rs in SETS.items() if not availability(rs) and rs.group != "mchec"]:
                try:
                    print(json.dumps({"set": n, **crosscheck(n, a.work, a.cv4_python)}), flush=True)
                except SetError as e:
                    print(json.dumps({"set": n, "error": str(e)}), flush=True)
            return 0
        if a.cmd == "verify":
            for n in a.names or [n for n, rs in SETS.items() if not availability(rs)]:
                print(json.dumps({"set": n, **verify(n, a.work, *a.flag)}), flush=True)
            return 0
        out = write(a.name, a.out, corners=a.corners)
        print(f"{a.name}: {out} ({len(list((out / 'captures').glob('*.json')))} captures)")
        return 0
    except SetError as e:
        print(f"real_sets: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
