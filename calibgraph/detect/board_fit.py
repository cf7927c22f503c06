"""Unbiased sub-pixel checkerboard and ChArUco corners: a photometric fit of the board around each corner.

Why: OpenCV's corner refiners look at a window around one corner and assume what they see is a
lone saddle. On small squares the window (or the blur) also sees the neighbouring corners and the
board's white border; these are not point-symmetric about an edge corner, so the corners move
outwards: a scale bias that puts cameras millimetres too close (scripts/results/bench_detect_bias.md
measures it). Fitting a model that *contains* the neighbours and the border removes that cause
instead of hoping it is small.

The model (for each inner corner, fitted to the original image's pixels, no interpolation):

* geometry: a local homography ``G`` (image -> board, in square units relative to the corner).
  Every square edge of the board is then a straight image line, ``X = k`` <=> ``(G0 - k G2) . u =
  0``, and its signed pixel distance ``d_k(x)`` is exact for a pinhole camera. Lens distortion
  bends lines over the board, not over the ~3 squares a local fit sees (what is left is even about
  the corner, so it does not move it to first order);
* optics: the printed board is black where ``floor(X) + floor(Y)`` is even inside the squares
  and white (paper) outside, i.e. ``black = (box_u box_v + w_u w_v) / 2`` with ``w`` the +-1
  square wave and ``box`` the board's extent along each axis. Both products expand into signed
  quadrants ``X > k, Y > l`` (wedges in the image), and a wedge blurred by a Gaussian of
  ``sigma`` (optics plus the pixel's area) is exactly the bivariate normal CDF
  ``Phi2(d_k / sigma, d_l / sigma; rho)``, ``rho`` the cosine between the two lines' normals;
  the model is therefore exact for a pinhole camera and a Gaussian blur, up to the pixel's
  square shape (its error is point-symmetric about every corner, so it moves none);
* photometry: ``I = lo(x) + gain(x) * white(x)`` with ``lo`` and ``gain`` affine in the image
  (a lighting gradient across the window would otherwise pull the corner towards the bright side).

Parameters per corner: 8 of ``G`` (``G22 = 1``), ``sigma``, 6 photometric; Levenberg-Marquardt
on all corners at once (independent problems, batched), started from a homography through the
detected corner and its neighbours. The window is +-1.5 squares around the corner for small
squares (so the fit sees the lines through the neighbouring corners and, at the board's edge, the
border) and about +-7 px for large ones (a lone saddle; more pixels would add time, not
accuracy). A fit that fails (the corner moves by more than 0.3 of its shortest grid step,
implausible blur or contrast) is started once more from a homography of its refined neighbours;
failing again, the corner keeps its input position.

ChArUco (:func:`refine_charuco`): the same fit, with each marker in the model as the solid black
square its border bit makes (inset by (square - marker) / 2 in every white square) and the
pixels within 3 blur sigmas of its data bits left out; 12 px windows, larger than for a
checkerboard because the masks take part of each (scripts/results/bench_detect_charuco.md and
scripts/results/detect_design_figures.md have the figures behind the choice).

What is not modelled: the pixel's square shape beyond its variance (folded into ``sigma``) and
the paper's edge beyond the board's white margin. Together with the pixel phase of each corner
they leave small per-corner errors that average out over corners and views, not a bias.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calibgraph.core.targets import Target

_SQRT2PI = float(np.sqrt(2.0 * np.pi))
WINDOW_PX = 7.0  # half-size of the fitted window for large squares, pixels
WINDOW_SQ = 1.5  # ... and its cap in squares for small ones
CHARUCO_WINDOW_PX = 12.0  # ChArUco: part of each window is masked, and see refine_charuco
N_PARAMS = 15  # 8 homography + sigma + 6 photometric
# Clipped pixels (0 or 255): "censored" (the fit: "at most" / "at least" that level) or "dropped" (the fit
# before, no weight; kept as the reference scripts/bench_clipped_fit.py compares against)
CLIPPED_PIXELS = "censored"


@dataclass(frozen=True)
class BoardFit:
    """Result of :func:`refine_checkerboard`.

    Attributes:
        uv_px: (N, 2) refined corners (input positions where the fit failed).
        refined: (N,) True where the fit succeeded.
        sigma_px: (N,) fitted edge blur (Gaussian sigma incl. the pixel's area), pixels.
        rms_grey: (N,) residual RMS of the fit, grey levels.
    """

    uv_px: np.ndarray
    refined: np.ndarray
    sigma_px: np.ndarray
    rms_grey: np.ndarray


def _phi_cdf(z: np.ndarray) -> np.ndarray:
    """Standard normal CDF (Abramowitz-Stegun 7.1.26 erf, |error| < 1.5e-7; numpy has no erf and
    scipy is not a dependency). Exactly odd about 0, so it cannot shift an edge."""
    x = np.abs(z) / np.sqrt(2.0)
    t = 1.0 / (1.0 + 0.3275911 * x)
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))))
    erf = 1.0 - poly * np.exp(-x * x)
    return 0.5 + 0.5 * np.sign(z) * erf


# Gauss-Legendre nodes on [0, 1] for the excess of the bivariate normal CDF.
_GL_T, _GL_W = np.polynomial.legendre.leggauss(8)
_GL_T, _GL_W = 0.5 * (_GL_T + 1.0), 0.5 * _GL_W


def _phi2_excess(z1, z2, rho, phi_pdf=None, phi_cdf=None):
    """``Phi2(z1, z2; rho) - Phi(z1) Phi(z2)`` and its derivatives by z1, z2 and rho (broadcast).

    The excess is (1 / 2 pi) * integral over theta in [0, asin rho] of
    exp(-(z1^2 + z2^2 - 2 z1 z2 sin theta) / (2 cos^2 theta)) (Sheppard), by 8-point
    Gauss-Legendre (|rho| <= 0.95 here: lines meeting at 18 deg or more); d Phi2 / d z1 =
    phi(z1) Phi((z2 - rho z1) / sqrt(1 - rho^2)). ``phi_pdf``, ``phi_cdf``: the normal density
    and CDF at (z1, z2), when the caller has them already."""
    a = np.arcsin(rho)
    th = a[..., None] * _GL_T  # (..., Q)
    sn, c2 = np.sin(th), np.cos(th) ** 2
    q1, q2 = z1[..., None], z2[..., None]
    f = np.exp(-(q1 * q1 + q2 * q2 - 2.0 * q1 * q2 * sn) / (2.0 * c2))
    ex = (f * _GL_W).sum(-1) * a / (2.0 * np.pi)
    sr = np.sqrt(1.0 - rho * rho)
    p1, p2 = phi_pdf or (np.exp(-0.5 * z1 * z1) / _SQRT2PI, np.exp(-0.5 * z2 * z2) / _SQRT2PI)
    P1, P2 = phi_cdf or (_phi_cdf(z1), _phi_cdf(z2))
    d1 = p1 * (_phi_cdf((z2 - rho * z1) / sr) - P2)
    d2 = p2 * (_phi_cdf((z1 - rho * z2) / sr) - P1)
    # d Phi2 / d rho is the bivariate normal density.
    dr = np.exp(-(z1 * z1 - 2.0 * rho * z1 * z2 + z2 * z2) / (2.0 * sr * sr)) / (2.0 * np.pi * sr)
    return ex, d1, d2, dr


@dataclass(frozen=True)
class _Pattern:
    """The printed board as sums of separable terms: black(X, Y) = sum_r s_r F_u^r(X) F_v^r(Y),
    each ``F^r`` a weighted sum of steps ``H(X - x_l)`` at lines ``x_l`` (board squares, from the
    board's outer edge).

    Checkerboard (R = 2): ``black = (box_u box_v + p w_u w_v) / 2`` (``box`` the board's extent,
    ``w`` the +-1 square wave, ``p = +1`` when the outer top-left square is black). ChArUco adds
    every marker as a solid black square inset by ``inset`` in each white square (R = 4):
    ``+ (m_u m_v - p m'_u m'_v) / 2`` with ``m`` the indicator of the squares' marker spans and
    ``m'`` the same with alternating sign. A marker's outer edge is its black border bit, the
    same on every marker; its data bits (inside ``data_lo`` of the square's edges) differ per
    marker and are left out of the fit (:func:`_data_mask`).
    """

    lines_u: tuple  # (x (L,), coefficients (L, R)) along the board's x (columns)
    lines_v: tuple  # ... and y (rows)
    s_r: np.ndarray  # (R,) weights of the separable terms
    offsets: tuple  # line offsets within one square period (squares): (0,) or (0, inset, -inset)
    parity: int  # +1: squares with a + b even are black
    data_lo: float | None  # ChArUco: data bits start this far inside a white square's edges (squares)


def _axis_lines(n_squares: int, inset: float | None):
    """Lines and jump coefficients along one axis (module docstring of :class:`_Pattern`)."""
    k = np.arange(n_squares + 1)
    wave = np.where((k >= 1) & (k <= n_squares - 1), 2.0 * (-1.0) ** k, 0.0)
    wave[0], wave[-1] = 1.0, (-1.0) ** n_squares
    box = np.zeros(n_squares + 1)
    box[0], box[-1] = 1.0, -1.0
    if inset is None:
        return k.astype(float), np.column_stack([box, wave])
    a = np.arange(n_squares)
    x = np.concatenate([k, a + inset, a + 1.0 - inset])
    zk, za = np.zeros(n_squares + 1), np.zeros(n_squares)
    alt = (-1.0) ** a
    coef = np.column_stack([np.concatenate([box, za, za]), np.concatenate([wave, za, za]),
                            np.concatenate([zk, np.ones(n_squares), -np.ones(n_squares)]),
                            np.concatenate([zk, alt, -alt])])
    order = np.argsort(x, kind="stable")
    return x[order], coef[order]


def _charuco_parity(target: Target) -> int:
    """+1 when OpenCV prints the board's top-left square black (the layout may vary with the
    board's size and ``legacy_charuco``, so it is read from OpenCV's own image of the board)."""
    img = target.cv_charuco_board().generateImage((target.squares_x * 40, target.squares_y * 40), marginSize=0)
    return 1 if img[20, 20] < 128 else -1


def _pattern(target: Target, marker_frac: float | None = None, marker_bits: int = 7) -> _Pattern:
    """The :class:`_Pattern` of a checkerboard or ChArUco target; a checkerboard with
    ``marker_frac`` has markers of that side (in squares) in its white squares, ``marker_bits``
    data bits a side (:func:`refine_marker_checkerboard`)."""
    if target.kind == "checkerboard" and marker_frac:
        inset = 0.5 * (1.0 - marker_frac)
        data_lo = inset + marker_frac / (marker_bits + 2)  # one black border bit
        parity, offsets = 1, (0.0, inset, -inset)
    elif target.kind == "checkerboard":
        inset, parity, data_lo, offsets = None, 1, None, (0.0,)
    elif target.kind == "charuco":
        import cv2

        inset = 0.5 * (1.0 - target.marker_m / target.pitch_m)
        bits = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary)).markerSize
        data_lo = inset + (target.marker_m / target.pitch_m) / (bits + 2)  # one black border bit
        parity, offsets = _charuco_parity(target), (0.0, inset, -inset)
    else:
        raise ValueError(f"board fit: {target.kind} is not a board of squares")
    lu, lv = _axis_lines(target.squares_x, inset), _axis_lines(target.squares_y, inset)
    s_r = 0.5 * np.array([1.0, parity] + ([] if inset is None else [1.0, -parity]))
    return _Pattern(lu, lv, s_r, offsets, parity, data_lo)


def _axis_setup(lines, centre: np.ndarray, kap: np.ndarray):
    """Per corner: coefficients (N, L, R) of the lines at ``centre + kap`` (zero where the board
    has none) and the constant (N, R) of the lines left of them (a pixel in the window is right
    of those: H = 1)."""
    x, c = lines
    pos = centre[:, None] + kap[None, :]
    match = np.abs(pos[:, :, None] - x[None, None, :]) < 1e-9
    left = x[None, :] < pos[:, :1] - 1e-9
    return match.astype(float) @ c, left.astype(float) @ c


def _data_mask(XY: np.ndarray, centre_u: np.ndarray, centre_v: np.ndarray, pat: _Pattern, target: Target,
               margin_sq: np.ndarray) -> np.ndarray:
    """(N, P) True for pixels (board coordinates ``XY`` relative to each corner) within
    ``margin_sq`` of a ChArUco marker's data bits, whose pattern the model does not hold."""
    Xa, Ya = XY[..., 0] + centre_u[:, None], XY[..., 1] + centre_v[:, None]
    a, b = np.floor(Xa), np.floor(Ya)
    fx, fy = Xa - a, Ya - b
    lo = pat.data_lo - margin_sq[:, None]
    white = ((a + b) % 2 == (0 if pat.parity < 0 else 1)) & (a >= 0) & (a < target.squares_x) & (b >= 0) \
        & (b < target.squares_y)
    return white & (fx > lo) & (fx < 1.0 - lo) & (fy > lo) & (fy < 1.0 - lo)


def _local_homographies(uv_px: np.ndarray, ij: np.ndarray, sel: np.ndarray, scale_px: np.ndarray,
                        origin_px: np.ndarray):
    """(n, 3, 3) G of the corners ``sel``, mapping local pixels ``u = (x - origin) / scale``
    (homogeneous) to board squares relative to the corner, by a direct linear transform from the
    corner and its detected neighbours in the 3x3 around it (all corners' ``uv_px`` are used).
    Both sides are already normalised (squares, pitches), so the DLT needs no conditioning."""
    where = {(int(a), int(b)): n for n, (a, b) in enumerate(ij)}
    n_sel = len(sel)
    rows = np.zeros((n_sel, 18, 9))
    for k, n in enumerate(sel):
        i, j = ij[n]
        r = 0
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                m = where.get((i + di, j + dj))
                if m is None:
                    continue  # a missing neighbour leaves two zero rows
                u, v = (uv_px[m] - origin_px[k]) / scale_px[k]
                X, Y = float(dj), float(di)
                # G maps (u, v, 1) to (X, Y, 1) up to scale: two equations per point.
                rows[k, r] = [u, v, 1, 0, 0, 0, -X * u, -X * v, -X]
                rows[k, r + 1] = [0, 0, 0, u, v, 1, -Y * u, -Y * v, -Y]
                r += 2
    _, sv, Vt = np.linalg.svd(rows)
    G = Vt[:, -1, :].reshape(n_sel, 3, 3)
    # G22 = 1 is the fit's gauge; degenerate neighbourhoods (collinear points, a 1-row board:
    # a second-smallest singular value near 0) and corners at the horizon start from a plain
    # scaling about the detected corner.
    ok = (np.abs(G[:, 2, 2]) > 1e-6) & (sv[:, -2] > 1e-6 * sv[:, 0])
    G[ok] /= G[ok, 2, 2][:, None, None]
    for k in np.nonzero(~ok)[0]:
        G[k] = np.eye(3)
        G[k, :2, 2] = -(uv_px[sel[k]] - origin_px[k]) / scale_px[k]
    return G


def _model(theta, U, ex, kap, coef, const, scale, s_r, jacobian=True):
    """Model grey levels (N, P), its Jacobian (15, N, P) (None unless ``jacobian``) and the
    whiteness of the board (N, P) (the model with lo = 0, gain = 1). ``coef`` (2, N, L, R) and
    ``const`` (2, N, R): :func:`_axis_setup` of the u (board x) and the v (board y) lines.

    Sums over lines are written as batched matrix products: numpy reduces short trailing axes
    an order of magnitude slower. The two axes (u: the board's x lines, v: its y lines) are
    computed as one stacked array (leading axis 2): the same arithmetic in half the numpy calls,
    which is what a fit of a few corners costs."""
    N, P, _ = U.shape
    G2 = np.concatenate([theta[:, 6:8], np.ones((N, 1))], axis=1)
    sig = theta[:, 8][:, None, None]
    q = theta[:, 9:15]
    s = scale[:, None, None]
    Ga = theta[:, 0:6].reshape(N, 2, 3).transpose(1, 0, 2)  # (2, N, 3): G's rows 0 and 1
    L = Ga[:, :, None, :] - kap[None, None, :, None] * G2[None, :, None, :]  # (2, N, L, 3) lines X = k, Y = k
    nrm = np.sqrt(L[..., 0] * L[..., 0] + L[..., 1] * L[..., 1])[:, :, None, :]  # (2, N, 1, L)
    num = U @ L.transpose(0, 1, 3, 2)  # (2, N, P, L)
    z = s * num / (nrm * sig)  # signed pixel distance / sigma
    Pz = _phi_cdf(z)
    pz = np.exp(-0.5 * z * z) / _SQRT2PI
    F = Pz @ coef + const[:, :, None, :]  # (2, N, P, R) the separable terms along each axis
    Fu, Fv = F[0], F[1]
    # Where a u-line and a v-line meet at an angle, the blurred quadrant X > k, Y > l is the
    # bivariate normal Phi2(z_k, z_l; rho) with rho the cosine between the lines' normals, not
    # the product Phi(z_k) Phi(z_l); add the difference (zero for square pixels of a frontal
    # board; left out, a sheared board's small squares come out ~0.01 px outwards).
    nl = L[..., :2] / nrm[:, :, 0, :, None]  # (2, N, L, 2) unit normals
    n_u, n_v = nl[0], nl[1]
    rho = np.clip(n_u @ n_v.transpose(0, 2, 1), -0.95, 0.95)  # (N, Lu, Lv)
    C = (coef[0] * s_r) @ coef[1].transpose(0, 2, 1)  # (N, Lu, Lv) weight of each quadrant
    Lu, Lv = kap.size, kap.size
    # The excess vanishes (< 1e-7) unless the pixel is within ~5.5 sigma of both lines, i.e.
    # near their node: it is evaluated on those few (pixel, node) pairs only (and only where the
    # lines bound a printed quadrant: a square's edge never with a marker's), and its sums over
    # nodes are gathered from them (np.bincount) rather than over all (pixel, node) pairs.
    near = np.abs(z) < 5.5
    n_i, p_i, lu_i, lv_i = np.nonzero(near[0][:, :, :, None] & near[1][:, :, None, :] & (C[:, None] != 0.0))
    Cw = C[n_i, lu_i, lv_i]
    z1, z2 = z[0][n_i, p_i, lu_i], z[1][n_i, p_i, lv_i]
    ex_k, d1, d2, dr = _phi2_excess(z1, z2, rho[n_i, lu_i, lv_i],
                                    phi_pdf=(pz[0][n_i, p_i, lu_i], pz[1][n_i, p_i, lv_i]),
                                    phi_cdf=(Pz[0][n_i, p_i, lu_i], Pz[1][n_i, p_i, lv_i]))
    pix = n_i * P + p_i
    NP = N * P

    def gather(w, n_bins=NP, at=pix):
        return np.bincount(at, weights=w, minlength=n_bins)

    white = 1.0 - (Fu * Fv) @ s_r - gather(ex_k * Cw).reshape(N, P)
    lo = q[:, 0:1] + q[:, 1:2] * ex[..., 0] + q[:, 2:3] * ex[..., 1]
    gain = q[:, 3:4] + q[:, 4:5] * ex[..., 0] + q[:, 5:6] * ex[..., 1]
    M = lo + gain * white
    if not jacobian:
        return M, None, white
    # d/d sigma of Phi(d / sigma) = -phi(z) z / sigma
    F_s = ((pz * z) @ coef) / -sig
    # Parameter-major (15, N, P): every row is written contiguously.
    J = np.empty((N_PARAMS, N, P))
    # d/d sigma through z = d / sigma: -(dz1 z1 + dz2 z2) / sigma
    corr_s = -gather((d1 * z1 + d2 * z2) * Cw).reshape(N, P) / sig[..., 0]
    J[8] = -gain * ((F_s[0] * Fv + Fu * F_s[1]) @ s_r + corr_s)
    # The excess's derivatives by each line's z, per line.
    extra = gather(np.concatenate([d1 * Cw, d2 * Cw]), 2 * NP * Lu,
                   np.concatenate([pix * Lu + lu_i, NP * Lu + pix * Lv + lv_i])).reshape(2, N, P, Lu)
    J[9] = 1.0
    J[10], J[11] = ex[..., 0], ex[..., 1]
    J[12] = white
    J[13], J[14] = white * ex[..., 0], white * ex[..., 1]
    # dM/dd_l for each line l of each axis (2, N, P, L); the other axis's terms multiply
    other = F[::-1] * s_r
    A = (-gain / sig[..., 0])[..., None] * (pz * (other @ coef.transpose(0, 1, 3, 2)) + extra)
    # d(d_l)/dL_m = scale * (U_m / nrm - num L_m / nrm^3 [m < 2]), with L = Ga - kap G2
    An = A / nrm
    Bn = A * num / nrm**3
    BL = Bn @ L[..., :2]  # (2, N, P, 2)
    s0 = s[..., 0]
    sA = s0 * An.sum(axis=3)  # (2, N, P)
    sK = s0 * (An @ kap)  # (2, N, P)
    BK = (Bn * kap) @ L[..., :2]
    for axis in (0, 1):
        for m in range(2):
            J[3 * axis + m] = sA[axis] * U[..., m] - s0 * BL[axis, ..., m]
        J[3 * axis + 2] = sA[axis]
    for m in range(2):
        J[6 + m] = (0.0 - (sK[0] * U[..., m] - s0 * BK[0, ..., m])) - (sK[1] * U[..., m] - s0 * BK[1, ..., m])
    # ... and through rho = n_u . n_v, the cosine between the lines: d rho / d L_u[:2] =
    # (n_v - rho n_u) / |L_u[:2]| (and the same with u, v swapped); L_u = G0 - kap_k G2.
    Rk = -gain[n_i, p_i] * Cw * dr  # per (pixel, node) pair
    rp = rho[n_i, lu_i, lv_i][:, None]
    nu_k, nv_k = n_u[n_i, lu_i], n_v[n_i, lv_i]  # (pairs, 2)
    Tu = (nv_k - rp * nu_k) / nrm[0, n_i, 0, lu_i][:, None]
    Tv = (nu_k - rp * nv_k) / nrm[1, n_i, 0, lv_i][:, None]
    T2 = -(kap[lu_i][:, None] * Tu + kap[lv_i][:, None] * Tv)
    # the six rows' sums in one gather: row r of (0, 1, 3, 4, 6, 7) in bins r * N * P + pixel
    T6 = np.concatenate([Tu.T, Tv.T, T2.T])  # (6, pairs)
    at6 = (np.arange(6)[:, None] * NP + pix[None, :]).ravel()
    add6 = gather((Rk[None, :] * T6).ravel(), 6 * NP, at6).reshape(6, N, P)
    J[[0, 1, 3, 4, 6, 7]] += add6
    return M, J, white


def _weights(XY, w_sq, valid):
    """Window weights: 1 within +-w squares of the corner, tapering to 0 over the last quarter."""
    t = np.abs(XY).max(axis=-1) / w_sq[:, None]
    return np.clip((1.0 - t) / 0.25, 0.0, 1.0) * valid


def _fit_corners(img: np.ndarray, target: Target, ij: np.ndarray, uv_all: np.ndarray, sel: np.ndarray,
                 max_iterations: int, pat: _Pattern, margin_px: np.ndarray | float = 0.0,
                 window_px: float = WINDOW_PX):
    """Fit the corners ``sel`` (indices into ``uv_all``, whose other rows serve as neighbours):
    (uv (n, 2), ok (n,), sigma_px (n,), rms_grey (n,)). ``margin_px``: ChArUco pixels closer
    than this to a marker's data bits get no weight (about 3 blur sigmas)."""
    N = len(sel)
    uv0 = uv_all[sel]
    H_img, W_img = img.shape
    # Local pitch: the longest step to a detected grid neighbour (the window must cover the
    # neighbours' lines in the widest direction too).
    where = {(int(a), int(b)): n for n, (a, b) in enumerate(ij)}
    pitch, short = np.zeros(N), np.zeros(N)
    for n, (i, j) in enumerate(ij[sel]):
        steps = [np.linalg.norm(uv_all[where[(i + a, j + b)]] - uv0[n])
                 for a, b in ((0, 1), (1, 0), (0, -1), (-1, 0)) if (i + a, j + b) in where]
        pitch[n], short[n] = (max(steps), min(steps)) if steps else (10.0, 10.0)
    origin = np.round(uv0)
    G = _local_homographies(uv_all, ij, sel, pitch, origin)
    w_sq = np.minimum(WINDOW_SQ, window_px / pitch)
    # Pixel box holding every corner's window (+ taper slack); one size for all, masked per corner.
    box_sq = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)
    box_n = np.concatenate([box_sq[None] * w_sq[:, None, None], np.ones((N, 4, 1))], axis=2)
    corners = np.einsum("nab,nkb->nka", np.linalg.inv(G), box_n)
    reach_px = np.abs(corners[..., :2] / corners[..., 2:3]).max(axis=(1, 2)) * pitch
    R = int(np.clip(np.ceil(np.nanmax(reach_px)) + 2, 4, 40))
    oy, ox = np.mgrid[-R:R + 1, -R:R + 1]
    off = np.stack([ox.ravel(), oy.ravel()], axis=1).astype(float)  # (P, 2)
    px = origin[:, None, :] + off[None]  # (N, P, 2) pixel centres
    inside = (px[..., 0] >= 0) & (px[..., 0] <= W_img - 1) & (px[..., 1] >= 0) & (px[..., 1] <= H_img - 1)
    xi = np.clip(px[..., 0], 0, W_img - 1).astype(int)
    yi = np.clip(px[..., 1], 0, H_img - 1).astype(int)
    I = img[yi, xi].astype(float)
    # Clipped pixels (over-exposed paper, crushed ink) say only "at least 255" / "at most 0": they
    # are censored (see ``censor`` below), not dropped. Fitting them as exact values pulls small
    # squares' corners inwards (-0.004 px at 6 px squares, exposure 1.2); dropping them, on boards
    # rendered or exposed hard (ink at 0, paper at 255: the MC-HEC recording) leaves ~20 quantised
    # edge pixels a corner, and the fit neither converges nor finds the corner (0.13-0.16 px RMS
    # against the renderer's truth on renders made like MC-HEC's; censored 0.05).
    if CLIPPED_PIXELS == "dropped":
        inside &= (I > 0) & (I < 255)
    U = np.concatenate([off[None] / pitch[:, None, None], np.ones((N, off.shape[0], 1))], axis=2)
    ex = np.broadcast_to(off[None] / R, U[..., :2].shape)
    # Lines that can reach a window: the window plus ~4 sigma of blur (sigma up to 2.5 px).
    reach = min(4.0, w_sq.max() + 10.0 / pitch.min())
    K = int(np.floor(reach)) + 1
    kap = np.unique(np.add.outer(np.arange(-K, K + 1, dtype=float), pat.offsets).ravel())
    kap = kap[np.abs(kap) <= reach + 1e-9]
    centre_u, centre_v = ij[sel, 1] + 1.0, ij[sel, 0] + 1.0  # corner (i, j) from the board's outer edge
    (cu, ku), (cv, kv) = _axis_setup(pat.lines_u, centre_u, kap), _axis_setup(pat.lines_v, centre_v, kap)
    coef, const = np.stack([cu, cv]), np.stack([ku, kv])  # (2, N, L, R), (2, N, R)

    theta = np.zeros((N, N_PARAMS))
    theta[:, 0:3], theta[:, 3:6], theta[:, 6:8] = G[:, 0], G[:, 1], G[:, 2, :2]
    theta[:, 8] = 1.0
    # The window (weights fixed at the initial geometry, so the cost is one function throughout);
    # keep only its pixels, padded to the largest window with weight 0.
    XY = (U @ np.stack([theta[:, 0:3], theta[:, 3:6]], axis=2)) / (U @ G[:, 2, :, None])
    wgt = _weights(XY, w_sq, inside)
    if pat.data_lo is not None:
        margin_sq = np.broadcast_to(np.asarray(margin_px, float), (N,)) / short
        wgt = wgt * ~_data_mask(XY, centre_u, centre_v, pat, target, margin_sq)
    keep = wgt > 0
    P = int(keep.sum(1).max())
    order = np.argsort(~keep, axis=1, kind="stable")[:, :P]
    U, I, wgt = (np.take_along_axis(a, order[..., None] if a.ndim == 3 else order, axis=1) for a in (U, I, wgt))
    hi, lo = I >= 255.0, I <= 0.0  # clipped: the true level is at least / at most this
    if CLIPPED_PIXELS == "dropped":
        hi, lo = np.zeros_like(hi), np.zeros_like(lo)
    ex = np.take_along_axis(np.ascontiguousarray(ex), order[..., None], axis=1)
    # Photometry from a linear fit at the initial geometry.
    _, _, white = _model(theta, U, ex, kap, coef, const, pitch, pat.s_r, jacobian=False)
    A = np.stack([np.ones_like(white), ex[..., 0], ex[..., 1], white, white * ex[..., 0], white * ex[..., 1]], axis=1)
    Aw = A * wgt[:, None, :]
    AtA = Aw @ A.transpose(0, 2, 1) + 1e-9 * np.eye(6)
    theta[:, 9:15] = np.linalg.solve(AtA, Aw @ I[..., None])[..., 0]

    def censor(r, J, rows):
        """A clipped pixel the model puts beyond its clip (above 255 where the image is 255, below 0
        where it is 0) agrees with it: residual and Jacobian 0 there (a one-sided, Tobit-like fit)."""
        h, l_ = (hi, lo) if rows is None else (hi[rows], lo[rows])
        free = (h & (r < 0)) | (l_ & (r > 0))
        if not free.any():
            return r, J
        return np.where(free, 0.0, r), J * ~free[None]

    def evaluate(th, rows):
        """Cost, residuals and Jacobian (n, 15, P) of the corners ``rows`` at parameters ``th``."""
        if rows.size == N:  # all of them (in order): no copies
            M, J, _ = _model(th, U, ex, kap, coef, const, pitch, pat.s_r)
            r, J = censor(I - M, J, None)
            return (wgt * r * r).sum(1), r, np.moveaxis(J, 0, 1)
        M, J, _ = _model(th, U[rows], ex[rows], kap, coef[:, rows], const[:, rows], pitch[rows], pat.s_r)
        r, J = censor(I[rows] - M, J, rows)
        return (wgt[rows] * r * r).sum(1), r, np.moveaxis(J, 0, 1)

    def corner_local(th):
        """Where G's first two rows vanish: (G00 G01; G10 G11) x = -(G02, G12)."""
        return np.linalg.solve(th[:, [0, 1, 3, 4]].reshape(-1, 2, 2), -th[:, [2, 5], None])[..., 0]

    allc = np.arange(N)
    c, r, J = evaluate(theta, allc)
    loc = corner_local(theta)  # the corners, in local units, at the current parameters
    lam = np.full(N, 1e-3)
    active = np.ones(N, bool)
    for _ in range(max_iterations):
        a = np.nonzero(active)[0]
        if a.size == 0:
            break
        Ja = J[a]
        Jw = Ja * wgt[a][:, None, :]
        JtJ = Jw @ Ja.transpose(0, 2, 1)
        g = (Jw @ r[a][..., None])[..., 0]
        D = np.einsum("naa->na", JtJ)
        damp = lam[a, None] * (D + 1e-6 * D.mean(1, keepdims=True))
        step = np.linalg.solve(JtJ + damp[:, :, None] * np.eye(N_PARAMS), g[..., None])[..., 0]
        cand = theta[a] + step
        cand[:, 8] = np.clip(cand[:, 8], 0.15, 5.0)
        c2, r2, J2 = evaluate(cand, a)
        better = c2 < c[a]
        loc2 = corner_local(cand)
        moved = np.linalg.norm(loc2 - loc[a], axis=1) * pitch[a]
        b = a[better]
        theta[b], c[b], r[b], J[b], loc[b] = cand[better], c2[better], r2[better], J2[better], loc2[better]
        # Converged: a step that moves the corner by < 3e-4 px (a twentieth of the bias we care
        # about), whether taken or not (near the optimum the cost is flat to rounding) as long
        # as the damping did not shrink it; or no descent left.
        done = (moved < 3e-4) & (better | (lam[a] < 1.0))
        lam[a] = np.where(better, lam[a] / 3.0, lam[a] * 4.0)
        active[a] = ~(done | (lam[a] > 1e5))
    uv = origin + loc * pitch[:, None]
    sigma = theta[:, 8]
    n_w = np.maximum(wgt.sum(1), 1.0)
    rms = np.sqrt(c / n_w)
    shift = np.linalg.norm(uv - uv0, axis=1)
    contrast = theta[:, 12]
    # A fit may move a corner a good way (SB on up-scaled tilted boards is off by > 1 px at
    # times) but not by a third of its shortest grid step: that would be another saddle.
    ok = (np.isfinite(uv).all(1) & (shift < 0.3 * short) & (sigma > 0.2) & (sigma < 4.0)
          & (np.abs(contrast) > 10.0) & (rms < 0.25 * np.abs(contrast)))
    return uv, ok, sigma, rms


def _predict_from_neighbours(uv: np.ndarray, ij: np.ndarray, good: np.ndarray, n: int):
    """Position of corner ``n`` from the homography of the good corners up to two steps away
    (None when they are fewer than 4 or degenerate)."""
    import cv2

    d = np.abs(ij - ij[n]).max(axis=1)
    nb = np.nonzero(good & (d <= 2) & (d > 0))[0]
    if len(nb) < 4:
        return None
    H, _ = cv2.findHomography((ij[nb] - ij[n])[:, ::-1].astype(float), uv[nb], 0)
    if H is None or abs(H[2, 2]) < 1e-12:
        return None
    return H[:2, 2] / H[2, 2]


def refine_checkerboard(grey: np.ndarray, target: Target, ids: np.ndarray, uv_px: np.ndarray,
                        max_iterations: int = 20) -> BoardFit:
    """Refine detected inner corners of a checkerboard by fitting the board model (module
    docstring) to the pixels of ``grey`` around each corner.

    Args:
        grey: (H, W) the original 8-bit image (not up-scaled: interpolation would add its own shift).
        target: the checkerboard spec.
        ids: (N,) point ids of the corners (rows of ``target.grid_ij``).
        uv_px: (N, 2) their detected positions, accurate to a fraction of a square.
        max_iterations: Levenberg-Marquardt iterations.
    Returns:
        :class:`BoardFit`.
    """
    return _refine(grey, target, ids, uv_px, max_iterations, _pattern(target), 0.0, WINDOW_PX)


# Pixels within this many blur sigmas of a ChArUco marker's data bits get no weight: a
# Gaussian's tail there is 0.13 % of the contrast (~0.3 grey levels), of a sign that varies
# from marker to marker.
DATA_MARGIN_SIGMAS = 3.0


def refine_charuco(grey: np.ndarray, target: Target, ids: np.ndarray, uv_px: np.ndarray,
                   blur_px: float | None = None, max_iterations: int = 20) -> BoardFit:
    """Refine detected ChArUco corners by the same fit, with each marker modelled as the solid
    black square its border bit makes, and the pixels near its data bits left out (module
    docstring of :class:`_Pattern`).

    Args:
        grey: (H, W) the original 8-bit image.
        target: the ChArUco spec.
        ids: (N,) ChArUco corner ids (a partial view is fine: missing neighbours are predicted
            from the detected corners for the fit's start).
        uv_px: (N, 2) their detected positions.
        blur_px: the image's edge blur (Gaussian sigma, pixels) if known; it sizes the margin
            around the data bits. Without it a first fit measures it.
        max_iterations: Levenberg-Marquardt iterations.
    Returns:
        :class:`BoardFit`.
    """
    return _refine_masked(grey, target, ids, uv_px, max_iterations, _pattern(target), blur_px)


def _refine_masked(grey, target, ids, uv_px, max_iterations, pat, blur_px) -> BoardFit:
    """The fit of a board with markers, the pixels within a margin of the data bits left out."""
    guess = 1.5 if blur_px is None or not np.isfinite(blur_px) else max(float(blur_px), 0.5)
    fit = _refine(grey, target, ids, uv_px, max_iterations, pat, DATA_MARGIN_SIGMAS * guess, CHARUCO_WINDOW_PX)
    if fit.refined.any():
        # The fit measures the blur itself; a margin sized for much less is done again.
        sigma = float(np.median(fit.sigma_px[fit.refined]))
        if sigma > 1.25 * guess:
            fit = _refine(grey, target, ids, uv_px, max_iterations, pat, DATA_MARGIN_SIGMAS * sigma, CHARUCO_WINDOW_PX)
    return fit


def refine_marker_checkerboard(grey: np.ndarray, target: Target, ids: np.ndarray, uv_px: np.ndarray,
                               marker_frac: float, blur_px: float | None = None, max_iterations: int = 20) -> BoardFit:
    """Refine the corners of a checkerboard with markers in its white squares (a ChArUco board
    declared as a checkerboard) as :func:`refine_charuco` does: each marker the solid black square
    of side ``marker_frac`` (squares) its border bit makes, the pixels near its data bits left out.
    The dictionary is not known, so the data bits are taken to start one bit of the densest
    predefined dictionary (7 x 7) inside the marker's edge: the fit then leaves out part of a
    coarser marker's border too, never a data bit. Without it the markers pull the corners by
    0.1-0.4 px RMS (up to 1 px) on rendered views, and the solver rejects those views."""
    return _refine_masked(grey, target, ids, uv_px, max_iterations, _pattern(target, marker_frac, 7), blur_px)


def _fill_neighbours(target: Target, ids: np.ndarray, uv0: np.ndarray):
    """Ids and predicted positions of the grid neighbours (3x3) of ``ids`` that were not
    detected (partial ChArUco views), by the homography of all detected corners: they only
    shape the fit's starting geometry, and local homographies of a few detected corners near a
    line (a partial view's usual shape) extrapolate wildly. None when the corners are too few
    or all on one line."""
    import cv2

    ij_all = target.grid_ij
    none = np.zeros(0, int), np.zeros((0, 2))
    ij = ij_all[ids].astype(float)
    if len(ids) < 4 or np.linalg.svd(ij - ij.mean(0), compute_uv=False)[-1] < 0.5:
        return none
    have = np.zeros(target.n_points, bool)
    have[ids] = True
    near = np.zeros(target.n_points, bool)
    for i, j in ij_all[ids]:
        near |= (np.abs(ij_all[:, 0] - i) <= 1) & (np.abs(ij_all[:, 1] - j) <= 1)
    missing = np.nonzero(near & ~have)[0]
    H, _ = cv2.findHomography(ij[:, ::-1], uv0, 0)
    if missing.size == 0 or H is None:
        return none
    q = np.column_stack([ij_all[missing, 1], ij_all[missing, 0], np.ones(missing.size)]) @ H.T
    good = np.abs(q[:, 2]) > 1e-9
    return missing[good], q[good, :2] / q[good, 2:3]


def _consistent(rms: np.ndarray, sigma: np.ndarray, typical: tuple) -> np.ndarray:
    """Fits whose residual and blur are in line with the board's typical (median) ones. A wrong
    minimum measured on rendered ChArUco views: residual 19 grey levels against 1.0, blur 1.5
    against 0.9 px."""
    rms_typ, sigma_typ = typical
    return (rms < 3.0 * rms_typ + 2.0) & (sigma < 1.5 * sigma_typ + 0.3)


def _refine(grey, target, ids, uv_px, max_iterations, pat, margin_px, window_px) -> BoardFit:
    """The fit of every corner, a second start for those that failed, the input kept where
    both fail."""
    ids = np.asarray(ids, int)
    uv0 = np.asarray(uv_px, float).reshape(-1, 2)
    N = len(ids)
    if N == 0:
        z = np.zeros(0)
        return BoardFit(uv0.copy(), z.astype(bool), z, z)
    img = np.asarray(grey)  # pixels are gathered per window, then made float
    extra_ids, extra_uv = (_fill_neighbours(target, ids, uv0) if target.kind == "charuco"
                           else (np.zeros(0, int), np.zeros((0, 2))))
    ij = target.grid_ij[np.concatenate([ids, extra_ids])]
    uv_all = np.vstack([uv0, extra_uv])

    def fit(uv_start, sel):
        return _fit_corners(img, target, ij, uv_start, sel, max_iterations, pat, margin_px, window_px)

    try:
        uv, ok, sigma, rms = fit(uv_all, np.arange(N))
    except np.linalg.LinAlgError:
        # Some corner's normal equations are singular (a degenerate start); the fits are
        # independent, so one by one keeps the others.
        uv, ok, sigma, rms = uv0.copy(), np.zeros(N, bool), np.full(N, np.nan), np.full(N, np.nan)
        for n in range(N):
            try:
                one = fit(uv_all, np.array([n]))
            except np.linalg.LinAlgError:
                continue
            uv[n], ok[n], sigma[n], rms[n] = (a[0] for a in one)
    typical = None
    if pat.data_lo is not None and ok.sum() >= 4:
        # Marker edges offer the fit other minima: a corner whose fit explains its window far
        # worse than the others explain theirs (the same noise and, nearly, the same blur over
        # one board) is not trusted and is started again below.
        typical = float(np.median(rms[ok])), float(np.median(sigma[ok]))
        ok &= _consistent(rms, sigma, typical)
    if not ok.all() and ok.sum() >= 4:
        # A detector corner far off (SB or classic on an up-scaled tilted board, now and then
        # by > 1 px) is beyond the fit's reach: start it again from its refined neighbours.
        guess = np.where(ok[:, None], uv, uv0)
        redo = []
        for n in np.nonzero(~ok)[0]:
            p = _predict_from_neighbours(guess, ij[:N], ok, n)
            if p is not None:
                guess[n] = p
                redo.append(n)
        if redo:
            redo = np.array(redo)
            try:
                uv2, ok2, s2, r2 = fit(np.vstack([guess, extra_uv]), redo)
                if typical is not None:
                    ok2 &= _consistent(r2, s2, typical)
                uv[redo], ok[redo], sigma[redo], rms[redo] = uv2, ok2, s2, r2
            except np.linalg.LinAlgError:
                pass  # they keep the detector's position
    out = np.where(ok[:, None], uv, uv0)
    return BoardFit(uv_px=out, refined=ok, sigma_px=sigma, rms_grey=rms)
