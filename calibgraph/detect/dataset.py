"""Detecting a whole dataset: every undetected view, in parallel, cached next to the data.

:func:`dataset_detector` returns the callable that ``Dataset.to_problem(detector=...)`` takes. It
detects on first use (a thread pool; OpenCV releases the GIL), shows a progress bar, stores the
results in ``DATASET/.calibgraph_cache/`` keyed by the target spec, the detector version and the
options, and collects a message for every image it could not use.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from calibgraph.core.errors import InputError
from calibgraph.detect.detection import ImageDetection, failed_detection
from calibgraph.detect.search import detect_image
from calibgraph.io.files import atomic_write_text

# Part of the cache key: bump when a change can move detected points.
DETECTOR_VERSION = "3"


def cache_path(dataset, cache_dir=None, **options) -> Path:
    """Cache file of a dataset's detections for a target spec, detector version and options
    (in ``DATASET/.calibgraph_cache/`` unless ``cache_dir`` is given)."""
    import hashlib

    key = json.dumps({"target": dataset.target.to_dict(), "version": DETECTOR_VERSION, "options": options},
                     sort_keys=True, default=str)
    h = hashlib.sha1(key.encode()).hexdigest()[:12]
    base = Path(cache_dir) if cache_dir is not None else Path(dataset.root) / ".calibgraph_cache"
    return base / f"detections-{h}.json"


@dataclass
class DatasetDetector:
    """Callable ``(view, dataset) -> (ids, uv_px) | None`` for ``Dataset.to_problem(detector=...)``.

    On its first call it detects every view of the dataset that has an image and no stored
    detection (in parallel, with a progress bar), caches the results in
    ``DATASET/.calibgraph_cache/detections-<hash>.json`` (keyed by image path, size and
    modification time) and then answers from memory.

    Attributes:
        views: optional set of (camera, capture) to detect (default: every undetected view).
        detect_view: optional ``(view, path, intrinsics) -> ImageDetection`` used instead of
            :func:`detect_image` (guided detection, :mod:`calibgraph.detect.guided`); its results
            are cached under ``cache_tag`` so they never stand in for an unguided run's.
        results: (camera, capture) -> :class:`ImageDetection`.
        problems: (file, message) for every image that could not be used; the CLI prints them.
    """

    dataset: object
    workers: int = 2
    progress: bool = True
    options: dict = field(default_factory=dict)
    cache: object = True
    views: object = None
    detect_view: object = None
    cache_tag: str = ""
    results: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    _done: bool = False

    def run(self) -> dict:
        """Detect all undetected views now (idempotent); returns ``results``."""
        if self._done:
            return self.results
        from concurrent.futures import ThreadPoolExecutor

        ds = self.dataset
        root = Path(ds.root)
        use_cache = self.cache is not False and self.cache is not None
        key_opts = dict(self.options, **({"guided": self.cache_tag} if self.cache_tag else {}))
        cpath = cache_path(ds, None if self.cache is True else self.cache, **key_opts) if use_cache else None
        cache = {}
        if use_cache and cpath.is_file():
            try:
                cache = json.loads(cpath.read_text()).get("entries", {})
            except (OSError, ValueError):
                cache = {}  # a damaged cache is only a lost speed-up
        todo, keys = [], {}
        wanted = None if self.views is None else set(self.views)
        for v in ds.views:
            if v.detected or (wanted is not None and (v.camera, v.capture) not in wanted):
                continue
            if not v.image:
                self.problems.append((f"camera {v.camera}, capture {v.capture}", "no image and no detection; skipped"))
                continue
            p = root / v.image
            try:
                st = p.stat()
                stamp = f"{st.st_size}:{int(st.st_mtime_ns)}"
            except OSError:
                stamp = "missing"
            key = v.image
            keys[(v.camera, v.capture)] = (key, stamp)
            hit = cache.get(key)
            if hit is not None and hit.get("stamp") == stamp and stamp != "missing":
                self.results[(v.camera, v.capture)] = ImageDetection.from_dict(hit["detection"])
            else:
                todo.append(v)

        def work(v):
            import cv2

            cv2.setNumThreads(1)  # parallelism comes from the pool; avoid oversubscription
            intr = ds.cameras.get(v.camera)
            try:
                if self.detect_view is not None:
                    return v, self.detect_view(v, root / v.image, intr)
                return v, detect_image(root / v.image, ds.target, intrinsics=intr, **self.options)
            except (cv2.error, ValueError, MemoryError) as e:
                # One odd image must not stop the run: record it and carry on with the rest.
                return v, failed_detection(f"detector failed on this image ({type(e).__name__}: {str(e).strip()[:200]})",
                                  ds.target, str(root / v.image))

        if todo:
            bar = None
            if self.progress:
                from tqdm import tqdm

                bar = tqdm(total=len(todo), desc="detect", unit="img", leave=False)
            with ThreadPoolExecutor(max_workers=max(1, int(self.workers))) as ex:
                for v, det in ex.map(work, todo):
                    self.results[(v.camera, v.capture)] = det
                    if bar is not None:
                        bar.update(1)
            if bar is not None:
                bar.close()
        if todo and use_cache:
            entries = dict(cache)
            for (cam, cap), det in self.results.items():
                k, stamp = keys.get((cam, cap), (None, None))
                if k is not None and stamp != "missing":
                    entries[k] = {"stamp": stamp, "detection": det.to_dict()}
            try:
                atomic_write_text(cpath, json.dumps({"version": DETECTOR_VERSION, "target": ds.target.to_dict(),
                                                     "options": {k: str(v) for k, v in key_opts.items()},
                                                     "entries": entries}))
            except InputError as e:
                self.problems.append((str(cpath), f"cannot write the detection cache ({e}); continuing without"))
        for (cam, cap), det in sorted(self.results.items(), key=lambda kv: (kv[0][0], kv[0][1])):
            if not det.ok:
                self.problems.append((det.image or f"camera {cam}, capture {cap}", det.reason))
        # A target that is found nowhere is most likely the wrong spec: say so once.
        if self.results and not any(d.ok for d in self.results.values()) and self.detect_view is None:
            t = ds.target
            self.problems.append((str(root), f"the target ({t.kind}, {t.rows}x{t.cols} points, pitch {t.pitch_m} m) was "
                                  "not found in any image: check the target spec in dataset.yaml"))
        self._done = True
        return self.results

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
                     cache_tag: str = "", **options) -> DatasetDetector:
    """A detector for ``Dataset.to_problem(detector=...)`` that detects all undetected views of
    ``dataset`` in parallel (``workers`` threads; OpenCV releases the GIL), shows a tqdm progress
    bar, caches results next to the data and collects per-file problems in ``.problems``.
    ``cache``: True (``DATASET/.calibgraph_cache/``), False (no cache) or a folder.
    ``options`` are passed to :func:`detect_image` (e.g. ``upscale=1``, ``method="sb"``); ``views``,
    ``detect_view`` and ``cache_tag`` as in :class:`DatasetDetector`."""
    return DatasetDetector(dataset=dataset, workers=workers, progress=progress, options=dict(options), cache=cache,
                           views=views, detect_view=detect_view, cache_tag=cache_tag)
