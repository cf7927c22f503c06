"""Real lenses are not false detections: a good view through a distorting lens, checked with
nominal distortion-free intrinsics, passes the grid filter; bent or swapped points still fail."""

import numpy as np
import pytest

from calibgraph.core.camera import Intrinsics
from calibgraph.core.targets import a4_board_54
from calibgraph.detect.grid_filter import check_grid
from calibgraph.sim.board_image import look_at_board, render_view

NOMINAL = Intrinsics.from_hfov(640, 480, 80.0)  # a wide wrist camera at VGA, no distortion given


def _lens(k1):
    return Intrinsics(NOMINAL.K, np.array([k1, -0.25 * k1, 0.0, 0.0, 0.0]), 640, 480)


@pytest.mark.parametrize("k1", [-0.4, -0.3, 0.2])
@pytest.mark.parametrize("pose", [(0.25, 20, 10, (60, 40)), (0.22, 0, 0, (0, 0)), (0.3, 30, -20, (-80, 50))])
def test_distorted_good_view_passes_and_false_ones_still_fail(k1, pose):
    t = a4_board_54()
    d, tx, ty, off = pose
    lens = _lens(k1)
    uv = render_view(t, lens, look_at_board(t, d, tx, ty, 0, off, lens)).uv_px
    assert check_grid(uv, t.line_ij, t.points_board_m, intrinsics=NOMINAL).ok
    assert check_grid(uv, t.line_ij, t.points_board_m, intrinsics=lens).ok  # the true lens: no fallback needed
    bent = uv.copy()
    bent[13] += [0.0, 4.0]  # one corner 4 px off (about a fifth of a pitch here)
    assert not check_grid(bent, t.line_ij, t.points_board_m, intrinsics=NOMINAL).ok
    swapped = uv.copy()
    swapped[[20, 21]] = swapped[[21, 20]]
    assert not check_grid(swapped, t.line_ij, t.points_board_m, intrinsics=NOMINAL).ok


def test_strong_barrel_needs_the_lens_fallback_and_reports_it():
    """At k1 = -0.3 the outer row bends 3.5 px, beyond the straightness tolerance: without the
    fallback this good view was 'row 0 is not straight'. The fitted division parameter has the
    sign of the barrel (negative k1 ~ negative lambda)."""
    t = a4_board_54()
    lens = _lens(-0.3)
    uv = render_view(t, lens, look_at_board(t, 0.22, 0, 0, 0, (0, 0), lens)).uv_px
    r = check_grid(uv, t.line_ij, t.points_board_m, intrinsics=NOMINAL)
    assert r.ok and r.lens_lambda < -0.1
    assert not check_grid(uv, t.line_ij, t.points_board_m).ok  # no intrinsics: no principal point, no fallback
