"""Incremental calibration on iSAM2: ``add_capture`` -> updated estimate (and 1-sigma) while capturing.

The graph is the batch graph (:mod:`calibgraph.solver.fit.graph`) grown one capture at a time. Until the
board mount can be initialised (views from several board orientations), captures are buffered;
then the robust initialiser runs once on the buffer, and every later view either joins the graph
(its camera is initialised) or waits in its camera's buffer until that camera has enough views
for a consensus pose given the current mount. A new view far from the current estimate is gated
out with a reason instead of corrupting the graph. Weak priors on camera and mount poses keep
iSAM2's partial systems well-posed; they are 1 rad / 10 m wide and do not bias the answer.
Corner weights are fixed (no IRLS), so the batch solver remains the reference for the final
result; this path is for live feedback.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from calibgraph.core.errors import InputError
from calibgraph.core.problem import Capture, SolverOptions
from calibgraph.core.transforms import inv
from calibgraph.solver.uncertainty.covariance import to_ref_axes
from calibgraph.solver.terms.factors import fk_noise, make_view_factor, project_chain
from calibgraph.solver.terms.initialise import (
    ViewCandidates,
    camera_from_mount,
    pnp_candidates,
    rotation_spread_deg,
)
from calibgraph.solver.terms.keys import B, C, F
from calibgraph.solver.output.result import sigmas_from_cov
from calibgraph.solver.fit.start import best_initial_guess
from calibgraph.solver.terms.views import MIN_CORNERS_PER_VIEW, View

WEAK_PRIOR = gtsam.noiseModel.Diagonal.Sigmas(np.array([1.0, 1.0, 1.0, 10.0, 10.0, 10.0]))


@dataclass(frozen=True)
class CameraEstimate:
    T_ref_cam: np.ndarray
    covariance: np.ndarray | None
    views: int

    @property
    def sigma_translation_mm(self):
        return None if self.covariance is None else sigmas_from_cov(self.covariance)[0]

    @property
    def sigma_rotation_deg(self):
        return None if self.covariance is None else sigmas_from_cov(self.covariance)[1]


@dataclass(frozen=True)
class IncrementalEstimate:
    """State after a capture: cameras initialised so far, the mount, and what waits or was gated."""

    cameras: dict
    T_mount_board: np.ndarray | None
    pending: dict  # camera -> buffered views
    gated: tuple  # (camera, capture, reason)
    update_time_s: float


@dataclass
class IncrementalSolver:
    """Live calibration. Usage::

        inc = IncrementalSolver(points_board_m, cameras)
        est = inc.add_capture(capture, detections)   # after every robot pose
    """

    points_board_m: np.ndarray
    cameras: dict
    mode: str = "eye_to_hand"
    options: SolverOptions = field(default_factory=SolverOptions)
    pixel_sigma_px: float = 0.5
    with_covariance: bool = True
    min_views_init: int = 5

    def __post_init__(self):
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        self._isam = gtsam.ISAM2(params)
        self._slots = {n: i for i, n in enumerate(self.cameras)}
        self._cam_ready: set = set()
        self._views_in_graph: dict = {n: 0 for n in self.cameras}
        self._pending: dict = {n: [] for n in self.cameras}  # (Capture, Detection, ViewCandidates)
        self._fk_in_graph: set = set()
        self._gated: list = []
        self._initialised = False
        self._estimate = gtsam.Values()
        if self.options.pixel_sigma_px:
            self.pixel_sigma_px = self.options.pixel_sigma_px

    # -- helpers -------------------------------------------------------------------------------
    def _T_ref_mount(self, cap: Capture) -> np.ndarray:
        """The robot pose of ``cap`` as the graph's F(k): T_base_flange, or T_flange_base in eye-in-hand."""
        return cap.T_base_flange if self.mode == "eye_to_hand" else inv(cap.T_base_flange)

    def _view_factor(self, cap, det):
        p = self.points_board_m[det.ids]
        sw = np.full(len(det.ids), 1.0 / self.pixel_sigma_px)
        return make_view_factor(C(self._slots[det.camera]), F(cap.index), B(0), p, det.uv_px, self.cameras[det.camera], sw)

    def _add_views(self, graph, values, items):
        for cap, det, _ in items:
            if cap.index not in self._fk_in_graph and not values.exists(F(cap.index)):
                T_ref_mount = self._T_ref_mount(cap)
                graph.add(gtsam.PriorFactorPose3(F(cap.index), gtsam.Pose3(T_ref_mount),
                                                 fk_noise(self.options, self.mode, T_ref_mount)))
                values.insert(F(cap.index), gtsam.Pose3(T_ref_mount))
            graph.add(self._view_factor(cap, det))
            self._views_in_graph[det.camera] += 1

    def _try_initialise(self):
        items = [it for n in self.cameras for it in self._pending[n]]
        if len(items) < self.min_views_init:
            return False
        s1, s2 = rotation_spread_deg([self._T_ref_mount(c) for c, _, _ in items])
        if s2 < 2.0:
            return False
        by_cam = {}
        for cap, det, vc in items:
            by_cam.setdefault(det.camera, []).append(vc)
        views = [View(camera=det.camera, capture=cap.index, ids=det.ids, p_board_m=self.points_board_m[det.ids],
                      uv_px=det.uv_px, T_ref_mount=self._T_ref_mount(cap)) for cap, det, _ in items]
        try:
            T0, mounts = best_initial_guess(self.cameras, views, by_cam, joint=True, seed=0)
        except Exception:  # noqa: BLE001 - not enough consistent views yet; keep buffering
            return False
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        values.insert(B(0), gtsam.Pose3(mounts[0]))
        graph.add(gtsam.PriorFactorPose3(B(0), gtsam.Pose3(mounts[0]), WEAK_PRIOR))
        self._mount0 = mounts[0]
        for name, T in T0.items():
            if len(by_cam.get(name, [])) < 3:
                continue
            values.insert(C(self._slots[name]), gtsam.Pose3(T))
            graph.add(gtsam.PriorFactorPose3(C(self._slots[name]), gtsam.Pose3(T), WEAK_PRIOR))
            self._cam_ready.add(name)
            self._add_views(graph, values, self._pending[name])
            self._pending[name] = []
        self._isam.update(graph, values)
        self._fk_in_graph |= {k for k in self._keys_F(values)}
        self._initialised = True
        return True

    @staticmethod
    def _keys_F(values):
        out = []
        for key in values.keys():
            s = gtsam.Symbol(key)
            if chr(s.chr()) == "f":
                out.append(s.index())
        return out

    def _gate(self, cap, det) -> str | None:
        T_ref_cam = self._estimate.atPose3(C(self._slots[det.camera])).matrix()
        T_mount_board = self._estimate.atPose3(B(0)).matrix()
        uv = project_chain(T_ref_cam, self._T_ref_mount(cap), T_mount_board, self.points_board_m[det.ids],
                           self.cameras[det.camera])
        rms = float(np.sqrt(np.nanmean(np.sum((uv - det.uv_px) ** 2, axis=1))))
        limit = max(10.0, 20.0 * self.pixel_sigma_px)
        if not np.isfinite(rms) or rms > limit:
            return f"view disagrees with the current estimate (rms {rms:.1f} px > {limit:.1f} px)"
        return None

    # -- public ----------------------------------------------------------------------------------
    def add_capture(self, capture: Capture, detections) -> IncrementalEstimate:
        """Add one robot pose and its detections; returns the updated estimate."""
        t0 = time.perf_counter()
        items = []
        for det in detections:
            if det.camera not in self.cameras:
                raise InputError(f"incremental: detection for unknown camera {det.camera!r}.")
            if det.capture != capture.index:
                raise InputError(f"incremental: detection of capture {det.capture} passed with capture {capture.index}.")
            if len(det.ids) < MIN_CORNERS_PER_VIEW:
                self._gated.append((det.camera, capture.index, f"only {len(det.ids)} corners"))
                continue
            R, t, rms = pnp_candidates(self.points_board_m[det.ids], det.uv_px, self.cameras[det.camera])
            if len(R) == 0:
                self._gated.append((det.camera, capture.index, "no valid PnP solution"))
                continue
            items.append((capture, det, ViewCandidates(det.camera, capture.index, self._T_ref_mount(capture), R, t, rms)))
        if not self._initialised:
            for it in items:
                self._pending[it[1].camera].append(it)
            self._try_initialise()
        else:
            graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
            ready = []
            for it in items:
                name = it[1].camera
                if name in self._cam_ready:
                    reason = self._gate(it[0], it[1])
                    if reason:
                        self._gated.append((name, capture.index, reason))
                    else:
                        ready.append(it)
                else:
                    self._pending[name].append(it)
                    if len(self._pending[name]) >= 3:
                        T_mount_board = self._estimate.atPose3(B(0)).matrix()
                        T, n_agree = camera_from_mount([x[2] for x in self._pending[name]], T_mount_board)
                        if T is not None and n_agree >= 3:
                            values.insert(C(self._slots[name]), gtsam.Pose3(T))
                            graph.add(gtsam.PriorFactorPose3(C(self._slots[name]), gtsam.Pose3(T), WEAK_PRIOR))
                            self._cam_ready.add(name)
                            ready += self._pending[name]
                            self._pending[name] = []
            if ready:
                self._add_views(graph, values, ready)
                self._isam.update(graph, values)
                self._fk_in_graph.add(capture.index)
                for k in self._keys_F(values):
                    self._fk_in_graph.add(k)
        if self._initialised:
            self._estimate = self._isam.calculateEstimate()
        return self._snapshot(time.perf_counter() - t0)

    def _snapshot(self, dt) -> IncrementalEstimate:
        cams = {}
        mount = None
        if self._initialised:
            mount = self._estimate.atPose3(B(0)).matrix()
            for name in (n for n in self.cameras if n in self._cam_ready):  # declared order: runs repeat exactly
                T = self._estimate.atPose3(C(self._slots[name])).matrix()
                cov = None
                if self.with_covariance:
                    cov = to_ref_axes(T, self._isam.marginalCovariance(C(self._slots[name])))
                cams[name] = CameraEstimate(T, cov, self._views_in_graph[name])
        return IncrementalEstimate(cameras=cams, T_mount_board=mount,
                                   pending={n: len(v) for n, v in self._pending.items() if v},
                                   gated=tuple(self._gated), update_time_s=dt)
