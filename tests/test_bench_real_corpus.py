"""scripts/bench_real_corpus.py's figures from its records (issue 45, item 8), without the sets: the
paired difference to the best OpenCV method and its SE, expected against measured, the bars it flags,
and the claims read from a result (a board's move is not a camera's)."""

import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))

import bench_real_corpus as brc  # noqa: E402


def _split(cg, tsai, park, expected):
    return {"label": "x", "scores": {"calibgraph": {"rms_px": cg}, "TSAI": {"rms_px": tsai}, "PARK": {"rms_px": park}},
            "calibgraph_prediction": {"expected_rms_px": expected}}


def test_heldout_summary_pairs_calibgraph_with_the_best_peer_over_the_splits():
    rec = {"splits": [_split(1.0, 1.5, 3.0, 1.0), _split(2.0, 2.5, 3.0, 1.0), _split(3.0, 2.5, 3.0, 1.0)],
           "calibgraph_sigma": {"ratio_pooled": 0.5, "dof": 5}}
    s = brc.heldout_summary(rec)
    assert s["best_peer"] == "TSAI" and s["peer_px"] == pytest.approx(6.5 / 3)
    d = np.array([-0.5, -0.5, 0.5])
    assert s["diff_px"] == pytest.approx(d.mean()) and s["se_px"] == pytest.approx(d.std(ddof=1) / np.sqrt(3))
    assert s["measured_px"] == pytest.approx(np.sqrt(14 / 3)) and s["expected_px"] == pytest.approx(1.0)
    flags = brc.flags({}, "cam", {}, s)
    assert any("stated / observed 0.50" in f for f in flags) and any("x2.16" in f for f in flags)
    assert not any("WORSE" in f for f in flags)  # -0.17 px: better, not worse beyond 1 SE
    worse = brc.heldout_summary({"splits": [_split(3.0, 1.0, 4.0, 3.0), _split(3.2, 1.1, 4.0, 3.0)]})
    assert any("WORSE than TSAI" in f for f in brc.flags({}, "cam", {}, worse))


def test_a_failed_train_split_is_left_out_of_the_pairing():
    bad = {"label": "x", "scores": {"TSAI": {"rms_px": 9.0}}, "calibgraph_error": "not calibrated: ..."}
    s = brc.heldout_summary({"splits": [_split(1.0, 2.0, 3.0, 1.0), bad, _split(1.0, 3.0, 3.0, 1.0)]})
    assert s["cg_splits"] == 2 and s["n_splits"] == 3 and s["best_peer"] == "TSAI"
    assert s["diff_px"] == pytest.approx(-1.5)


def _result(notes, moved=None, settings=None):
    cam = SimpleNamespace(moved=moved, calibrated=True)
    return SimpleNamespace(notes=tuple(notes), cameras={"cam": cam}, settings=settings or {}, converged=True,
                           iterations=9, board_scale=1.0, board_scale_sigma=None, fk_noise={}, not_calibrated={})


def test_a_board_move_is_not_read_as_a_camera_move():
    board = ("the board moved during capture, between captures 23 and 24, by 7.0 mm and 2.14 deg (F 44): the views "
             "before and after agree once each side has its own board pose, and no camera moved.")
    c = brc.claims_of(_result([board], settings={"board_moved": {"displacement_mm": 7.0, "last_capture_before": 23,
                                                                 "capture": 24}}))
    assert c["board moved"] == "7.0 mm between captures 23 and 24" and c["camera moved"] is False
    c = brc.claims_of(_result(["camera cam moved during capture, between captures 5 and 6"],
                              moved={"displacement_mm": 5.2, "last_capture_before": 5, "capture": 6}))
    assert c["camera moved"] == "cam: 5.2 mm between captures 5 and 6" and c["board moved"] is False
    assert not any(brc.claims_of(_result(["camera cam: focal length estimated +0.8 %"])).values())
