"""rosbag2 (sqlite3 or MCAP storage) -> calibgraph dataset, with the pure-Python ``rosbags`` library.

What is read:

- cameras: ``sensor_msgs/Image`` (mono8, rgb8, bgr8, rgba8, bgra8, mono16) or
  ``sensor_msgs/CompressedImage`` topics, each with a ``sensor_msgs/CameraInfo`` on the sibling
  topic ``<namespace>/camera_info`` (``/cam0/color/image_raw`` -> ``/cam0/color/camera_info``), or
  the only CameraInfo under the same first namespace. Unless named, image topics are found by
  type; a camera is named after its topic's first namespace (``/cam0/color/image_raw`` -> ``cam0``),
  depth topics are skipped and a raw topic is preferred to its ``/compressed`` twin;
- the robot: the ``/tf`` + ``/tf_static`` chain from ``base_frame`` to ``flange_frame`` (Franka
  defaults: ``fr3_link0``/``panda_link0`` -> ``fr3_link8``/``panda_link8``, whichever the bag has),
  or, when TF has no such chain (or ``robot_pose='joint_states'``), ``/joint_states`` through a
  forward-kinematics callable (the CLI passes the Franka FR3/Panda model). Whenever joint states
  exist the capture stores ``q_rad`` (the sample nearest the capture moment, within the still
  moment);

Stills: the robot pose samples are split into *still* spans (every sample within ``still_mm`` /
``still_deg`` of the span's first, lasting at least ``min_still_s``). Each camera contributes the
frame it has stamped inside a still (the one nearest the still's middle, when it has several), and a
still with a frame from any camera becomes a capture with those views (the pose is the sample
nearest the middle): cameras that publish at a lower rate, or only when they see the board, cost
nothing but their own missing views. A camera with no frame in any still is left out with a
warning; a still with no frame from any camera is skipped, and the report says why. Stamps are the
messages' header stamps (bag time when zero). Intrinsics come from CameraInfo with source
'calibration'. A frame that cannot be decoded costs its view, with a warning.

Errors name what is missing: a CameraInfo for a camera with frames, a TF path between the frames, a
still moment, any camera frame in any still (with the image topics seen). The output folder is
checked before the bag is read, as every ``--out`` is (:func:`calibgraph.io.files.output_folder`).
"""

from __future__ import annotations

import posixpath
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.problem import Capture
from calibgraph.core.targets import a4_board_54
from calibgraph.core.transforms import inv, log_so3, make_T, quat_xyzw_to_R
from calibgraph.io.dataset import image_relpath, write_capture, write_header
from calibgraph.io.files import atomic_write_png, output_folder
from calibgraph.io.lock import dataset_lock

__all__ = ["import_rosbag2", "ImportReport", "BASE_FRAMES", "FLANGE_FRAMES", "camera_name_of"]

BASE_FRAMES = ("fr3_link0", "panda_link0")
FLANGE_FRAMES = ("fr3_link8", "panda_link8")
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
INFO = "sensor_msgs/msg/CameraInfo"
TF = "tf2_msgs/msg/TFMessage"
JOINTS = "sensor_msgs/msg/JointState"


@dataclass(frozen=True)
class ImportReport:
    """What the import found and wrote.

    ``cameras``: the dataset's cameras (camera -> image topic); ``stills_per_camera``: how many
    captures each appears in; ``left_out``: camera -> (topic, why) of cameras with no frame in any
    still; ``skipped``: (still start s, reason) of stills that became no capture; ``warnings``:
    lines for the user (cameras left out, frames that could not be decoded)."""

    out: Path
    cameras: dict  # camera -> image topic
    robot_source: str  # 'joint_states' or 'tf base->flange'
    still_segments: int
    captures: int
    skipped: tuple  # (segment start s, reason)
    stills_per_camera: dict = field(default_factory=dict)
    left_out: dict = field(default_factory=dict)
    warnings: tuple = ()

    def summary(self) -> str:
        cams = ", ".join(f"{n} <- {t}" + (f" (in {self.stills_per_camera[n]} stills)" if n in self.stills_per_camera else "")
                         for n, t in self.cameras.items())
        text = (f"{self.captures} captures from {self.still_segments} still moments (robot from {self.robot_source}); "
                f"cameras: {cams}")
        if self.left_out:
            text += "; left out: " + ", ".join(f"{n} <- {t} ({why})" for n, (t, why) in self.left_out.items())
        if self.skipped:
            reasons = {}
            for t0, why in self.skipped:
                reasons.setdefault(why, []).append(t0)
            text += f"; {len(self.skipped)} moments skipped: " + "; ".join(
                f"{why} (at t = {', '.join(f'{t:.1f}' for t in ts[:4])}{', ...' if len(ts) > 4 else ''} s)"
                for why, ts in reasons.items())
        return text


def camera_name_of(topic: str) -> str:
    """First namespace of a topic: ``/cam0/color/image_raw`` -> ``cam0``."""
    parts = [p for p in topic.split("/") if p]
    return parts[0] if len(parts) > 1 else parts[0] if parts else topic


def _stamp(msg, t_ns: int) -> float:
    h = getattr(msg, "header", None)
    if h is not None and (h.stamp.sec or h.stamp.nanosec):
        return h.stamp.sec + h.stamp.nanosec * 1e-9
    return t_ns * 1e-9


def _decode(msg, msgtype: str, topic: str) -> np.ndarray:
    import cv2

    if msgtype == COMPRESSED:
        img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"{topic}: a CompressedImage ({msg.format!r}) could not be decoded.")
        return img
    enc = msg.encoding.lower()
    ch = {"mono8": 1, "8uc1": 1, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4, "mono16": 1, "16uc1": 1}.get(enc)
    if ch is None:
        raise InputError(f"{topic}: image encoding {msg.encoding!r} is not supported (mono8/16, rgb8, bgr8, rgba8, bgra8).")
    dt = np.uint16 if enc in ("mono16", "16uc1") else np.uint8
    row = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.height, msg.step)
    img = row[:, : msg.width * ch * np.dtype(dt).itemsize].copy().view(dt)
    if msg.is_bigendian and dt == np.uint16:
        img = img.byteswap()
    img = img.reshape(msg.height, msg.width, ch) if ch > 1 else img.reshape(msg.height, msg.width)
    if enc == "rgb8":
        img = img[:, :, ::-1]
    elif enc == "rgba8":
        img = cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    elif enc == "bgra8":
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)
    return img


def _intrinsics(msg, topic: str) -> Intrinsics:
    K = np.asarray(msg.k, float).reshape(3, 3)
    if not K[0, 0] > 0:
        raise InputError(f"{topic}: CameraInfo has no calibration (K is zero).")
    d = np.asarray(msg.d, float)
    model = (msg.distortion_model or "plumb_bob").lower()
    if model not in ("plumb_bob", "rational_polynomial", ""):
        raise InputError(f"{topic}: distortion model {msg.distortion_model!r} is not supported (plumb_bob, rational_polynomial).")
    return Intrinsics(K=K, dist=d if d.size else np.zeros(5), width_px=int(msg.width), height_px=int(msg.height),
                      source="calibration")


def _tf_T(tr) -> np.ndarray:
    q, t = tr.rotation, tr.translation
    return make_T(quat_xyzw_to_R([q.x, q.y, q.z, q.w]), [t.x, t.y, t.z])


class _TfTree:
    """Static and time-stamped edges parent -> child; a chain is composed from the latest sample
    of each dynamic edge at or before the query time."""

    def __init__(self):
        self.static, self.dynamic = {}, {}  # child -> (parent, T) / child -> (parent, [(t, T)])

    def add(self, msg, static: bool, t_ns: int):
        for tf in msg.transforms:
            child, parent = tf.child_frame_id.lstrip("/"), tf.header.frame_id.lstrip("/")
            if static:
                self.static[child] = (parent, _tf_T(tf.transform))
            else:
                self.dynamic.setdefault(child, (parent, []))[1].append((_stamp(tf, t_ns), _tf_T(tf.transform)))

    def frames(self) -> set:
        out = set(self.static) | set(self.dynamic)
        return out | {p for p, _ in self.static.values()} | {p for p, _ in self.dynamic.values()}

    def path(self, base: str, flange: str):
        """Edges (child names) from flange up to base, or None."""
        up, f = [], flange
        while f != base:
            nxt = self.static.get(f) or self.dynamic.get(f)
            if nxt is None or len(up) > 64:
                return None
            up.append(f)
            f = nxt[0]
        return up

    def times(self, chain) -> np.ndarray:
        ts = sorted({t for c in chain if c in self.dynamic for t, _ in self.dynamic[c][1]})
        return np.asarray(ts) if ts else np.array([0.0])

    def pose(self, chain, t: float) -> np.ndarray:
        T = np.eye(4)
        for c in chain:  # flange side first: T_base_flange = T_base_x ... T_y_flange
            if c in self.static:
                T_pc = self.static[c][1]
            else:
                samples = self.dynamic[c][1]
                ts = np.fromiter((s for s, _ in samples), float)
                i = int(np.clip(np.searchsorted(ts, t + 1e-9) - 1, 0, len(samples) - 1))
                T_pc = samples[i][1]
            T = T_pc @ T
        return T


def _pick_cameras(topics: dict, named: dict) -> dict:
    """camera -> (image topic, msgtype)."""
    if named:
        out = {}
        for name, topic in named.items():
            if topic not in topics:
                raise InputError(f"camera {name}: topic {topic} is not in the bag (image topics: "
                                 f"{', '.join(sorted(t for t, m in topics.items() if m in (IMAGE, COMPRESSED))) or 'none'}).")
            if topics[topic] not in (IMAGE, COMPRESSED):
                raise InputError(f"camera {name}: topic {topic} is a {topics[topic]}, not an Image or CompressedImage.")
            out[name] = (topic, topics[topic])
        return out
    by_cam = {}
    for t, m in sorted(topics.items()):
        if m not in (IMAGE, COMPRESSED) or "depth" in t.lower():
            continue
        by_cam.setdefault(camera_name_of(t), []).append((t, m))
    out = {}
    for name, cands in by_cam.items():
        raw = [c for c in cands if c[1] == IMAGE]
        pool = raw or cands
        color = [c for c in pool if "color" in c[0] or "image_raw" in c[0]]
        out[name] = (color or pool)[0]
    if not out:
        raise InputError("the bag has no sensor_msgs/Image or CompressedImage topic (besides depth).")
    return out


def _info_topic(image_topic: str, topics: dict) -> str:
    t = image_topic[: -len("/compressed")] if image_topic.endswith("/compressed") else image_topic
    sib = posixpath.join(posixpath.dirname(t), "camera_info")
    if topics.get(sib) == INFO:
        return sib
    ns = camera_name_of(image_topic)
    same = [k for k, m in topics.items() if m == INFO and camera_name_of(k) == ns]
    if len(same) == 1:
        return same[0]
    raise InputError(f"no CameraInfo for {image_topic} (looked for {sib}"
                     + (f"; several under /{ns}: {', '.join(sorted(same))}" if same else "") + ").")


def _still_segments(times: np.ndarray, poses: list, still_mm: float, still_deg: float, min_still_s: float) -> list:
    """[(t_start, t_end, index of the middle sample)] of runs where the pose stays put."""
    segs, i, n = [], 0, len(times)
    while i < n:
        j = i + 1
        while j < n:
            d = inv(poses[i]) @ poses[j]
            if (np.linalg.norm(poses[j][:3, 3] - poses[i][:3, 3]) * 1e3 > still_mm
                    or np.degrees(np.linalg.norm(log_so3(d[:3, :3]))) > still_deg):
                break
            j += 1
        if times[j - 1] - times[i] >= min_still_s:
            mid_t = 0.5 * (times[i] + times[j - 1])
            segs.append((times[i], times[j - 1], i + int(np.argmin(np.abs(times[i:j] - mid_t)))))
        i = j
    return segs


def import_rosbag2(bag, out, base_frame: str | None = None, flange_frame: str | None = None, cameras: dict | None = None,
                   target=None, fk=None, joint_names: tuple | None = None, still_mm: float = 0.2,
                   still_deg: float = 0.02, min_still_s: float = 0.3, robot_pose: str = "auto", progress=None) -> ImportReport:
    """Read the rosbag2 at ``bag`` and write a calibgraph dataset to ``out`` (module docstring).

    ``cameras``: name -> image topic (default: found by type); ``target``: the board (default: the
    A4 54-corner board); ``fk(q_rad) -> T_base_flange``: the robot model for /joint_states;
    ``joint_names``: the 7 joint names in order (default ``fr3_joint1..7`` or ``panda_joint1..7``,
    whichever the messages carry); ``robot_pose``: 'auto' (TF chain when the bag has one, else
    joint states), 'tf' or 'joint_states'; ``progress``: a callable receiving progress lines."""
    if robot_pose not in ("auto", "tf", "joint_states"):
        raise InputError(f"robot_pose must be auto, tf or joint_states, got {robot_pose!r}.")
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise InputError("reading rosbag2 needs the 'rosbags' package: pip install 'calibgraph[rosbag]'") from None
    bag, out = Path(bag), Path(out)
    if not bag.exists():
        raise InputError(f"{bag}: no such bag.")
    if bag.is_file():  # the .db3 / .mcap inside a bag folder: read the folder (its metadata.yaml)
        if not (bag.parent / "metadata.yaml").is_file():
            raise InputError(f"{bag}: a rosbag2 is read from its folder with metadata.yaml; none beside this file.")
        bag = bag.parent
    if not (bag / "metadata.yaml").is_file():
        raise InputError(f"{bag}: not a rosbag2 folder (no metadata.yaml).")
    if out.is_dir() and (out / "dataset.yaml").exists():
        raise InputError(f"{out}: a dataset already exists here; choose a new --out.")
    if out.is_dir() and (out / "captures").exists():
        raise InputError(f"{out}: holds captures/ of another run; choose a new --out.")
    created = not out.exists()
    output_folder(out, "dataset folder (--out)")
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as e:  # noqa: BLE001 - rosbags raises several types for unreadable bags
        _remove_if_empty(out, created)
        raise InputError(f"{bag}: not a readable rosbag2 ({str(e).splitlines()[0] if str(e) else type(e).__name__}).") from None
    try:
        with dataset_lock(out, "import"):  # a solve or a second import of this folder is refused meanwhile
            return _import(reader, bag, out, base_frame, flange_frame, cameras or {}, target, fk, joint_names,
                           still_mm, still_deg, min_still_s, robot_pose, progress or (lambda s: None))
    except BaseException:
        _remove_if_empty(out, created)
        raise
    finally:
        reader.close()


def _remove_if_empty(out: Path, created: bool) -> None:
    """A refused import leaves no empty folder behind where there was none."""
    if created:
        try:
            out.rmdir()
        except OSError:
            pass


def _import(reader, bag, out, base_frame, flange_frame, named, target, fk, joint_names, still_mm, still_deg, min_still_s,
            robot_pose, say) -> ImportReport:
    topics = {c.topic: c.msgtype for c in reader.connections}
    cams = _pick_cameras(topics, named)
    info_topics, info_missing = {}, {}
    for n, (t, _) in cams.items():
        try:
            info_topics[n] = _info_topic(t, topics)
        except InputError as e:  # an error only if this camera has frames to import
            info_missing[n] = str(e)
    has_joints = any(m == JOINTS for m in topics.values())
    if robot_pose == "joint_states" and not has_joints:
        raise InputError(f"{bag}: no sensor_msgs/JointState topic, so no joint states to take the robot pose from.")
    tf = _TfTree()
    intr, frames, joint_samples = {}, {n: [] for n in cams}, []
    wanted = {t for t, _ in cams.values()} | set(info_topics.values())
    wanted |= {t for t, m in topics.items() if m in (JOINTS, TF)}
    conns = [c for c in reader.connections if c.topic in wanted]
    topic_cam = {t: n for n, (t, _) in cams.items()}
    info_cam = {t: n for n, t in info_topics.items()}
    for conn, t_ns, raw in reader.messages(connections=conns):
        if conn.topic in topic_cam:
            # decode later: keep the raw message (a bag may hold thousands of frames)
            frames[topic_cam[conn.topic]].append((t_ns, conn, raw))
            continue
        msg = reader.deserialize(raw, conn.msgtype)
        if conn.topic in info_cam:
            intr.setdefault(info_cam[conn.topic], _intrinsics(msg, conn.topic))
        elif conn.msgtype == TF:
            tf.add(msg, conn.topic.endswith("tf_static"), t_ns)
        elif conn.msgtype == JOINTS:
            joint_samples.append((_stamp(msg, t_ns), list(msg.name), np.asarray(msg.position, float)))
    times, poses, source = _robot_track(tf, joint_samples, fk, joint_names, base_frame, flange_frame, robot_pose)
    jt, jq = _joint_track(joint_samples, joint_names) if joint_samples else (None, None)
    segs = _still_segments(times, poses, still_mm, still_deg, min_still_s)
    if not segs:
        raise InputError(f"no still moment: the robot ({source}) never stays within {still_mm:g} mm / {still_deg:g} deg "
                         f"for {min_still_s:g} s in {bag}.")
    stamps = {n: np.asarray([_stamp(reader.deserialize(raw, conn.msgtype), t_ns) for t_ns, conn, raw in frames[n]])
              for n in cams}
    picks = [_frames_in_still(stamps, t0, t1, times[mid]) for t0, t1, mid in segs]
    in_stills = {n: sum(n in p for p in picks) for n in cams}
    if not any(in_stills.values()):
        seen = ", ".join(f"{t} ({len(frames[n])} frames)" for n, (t, _) in cams.items())
        others = sorted(t for t, m in topics.items() if m in (IMAGE, COMPRESSED) and t not in topic_cam)
        raise InputError(f"no camera has a frame in any of the {len(segs)} still moments of {bag} (the robot from "
                         f"{source}); image topics seen: {seen}" + (f"; not read: {', '.join(others)}" if others else "")
                         + "; check that the cameras publish while the robot rests (header stamps).")
    for n in cams:
        if in_stills[n]:
            if n in info_missing:
                raise InputError(info_missing[n])
            if n not in intr:
                raise InputError(f"no CameraInfo message on {info_topics[n]} for camera {n} ({cams[n][0]}).")
    warnings, skipped, per_cam = [], [], {n: 0 for n in cams}
    written = 0
    for (t0, t1, mid), pick in zip(segs, picks):
        if not pick:
            skipped.append((float(t0), "no frame from any camera while still"))
            continue
        mid_t = times[mid]
        views = {}
        for n, i in pick.items():
            t_ns, conn, raw = frames[n][i]
            try:
                img = _decode(reader.deserialize(raw, conn.msgtype), conn.msgtype, conn.topic)
            except InputError as e:
                warnings.append(f"{e} (t = {stamps[n][i]:.3f} s): that view is left out.")
                continue
            rel = image_relpath(n, written)
            atomic_write_png(out / rel, img)
            views[n] = {"image": rel, "stamp_s": float(stamps[n][i])}
        if not views:
            skipped.append((float(t0), "no frame of it could be decoded"))
            continue
        q = None
        if jt is not None and jt.size:
            j = int(np.argmin(np.abs(jt - mid_t)))
            q = jq[j] if t0 - 1e-6 <= jt[j] <= t1 + 1e-6 else None
        write_capture(out, Capture(index=written, T_base_flange=poses[mid], q_rad=q, stamp_s=float(mid_t)), views)
        for n in views:
            per_cam[n] += 1
        written += 1
        say(f"capture {written}: t = {mid_t:.2f} s, {', '.join(views)}")
    left_out = {}
    for n, (t, _) in cams.items():
        if per_cam[n]:
            continue
        why = ("no frame in the bag" if not frames[n] else
               f"none of its {len(frames[n])} frames is inside a still moment" if not in_stills[n] else
               f"none of its frames in {in_stills[n]} still moments could be decoded")
        left_out[n] = (t, why)
        warnings.append(f"camera {n} ({t}): {why}; it is left out of the dataset.")
    if not written:
        raise InputError(f"no capture: no frame in the {len(segs)} still moments of {bag} could be decoded "
                         f"({'; '.join(warnings[:2])}).")
    used = {n: cams[n][0] for n in cams if per_cam[n]}
    # the header last: a folder without dataset.yaml is an import that did not finish
    write_header(out, target or a4_board_54(), {n: intr[n] for n in used},
                 extra={"source": {"rosbag2": str(bag), "robot": source}})
    return ImportReport(out, used, source, len(segs), written, tuple(skipped), stills_per_camera={n: per_cam[n] for n in used},
                        left_out=left_out, warnings=tuple(warnings))


def _frames_in_still(stamps: dict, t0: float, t1: float, mid_t: float) -> dict:
    """camera -> index of its frame stamped inside [t0, t1] nearest ``mid_t`` (cameras with none left out)."""
    pick = {}
    for n, st in stamps.items():
        inside = np.flatnonzero((st >= t0) & (st <= t1))
        if inside.size:
            pick[n] = int(inside[np.argmin(np.abs(st[inside] - mid_t))])
    return pick


def _joint_track(joint_samples: list, joint_names):
    """(times (N,), [q_rad (7,)]) of the samples that carry every joint, in time order."""
    names0 = joint_samples[0][1]
    if joint_names is None:
        for prefix in ("fr3_joint", "panda_joint"):
            if all(f"{prefix}{i}" in names0 for i in range(1, 8)):
                joint_names = tuple(f"{prefix}{i}" for i in range(1, 8))
                break
    if joint_names is None:
        raise InputError(f"/joint_states carries {names0}, not fr3_joint1..7 or panda_joint1..7.")
    rows = []
    for t, names, pos in sorted(joint_samples, key=lambda s: s[0]):
        idx = {n: i for i, n in enumerate(names)}
        if all(j in idx for j in joint_names):
            rows.append((t, pos[[idx[j] for j in joint_names]]))
    return np.asarray([r[0] for r in rows]), [r[1] for r in rows]


def _robot_track(tf: _TfTree, joint_samples: list, fk, joint_names, base_frame, flange_frame, robot_pose: str):
    """(times (N,), T_base_flange list, source): the TF chain base -> flange, or the joint states
    through ``fk``."""
    frames = tf.frames()
    base = base_frame or next((f for f in BASE_FRAMES if f in frames), None)
    flange = flange_frame or next((f for f in FLANGE_FRAMES if f in frames), None)
    chain = tf.path(base, flange) if base is not None and flange is not None else None
    if robot_pose == "tf" or (robot_pose == "auto" and (chain is not None or not joint_samples)):
        if base is None or flange is None:
            raise InputError(f"no robot pose: {'no /joint_states, and ' if not joint_samples else ''}TF has no "
                             f"{'base frame ' + (base_frame or '/'.join(BASE_FRAMES)) if base is None else 'flange frame ' + (flange_frame or '/'.join(FLANGE_FRAMES))}"
                             f" (frames: {', '.join(sorted(frames)) or 'none'}); pass --base-frame / --flange-frame.")
        if chain is None:
            raise InputError(f"no TF path from {base} to {flange} in /tf + /tf_static (frames: {', '.join(sorted(frames))}).")
        times = tf.times(chain)
        return times, [tf.pose(chain, t) for t in times], f"tf {base}->{flange}"
    if fk is None:
        raise InputError("the robot pose must come from /joint_states, but no robot model was given.")
    times, qs = _joint_track(joint_samples, joint_names)
    return times, [fk(q) for q in qs], "joint_states"
