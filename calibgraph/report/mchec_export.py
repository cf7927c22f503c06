"""Export a dataset in the Multi-Camera-Hand-Eye-Calibration (MC-HEC) folder layout, so the thesis's
published successor can be run on the same captures (the layout and its conventions:
:mod:`calibgraph.io.peer_mchec`, which reads it back)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.io.files import output_folder
from calibgraph.io.ground_truth import load_ground_truth
from calibgraph.io.layouts import as_dataset
from calibgraph.io.peer_mchec import (
    DIST_KEYS,
    IMAGE_EXT,
    INFO_NAME,
    INTRINSICS_NAME,
    SIDECAR_NAME,
)


def _write_pose(path: Path, T: np.ndarray) -> None:
    path.write_text("\n".join(" ".join(f"{v:.18e}" for v in row) for row in np.asarray(T, float)) + "\n")


def export_mchec(dataset_or_root, out_dir) -> Path:
    """Write a dataset (a :class:`~calibgraph.io.dataset.Dataset` or a folder any loader reads) in the
    MC-HEC layout at ``out_dir`` (created; must not exist yet). Returns ``out_dir``."""
    import cv2
    import yaml

    ds = as_dataset(dataset_or_root)
    out = Path(out_dir)
    if out.exists() or out.is_symlink():
        output_folder(out, "export folder", empty=True)
    if ds.target.kind != "checkerboard":
        raise InputError(f"MC-HEC export: target {ds.target.kind!r}; MC-HEC calibrates with checkerboards only.")
    cams = sorted(ds.cameras)
    folder_of = {c: f"camera{k + 1}" for k, c in enumerate(cams)}
    caps = sorted(ds.captures, key=lambda c: c.index)
    if not caps:
        raise InputError(f"{ds.root}: no captures to export.")
    view_of = {(v.camera, v.capture): v for v in ds.views}
    output_folder(out, "export folder")
    info = {"number_of_cameras": len(cams), "camera_folder_prefix": "camera", "pattern_type": "checkerboard",
            "number_of_rows": ds.target.cols, "number_of_columns": ds.target.rows, "size": float(ds.target.pitch_m),
            "resize_factor": 1, "visual_error": 0, "calibration_setup": 1 if ds.mode == "eye_to_hand" else 0}
    (out / INFO_NAME).write_text(yaml.safe_dump(info, sort_keys=False))
    width = max(4, len(str(max(c.index for c in caps))))
    placeholders = []
    for c in cams:
        intr = ds.cameras[c]
        if abs(intr.K[0, 1]) > 1e-12:
            raise InputError(f"MC-HEC export: camera {c!r} has a skewed K; MC-HEC's model has no skew.")
        d8 = intr.dist8
        f = out / folder_of[c]
        (f / "image").mkdir(parents=True)
        (f / "pose").mkdir()
        intr_d = {"fx": float(intr.K[0, 0]), "fy": float(intr.K[1, 1]), "cx": float(intr.K[0, 2]), "cy": float(intr.K[1, 2]),
                  "has_dist_coeff": 1, **{k: float(v) for k, v in zip(DIST_KEYS, d8)},
                  "img_width": intr.width_px, "img_height": intr.height_px}
        (f / INTRINSICS_NAME).write_text(yaml.safe_dump(intr_d, sort_keys=False))
        for cap in caps:
            stem = f"{cap.index:0{width}d}"
            _write_pose(f / "pose" / f"{stem}.csv", cap.T_base_flange)
            v = view_of.get((c, cap.index))
            src = (Path(ds.root) / v.image) if v is not None and v.image else None
            if src is not None and src.is_file() and src.suffix.lower() in IMAGE_EXT:
                shutil.copyfile(src, f / "image" / f"{stem}{src.suffix.lower()}")
            else:
                if not (intr.width_px and intr.height_px):
                    raise InputError(f"MC-HEC export: camera {c!r} has no image size; cannot write a placeholder image.")
                rel = f"{folder_of[c]}/image/{stem}.png"
                cv2.imwrite(str(out / rel), np.zeros((intr.height_px, intr.width_px), np.uint8))
                placeholders.append(rel)
    side = {"written_by": "calibgraph export_mchec", "camera_names": {folder_of[c]: c for c in cams},
            "placeholders": placeholders,
            "note": "placeholders are black images for captures a camera did not see (MC-HEC needs one image per waypoint)"}
    (out / SIDECAR_NAME).write_text(yaml.safe_dump(side, sort_keys=False))
    gt = Path(ds.root) / "ground_truth.json"
    if gt.is_file():
        try:
            truth = load_ground_truth(ds.root)
            (out / "GT").mkdir()
            for c in cams:
                if c in truth["T_base_cam"]:
                    _write_pose(out / "GT" / f"gt_{folder_of[c].replace('camera', 'cam')}.csv", truth["T_base_cam"][c])
        except (InputError, KeyError):
            pass  # ground truth is a convenience for comparisons, not part of the data
    return out
