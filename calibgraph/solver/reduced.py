"""A solved graph linearised and reduced to its few global variables.

The per-capture robot poses (``f``; ``h`` in the corner formulation) are many and each couples only
to the global variables its factors touch (cameras, intrinsics, mount, scale, offsets), so they are
eliminated first (Schur complement). What remains is a small dense system from which any column of
the full covariance, and the Gauss-Newton step of any subset of the global variables, follows. The
error budget (:mod:`calibgraph.solver.budget`) and the test of exact intrinsics claims
(:mod:`calibgraph.solver.claims`) read it.
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
    c = _chars(keys)
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
    """A graph linearised at its values and reduced to its global variables."""

    factors: list  # (source, keys, {key: whitened Jacobian block A_key})
    index: dict  # global key -> slice in the global vector
    locals_: dict  # local key -> (H_ll^-1 (d, d), {global key: H_lg block})
    S: np.ndarray  # Schur complement: the information of the global variables, the locals eliminated
    g: np.ndarray  # the cost's gradient on the global variables with the locals at their optimum
    prior_K: dict  # K key -> its prior's information (6, 6)
    H_src: dict | None = None  # source -> its factors' global-global information (before the reduction)
    local_src: dict | None = None  # local key -> {source: (H_ll block, {global key: H_lg block})}

    @cached_property
    def covariance(self) -> np.ndarray:
        """``S^-1``: the joint covariance of the global variables (computed once)."""
        return _inverse(self.S)

    def marginals(self, keys) -> "ReducedMarginals":
        """Marginal covariances of the graph's variables (``keys``: all of them) from this reduction;
        raises LinAlgError when the information is not positive definite."""
        return ReducedMarginals(self, set(keys))

    def information(self, scale: dict) -> np.ndarray:
        """The Schur complement were each source's information (its factors' whitened ``A^T A``)
        multiplied by ``scale[source]`` (1 for a source not named): what the global variables would
        know with that source's noise scaled by ``scale ** -0.5``. ``information({})`` is ``S``."""
        H = sum(scale.get(src, 1.0) * Hs for src, Hs in self.H_src.items())
        for parts in self.local_src.values():
            Hll = sum(scale.get(src, 1.0) * p[0] for src, p in parts.items())
            lg = {}
            for src, (_, blocks) in parts.items():
                for g, Bg in blocks.items():
                    lg[g] = lg.get(g, 0) + scale.get(src, 1.0) * Bg
            if not lg:
                continue
            idx = np.concatenate([np.arange(self.index[g].start, self.index[g].stop) for g in lg])
            Bm = np.hstack([lg[g] for g in lg])
            H[np.ix_(idx, idx)] -= Bm.T @ np.linalg.solve(Hll, Bm)
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


def linearise_graph(graph, values) -> Linear:
    """The Schur-reduced information of a solved graph (see the module docstring)."""
    lin = graph.linearize(values)
    zero = values.zeroVectors()
    dims = {k: zero.at(k).shape[0] for k in values.keys()}
    glob = [k for k in values.keys() if chr(gtsam.Symbol(k).chr()) not in LOCAL]
    index, n = {}, 0
    for k in glob:
        index[k] = slice(n, n + dims[k])
        n += dims[k]
    H = np.zeros((n, n))
    grad = np.zeros(n)
    H_ll, H_lg, g_l = {}, {}, {}
    factors, prior_K = [], {}
    H_src = {src: np.zeros((n, n)) for src in SOURCES}
    local_src = {}
    for i in range(lin.size()):
        f = lin.at(i)
        if f is None:
            continue
        keys = list(f.keys())
        A, b = f.jacobian()
        blocks, cols, col = {}, {}, 0
        for k in keys:
            blocks[k] = A[:, col:col + dims[k]]
            cols[k] = slice(col, col + dims[k])
            col += dims[k]
        src = _source(keys)
        factors.append((src, keys, blocks))
        AtA, Atb = A.T @ A, A.T @ b  # one product per factor, its blocks scattered below
        if src == "intrinsics":
            prior_K[keys[0]] = AtA[cols[keys[0]], cols[keys[0]]]
        loc = [k for k in keys if k not in index]
        gl = [k for k in keys if k in index]
        Hs = H_src[src]
        for a in gl:
            grad[index[a]] -= Atb[cols[a]]
            for c in gl:
                Hs[index[a], index[c]] += AtA[cols[a], cols[c]]
        for l in loc:  # at most one local variable per factor
            g_l[l] = g_l.get(l, 0) - Atb[cols[l]]
            ll, lg = local_src.setdefault(l, {}).setdefault(src, [0, {}])
            local_src[l][src][0] = ll + AtA[cols[l], cols[l]]
            for g in gl:
                lg[g] = lg.get(g, 0) + AtA[cols[l], cols[g]]
    H += sum(H_src.values())
    for l, parts in local_src.items():
        H_ll[l] = sum(p[0] for p in parts.values())
        lg = H_lg.setdefault(l, {})
        for _, blocks in parts.values():
            for g, Bg in blocks.items():
                lg[g] = lg.get(g, 0) + Bg
    locals_ = {}
    for l, Hll in H_ll.items():
        inv = np.linalg.inv(Hll)
        locals_[l] = (inv, H_lg.get(l, {}))
        for a, Ba in H_lg.get(l, {}).items():
            grad[index[a]] -= Ba.T @ inv @ g_l[l]
            for c, Bc in H_lg[l].items():
                H[index[a], index[c]] -= Ba.T @ inv @ Bc
    return Linear(factors, index, locals_, 0.5 * (H + H.T), grad, prior_K, H_src, local_src)


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
    for loc, (inv, lg) in L.locals_.items():
        X[loc] = -inv @ sum(B @ X[g] for g, B in lg.items()) if lg else np.zeros((inv.shape[0], m))
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
    """The marginals a :class:`~calibgraph.solver.graph.Marginals` gives, from a :class:`Linear`:
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
        inv, lg = L.locals_[key]
        if not lg:
            return inv
        B = np.hstack([lg[g] for g in lg])
        r = self._rows(list(lg))
        return inv + inv @ B @ L.covariance[np.ix_(r, r)] @ B.T @ inv

    def has(self, key) -> bool:
        """True when ``key`` is a variable of the graph."""
        return key in self._keys

    def joint(self, keys) -> np.ndarray:
        """Joint covariance of the global variables ``keys``, in the order given."""
        r = self._rows(list(keys))
        return self._L.covariance[np.ix_(r, r)]
