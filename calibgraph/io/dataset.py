"""The calibgraph dataset folder: what capture writes and solve reads.

Layout (``calibgraph-dataset/1``)::

    DATASET/
      dataset.yaml              target, cameras (intrinsics), mode, optional solver settings
      captures/000000.json      one file per robot pose, written atomically (tmp + rename)
      images/<camera>/000000.png
      ground_truth.json         simulated datasets only

``dataset.yaml``::

    format: calibgraph-dataset/1
    mode: eye_to_hand            # or eye_in_hand
    units: {length: m, angle: rad, pixel: px}
    target: {kind: checkerboard, rows: 6, cols: 9, pitch_m: 0.025}
    cameras:
      cam0: {K: [[fx,0,cx],[0,fy,cy],[0,0,1]], dist: [k1,k2,p1,p2,k3], width_px: 1920, height_px: 1080}
    solver: {fk_sigma_translation_m: 1.0e-4}      # optional SolverOptions fields

``captures/NNNNNN.json``::

    {"index": 12, "T_base_flange": 4x4 (m), "q_rad": [7 joints] | null, "stamp_s": 1712.3,
     "views": {"cam0": {"image": "images/cam0/000012.png", "stamp_s": 1712.31,
                        "detection": {"ids": [...], "uv_px": [[u, v], ...]} | null}}}

A view without ``detection`` is detected from its image when the problem is built; the detector
caches its results in ``DATASET/.calibgraph_cache/detections-<hash>.json`` (the hash covers the
target spec, detector version and options).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.problem import Capture, Detection, Problem, SolverOptions
from calibgraph.core.targets import Target
from calibgraph.core.version import format_age
from calibgraph.io.files import atomic_write_text, read_input_bytes, read_yaml

FORMAT = "calibgraph-dataset/1"


@dataclass(frozen=True)
class View:
    """One camera's frame at one capture."""

    camera: str
    capture: int
    image: str | None
    stamp_s: float | None = None
    ids: np.ndarray | None = None
    uv_px: np.ndarray | None = None

    @property
    def detected(self) -> bool:
        return self.ids is not None


@dataclass(frozen=True)
class Dataset:
    """A dataset in memory; ``root`` is the folder it was read from (image paths are relative to it)."""

    root: Path
    target: Target
    cameras: dict
    captures: tuple
    views: tuple
    mode: str = "eye_to_hand"
    solver: dict = field(default_factory=dict)
    problems: tuple = ()  # (file, message) for captures that could not be read

    def to_problem(self, method: str = "joint", options: SolverOptions | None = None, detector=None) -> Problem:
        """Build the solver's Problem. Views without detections are detected with ``detector``
        (a callable ``(view, dataset) -> (ids, uv_px) | None``); without one they are skipped."""
        dets = []
        for v in self.views:
            ids, uv = v.ids, v.uv_px
            if ids is None and detector is not None:
                got = detector(v, self)
                if got is None:
                    continue
                ids, uv = got
            if ids is None or len(ids) == 0:
                continue
            dets.append(Detection(camera=v.camera, capture=v.capture, ids=ids, uv_px=uv,
                                  image=str(self.root / v.image) if v.image else None))
        if options is None:
            try:
                options = SolverOptions(**self.solver)
            except TypeError as e:
                raise InputError(f"{self.root / 'dataset.yaml'}: solver settings: {e}") from None
        return Problem(points_board_m=self.target.points_board_m, cameras=dict(self.cameras),
                       captures=self.captures, detections=tuple(dets), mode=self.mode, method=method,
                       options=options, target=self.target)


def write_header(root, target: Target, cameras: dict, mode: str = "eye_to_hand", solver: dict | None = None,
                 extra: dict | None = None) -> Path:
    """Write ``dataset.yaml`` (atomically)."""
    import yaml

    root = Path(root)
    d = {
        "format": FORMAT,
        "mode": mode,
        "units": {"length": "m", "angle": "rad", "pixel": "px"},
        "frame_convention": "T_a_b maps points from frame b to frame a (p_a = T_a_b @ p_b)",
        "target": target.to_dict(),
        "cameras": {n: i.to_dict() for n, i in cameras.items()},
    }
    if solver:
        d["solver"] = solver
    if extra:
        d.update(extra)
    atomic_write_text(root / "dataset.yaml", yaml.safe_dump(d, sort_keys=False))
    return root / "dataset.yaml"


def capture_path(root, index: int) -> Path:
    return Path(root) / "captures" / f"{int(index):06d}.json"


def image_relpath(camera: str, index: int, ext: str = "png") -> str:
    return f"images/{camera}/{int(index):06d}.{ext}"


def write_capture(root, capture: Capture, views: dict) -> Path:
    """Write one capture file atomically. ``views``: camera -> dict(image=, stamp_s=, ids=, uv_px=)."""
    out = {
        "index": capture.index,
        "T_base_flange": capture.T_base_flange.tolist(),
        "q_rad": None if capture.q_rad is None else capture.q_rad.tolist(),
        "stamp_s": capture.stamp_s,
        "views": {},
    }
    for cam, v in views.items():
        det = None
        if v.get("ids") is not None:
            det = {"ids": np.asarray(v["ids"]).astype(int).tolist(), "uv_px": np.asarray(v["uv_px"], float).tolist()}
        out["views"][cam] = {"image": v.get("image"), "stamp_s": v.get("stamp_s"), "detection": det}
    p = capture_path(root, capture.index)
    atomic_write_text(p, json.dumps(out))
    return p


def write_problem(root, problem, target: Target | None = None) -> Path:
    """A problem's captures (with their joint angles) and detections as a dataset folder: detections
    stored, no images (simulated sets for tests and benches). ``target``: default the problem's."""
    write_header(root, target or problem.target, dict(problem.cameras), mode=problem.mode)
    by_cap = {}
    for d in problem.detections:
        by_cap.setdefault(d.capture, {})[d.camera] = {"image": None, "ids": d.ids, "uv_px": d.uv_px}
    for c in problem.captures:
        write_capture(root, c, by_cap.get(c.index, {}))
    return Path(root)


def recorded_run(root) -> dict:
    """What made a calibgraph dataset (``made_by`` of its ``dataset.yaml``: mode, input hashes,
    ``workcell_file``); {} when it does not say (not recorded, another layout, an unreadable header)."""
    try:
        d = read_yaml(Path(root) / "dataset.yaml", "dataset header")
    except (InputError, OSError):
        return {}
    rec = d.get("made_by") if isinstance(d, dict) else None
    return dict(rec) if isinstance(rec, dict) else {}


def recorded_workcell(root) -> Path | None:
    """The workcell file a calibgraph dataset records it was captured with (``made_by.workcell_file``)
    when that file is still there; None otherwise."""
    f = recorded_run(root).get("workcell_file")
    return Path(f) if isinstance(f, str) and Path(f).is_file() else None


def is_calibgraph_dataset(root) -> bool:
    return (Path(root) / "dataset.yaml").is_file()


def _parse_view(v, cam: str, capture: int, n_points: int) -> View:
    """One view of a capture file; :class:`InputError` saying what is wrong with it."""
    if not isinstance(v, dict):
        raise InputError("a view must be a mapping with 'image' and/or 'detection'")
    det = v.get("detection")
    ids = uv = None
    if det is not None:
        if not isinstance(det, dict) or "ids" not in det or "uv_px" not in det:
            raise InputError("'detection' needs 'ids' and 'uv_px'")
        try:
            ids_f = np.asarray(det["ids"], float).reshape(-1)
            uv = np.asarray(det["uv_px"], float).reshape(-1, 2)
        except (TypeError, ValueError):
            raise InputError("detection ids must be integers and uv_px pairs of numbers") from None
        if not np.all(np.isfinite(ids_f)) or np.any(ids_f != np.round(ids_f)):
            raise InputError("detection ids must be integers")
        ids = ids_f.astype(int)
        if len(ids) != len(uv):
            raise InputError(f"{len(ids)} ids but {len(uv)} uv_px points")
        if len(ids) and (ids.min() < 0 or ids.max() >= n_points):
            raise InputError(f"corner ids {ids.min()}..{ids.max()} outside the target's 0..{n_points - 1} "
                             "(another board, or rows/cols of the target section wrong)")
        if len(np.unique(ids)) != len(ids):
            raise InputError("a corner id appears twice")
        if not np.all(np.isfinite(uv)):
            raise InputError("uv_px contains NaN/inf")
    image = v.get("image")
    if image is not None and not isinstance(image, str):
        raise InputError("'image' must be a path relative to the dataset folder")
    return View(camera=cam, capture=capture, image=image, stamp_s=v.get("stamp_s"), ids=ids, uv_px=uv)


def read_calibgraph_dataset(root) -> Dataset:
    """Read a ``calibgraph-dataset/1`` folder. Unreadable capture files are listed in ``problems``
    and skipped; nothing else is dropped silently. (:func:`calibgraph.io.load_dataset` reads any
    supported layout.)"""
    root = Path(root)
    head = read_yaml(root / "dataset.yaml", "dataset header")
    fmt = str(head.get("format", FORMAT))
    if fmt != FORMAT:
        age = format_age(fmt, FORMAT)
        raise InputError(f"{root / 'dataset.yaml'}: format {fmt!r} " + (
            f"is newer than this calibgraph reads ({FORMAT}); upgrade calibgraph." if age == "newer" else
            f"is older than the one this calibgraph reads ({FORMAT}): write the dataset's header as docs/formats.md "
            "describes, or capture (import) it again with this calibgraph." if age == "older" else
            f"is not a calibgraph dataset ({FORMAT})."))
    if "target" not in head or "cameras" not in head:
        raise InputError(f"{root / 'dataset.yaml'}: needs 'target' and 'cameras' sections (see README, Dataset format).")
    where = root / "dataset.yaml"
    if not isinstance(head["target"], dict):
        raise InputError(f"{where}: 'target' must be a mapping (kind, rows, cols, pitch_m).")
    if not isinstance(head["cameras"], dict) or not head["cameras"]:
        raise InputError(f"{where}: 'cameras' must map each camera name to its intrinsics (K, dist, width_px, height_px).")
    if head.get("mode", "eye_to_hand") not in ("eye_to_hand", "eye_in_hand"):
        raise InputError(f"{where}: mode {head.get('mode')!r}; give eye_to_hand or eye_in_hand.")
    if head.get("solver") is not None and not isinstance(head.get("solver"), dict):
        raise InputError(f"{where}: 'solver' must be a mapping of solver settings.")
    try:
        target = Target.from_dict(head["target"])
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    except (TypeError, ValueError, KeyError) as e:
        raise InputError(f"{where}: target section malformed ({e}).") from None
    cameras = {}
    for name, d in head["cameras"].items():
        if not isinstance(d, dict):
            raise InputError(f"{where}: camera {name!r}: needs a mapping with K, dist, width_px, height_px.")
        try:
            cameras[str(name)] = Intrinsics.from_dict(d.get("intrinsics", d))
        except InputError as e:
            raise InputError(f"{root / 'dataset.yaml'}: camera {name!r}: {e}") from None
        except (TypeError, ValueError, KeyError, IndexError) as e:
            raise InputError(f"{root / 'dataset.yaml'}: camera {name!r}: intrinsics malformed ({e}); give K (3x3), "
                             "dist (list), width_px and height_px.") from None
    captures, views, problems = [], [], []
    file_of = {}
    for f in sorted((root / "captures").glob("*.json")):
        try:
            d = json.loads(read_input_bytes(f, "capture file"))  # a FIFO is refused, never waited on
            cap = Capture(index=d["index"], T_base_flange=np.asarray(d["T_base_flange"], float),
                          q_rad=d.get("q_rad"), stamp_s=d.get("stamp_s"))
        except (OSError, ValueError, KeyError, TypeError) as e:
            problems.append((str(f), f"unreadable capture file ({type(e).__name__}: {e}); skipped"))
            continue
        except InputError as e:
            problems.append((str(f), f"{e}; skipped"))
            continue
        if cap.index in file_of:
            raise InputError(f"{f}: capture index {cap.index} is also used by {file_of[cap.index]}; capture indices "
                             "must be unique: renumber one of the two files, or remove it if it is a copy.")
        file_of[cap.index] = f
        captures.append(cap)
        vs = d.get("views") or {}
        if not isinstance(vs, dict):
            problems.append((str(f), "'views' must be a mapping camera -> view; its views skipped"))
            continue
        for cam, v in vs.items():
            if cam not in cameras:
                problems.append((str(f), f"view of unknown camera {cam!r} (not in dataset.yaml); skipped"))
                continue
            try:
                views.append(_parse_view(v, cam, cap.index, target.points_board_m.shape[0]))
            except InputError as e:
                problems.append((str(f), f"camera {cam!r}: {e}; view skipped"))
    return Dataset(root=root, target=target, cameras=cameras, captures=tuple(captures), views=tuple(views),
                   mode=head.get("mode", "eye_to_hand"), solver=head.get("solver") or {}, problems=tuple(problems))
