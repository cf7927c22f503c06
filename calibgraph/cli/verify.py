"""``calibgraph verify --result RESULT.json DATASET``: has any camera moved since the calibration?

Each camera seen in the (short) dataset is re-estimated with the board mount, its intrinsics and
the board scale held at the stored estimates, and the change is tested against the stored
covariance plus the new one (chi-square, 6 dof; :mod:`calibgraph.solver.changes.verify`). Exit 0: nothing
moved; 3: a camera (or the board mount / robot) moved; 2: bad input. The verdict is written to
``DATASET/verify.json`` (``--verdict`` elsewhere).
"""

from __future__ import annotations

from pathlib import Path

EXIT_MOVED = 3


def add_parser(sub):
    p = sub.add_parser("verify", help="test whether any camera moved since a stored calibration",
                       description="Re-estimate each camera from a short fresh capture with everything else held at "
                                   "the stored calibration and test the change against the stored 1-sigma "
                                   "(chi-square, 6 dof). Exit 0: nothing moved, 3: something moved, 2: bad input.")
    p.add_argument("dataset", type=Path, help="the fresh capture (a dataset folder, any supported layout)")
    p.add_argument("--result", type=Path, required=True, help="the stored calibration (result.json)")
    p.add_argument("--alpha", type=float, default=None,
                   help="false-alarm probability per camera of the test (default 0.001)")
    p.add_argument("--verdict", type=Path, default=None, help="verdict JSON (default DATASET/verify.json)")
    p.add_argument("--quiet", action="store_true", help="no table: only the verdict line (and warnings, errors)")
    return p


def format_verdict(vr) -> str:
    """The per-camera table and the verdict in words."""
    from calibgraph.solver.changes.verify import chi2_isf_6

    lines = [f"test: chi-square 6 dof against stored + new covariance, alpha {vr.alpha:g} per camera "
             f"(threshold {chi2_isf_6(vr.alpha):.1f}), pixel sigma {vr.pixel_sigma_px:.3f} px",
             f"{'camera':10s} {'status':10s} {'views':>5s} {'moved [mm]':>16s} {'turned [deg]':>18s} {'m2':>8s} {'p-value':>9s}"]
    for n, c in vr.cameras.items():
        if c.status == "not_seen":
            lines.append(f"{n:10s} {'not seen':10s} {0:5d}")
            continue
        lines.append(f"{n:10s} {c.status:10s} {c.views:5d} {c.displacement_mm:7.2f} ± {c.sigma_displacement_mm:6.2f} "
                     f"{c.rotation_deg:8.3f} ± {c.sigma_rotation_deg:6.3f} {c.mahalanobis2:8.1f} {c.p_value:9.2g}")
    for note in vr.notes:
        lines.append(f"note: {note}")
    if vr.verdict == "mount_or_robot_moved":
        lines.append("verdict: the board mount or the robot moved, not the cameras")
    elif vr.verdict == "cameras_moved":
        lines.append(f"verdict: moved: {', '.join(vr.moved)}")
    else:
        unseen = [n for n, c in vr.cameras.items() if c.status == "not_seen"]
        lines.append("verdict: nothing moved" + (f" (not seen, so not verified: {', '.join(unseen)})" if unseen else ""))
    return "\n".join(lines)


def run(args) -> int:
    import json

    from calibgraph.core.errors import InputError
    from calibgraph.io.files import atomic_write_text
    from calibgraph.io.layouts import load_dataset
    from calibgraph.io.output_guard import check_output_file, write_keeping_previous
    from calibgraph.solver.solve.build import build_problem
    from calibgraph.solver.output.result import load_result, result_path, solved_target
    from calibgraph.solver.changes.verify import DEFAULT_ALPHA, check_fresh_data, verify

    args.result = result_path(args.result)  # the stored calibration's dataset folder: its result.json
    stored = load_result(args.result)
    # a fresh ViSP folder that names no board is checked with the stored calibration's
    dataset = load_dataset(args.dataset, fallback_target=solved_target(stored))
    if not dataset.captures:
        raise InputError(f"{args.dataset}: no captures to verify with.")
    check_fresh_data(stored, dataset.cameras, dataset.target, str(args.result))  # before detecting anything
    out = check_output_file(args.verdict or (Path(args.dataset) / "verify.json"), "verdict", "verdict file",
                            "verify.json", inputs=[args.result], datasets=[args.dataset])
    problem, _ = build_problem(dataset, progress=not args.quiet)
    vr = verify(problem, stored, alpha=DEFAULT_ALPHA if args.alpha is None else args.alpha, where=str(args.result),
                target=dataset.target)
    d = vr.to_dict()
    d.update({"result": str(args.result), "dataset": str(args.dataset)})
    kept = write_keeping_previous(out, lambda: atomic_write_text(out, json.dumps(d, indent=2)))
    if kept is not None:
        print(f"kept the previous verdict as {kept}")
    if not args.quiet:
        print(format_verdict(vr))
        print(f"wrote {out}")
    else:
        print(vr.verdict)
    return EXIT_MOVED if vr.anything_moved else 0

