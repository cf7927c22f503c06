"""Detecting a whole dataset: every undetected view, streamed through a worker pool, cached next
to the data, stopped early when the board spec is wrong.

:func:`dataset_detector` returns the callable that ``Dataset.to_problem(detector=...)`` takes. It
detects on first use (:class:`~calibgraph.detect.stream.OrderedPool`; OpenCV releases the GIL),
shows a progress bar, stores the results in ``DATASET/.calibgraph_cache/`` (:class:`DetectionCache`,
keyed by the target spec, the detector version and the options) and collects a message for every
image it could not use. Frames are taken in an order that spreads each camera's first frames over
the whole run, so that with ``fail_fast`` the first frames of every camera can tell a wrong board
spec (:mod:`calibgraph.detect.spec_check`) before the rest are searched.
"""

from __future__ import annotations

import json
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.core.errors import DetectionError, InputError
from calibgraph.detect import progress as search_progress
from calibgraph.detect.blind import look_blind, search_in_full
from calibgraph.detect.board_look import dataset_board_notes, explain_wrong_spec
from calibgraph.detect.detection import ImageDetection, failed_detection
from calibgraph.detect.image import Frame
from calibgraph.detect.spec_check import FIRST_FRAMES, BoardSpecCheck
from calibgraph.detect.stream import OrderedPool
from calibgraph.io.files import atomic_write_text, read_input_bytes

# Part of the cache key: bump when a change can move detected points.
DETECTOR_VERSION = "6"


def cache_path(dataset, cache_dir=None, **options) -> Path:
    """Cache file of a dataset's detections for a target spec, detector version and options
    (in ``DATASET/.calibgraph_cache/`` unless ``cache_dir`` is given)."""
    import hashlib

    key = json.dumps({"target": dataset.target.to_dict(), "version": DETECTOR_VERSION, "options": options},
                     sort_keys=True, default=str)
    h = hashlib.sha1(key.encode()).hexdigest()[:12]
    base = Path(cache_dir) if cache_dir is not None else Path(dataset.root) / ".calibgraph_cache"
    return base / f"detections-{h}.json"


class DetectionCache:
    """A dataset's detections stored beside it, one entry per image (and per ``tag``: how the
    image was searched), valid while the image file keeps its size and modification time.

    ``cache``: True (``DATASET/.calibgraph_cache/``), False/None (no cache) or a folder;
    ``options``: what the detections depend on besides the target and the detector version.
    """

    def __init__(self, dataset, cache=True, options: dict | None = None):
        self.dataset = dataset
        self.options = dict(options or {})
        self.path = None if cache is False or cache is None else \
            cache_path(dataset, None if cache is True else cache, **self.options)
        self.entries = {}
        self.changed = False
        if self.path is not None and self.path.is_file():
            try:
                self.entries = json.loads(read_input_bytes(self.path, "detection cache")).get("entries", {})
            except (OSError, ValueError, InputError):
                self.entries = {}  # a damaged cache is only a lost speed-up
        self._stamps = {}

    def _stamp(self, view) -> str:
        if view.image not in self._stamps:
            try:
                st = (Path(self.dataset.root) / view.image).stat()
                self._stamps[view.image] = f"{st.st_size}:{int(st.st_mtime_ns)}"
            except OSError:
                self._stamps[view.image] = "missing"
        return self._stamps[view.image]

    @staticmethod
    def _key(view, tag: str) -> str:
        return view.image if not tag else f"{view.image}#{tag}"

    def lookup(self, view, tag: str = "") -> ImageDetection | None:
        """The stored detection of ``view``'s image searched as ``tag``, if still valid."""
        hit = self.entries.get(self._key(view, tag))
        stamp = self._stamp(view)
        if hit is None or hit.get("stamp") != stamp or stamp == "missing":
            return None
        return ImageDetection.from_dict(hit["detection"])

    def store(self, view, det: ImageDetection, tag: str = "") -> None:
        stamp = self._stamp(view)
        if self.path is not None and stamp != "missing":
            self.entries[self._key(view, tag)] = {"stamp": stamp, "detection": det.to_dict()}
            self.changed = True

    def save(self) -> list:
        """Write the cache if anything new was stored; a (file, message) problem when it cannot be."""
        if self.path is None or not self.changed:
            return []
        try:
            atomic_write_text(self.path, json.dumps({"version": DETECTOR_VERSION, "target": self.dataset.target.to_dict(),
                                                     "options": {k: str(v) for k, v in self.options.items()},
                                                     "entries": self.entries}))
        except InputError as e:
            return [(str(self.path), f"cannot write the detection cache ({e}); continuing without")]
        self.changed = False
        return []


def spread_order(views, n: int = FIRST_FRAMES) -> list:
    """``views`` reordered so that the first ``n`` captures taken are spread evenly over the run
    (then the rest in their order): the first frames of every camera then sample the whole run."""
    caps = sorted({v.capture for v in views})
    first = spread(caps, n)
    rank = {c: (0 if c in first else 1, i) for i, c in enumerate(caps)}
    return sorted(views, key=lambda v: rank[v.capture])


def spread(items: list, n: int) -> set:
    """``n`` items evenly spread over ``items`` (all of them when there are fewer)."""
    if len(items) <= n:
        return set(items)
    return {items[int(i)] for i in np.round(np.linspace(0, len(items) - 1, n))}


def progress_bar(total: int, show: bool):
    """A tqdm bar over ``total`` images, or None when not shown."""
    if not show or total <= 0:
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc="detect", unit="img", leave=False)


def pass_reporter(bar):
    """The ``waiting`` callback of a pass with progress ``bar`` (None: no bar, no lines): a line on
    what the pass searches at least every ``PROGRESS_EVERY_S`` seconds
    (:mod:`calibgraph.detect.progress`)."""
    if bar is None:
        return None
    rep = search_progress.Reporter(search_progress.bar_writer(bar), what=bar.desc or "detect")
    return lambda: rep.tick(int(bar.n), int(bar.total))


def unusable(target, path, error: Exception) -> ImageDetection:
    """The record of an image the detector itself failed on (one odd image must not stop a run)."""
    return failed_detection(f"detector failed on this image ({type(error).__name__}: {str(error).strip()[:200]})",
                            target, str(path))


def open_frame(path, target) -> tuple:
    """(:class:`~calibgraph.detect.image.Frame` of ``path`` decoded at full resolution, None), or
    (None, the failed detection naming the problem) when the file cannot be read."""
    frame = Frame(path)
    try:
        frame.grey()
    except DetectionError as e:
        return None, failed_detection(str(e), target, str(path), unreadable=True)
    return frame, None


def view_problems(results: dict) -> list:
    """(file, message) for every view in ``results`` ((camera, capture) -> :class:`ImageDetection`)
    that gave no board; an unreadable image is named with its camera and capture, and costs that
    view only."""
    out = []
    for (cam, cap), det in sorted(results.items(), key=lambda kv: (kv[0][0], kv[0][1])):
        if det.ok:
            continue
        where = det.image or f"camera {cam}, capture {cap}"
        if det.unreadable:
            why = det.reason[len(f"{det.image}: "):] if det.image and det.reason.startswith(f"{det.image}: ") \
                else det.reason
            out.append((where, f"camera {cam}, capture {cap}: {why.rstrip('.')}; this view is left out"))
        else:
            out.append((where, det.reason))
    return out


def wrong_spec_everywhere(dataset, results: dict) -> list:
    """A (folder, message) problem when the target was found in no image at all (of those that
    could be read): most likely the wrong spec, said once."""
    searched = [d for d in results.values() if not d.unreadable]
    if searched and not any(d.ok for d in searched):
        t = dataset.target
        return [(str(dataset.root), f"the target ({t.kind}, {t.rows}x{t.cols} points, pitch {t.pitch_m} m) was "
                 "not found in any image: check the target spec in dataset.yaml")]
    return []


@dataclass
class DatasetDetector:
    """Callable ``(view, dataset) -> (ids, uv_px) | None`` for ``Dataset.to_problem(detector=...)``.

    On its first call it detects every view of the dataset that has an image and no stored
    detection (in parallel, with a progress bar), caches the results in
    ``DATASET/.calibgraph_cache/detections-<hash>.json`` (keyed by image path, size and
    modification time) and then answers from memory.

    Attributes:
        views: optional set of (camera, capture) to detect (default: every undetected view).
        detect_view: optional ``(view, path, intrinsics) -> ImageDetection`` used instead of the
            blind look (:func:`calibgraph.detect.blind.look_blind`); its results are cached under
            ``cache_tag`` so they never stand in for an unguided run's.
        fail_fast: stop with one :class:`InputError` naming the likely cause when the first
            frames of every camera show no board, or a board of another size
            (:mod:`calibgraph.detect.spec_check`); off, such a run ends with a problem saying the
            target was found nowhere.
        where: the file that declares the target, named in that error.
        results: (camera, capture) -> :class:`ImageDetection`.
        problems: (file, message) for every image that could not be used; the CLI prints them.
        notes: what the images show beside the spec, in words (markers in a checkerboard's white
            squares: :mod:`calibgraph.detect.board_look`); the CLI prints them.
    """

    dataset: object
    workers: int = 2
    progress: bool = True
    options: dict = field(default_factory=dict)
    cache: object = True
    views: object = None
    detect_view: object = None
    cache_tag: str = ""
    fail_fast: bool = False
    where: str = "dataset.yaml"
    results: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    _done: bool = False
    _unreadable: set = field(default_factory=set)

    def run(self) -> dict:
        """Detect all undetected views now (idempotent); returns ``results``."""
        if self._done:
            return self.results
        ds = self.dataset
        cache = DetectionCache(ds, self.cache, dict(self.options, **({"guided": self.cache_tag} if self.cache_tag
                                                                      else {})))
        wanted = None if self.views is None else set(self.views)
        todo = []
        for v in ds.views:
            if v.detected or (wanted is not None and (v.camera, v.capture) not in wanted):
                continue
            if not v.image:
                self.problems.append((f"camera {v.camera}, capture {v.capture}", "no image and no detection; skipped"))
                continue
            todo.append(v)
        todo = spread_order(todo)
        check = None
        if self.fail_fast and self.detect_view is None:
            check = BoardSpecCheck(ds.target, {c: sum(v.camera == c for v in todo) for c in ds.cameras}, self.where)
        hits = {(v.camera, v.capture): cache.lookup(v) for v in todo}
        bar = progress_bar(sum(h is None for h in hits.values()), self.progress)
        waiting = pass_reporter(bar)
        items = iter(todo)
        # frames the spec check put off (key -> (view, deferred detection)); those now due for a search,
        # as (view, deferred detection) for a sampled frame's full search (spec_check.py), or (view,
        # None) for the ordinary search once the spec is settled; the keys of the sampled frames out
        deferred, again, sampled = {}, deque(), set()
        try:
            with OrderedPool(self.workers) as pool:
                while True:
                    while pool.has_room:
                        if again:
                            v, full = again.popleft()
                            pool.submit(v, self._work, v, False, full)
                            continue
                        v = next(items, None)
                        if v is None:
                            break
                        hit = hits[(v.camera, v.capture)]
                        if hit is not None:
                            pool.put(v, hit)
                        else:
                            pool.submit(v, self._work, v, check is not None and check.searching)
                    if len(pool):
                        v, det = pool.next(waiting)
                        self._take(v, det, hits, cache, bar, deferred, sampled, check)
                        sample = check.judge() if check is not None else []
                    elif check is None or not deferred:
                        break
                    else:
                        sample = check.judge(final=True)  # the stream is done: settled, sampled or named wrong
                    for key in sample:
                        if key in deferred:
                            sampled.add(key)
                            again.append(deferred.pop(key))
                    if not sample and check is not None and check.settled and deferred:
                        again.extend((v, None) for v, _ in deferred.values())
                        deferred.clear()
        except InputError as e:  # a wrong spec: a ChArUco board's markers may name the right dictionary
            raise explain_wrong_spec(e, ds) from None
        finally:
            if bar is not None:
                bar.close()
        self.problems += cache.save()
        self.problems += view_problems(self.results)
        if self.detect_view is None:
            self.problems += wrong_spec_everywhere(ds, self.results)
            self.notes += dataset_board_notes(ds, self.results)
        self._done = True
        return self.results

    def _take(self, v, det, hits, cache, bar, deferred, sampled, check) -> None:
        """One frame's answer: kept (and cached) unless the spec check deferred it. A sampled frame
        whose full search missed goes back to the deferred ones: its region search is no stand-in
        for the frame's ordinary search once the spec is settled."""
        key = (v.camera, v.capture)
        if check is not None:
            check.add(v.camera, det, readable=key not in self._unreadable, key=key)
        if key in sampled:
            sampled.discard(key)
            if not det.ok and not det.unreadable:
                deferred[key] = (v, det)
                return
        if det.deferred:
            deferred[key] = (v, det)
        else:
            self.results[key] = det
            if hits[key] is None:
                cache.store(v, det)
                if bar is not None:
                    bar.update(1)

    def _work(self, v, check_spec: bool, full=None) -> ImageDetection:
        """The blind look at ``v``'s frame, or with ``full`` (its deferred detection) the spec
        check's full search of it (what it does is said by :mod:`calibgraph.detect.progress`)."""
        ds = self.dataset
        path = Path(ds.root) / v.image
        intr = ds.cameras.get(v.camera)
        with search_progress.searching(path):
            return self._search(v, path, intr, check_spec, full)

    def _search(self, v, path, intr, check_spec: bool, full=None) -> ImageDetection:
        import cv2

        ds = self.dataset
        try:
            if self.detect_view is not None:
                return self.detect_view(v, path, intr)
            frame, unreadable = open_frame(path, ds.target)
            if unreadable is not None:
                self._unreadable.add((v.camera, v.capture))  # set.add: safe from worker threads
                return unreadable
            if full is not None:
                search_progress.stage("a full search before the board spec is judged (up-scaled, SB detector)")
                return search_in_full(frame, ds.target, intr, full.pattern, full.other_grid)
            return look_blind(frame, ds.target, intr, check_spec=check_spec, **self.options)
        except (cv2.error, ValueError, MemoryError) as e:
            return unusable(ds.target, path, e)

    def __call__(self, view, dataset=None):
        self.run()
        return view_points(view, self.results)


def view_points(view, results: dict):
    """``(ids, uv_px)`` of ``view``: its stored detection, else its accepted entry in ``results``
    ((camera, capture) -> :class:`ImageDetection`); None when it has neither."""
    if view.detected:
        return view.ids, view.uv_px
    det = results.get((view.camera, view.capture))
    return (det.ids, det.uv_px) if det is not None and det.ok else None


def dataset_detector(dataset, workers: int = 2, progress: bool = True, cache=True, views=None, detect_view=None,
                     cache_tag: str = "", fail_fast: bool = False, where: str = "dataset.yaml",
                     **options) -> DatasetDetector:
    """A detector for ``Dataset.to_problem(detector=...)`` that detects all undetected views of
    ``dataset`` in parallel (``workers`` threads; OpenCV releases the GIL), shows a tqdm progress
    bar, caches results next to the data and collects per-file problems in ``.problems``.
    ``cache``: True (``DATASET/.calibgraph_cache/``), False (no cache) or a folder.
    ``options`` are passed to :func:`~calibgraph.detect.search.detect_image` (e.g. ``upscale=1``,
    ``method="sb"``); ``views``, ``detect_view``, ``cache_tag``, ``fail_fast`` and ``where`` as in
    :class:`DatasetDetector`."""
    return DatasetDetector(dataset=dataset, workers=workers, progress=progress, options=dict(options), cache=cache,
                           views=views, detect_view=detect_view, cache_tag=cache_tag, fail_fast=fail_fast,
                           where=where)
