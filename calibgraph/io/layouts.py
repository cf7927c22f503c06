"""Which dataset layout a folder holds, and reading it: calibgraph's own, industrial_calibration /
robot_cal_tools (RCT), Multi-Camera-Hand-Eye-Calibration (MC-HEC), or ViSP's hand-eye folders."""

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
from calibgraph.io.peer_visp import is_visp_dataset, load_visp_dataset


def load_dataset(root, target=None, fallback_target=None) -> Dataset:
    """Read a dataset folder in any supported layout (calibgraph, industrial_calibration/RCT,
    Multi-Camera-Hand-Eye-Calibration, ViSP). Unreadable capture files and dropped duplicated captures are
    listed in ``problems``; nothing else is dropped silently. Everyday mistakes (poses in millimetres,
    rows and cols swapped, a pitch far off, images of another size than the intrinsics) are refused
    with their cause (:mod:`calibgraph.io.checks`).

    ``target`` (a :class:`~calibgraph.core.targets.Target`, ``--target``): the board of a layout
    that may not name one (ViSP's); refused for a layout that names its own. ``fallback_target``: the
    board of such a layout when the folder names none (a stored result's); ignored by the others."""
    root = Path(root)
    if not root.exists():
        raise InputError(f"{root}: no such dataset folder.")
    if not root.is_dir():
        raise InputError(f"{root}: is a file; give the dataset folder (the one holding dataset.yaml and captures/).")
    own = next((f for f, test in OWN_BOARD if test(root)), None)
    if own is not None and target is not None:
        raise InputError(f"--target: {root} names its board in {own}; --target is for layouts that name none "
                         "(ViSP's hand-eye folders): leave it out, or change the board there.")
    if is_calibgraph_dataset(root):
        return check_dataset(read_calibgraph_dataset(root))
    if is_rct_dataset(root):
        return check_dataset(load_rct_dataset(root))
    if is_mchec_dataset(root):
        return check_dataset(load_mchec_dataset(root))
    if is_visp_dataset(root):
        return check_dataset(load_visp_dataset(root, target, fallback_target))
    raise InputError(
        f"{root}: not a calibgraph dataset (no dataset.yaml) and no supported peer layout found "
        "(industrial_calibration cal_data.yaml, Multi-Camera-Hand-Eye-Calibration CalibrationInfo.yaml, or ViSP's "
        "pose_fPe_N.yaml / *_rPe_N.yaml with camera.xml)."
    )


# layouts whose own files name the board (the file, and the test of the folder)
OWN_BOARD = (("dataset.yaml", is_calibgraph_dataset), ("cal_data.yaml", is_rct_dataset),
             ("CalibrationInfo.yaml", is_mchec_dataset))


def is_dataset_root(root) -> bool:
    """True when the folder ``root`` holds a dataset calibgraph reads (its own layout or a peer's)."""
    return is_calibgraph_dataset(root) or is_rct_dataset(root) or is_mchec_dataset(root) or is_visp_dataset(root)


def as_dataset(dataset, fallback_target=None):
    """A Dataset from a Dataset, a folder path, or None (passed through); ``fallback_target`` as in
    :func:`load_dataset`."""
    if dataset is None or isinstance(dataset, Dataset):
        return dataset
    if isinstance(dataset, (str, Path)):
        return load_dataset(dataset, fallback_target=fallback_target)
    return dataset
