"""The simulator's ground-truth file (``ground_truth.json``, ``calibgraph-ground-truth/1``) beside a dataset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.io.files import atomic_write_text, read_input_bytes

GT_FORMAT = "calibgraph-ground-truth/1"


GT_NAME = "ground_truth.json"


_CONVENTION = ("T_a_b maps points from frame b to frame a: p_a = T_a_b @ p_b (4x4, metres). Camera frames are "
               "OpenCV optical frames (x right, y down, z forward); the board frame has its origin at point 0, "
               "x along a row, y along a column, z into the board.")


def load_ground_truth(dataset_dir) -> dict:
    """Read ``ground_truth.json`` (in the folder ``dataset_dir``, or that file itself) with poses as numpy arrays:
    ``{"T_flange_board", "T_base_cam": {cam: 4x4}, "T_base_flange_true": {capture: 4x4},
    "joint_offsets_rad": (7,) (zeros when the file has none), "intrinsics_true": {cam: Intrinsics}
    (the ones the images were rendered with; from ``intrinsics`` in files that predate
    ``intrinsics_true``), "raw": dict}``."""
    p = Path(dataset_dir)
    p = p if p.is_file() or p.suffix == ".json" else p / GT_NAME
    try:
        d = json.loads(read_input_bytes(p, "ground truth"))
    except (OSError, ValueError, InputError) as e:
        raise InputError(f"{p}: no readable ground truth ({e}); only simulated datasets have one.") from None
    try:
        return _parse(d)
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise InputError(f"{p}: not a calibgraph ground truth ({GT_FORMAT}: {type(e).__name__} {e}); only simulated "
                         "datasets (calibgraph sim, demo) have one.") from None


def _parse(d: dict) -> dict:
    return {
        "T_flange_board": np.asarray(d["T_flange_board"], float),
        "T_base_cam": {c: np.asarray(v["T_base_cam"], float) for c, v in d["cameras"].items()},
        "T_base_flange_true": {int(k): np.asarray(v["T_base_flange_true"], float) for k, v in d["captures"].items()},
        "joint_offsets_rad": np.asarray((d.get("robot") or {}).get("joint_offsets_rad") or np.zeros(7), float),
        "intrinsics_true": {c: Intrinsics.from_dict(v.get("intrinsics_true") or v["intrinsics"])
                            for c, v in d["cameras"].items() if v.get("intrinsics_true") or v.get("intrinsics")},
        "raw": d,
    }


def write_ground_truth_file(dataset_dir, gt: dict) -> Path:
    """Write ``gt`` (a ``calibgraph-ground-truth/1`` dict, see :mod:`calibgraph.sim.rendered_dataset`) beside the dataset."""
    return atomic_write_text(Path(dataset_dir) / GT_NAME, json.dumps({"format": GT_FORMAT, "frame_convention": _CONVENTION,
                                                                      **gt}, indent=1))
