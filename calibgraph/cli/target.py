"""``calibgraph target print SPEC --out board.pdf [--paper A4|A3]`` and ``calibgraph target show SPEC``."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("target", help="print or inspect a calibration target spec",
                       description="Targets: write a printable PDF at exact scale, or show a spec's points.")
    tsub = p.add_subparsers(dest="target_command", metavar="ACTION", required=True)
    pr = tsub.add_parser("print", help="write a PDF of the target at exact physical scale, with a ruler")
    pr.add_argument("spec", type=Path, help="target spec YAML (see datasets/targets/)")
    pr.add_argument("--out", type=Path, default=None, help="output PDF (default: SPEC with .pdf)")
    pr.add_argument("--paper", choices=("A4", "A3", "a4", "a3"), default="A4")
    sh = tsub.add_parser("show", help="print the spec, its board frame and point coordinates")
    sh.add_argument("spec", type=Path)
    return p


def run(args) -> int:
    from calibgraph.io.specs import load_target

    t = load_target(args.spec)
    if args.target_command == "print":
        from calibgraph.report.pdf import write_target_pdf

        from calibgraph.io.output_guard import check_output_file

        out = check_output_file(args.out or args.spec.with_suffix(".pdf"), "PDF", "PDF file", "board.pdf",
                                inputs=[args.spec])
        write_target_pdf(t, out, args.paper.upper())
        print(f"wrote {out} ({args.paper.upper()}); print at 100% scale and check the 100 mm ruler")
        return 0
    pts = t.points_board_m
    print(f"{t.kind}: {t.rows} x {t.cols} = {t.n_points} points, pitch {t.pitch_m * 1e3:.3f} mm"
          f"{', symmetric (ids ambiguous)' if t.is_symmetric else ''}")
    x0, y0, x1, y1 = t.extent_m
    print(f"printed extent {1e3 * (x1 - x0):.1f} x {1e3 * (y1 - y0):.1f} mm")
    for k in sorted({0, t.cols - 1, t.n_points - t.cols, t.n_points - 1}):
        print(f"  id {k:4d}: ({pts[k, 0]:.4f}, {pts[k, 1]:.4f}, 0) m")
    return 0
