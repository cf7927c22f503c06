"""What an autonomous run (:mod:`calibgraph.acquire.auto`) knows, and its journal.

:class:`AutoState` holds the station it captures with, the live iSAM2 solver fed with every
capture, the batch solve of the captures so far (the reference the stop rule and the planner
use), what the survey learnt about each camera (first views, PnP candidates, refuted mirror
positions) and the journal of steps, rewritten after every step.

Files in ``out_dir`` (a ``calibgraph-dataset/1``, solvable by ``calibgraph solve`` at any time):

- ``captures/NNNNNN.json`` and ``images/<camera>/NNNNNN.png`` as always: step k is capture k;
- ``plan_log.json`` (``calibgraph-plan-log/1``), the journal: per step the pose, the phase, why it
  was chosen, the cameras expected and those that saw the board, predicted and achieved 1-sigma
  per camera (mm, deg), the motion time, the board centre of the capture (``board_centre_m``);
  active steps add the best candidates of the choice (``candidates``: board centre, score = gain
  per second, gain; best first, at most 20), ``chosen_candidate`` (its index there) and
  ``chosen_board_centre_m``, which the rerun recording shows; ``out_of_reach``: the cameras given
  up, each with the capture it was given up at, the captures then left, its 1-sigma then and the
  best 1-sigma the bound allowed (``best_possible``, mm and deg; 0 where not bounded); rewritten
  atomically after each step's capture file;
- ``result.json``: the batch solve at the stop.

Resume (``resume=True``) after a kill at any instant: captures on disk are replayed into the
solver (a capture written just before the kill but missing from the log is recovered), survey
stops already done are not repeated, and the loop carries on from the robot's actual joints.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from calibgraph.acquire.loop import Station, Visit
from calibgraph.core.errors import CalibgraphError
from calibgraph.core.problem import Capture, Detection
from calibgraph.io.files import atomic_write_text, read_input_bytes
from calibgraph.io.layouts import load_dataset
from calibgraph.plan.active import CameraBelief, keepout_violation, motion_time_s, shortfall, sigma_norms
from calibgraph.plan.information import intrinsics_prior
from calibgraph.plan.planner import free_motion
from calibgraph.solver.solve.batch import solve
from calibgraph.solver.solve.build import build_problem
from calibgraph.solver.solve.incremental import IncrementalSolver
from calibgraph.solver.terms.initialise import pnp_candidates

__all__ = ["AutoState", "PLAN_LOG_FORMAT", "PLAN_LOG_NAME", "refuted_from_steps", "sigma_pair"]

PLAN_LOG_FORMAT = "calibgraph-plan-log/1"
PLAN_LOG_NAME = "plan_log.json"


def sigma_pair(cov):
    """[1-sigma translation norm mm, rotation norm deg] of a 6x6 pose covariance, or None."""
    return None if cov is None else [round(v, 4) for v in sigma_norms(cov)]


def refuted_from_steps(steps) -> dict:
    """camera -> [camera positions (3,)] that a facing stop refuted, from the journaled steps."""
    out = {}
    for s in steps:
        r = s.get("refutes")
        if isinstance(r, dict) and isinstance(r.get("camera"), str):
            try:
                pos = np.asarray(r["position_m"], float).reshape(3)
            except (KeyError, TypeError, ValueError):
                continue  # a damaged entry costs one repeated stop, not the resume
            if np.all(np.isfinite(pos)):
                out.setdefault(r["camera"], []).append(pos)
    return out


@dataclass
class AutoState:
    """What the autonomous run knows: the station it captures with, the live solver, the batch
    reference, the journal (``steps``) and what the survey learnt about each camera."""

    station: Station
    cell: object
    world: object
    opts: object  # calibgraph.acquire.auto.AutoOptions
    log: callable
    steps: list = field(default_factory=list)
    views_bb: dict = field(default_factory=dict)  # camera -> [T_base_board (nominal mount) of its views]
    first_view: dict = field(default_factory=dict)  # camera -> (T_base_board, R (m,3,3), t (m,3))
    pnp_views: dict = field(default_factory=dict)  # camera not placed -> [(T_base_board, R, t, rms)] of its views
    refuted: dict = field(default_factory=dict)  # camera -> camera positions a facing stop did not show the board to
    history: list = field(default_factory=list)  # per capture fed: (T_base_flange, cameras that saw the board)
    pixel_sigma_px: float | None = None
    cov_scale: dict = field(default_factory=dict)  # camera -> variance factor bringing iSAM2 to the batch 1-sigma
    est: object = None
    ref: object = None  # the batch Result of the captures so far (None: stale or failed), see refresh()
    ref_at: int = -1  # n_captures when ``ref`` was solved
    messages: list = field(default_factory=list)
    final: object = None  # the batch Result the loop converged on
    out_of_reach: dict = field(default_factory=dict)  # camera given up -> the bound that said so (journaled)
    reach_strikes: dict = field(default_factory=dict)  # camera -> choices in a row its bound was out of tolerance
    accept: object = None  # result -> {camera: [reasons]} it fails the commissioning tolerances (run_auto's accept)

    @property
    def robot(self):
        return self.station.robot

    @property
    def intr(self) -> dict:
        return self.station.intr

    @property
    def lost(self) -> list:
        return self.station.lost

    @property
    def out(self) -> Path:
        return self.station.out

    # -- solver ------------------------------------------------------------------------------------
    def new_solver(self):
        kw = {"pixel_sigma_px": self.pixel_sigma_px} if self.pixel_sigma_px else {}
        self.inc = IncrementalSolver(self.cell.target.points_board_m, dict(self.intr), **kw)
        self.est = None

    def feed(self, cap, dets):
        self.est = self.inc.add_capture(cap, dets)
        self.history.append((np.asarray(cap.T_base_flange, float), tuple(sorted({d.camera for d in dets}))))
        for d in dets:
            T_bb = cap.T_base_flange @ self.cell.T_flange_board
            self.views_bb.setdefault(d.camera, []).append(T_bb)
            if d.camera not in self.first_view or d.camera not in self.placed():
                R, t, rms = pnp_candidates(self.cell.target.points_board_m[d.ids], d.uv_px, self.intr[d.camera])
                if len(R):
                    self.first_view.setdefault(d.camera, (T_bb, R, t))
                    self.pnp_views.setdefault(d.camera, []).append((T_bb, R, t, rms))

    def replay(self):
        """Rebuild the solver from the capture files on disk (resume, or a new pixel sigma)."""
        self.new_solver()
        self.views_bb, self.first_view, self.history, self.pnp_views = {}, {}, [], {}
        for cap, dets in self.captures_on_disk():
            self.feed(cap, dets)

    def captures_on_disk(self):
        out = []
        for f in sorted((self.out / "captures").glob("*.json")):
            d = json.loads(read_input_bytes(f, "capture file"))
            cap = Capture(index=int(d["index"]), T_base_flange=np.asarray(d["T_base_flange"], float),
                          q_rad=None if d.get("q_rad") is None else np.asarray(d["q_rad"], float), stamp_s=d.get("stamp_s"))
            dets = []
            for c, v in (d.get("views") or {}).items():
                det = v.get("detection")
                if det and c in self.intr:
                    dets.append(Detection(camera=c, capture=cap.index, ids=np.asarray(det["ids"], int),
                                          uv_px=np.asarray(det["uv_px"], float)))
            out.append((cap, dets))
        return out

    def mount(self):
        if self.est is not None and self.est.T_mount_board is not None:
            return self.est.T_mount_board
        return self.cell.T_flange_board

    def cov(self, name):
        ce = self.est.cameras.get(name) if self.est else None
        if ce is None or ce.covariance is None:
            return None
        return ce.covariance * self.cov_scale.get(name, 1.0)

    def _ref_camera(self, name):
        """The batch solve's camera result when that solve covers every capture so far, else None."""
        if self.ref is None or self.ref_at != self.n_captures:
            return None
        return self.ref.cameras.get(name)

    def beliefs(self) -> dict:
        """What the planner knows per placed camera: the batch solve of every capture so far when there
        is one (pose and covariance marginal over the mount, board scale and intrinsics: the numbers the
        stop rule and ``result.json`` use), else iSAM2's, scaled to the last batch solve."""
        out = {}
        for n, ce in (self.est.cameras if self.est else {}).items():
            rc = self._ref_camera(n)
            if rc is not None and rc.calibrated:
                out[n] = CameraBelief(n, self.intr[n], rc.T_ref_cam, rc.covariance, ce.views, self._model_prior(n, rc))
            else:
                out[n] = CameraBelief(n, self.intr[n], ce.T_ref_cam, self.cov(n), ce.views, self._model_prior(n, None))
        return out

    def estimates(self) -> dict:
        """camera -> (T_base_cam, 1-sigma mm, deg) of :meth:`beliefs` (the live view's)."""
        return {n: (b.T_base_cam, *(sigma_pair(b.covariance) or (None, None))) for n, b in self.beliefs().items()}

    def _model_prior(self, name, rc):
        """The prior the batch solver puts on camera ``name``'s model (the wide one when its last
        solve found the given values contradicted by the views), None when it holds it known."""
        rec = (rc.intrinsics or {}) if rc is not None else {}
        return intrinsics_prior(self.intr[name], wide=rec.get("prior") == "wide")

    def sigmas(self) -> dict:
        """camera -> [1-sigma mm, deg] the loop works with (see :meth:`beliefs`)."""
        return {n: sigma_pair(b.covariance) for n, b in self.beliefs().items()}

    def refresh(self):
        """Batch-solve every capture so far (the views of a calibration are few, so this is quick) and
        make it the loop's reference: the stop rule and the next choice use its 1-sigma, and iSAM2 is
        re-scaled to it, since the ratio of the two changes as the board scale and mount get
        determined. Returns the result or None."""
        if self.ref_at == self.n_captures:
            return self.ref
        res, _ = self.batch_solve()
        self.ref, self.ref_at = res, self.n_captures
        if res is not None:
            self.calibrate_to(res)
        return res

    def calibrate_to(self, res):
        """Scale each camera's iSAM2 covariance so its shortfall matches the batch result ``res``:
        the batch solver (IRLS, estimated pixel noise) is the reference the stop rule trusts."""
        tol = (self.opts.tolerance_mm, self.opts.tolerance_deg)
        for n, c in res.cameras.items():
            ce = self.est.cameras.get(n) if self.est else None
            if ce is None or ce.covariance is None or not c.calibrated:  # no batch 1-sigma to scale to
                continue
            r_isam, r_batch = shortfall(ce.covariance, *tol), shortfall(c.covariance, *tol)
            if np.isfinite(r_isam) and r_isam > 0:
                self.cov_scale[n] = float(np.clip((r_batch / r_isam) ** 2, 0.25, 16.0))

    # -- journal -----------------------------------------------------------------------------------
    def save_log(self, stop=None):
        d = {"format": PLAN_LOG_FORMAT, "cell": self.cell.name, "cameras": list(self.intr),
             "options": {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.opts.__dict__.items()},
             "pixel_sigma_px": self.pixel_sigma_px, "cov_scale": self.cov_scale, "steps": self.steps,
             "messages": self.messages, "out_of_reach": self.out_of_reach}
        if stop is not None:
            d["stop"] = stop
        atomic_write_text(self.out / PLAN_LOG_NAME, json.dumps(d, indent=1))

    @property
    def n_captures(self) -> int:
        return sum(s["status"] in ("captured", "no_views", "recovered") for s in self.steps)

    def robot_time(self) -> float:
        return float(sum(s.get("motion_time_s", 0.0) for s in self.steps))

    def free(self, q) -> bool:
        """Keep-out round the estimated camera stands (checked for survey stops too)."""
        b = self.beliefs()
        if not b:
            return True
        T_bf = self.world.T_base_flange()
        T_bb = T_bf @ self.mount()
        tg = self.cell.target
        outline = tg.points_board_m[[0, tg.cols - 1, tg.n_points - tg.cols, tg.n_points - 1]]
        pts = np.vstack([T_bf[:3, 3], outline @ T_bb[:3, :3].T + T_bb[:3, 3]])
        return keepout_violation(pts, b, self.cell.floor_z_m) is None

    # -- one step ----------------------------------------------------------------------------------
    def step(self, phase: str, label: str, q_goal, why: str, expected=(), predicted=None, motion=None):
        """One visit of the acquisition loop: to ``q_goal`` through ``motion``'s vias (or a planned free
        motion), capture every live camera; journal it. A generator (``yield from`` it): yields the
        :class:`Visit`, returns the step dict."""
        k = len(self.steps)
        q_now = np.asarray(self.robot.joint_positions(), float)
        entry = {"step": k, "phase": phase, "label": label, "why": why, "q_rad": np.asarray(q_goal).tolist(),
                 "expected": list(expected), "predicted": predicted or {}, "sigma_before": self.sigmas()}
        if motion is None:
            motion = free_motion(self.world, q_now, q_goal)
        if motion is None:
            return self._skip(entry, "skipped_unreachable", "no collision-free motion in the planning world")
        o = yield Visit(k, tuple((np.asarray(q, float), None) for q in motion))
        t_motion, q = 0.0, q_now
        for qq in motion[:o.legs_done]:
            t_motion += motion_time_s(q, qq, self.opts.dq_max_rad_s, self.opts.speed_scale)
            q = qq
        self._note_lost()
        if o.status not in ("captured", "no_views"):
            return self._skip(entry, o.status, o.message, t_motion)
        entry["motion_time_s"] = round(t_motion, 3)
        entry["vias"] = len(motion) - 1
        entry["T_base_flange"] = o.T_base_flange.tolist()
        T_bb = o.T_base_flange @ self.mount()
        entry["board_centre_m"] = [round(float(v), 4) for v in T_bb[:3, :3] @ self.cell.target.points_board_m.mean(axis=0)
                                   + T_bb[:3, 3]]
        entry["seen_by"] = sorted(o.views)
        entry["rejected"] = dict(o.rejected)
        entry["status"] = o.status
        if o.capture is not None:
            try:
                self.feed(o.capture, list(o.detections))
            except Exception as e:  # the live estimate is advisory; the capture is safe on disk
                self.messages.append(f"step {k}: the live solver could not take the capture ({type(e).__name__}: {e})")
        self.steps.append(entry)
        if o.views and self.pixel_sigma_px is not None:  # past the survey: the batch solve is the reference
            self.refresh()
        entry["achieved"] = self.sigmas()
        self.save_log()
        self.log(self._line(entry))
        return entry

    def _note_lost(self):
        for c in self.lost:
            note = f"camera {c} lost (failed grabs); continuing without it"
            if c in self.station.intr and note not in self.messages:
                self.messages.append(note)

    def _skip(self, entry, status, msg, t_motion=0.0):
        entry.update(status=status, message=msg, motion_time_s=round(t_motion, 3), seen_by=[], achieved=self.sigmas())
        self.steps.append(entry)
        self.save_log()
        self.log(f"step {entry['step']} ({entry['label']}): {status.replace('_', ' ')}: {msg}")
        return entry

    def _line(self, e) -> str:
        s = ", ".join(f"{c} {v[0]:.2f} mm/{v[1]:.3f}°" for c, v in sorted(e["achieved"].items()) if v) or "no pose yet"
        seen = ", ".join(e["seen_by"]) or "no camera"
        return (f"step {e['step']} [{e['phase']}] {e['label']}: seen by {seen}; {e['motion_time_s']:.1f} s motion | 1σ {s}")

    def placed(self) -> set:
        """The cameras the live solver has placed."""
        return set(self.est.cameras) if self.est else set()

    def within(self, cov) -> bool:
        """A camera covariance within both tolerances."""
        return shortfall(cov, self.opts.tolerance_mm, self.opts.tolerance_deg) <= 1.0

    def file_failures(self, res) -> dict:
        """camera -> why the batch result ``res`` fails it against the commissioning tolerances (the
        file the report uses: views, reprojection, workspace 1σ, ...; ``accept``), for the cameras not
        given up as out of reach; {} when every one passes or no ``accept`` was given."""
        if self.accept is None or res is None:
            return {}
        return {n: list(r) for n, r in (self.accept(res) or {}).items() if r and n not in self.out_of_reach}

    def accepted(self, res) -> bool:
        """The stop rule: a converged batch solve in which every camera (but those out of reach) is
        within the 1σ tolerances and passes the commissioning tolerances."""
        return bool(res is not None and res.cameras and res.converged
                    and all(self.within(c.covariance) for n, c in res.cameras.items() if n not in self.out_of_reach)
                    and not self.file_failures(res))

    def batch_solve(self):
        """Batch solve of the dataset so far, over the cameras placed by the live solver (a camera
        never seen, or seen too little to place, would make the whole solve refuse)."""
        try:
            problem, _ = build_problem(load_dataset(self.out), "joint", None, progress=False)
            keep = self.placed() & set(problem.cameras)
            if not keep:
                return None, "no camera placed yet"
            if keep != set(problem.cameras):
                problem = problem.with_(cameras={c: i for c, i in problem.cameras.items() if c in keep},
                                        detections=tuple(d for d in problem.detections if d.camera in keep))
            return solve(problem, seed=self.opts.seed), None
        except CalibgraphError as e:
            return None, str(e)

    def reload(self) -> None:
        """Resume: the journaled steps, the solver replayed from the captures on disk (a capture written
        just before a kill, before its log entry, is recovered)."""
        d = json.loads(read_input_bytes(self.out / PLAN_LOG_NAME, "plan log"))
        self.steps = list(d.get("steps", []))
        self.refuted = refuted_from_steps(self.steps)
        self.pixel_sigma_px = d.get("pixel_sigma_px")
        self.cov_scale = dict(d.get("cov_scale") or {})
        self.messages = list(d.get("messages", []))
        self.out_of_reach = {str(c): dict(v) for c, v in (d.get("out_of_reach") or {}).items() if isinstance(v, dict)}
        logged = {s["step"] for s in self.steps}
        self.replay()
        for cap, dets in self.captures_on_disk():
            if cap.index not in logged:
                self.steps.append({"step": cap.index, "phase": "recovered", "label": f"capture {cap.index}",
                                   "why": "capture file found on resume", "status": "recovered",
                                   "seen_by": sorted(d.camera for d in dets), "motion_time_s": 0.0,
                                   "q_rad": None if cap.q_rad is None else cap.q_rad.tolist()})
        self.steps.sort(key=lambda s: s["step"])
        self.log(f"resume: {len(self.steps)} steps in the log, {self.n_captures} capture poses; cameras placed: "
                 f"{sorted(self.est.cameras) if self.est else []}")
