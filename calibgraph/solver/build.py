"""Building the solver's :class:`~calibgraph.core.problem.Problem` from a dataset folder, detecting
the images that carry no stored corners — guided by a first estimate when there are many.

Guided detection (:mod:`calibgraph.detect.guided`): a blind search of a frame without the board
is the detector's most expensive case (it tries up-scaled regions that merely look like a board),
and in recordings where every camera captures at every robot pose most frames are such frames.
So, for a dataset with many undetected views:

1. a *survey*: the views of ``SURVEY_CAPTURES`` captures spread over the run are detected blind,
   first without up-scaling (an empty frame then costs a fraction of the full search); only the
   survey views of cameras that this leaves without a pose are searched again with up-scaling;
2. a coarse solve of the survey gives every camera that saw the board a pose (and the board mount);
3. every other view gets a prediction from its capture's flange pose — the board's image region
   and square size, or "not in view" — and is detected in that region at that scale, or confirmed
   empty by a quick check. Cameras the survey could not place are searched blind.

The final answer comes from the full solve of all detections, as without guidance; only where the
detector looks changes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibgraph.core.errors import CalibgraphError
from calibgraph.core.problem import Problem, SolverOptions, mode_frames
from calibgraph.core.transforms import inv
from calibgraph.detect.dataset import dataset_detector, view_points
from calibgraph.detect.guided import GUIDED_MIN_PITCH_PX, ViewHint, detect_with_hint, predict_view
from calibgraph.io.dataset import Dataset
from calibgraph.solver.batch import solve

GUIDED_MIN_VIEWS = 48  # fewer undetected views than this: a blind pass costs little, skip the survey
SURVEY_CAPTURES = 24   # captures detected blind to place the cameras


def build_problem(dataset: Dataset, method: str = "joint", options: SolverOptions | None = None,
                  progress: bool = True, guided: bool = True) -> tuple[Problem, object]:
    """The :class:`Problem` of ``dataset`` and the detector used (``None`` when every view carries a
    stored detection; otherwise its ``problems`` list names the images it could not use).

    ``guided``: with many undetected views, detect a survey blind and the rest guided by its
    coarse solve (module docstring); False searches every image blind.
    """
    todo = [v for v in dataset.views if not v.detected and v.image]
    detector = None
    if guided and len(todo) >= GUIDED_MIN_VIEWS:
        detector = GuidedDatasetDetector(dataset, progress=progress, method=method, options=options)
        detector.run()
    elif any(not v.detected for v in dataset.views):
        detector = dataset_detector(dataset, progress=progress)
    return dataset.to_problem(method=method, options=options, detector=detector), detector


@dataclass
class GuidedDatasetDetector:
    """A dataset detector (callable ``(view, dataset) -> (ids, uv_px) | None``, with ``results`` and
    ``problems`` like :class:`~calibgraph.detect.dataset.DatasetDetector`) that detects a survey
    blind and the other views guided by the survey's coarse solve.

    Attributes:
        notes: what it did, in words (the CLI prints them).
        hints: (camera, capture) -> :class:`~calibgraph.detect.guided.ViewHint` of guided views.
    """

    dataset: Dataset
    progress: bool = True
    method: str = "joint"
    options: SolverOptions | None = None
    results: dict = field(default_factory=dict)
    problems: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    hints: dict = field(default_factory=dict)
    _done: bool = False

    def run(self) -> dict:
        """Detect every undetected view (idempotent); returns ``results``."""
        if self._done:
            return self.results
        ds = self.dataset
        todo = [v for v in ds.views if not v.detected and v.image]
        survey_caps = _spread(sorted({v.capture for v in todo}), SURVEY_CAPTURES)
        survey = {(v.camera, v.capture) for v in todo if v.capture in survey_caps}
        cache_problems = []
        quick = dataset_detector(ds, progress=self.progress, views=survey, upscale=1)
        quick.run()
        self.results.update(quick.results)
        coarse = self._coarse_solve(survey_caps)
        placed = set() if coarse is None else set(coarse.cameras)
        again = {(c, k) for (c, k) in survey if c not in placed and not self.results[(c, k)].ok}
        if again:
            deep = dataset_detector(ds, progress=self.progress, views=again)
            deep.run()
            self.results.update(deep.results)
            cache_problems += _cache_problems(deep)
            coarse = self._coarse_solve(survey_caps)
        cache_problems += _cache_problems(quick)
        # every other view, and the survey views of placed cameras that the quick pass missed or
        # found with small squares (not up-scaled: less accurate), are searched where the estimate says
        rest = [v for v in todo if (v.camera, v.capture) not in survey
                or (v.camera in placed and (v.camera, v.capture) not in again
                    and not _good_native(self.results[(v.camera, v.capture)]))]
        if coarse is not None:
            self.hints = _predict(ds, coarse, rest)
        target = ds.target

        def detect_view(view, path, intrinsics):
            return detect_with_hint(path, target, intrinsics, self.hints.get((view.camera, view.capture)))

        guided = dataset_detector(ds, progress=self.progress, views={(v.camera, v.capture) for v in rest},
                                  detect_view=detect_view, cache_tag="guided-1")
        guided.run()
        self.results.update(guided.results)
        cache_problems += _cache_problems(guided)
        self.problems = cache_problems + [(d.image or f"camera {c}, capture {k}", d.reason)
                                          for (c, k), d in sorted(self.results.items()) if not d.ok]
        if self.results and not any(d.ok for d in self.results.values()):
            t = ds.target
            self.problems.append((str(ds.root), f"the target ({t.kind}, {t.rows}x{t.cols} points, pitch {t.pitch_m} m) "
                                  "was not found in any image: check the target spec in dataset.yaml"))
        unplaced = sorted({v.camera for v in rest} - {c for (c, _) in self.hints})
        n_empty = sum(not h.visible for h in self.hints.values())
        self.notes.append(f"guided detection: {len(survey)} views of {len(survey_caps)} captures searched blind "
                          f"({len(again)} again with up-scaling), {len(self.hints)} guided by the survey's estimate "
                          f"({n_empty} predicted out of view)"
                          + (f"; cameras {', '.join(unplaced)} not placed by the survey, searched blind" if unplaced
                             else ""))
        self._done = True
        return self.results

    def _answer(self, view, dataset=None):
        """Detections found so far (no further search)."""
        return view_points(view, self.results)

    def _coarse_solve(self, survey_caps):
        """Solve the survey's detections; None (and a note) when they cannot place the cameras.
        Cameras with too few survey views are left out of this solve (searched blind later)."""
        ds = self.dataset
        views = [v for v in ds.views if v.capture in survey_caps]
        seen = {}
        for v in views:
            if self._answer(v) is not None:
                seen[v.camera] = seen.get(v.camera, 0) + 1
        opts = self.options or SolverOptions(**ds.solver)
        cams = {c: i for c, i in ds.cameras.items() if seen.get(c, 0) >= max(opts.min_views_per_camera, 4)}
        if not cams:
            return None
        sub = Dataset(root=ds.root, target=ds.target, cameras=cams,
                      captures=tuple(c for c in ds.captures if c.index in survey_caps),
                      views=tuple(v for v in views if v.camera in cams), mode=ds.mode, solver=ds.solver)
        try:
            return solve(sub.to_problem(method=self.method, options=self.options, detector=self._answer))
        except CalibgraphError as e:
            self.notes.append(f"guided detection: the survey could not place the cameras ({e}); searching blind")
            return None

    def __call__(self, view, dataset=None):
        self.run()
        return view_points(view, self.results)


def _good_native(det) -> bool:
    """A quick-survey detection that needs no second, guided look: found, with squares large
    enough that the blind detector would not have up-scaled them either."""
    return det.ok and det.pitch_px >= GUIDED_MIN_PITCH_PX


def _cache_problems(detector) -> list:
    """A sub-detector's problems that are not about one image (e.g. an unwritable cache)."""
    images = {d.image for d in detector.results.values()}
    return [(f, m) for f, m in detector.problems if f not in images and not f.startswith("camera ")]


def _spread(items: list, n: int) -> set:
    """``n`` items evenly spread over ``items`` (all of them when there are fewer)."""
    if len(items) <= n:
        return set(items)
    return {items[int(i)] for i in np.round(np.linspace(0, len(items) - 1, n))}


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


__all__ = ["GUIDED_MIN_VIEWS", "GuidedDatasetDetector", "SURVEY_CAPTURES", "ViewHint", "build_problem"]
