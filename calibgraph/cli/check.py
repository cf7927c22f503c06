"""``calibgraph check RESULT [--truth ground_truth.json]``: a result against a simulated dataset's ground truth.

Per camera: the true error (mm, deg), the 1σ norm, error / 1σ, the squared Mahalanobis distance of
the 6-dof error under the result's covariance and its chi-square p (6 dof); the focal length given
and solved against the true one. Exit 0 when every camera is inside (p >= --alpha), 3 when one is
outside or not calibrated, 2 on bad input. See :mod:`calibgraph.report.truth`."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("check", help="compare a result with the simulator's ground truth (error, 1σ, chi-square)",
                       description="A result against a known truth (a simulated dataset's ground_truth.json): per "
                                   "camera the true error, its 1σ norm, error / 1σ, the Mahalanobis² of the 6-dof "
                                   "error under the result's covariance and its chi-square p. Exit 0: every camera "
                                   "inside; 3: a camera outside (p < --alpha) or not calibrated; 2: bad input.")
    p.add_argument("result", type=Path, metavar="RESULT",
                   help="result.json / result.yaml, or the dataset folder solve wrote result.json into")
    p.add_argument("--truth", type=Path, default=None,
                   help="ground_truth.json (default: the one in RESULT's folder, else in the dataset the result names)")
    p.add_argument("--alpha", type=float, default=0.001,
                   help="a camera is outside when P(chi2_6 > Mahalanobis²) < ALPHA (default 0.001: the rate at which "
                        "a camera with an honest 1σ is called outside)")
    return p


def _truth_file(args, result) -> Path:
    from calibgraph.core.errors import InputError
    from calibgraph.io.ground_truth import GT_NAME

    if args.truth is not None:
        t = Path(args.truth)
        return t / GT_NAME if t.is_dir() else t
    tried = [Path(args.result).parent / GT_NAME]
    if result.dataset:
        tried.append(Path(result.dataset) / GT_NAME)
    for t in tried:
        if t.is_file():
            return t
    raise InputError(f"no ground truth found (looked for {' and '.join(map(str, dict.fromkeys(tried)))}); give it with "
                     "--truth ground_truth.json (only simulated datasets have one)")


def run(args) -> int:
    from calibgraph.io.ground_truth import load_ground_truth
    from calibgraph.report.truth import check_against_truth, format_truth_table
    from calibgraph.solver.output.result import load_result, result_path

    args.result = result_path(args.result)
    result = load_result(args.result)
    truth_file = _truth_file(args, result)
    truth = load_ground_truth(truth_file)
    rows = check_against_truth(result, truth, args.alpha)
    print(f"{args.result} against {truth_file}:")
    print(format_truth_table(rows, args.alpha))
    return 0 if all(r.status == "inside" for r in rows) else 3
