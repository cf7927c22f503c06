"""Reading ViSP's hand-eye calibration folders as they are (``calibgraph solve DIR``)::

    DIR/
      pose_fPe_1.yaml ...        the end-effector in the robot base (ViSP's fMe / rMe): a vpPoseVector,
      (or franka_pose_rPe_1.yaml)  rows: 6, cols: 1, data: [[tx], [ty], [tz], [tux], [tuy], [tuz]],
                                   metres and a theta-u rotation vector in radians
      image-1.png ...            the image at that pose (franka_image-1.png beside franka_pose_rPe_1.yaml)
      camera.xml                 vpCameraParameters (vpXmlParserCamera): px py u0 v0 [kud kdu]
      chessboard-data.txt        optional: "9 x 6" and "square size: 0.0236 m"
      target.yaml                optional (placed by the user): a calibgraph target spec, and
                                 ``mode: eye_to_hand`` for ViSP's eye-to-hand folders

What ViSP writes, read from its code (``apps/calibration/hand-eye``, ``tutorial/calibration``):

- Pose files. ``visp-acquire-franka-calib-data`` saves ``robot.getPosition(END_EFFECTOR_FRAME, rPe)``
  with ``vpPoseVector::saveYAML`` as ``franka_pose_rPe_N.yaml`` (older tutorials ``pose_fPe_N.yaml``),
  and the matching image as ``franka_image-N.png`` (``image-N.png``), N from 1. A vpPoseVector
  ``[t, theta-u]`` is the homogeneous matrix ``rMe`` = ``[R(theta-u) t]``, which maps end-effector
  points into the base: calibgraph's ``T_base_flange`` (the "flange" being ViSP's end-effector
  frame). Pose N and image N are one capture, index N; an image with no pose is not used (a
  warning), a pose with no image is refused. The eye-in-hand result ViSP prints is ``eMc``:
  calibgraph's ``T_flange_cam``.
- ``camera.xml``. ``vpXmlParserCamera`` files hold one or more ``<camera>`` (name, image_width,
  image_height, one or more ``<model>``). The camera used is the one whose image size is the
  images' (one that states no size fits any); where several fit, the one named ``Camera`` (the
  name ViSP's tools default to), else the first; a warning says which was taken whenever the file
  holds more than one. Of its models, ``perspectiveProjWithDistortion`` is used when present
  (ViSP's chessboard-pose tool tries it first), else ``perspectiveProjWithoutDistortion``;
  ``ProjWithKannalaBrandtDistortion`` (fisheye) is refused: calibgraph's model is OpenCV's.
- Distortion. ViSP's ``perspectiveProjWithDistortion`` maps undistorted normalised coordinates to
  distorted ones by ``x' = x (1 + kud r^2)``, ``r^2 = x^2 + y^2``, then ``u = u0 + px x'``
  (``vpCameraParameters`` documentation): OpenCV's model with ``k1 = kud`` and every other
  coefficient zero, which is also how ViSP's own OpenCV bridge converts it
  (``tutorial-bridge-opencv``: ``D = [kud, 0, 0, 0]``). So the camera is read as ``dist = [kud, 0,
  0, 0, 0]`` -- the same projection ViSP uses, exactly. ``kud`` is a single-coefficient fit, so it
  is not the ``k1`` an OpenCV five-coefficient calibration of the same lens would give (it absorbs
  the higher orders); ``kdu`` is ViSP's approximate inverse (pixels to normalised) and is not
  needed. ``kud = 0`` is no distortion.
- Where the intrinsics come from. ViSP's acquisition tools write ``camera.xml`` from the device
  (``vpRealSense2::getCameraParameters``; the tutorial: "intrinsic camera parameters extracted from
  camera firmware"), with nothing else in the ``<camera>`` element; ViSP's intrinsic calibration
  tool adds an ``<additional_information>`` element (its reprojection errors). A camera with that
  element is read as ``source: calibration``, one without as ``source: factory`` (a 2 % focal
  prior: device values of RGB-D cameras are often 1-2 % off), so ``--intrinsics-source`` does not
  apply; ``--intrinsics camera=CAM.yaml`` and ``--fixed-intrinsics`` do as for any dataset.
- The board. ViSP's folders do not always name it. In order: the command line's ``--target
  SPEC.yaml``; a ``target.yaml`` beside the images (a calibgraph target spec, ``target: {kind,
  rows, cols, pitch_m}``, rows/cols counting inner corners); ViSP's ``chessboard-data.txt``
  ("W x H", "square size: S m"). ViSP's chessboard tool passes ``W x H`` to
  ``cv::findChessboardCorners`` (default 9 x 6: inner corners) and puts corner ``(i, j)`` at
  ``(j S, i S, 0)``: a calibgraph checkerboard of ``rows = H``, ``cols = W``, the same board frame.
  A folder that names no board is refused with one line saying how to give it.
- Mode: eye-in-hand (the camera on the end-effector, as ViSP's eye-in-hand folders), unless the
  ``target.yaml`` says ``mode: eye_to_hand`` (ViSP's eye-to-hand folders look the same).

Only files in ``DIR`` itself are read; nothing is written there except what ``calibgraph solve``
writes into any dataset's top folder (``result.json``, the detection cache, the lock).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.problem import Capture
from calibgraph.core.targets import Target
from calibgraph.core.transforms import check_pose, exp_so3, make_T
from calibgraph.io.dataset import Dataset, View
from calibgraph.io.files import image_size, parse_yaml, read_input_bytes, read_input_text, read_yaml

CAMERA = "camera"  # the one camera's name, as for the RCT layout
SIDE_FILE = "target.yaml"
CHESSBOARD_FILE = "chessboard-data.txt"
# <prefix>[pose_]fPe_<N>.yaml or rPe: the prefix is empty or ends in '_' or '-'
POSE_RE = re.compile(r"^(?P<prefix>(?:.*[_-])?)(?P<kind>fPe|rPe)_(?P<n>\d+)\.ya?ml$")
IMAGE_EXT = (".png", ".jpg", ".jpeg", ".bmp", ".pgm", ".ppm", ".tif", ".tiff")
IMAGE_RE = re.compile(r"^(?P<stem>.*?)[-_](?P<n>\d+)$")
BOARD_HOW = (f"give it with --target SPEC.yaml, or put a {SIDE_FILE} beside the images (a calibgraph target spec: "
             "target: {kind: checkerboard, rows: 6, cols: 9, pitch_m: 0.025}, rows/cols counting inner corners)")


def _files(root: Path) -> list:
    try:
        with os.scandir(root) as it:
            return sorted(e.name for e in it if e.is_file())
    except OSError:
        return []


def _pose_files(root: Path) -> dict:
    """N -> file name of every ViSP pose file in ``root``."""
    out = {}
    for name in _files(root):
        m = POSE_RE.match(name)
        if m:
            out.setdefault(int(m.group("n")), []).append(name)
    return out


def is_visp_dataset(root) -> bool:
    """True when ``root`` holds ViSP hand-eye pose files (``*fPe_N.yaml`` / ``*rPe_N.yaml``)."""
    try:
        with os.scandir(root) as it:
            return any(POSE_RE.match(e.name) and e.is_file() for e in it)
    except OSError:
        return False


# ---------------------------------------------------------------------------------------------
# vpPoseVector
# ---------------------------------------------------------------------------------------------
def _pose_fields(text: str, path: Path):
    """(rows, cols, data) of a vpArray2D YAML file: parsed as YAML, else line by line as ViSP's own
    loader reads it (its header lines are free text ahead of ``rows:``)."""
    try:
        d = parse_yaml(text.encode("utf-8"), path, "pose file", mapping=False)
    except InputError:
        d = None
    if isinstance(d, dict) and {"rows", "cols", "data"} <= set(d):
        return d["rows"], d["cols"], d["data"]
    lines = text.splitlines()
    got = {}
    for k, ln in enumerate(lines):
        s = ln.strip()
        for key in ("rows", "cols"):
            if s.startswith(f"{key}:"):
                got[key] = s.split(":", 1)[1].strip()
        if s.startswith("data:"):
            got["data"] = [x.strip().lstrip("-").strip().strip("[]") for x in lines[k + 1:] if x.strip().startswith("-")]
            break
    if set(got) != {"rows", "cols", "data"}:
        return None
    return got["rows"], got["cols"], [[x for x in re.split(r"[,\s]+", e) if x] for e in got["data"]]


def read_visp_pose(path) -> np.ndarray:
    """``T_base_flange`` (4x4) of a ViSP vpPoseVector YAML file (``[tx ty tz tux tuy tuz]``, m and rad)."""
    p = Path(path)
    want = ("not a ViSP vpPoseVector file (rows: 6, cols: 1, data: [[tx], [ty], [tz], [tux], [tuy], [tuz]], metres and "
            "a theta-u rotation in radians)")
    text = read_input_text(p, "pose file")
    fields = _pose_fields(text, p)
    if fields is None:
        raise InputError(f"{p}: {want}.")
    rows, cols, data = fields
    try:
        v = np.array([float(x) for row in (data if isinstance(data, list) else [])
                      for x in (row if isinstance(row, list) else [row])], float)
        shape = (int(rows), int(cols))
    except (TypeError, ValueError):
        raise InputError(f"{p}: {want}; its values are not numbers.") from None
    if shape != (6, 1) or v.size != 6:
        raise InputError(f"{p}: {want}; it holds {shape[0]} x {shape[1]} ({v.size} values).")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{p}: {want}; it holds NaN or infinite values.")
    return check_pose(make_T(exp_so3(v[3:]), v[:3]), str(p))


# ---------------------------------------------------------------------------------------------
# vpCameraParameters XML
# ---------------------------------------------------------------------------------------------
def _camera_file(root: Path, prefixes: set) -> Path | None:
    names = _files(root)
    for pre in sorted(prefixes, key=len, reverse=True):  # franka_camera.xml beside franka_pose_rPe_N.yaml
        if f"{pre}camera.xml" in names:
            return root / f"{pre}camera.xml"
    xml = [n for n in names if n.lower().endswith(".xml") and "camera" in n.lower()]
    return root / xml[0] if len(xml) == 1 else None


def _text(el, tag: str):
    c = el.find(tag)
    return None if c is None or c.text is None else c.text.strip()


def _number(el, tag: str, where: str) -> float:
    s = _text(el, tag)
    try:
        x = float(s)
    except (TypeError, ValueError):
        raise InputError(f"{where}: <{tag}> is {'missing' if s is None else repr(s)}; a vpCameraParameters model "
                         "needs px, py, u0, v0 (and kud, kdu with distortion).") from None
    if not np.isfinite(x):
        raise InputError(f"{where}: <{tag}> is {s!r}, not a finite number.")
    return x


def read_visp_cameras(path) -> list:
    """Every ``<camera>`` of a vpXmlParserCamera file as dicts: name, width, height (0 when not
    stated), model (the type used), K, dist, source."""
    import xml.etree.ElementTree as ET

    p = Path(path)
    try:
        root = ET.fromstring(read_input_bytes(p, "camera file"))
    except ET.ParseError as e:
        raise InputError(f"{p}: not a ViSP camera file (vpXmlParserCamera XML): {e}.") from None
    cams = root.findall("camera") if root.tag == "root" else []
    if not cams:
        raise InputError(f"{p}: no <camera> under <root>; not a ViSP camera file (vpXmlParserCamera).")
    out = []
    for k, c in enumerate(cams):
        name = _text(c, "name") or ""
        where = f"{p}: camera {name or k + 1!r}"
        try:
            w, h = int(_text(c, "image_width") or 0), int(_text(c, "image_height") or 0)
        except ValueError:
            raise InputError(f"{where}: image_width / image_height are not whole numbers.") from None
        models = {(_text(m, "type") or ""): m for m in c.findall("model")}
        model = next((t for t in ("perspectiveProjWithDistortion", "perspectiveProjWithoutDistortion") if t in models), None)
        if model is None:
            kinds = ", ".join(sorted(models)) or "none"
            raise InputError(f"{where}: no perspective projection model (it has: {kinds}); calibgraph reads "
                             "perspectiveProjWithDistortion or perspectiveProjWithoutDistortion (a Kannala-Brandt fisheye "
                             "model is not OpenCV's: calibrate the camera with `calibgraph intrinsics`).")
        m = models[model]
        mw = f"{where}, model {model}"
        px, py, u0, v0 = (_number(m, t, mw) for t in ("px", "py", "u0", "v0"))
        kud = _number(m, "kud", mw) if model == "perspectiveProjWithDistortion" else 0.0
        if px <= 0 or py <= 0:
            raise InputError(f"{mw}: px = {px:g}, py = {py:g}; both must be positive (pixels).")
        out.append({"name": name, "width": w, "height": h, "model": model,
                    "K": [[px, 0.0, u0], [0.0, py, v0], [0.0, 0.0, 1.0]], "dist": [kud + 0.0, 0.0, 0.0, 0.0, 0.0],
                    "source": "calibration" if c.find("additional_information") is not None else "factory"})
    return out


def pick_camera(cams: list, size: tuple, path) -> tuple:
    """(camera, warning or '') for images of ``size`` (w, h): see the module docstring."""
    w, h = size
    fit = [c for c in cams if (c["width"], c["height"]) in ((w, h), (0, 0))]
    if not fit:
        have = ", ".join(f"{c['name'] or '?'} {c['width']}x{c['height']}" for c in cams)
        raise InputError(f"{path}: no camera for {w}x{h} px images (it holds {have}); use the camera file of the "
                         "resolution the images were taken at.")
    chosen = next((c for c in fit if c["name"] == "Camera"), fit[0]) if len(fit) > 1 else fit[0]
    if len(cams) == 1:
        return chosen, ""
    why = ("the one of the images' size" if len(fit) == 1 else
           f"of {len(fit)} of the images' size, the one named 'Camera'" if chosen["name"] == "Camera" else
           f"the first of {len(fit)} of the images' size")
    return chosen, (f"{len(cams)} cameras in the file; using {chosen['name'] or 'unnamed'!r} ({chosen['model']}), {why}; "
                    "give --intrinsics camera=CAM.yaml for another")


# ---------------------------------------------------------------------------------------------
# the board
# ---------------------------------------------------------------------------------------------
def read_target_file(path) -> tuple:
    """(Target, mode or None) of a calibgraph target spec file; ``mode`` (eye_in_hand / eye_to_hand)
    is read beside ``target:`` for ViSP's folders."""
    p = Path(path)
    d = dict(read_yaml(p, "target spec"))
    mode = d.pop("mode", None)
    if mode is not None and mode not in ("eye_in_hand", "eye_to_hand"):
        raise InputError(f"{p}: mode must be eye_in_hand or eye_to_hand, got {mode!r}.")
    try:
        return Target.from_dict(d["target"] if isinstance(d.get("target"), dict) else d), mode
    except InputError as e:
        raise InputError(f"{p}: {e}") from None


def read_chessboard_data(path) -> Target:
    """The board of ViSP's ``chessboard-data.txt`` ("W x H" inner corners, "square size: S m")."""
    p = Path(path)
    text = read_input_text(p, "chessboard description")
    size = re.search(r"(\d+)\s*[xX\u00d7]\s*(\d+)", text)
    sq = re.search(r"square\s*size\s*[:=]?\s*([0-9]*\.?[0-9]+(?:[eE][-+]?\d+)?)\s*(mm|m)?\b", text, re.IGNORECASE)
    if size is None or sq is None:
        raise InputError(f"{p}: expected the chessboard's inner corners as 'W x H' and 'square size: S m'; "
                         f"or {BOARD_HOW}.")
    pitch = float(sq.group(1)) * (1e-3 if (sq.group(2) or "m").lower() == "mm" else 1.0)
    try:
        return Target(kind="checkerboard", rows=int(size.group(2)), cols=int(size.group(1)), pitch_m=pitch)
    except InputError as e:
        raise InputError(f"{p}: {e}") from None


def visp_board(root: Path, target=None, fallback_target=None) -> tuple:
    """(Target, mode or None, where it came from) by the order in the module docstring."""
    mode = None
    side = root / SIDE_FILE
    if side.is_file():
        side_target, mode = read_target_file(side)
    else:
        side_target = None
    if target is not None:
        return target, mode, "the command line"
    if side_target is not None:
        return side_target, mode, str(side)
    if (root / CHESSBOARD_FILE).is_file():
        return read_chessboard_data(root / CHESSBOARD_FILE), mode, str(root / CHESSBOARD_FILE)
    if fallback_target is not None:
        return fallback_target, mode, "the stored result"
    raise InputError(f"{root}: a ViSP hand-eye folder that names no board (no {SIDE_FILE}, no {CHESSBOARD_FILE}): "
                     f"{BOARD_HOW}.")


# ---------------------------------------------------------------------------------------------
# the folder
# ---------------------------------------------------------------------------------------------
def _image_for(n: int, prefix: str, images: dict) -> str | None:
    """The image file of capture ``n``: ``<prefix>image-<n>.*`` first, else the one image whose name
    ends in ``-<n>`` / ``_<n>``."""
    cands = images.get(n, [])
    exact = [c for c in cands if Path(c).stem == f"{prefix}image-{n}"]
    if exact:
        return exact[0]
    same = [c for c in cands if c.startswith(prefix)] if prefix else cands
    return same[0] if len(same) == 1 else (cands[0] if len(cands) == 1 else None)


def load_visp_dataset(root, target=None, fallback_target=None):
    """Read a ViSP hand-eye folder as a :class:`calibgraph.io.dataset.Dataset` (one camera named
    ``camera``; views carry images, no detections). ``target``: the board from the command line
    (wins over the folder's files); ``fallback_target``: the board to use when the folder names none
    (a stored result's)."""
    root = Path(root)
    poses = _pose_files(root)
    if not poses:
        raise InputError(f"{root}: no ViSP pose files (pose_fPe_N.yaml or *_rPe_N.yaml).")
    twice = {n: names for n, names in poses.items() if len(names) > 1}
    if twice:
        n, names = min(twice.items())
        raise InputError(f"{root}: two pose files for capture {n} ({', '.join(names)}); a ViSP folder holds one "
                         "series: keep one of them (in a copy of the folder).")
    images = {}
    for name in _files(root):
        stem, ext = os.path.splitext(name)
        m = IMAGE_RE.match(stem)
        if ext.lower() in IMAGE_EXT and m:
            images.setdefault(int(m.group("n")), []).append(name)
    pairs, prefixes = [], set()
    for n in sorted(poses):
        pose = poses[n][0]
        prefix = POSE_RE.match(pose).group("prefix")
        prefix = prefix[: -len("pose_")] if prefix.endswith("pose_") else prefix
        prefixes.add(prefix)
        img = _image_for(n, prefix, images)
        if img is None:
            had = images.get(n)
            why = f"several images end in {n} ({', '.join(had)})" if had else f"expected {prefix}image-{n}.png"
            raise InputError(f"{root / pose}: no image for this pose ({why}); ViSP pairs pose N with image N: add the "
                             "image, or leave the pose file out (in a copy of the folder).")
        pairs.append((n, pose, img))
    used = {img for _, _, img in pairs}
    problems = [(str(root / name), "an image with no pose file of its number; not used")
                for names in images.values() for name in names if name not in used
                and any(name.startswith(p + "image") for p in prefixes)]

    size = next((s for s in (image_size(root / img) for _, _, img in pairs) if s is not None), None)
    if size is None:
        raise InputError(f"{root}: none of the {len(pairs)} images can be read; cannot determine the image size.")
    cam_file = _camera_file(root, prefixes)
    if cam_file is None:
        names = " or ".join(f"{p}camera.xml" for p in sorted(prefixes))
        raise InputError(f"{root}: no ViSP camera file ({names}: vpCameraParameters XML) beside the pose files; "
                         "ViSP's acquisition tool writes it with the images: put it back beside them.")
    cam, note = pick_camera(read_visp_cameras(cam_file), size, cam_file)
    if note:
        problems.append((str(cam_file), note))
    intr = Intrinsics(K=cam["K"], dist=cam["dist"], width_px=size[0], height_px=size[1], source=cam["source"])

    board, mode, _ = visp_board(root, target, fallback_target)
    captures, views = [], []
    for n, pose, img in pairs:
        captures.append(Capture(index=n, T_base_flange=read_visp_pose(root / pose)))
        views.append(View(camera=CAMERA, capture=n, image=img))
    return Dataset(root=root, target=board, cameras={CAMERA: intr}, captures=tuple(captures), views=tuple(views),
                   mode=mode or "eye_in_hand", solver={}, problems=tuple(problems))
