"""01 — Solve a dataset folder: load it, build the problem, solve, read the answer, save it.

    python scripts/examples/01_solve_a_dataset.py DATASET [--out result.json]

DATASET is any layout calibgraph reads: its own (``dataset.yaml`` + ``captures/``),
industrial_calibration's (``cal_data.yaml``) or MC-HEC's (``CalibrationInfo.yaml``). Without an
argument it solves the real ChArUco dataset in ``../shared/datasets`` when that sits beside the
checkout. This is what ``calibgraph solve DATASET`` does, in six lines of API.
"""

import argparse
import sys
from pathlib import Path

import calibgraph as cg


def main(argv=None) -> int:
    default = Path(__file__).resolve().parents[3] / "shared" / "datasets" / "rct_static_camera_charuco"
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", type=Path, nargs="?", default=default)
    ap.add_argument("--out", type=Path, default=None, help="result file (default: none written)")
    args = ap.parse_args(argv)

    dataset = cg.load_dataset(args.dataset)                  # any supported layout
    problem, _detector = cg.build_problem(dataset)           # detects images that carry no stored corners
    result = cg.solve(problem)                               # Problem in, Result out

    for name, cam in result.cameras.items():
        t = cam.T_ref_cam[:3, 3]
        print(f"{name}: position {t.round(4).tolist()} m, 1-sigma {cam.sigma_translation_mm.round(3).tolist()} mm / "
              f"{cam.sigma_rotation_deg.round(4).tolist()} deg, reprojection {cam.reprojection_rms_px:.3f} px, "
              f"{cam.views_used} views")
    if args.out:
        result.save(args.out)                                # .json or .yaml
        assert cg.load_result(args.out) == result            # reads back equal, every number
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except cg.CalibgraphError as e:
        sys.exit(f"error: {e}")
