"""Building the solver's :class:`~calibgraph.core.problem.Problem` from a dataset folder."""

from __future__ import annotations

from calibgraph.core.problem import Problem, SolverOptions
from calibgraph.detect.corners import dataset_detector
from calibgraph.io.dataset import Dataset


def build_problem(dataset: Dataset, method: str = "joint", options: SolverOptions | None = None,
                  progress: bool = True) -> tuple[Problem, object]:
    """The :class:`Problem` of ``dataset`` and the detector used (``None`` when every view carries a
    stored detection; otherwise its ``problems`` list names the images it could not read)."""
    detector = None
    if any(not v.detected for v in dataset.views):
        detector = dataset_detector(dataset, progress=progress)
    return dataset.to_problem(method=method, options=options, detector=detector), detector
