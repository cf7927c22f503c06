"""The dataset's detection pass: the images that carry no stored corners detected — guided by a
first estimate when there are many. The solver builds its :class:`~calibgraph.core.problem.Problem`
from it (:func:`calibgraph.solver.solve.build.build_problem`, which passes its ``solve`` as the
coarse solve: detection is an earlier stage than the solver and does not import it).

Guided detection (:mod:`calibgraph.detect.guided`): a blind search of a frame without the board
is the detector's most expensive case (it tries up-scaled regions that merely look like a board),
and in recordings where every camera captures at every robot pose most frames are such frames.
So, for a dataset with many undetected views, :class:`GuidedDatasetDetector` streams the frames
through one worker pool (:class:`~calibgraph.detect.stream.OrderedPool`), both cores busy from
the first frame to the last, in this order of priority:

1. a *survey*: the views of ``SURVEY_CAPTURES`` captures spread over the run are detected blind,
   without up-scaling, and only where a quick probe sees a chessboard (an empty frame then costs
   little more than its decoding; every survey miss gets a second look, guided or deep). These first
   frames of every camera also decide whether the board spec is wrong
   (:mod:`calibgraph.detect.spec_check`): then the run stops with one line naming the likely cause;
2. as soon as a camera has ``PLACE_VIEWS`` survey detections, a coarse solve of the survey so far
   gives it a pose (and the board mount), and from then on its frames are searched guided: each
   gets a prediction from its capture's flange pose — the board's image region and square size,
   "not in view" (confirmed by a quick check) or "far out of view" (not even decoded; every
   ``SPOT_CHECK_EVERY``-th such frame is checked anyway, and one that shows the board sends all of
   that camera's frames back to the quick check). Each later coarse solve (another camera placed,
   the survey complete) refines the predictions of the frames not yet searched, and a predicted
   board missed under an older estimate is searched once more where the newer one says;
3. the survey views of cameras the quick survey could not place are searched again with
   up-scaling; cameras still without a pose are searched blind. Both passes search a candidate
   region up-scaled only where a quick probe sees a board there (``bounded``), so a frame without
   the board costs a fraction of a second, not seconds.

The frames' answers are taken in the order they were asked for, so every decision (and so the
detections) is the same whatever the threads' timing. The final answer comes from the full solve
of all detections, as without guidance; only where the detector looks changes.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.core.problem import SolverOptions, mode_frames
from calibgraph.core.transforms import inv
from calibgraph.detect.blind import look_blind, search_in_full
from calibgraph.detect.board_look import dataset_board_notes, explain_wrong_spec
from calibgraph.detect import progress as search_progress
from calibgraph.detect.dataset import (DetectionCache, dataset_detector, open_frame, pass_reporter, progress_bar, spread,
                                       unusable, view_points, view_problems, wrong_spec_everywhere)
from calibgraph.detect.guided import GUIDED_MIN_PITCH_PX, ViewHint, detect_with_hint, predict_view
from calibgraph.detect.image import Frame
from calibgraph.detect.spec_check import BoardSpecCheck
from calibgraph.detect.stream import OrderedPool
from calibgraph.io.dataset import Dataset

GUIDED_MIN_VIEWS = 48   # fewer undetected views than this: a blind pass costs little, skip the survey
SURVEY_CAPTURES = 24    # captures detected blind to place the cameras
PLACE_VIEWS = 6         # survey detections of a camera at which a coarse solve places it
SPOT_CHECK_EVERY = 8    # of the frames predicted far out of view, those of every n-th capture are read
GUIDED_CACHE_TAG = "guided-3"
_PRIORITY = ("survey", "deep", "guided", "blind")


def detect_dataset(dataset: Dataset, coarse_solve: Callable, method: str = "joint",
                   options: SolverOptions | None = None, progress: bool = True, guided: bool = True):
    """The detector of ``dataset``'s views, run (``None`` when every view carries a stored detection;
    otherwise its ``problems`` list names the images it could not use).

    ``guided``: with many undetected views, detect a survey blind and the rest guided by its
    coarse solve (``coarse_solve``: a Problem in, a Result out; module docstring); False searches
    every image blind. Either way a wrong board spec stops the run early with an
    :class:`~calibgraph.core.errors.InputError` naming it.
    """
    todo = [v for v in dataset.views if not v.detected and v.image]
    detector = None
    if guided and len(todo) >= GUIDED_MIN_VIEWS:
        detector = GuidedDatasetDetector(dataset, progress=progress, method=method, options=options,
                                         coarse_solve=coarse_solve)
        detector.run()
    elif any(not v.detected for v in dataset.views):
        detector = dataset_detector(dataset, progress=progress, fail_fast=True)
    return detector


@dataclass
class GuidedDatasetDetector:
    """A dataset detector (callable ``(view, dataset) -> (ids, uv_px) | None``, with ``results`` and
    ``problems`` like :class:`~calibgraph.detect.dataset.DatasetDetector`) that detects a survey
    blind and the other views guided by coarse solves of the survey (module docstring).

    Attributes:
        notes: what it did, in words (the CLI prints them).
        hints: (camera, capture) -> :class:`~calibgraph.detect.guided.ViewHint` of guided views
            (the last prediction each was searched with).
        fail_fast: stop with an :class:`~calibgraph.core.errors.InputError` on a wrong board spec.
        coarse_solve: the solve of the survey's detections (a Problem in, a Result out: the
            solver's ``solve``, given by the caller; keyword only).
    """

    dataset: Dataset
    progress: bool = True
    method: str = "joint"
    options: SolverOptions | None = None
    workers: int = 2
    cache: object = True
    fail_fast: bool = True
    results: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    hints: dict = field(default_factory=dict)
    _done: bool = False
    coarse_solve: Callable = field(kw_only=True)

    def run(self) -> dict:
        """Detect every undetected view (idempotent); returns ``results``."""
        if self._done:
            return self.results
        run = _GuidedRun(self)
        try:
            run.execute()
        except InputError as e:  # a wrong spec: a ChArUco board's markers may name the right dictionary
            raise explain_wrong_spec(e, self.dataset) from None
        self.problems = run.cache_problems + view_problems(self.results)
        self.problems += wrong_spec_everywhere(self.dataset, self.results)
        self.notes.append(run.summary())
        self.notes += dataset_board_notes(self.dataset, self.results)
        self._done = True
        return self.results

    def __call__(self, view, dataset=None):
        self.run()
        return view_points(view, self.results)


class _GuidedRun:
    """One run of :class:`GuidedDatasetDetector`: the job queues, the estimate and the pool loop."""

    def __init__(self, owner: GuidedDatasetDetector):
        self.o = owner
        ds = self.ds = owner.dataset
        todo = [v for v in ds.views if not v.detected and v.image]
        self.survey_caps = spread(sorted({v.capture for v in todo}), SURVEY_CAPTURES)
        # capture by capture, every camera's view of it: the first frames of every camera come first
        survey = sorted((v for v in todo if v.capture in self.survey_caps), key=lambda v: (v.capture, v.camera))
        self.survey_keys = {(v.camera, v.capture) for v in survey}
        self.queues = {k: deque() for k in _PRIORITY}
        self.queues["survey"].extend(("survey", v, None) for v in survey)
        self.rest = {c: [v for v in todo if v.camera == c and v.capture not in self.survey_caps] for c in ds.cameras}
        self.views = {(v.camera, v.capture): v for v in todo}
        self.in_flight = Counter()
        self.n_total = len(todo)
        self.coarse = None
        self.placed = set()
        self.ok_survey = Counter()
        self.solved_at = -1            # survey/deep detections found when the last coarse solve ran
        self.n_found_blind = 0
        self.stage = "survey"
        self.retried = set()
        self.distrusted = set()
        self.counts = Counter()
        self.unreadable = set()
        self.deferred = {}         # survey frames the spec check put off: key -> their deferred detection
        self.sampled = {}          # frames the spec check wants searched in full (search_in_full): key -> the same
        self.cache = DetectionCache(ds, owner.cache, {"guided": GUIDED_CACHE_TAG})
        self.cache_problems = []
        self.check = BoardSpecCheck(ds.target, {c: sum(v.camera == c for v in survey) for c in ds.cameras}) \
            if owner.fail_fast else None

    # -- the loop -------------------------------------------------------------------------------
    def execute(self) -> None:
        self.bar = progress_bar(self.n_total, self.o.progress)
        waiting = pass_reporter(self.bar)
        try:
            with OrderedPool(self.o.workers) as pool:
                while True:
                    self._top_up(pool)
                    if not len(pool):
                        break
                    job, det = pool.next(waiting)
                    self._take(job, det)
        finally:
            if self.bar is not None:
                self.bar.close()
        self.cache_problems = self.cache.save()

    def _top_up(self, pool) -> None:
        while True:
            while self.stage != "done" and not self.queues[self.stage] and not self.in_flight[self.stage]:
                self._advance()  # the survey (or the deep pass) is complete: start what comes next
            q = next((self.queues[k] for k in _PRIORITY if self.queues[k]), None)
            if q is None or not pool.has_room:
                return
            kind, v, hint = q.popleft()
            full = self.sampled.get((v.camera, v.capture)) if kind == "survey" else None
            tag = ("full" if full is not None else kind) if kind in ("survey", "deep", "blind") else _hint_tag(hint)
            job = (kind, v, hint, tag)
            self.in_flight[kind] += 1
            hit = self.cache.lookup(v, tag)
            if hit is not None:
                pool.put(job + (True,), hit)
            else:
                check_spec = kind in ("survey", "deep") and self.check is not None and self.check.searching
                pool.submit(job + (False,), self._work, kind, v, hint, check_spec, full)

    def _work(self, kind, v, hint, check_spec, full=None):
        """One frame's search; ``full``: the deferred detection of a frame the spec check sampled,
        searched in full (:func:`~calibgraph.detect.blind.search_in_full`). What it does is said by
        :mod:`calibgraph.detect.progress`."""
        path = Path(self.ds.root) / v.image
        with search_progress.searching(path):
            return self._search(kind, v, hint, path, check_spec, full)

    def _search(self, kind, v, hint, path, check_spec, full=None):
        import cv2

        ds = self.ds
        intr = ds.cameras.get(v.camera)
        try:
            if kind in ("guided", "spot"):
                return detect_with_hint(Frame(path), ds.target, intr, hint)
            frame, unreadable = open_frame(path, ds.target)
            if unreadable is not None:
                self.unreadable.add((v.camera, v.capture))  # set.add: safe from worker threads
                return unreadable
            if full is not None:
                search_progress.stage("a full search before the board spec is judged (up-scaled, SB detector)")
                return search_in_full(frame, ds.target, intr, full.pattern, full.other_grid)
            return look_blind(frame, ds.target, intr, check_spec=check_spec,
                              **({"upscale": 1, "gate": True} if kind == "survey" else {"bounded": True}))
        except (cv2.error, ValueError, MemoryError) as e:
            return unusable(ds.target, path, e)

    def _take(self, job, det) -> None:
        kind, v, hint, tag, cached = job
        key = (v.camera, v.capture)
        self.in_flight[kind] -= 1
        self.counts[kind] += 1
        if not cached and not det.deferred:
            self.cache.store(v, det, tag)
        if self.bar is not None:
            self.bar.update(1)
        if kind == "survey" and self.check is not None:
            self.check.add(v.camera, det, readable=key not in self.unreadable, key=key)
        if self.sampled.pop(key, None) is not None and not det.ok and not det.unreadable:
            det = replace(det, deferred=True)  # a sampled frame's full search missed: searched as usual once settled
        if det.deferred:  # searched in full once the spec check has settled (blind.py)
            self.deferred[key] = det
            self.o.results.setdefault(key, det)
            self._judge()
            return
        old = self.o.results.get(key)
        if old is None or det.ok or not old.ok:  # a redo that misses keeps the first look's board
            self.o.results[key] = det
        if hint is not None:
            self.o.hints[key] = hint
        if kind == "survey":
            if det.ok:
                self.ok_survey[v.camera] += 1
                self.n_found_blind += 1
            if v.camera in self.placed and not _good_native(det):
                self._guide([v])
            elif v.camera not in self.placed and self.ok_survey[v.camera] == PLACE_VIEWS:
                self._solve()
        elif kind == "deep" and det.ok:
            self.n_found_blind += 1
            if self.check is not None:
                self.check.add(v.camera, det)
        elif kind in ("guided", "spot") and not det.ok:
            self._retry([v])
        elif kind == "spot" and v.camera not in self.distrusted:
            # a frame predicted far out of view shows the board: the estimate is wrong for this camera
            self._distrust(v.camera)
        self._judge()

    def _judge(self, final: bool = False) -> None:
        """Let the spec check judge (it raises on a wrong spec); queue the frames it wants searched
        in full (a sample, or every deferred frame once the spec is settled)."""
        if self.check is None:
            return
        sample = set(self.check.judge(final=final)) & set(self.deferred)
        redo = sample if sample else (set(self.deferred) if self.check.settled else set())
        if not redo:
            return
        self.sampled.update((k, self.deferred[k]) for k in sample)  # searched in full before the spec is judged
        for k in redo:
            del self.deferred[k]
        jobs = [("survey", self.views[k], None) for k in sorted(redo)]
        if sample:  # next: the spec is judged on them
            self.queues["survey"].extendleft(reversed(jobs))
        else:
            self.queues["survey"].extend(jobs)
        if self.bar is not None:
            self.bar.total += len(redo)  # frames looked at again
            self.bar.refresh()

    def _advance(self) -> None:
        """The survey (then the deep pass) is complete: solve again, and start what comes next."""
        if self.stage == "survey":
            if self.n_found_blind != self.solved_at:
                self._solve()
            again = [v for v in (self.views[k] for k in sorted(self.survey_keys))
                     if v.camera not in self.placed and not self.o.results[(v.camera, v.capture)].ok]
            self.queues["deep"].extend(("deep", v, None) for v in again)
            self.counts["again"] = len(again)
            self.stage = "deep"
            return
        if self.n_found_blind != self.solved_at:
            self._solve()
        self._judge(final=True)
        for cam in sorted(set(self.ds.cameras) - self.placed):
            self.queues["blind"].extend(("blind", v, None) for v in self.rest[cam])
            self.rest[cam] = []
        self.stage = "done"

    # -- the estimate ---------------------------------------------------------------------------
    def _solve(self) -> None:
        """Coarse solve of the survey so far; newly placed cameras get their frames guided, and the
        queued guided frames of placed ones get the newer predictions."""
        self.solved_at = self.n_found_blind
        coarse = self._coarse_solve()
        if coarse is None:
            return
        self.coarse = coarse
        new = set(coarse.cameras) - self.placed
        self.placed |= new
        queued = [v for _, v, _ in self.queues["guided"]]
        self.queues["guided"].clear()
        todo = list(queued)
        for cam in sorted(new):
            todo += self.rest[cam]
            self.rest[cam] = []
            pending = [j for j in self.queues["survey"] if j[1].camera == cam]
            for j in pending:
                self.queues["survey"].remove(j)
            todo += [j[1] for j in pending]
            todo += [self.views[k] for k, d in sorted(self.o.results.items())
                     if k[0] == cam and k in self.survey_keys and not _good_native(d)]
        self._guide(todo)
        self._retry([self.views[k] for k in sorted(self.o.hints) if k[0] in self.placed and not self.o.results[k].ok])

    def _retry(self, views) -> None:
        """Search once more the guided frames that missed under an older estimate where the current
        one predicts the board somewhere else (or in view after all)."""
        redo = {}
        for v in views:
            key = (v.camera, v.capture)
            if key in self.retried or key not in self.o.hints:
                continue
            newer = self._hint(v)
            if newer is not None and newer.visible and _hint_tag(newer) != _hint_tag(self.o.hints[key]):
                self.retried.add(key)
                redo[key] = newer
        if redo:
            self._guide([self.views[k] for k in redo], hints=redo)

    def _distrust(self, camera: str) -> None:
        """A frame predicted far out of view showed the board: the estimate is wrong for ``camera``,
        so all its frames predicted far out of view are read after all (quick check)."""
        self.distrusted.add(camera)
        q = self.queues["guided"]
        keep = [j for j in q if not (j[1].camera == camera and j[2].far)]
        far = [j[1] for j in q if j[1].camera == camera and j[2].far]
        far += [self.views[k] for k, h in sorted(self.o.hints.items()) if k[0] == camera and h.far]
        q.clear()
        q.extend(keep)
        self._guide(far)

    def _coarse_solve(self):
        """Solve the survey's detections; None (and a note) when they cannot place the cameras.
        Cameras with too few survey views are left out of this solve (searched blind later)."""
        ds = self.ds
        views = [v for v in ds.views if v.capture in self.survey_caps]
        seen = Counter(v.camera for v in views if view_points(v, self.o.results) is not None)
        opts = self.o.options or SolverOptions(**ds.solver)
        cams = {c: i for c, i in ds.cameras.items() if seen.get(c, 0) >= max(opts.min_views_per_camera, 4)}
        if not cams:
            return None
        sub = Dataset(root=ds.root, target=ds.target, cameras=cams,
                      captures=tuple(c for c in ds.captures if c.index in self.survey_caps),
                      views=tuple(v for v in views if v.camera in cams), mode=ds.mode, solver=ds.solver)
        try:
            return self.o.coarse_solve(sub.to_problem(method=self.o.method, options=self.o.options,
                                                      detector=lambda v, _=None: view_points(v, self.o.results)))
        except CalibgraphError as e:
            self.o.notes.append(f"guided detection: the survey could not place the cameras ({e}); searching blind")
            return None

    def _hint(self, v) -> ViewHint | None:
        return _predict(self.ds, self.coarse, [v]).get((v.camera, v.capture)) if self.coarse is not None else None

    def _guide(self, views, hints=None) -> None:
        """Queue ``views`` for guided search with the current estimate's predictions (or ``hints``);
        a frame predicted far out of view is read only on a spot check or when its camera is
        distrusted."""
        hints = hints or _predict(self.ds, self.coarse, views)
        for v in views:
            key = (v.camera, v.capture)
            h = hints.get(key)
            if h is None:
                continue
            if h.far and (v.camera in self.distrusted or v.capture % SPOT_CHECK_EVERY == 0):
                self.queues["guided"].append(("spot", v, replace(h, far=False)))
            else:
                self.queues["guided"].append(("guided", v, h))
            if key in self.o.results and self.bar is not None:
                self.bar.total += 1  # a frame looked at again
                self.bar.refresh()

    def summary(self) -> str:
        hints = self.o.hints
        n_empty = sum(not h.visible for h in hints.values())
        n_far = sum(h.far for h in hints.values())
        unplaced = sorted(set(self.ds.cameras) - self.placed)
        return (f"guided detection: {len(self.survey_keys)} views of {len(self.survey_caps)} captures searched blind "
                f"({self.counts['again']} again with up-scaling), {len(hints)} guided by the survey's estimate "
                f"({n_empty} predicted out of view, {n_far} of them far enough not to be read)"
                + (f"; cameras {', '.join(unplaced)} not placed by the survey, searched blind" if unplaced else ""))


def _hint_tag(hint: ViewHint) -> str:
    """How a guided frame is searched, for the cache: the same prediction gives the same search."""
    if hint.far:
        return "far"
    if not hint.visible:
        return "empty"
    small = 0 < hint.pitch_px < GUIDED_MIN_PITCH_PX
    return "region:" + ",".join(str(int(x)) for x in hint.region_px) + (":up" if small else "")


def _good_native(det) -> bool:
    """A quick-survey detection that needs no second, guided look: found, with squares large
    enough that the blind detector would not have up-scaled them either."""
    return det.ok and det.pitch_px >= GUIDED_MIN_PITCH_PX


def _predict(ds: Dataset, coarse, views) -> dict:
    """(camera, capture) -> ViewHint for ``views`` of cameras the coarse result placed."""
    frames = mode_frames(ds.mode)
    T_mount_board = coarse.T_mount_board
    flange = {c.index: c.T_base_flange for c in ds.captures}
    hints = {}
    for v in views:
        cam = coarse.cameras.get(v.camera)
        if cam is None or v.capture not in flange or T_mount_board is None:
            continue
        T_bf = flange[v.capture]
        if frames.ref == "base":   # eye-to-hand: camera in the base frame, board on the flange
            T_cam_board = inv(cam.T_ref_cam) @ T_bf @ T_mount_board
        else:                      # eye-in-hand: camera on the flange, board in the base frame
            T_cam_board = inv(cam.T_ref_cam) @ inv(T_bf) @ T_mount_board
        hints[(v.camera, v.capture)] = predict_view(ds.target, ds.cameras[v.camera], T_cam_board)
    return hints


__all__ = ["GUIDED_MIN_VIEWS", "GuidedDatasetDetector", "SURVEY_CAPTURES", "ViewHint", "detect_dataset"]
