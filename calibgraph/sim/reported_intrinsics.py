"""The intrinsics a simulated camera reports, as a real device's differ from its true ones.

No real camera hands out its exact intrinsics: a RealSense's or Kinect's factory calibration is off
by tenths of a percent in focal length and by pixels in principal point and distortion. A
simulation that reports the very intrinsics it renders with measures an oracle: the solver is told
the camera model exactly. :class:`ReportedIntrinsics` says how far off a simulated device's
reported intrinsics are; :func:`reported_intrinsics` draws them, seeded per camera, while the
images (or synthetic corners) keep coming from the true ones.

Focal lengths err as a factory calibration's do: one common scale error of fx and fy
(``focal_rel_sigma``) and a small independent aspect part (``aspect_rel_sigma``), so fx and fy
are strongly correlated (above 0.99 with the defaults): the pixel pitch is known far better than
the focal length. The principal point moves by ``principal_point_sigma_px`` per axis; k1 and k2 by
``k1_sigma`` and ``k2_sigma`` (the other coefficients are kept). The draw depends only on the seed
and the camera's name, so a camera reports the same intrinsics in every run and scene, whatever
the order of the cameras.
"""

from __future__ import annotations

import zlib
from dataclasses import asdict, dataclass, replace

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError

EXACT = "exact"


@dataclass(frozen=True)
class ReportedIntrinsics:
    """1-sigma errors of the intrinsics a simulated device reports (defaults: factory-class).

    Attributes:
        focal_rel_sigma: common relative error of fx and fy.
        principal_point_sigma_px: error of cx and cy, each, in pixels.
        k1_sigma, k2_sigma: error of the first two radial distortion coefficients.
        aspect_rel_sigma: relative error of fx / fy (independent of the common part).
        seed: seed of the draw (combined with the camera name).
    """

    focal_rel_sigma: float = 0.006
    principal_point_sigma_px: float = 3.0
    k1_sigma: float = 0.01
    k2_sigma: float = 0.01
    aspect_rel_sigma: float = 0.0005
    seed: int = 11

    def __post_init__(self):
        for name in ("focal_rel_sigma", "principal_point_sigma_px", "k1_sigma", "k2_sigma", "aspect_rel_sigma"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise InputError(f"reported_intrinsics: {name} must be a number >= 0, got {v!r}.")
            object.__setattr__(self, name, float(v))
        if self.focal_rel_sigma >= 0.2 or self.aspect_rel_sigma >= 0.2:
            raise InputError("reported_intrinsics: focal_rel_sigma and aspect_rel_sigma are relative (0.006 = 0.6 %); "
                             f"got {self.focal_rel_sigma} and {self.aspect_rel_sigma}.")
        try:
            object.__setattr__(self, "seed", int(self.seed))
        except (TypeError, ValueError):
            raise InputError(f"reported_intrinsics: seed must be an integer, got {self.seed!r}.") from None

    def to_dict(self) -> dict:
        return asdict(self)


FACTORY = ReportedIntrinsics()


def parse_reported(value, where: str = "reported_intrinsics"):
    """``'exact'`` or a :class:`ReportedIntrinsics` from a YAML value: 'exact', 'factory' (the
    defaults), a mapping of :class:`ReportedIntrinsics` fields, or an instance."""
    if isinstance(value, ReportedIntrinsics) or value == EXACT:
        return value
    if value == "factory":
        return FACTORY
    if isinstance(value, dict):
        try:
            return ReportedIntrinsics(**value)
        except TypeError:
            allowed = ", ".join(ReportedIntrinsics.__dataclass_fields__)
            raise InputError(f"{where}: unknown keys {', '.join(sorted(set(value) - set(ReportedIntrinsics.__dataclass_fields__)))}; "
                             f"allowed: {allowed}.") from None
    raise InputError(f"{where}: give 'exact' (the device reports its true intrinsics: an oracle), 'factory', or a "
                     f"mapping such as {{focal_rel_sigma: 0.006, principal_point_sigma_px: 3.0, k1_sigma: 0.01, "
                     f"k2_sigma: 0.01, seed: 11}}; got {value!r}.")


def reported_to_yaml(value):
    """The YAML form of what :func:`parse_reported` reads."""
    return value if value == EXACT else value.to_dict()


def reported_intrinsics(true: Intrinsics, camera: str, reported) -> Intrinsics:
    """What camera ``camera`` with intrinsics ``true`` reports under ``reported`` ('exact' or a
    :class:`ReportedIntrinsics`): the true values with ``source='exact'``, or drawn values (seeded
    by ``reported.seed`` and the name) with ``source='factory'``."""
    if reported == EXACT:
        return replace(true, source="exact")
    r = reported
    rng = np.random.default_rng([r.seed, zlib.crc32(camera.encode())])
    e_f, e_a = rng.normal(scale=[r.focal_rel_sigma, r.aspect_rel_sigma])
    d_c = rng.normal(scale=r.principal_point_sigma_px, size=2)
    d_k = rng.normal(scale=[r.k1_sigma, r.k2_sigma])
    K = true.K.copy()
    K[0, 0] *= (1.0 + e_f) * (1.0 + e_a / 2)
    K[1, 1] *= (1.0 + e_f) * (1.0 - e_a / 2)
    K[:2, 2] += d_c
    dist = true.dist8[: max(true.dist.size, 5)].copy()
    dist[:2] += d_k
    return Intrinsics(K=K, dist=dist, width_px=true.width_px, height_px=true.height_px, source="factory")
