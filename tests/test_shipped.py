"""The shipped files (datasets/: targets, workcells, tolerances) resolve from any folder, by name, alias
or documented path; one board has one name; the printout's scale checks are the guide's and sit
inside a 10 mm margin (measured on the drawing and, where poppler is installed, on the rendered page)."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from calibgraph.cli.main import main
from calibgraph.core.errors import InputError
from calibgraph.core.targets import a4_board_54, thesis_board
from calibgraph.io.shipped import KINDS, resolve_shipped, shipped_names, shipped_path, shipped_root, target_name
from calibgraph.io.specs import load_target
from calibgraph.plan.cell import board_by_name
from calibgraph.report.pdf import CHECK_SQUARE_MM, MARGIN_MM, RULER_MM, target_layout, write_target_pdf

ROOT = Path(__file__).resolve().parents[1]


def test_every_shipped_file_resolves_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no datasets/ here
    for kind, folder in KINDS.items():
        files = sorted((ROOT / "datasets" / folder).glob("*.yaml"))
        assert [f.stem for f in files] == shipped_names(kind) and files
        for f in files:
            for spelling in (f.stem, f.name, f"datasets/{folder}/{f.name}"):
                p = resolve_shipped(spelling, kind)
                assert p.is_file() and p.read_bytes() == f.read_bytes(), (kind, spelling)
    assert load_target("datasets/targets/a4_7x10_25mm.yaml") == a4_board_54()
    from calibgraph.report.tolerances import load_tolerances
    from calibgraph.sim.workcell import load_workcell

    assert load_workcell("datasets/workcells/default.yaml").target == a4_board_54()
    assert load_tolerances("datasets/tolerances/default.yaml")["defaults"]["min_views_used"] == 8


def test_a_users_own_file_wins_and_an_unknown_name_is_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    own = tmp_path / "datasets" / "targets" / "a4_7x10_25mm.yaml"
    own.parent.mkdir(parents=True)
    own.write_text("target: {kind: checkerboard, rows: 4, cols: 5, pitch_m: 0.03}\n")
    assert load_target("datasets/targets/a4_7x10_25mm.yaml").rows == 4  # the path that exists is read as it is
    assert load_target("a4_54") == a4_board_54()  # a bare name is the shipped board
    with pytest.raises(InputError, match="shipped: a4_7x10_25mm, .*calibgraph target list"):
        shipped_path("target", "a5_board")
    assert main(["target", "show", "a5_board"]) == 2
    assert "no such file, nor a shipped target" in capsys.readouterr().err


def test_the_wheel_carries_every_shipped_file():
    setup = (ROOT / "setup.py").read_text()
    assert '"calibgraph.datasets": "datasets"' in setup and '"calibgraph.datasets"]' in setup
    folders = re.search(r"SHIPPED = \(([^)]*)\)", setup).group(1)
    assert sorted(re.findall(r'"(\w+)"', folders)) == sorted(KINDS.values())
    assert 'package_data={"calibgraph.datasets": [f"{d}/*.yaml" for d in SHIPPED]}' in setup
    shipped = {p.relative_to(ROOT / "datasets") for p in (ROOT / "datasets").rglob("*") if p.is_file()}
    assert shipped == {Path(f) / p.name for f in KINDS.values() for p in (ROOT / "datasets" / f).glob("*.yaml")}
    assert shipped_root() in (ROOT / "datasets", ROOT / "calibgraph" / "datasets")


def test_one_board_one_name():
    a4 = a4_board_54()
    assert target_name(a4) == "a4_7x10_25mm" and target_name(thesis_board()) == "thesis_5x4_46mm"
    for alias in ("a4_54", "a4", "54", "a4_7x10_25mm", "a4_7x10_25mm.yaml", "datasets/targets/a4_7x10_25mm.yaml"):
        assert board_by_name(alias) == a4, alias
    assert board_by_name("thesis") == thesis_board()
    # the name says what the board is: 7 x 10 squares of 25 mm (rows x cols, as the spec's 6 x 9 corners)
    assert a4.describe() == "checkerboard, 7 x 10 squares of 25 mm, 6 x 9 inner corners"
    from calibgraph.cli.main import build_parser

    demo = build_parser().parse_args(["demo"])
    assert demo.board == "a4_7x10_25mm"
    for f in (ROOT / "datasets" / "workcells").glob("*.yaml"):
        m = re.search(r"^board: (\S+)", f.read_text(), re.M)
        assert m and m.group(1) in shipped_names("target"), f.name


def test_target_list_and_show(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["target", "list"]) == 0
    out = capsys.readouterr().out
    for n in shipped_names("target"):
        assert re.search(rf"^  {n} ", out, re.M), n
    assert "also a4_54" in out
    assert main(["target", "show", "a4_54"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("a4_7x10_25mm: checkerboard, 7 x 10 squares of 25 mm") and "250.0 mm across" in out
    assert main(["target", "print", "a4_54"]) == 0  # a shipped name: NAME.pdf here, never into the package
    assert (tmp_path / "a4_7x10_25mm.pdf").is_file()


def _boards():
    return [(n, load_target(shipped_path("target", n))) for n in shipped_names("target")]


@pytest.mark.parametrize("name,target", _boards(), ids=[n for n, _ in _boards()])
def test_the_printout_sits_inside_the_margin_with_the_guides_checks(name, target):
    try:
        lay = target_layout(target, "A4", name)
    except InputError:
        lay = target_layout(target, "A3", name)  # the 250 mm modified circle grid is an A3 board
    W, H = lay["paper_mm"]
    boxes = lay["boxes"] + [("pattern", *lay["pattern_mm"])]
    for what, x0, y0, x1, y1 in boxes:
        assert MARGIN_MM - 1e-6 <= x0 <= x1 <= W - MARGIN_MM + 1e-6, (what, x0, x1, W)
        assert MARGIN_MM - 1e-6 <= y0 <= y1 <= H - MARGIN_MM + 1e-6, (what, y0, y1, H)
    px0, py0, px1, py1 = lay["pattern_mm"]
    for what, x0, y0, x1, y1 in lay["boxes"]:  # nothing of the strip on the pattern
        assert x1 <= px0 or x0 >= px1 or y1 <= py0 or y0 >= py1, what
    sq = [b for b in lay["boxes"] if b[0] == "check square"]
    assert len(sq) == 1 and np.isclose(sq[0][3] - sq[0][1], CHECK_SQUARE_MM) and np.isclose(sq[0][4] - sq[0][2], CHECK_SQUARE_MM)
    ruler = [b for b in lay["boxes"] if b[0] == "ruler"][0]
    assert np.isclose(max(ruler[3] - ruler[1], ruler[4] - ruler[2]), RULER_MM)
    # the caption names the board by its one name
    assert any(f"calibgraph {name}: {target.describe()}" in b[0] for b in lay["boxes"])


def test_the_guide_names_the_checks_the_printout_has():
    guide = (ROOT / "docs" / "guide.md").read_text()
    assert f"printed {RULER_MM:g} mm ruler, the {CHECK_SQUARE_MM:g} mm square" in guide
    assert "50 mm square" not in guide + (ROOT / "docs" / "cli.md").read_text() + (ROOT / "docs" / "formats.md").read_text()


def test_the_rendered_page_measures_as_drawn(tmp_path):
    """pdftoppm (poppler-utils; CI installs it) renders the A4 board's page: no ink within 10 mm of
    an edge, the check square 10 mm on both axes, the pattern's outer squares 250 x 175 mm."""
    if shutil.which("pdftoppm") is None:
        pytest.skip("pdftoppm (Debian poppler-utils) not installed")
    import cv2

    pdf = write_target_pdf(a4_board_54(), tmp_path / "board.pdf", "A4", name="a4_7x10_25mm")
    dpi = 200
    subprocess.run(["pdftoppm", "-r", str(dpi), "-gray", "-png", str(pdf), str(tmp_path / "page")], check=True)
    img = cv2.imread(str(next(tmp_path.glob("page*.png"))), cv2.IMREAD_GRAYSCALE)
    mm = 25.4 / dpi
    assert img.shape[1] * mm == pytest.approx(297, abs=1) and img.shape[0] * mm == pytest.approx(210, abs=1)  # landscape
    ys, xs = np.nonzero(img < 160)
    margins = [xs.min() * mm, (img.shape[1] - 1 - xs.max()) * mm, ys.min() * mm, (img.shape[0] - 1 - ys.max()) * mm]
    assert min(margins) >= MARGIN_MM - 1.5 * mm, margins
    n, _, stats, _ = cv2.connectedComponentsWithStats((img < 160).astype(np.uint8), connectivity=8)
    sizes = sorted((w * mm, h * mm) for x, y, w, h, a in stats[1:] if a > 0.95 * w * h and w * mm > 5)
    squares = [(w, h) for w, h in sizes if abs(w - CHECK_SQUARE_MM) < 1 and abs(h - CHECK_SQUARE_MM) < 1]
    assert len(squares) == 1 and max(abs(v - CHECK_SQUARE_MM) for v in squares[0]) < 2 * mm, sizes
    board = max(((w, h) for x, y, w, h, a in stats[1:] for w, h in [(w * mm, h * mm)]), key=lambda s: s[0] * s[1])
    assert board == pytest.approx((250.0, 175.0), abs=2 * mm)
