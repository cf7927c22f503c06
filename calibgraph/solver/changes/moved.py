"""A camera knocked during capture: found, named, and solved as the two poses it had.

A fixed camera knocked between two captures has two poses in one dataset. Solved as one pose, its
views disagree, and the solve explains the disagreement with what every camera shares: a wider FK
prior, a board scale, a corner-noise factor, a camera model the data "contradict". The estimate
lands between the two poses and drags the other cameras with it. So the test comes first: right
after the robust rounds of a solve (:func:`check_after_rounds`, called by
:mod:`calibgraph.solver.solve.optimise`), before anything shared is widened, every camera's views are
tested for a change point in time against the other cameras held (:mod:`calibgraph.solver.changes.change_point`).
The camera with the clearest move is split: its views before the move become a camera of their own
(``"<name> (before the move)"``, same intrinsics), and the problem is solved again, tested again
(up to ``MAX_MOVED`` cameras). The two poses are never averaged: the result reports the camera as
it stood after the move, with the pose before it, its covariance and the displacement in
``CameraResult.moved``, and one note naming the camera, the captures between which it moved and by
how much. The shared parameters (mount, board scale, FK check, corner-noise model) are judged on a
model in which the camera's views agree.

A side with fewer views than ``min_views_per_camera`` is not solved: before the move, its views are
set aside (listed as rejected, with the reason); after it, the camera is reported as not calibrated
as it now stands, with the pose before the move when that side could be solved.

:func:`find_moves_live` runs the same test against a calibration already at hand (a stored result,
or the live estimate of a capture) for ``verify`` and the capture's live warning.
"""

from __future__ import annotations

from contextvars import ContextVar
from dataclasses import dataclass, field, replace

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import CalibgraphError, ObservabilityError
from calibgraph.core.transforms import pose_error
from calibgraph.solver.changes.change_point import Split, board_split, camera_splits
from calibgraph.solver.robot.fk_check import fk_variance_ratio
from calibgraph.solver.fit.graph import Estimate
from calibgraph.solver.terms.noise_model import robust_pixel_sigma
from calibgraph.solver.output.result import CameraResult, RejectedView
from calibgraph.solver.terms.views import prepare_views

MAX_MOVED = 3  # cameras split in one solve
BEFORE = " (before the move)"


@dataclass(frozen=True)
class Move:
    """A camera whose views split in capture order into two poses (``split`` has the test's figures)."""

    camera: str
    split: Split
    pseudo: str | None = None  # name of the camera holding the views before the move in the split solve

    @property
    def last_before(self) -> int:
        return self.split.captures_before[-1]

    @property
    def first_after(self) -> int:
        return self.split.captures_after[0]

    @property
    def back(self) -> bool:
        """Moved and moved back: its views after the span (``split.captures_back``) are where it was."""
        return bool(self.split.captures_back)

    def where(self) -> str:
        w = f"between captures {self.last_before} and {self.first_after}"
        if self.back:
            w += f" and back between captures {self.split.captures_after[-1]} and {self.split.captures_back[0]}"
        return w

    def span(self) -> str:
        """The captures of the views while it was moved (a moved-and-back camera)."""
        return f"captures {self.first_after}-{self.split.captures_after[-1]}"


@dataclass
class _Watch:
    """What :func:`solve_minding_moves` asks of the solves it runs."""

    skip: set = field(default_factory=set)  # cameras not to test (split already)
    active: bool = True
    board: bool = True  # a move the board explains better is the board's (off within a segment already cut)


_WATCH: ContextVar = ContextVar("calibgraph_solver_moved_watch", default=None)


class BoardMoved(Exception):
    """Raised inside a watched solve when the board, not a camera, moved (``split``: the board's
    split, its ``camera`` the camera whose views showed it); never leaves :func:`solve_minding_moves`."""

    def __init__(self, split: Split):
        super().__init__("board")
        self.split = split


class CameraMoved(Exception):
    """Raised inside a solve watched by :func:`solve_minding_moves` when a camera moved; never
    leaves :func:`solve_minding_moves`."""

    def __init__(self, move: Move):
        super().__init__(move.camera)
        self.move = move


def check_after_rounds(problem, views: list, start, rounds) -> None:
    """The hook after a graph's robust rounds: raise :class:`CameraMoved` for the camera whose views
    show the clearest move, when the solve is watched (``solve()``; ``solve_once`` is not).

    ``views``: every view the graph was given (those of cameras the rounds left out too), ``start``:
    the Estimate the rounds started from (poses of cameras they left out), ``rounds``: their Rounds."""
    watch = _WATCH.get()
    if watch is None or not watch.active:
        return
    names = [n for n in dict.fromkeys(v.camera for v in views) if n not in watch.skip]
    scales = robot_scales(problem, views, rounds)
    # min_after=1: a move before a camera's last view is never answered with the pose before it
    splits = camera_splits(problem, views, rounds.est, rounds.sigma_px, names, start.T_ref_cam, min_after=1,
                           robot_scales=scales)
    moves = sorted((s for s in splits.values() if s.is_move), key=lambda s: -s.f_stat)
    if moves:
        m = _explains_the_others(problem, views, start, rounds, moves) if len(moves) > 1 else moves[0]
        if watch.board:
            board = _board_explains(problem, rounds, m, scales)
            if board is not None:
                raise BoardMoved(board)
        raise CameraMoved(Move(m.camera, m))


def _board_explains(problem, rounds, m: Split, scales) -> Split | None:
    """The board's own split where it explains camera ``m.camera``'s views better than the camera's move
    ``m`` does (a larger likelihood ratio for the same 6 parameters, and a move by the same tests): a board
    knocked on its mount, or on the table, between two captures moves every camera's views, and one
    camera's views then read as a move of it that changes with the robot pose. None otherwise."""
    best, f_best = None, 1.0
    for f in scales:
        b = board_split(problem, rounds.views, rounds.est, rounds.sigma_px, m.camera, f)
        if b is not None and (best is None or b.log_likelihood > best.log_likelihood):
            best, f_best = b, f
    if best is None or not best.is_move or best.glr <= m.glr:
        return None
    # a board that moved moves every camera's views at that cut: each other camera with views on both sides
    # must show the same board move there (a knocked camera's views alone can read as a board that moved)
    cut = best.captures_after[0]
    for n in dict.fromkeys(v.camera for v in rounds.views if v.active and v.camera != m.camera):
        caps = [v.capture for v in rounds.views if v.active and v.camera == n]
        if sum(c < cut for c in caps) < 2 or sum(c >= cut for c in caps) < 2:
            continue
        other = board_split(problem, rounds.views, rounds.est, rounds.sigma_px, n, f_best, at_capture=cut)
        if other is None or not other.is_move:
            return None
    return best


def robot_scales(problem, views: list, rounds) -> tuple:
    """The factors on the stated FK sigmas the move test tries (:func:`~calibgraph.solver.changes.change_point.camera_splits`):
    1 where the robust rounds' fit finds the arm as accurate as stated; where it departs
    (:func:`~calibgraph.solver.robot.fk_check.fk_variance_ratio`), a geometric ladder from 1 to the factor that
    fit implies. A real arm's error, millimetres that repeat with its configuration where a Panda-class
    0.1 mm is stated, moves a camera's views as a knock would: judged against the stated accuracy alone,
    it is read as a move (a Franka's three sessions of the same 12 joint targets merged: 'moved by
    6.4 mm', where the sessions solved alone agree to 1.3 mm)."""
    ratio = fk_variance_ratio(problem, [v for v in rounds.views if v.camera in rounds.est.T_ref_cam], rounds.est,
                              rounds.sigma_px)
    if ratio is None or not ratio.widens:
        return (1.0,)
    top = float(np.sqrt(ratio.applied))
    n = max(2, int(np.ceil(np.log2(top))) + 1)
    return tuple(float(x) for x in np.geomspace(1.0, top, n))


def _explains_the_others(problem, views: list, start, rounds, moves: list) -> Split:
    """Of several cameras whose views show a move, the one to split first: the one whose views, left
    out of the robot poses, take the most of the other moves away (the clearest move on a tie).

    Each camera is tested against the robot poses the *other* cameras' views give; a knocked camera's
    views pull the poses of the captures it shares, and a still camera that shares them can show a
    false move over those captures (a rendered cell: a 5 mm knock of cam0 made cam1 show a "moved and
    moved back" at F 86, above cam0's own 29, and cam1 was split first). Splitting the knocked camera
    first, the solve tests the others again on a model in which its views agree."""
    best, best_key = moves[0], None
    for m in moves:
        without = [replace(v, active=False) if v.camera == m.camera else v for v in views]
        others = [o.camera for o in moves if o.camera != m.camera]
        again = camera_splits(problem, without, rounds.est, rounds.sigma_px, others, start.T_ref_cam, min_after=1,
                              robot_scales=robot_scales(problem, views, rounds))
        key = (sum(1 for n in others if not (n in again and again[n].is_move)), m.f_stat)
        if best_key is None or key > best_key:
            best, best_key = m, key
    return best


def find_moves_live(problem, reference) -> list:
    """Cameras of ``problem`` whose views, in capture order, show a move, judged against
    ``reference``, a calibration at hand: a :class:`~calibgraph.solver.output.result.Result`, a result.json
    dict (:func:`~calibgraph.solver.output.result.load_result_dict`), verify's ``StoredModel``, or the live
    estimate of a capture (``IncrementalEstimate``: anything with ``cameras[name].T_ref_cam`` and
    ``T_mount_board``). Returns :class:`Move` s, the clearest first (``move.camera``, ``move.where()``,
    ``move.split.displacement_mm`` / ``rotation_deg`` / ``f_stat``); [] when nothing moved or there
    is too little to tell (a camera needs ``2 * MIN_GROUP_VIEWS`` views in ``problem``).

    For ``verify`` (did a camera move *during* the fresh capture?) and the capture's live warning
    (call it every few captures with the views so far)."""
    est, sigma = _reference_estimate(problem, reference)
    if est is None:
        return []
    views = [v for v in prepare_views(problem)[0] if v.camera in est.T_ref_cam]
    if not views:
        return []
    if not sigma:
        sigma = problem.options.pixel_sigma_px or robust_pixel_sigma(views, est.residual_norms(views, problem.cameras))
    moves, names = [], sorted({v.camera for v in views}, key=list(problem.cameras).index)
    while names:  # the clearest move first; its camera's views then no longer hold the robot poses
        splits = camera_splits(problem, views, est, sigma, names)
        found = sorted((s for s in splits.values() if s.is_move), key=lambda s: -s.f_stat)
        if not found:
            break
        moves.append(Move(found[0].camera, found[0]))
        names.remove(found[0].camera)
        views = [replace(v, active=False) if v.camera == found[0].camera else v for v in views]
    return moves


def _reference_estimate(problem, ref) -> tuple:
    """(Estimate of the cameras of ``problem`` that ``ref`` calibrated, its pixel sigma or 0) for
    :func:`find_moves_live`; (None, 0) when ``ref`` has no board mount."""
    if isinstance(ref, dict):  # result.json
        key = "T_base_cam" if ref.get("mode", "eye_to_hand") == "eye_to_hand" else "T_flange_cam"
        cams = {n: (c.get(key), c.get("intrinsics")) for n, c in (ref.get("cameras") or {}).items()}
        mount = ref.get("T_flange_board", ref.get("T_base_board"))
        scale = (ref.get("board_scale") or {}).get("scale")
        sigma = (ref.get("solver") or {}).get("pixel_sigma_px")
    elif hasattr(ref, "T_base_cam") and hasattr(ref, "T_flange_board"):  # verify's StoredModel
        cams = {n: (T, ref.intrinsics.get(n)) for n, T in ref.T_base_cam.items()}
        mount, scale, sigma = ref.T_flange_board, ref.board_scale, ref.pixel_sigma_px
    else:  # Result, IncrementalEstimate
        cams = {n: (getattr(c, "T_ref_cam", None), getattr(c, "intrinsics", None))
                for n, c in (getattr(ref, "cameras", None) or {}).items()}
        mount, scale = getattr(ref, "T_mount_board", None), getattr(ref, "board_scale", None)
        sigma = getattr(ref, "pixel_sigma_px", None)
    cams = {n: c for n, c in cams.items() if n in problem.cameras and c[0] is not None}
    if mount is None or not cams:
        return None, 0.0
    intr = {n: Intrinsics.from_dict(i) if isinstance(i, dict) else i for n, (_, i) in cams.items()
            if isinstance(i, (dict, Intrinsics))}
    est = Estimate(T_ref_cam={n: np.asarray(T, float).reshape(4, 4) for n, (T, _) in cams.items()},
                   T_mount_board=np.asarray(mount, float).reshape(4, 4), T_ref_mount={}, intrinsics=intr,
                   board_scale=float(scale or 1.0))
    return est, float(sigma or 0.0)


def solve_minding_moves(problem, resolve, board: bool = True) -> object:
    """``resolve(problem)`` with every camera tested for a move during capture after the robust
    rounds; a camera that moved is solved as two poses (module docstring); a board that moved, as two
    segments of captures (:func:`_board_segments`)."""
    watch, moves, split = _Watch(board=board), [], problem
    token = _WATCH.set(watch)
    try:
        while True:
            try:
                result = resolve(split)
                break
            except BoardMoved as e:
                _WATCH.reset(token)
                token = None
                return _board_segments(problem, resolve, e.split)
            except CameraMoved as e:
                m = e.move
                watch.skip |= {m.camera}
                split, m = _split(split, m)
                if m.pseudo:
                    watch.skip.add(m.pseudo)
                moves.append(m)
                watch.active = len(moves) < MAX_MOVED
    finally:
        if token is not None:
            _WATCH.reset(token)
    return _fold(problem, result, moves) if moves else result


def _board_segments(problem, resolve, split: Split):
    """The result of a problem whose board moved between captures ``split.captures_before[-1]`` and
    ``split.captures_after[0]``: the captures on each side are solved apart (each with its own board
    pose; cameras tested for moves in each), and the side with more views is reported, the other side's
    views set aside with the reason and its cameras compared with the reported ones in a note. No camera
    is called moved: the cameras' views on the two sides agree once each side has its own board."""
    cut = split.captures_after[0]
    sides = {"before": {c.index for c in problem.captures if c.index < cut},
             "after": {c.index for c in problem.captures if c.index >= cut}}
    solved, why = {}, {}
    for side, caps in sides.items():
        sub = problem.with_(captures=tuple(c for c in problem.captures if c.index in caps),
                            detections=tuple(d for d in problem.detections if d.capture in caps))
        try:
            solved[side] = solve_minding_moves(sub, resolve, board=False)
        except CalibgraphError as e:
            why[side] = str(e)
    views = {side: sum(1 for d in problem.detections if d.capture in caps) for side, caps in sides.items()}
    if not solved:
        raise ObservabilityError(f"the board moved between captures {split.captures_before[-1]} and {cut} (by about "
                                 f"{split.displacement_mm:.1f} mm and {split.rotation_deg:.2f} deg), and neither side "
                                 f"can be solved on its own: {'; '.join(why.values())}")
    keep = max(solved, key=lambda sd: views[sd])
    other = "after" if keep == "before" else "before"
    result = solved[keep]
    T_k, T_o = result.T_mount_board, solved[other].T_mount_board if other in solved else None
    if T_o is not None and T_k is not None:
        d_m, d_deg = pose_error(T_k, T_o)
        d_mm = 1e3 * d_m
    else:
        d_mm, d_deg = split.displacement_mm, split.rotation_deg
    agree = []
    if other in solved:
        for n, c in result.cameras.items():
            o = solved[other].cameras.get(n)
            if c.calibrated and o is not None and o.calibrated:
                e_m, e_deg = pose_error(c.T_ref_cam, o.T_ref_cam)
                agree.append(f"{n} {1e3 * e_m:.1f} mm / {e_deg:.2f} deg")
    aside = tuple(RejectedView(d.camera, d.capture, f"the board moved between captures {split.captures_before[-1]} "
                               f"and {cut}: this view is from the {other} side, solved apart (its own board pose)")
                  for d in problem.detections if d.capture in sides[other])
    cams = {n: replace(c, views_rejected=tuple(c.views_rejected) + tuple(r for r in aside if r.camera == n))
            for n, c in result.cameras.items()}
    note = (f"the board moved during capture, between captures {split.captures_before[-1]} and {cut}, by {d_mm:.1f} mm "
            f"and {d_deg:.2f} deg (F {split.f_stat:.0f}): the views before and after agree once each side has its own "
            f"board pose, and no camera moved. Calibrated from the {views[keep]} views {keep} it; the {views[other]} "
            f"views {other} it were solved apart"
            + (f" and give the cameras within {', '.join(agree)} of these" if agree else
               f" and could not be solved on their own ({why.get(other, 'too few')})")
            + ". Fix the board to its mount (or the table) before capturing again.")
    record = {"last_capture_before": int(split.captures_before[-1]), "capture": int(cut),
              "displacement_mm": float(d_mm), "rotation_deg": float(d_deg), "f_stat": float(split.f_stat),
              "solved_from": keep, "views_used_side": int(views[keep]), "views_other_side": int(views[other])}
    return replace(result, cameras=cams, notes=result.notes + (note,),
                   rejected_views=tuple(rv for c in cams.values() for rv in c.views_rejected),
                   settings={**result.settings, "board_moved": record})


def _split(problem, m: Move):
    """(the problem with camera ``m.camera``'s views before the move under a camera of their own, or
    set aside / the camera taken out when a side is too small to solve; ``m`` with its pseudo name).
    A camera moved and moved back keeps its views before and after the span; the span's are set aside."""
    need = problem.options.min_views_per_camera
    before, after = set(m.split.captures_before), set(m.split.captures_after)
    name, pseudo = m.camera, m.camera + BEFORE
    cams, dets = dict(problem.cameras), []
    if m.back:
        keep = len(before) + len(m.split.captures_back) >= need
        dets = [d for d in problem.detections if d.camera != name or (keep and d.capture not in after)]
        if not keep:
            del cams[name]
        if not cams:
            raise ObservabilityError(f"{_headline(m)}; {_too_few_after(m, need)}", camera=name)
        return problem.with_(cameras=cams, detections=tuple(dets)), m
    keep_before = len(before) >= need
    keep_after = len(after) >= need
    for d in problem.detections:
        if d.camera == name and d.capture in before:
            if keep_before:
                dets.append(replace(d, camera=pseudo))
            continue
        if d.camera == name and not keep_after:
            continue
        dets.append(d)
    if keep_before:
        cams[pseudo] = problem.cameras[name]
    if not keep_after:
        del cams[name]
    if not cams:
        raise ObservabilityError(f"{_headline(m)}; {_too_few_after(m, need)}", camera=name)
    return problem.with_(cameras=cams, detections=tuple(dets)), replace(m, pseudo=pseudo if keep_before else None)


def _headline(m: Move) -> str:
    s = m.split
    return (f"camera {m.camera} moved during capture, {m.where()}, by about {s.displacement_mm:.1f} mm and "
            f"{s.rotation_deg:.2f} deg")


def _too_few_after(m: Move, need: int) -> str:
    """Why a camera that moved cannot be calibrated as it now stands."""
    s = m.split
    if m.back:
        n = len(s.captures_before) + len(s.captures_back)
        return (f"only {n} of its views are from before and after the span ({need} needed): it cannot be calibrated; "
                "fix its mount and capture more views of it")
    n, caps = len(s.captures_after), ", ".join(str(c) for c in s.captures_after)
    pl = "s" if n != 1 else ""
    return (f"moved after capture {m.last_before}? only {n} view{pl} after (capture{pl} {caps}) and at least {need} "
            "needed: it cannot be calibrated as it now stands, and its pose before is not where it stands. If it did "
            f"not move, the view{pl} of capture{pl} {caps} {'are' if n != 1 else 'is'} bad: remove "
            f"{'them' if n != 1 else 'it'} and solve again; else fix its mount and capture more views of it")


def _moved_record(result, m: Move, pseudo_cam: CameraResult | None, after_cam: CameraResult | None) -> dict:
    """``CameraResult.moved``: where and by how much the camera moved, and its pose before."""
    s = m.split
    rec = {"capture": m.first_after, "last_capture_before": m.last_before,
           "views_before": len(s.captures_before), "views_after": len(s.captures_after),
           "displacement_mm": s.displacement_mm, "rotation_deg": s.rotation_deg,
           "sigma_displacement_mm": s.sigma_displacement_mm, "f_stat": s.f_stat,
           "T_before": None, "covariance_before": None}
    if m.back:  # the pose reported is the one before and after the span; the span's views were set aside
        rec.update(back_capture=s.captures_back[0], last_capture_moved=s.captures_after[-1],
                   views_after=len(s.captures_back), views_while_moved=len(s.captures_after))
    if pseudo_cam is not None and pseudo_cam.calibrated:
        rec["T_before"], rec["covariance_before"] = pseudo_cam.T_ref_cam, pseudo_cam.covariance
        if after_cam is not None and after_cam.calibrated:
            T_a, T_b = after_cam.T_ref_cam, pseudo_cam.T_ref_cam
            d_m, rec["rotation_deg"] = pose_error(T_a, T_b)
            rec["displacement_mm"] = 1e3 * d_m
            u = (T_a[:3, 3] - T_b[:3, 3]) / max(d_m, 1e-12)  # the displacement's direction, reference axes
            # its 1-sigma along it: from the joint marginal of the two poses (a pair, in its first camera's
            # axes), else from the two marginals as if independent (covariances in reference axes)
            for (a, b), T_axes in (((m.camera, m.pseudo), T_a), ((m.pseudo, m.camera), T_b)):
                if (a, b) in result.pairs:
                    w = T_axes[:3, :3].T @ u
                    var = w @ result.pairs[(a, b)].covariance[3:, 3:] @ w
                    break
            else:
                var = u @ (after_cam.covariance[3:, 3:] + pseudo_cam.covariance[3:, 3:]) @ u
            rec["sigma_displacement_mm"] = 1e3 * float(np.sqrt(max(var, 0.0)))
    return rec


def _note(m: Move, rec: dict, after_cam: CameraResult | None, need: int) -> str:
    head = (f"camera {m.camera} moved during capture, {m.where()}, by {rec['displacement_mm']:.1f} mm "
            f"(1-sigma {rec['sigma_displacement_mm']:.1f} mm) and {rec['rotation_deg']:.2f} deg: its views "
            + ("in that span and outside it" if m.back else "before and after") +
            f" disagree (F {m.split.f_stat:.0f} against the other cameras)")
    if after_cam is None or not after_cam.calibrated:
        return f"{head}; it is NOT calibrated: {_too_few_after(m, need)}."
    nb = rec["views_before"]
    if m.back:
        return (f"{head}; its {rec['views_while_moved']} views in between ({m.span()}) were set aside. Calibrated "
                f"from the {nb + rec['views_after']} views before and after that span, where it stands again (never "
                "averaged with the span's). Check the camera's mount: it was knocked and sprang back, or was moved "
                "and put back.")
    before = (f"its pose before the move, from the {nb} views before it, is reported beside it" if rec["T_before"]
              is not None else f"the {nb} views before the move were set aside (too few to solve that pose)")
    return (f"{head}. Calibrated as it stood after the move, from the {rec['views_after']} views after it; {before} "
            "(never averaged). Fix the camera's mount; re-capture for more views in its final pose.")


def _fold(problem, result, moves: list):
    """The result of the split problem with each moved camera's two poses folded back into one
    CameraResult (``moved``), the pseudo cameras and their pairs removed, one note per move."""
    cams, notes = dict(result.cameras), list(result.notes)
    need = problem.options.min_views_per_camera
    for m in moves:
        pseudo_cam = cams.pop(m.pseudo, None) if m.pseudo else None
        after_cam = cams.get(m.camera)
        rec = _moved_record(result, m, pseudo_cam, after_cam)
        if m.back:
            aside = tuple(RejectedView(m.camera, c, f"camera moved {m.where()}: this view is from while it was moved, "
                                       "and was set aside") for c in m.split.captures_after)
        else:
            aside = tuple(RejectedView(m.camera, c, f"camera moved {m.where()}: this view is from before the move, too "
                                       "few of those to solve that pose, and was set aside")
                          for c in m.split.captures_before) if pseudo_cam is None else ()
        if pseudo_cam is not None:
            aside += tuple(replace(rv, camera=m.camera) for rv in pseudo_cam.views_rejected)
        if after_cam is None:
            why = f"{_too_few_after(m, need)}. {_headline(m)}"
            after_cam = CameraResult(name=m.camera, ref_frame="base" if problem.mode == "eye_to_hand" else "flange",
                                     T_ref_cam=None, covariance=None, reprojection_rms_px=float("nan"),
                                     reprojection_max_px=float("nan"), views_used=0, calibrated=False, why=why)
        residuals = dict(after_cam.residuals_px)
        if pseudo_cam is not None:
            residuals.update(pseudo_cam.residuals_px)
        cams[m.camera] = replace(after_cam, moved=rec, views_rejected=tuple(after_cam.views_rejected) + aside,
                                 residuals_px=dict(sorted(residuals.items())))
        notes.append(_note(m, rec, cams[m.camera], need))
    pseudo = {m.pseudo for m in moves if m.pseudo}
    order = [n for n in problem.cameras if n in cams]
    cams = {n: cams[n] for n in order}
    pairs = {k: p for k, p in result.pairs.items() if not (set(k) & pseudo)}
    rename = {m.pseudo: m.camera for m in moves if m.pseudo}
    corners = tuple((rename.get(c, c), k, i, r) for c, k, i, r in result.rejected_corners)
    return replace(result, cameras=cams, pairs=pairs, notes=tuple(notes), rejected_corners=corners,
                   rejected_views=tuple(rv for c in cams.values() for rv in c.views_rejected))
