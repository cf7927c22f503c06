"""``calibgraph report RESULT --out report.html``: the commissioning report (one HTML file)."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("report", help="write the commissioning report (self-contained HTML)",
                       description="Per-camera poses with 1-sigma, reprojection errors, views used and rejected, "
                                   "pass/fail against tolerances, residual plots, image coverage, workspace "
                                   "uncertainty maps and provenance, in one HTML file.")
    p.add_argument("result", type=Path, help="result.json or result.yaml written by `calibgraph solve`")
    p.add_argument("--out", type=Path, default=None, help="output HTML (default: report.html beside RESULT)")
    p.add_argument("--config", type=Path, default=None,
                   help="tolerances YAML (default: datasets/tolerances/default.yaml)")
    p.add_argument("--dataset", type=Path, default=None,
                   help="dataset folder: adds intrinsics, image coverage and residuals the result lacks "
                        "(default: the dataset named in RESULT, if it exists)")
    return p


def run(args) -> int:
    from calibgraph.report.html import write_report
    from calibgraph.solver.result import load_result_dict

    from calibgraph.io.files import output_file

    d = load_result_dict(args.result)
    out = output_file(args.out or args.result.with_name("report.html"), "report file", "report.html")
    dataset = args.dataset
    if dataset is None and d.get("dataset") and Path(d["dataset"]).is_dir():
        dataset = Path(d["dataset"])  # the dataset the result names, when it is still there
    path = write_report(d, out, config=args.config, dataset=dataset, result_path=args.result)
    print(f"wrote {path}")
    return 0
