"""``calibgraph target list``, ``calibgraph target print SPEC [--out board.pdf] [--paper A4|A3]`` and
``calibgraph target show SPEC``.

SPEC is a target spec file or a shipped board's name (``calibgraph target list``: ``a4_7x10_25mm``,
its alias ``a4_54``, ...) or its documented path ``datasets/targets/NAME.yaml``, from any folder."""

from __future__ import annotations

from pathlib import Path

SPEC_HELP = ("a shipped board's name (calibgraph target list; e.g. a4_7x10_25mm, alias a4_54) or a target spec "
             "YAML file (datasets/targets/NAME.yaml works from any folder)")


def add_parser(sub):
    p = sub.add_parser("target", help="list, print or inspect the calibration targets",
                       description="Targets: list the shipped boards, write a printable PDF at exact scale, or show a "
                                   "spec's points.")
    tsub = p.add_subparsers(dest="target_command", metavar="ACTION", required=True)
    tsub.add_parser("list", help="the shipped boards: name, aliases, what they are",
                    description="The shipped boards, each by the one name every command takes (its aliases still work).")
    pr = tsub.add_parser("print", help="write a PDF of the target at exact physical scale, with a ruler",
                         description="A PDF of the target at exact physical scale (print at 'actual size', no scaling), "
                                     "with a 100 mm ruler, a 10 mm square and the board's own size printed beside it "
                                     "to check the print on both axes; everything inside a 10 mm margin.")
    pr.add_argument("spec", type=Path, help=SPEC_HELP)
    pr.add_argument("--out", type=Path, default=None,
                    help="output PDF (default: SPEC with .pdf for a spec file; NAME.pdf in the current folder for a "
                         "shipped board)")
    pr.add_argument("--paper", choices=("A4", "A3", "a4", "a3"), default="A4",
                    help="paper size, A4 (default) or A3; the page turns to landscape for a wide board")
    sh = tsub.add_parser("show", help="print the spec, its size, its board frame and some point coordinates",
                         description="The spec in words, its printed size, and the board-frame coordinates of its "
                                     "corner points (ids 0, cols-1, ... : the frame the result's T_flange_board uses).")
    sh.add_argument("spec", type=Path, help=SPEC_HELP)
    return p


def _list() -> int:
    from calibgraph.io.shipped import ALIASES, shipped_names, shipped_root
    from calibgraph.io.specs import load_target

    aliases = {}
    for a, n in ALIASES["target"].items():
        aliases.setdefault(n, []).append(a)
    names = shipped_names("target")
    w = max(len(n) for n in names)
    print(f"shipped boards ({shipped_root() / 'targets'}); give the name to any command that takes a target:")
    for n in names:
        t = load_target(shipped_root() / "targets" / f"{n}.yaml")
        x0, y0, x1, y1 = t.extent_m
        also = f"; also {', '.join(aliases[n])}" if n in aliases else ""
        print(f"  {n:{w}s}  {t.describe()}; printed {1e3 * (x1 - x0):.0f} mm across, {1e3 * (y1 - y0):.0f} mm down{also}")
    return 0


def run(args) -> int:
    if args.target_command == "list":
        return _list()
    from calibgraph.io.shipped import canonical_name, resolve_shipped, shipped_path
    from calibgraph.io.specs import load_target

    given = resolve_shipped(args.spec, "target")
    shipped = given != args.spec  # a name, alias or documented path found among the shipped files
    t = load_target(args.spec)  # a missing file that names no shipped board: one line naming the shipped ones
    name = canonical_name("target", given.name)
    if name is not None and load_target(shipped_path("target", name)) != t:
        name = None  # a user's own file that happens to share a shipped file's name
    label = name or given.stem
    if args.target_command == "print":
        from calibgraph.io.output_guard import check_output_file
        from calibgraph.report.pdf import write_target_pdf

        default = Path(f"{label}.pdf") if shipped else given.with_suffix(".pdf")
        out = check_output_file(args.out or default, "PDF", "PDF file", "board.pdf", inputs=[given])
        write_target_pdf(t, out, args.paper.upper(), name=label)
        x0, y0, x1, y1 = t.extent_m
        print(f"wrote {out} ({args.paper.upper()}): {label}, {t.describe()}; print at 100% scale (no scaling) and "
              f"check the 100 mm ruler, the 10 mm square and the pattern ({1e3 * (x1 - x0):.1f} mm across, "
              f"{1e3 * (y1 - y0):.1f} mm down)")
        return 0
    pts = t.points_board_m
    print(f"{label}: {t.describe()} ({t.kind}, rows {t.rows}, cols {t.cols}: {t.n_points} points, pitch "
          f"{t.pitch_m * 1e3:.3f} mm{', symmetric: ids ambiguous' if t.is_symmetric else ''})")
    print(f"file {given}")
    x0, y0, x1, y1 = t.extent_m
    print(f"printed extent {1e3 * (x1 - x0):.1f} mm across (x), {1e3 * (y1 - y0):.1f} mm down (y)")
    for k in sorted({0, t.cols - 1, t.n_points - t.cols, t.n_points - 1}):
        print(f"  id {k:4d}: ({pts[k, 0]:.4f}, {pts[k, 1]:.4f}, 0) m")
    return 0
