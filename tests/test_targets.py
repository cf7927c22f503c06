"""Target geometry, specs and the printable PDF."""

import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target, rct_charuco_board, thesis_board
from calibgraph.io.specs import load_target

REPO = Path(__file__).resolve().parents[1]
SPECS = sorted((REPO / "datasets" / "targets").glob("*.yaml"))


def test_thesis_board_counts_inner_corners():
    t = thesis_board()
    assert (t.squares_x, t.squares_y, t.n_points) == (5, 4, 12)
    assert not t.is_symmetric  # 3 + 4 odd: colours fix the orientation
    assert np.allclose(t.points_board_m[5], [0.046, 0.046, 0])


@pytest.mark.parametrize("squares", [(5, 7), (6, 8), (4, 4), (7, 10)])
@pytest.mark.parametrize("legacy", [False, True])
def test_charuco_points_and_ids_match_opencv_board(squares, legacy):
    sx, sy = squares
    t = Target(kind="charuco", rows=sy - 1, cols=sx - 1, pitch_m=0.03, marker_m=0.022, dictionary="DICT_5X5_250",
               legacy_charuco=legacy)
    b = t.cv_charuco_board()
    assert b.getLegacyPattern() == legacy
    assert np.abs(b.getChessboardCorners() - t.points_board_m).max() < 1e-7


def test_dictionary_ids_and_names():
    t = Target.from_dict(dict(kind="charuco", squares_x=5, squares_y=7, pitch_m=0.036195, marker_m=0.018256, dictionary=10))
    assert t.dictionary == "DICT_6X6_250" and (t.rows, t.cols) == (6, 4)
    assert Target.from_dict({**t.to_dict(), "dictionary": "6x6_250"}).dictionary == "DICT_6X6_250"
    assert cv2.aruco.DICT_6X6_250 == 10
    with pytest.raises(InputError, match="unknown ArUco dictionary"):
        replace(t, dictionary="DICT_9X9_1")
    with pytest.raises(InputError, match="millimetres"):
        Target(kind="checkerboard", rows=3, cols=4, pitch_m=46)


def test_modified_circle_grid_matches_peer_layout():
    # industrial_calibration ModifiedCircleGridTarget::createPoints: for i in 1..rows: y = (rows - i) * s,
    # for j in 0..cols-1: x = j * s. The big dot is the origin, id (rows - 1) * cols.
    rows, cols, s = 4, 6, 0.02
    t = Target(kind="modified_circles", rows=rows, cols=cols, pitch_m=s)
    peer = np.array([[j * s, (rows - i) * s, 0.0] for i in range(1, rows + 1) for j in range(cols)])
    assert np.allclose(t.points_board_m, peer)
    assert np.allclose(t.points_board_m[(rows - 1) * cols], 0)
    assert not t.is_symmetric
    with pytest.raises(InputError, match="too large"):
        Target(kind="modified_circles", rows=4, cols=6, pitch_m=0.02, circle_diameter_m=0.011)


def test_symmetry_flags():
    assert Target(kind="checkerboard", rows=3, cols=5, pitch_m=0.02).is_symmetric
    assert not Target(kind="checkerboard", rows=6, cols=9, pitch_m=0.02).is_symmetric
    assert Target(kind="circles", rows=3, cols=4, pitch_m=0.02).is_symmetric
    assert not Target(kind="acircles", rows=11, cols=4, pitch_m=0.02).is_symmetric
    assert Target(kind="acircles", rows=4, cols=11, pitch_m=0.02).is_symmetric
    assert not rct_charuco_board().is_symmetric


@pytest.mark.parametrize("spec", SPECS, ids=[p.stem for p in SPECS])
def test_specs_load_and_round_trip(spec):
    t = load_target(spec)
    assert Target.from_dict(t.to_dict()) == t
    assert len(t.spec_hash()) == 12


def _rasterize_own_pdf(data: bytes, px_per_mm: float) -> np.ndarray:
    """Rasterise the pattern part of calibgraph's PDF (filled rectangles and Bézier circles drawn
    outside q..Q; the ruler strip is inside q..Q) with OpenCV's pixel-centre convention."""
    m = re.search(rb"/MediaBox \[0 0 ([\d.]+) ([\d.]+)\]", data)
    w_pt, h_pt = float(m.group(1)), float(m.group(2))
    s = data.index(b"stream\n") + 7
    ops = data[s:data.index(b"\nendstream")].decode("latin-1").split("\n")
    k = px_per_mm * 25.4 / 72
    img = np.full((int(round(h_pt * k)), int(round(w_pt * k))), 255, np.uint8)
    depth, sh = 0, 8
    for op in ops:
        if op.startswith("q "):
            depth += 1
        elif op == "Q":
            depth -= 1
        elif depth == 0 and op.endswith(" re f"):
            x, y, w, h = map(float, op.split()[:4])
            pts = np.array([[x, h_pt - y - h], [x + w, h_pt - y - h], [x + w, h_pt - y], [x, h_pt - y]]) * k - 0.5
            cv2.fillConvexPoly(img, np.round(pts * 2**sh).astype(np.int32), 0, cv2.LINE_AA, sh)
        elif depth == 0 and op.endswith(" f") and " c " in op:
            v = np.array(list(map(float, re.findall(r"-?[\d.]+", op))))
            xs, ys = v[0::2], v[1::2]
            cx, cy, r = (xs.max() + xs.min()) / 2, (ys.max() + ys.min()) / 2, (xs.max() - xs.min()) / 2
            c = (int(round((cx * k - 0.5) * 2**sh)), int(round(((h_pt - cy) * k - 0.5) * 2**sh)))
            cv2.circle(img, c, int(round(r * k * 2**sh)), 0, -1, cv2.LINE_AA, sh)
    return img


def _page_metric_error(target, det_ids, uv_px, px_per_mm):
    """Max deviation (mm) of detected page points from the target's geometry after removing the
    translation (and the y flip of the modified grid): checks the printed scale is exact."""
    P = target.points_board_m[det_ids, :2] * 1e3
    if target.kind == "modified_circles":
        P[:, 1] = -P[:, 1]
    Q = uv_px / px_per_mm
    return np.abs((Q - Q.mean(0)) - (P - P.mean(0))).max()


@pytest.mark.parametrize("name,paper", [("thesis_5x4_46mm", "A4"), ("charuco_rct_5x7", "A4"),
                                        ("acircles_a4_4x11_20mm", "A4"), ("modified_circles_rct_10x10", "A3")])
def test_pdf_is_exact_scale_and_detectable(tmp_path, name, paper):
    from calibgraph.cli.main import main
    from calibgraph.detect.corners import detect_image

    spec = REPO / "datasets" / "targets" / f"{name}.yaml"
    out = tmp_path / "board.pdf"
    assert main(["target", "print", str(spec), "--out", str(out), "--paper", paper]) == 0
    data = out.read_bytes()
    assert data.startswith(b"%PDF-1.4") and data.rstrip().endswith(b"%%EOF")
    w_mm, h_mm = (210, 297) if paper == "A4" else (297, 420)
    m = re.search(rb"/MediaBox \[0 0 ([\d.]+) ([\d.]+)\]", data)
    size = sorted([float(m.group(1)) * 25.4 / 72, float(m.group(2)) * 25.4 / 72])
    assert np.allclose(size, [w_mm, h_mm], atol=0.01)
    # The xref table points at the objects (a strict reader needs that).
    xref = int(re.search(rb"startxref\n(\d+)", data).group(1))
    assert data[xref:xref + 4] == b"xref"
    t = load_target(spec)
    ppm = 4.0
    img = _rasterize_own_pdf(data, ppm)
    det = detect_image(img, t, upscale=1)
    assert det.ok, det.reason
    assert det.n_found == t.n_points
    # Scale: rasterised at 4 px/mm, detected points sit where the spec says, to < 0.1 mm.
    assert _page_metric_error(t, det.ids, det.uv_px, ppm) < 0.1


def test_pdf_refuses_a_board_too_big_for_the_paper(tmp_path):
    from calibgraph.report.pdf import target_pdf

    with pytest.raises(InputError, match="A3"):
        target_pdf(Target(kind="checkerboard", rows=8, cols=11, pitch_m=0.03), "A4")
