"""Detection's fast paths against the slow, full answers they stand in for (issue 36).

- ``roi_candidates`` merges and ranks the saddle responses in the box around them, not the whole
  image: the same regions as the whole image gives, on rendered frames and on the MC-HEC
  recording's real 1080p frames.
- The blind look remembers what its probe saw in a frame file (by the file's bytes): a second look
  at the same file is the same detection as a fresh look, without probing or decoding when the
  probe saw nothing; a file with other bytes is probed afresh.
- The board fit's model computes both axes as one stacked array: its analytic Jacobian matches
  central differences of the model (checkerboard and ChArUco, tilted views: every term, the
  bivariate-normal one included).
- The renderer's sub-pixel box mean (OpenCV's area resize at 4x4 samples) and its reuse of the last
  board texture: the same images, bit for bit, as numpy's mean over a texture painted afresh
  (the hand-held board's frames, distorted and not, 8 and 16 bit).
"""

from pathlib import Path

import cv2
import numpy as np
import pytest

import calibgraph.detect.blind as blind
import calibgraph.detect.board_fit as board_fit
from calibgraph.core.camera import Intrinsics
from calibgraph.core.targets import Target
from calibgraph.detect.image import Frame
from calibgraph.detect.regions import roi_candidates
from calibgraph.sim.board_image import look_at_board, render_view

F_PX = 1400.0
INTR = Intrinsics(K=np.array([[F_PX, 0, 959.5], [0, F_PX, 539.5], [0, 0, 1]]), dist=np.zeros(5), width_px=1920,
                  height_px=1080)
BOARD = Target.from_dict({"kind": "checkerboard", "rows": 3, "cols": 4, "pitch_m": 0.05})


def _frames(n, seed, square_px=(6, 30)):
    """``n`` rendered 1080p frames of BOARD (squares of ``square_px`` pixels, tilted, off centre) on
    a background with a few dark bars (clutter the saddle filter also answers)."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        sq = rng.uniform(*square_px)
        tilt, phi = rng.uniform(0, 45), rng.uniform(0, 2 * np.pi)
        off = rng.uniform(-0.6, 0.6, 2) * np.array([960, 540])
        T = look_at_board(BOARD, F_PX * BOARD.pitch_m / sq, tilt * np.cos(phi), tilt * np.sin(phi),
                          rng.uniform(0, 360), tuple(off), INTR)
        img = render_view(BOARD, INTR, T, blur_sigma_px=rng.uniform(0.4, 1.2), noise_sigma=1.0, seed=k).image.copy()
        for _ in range(3):
            x, y = int(rng.integers(0, 1800)), int(rng.integers(0, 1000))
            img[y:y + int(rng.integers(10, 80)), x:x + int(rng.integers(10, 120))] = int(rng.integers(0, 60))
        out.append(img)
    return out


def test_saddle_regions_from_the_box_equal_the_whole_image():
    frames = _frames(12, 1)
    frames.append(np.full((1080, 1920), 128, np.uint8))  # no response at all
    for img in frames:
        assert roi_candidates(img, BOARD) == roi_candidates(img, BOARD, crop=False)


def test_saddle_regions_on_the_mchec_recording(shared_dir):
    root = shared_dir / "datasets" / "mchec_medium_workcell"
    files = sorted(root.glob("camera*/image/*.png"))[::25]
    if not files:
        pytest.skip(f"{root} has no frames")
    for f in files:
        img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        assert roi_candidates(img, BOARD) == roi_candidates(img, BOARD, crop=False), f


def _same(a, b):
    assert (a.ok, a.reason, a.deferred, a.other_grid, a.pattern) == (b.ok, b.reason, b.deferred, b.other_grid,
                                                                     b.pattern)
    assert np.array_equal(a.ids, b.ids) and np.array_equal(a.uv_px, b.uv_px)


@pytest.mark.parametrize("check_spec", [True, False])
def test_a_frame_looked_at_again_is_the_same_look(tmp_path, monkeypatch, check_spec):
    board, empty = _frames(1, 2, square_px=(25, 30))[0], np.full((1080, 1920), 90, np.uint8)
    empty[400:600, 700:1100] = 30
    paths = []
    for name, img in (("board.png", board), ("empty.png", empty)):
        cv2.imwrite(str(tmp_path / name), img)
        paths.append(tmp_path / name)
    monkeypatch.setattr(blind, "_SEEN", type(blind._SEEN)())
    probes, decodes = [], []
    real_seen, real_grey = blind.chessboard_seen, Frame.grey
    # the probes of the whole frame (full or reduced), not _part_of_larger's of a found grid's surroundings
    monkeypatch.setattr(blind, "chessboard_seen",
                        lambda g, *a, **k: (g.shape[1] * 2 >= 1920 and probes.append(1)) or real_seen(g, *a, **k))
    monkeypatch.setattr(Frame, "grey", lambda self: decodes.append(1) or real_grey(self))
    for p in paths:
        first = blind.look_blind(Frame(p), BOARD, INTR, check_spec=check_spec, gate=True, upscale=1)
        n_probes, n_decodes = len(probes), len(decodes)
        again = blind.look_blind(Frame(p), BOARD, INTR, check_spec=check_spec, gate=True, upscale=1)
        _same(first, again)
        assert len(probes) == n_probes  # remembered
        if p.name == "empty.png":
            assert not first.ok and len(decodes) == n_decodes  # nothing seen: not even decoded again
        # the slow answer: a look with nothing remembered
        monkeypatch.setattr(blind, "_SEEN", type(blind._SEEN)())
        _same(first, blind.look_blind(Frame(p), BOARD, INTR, check_spec=check_spec, gate=True, upscale=1))
    assert blind.look_blind(Frame(paths[0]), BOARD, INTR, gate=True, upscale=1).ok
    # other bytes under the same name are probed afresh
    other = empty.copy()
    other[100:300, 200:500] = 200
    cv2.imwrite(str(paths[0]), other)
    n_probes = len(probes)
    assert not blind.look_blind(Frame(paths[0]), BOARD, INTR, gate=True, upscale=1).ok
    assert len(probes) > n_probes


def _model_call(target, T, blur):
    """The arguments of the board fit's first model evaluation with a Jacobian on a rendered view."""
    rv = render_view(target, INTR, T, blur_sigma_px=blur, noise_sigma=0.5, seed=3)
    calls = []
    real = board_fit._model

    def spy(*a, **k):
        if k.get("jacobian", True) and not calls:
            calls.append((a, k))
        return real(*a, **k)

    board_fit._model = spy
    try:
        if target.kind == "charuco":
            board_fit.refine_charuco(rv.image, target, rv.ids, rv.uv_px + 0.3, blur_px=blur, max_iterations=1)
        else:
            board_fit.refine_checkerboard(rv.image, target, rv.ids, rv.uv_px + 0.3, max_iterations=1)
    finally:
        board_fit._model = real
    return calls[0][0]


@pytest.mark.parametrize("kind", ["checkerboard", "charuco"])
def test_board_fit_jacobian_matches_central_differences(kind):
    if kind == "charuco":
        target = Target.from_dict({"kind": "charuco", "rows": 4, "cols": 5, "pitch_m": 0.03, "marker_m": 0.022,
                                   "dictionary": "DICT_4X4_50"})
    else:
        target = Target.from_dict({"kind": "checkerboard", "rows": 5, "cols": 6, "pitch_m": 0.02})
    # tilted and sheared, squares of ~9 px: the windows see the neighbours' lines and the nodes
    T = look_at_board(target, F_PX * target.pitch_m / 9.0, 35, -25, 20, (60, -30), INTR)
    theta, *rest = _model_call(target, T, 0.9)
    theta = theta.copy()
    theta[:, 8] = 0.9  # a blur where every term is alive
    M, J, _ = board_fit._model(theta, *rest)
    for p in range(board_fit.N_PARAMS):
        h = 1e-6 * max(1.0, float(np.abs(theta[:, p]).max()))
        up, dn = theta.copy(), theta.copy()
        up[:, p] += h
        dn[:, p] -= h
        fd = (board_fit._model(up, *rest, jacobian=False)[0] - board_fit._model(dn, *rest, jacobian=False)[0]) / (2 * h)
        scale = max(1.0, float(np.abs(fd).max()))
        # The model leaves the bivariate excess out beyond 5.5 sigma of a node (under 1e-7 of the
        # contrast): a step that moves a pixel across that edge jumps by that much, seen in the
        # differences as up to ~1e-4 of the largest derivative (the same with the model before
        # the two axes were stacked). A wrong term is off by its own size.
        assert np.abs(J[p] - fd).max() < 5e-4 * scale, (kind, p, float(np.abs(J[p] - fd).max()), scale)


def test_render_fast_paths_give_the_same_images_bit_for_bit(monkeypatch):
    import calibgraph.sim.board_image as board_image
    from calibgraph.core.targets import a4_board_54
    from calibgraph.solver.camera.session_plan import session_poses

    board = a4_board_54()
    lens = Intrinsics(K=INTR.K, dist=np.array([0.05, -0.08, 0.0004, -0.0003, 0.02]), width_px=1920, height_px=1080)
    cases = [(intr, T) for intr in (INTR, lens)
             for T in session_poses(intr, board, 3, (0.3, 1.0), rng=np.random.default_rng(4))]
    fast = [[render_view(board, intr, T, bit_depth=b, seed=None).image for b in (8, 16)] for intr, T in cases]
    again = render_view(board, *cases[-1], bit_depth=16, seed=None).image  # the texture reused
    monkeypatch.setattr(board_image, "_box_mean", lambda samp, nv, nu, S: samp.reshape(nv, S, nu, S).mean(axis=(1, 3)))
    monkeypatch.setattr(board_image, "_texture_for", board_image.board_texture)
    for (intr, T), imgs in zip(cases, fast):
        for b, img in zip((8, 16), imgs):
            np.testing.assert_array_equal(img, render_view(board, intr, T, bit_depth=b, seed=None).image)
    np.testing.assert_array_equal(again, fast[-1][1])
