"""A solved graph linearised and reduced to its few global variables.

The per-capture robot poses (``f``; ``h`` in the corner formulation) are many and each couples only
to the global variables its factors touch (cameras, intrinsics, mount, scale, offsets), so they are
eliminated first (Schur complement). What remains is a small dense system from which any column of
the full covariance, and the Gauss-Newton step of any subset of the global variables, follows. The
error budget (:mod:`calibgraph.solver.uncertainty.budget`) and the test of exact intrinsics claims
(:mod:`calibgraph.solver.camera.claims`) read it.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import gtsam
import numpy as np

LOCAL = {"f", "h"}  # per-capture variables (robot poses), eliminated first


def _chars(keys) -> set:
    return {chr(gtsam.Symbol(k).chr()) for k in keys}


def _source(keys) -> str:
    return _source_of_chars(_chars(keys))


def _source_of(keys, chars: dict) -> str:
    """:func:`_source` with the keys' characters looked up in ``chars`` (key -> character)."""
    return _source_of_chars({chars[k] for k in keys})


def _source_of_chars(c: set) -> str:
    if "c" in c:
        return "corners"
    if c == {"k"}:
        return "intrinsics"
    if c <= {"s", "p"}:
        return "board"
    return "robot_fk"  # F(k) priors, kinematic factors, the joint-offset prior, the corner form's between factors


TRANSLATION = slice(3, 6)  # GTSAM Pose3 tangent: rotation first
SOURCES = ("corners", "intrinsics", "robot_fk", "board")


@dataclass(frozen=True)
class Linear:
    """A graph linearised at its values and reduced to its global variables.

    The per-capture (local) variables' parts are dense arrays over the locals (all of one tangent
    dimension ``d``) and the global vector: ``Hll`` (L, d, d) and ``Hlg`` (L, d, n), by source too,
    so a reduction with the sources scaled (:meth:`information`) is a few array products."""

    raw: list  # (source, keys, whitened Jacobian A, dims of the keys' columns) per factor
    index: dict  # global key -> slice in the global vector
    locals_: dict  # local key -> its row in the local arrays
    S: np.ndarray  # Schur complement: the information of the global variables, the locals eliminated
    g: np.ndarray  # the cost's gradient on the global variables with the locals at their optimum
    prior_K: dict  # K key -> its prior's information (6, 6)
    H_src: dict  # source -> its factors' global-global information (before the reduction)
    Hll_src: dict  # source -> (L, d, d) its factors' local-local information
    Hlg_src: dict  # source -> (L, d, n) its factors' local-global information (sources that have any)
    Hll_inv: np.ndarray  # (L, d, d) the inverse of the locals' information, all sources
    Hlg: np.ndarray  # (L, d, n) the locals' information with the globals, all sources

    @cached_property
    def factors(self) -> list:
        """(source, keys, {key: whitened Jacobian block A_key}) per factor."""
        out = []
        for src, keys, A, dims in self.raw:
            blocks, col = {}, 0
            for k, d in zip(keys, dims):
                blocks[k] = A[:, col:col + d]
                col += d
            out.append((src, keys, blocks))
        return out

    @cached_property
    def covariance(self) -> np.ndarray:
        """``S^-1``: the joint covariance of the global variables (computed once)."""
        return _inverse(self.S)

    @cached_property
    def local_covariances(self) -> np.ndarray:
        """(L, d, d) every local variable's marginal covariance, ``H_ll^-1 + X Sigma_gg X^T`` with
        ``X = H_ll^-1 H_lg`` (all at once, on first use)."""
        X = self.Hll_inv @ self.Hlg
        L, d, n = X.shape
        XS = (X.reshape(L * d, n) @ self.covariance).reshape(L, d, n)
        return self.Hll_inv + XS @ X.transpose(0, 2, 1)

    def marginals(self, keys) -> "ReducedMarginals":
        """Marginal covariances of the graph's variables (``keys``: all of them) from this reduction;
        raises LinAlgError when the information is not positive definite."""
        return ReducedMarginals(self, set(keys))

    def information(self, scale: dict) -> np.ndarray:
        """The Schur complement were each source's information (its factors' whitened ``A^T A``)
        multiplied by ``scale[source]`` (1 for a source not named): what the global variables would
        know with that source's noise scaled by ``scale ** -0.5``. ``information({})`` is ``S``."""
        H = sum(scale.get(src, 1.0) * Hs for src, Hs in self.H_src.items())
        if not self.locals_:
            return 0.5 * (H + H.T)
        Hll = sum(scale.get(src, 1.0) * Hs for src, Hs in self.Hll_src.items())
        Hlg = sum(scale.get(src, 1.0) * Hs for src, Hs in self.Hlg_src.items())
        H = H - _reduction(np.linalg.inv(Hll), Hlg)
        return 0.5 * (H + H.T)

    def step_gain(self, free: list) -> float:
        """Decrease of the linearised cost by the Gauss-Newton step of the global variables ``free``
        (keys) with the locals re-fitted and every other global variable held."""
        idx = np.concatenate([np.arange(self.index[k].start, self.index[k].stop) for k in free])
        g = self.g[idx]
        return 0.5 * float(g @ np.linalg.solve(self.S[np.ix_(idx, idx)], g))

    def step(self, free: list) -> dict:
        """The Gauss-Newton step of the global variables ``free`` (others held): key -> (d,)."""
        idx = np.concatenate([np.arange(self.index[k].start, self.index[k].stop) for k in free])
        d = -np.linalg.solve(self.S[np.ix_(idx, idx)], self.g[idx])
        out, n = {}, 0
        for k in free:
            m = self.index[k].stop - self.index[k].start
            out[k] = d[n:n + m]
            n += m
        return out


def _reduction(Hll_inv: np.ndarray, Hlg: np.ndarray) -> np.ndarray:
    """sum over the locals of ``Hlg_l^T Hll_l^-1 Hlg_l`` (n, n): what eliminating them takes from the
    globals' information (one matrix product over all the locals' rows)."""
    L, d, n = Hlg.shape
    return Hlg.reshape(L * d, n).T @ (Hll_inv @ Hlg).reshape(L * d, n)


def linearise_graph(graph, values) -> Linear:
    """The Schur-reduced information of a solved graph (see the module docstring).

    Each factor's ``A^T A`` is formed once with its local variable's columns first (a factor has at
    most one local variable); factors of one source on the same global keys are summed before their
    blocks are scattered, and the locals are eliminated all at once."""
    lin = graph.linearize(values)
    zero = values.zeroVectors()
    keys_all = list(values.keys())
    dims = {k: zero.at(k).shape[0] for k in keys_all}
    chars = {k: chr(gtsam.Symbol(k).chr()) for k in keys_all}
    glob = [k for k in keys_all if chars[k] not in LOCAL]
    index, n = {}, 0
    for k in glob:
        index[k] = slice(n, n + dims[k])
        n += dims[k]
    loc_keys = [k for k in keys_all if chars[k] in LOCAL]
    locals_ = {k: i for i, k in enumerate(loc_keys)}
    d = max([dims[k] for k in loc_keys], default=6)
    if any(dims[k] != d for k in loc_keys):
        raise ValueError("linearise_graph: the local variables must share one tangent dimension")
    raw, groups, shapes = [], {}, {}
    for i in range(lin.size()):
        f = lin.at(i)
        if f is None:
            continue
        keys = f.keys()
        A, b = f.jacobian()
        shape = shapes.get(tuple(keys))
        if shape is None:  # the factor's source, dims, group and where its local's columns start
            loc = [j for j, k in enumerate(keys) if k in locals_]
            kd = [dims[k] for k in keys]
            src = _source_of(keys, chars)
            gl = tuple(k for k in keys if k in index)
            shape = shapes[tuple(keys)] = (src, kd, (src, gl, bool(loc)), sum(kd[:loc[0]]) if loc else None,
                                           locals_[keys[loc[0]]] if loc else -1)
        src, kd, key, start, lid = shape
        raw.append((src, list(keys), A, kd))
        if start:  # the local's columns first
            A = np.concatenate([A[:, start:start + d], A[:, :start], A[:, start + d:]], axis=1)
        grp = groups.get(key)
        if grp is None:
            grp = groups[key] = ([], [], [])
        grp[0].append(A.T @ A)
        grp[1].append(A.T @ b)
        grp[2].append(lid)
    H_src = {src: np.zeros((n, n)) for src in SOURCES}
    Hll_src, Hlg_src = {}, {}
    grad, g_l = np.zeros(n), np.zeros((len(loc_keys), d))
    prior_K = {}
    ar = np.arange(d)
    for (src, gl, has_local), (AtA, Atb, lid) in groups.items():
        AtA, Atb, lid = np.array(AtA), np.array(Atb), np.array(lid)
        cols = np.concatenate([np.arange(index[k].start, index[k].stop) for k in gl]) if gl else np.zeros(0, int)
        o = d if has_local else 0
        H_src[src][np.ix_(cols, cols)] += AtA[:, o:, o:].sum(axis=0)
        grad[cols] -= Atb[:, o:].sum(axis=0)
        if src == "intrinsics" and len(gl) == 1 and chars[gl[0]] == "k":
            prior_K[gl[0]] = AtA[:, o:, o:].sum(axis=0)
        if not has_local:
            continue
        if src not in Hll_src:
            Hll_src[src] = np.zeros((len(loc_keys), d, d))
        np.add.at(Hll_src[src], lid, AtA[:, :d, :d])
        np.add.at(g_l, lid, -Atb[:, :d])
        if len(cols):
            if src not in Hlg_src:
                Hlg_src[src] = np.zeros((len(loc_keys), d, n))
            np.add.at(Hlg_src[src], (lid[:, None, None], ar[None, :, None], cols[None, None, :]), AtA[:, :d, d:])
    H = sum(H_src.values())
    Hll = sum(Hll_src.values()) if Hll_src else np.zeros((0, d, d))
    Hlg = sum(Hlg_src.values()) if Hlg_src else np.zeros((len(loc_keys), d, n))
    Hll_inv = np.linalg.inv(Hll) if len(loc_keys) else Hll
    if len(loc_keys):
        H = H - _reduction(Hll_inv, Hlg)
        grad -= np.einsum("lan,la->n", Hlg, np.einsum("lab,lb->la", Hll_inv, g_l))
    return Linear(raw, index, locals_, 0.5 * (H + H.T), grad, prior_K, H_src, Hll_src, Hlg_src, Hll_inv, Hlg)


def columns(L: Linear, S: np.ndarray, wanted: list) -> dict:
    """Columns of the full covariance (from the global information ``S``): ``wanted`` is a list of
    (key, slice of its rows); returns variable -> (d, m), the m columns in the order asked."""
    m = sum(r.stop - r.start for _, r in wanted)
    e = np.zeros((S.shape[0], m))
    j = 0
    for key, rows in wanted:
        start = L.index[key].start
        n = rows.stop - rows.start
        e[start + rows.start: start + rows.stop, j:j + n] = np.eye(n)
        j += n
    Xg = np.linalg.solve(S, e)
    X = {k: Xg[s] for k, s in L.index.items()}
    if L.locals_:
        X_loc = -(L.Hll_inv @ (L.Hlg @ Xg))  # (L, d, m)
        X.update({k: X_loc[i] for k, i in L.locals_.items()})
    return X


def sigma_with(L: Linear, cam_key, S: np.ndarray | None = None, add_info: dict | None = None,
               cov: np.ndarray | None = None) -> float:
    """sqrt(trace) of the translation covariance (mm) of the camera pose ``cam_key``, from the
    information ``S`` (default: the graph's) with ``add_info`` (key -> information to add) added.
    Only the global system is solved: the camera is a global variable. ``cov``: the inverse of ``S``
    when the caller has it (one inverse serves every camera); the added information then enters as
    a low-rank update of it, ``Sigma' = Sigma - Sigma_tI (I + D Sigma_II)^-1 D Sigma_It``."""
    if cov is None:
        cov = L.covariance if S is None else _inverse(S)
    rows = np.arange(L.index[cam_key].start, L.index[cam_key].stop)[TRANSLATION]
    X = cov[np.ix_(rows, rows)]
    if add_info:
        idx = np.concatenate([np.arange(L.index[k].start, L.index[k].stop) for k in add_info])
        D = np.zeros((len(idx), len(idx)))
        n = 0
        for dH in add_info.values():
            m = dH.shape[0]
            D[n:n + m, n:n + m] = dH
            n += m
        C_tI, C_II = cov[np.ix_(rows, idx)], cov[np.ix_(idx, idx)]
        X = X - C_tI @ np.linalg.solve(np.eye(len(idx)) + D @ C_II, D @ C_tI.T)
    return 1e3 * float(np.sqrt(max(np.trace(X), 0.0)))


def _inverse(S: np.ndarray) -> np.ndarray:
    """The covariance of an information matrix (symmetrised)."""
    C = np.linalg.inv(S)
    return 0.5 * (C + C.T)


class ReducedMarginals:
    """The marginals a :class:`~calibgraph.solver.fit.graph.Marginals` gives, from a :class:`Linear`:
    the global variables' joint covariance is ``S^-1``; a local variable's adds what it does not
    share, ``H_ll^-1 + H_ll^-1 H_lg Sigma_gg H_gl H_ll^-1``."""

    def __init__(self, L: Linear, keys: set):
        np.linalg.cholesky(L.S)  # LinAlgError when the graph leaves a direction undetermined
        self._L, self._keys = L, keys

    def _rows(self, keys) -> np.ndarray:
        return np.concatenate([np.arange(self._L.index[k].start, self._L.index[k].stop) for k in keys])

    def marginalCovariance(self, key) -> np.ndarray:  # noqa: N802 - mirrors gtsam.Marginals
        L = self._L
        if key in L.index:
            r = self._rows([key])
            return L.covariance[np.ix_(r, r)]
        return L.local_covariances[L.locals_[key]]

    def has(self, key) -> bool:
        """True when ``key`` is a variable of the graph."""
        return key in self._keys

    def joint(self, keys) -> np.ndarray:
        """Joint covariance of the global variables ``keys``, in the order given."""
        r = self._rows(list(keys))
        return self._L.covariance[np.ix_(r, r)]
