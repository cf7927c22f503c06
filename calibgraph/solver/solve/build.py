"""Building the solver's :class:`~calibgraph.core.problem.Problem` from a dataset folder: the views
without stored corners detected first (:mod:`calibgraph.detect.guided_dataset`, guided by coarse
solves of a survey when there are many; this module gives it :func:`~calibgraph.solver.solve.batch.solve`
for them, as detection is an earlier stage than the solver)."""

from __future__ import annotations

from calibgraph.core.problem import Problem, SolverOptions
from calibgraph.detect.guided_dataset import detect_dataset
from calibgraph.io.dataset import Dataset
from calibgraph.solver.solve.batch import solve


def build_problem(dataset: Dataset, method: str = "joint", options: SolverOptions | None = None,
                  progress: bool = True, guided: bool = True) -> tuple[Problem, object]:
    """The :class:`Problem` of ``dataset`` and the detector used (``None`` when every view carries a
    stored detection; otherwise its ``problems`` list names the images it could not use).

    ``guided``: with many undetected views, detect a survey blind and the rest guided by its
    coarse solve (:mod:`calibgraph.detect.guided_dataset`); False searches every image blind. Either
    way a wrong board spec stops the run early with an :class:`~calibgraph.core.errors.InputError`
    naming it.
    """
    detector = detect_dataset(dataset, solve, method=method, options=options, progress=progress, guided=guided)
    return dataset.to_problem(method=method, options=options, detector=detector), detector


__all__ = ["build_problem"]
