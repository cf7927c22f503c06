"""Which dataset layout a folder holds, and reading it: calibgraph's own, industrial_calibration /
robot_cal_tools (RCT), or Multi-Camera-Hand-Eye-Calibration (MC-HEC)."""

from __future__ import annotations

from pathlib import Path

from calibgraph.core.errors import InputError
from calibgraph.io.checks import check_dataset
from calibgraph.io.dataset import (
    Dataset,
    is_calibgraph_dataset,
    read_calibgraph_dataset,
)
from calibgraph.io.peer_mchec import is_mchec_dataset, load_mchec_dataset
from calibgraph.io.peer_rct import is_rct_dataset, load_rct_dataset


def load_dataset(root) -> Dataset:
    """Read a dataset folder in any supported layout (calibgraph, industrial_calibration/RCT,
    Multi-Camera-Hand-Eye-Calibration). Unreadable capture files and dropped duplicated captures are
    listed in ``problems``; nothing else is dropped silently. Everyday mistakes (poses in millimetres,
    rows and cols swapped, a pitch far off, images of another size than the intrinsics) are refused
    with their cause (:mod:`calibgraph.io.checks`)."""
    root = Path(root)
    if not root.exists():
        raise InputError(f"{root}: no such dataset folder.")
    if not root.is_dir():
        raise InputError(f"{root}: is a file; give the dataset folder (the one holding dataset.yaml and captures/).")
    if is_calibgraph_dataset(root):
        return check_dataset(read_calibgraph_dataset(root))
    if is_rct_dataset(root):
        return check_dataset(load_rct_dataset(root))
    if is_mchec_dataset(root):
        return check_dataset(load_mchec_dataset(root))
    raise InputError(
        f"{root}: not a calibgraph dataset (no dataset.yaml) and no supported peer layout found "
        "(industrial_calibration cal_data.yaml, or Multi-Camera-Hand-Eye-Calibration CalibrationInfo.yaml)."
    )


def is_dataset_root(root) -> bool:
    """True when the folder ``root`` holds a dataset calibgraph reads (its own layout or a peer's)."""
    return is_calibgraph_dataset(root) or is_rct_dataset(root) or is_mchec_dataset(root)


def as_dataset(dataset):
    """A Dataset from a Dataset, a folder path, or None (passed through)."""
    if dataset is None or isinstance(dataset, Dataset):
        return dataset
    if isinstance(dataset, (str, Path)):
        return load_dataset(dataset)
    return dataset
