"""Stage 1 — files: the ``calibgraph-dataset/1`` folder, the peer layouts it reads
(industrial_calibration/RCT, MC-HEC), the simulator's ground-truth file, target specs, YAML
reading and the one atomic writer."""

from calibgraph.io.dataset import Dataset, View
from calibgraph.io.layouts import as_dataset, load_dataset

__all__ = ["Dataset", "View", "as_dataset", "load_dataset"]
