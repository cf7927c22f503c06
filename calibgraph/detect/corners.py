"""Target detection: image -> point ids, sub-pixel pixels and a quality record.

One entry point per image, :func:`detect_image`, and one per dataset, :func:`dataset_detector`
(parallel, cached next to the data, with a progress bar, for ``Dataset.to_problem(detector=...)``).
This module gathers the public names of the detection stage; each lives in the module of its
concept:

* :mod:`~calibgraph.detect.detection`: :class:`ImageDetection`, the record of one image's detection;
* :mod:`~calibgraph.detect.image`: reading files and arrays as 8-bit grey;
* :mod:`~calibgraph.detect.search`: :func:`detect_image`, the search ladder (whole frame, regions,
  up-scaling for far cameras, board fit, grid filter);
* :mod:`~calibgraph.detect.chessboard`, :mod:`~calibgraph.detect.charuco`,
  :mod:`~calibgraph.detect.circles`: the per-kind finders, with :mod:`~calibgraph.detect.orient`
  ordering their grids to the target's ids and :mod:`~calibgraph.detect.regions` proposing where
  to look;
* :mod:`~calibgraph.detect.board_fit`: the photometric sub-pixel fit of checkerboard and ChArUco
  corners;
* :mod:`~calibgraph.detect.grid_filter`: the false-detection filter;
* :mod:`~calibgraph.detect.quality`: blur and coverage measures;
* :mod:`~calibgraph.detect.dataset`: the dataset detector with its cache and pool.
"""

from __future__ import annotations

from calibgraph.detect.chessboard import SB_BELOW_PITCH_PX
from calibgraph.detect.dataset import DETECTOR_VERSION, DatasetDetector, cache_path, dataset_detector
from calibgraph.detect.detection import ImageDetection
from calibgraph.detect.image import read_grey, to_grey8
from calibgraph.detect.search import detect_image

__all__ = ["DETECTOR_VERSION", "DatasetDetector", "ImageDetection", "SB_BELOW_PITCH_PX", "cache_path",
           "dataset_detector", "detect_image", "read_grey", "to_grey8"]
