"""The views of a solve: one camera's corners in one capture, with the robot pose of the capture.

A :class:`View` is what the graph turns into a projection factor. It is frozen: the robust rounds
(:mod:`calibgraph.solver.fit.robust`) return new views with new corner weights rather than editing
them, so every stage can be read as values in, values out.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from calibgraph.core.problem import Problem
from calibgraph.core.transforms import inv
from calibgraph.solver.terms.initialise import ViewCandidates, pnp_candidates
from calibgraph.solver.output.result import RejectedView

MIN_CORNERS_PER_VIEW = 4


@dataclass(frozen=True)
class View:
    """One camera's detections in one capture, as the solver uses them.

    ``w`` (N,) are the corners' robust weights in [0, 1] (0: rejected corner); ``active`` says
    whether the view is in the graph, ``reason`` why not; ``noise_scale`` is its camera's corner
    noise over the solve's reference pixel sigma (cameras differ: a Kinect's corners scatter
    several times a close L515's) and ``view_noise`` this view's over its camera's (a far, small or
    blurred board's corners scatter more than a near one's), so a corner's sigma is
    ``sigma_px * noise_scale * view_noise / sqrt(w)``.
    """

    camera: str
    capture: int
    ids: np.ndarray  # (N,) corner ids
    p_board_m: np.ndarray  # (N, 3) corners in the board frame
    uv_px: np.ndarray  # (N, 2) detected corners
    T_ref_mount: np.ndarray  # (4, 4) robot pose of the capture from forward kinematics (the prior)
    w: np.ndarray = field(default=None, repr=False)  # (N,) robust weights; None: all 1
    active: bool = True
    reason: str = ""
    noise_scale: float = 1.0
    view_noise: float = 1.0
    # the sign of the board normal's z in the camera frame at the view's best PnP pose (-1: the board
    # seen from behind); None: not known (computed where needed)
    facing: float | None = None

    def __post_init__(self):
        if self.w is None:
            object.__setattr__(self, "w", np.ones(len(self.ids)))

    @cached_property
    def kept(self) -> np.ndarray:
        """(N,) True for the corners with a non-zero weight (computed once: a view's ``w`` is not
        changed in place, a new view is made)."""
        return self.w > 0

    def evolve(self, **changes) -> "View":
        """``dataclasses.replace(self, **changes)`` without running ``__init__`` again (the robust
        rounds make thousands per round); ``w``, when changed, must be an array."""
        new = object.__new__(type(self))
        new.__dict__.update(self.__dict__)
        if "w" in changes:
            new.__dict__.pop("kept", None)
        new.__dict__.update(changes)
        return new

    @property
    def weight(self) -> np.ndarray:
        """(N,) the corners' weights in the graph: the robust weight over the view's sigma scale squared."""
        return self.w / self.sigma_scale ** 2

    @property
    def sigma_scale(self) -> float:
        """This view's corner sigma over the solve's reference pixel sigma: its camera's ``noise_scale``
        times its own ``view_noise``."""
        return self.noise_scale * self.view_noise


def robot_prior_poses(problem: Problem) -> dict:
    """capture -> T_ref_mount as forward kinematics reports it (the prior of F(k))."""
    if problem.mode == "eye_to_hand":
        return {c.index: c.T_base_flange for c in problem.captures}
    return {c.index: inv(c.T_base_flange) for c in problem.captures}


def prepare_views(problem: Problem) -> tuple[list, list]:
    """(views, rejected): the problem's detections as :class:`View` s, and those with fewer than
    MIN_CORNERS_PER_VIEW corners as :class:`RejectedView` s."""
    robot_poses = robot_prior_poses(problem)
    views, rejected = [], []
    for d in problem.detections:
        if len(d.ids) < MIN_CORNERS_PER_VIEW:
            rejected.append(RejectedView(d.camera, d.capture, f"only {len(d.ids)} corners (need {MIN_CORNERS_PER_VIEW})"))
            continue
        views.append(View(camera=d.camera, capture=d.capture, ids=d.ids, p_board_m=problem.points_board_m[d.ids],
                          uv_px=d.uv_px, T_ref_mount=robot_poses[d.capture]))
    return views, rejected


def view_candidates(problem: Problem, views: list) -> tuple[dict, list]:
    """(camera -> [ViewCandidates], views without a valid PnP solution): both IPPE poses of every view."""
    out, bad = {}, []
    for v in views:
        R, t, rms = pnp_candidates(v.p_board_m, v.uv_px, problem.cameras[v.camera])
        if len(R) == 0:
            bad.append(v)
            continue
        out.setdefault(v.camera, []).append(ViewCandidates(v.camera, v.capture, v.T_ref_mount, R, t, rms))
    return out, bad


def usable_views(problem: Problem) -> tuple[list, dict, list]:
    """(views, their PnP candidates by camera, refused views): views need enough corners and a PnP solution."""
    views, rejected = prepare_views(problem)
    cands, bad = view_candidates(problem, views)
    for v in bad:
        rejected.append(RejectedView(v.camera, v.capture, "no valid PnP solution (corners degenerate or ids wrong)"))
    bad_ids = {id(v) for v in bad}
    good = [v for v in views if id(v) not in bad_ids]
    # each view's candidates, in the order view_candidates met them: its side of the board
    firsts = {name: iter(vs) for name, vs in cands.items()}
    return [replace(v, facing=float(np.sign(next(firsts[v.camera]).R[0][2, 2]))) for v in good], cands, rejected


def captures_by_camera(views: list) -> dict:
    """camera -> captures of its views (what the observability check counts)."""
    out = {}
    for v in views:
        out.setdefault(v.camera, []).append(v.capture)
    return out


def reprojections(views: list, T_ref_cam: dict, T_mount_board: np.ndarray, T_ref_mount: dict, cameras: dict,
                  board_scale: float = 1.0) -> list:
    """Reprojected corners (px, (N, 2) per view) of ``views`` at the given values, batched per camera:
    one projection call per camera instead of one per view. ``T_ref_mount``: capture -> robot pose
    (a capture missing there is taken at its FK pose); ``cameras``: name -> Intrinsics to project with."""
    out = [None] * len(views)
    by_cam = {}
    for i, v in enumerate(views):
        by_cam.setdefault(v.camera, []).append(i)
    for cam, idx in by_cam.items():
        T_cs = inv(T_ref_cam[cam])
        pts, counts = [], []
        for i in idx:
            v = views[i]
            T = T_cs @ T_ref_mount.get(v.capture, v.T_ref_mount) @ T_mount_board
            pts.append((board_scale * v.p_board_m) @ T[:3, :3].T + T[:3, 3])
            counts.append(len(v.ids))
        uv_hat = cameras[cam].project(np.concatenate(pts))
        for i, part in zip(idx, np.split(uv_hat, np.cumsum(counts)[:-1])):
            out[i] = part
    return out


def residual_norms(views: list, T_ref_cam: dict, T_mount_board: np.ndarray, T_ref_mount: dict, cameras: dict,
                   board_scale: float = 1.0) -> list:
    """Residual norms (px, (N,) per view) of ``views`` at the given values (see :func:`reprojections`;
    a corner that does not project counts as 1e6 px)."""
    uv_hats = reprojections(views, T_ref_cam, T_mount_board, T_ref_mount, cameras, board_scale)
    return norms_of([uv_hat - v.uv_px for v, uv_hat in zip(views, uv_hats)])


def norms_of(residuals: list) -> list:
    """Residual norms (px, (N,) per view) of residuals ((N, 2) per view); a corner that does not
    project counts as 1e6 px."""
    out = []
    for d in residuals:
        r = np.linalg.norm(d, axis=1)
        out.append(np.where(np.isfinite(r), r, 1e6))
    return out


def robot_keys(problem, views) -> dict:
    """capture -> (the capture whose robot pose F the graph gives it, the fixed offset D (4, 4) of its
    reported pose from that one's, or None) for the captures of the active ``views``. A capture that
    revisits a configuration (:attr:`Problem.configurations`) shares the robot pose of the first active
    capture of its configuration: a real arm's absolute error repeats with its joint configuration, so
    a revisit is not a second, independent draw of it (T_ref_mount = F D, D from the reported poses)."""
    config = problem.configurations
    T_fk = {v.capture: v.T_ref_mount for v in views}
    first, out = {}, {}
    for k in sorted({v.capture for v in views if v.active}):
        r = first.setdefault(config.get(k, k), k)
        out[k] = (r, None if r == k else np.linalg.inv(T_fk[r]) @ T_fk[k])
    return out
