"""What the board in the images looks like beside what the target spec declares: ArUco markers.

A ChArUco board carries ArUco markers in its white squares. Its squares are a checkerboard, so a
ChArUco board declared ``checkerboard`` is detected (OpenCV's detectors see the squares' corners
and the markers only darken the white squares' insides), and a ChArUco board declared with another
dictionary decodes no marker and is found nowhere. Both are said in words:

* :func:`markers_in_white_squares`: the share of a detected checkerboard's white squares whose
  middle is marked (darker than half-way to black over a fifth of it); a plain board has none;
* :func:`markers_seen`: the ArUco dictionary families whose markers decode in an image (each
  family's largest dictionary holds its smaller ones: ids < 50 are DICT_nXn_50's too), with the
  markers' side as a fraction of the squares' when the checkerboard is known;
* :func:`board_look_note`: the note for a dataset (the CLI prints it): "the board has ArUco markers
  of DICT_5X5_100 in its white squares: a ChArUco board ..." for a checkerboard spec, "the images
  show ArUco markers of DICT_4X4_50, not DICT_6X6_250" for a ChArUco spec with another dictionary.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calibgraph.core.errors import DetectionError, InputError
from calibgraph.core.targets import Target
from calibgraph.detect.board_size import chessboard_seen
from calibgraph.detect.charuco import find_charuco
from calibgraph.detect.image import read_grey, sample_bilinear
from calibgraph.detect.regions import roi_from_points

# Dictionary families looked for, each by its dictionary of up to 250 markers (ids < 50 are also
# DICT_nXn_50's): a board needs one marker per white square, so 250 covers boards of up to 500
# squares, and decoding against a 1000-marker dictionary costs ~4x as much (about 1 s an image).
# The rarely used AprilTag 16h5, 25h9, 36h10 and MIP 36h12 families are left out (36h10 alone
# costs 3 s an image).
FAMILIES = (("DICT_4X4", (50, 100, 250)), ("DICT_5X5", (50, 100, 250)), ("DICT_6X6", (50, 100, 250)),
            ("DICT_7X7", (50, 100, 250)), ("DICT_ARUCO_ORIGINAL", ()), ("DICT_APRILTAG_36h11", ()))
MARKED_SQUARES = 0.5   # share of white squares with a marked middle that makes a board a marker board
MARKED_DARK = 0.2      # share of a white square's middle darker than half-way to black that marks it


def _cell_homography(ij: np.ndarray, uv: np.ndarray):
    """Homography from grid coordinates (column, row) to pixels, or None."""
    import cv2

    if len(ij) < 4:
        return None
    H, _ = cv2.findHomography(ij[:, ::-1].astype(float), uv, 0)
    return H


def _map(H, xy: np.ndarray) -> np.ndarray:
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return p[:, :2] / p[:, 2:3]


def _squares(target: Target, ids: np.ndarray, uv_px: np.ndarray):
    """(white, homography from square coordinates [0, 1]^2 to pixels) of every inner square of a
    detected checkerboard whose four corners were all detected (each through its own corners: lens
    distortion bends the board, not a square). Square (i, j) between inner corners is black iff
    i + j is even."""
    where = {int(i): k for k, i in enumerate(np.asarray(ids, int))}
    uv = np.asarray(uv_px, float).reshape(-1, 2)
    for i in range(target.rows - 1):
        for j in range(target.cols - 1):
            corners = [where.get(int(target.cols * (i + a) + j + b)) for a, b in ((0, 0), (0, 1), (1, 0), (1, 1))]
            if any(c is None for c in corners):
                continue
            H = _cell_homography(np.array([[0, 0], [0, 1], [1, 0], [1, 1]]), uv[corners])
            if H is not None:
                yield (i + j) % 2 == 1, H


def markers_in_white_squares(grey: np.ndarray, target: Target, ids: np.ndarray, uv_px: np.ndarray) -> float:
    """Share of the white inner squares of a detected checkerboard whose middle is marked (module
    docstring); 0 for a plain board, about 1 for a ChArUco board. Squares whose four corners were
    all detected are measured, each through the homography of its own corners (lens distortion
    bends the board, not a square); NaN when no square of each colour is whole."""
    # A 7 x 7 sample of the middle [0.2, 0.8]^2 of a square, and its edge band for the paper level.
    s = np.linspace(0.2, 0.8, 7)
    mid = np.array([(x, y) for y in s for x in s])
    band = np.array([(x, y) for x in np.linspace(0.08, 0.92, 8) for y in (0.08, 0.92)] +
                    [(x, y) for y in np.linspace(0.2, 0.8, 5) for x in (0.08, 0.92)])
    white_mid, white_band, black_mid = [], [], []
    for white, H in _squares(target, ids, uv_px):
        if white:
            white_mid.append(sample_bilinear(grey, _map(H, mid)))
            white_band.append(sample_bilinear(grey, _map(H, band)))
        else:
            black_mid.append(sample_bilinear(grey, _map(H, mid)))
    if not white_mid or not black_mid:
        return float("nan")
    black = float(np.median(np.concatenate(black_mid)))
    marked = [np.mean(m < 0.5 * (black + float(np.median(b)))) > MARKED_DARK for m, b in zip(white_mid, white_band)]
    return float(np.mean(marked))


def marked_light_squares(grey: np.ndarray, grid_uv: np.ndarray) -> float:
    """:func:`markers_in_white_squares` for a grid whose ids are not known (a symmetric spec that
    cannot be oriented): ``grid_uv`` (r, c, 2) inner corners in any of its orderings. Which squares
    are white is read from the image (their edge bands), not from the ids; NaN when there are no
    squares of both colours."""
    s = np.linspace(0.2, 0.8, 7)
    mid = np.array([(x, y) for y in s for x in s])
    band = np.array([(x, y) for x in np.linspace(0.08, 0.92, 8) for y in (0.08, 0.92)] +
                    [(x, y) for y in np.linspace(0.2, 0.8, 5) for x in (0.08, 0.92)])
    G = np.asarray(grid_uv, float)
    mids, bands = [], []
    for i in range(G.shape[0] - 1):
        for j in range(G.shape[1] - 1):
            corners = np.array([G[i, j], G[i, j + 1], G[i + 1, j], G[i + 1, j + 1]])
            H = _cell_homography(np.array([[0, 0], [0, 1], [1, 0], [1, 1]]), corners)
            if H is not None:
                mids.append(sample_bilinear(grey, _map(H, mid)))
                bands.append(float(np.median(sample_bilinear(grey, _map(H, band)))))
    if len(bands) < 2:
        return float("nan")
    bands = np.asarray(bands)
    split = 0.5 * (bands.min() + bands.max())
    light = bands > split
    if light.all() or not light.any():
        return float("nan")
    black = float(np.median(np.concatenate([m for m, lit in zip(mids, light) if not lit])))
    marked = [np.mean(m < 0.5 * (black + b)) > MARKED_DARK for m, b, lit in zip(mids, bands, light) if lit]
    return float(np.mean(marked))


def grid_marker_note(grey: np.ndarray, grid_uv: np.ndarray) -> str | None:
    """For a checkerboard grid found but not numbered (``grid_uv`` (r, c, 2), a symmetric spec):
    "the board has ArUco markers of DICT_6X6_250 in its white squares: a ChArUco board" when most
    of its white squares are marked (:func:`marked_light_squares`), else None."""
    if not marked_light_squares(grey, grid_uv) >= MARKED_SQUARES:
        return None
    uv = np.asarray(grid_uv, float).reshape(-1, 2)
    seen = markers_seen(grey, roi_from_points(uv, grey.shape, pad_frac=0.3))
    which = f" of {seen[0][0]}" if seen else ""
    return f"the board has ArUco markers{which} in its white squares: a ChArUco board, not a plain checkerboard"


def marker_side(grey: np.ndarray, target: Target, ids: np.ndarray, uv_px: np.ndarray) -> float | None:
    """Side of the markers in a detected checkerboard's white squares, in squares, or None for a
    plain board (fewer than ``MARKED_SQUARES`` of its white squares marked). Measured without
    decoding a marker: across the middle of every white square, from each of its four edges in
    turn, the darkness profile (0 paper, 1 ink) averaged over the squares rises through 1/2 where
    the marker's black border starts, ``(1 - side) / 2`` inside the edge (the half-way crossing of
    a blurred edge is unbiased)."""
    if not markers_in_white_squares(grey, target, ids, uv_px) >= MARKED_SQUARES:
        return None
    x = np.linspace(0.0, 0.5, 101)
    y = np.linspace(0.4, 0.6, 5)
    prof = np.array([(a, b) for a in x for b in y])  # from the left edge, across the middle
    sides = [prof, np.column_stack([1 - prof[:, 0], prof[:, 1]]), prof[:, ::-1],
             np.column_stack([prof[:, 1], 1 - prof[:, 0]])]
    white, black = [], []
    for is_white, H in _squares(target, ids, uv_px):
        if is_white:
            white.append([sample_bilinear(grey, _map(H, p)).reshape(len(x), len(y)).mean(1) for p in sides])
        else:
            black.append(sample_bilinear(grey, _map(H, np.array([[0.5, 0.5]]))))
    if not white or not black:
        return None
    profile = np.asarray(white, float).reshape(-1, len(x)).mean(0)
    paper, ink = float(profile[len(x) // 10:len(x) // 4].max()), float(np.median(black))
    dark = (paper - profile) / max(paper - ink, 1.0)
    start = len(x) // 10  # past the square's own edge
    k = next((n for n in range(start + 1, len(x)) if dark[n] >= 0.5 and dark[n - 1] < 0.5), None)
    if k is None:
        return None
    inset = x[k - 1] + (0.5 - dark[k - 1]) / (dark[k] - dark[k - 1]) * (x[k] - x[k - 1])
    return float(1.0 - 2.0 * inset)


def _family_dictionary(family: str, sizes: tuple, max_id: int):
    """The smallest predefined dictionary of ``family`` that holds marker ``max_id``."""
    for n in sizes:
        if max_id < n:
            return f"{family}_{n}"
    return f"{family}_{sizes[-1]}" if sizes else family


def markers_seen(grey: np.ndarray, region_px=None, families=FAMILIES) -> list:
    """ArUco markers decoded in ``grey`` (within ``region_px`` = (x0, y0, x1, y1) if given), per
    dictionary family: a list of (dictionary name, number of markers, marker corners (M, 4, 2)),
    most markers first; families none of whose markers decode are left out."""
    import cv2

    x0, y0 = 0, 0
    img = grey
    if region_px is not None:
        x0, y0, x1, y1 = (int(v) for v in region_px)
        img = grey[y0:y1, x0:x1]
    params = cv2.aruco.DetectorParameters()
    params.minMarkerPerimeterRate = 0.01  # far boards' markers, as the ChArUco finder allows
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX  # for the markers' side
    names = [f"{family}_{sizes[-1]}" if sizes else family for family, sizes in families]
    dicts = [cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, n)) for n in names]
    det = cv2.aruco.ArucoDetector(dicts[0], params)
    if hasattr(det, "detectMarkersMultiDict"):  # OpenCV >= 4.11: the candidates are found once
        det.setDictionaries(dicts)
        corners, ids, _, which = det.detectMarkersMultiDict(img)
        ids = [] if ids is None else [int(i) for i in np.ravel(ids)]
        which = [] if which is None else [int(w) for w in np.ravel(which)]
        found = [([c for c, w in zip(corners, which) if w == k], [i for i, w in zip(ids, which) if w == k])
                 for k in range(len(dicts))]
    else:
        found = []
        for d in dicts:
            corners, ids, _ = cv2.aruco.ArucoDetector(d, params).detectMarkers(img)
            found.append((list(corners), [] if ids is None else [int(i) for i in np.ravel(ids)]))
    out = []
    for (family, sizes), (corners, ids) in zip(families, found):
        # The same id twice is no board's: a chance decoding (more so in the small 4x4 family).
        if not ids or len(set(ids)) < len(ids):
            continue
        c = np.asarray(corners, float).reshape(-1, 4, 2) + [x0, y0]
        out.append((_family_dictionary(family, sizes, max(ids)), len(ids), c))
    return sorted(out, key=lambda r: -r[1])


def marker_fraction(target: Target, ids: np.ndarray, uv_px: np.ndarray, marker_corners: np.ndarray) -> float:
    """Median side of the markers in squares of the detected checkerboard (its homography)."""
    H = _cell_homography(target.grid_ij[np.asarray(ids, int)], np.asarray(uv_px, float))
    if H is None or len(marker_corners) == 0:
        return float("nan")
    Hi = np.linalg.inv(H)
    sides = []
    for c in marker_corners:
        g = _map(Hi, c)
        sides.append(np.mean(np.linalg.norm(g - np.roll(g, 1, axis=0), axis=1)))
    return float(np.median(sides))


def checkerboard_marker_note(grey: np.ndarray, target: Target, det, where: str = "the target spec") -> str | None:
    """The note for a checkerboard spec whose detected board (``det``, accepted) has markers in its
    white squares, or None for a plain board."""
    if target.kind != "checkerboard" or not det.ok or not markers_in_white_squares(grey, target, det.ids,
                                                                                  det.uv_px) >= MARKED_SQUARES:
        return None
    seen = markers_seen(grey, roi_from_points(det.uv_px, grey.shape, pad_frac=0.3))
    head = (f"the board has markers in its white squares (a ChArUco board?), declared a {target.rows}x{target.cols} "
            f"checkerboard in {where}: it is detected as a checkerboard")
    if not seen:
        return head + "; no ArUco dictionary decodes its markers"
    name, n, corners = seen[0]
    frac = marker_fraction(target, det.ids, det.uv_px, corners)
    spec = (f"kind: charuco, rows: {target.rows}, cols: {target.cols}, pitch_m: {target.pitch_m:g}, "
            f"marker_m: {frac * target.pitch_m:.4g}, dictionary: {name}")
    return (f"{head}, its corners fitted with the markers modelled; {n} ArUco markers of {name} decode in it, about "
            f"{frac:.2f} of a square wide. Declared as the ChArUco board it is ({spec}; measure marker_m), views of "
            "part of it count too")


def charuco_dictionary_note(grey: np.ndarray, target: Target, where: str = "the target spec") -> str | None:
    """For a ChArUco spec: a note when the image's markers decode in another dictionary family
    than the declared one (more of them than in the declared dictionary), else None."""
    if target.kind != "charuco":
        return None
    declared = [r for r in markers_seen(grey, families=((target.dictionary, ()),))]
    n_declared = declared[0][1] if declared else 0
    others = [r for r in markers_seen(grey) if not _same_family(r[0], target.dictionary)]
    if not others or others[0][1] < max(4, 2 * n_declared):
        return None
    name, n, _ = others[0]
    return (f"the images show ArUco markers of {name} ({n} in one image; {n_declared} decode as {target.dictionary}), "
            f"not {target.dictionary} as {where} declares: check the target's dictionary")


def _same_family(a: str, b: str) -> bool:
    fa = next((f for f, sizes in FAMILIES if a == f or a.startswith(f + "_") and sizes), a)
    fb = next((f for f, sizes in FAMILIES if b == f or b.startswith(f + "_") and sizes), b)
    return fa.lower() == fb.lower()


def dataset_board_notes(dataset, results: dict, where: str = "the target spec") -> list:
    """Notes on a detected dataset's board (``results``: (camera, capture) -> ImageDetection): a
    board found printed white on black (in the inverted image, :mod:`calibgraph.detect.polarity`);
    markers in a checkerboard's white squares, seen on its largest accepted view; for a ChArUco spec
    found in no image, markers of another dictionary (or none: a plain chessboard) in its first frames."""
    t = dataset.target
    notes = []
    ok = [d for d in results.values() if d.ok]
    inverted = [d for d in ok if d.inverted]
    if inverted:
        notes.append(f"board: printed white on black: found in the inverted image in {len(inverted)} of {len(ok)} "
                     "views (its point ids are those of the board as printed)")
    note = None
    if t.kind == "checkerboard":
        ok = [d for d in ok if d.image]
        if ok:
            best = max(ok, key=lambda d: d.size_px)
            try:
                grey = read_grey(best.image)
                note = checkerboard_marker_note(255 - grey if best.inverted else grey, t, best, where)
            except DetectionError:
                note = None
    elif t.kind == "charuco" and results and not ok:
        note = frames_dictionary_note(dataset, where)
    return notes + ([f"board: {note}"] if note else [])


def frames_dictionary_note(dataset, where: str = "the target spec", frames: int = 2) -> str | None:
    """:func:`charuco_dictionary_note` on the first ``frames`` readable images of ``dataset``, each as
    printed and inverted (a board printed white on black: its markers decode only there)."""
    for grey in _first_frames(dataset, frames):
        for img, inverted in ((grey, False), (255 - grey, True)):
            note = charuco_dictionary_note(img, dataset.target, where)
            if note:
                return note + (" (the board is printed white on black: they decode in the inverted image)"
                               if inverted else "")
    return None


def _first_frames(dataset, frames: int):
    """The first ``frames`` readable images of ``dataset``, grey."""
    looked = 0
    for v in dataset.views:
        if not v.image or looked >= frames:
            continue
        try:
            grey = read_grey(Path(dataset.root) / v.image)
        except DetectionError:
            continue
        looked += 1
        yield grey


def plain_chessboard_note(grey: np.ndarray, target: Target) -> str | None:
    """For a ChArUco spec: "the images show a plain chessboard of 6x9 inner corners and no ArUco
    markers ..." when ``grey`` shows a chessboard (OpenCV's SB detector, any size) and no marker of
    any dictionary family decodes; else None."""
    if target.kind != "charuco" or markers_seen(grey) or markers_seen(255 - grey):  # none either way round
        return None
    seen = chessboard_seen(grey)
    if seen is None or seen.size[0] < 3:
        return None
    a, b = seen.size if target.rows <= target.cols else seen.size[::-1]
    return (f"the images show a plain chessboard of {a}x{b} inner corners and no ArUco markers: a checkerboard, not a "
            f"ChArUco board; declare it as one (kind: checkerboard, rows: {a}, cols: {b}, pitch_m: {target.pitch_m:g})")


def charuco_spec_note(grey: np.ndarray, target: Target) -> str | None:
    """For a checkerboard spec whose frames decode ArUco markers (4 or more of one family): the ChArUco
    spec to declare instead, its marker side measured from the markers (their side against the
    distance between diagonal neighbours, a square's diagonal) and OpenCV's board layout (from 4.6 on,
    or the older ``legacy_charuco``) the one whose detector finds more corners in ``grey``; None when no
    markers decode (as printed, or in the inverted image: a board printed white on black, then said)."""
    if target.kind != "checkerboard":
        return None
    seen, wob = markers_seen(grey), ""
    if not seen or seen[0][1] < 4:
        grey = 255 - grey
        seen, wob = markers_seen(grey), " (printed white on black: its markers decode in the inverted image)"
    if not seen or seen[0][1] < 4:
        return None
    name, n, corners = seen[0]
    sides = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=-1).mean(axis=1)
    centres = corners.mean(axis=1)
    d = np.linalg.norm(centres[:, None] - centres[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    frac = float(np.median(sides) / (np.median(d.min(axis=1)) / np.sqrt(2.0)))
    marker_m = round(float(np.clip(frac, 0.3, 0.95)) * target.pitch_m, 4)
    found = {}
    for legacy in (False, True):
        try:
            t = Target(kind="charuco", rows=target.rows, cols=target.cols, pitch_m=target.pitch_m, marker_m=marker_m,
                        dictionary=name, legacy_charuco=legacy)
            r, _ = find_charuco(grey, t, None)
        except Exception:  # noqa: BLE001 (an odd layout OpenCV refuses says nothing)
            r = None
        found[legacy] = 0 if r is None else len(r[0])
    legacy = found[True] > found[False]
    return (f"declare it as the ChArUco board it is: kind: charuco, rows: {target.rows}, cols: {target.cols}, "
            f"pitch_m: {target.pitch_m:g}, marker_m: {marker_m:g} (about {frac:.2f} of a square: measure it), "
            f"dictionary: {name}{', legacy_charuco: true' if legacy else ''} ({n} of its markers decode in one image){wob}")


def explain_wrong_spec(error, dataset, where: str = "the target spec"):
    """The wrong-spec :class:`InputError` ``error``, with what the first frames show of the board's
    kind: for a ChArUco spec, the markers' own dictionary when the images show another one, or a plain
    chessboard when they show no markers; for a checkerboard spec whose frames show ArUco markers, the
    ChArUco spec to declare. ``error`` itself otherwise."""
    t = dataset.target
    note = None
    if t.kind == "charuco":
        note = frames_dictionary_note(dataset, where)
        if note is None:
            note = next((n for n in map(lambda g: plain_chessboard_note(g, t), _first_frames(dataset, 2)) if n), None)
    elif t.kind == "checkerboard":
        note = next((n for n in map(lambda g: charuco_spec_note(g, t), _first_frames(dataset, 2)) if n), None)
        if note is not None and "ArUco" not in str(error):
            note = "the images show ArUco markers: a ChArUco board, not a plain checkerboard; " + note
    return InputError(f"{str(error).rstrip('.')}; {note}") if note else error
