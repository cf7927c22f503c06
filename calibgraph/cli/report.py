"""``calibgraph report RESULT --out report.html``: the commissioning report (one HTML file)."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("report", help="write the commissioning report (self-contained HTML)",
                       description="Per-camera poses with 1-sigma, reprojection errors, views used and rejected, "
                                   "pass/fail against tolerances, residual plots, image coverage, workspace "
                                   "uncertainty maps and provenance, in one HTML file.")
    p.add_argument("result", type=Path, help="result.json or result.yaml written by `calibgraph solve` (or the dataset "
                                             "folder it wrote result.json into)")
    p.add_argument("--out", type=Path, default=None, help="output HTML (default: report.html beside RESULT)")
    p.add_argument("--config", type=Path, default=None,
                   help="tolerances YAML (default: datasets/tolerances/default.yaml)")
    p.add_argument("--dataset", type=Path, default=None,
                   help="the dataset RESULT was solved from: adds intrinsics, image coverage and residuals the result "
                        "lacks (default: the dataset named in RESULT, if it exists); another dataset is refused")
    p.add_argument("--strict", action="store_true",
                   help=f"exit {EXIT_FAIL} when the verdict is FAIL (the report is still written); default: exit 0 "
                        "whatever the verdict")
    return p


EXIT_FAIL = 3  # with --strict: the report is written, and its verdict is FAIL


def print_verdict(result, verdicts: dict) -> bool:
    """Print 'verdict: PASS' or 'verdict: FAIL (...)' with, under a FAIL, the step that fixes each
    failing check; True when it passed."""
    failing = {n: v for n, v in verdicts.items() if not v["pass"]}
    if not failing and result.converged:
        print("verdict: PASS")
        return True
    why = ["the solver did not converge"] if not result.converged else []
    print("verdict: FAIL (" + "; ".join(why + [f"{n}: {', '.join(v['reasons'])}" for n, v in failing.items()]) + ")")
    for v in failing.values():
        for f in v.get("fixes", []):
            print(f"  to fix: {f}")
    return False


def run(args) -> int:
    import sys

    from calibgraph.io.layouts import load_dataset
    from calibgraph.io.output_guard import check_output_file, write_keeping_previous
    from calibgraph.report.html import dataset_mismatch, report_verdicts, write_report
    from calibgraph.solver.output.result import load_result, result_path, solved_target

    args.result = result_path(args.result)  # a dataset folder: the result.json solve wrote into it
    result = load_result(args.result)
    # the report may go into the top folder of the result's own dataset (the one it names or sits in)
    out = check_output_file(args.out or args.result.with_name("report.html"), "report", "report file", "report.html",
                            inputs=[args.result, args.config],
                            datasets=[result.dataset, args.dataset, args.result.parent])
    board = solved_target(result)  # the board of a layout that names none (ViSP's): the one it was solved with
    dataset = load_dataset(args.dataset, fallback_target=board) if args.dataset is not None else None
    if dataset is None and result.dataset and Path(result.dataset).is_dir():
        # the dataset the result names, when it is still there and still its own
        named = load_dataset(result.dataset, fallback_target=board)
        differ = dataset_mismatch(result, named)
        if differ:
            print(f"warning: {result.dataset} (named in {args.result}) no longer holds the data of this result "
                  f"({differ[0]}); reporting from the result alone", file=sys.stderr)
        else:
            dataset = named
    # a report edited since calibgraph wrote it is kept beside it (as report.1.html), as a replaced result is
    kept = write_keeping_previous(out, lambda: write_report(result, out, config=args.config, dataset=dataset,
                                                            result_path=args.result))
    path = out
    if kept is not None:
        print(f"kept the previous report as {kept} (edited since calibgraph wrote it, or too old to tell)")
    passed = print_verdict(result, report_verdicts(result, config=args.config, dataset=dataset))
    print(f"wrote {path}")
    return EXIT_FAIL if args.strict and not passed else 0
