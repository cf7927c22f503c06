"""Camera intrinsics and the projection model (OpenCV pinhole + radial/tangential distortion).

The model matches ``cv2.projectPoints`` for 0, 4, 5 or 8 distortion coefficients
``(k1, k2, p1, p2[, k3[, k4, k5, k6]])``. Pixel centres are at integer coordinates, as in OpenCV.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calibgraph.core.errors import InputError

_ALLOWED_DIST = (0, 4, 5, 8)
# 'unknown': no values given (only the image size); the solver initialises them from the views
INTRINSICS_SOURCES = ("", "exact", "factory", "calibration", "unknown")
# the solver's intrinsics vector: what a generic prior is over
INTRINSICS_VECTOR = ("fx", "fy", "cx", "cy", "k1", "k2")
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")
# a calibration file's covariance may cover more: the solver then estimates (and keeps the prior on)
# the first 6, 8 or 9 of these (its distortion entries are OpenCV's first coefficients, in order)
INTRINSICS_FULL = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
INTRINSICS_SIZES = (9, 8, 6)


def intrinsics_names(n: int) -> tuple:
    """The names of an intrinsics vector (or covariance) of size ``n`` (6, 8 or 9)."""
    if n not in INTRINSICS_SIZES:
        raise InputError(f"intrinsics: a vector of {n} parameters; expected one of {sorted(INTRINSICS_SIZES)} "
                         f"(the first of {list(INTRINSICS_FULL)}).")
    return INTRINSICS_FULL[:n]


def covered_size(names, n_dist: int | None = None) -> int | None:
    """The largest of 9, 8, 6 whose first parameters of ``INTRINSICS_FULL`` all appear in ``names``
    (and, given ``n_dist``, are among the first ``n_dist`` distortion coefficients); None when even
    [fx, fy, cx, cy, k1, k2] are not all there."""
    have = set(names)
    for n in INTRINSICS_SIZES:
        if set(INTRINSICS_FULL[:n]) <= have and (n_dist is None or n - 4 <= max(n_dist, 2)):
            return n
    return None


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics with OpenCV distortion.

    Attributes:
        K: (3, 3) camera matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] in pixels.
        dist: (n,) distortion coefficients in OpenCV order, n in {0, 4, 5, 8}.
        width_px, height_px: image size.
        source: where these values come from, which sets how far the solver trusts them
            (``SolverOptions.intrinsics``): 'exact' (a simulation's own camera: held fixed),
            'factory', 'calibration', 'unknown' (only the image size is known: K is a placeholder
            the solver replaces with values from the views), or '' (not said: the solver's default).
        covariance: covariance of [fx, fy, cx, cy, k1, k2] (6, 6), or of those and [p1, p2] (8, 8) or
            [p1, p2, k3] (9, 9) (``INTRINSICS_FULL``), when the values come with one (a ``calibgraph
            intrinsics`` file): the solver's prior then, over every parameter it covers (estimated with
            the others, so that an error in the file's tangential or third radial coefficient is not
            held as if exact).
    """

    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    width_px: int = 0
    height_px: int = 0
    source: str = ""
    covariance: np.ndarray | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        K = np.asarray(self.K, dtype=float)
        dist = np.asarray(self.dist, dtype=float).reshape(-1)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise InputError(f"intrinsics: K must be a finite 3x3 matrix, got {K.tolist()}.")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise InputError(f"intrinsics: K is not a camera matrix (fx, fy > 0, last row 0 0 1): {K.tolist()}.")
        if dist.size not in _ALLOWED_DIST:
            raise InputError(
                f"intrinsics: {dist.size} distortion coefficients given; calibgraph supports 0, 4, 5 or 8 "
                "(k1 k2 p1 p2 [k3 [k4 k5 k6]])."
            )
        if not np.all(np.isfinite(dist)):
            raise InputError("intrinsics: distortion coefficients contain NaN/inf.")
        if int(self.width_px) < 0 or int(self.height_px) < 0:
            raise InputError("intrinsics: image size must be non-negative.")
        if self.source not in INTRINSICS_SOURCES:
            raise InputError(f"intrinsics: source must be one of {INTRINSICS_SOURCES[1:]}, got {self.source!r}.")
        if self.covariance is not None:
            cov = np.asarray(self.covariance, float)
            n = cov.shape[0] if cov.ndim == 2 else -1
            if cov.ndim != 2 or cov.shape[1] != n or n not in INTRINSICS_SIZES or not np.all(np.isfinite(cov)) \
                    or n - 4 > max(dist.size, 2):
                raise InputError(f"intrinsics: covariance must be a finite square matrix over "
                                 f"{list(INTRINSICS_VECTOR)} (optionally then p1, p2 [, k3], each a distortion "
                                 f"coefficient given), got shape {cov.shape} with {dist.size} distortion coefficients.")
            cov = 0.5 * (cov + cov.T)
            if np.linalg.eigvalsh(cov).min() <= 0:
                raise InputError("intrinsics: covariance is not positive definite; give a covariance from a "
                                 "calibration (calibgraph intrinsics writes one) or none.")
            object.__setattr__(self, "covariance", cov)
        if self.source == "unknown" and (self.width_px <= 0 or self.height_px <= 0):
            raise InputError("intrinsics: unknown intrinsics need the image size (width_px, height_px).")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "width_px", int(self.width_px))
        object.__setattr__(self, "height_px", int(self.height_px))

    # -- constructors ---------------------------------------------------------------------------
    @classmethod
    def from_hfov(cls, width_px: int, height_px: int, hfov_deg: float, dist=None) -> "Intrinsics":
        """Square-pixel camera with the given horizontal field of view; principal point at the
        image centre in OpenCV's convention ((W - 1) / 2, (H - 1) / 2)."""
        f = (width_px / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        K = np.array([[f, 0.0, (width_px - 1) / 2.0], [0.0, f, (height_px - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(K=K, dist=np.zeros(5) if dist is None else np.asarray(dist, float), width_px=width_px, height_px=height_px)

    @classmethod
    def unknown(cls, width_px: int, height_px: int) -> "Intrinsics":
        """A camera of which only the image size is known: a placeholder K (a 60 deg horizontal
        field of view, principal point at the centre, no distortion) that the solver replaces with
        values from the views before it uses them."""
        f = (width_px / 2.0) / np.tan(np.radians(30.0))
        K = np.array([[f, 0.0, (width_px - 1) / 2.0], [0.0, f, (height_px - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(K=K, dist=np.zeros(5), width_px=width_px, height_px=height_px, source="unknown")

    def with_pinhole(self, k6) -> "Intrinsics":
        """A copy with [fx, fy, cx, cy] and, when given, the first distortion coefficients [k1, k2
        [, p1, p2 [, k3]]] replaced by ``k6`` (4, 6, 8 or 9 values: ``INTRINSICS_FULL``'s order),
        built without validation: the solver calls this for every view at every iteration with
        values of its own graph (validating them cost a quarter of the optimiser's time)."""
        K = self.K.copy()
        K[0, 0], K[1, 1], K[0, 2], K[1, 2] = k6[:4]
        dist = self.dist8 if self.dist.size < 5 else self.dist.copy()
        if len(k6) > 4:
            dist = dist.copy()
            dist[:len(k6) - 4] = k6[4:]
        out = object.__new__(Intrinsics)
        for name, value in (("K", K), ("dist", dist), ("width_px", self.width_px), ("height_px", self.height_px),
                            ("source", self.source), ("covariance", None)):
            object.__setattr__(out, name, value)
        return out

    @property
    def known(self) -> bool:
        """False when only the image size is known (``source == 'unknown'``)."""
        return self.source != "unknown"

    @property
    def sigma(self) -> dict | None:
        """1-sigma of the parameters ``covariance`` covers (None without one)."""
        if self.covariance is None:
            return None
        return dict(zip(intrinsics_names(self.covariance.shape[0]), np.sqrt(np.diag(self.covariance)).tolist()))

    @property
    def dist8(self) -> np.ndarray:
        """Distortion padded to 8 coefficients."""
        d = np.zeros(8)
        d[: self.dist.size] = self.dist
        return d

    def to_dict(self) -> dict:
        d = {
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            "width_px": self.width_px,
            "height_px": self.height_px,
        }
        if self.source:
            d["source"] = self.source
        if self.covariance is not None:
            d["covariance"] = self.covariance.tolist()
            d["covariance_order"] = list(intrinsics_names(self.covariance.shape[0]))
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Intrinsics":
        """From K (3x3) or fx, fy, cx, cy; ``dist`` or ``distortion`` (a list, or a mapping with
        ``coefficients``); ``width_px``/``height_px``; ``source``; and an optional ``covariance``
        whose rows follow ``covariance_order`` (default fx, fy, cx, cy, then the distortion
        coefficients in order). A mapping with only the image size is a camera of unknown intrinsics."""
        width, height = int(d.get("width_px", d.get("width", 0)) or 0), int(d.get("height_px", d.get("height", 0)) or 0)
        if "K" in d:
            K = np.asarray(d["K"], float).reshape(3, 3)
        elif not any(k in d for k in ("fx", "fy", "cx", "cy")) and width > 0 and height > 0 \
                and str(d.get("source") or "unknown") == "unknown":
            return cls.unknown(width, height)
        else:
            try:
                K = np.array([[d["fx"], d.get("s", 0.0), d["cx"]], [0, d["fy"], d["cy"]], [0, 0, 1]], float)
            except KeyError as e:
                raise InputError(f"intrinsics: missing key {e}; give K (3x3) or fx, fy, cx, cy (or only width_px "
                                 "and height_px for a camera whose intrinsics the solver should find).") from None
        dist = d.get("dist", d.get("distortion", [0.0] * 5))
        if isinstance(dist, dict):
            dist = dist.get("coefficients", [0.0] * 5)
        dist = np.asarray(dist, float).reshape(-1)
        cov = d.get("covariance")
        if cov is not None:
            cov = _intrinsics_block(np.asarray(cov, float), d.get("covariance_order"), dist.size)
        return cls(K=K, dist=dist, width_px=width, height_px=height, source=str(d.get("source") or ""), covariance=cov)

    # -- model ----------------------------------------------------------------------------------
    def project(self, p_cam_m: np.ndarray, with_jacobian: bool = False):
        """Project camera-frame points to pixels.

        Args:
            p_cam_m: (N, 3) points in the OpenCV camera frame (z forward), metres.
            with_jacobian: also return d(uv)/d(p_cam) as (N, 2, 3).
        Returns:
            uv_px (N, 2) [, J (N, 2, 3)]. Points with z <= 0 project to NaN.
        """
        uv, J, _ = project_points(p_cam_m, self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2], self.K[0, 1],
                                  self.dist8, with_jacobian)
        return (uv, J) if with_jacobian else uv

    def in_image(self, uv_px: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
        """Boolean mask of pixels inside the image (needs width/height)."""
        uv = np.asarray(uv_px)
        return (
            np.isfinite(uv).all(axis=1)
            & (uv[:, 0] >= -0.5 + margin_px)
            & (uv[:, 1] >= -0.5 + margin_px)
            & (uv[:, 0] <= self.width_px - 0.5 - margin_px)
            & (uv[:, 1] <= self.height_px - 0.5 - margin_px)
        )


def project_points(p_cam_m, fx, fy, cx, cy, s, dist8, with_jacobian: bool = False):
    """The OpenCV camera model, with parameters that are scalars (one camera) or (N,) arrays (one
    per point: many cameras' points projected in one pass). ``dist8``: (8,) or (8, N).

    Returns (uv_px (N, 2), d uv / d p_cam (N, 2, 3) or None, normalised coordinates
    (x, y, x_d, y_d, r2, b) for the intrinsics' Jacobian or None). Points with z <= 0 give NaN.
    """
    P = np.asarray(p_cam_m, float).reshape(-1, 3)
    Zs = np.where(P[:, 2] > 1e-9, P[:, 2], np.nan)
    x = P[:, 0] / Zs
    y = P[:, 1] / Zs
    k1, k2, p1, p2, k3, k4, k5, k6 = dist8
    r2 = x * x + y * y
    a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    rad = a / b
    xd = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    uv = np.column_stack([fx * xd + s * yd + cx, fy * yd + cy])
    if not with_jacobian:
        return uv, None, None
    da = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    db = k4 + r2 * (2 * k5 + 3 * k6 * r2)
    drad = (da * b - a * db) / (b * b)
    dxd_dx = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
    dxd_dy = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
    dyd_dx = dxd_dy
    dyd_dy = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
    # d(uv)/d(xd, yd)
    du_dx = fx * dxd_dx + s * dyd_dx
    du_dy = fx * dxd_dy + s * dyd_dy
    dv_dx = fy * dyd_dx
    dv_dy = fy * dyd_dy
    iz = 1.0 / Zs
    J = np.empty((P.shape[0], 2, 3))
    J[:, 0, 0] = du_dx * iz
    J[:, 0, 1] = du_dy * iz
    J[:, 0, 2] = -(du_dx * x + du_dy * y) * iz
    J[:, 1, 0] = dv_dx * iz
    J[:, 1, 1] = dv_dy * iz
    J[:, 1, 2] = -(dv_dx * x + dv_dy * y) * iz
    return uv, J, (x, y, xd, yd, r2, b)


def distortion_partials(x, y, dist8, n: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """d(x_d, y_d) / d(the first ``n`` distortion coefficients, in ``DIST_NAMES`` order: k1, k2, p1,
    p2, k3, k4, k5, k6) at undistorted normalised points (x, y): two (N, n) arrays. ``dist8``: (8,)
    or (8, N) (one camera, or one per point)."""
    k1, k2, p1, p2, k3, k4, k5, k6 = dist8
    r2 = x * x + y * y
    b = 1 + r2 * (k4 + r2 * (k5 + r2 * k6))
    powers = (r2, r2 * r2, r2 * r2 * r2)
    dx, dy = np.zeros((x.size, n)), np.zeros((x.size, n))
    for i, name in enumerate(DIST_NAMES[:n]):
        if name == "p1":
            dx[:, i], dy[:, i] = 2 * x * y, r2 + 2 * y * y
            continue
        if name == "p2":
            dx[:, i], dy[:, i] = r2 + 2 * x * x, 2 * x * y
            continue
        if name in ("k1", "k2", "k3"):
            drad = powers[("k1", "k2", "k3").index(name)] / b
        else:
            a = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = -a * powers[("k4", "k5", "k6").index(name)] / (b * b)
        dx[:, i], dy[:, i] = x * drad, y * drad
    return dx, dy


def _intrinsics_block(cov: np.ndarray, order, n_dist: int) -> np.ndarray:
    """The block of a covariance (the marginal covariance of those parameters) over the first 9, 8
    or 6 of ``INTRINSICS_FULL`` it covers, from one whose rows follow ``order`` (default fx, fy, cx,
    cy, then the distortion coefficients)."""
    order = list(order) if order is not None else ["fx", "fy", "cx", "cy", *DIST_NAMES[:n_dist]]
    if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or cov.shape[0] != len(order):
        raise InputError(f"intrinsics: covariance of shape {cov.shape} does not match covariance_order {order}.")
    n = covered_size(order, n_dist)
    if n is None:
        missing = [m for m in INTRINSICS_VECTOR if m not in order]
        raise InputError(f"intrinsics: covariance has no rows for {missing}; it must cover {list(INTRINSICS_VECTOR)}.")
    idx = [order.index(m) for m in INTRINSICS_FULL[:n]]
    return cov[np.ix_(idx, idx)]


# Presets used by the simulator and the benchmarks (colour streams).
PRESETS = {
    "d455": dict(width_px=1280, height_px=800, hfov_deg=90.0),
    "l515": dict(width_px=1920, height_px=1080, hfov_deg=70.0),
    "kinect_v2": dict(width_px=1920, height_px=1080, hfov_deg=84.1),
}


def preset(name: str) -> Intrinsics:
    """Ideal intrinsics of a named camera preset ('d455', 'l515', 'kinect_v2')."""
    key = name.lower().replace("-", "_")
    if key not in PRESETS:
        raise InputError(f"unknown camera preset {name!r}; choose one of {sorted(PRESETS)}.")
    p = PRESETS[key]
    return Intrinsics.from_hfov(p["width_px"], p["height_px"], p["hfov_deg"])


def undistort_normalised(intr: Intrinsics, uv_px: np.ndarray, iterations: int = 25) -> np.ndarray:
    """(N, 2) normalised coordinates (x/z, y/z) whose projection is ``uv_px``: the inverse of the
    distortion by fixed-point iteration (as OpenCV's undistortPoints), vectorised in numpy."""
    uv = np.asarray(uv_px, float).reshape(-1, 2)
    Kinv2 = np.linalg.inv(intr.K[:2, :2])
    xd = (uv - intr.K[:2, 2]) @ Kinv2.T
    if not np.any(intr.dist8):
        return xd
    k1, k2, p1, p2, k3, k4, k5, k6 = intr.dist8
    x, y = xd[:, 0].copy(), xd[:, 1].copy()
    for _ in range(iterations):
        r2 = x * x + y * y
        rad = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        x = (xd[:, 0] - dx) / rad
        y = (xd[:, 1] - dy) / rad
    return np.column_stack([x, y])
