"""The values of a result file: plain JSON for the free-form sections, arrays in their shapes for
the rest, each entry checked as it is read (one :class:`InputError` naming it), and the exact
equality that says a result read back is the one saved."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from calibgraph.core.errors import InputError


def residual_from_dict(v: dict) -> dict:
    """One view's residual record as a result file holds it (its arrays are shaped by
    :func:`residual_record` when the CameraResult is made)."""
    ids = np.asarray(v["ids"], int).reshape(-1)
    w = v.get("weight")
    if w is None:  # files before the weights were written: the rejected flags are what is known
        cr = v.get("corner_rejected")
        w = np.ones(ids.size) if cr is None else np.where(np.asarray(cr, bool), 0.0, 1.0)
    return {"ids": ids, "uv_detected_px": v["uv_detected_px"], "residual_px": v["residual_px"], "weight": w,
            "rejected": v.get("rejected", False)}


def residual_record(v) -> dict:
    """One view's residual record with its arrays in their shapes and dtypes."""
    ids = np.asarray(v["ids"]).astype(int).reshape(-1)
    w = v.get("weight")
    return {"ids": ids,
            "uv_detected_px": floats(v["uv_detected_px"]).reshape(-1, 2),
            "residual_px": floats(v["residual_px"]).reshape(-1, 2),
            "weight": np.ones(ids.size) if w is None else floats(w).reshape(-1),
            "rejected": bool(v.get("rejected", False))}


def mapping(x, what: str) -> dict:
    """``x``, which must be a mapping (``what`` names it in the error)."""
    if not isinstance(x, dict):
        raise InputError(f"{what} is not a mapping.")
    return x


def section(d: dict, key: str, where: str) -> dict | None:
    """An optional free-form section: a mapping or absent."""
    return None if d.get(key) is None else mapping(d[key], f"{where}: {key}")


def matrix(x, shape: tuple, what: str) -> np.ndarray:
    """``x`` as a float array of ``shape`` (``what`` names it in the error)."""
    try:
        a = np.asarray(x, float)
    except (TypeError, ValueError):
        raise InputError(f"{what} is not a {shape[0]}x{shape[1]} matrix of numbers.") from None
    if a.shape != shape:
        raise InputError(f"{what} is not a {shape[0]}x{shape[1]} matrix (got shape {a.shape}).")
    return a


RIGID_TOL = 1e-6  # |R^T R - I| of a pose read back: a saved one is at 1e-15; a few printed digits reach 1e-7


def pose_matrix(x, what: str) -> np.ndarray:
    """``x`` as a finite 4x4 rigid transform (rotation orthonormal with det +1, last row 0 0 0 1),
    returned as written (not re-orthonormalised: a result reads back equal to the one saved)."""
    T = matrix(x, (4, 4), what)
    if not np.all(np.isfinite(T)):
        raise InputError(f"{what} is not a finite 4x4 matrix: the result file was damaged or edited; re-solve.")
    R = T[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if err > RIGID_TOL or det < 0 or np.abs(T[3] - [0.0, 0.0, 0.0, 1.0]).max() > RIGID_TOL:
        raise InputError(f"{what} is not a rigid transform (|R^T R - I| = {err:.2g}, det {det:.3g}, last row "
                         f"{np.round(T[3], 6).tolist()}): the result file was damaged or edited; re-solve.")
    return T


def number_or(x, default: float) -> float:
    """``x`` as a float, ``default`` when absent (None)."""
    return default if x is None else float(x)


def set_fields(obj, **values) -> None:
    """Set fields of a frozen dataclass (its ``__post_init__`` normalising them)."""
    for k, v in values.items():
        object.__setattr__(obj, k, v)


def floats(x) -> np.ndarray:
    """``x`` as a float array."""
    return np.asarray(x, dtype=float)


def floats_or_none(x) -> np.ndarray | None:
    """``x`` as a float array, or None."""
    return None if x is None else floats(x)


def plain_json(x):
    """``x`` as the JSON value it is saved as (lists for tuples and arrays, Python scalars, string
    keys), so a free-form section equals itself read back."""
    if x is None or isinstance(x, (str, bool)):
        return x
    if isinstance(x, dict):
        return {str(k): plain_json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain_json(x.tolist())
    if isinstance(x, np.generic):
        return plain_json(x.item())
    if isinstance(x, (int, float)):
        return x
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"result: {type(x).__name__} value {x!r} cannot be saved in a result file")


def exactly_equal(a, b) -> bool:
    """Exact equality of results and their parts (what ``==`` of a Result, CameraResult or
    PairResult means): same types, arrays of equal shape and values, NaN equal to NaN."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.shape == b.shape and bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
    if dataclasses.is_dataclass(a):
        return all(exactly_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(exactly_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(exactly_equal(x, y) for x, y in zip(a, b))
    if isinstance(a, float) and math.isnan(a):
        return math.isnan(b)
    return a == b
