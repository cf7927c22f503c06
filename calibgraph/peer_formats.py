"""Readers for peer projects' dataset layouts (industrial_calibration / RCT, MC-HEC).

Filled in by the detection and capture work; this module only dispatches.
"""

from __future__ import annotations

from pathlib import Path

from .errors import InputError


def load_peer_dataset(root):
    root = Path(root)
    raise InputError(
        f"{root}: not a calibgraph dataset (no dataset.yaml) and no supported peer layout found "
        "(industrial_calibration cal_data.yaml, or Multi-Camera-Hand-Eye-Calibration CalibrationInfo.yaml)."
    )
