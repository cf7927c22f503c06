"""The robot error model chosen by held-out captures: the per-pose FK prior, or joint zero offsets
(``SolverOptions.kinematics = 'auto'``, the default).

An arm whose joint zero offsets are off by a milliradian or two (a Panda whose joints were never
re-referenced, a replaced motor) moves the flange millimetres from its reported pose, and the
error repeats from pose to pose: the per-pose FK prior cannot describe it. The FK check
(:mod:`calibgraph.solver.robot.fk_check`) then finds the fitted flange poses departing from FK and widens
the prior and the 1-sigma, but the cameras' poses stay biased. On the simulator's offset cells
(0.5-2 mrad on joints 2-6, 3 cameras at 1.5-5 m, 30 captures) the per-pose model left 8.9-19 mm of
error, with error / 1-sigma up to 6.1; with the offsets estimated 2.9-12.4 mm, up to 1.7.

So when the arm departs from its stated FK (the FK check widened its prior or the folds' jackknife
widened the 1-sigma) and every capture records joint angles that the kinematic model maps to the
recorded flange poses, both models are cross-validated as a user applies them: the captures are
dealt into :data:`FOLDS` folds, each model is solved without a fold, and the fold's corners are
predicted from its reported poses (the per-pose model) or from its reported joint angles through the
arm with the estimated offsets (the offset model). The offsets are used only when they predict
clearly better: held-out RMS at least :data:`MARGIN` below the per-pose model's *and* a paired
per-capture t below ``-``:data:`T_MIN`. Five more parameters cannot win by chance that way, and an
arm whose errors are independent from pose to pose (no offsets) keeps the per-pose model (simulated
FK noise 3x the stated, 30 captures: held-out RMS 3-16 % worse with offsets; 6 seeds of 6 kept).

Nothing is tried (and the result is what 'none' gives, to the digit) when the arm matches its
stated accuracy, the captures lack joint angles, or the cell is not eye-to-hand with method
'joint'; a note says why when the arm departs but the offsets could not be tried. The result's
``kinematics_selection`` says which of these it was (``tried`` False, ``why_not``). Recorded joint
angles that the kinematic model does not map to the recorded poses (in degrees, say) get a note
whether or not the arm departs: the per-pose model does not use them, but they are wrong.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calibgraph.core.errors import CalibgraphError
from calibgraph.core.problem import configuration_folds
from calibgraph.core.transforms import inv
from calibgraph.solver.robot import kinematics as kin

FOLDS = 5
# the offsets must predict the held-out captures this fraction better than the per-pose model ...
MARGIN = 0.05
# ... with a paired per-capture t (log ratio of the offsets' squared misses to the per-pose model's) below
# minus this. Simulated, 6-30 captures (scripts/results/bench_kinematics_auto.md): with FK errors independent
# from pose to pose (no offsets) t >= -0.95 in 48 of 48 train sets; with offsets t < -1.5 in 42 of 48 (< -2: 40)
T_MIN = 1.5
# the kinematic model must map each capture's joint angles to its recorded flange pose this closely
FK_MATCH_M, FK_MATCH_RAD = kin.FK_MATCH_M, kin.FK_MATCH_RAD


# kinematics_selection's why_not where nothing is tried
NO_ANGLES = "the captures record no joint angles (q_rad)"
AS_STATED = ("the arm is not found less accurate than stated: nothing for joint offsets to explain, the per-pose FK "
             "model is kept")


def robot_departs(result) -> bool:
    """The solve found the arm less accurate than stated: the FK check widened its prior or the
    folds' jackknife widened the 1-sigma (what the robot note of :func:`~calibgraph.solver.robot.fk_check.fk_note` says)."""
    fk = result.fk_noise or {}
    cv = fk.get("cross_validation") or {}
    return float(fk.get("applied", 1.0)) > 1.0 or float(cv.get("jackknife_applied", 1.0)) > 1.0


def why_not_tried(problem) -> str | None:
    """Why joint offsets cannot be tried on ``problem``, whose captures all record joint angles (None: they can).
    Recorded angles that the kinematic model does not map to the recorded poses are named first,
    whatever the cell: that is a fact about the data (degrees, say), not about the method."""
    caps = problem.captures
    mismatch = kin.angles_mismatch(problem)
    if mismatch is not None:
        return mismatch.describe() + " to have them tried"
    if problem.method != "joint":
        return "joint offsets are estimated for cells solved jointly (one shared board mount) only"
    model = problem.options.kinematics_model
    try:
        chain = kin.load_chain(model)
    except CalibgraphError as e:  # not asked for: the per-pose result stands, the note says why
        return f"the kinematic model could not be read: {e}"
    sizes = {c.q_rad.size for c in caps}
    if sizes != {chain.n_joints}:
        return (f"the captures record {'/'.join(str(s) for s in sorted(sizes))} joint angles, the kinematic model "
                f"{model!r} has {chain.n_joints} joints")
    try:
        kin.check_motion(kin.setup(problem.with_(options=replace(problem.options, kinematics="joint-offsets"))),
                         [c.index for c in caps])
    except CalibgraphError as e:
        return str(e)
    return None


def _subset(problem, keep: set):
    return problem.with_(captures=tuple(c for c in problem.captures if c.index in keep),
                         detections=tuple(d for d in problem.detections if d.capture in keep))


def _misses(problem, result, test: set, flange: dict, skip_views: set, skip_corners: set) -> dict:
    """(camera, capture) -> (squared miss sum, corners) of the test captures' corners predicted by
    ``result`` from the flange poses ``flange`` (capture -> T_base_flange), the full solve's
    rejected views and corners left out."""
    out = {}
    for d in problem.detections:
        if d.capture not in test or (d.camera, d.capture) in skip_views:
            continue
        cam = result.cameras.get(d.camera)
        if cam is None or not cam.calibrated or cam.solved_intrinsics is None or result.T_mount_board is None:
            continue
        keep = np.array([(d.camera, d.capture, int(i)) not in skip_corners for i in d.ids], bool)
        if not keep.any():
            continue
        T_ref_mount = flange[d.capture] if problem.mode == "eye_to_hand" else inv(flange[d.capture])
        T_cam_board = inv(cam.T_ref_cam) @ T_ref_mount @ result.T_mount_board
        p = problem.points_board_m[np.asarray(d.ids)[keep]] * result.board_scale
        e = cam.solved_intrinsics.project(p @ T_cam_board[:3, :3].T + T_cam_board[:3, 3]) - np.asarray(d.uv_px)[keep]
        out[(d.camera, d.capture)] = (float(np.sum(e ** 2)), int(keep.sum()))
    return out


def cross_validate(problem, per_pose, resolve) -> dict:
    """Both models' held-out prediction (module docstring): ``{"folds", "rms_px": {"none", "joint-offsets"},
    "t": paired per-capture t of offsets against per-pose, "captures"}``. ``per_pose``: the full
    solve with the per-pose model (its rejected views and corners are left out of the scoring);
    ``resolve(problem)``: a solve. Raises CalibgraphError when a fold cannot be solved."""
    caps = sorted(c.index for c in problem.captures)
    folds = configuration_folds(problem.captures, FOLDS)  # a revisit of a held-out target is held out with it
    if len(folds) < FOLDS:
        raise CalibgraphError(f"{len(folds)} distinct arm configurations, too few for {FOLDS} folds")
    skip_views = {(v.camera, v.capture) for v in per_pose.rejected_views}
    skip_corners = {(c, k, i) for c, k, i, _ in per_pose.rejected_corners}
    reported = {c.index: c.T_base_flange for c in problem.captures}
    jo = problem.with_(options=replace(problem.options, kinematics="joint-offsets"))
    ks = kin.setup(jo)
    misses = {"none": {}, "joint-offsets": {}}
    for fold in folds:
        train = set(caps) - fold
        r0 = resolve(_subset(problem.with_(options=replace(problem.options, kinematics="none")), train))
        r1 = resolve(_subset(jo, train))
        corrected = {k: T for k, (T, _) in kin.corrected_flange_poses(ks, r1.robot["joint_offsets_rad"]).items()}
        misses["none"].update(_misses(problem, r0, fold, reported, skip_views, skip_corners))
        misses["joint-offsets"].update(_misses(problem, r1, fold, corrected, skip_views, skip_corners))
    both = sorted(set(misses["none"]) & set(misses["joint-offsets"]))
    if not both:
        raise CalibgraphError("no held-out corner was predicted by both models")
    rms = {m: float(np.sqrt(sum(misses[m][v][0] for v in both) / sum(misses[m][v][1] for v in both)))
           for m in misses}
    per_cap = {}  # capture -> squared misses (offsets, per-pose)
    for v in both:
        a, b = per_cap.get(v[1], (0.0, 0.0))
        per_cap[v[1]] = (a + misses["joint-offsets"][v][0], b + misses["none"][v][0])
    # each capture's log ratio: a few captures far off (a pose the arm reached worst) do not make the test
    d = np.array([np.log(max(a, 1e-300) / max(b, 1e-300)) for a, b in per_cap.values()])
    se = float(np.std(d, ddof=1) / np.sqrt(len(d))) if len(d) > 1 else 0.0
    t = float(np.mean(d) / se) if se > 0 else 0.0
    return {"folds": FOLDS, "rms_px": rms, "t": t, "captures": len(per_cap)}


def choose_kinematics(problem, per_pose, resolve):
    """The result to report for ``problem`` solved with ``kinematics='auto'``: ``per_pose`` (its solve
    with the per-pose FK prior) or, where the offsets predict held-out captures clearly better, the
    joint-offset solve; ``resolve(problem) -> Result`` solves a problem. The result's settings say
    which (``kinematics_used``) and why (``kinematics_selection``, always: with ``tried`` False and
    ``why_not`` where nothing was tried); a note says it when the arm departs from its FK, or when
    the recorded joint angles do not give the recorded poses."""
    used = {**per_pose.settings, "kinematics": "auto", "kinematics_used": "none"}
    if not problem.records_joint_angles:  # the robot note, when there is one, names what the angles would open
        return replace(per_pose, settings={**used, "kinematics_selection": {"tried": False, "why_not": NO_ANGLES}})
    if not robot_departs(per_pose):
        # nothing for the offsets to explain; recorded angles that do not give the recorded poses are still named
        record = {"tried": False, "why_not": AS_STATED}
        mismatch = kin.angles_mismatch(problem)
        if mismatch is None:
            return replace(per_pose, settings={**used, "kinematics_selection": record})
        said = mismatch.describe()
        record["why_not"] += f"; and {said}"
        note = (f"robot: the recorded joint angles do not give the recorded flange poses: {said}; the per-pose FK "
                "model uses the recorded poses alone and is kept, but joint zero offsets cannot be estimated from "
                "these angles")
        return replace(per_pose, settings={**used, "kinematics_selection": record}, notes=per_pose.notes + (note,))
    why = why_not_tried(problem)
    if why is not None:
        record = {"tried": False, "why_not": why}
        note = f"robot: joint zero offsets were not tried ({why}); the per-pose FK model is kept"
        return replace(per_pose, settings={**used, "kinematics_selection": record}, notes=per_pose.notes + (note,))
    def kept(why: str):
        record = {"tried": True, "chosen": "none", "why_not": why}
        note = f"robot: joint zero offsets were tried and could not be estimated ({why}); the per-pose FK model is kept"
        return replace(per_pose, settings={**used, "kinematics_selection": record}, notes=per_pose.notes + (note,))

    try:
        cv = cross_validate(problem, per_pose, resolve)
    except CalibgraphError as e:
        return kept(str(e))
    rms = cv["rms_px"]
    chosen = "joint-offsets" if rms["joint-offsets"] < (1.0 - MARGIN) * rms["none"] and cv["t"] < -T_MIN else "none"
    if chosen == "joint-offsets":  # all captures solved with the offsets only where they are used
        try:
            offsets = resolve(problem.with_(options=replace(problem.options, kinematics="joint-offsets")))
        except CalibgraphError as e:
            return kept(str(e))
        if not offsets.robot:
            return kept("the solve with them gave no offsets")
    record = {"tried": True, "chosen": chosen, **cv, "margin": MARGIN, "t_min": T_MIN}
    figures = (f"held-out captures predicted to {rms['joint-offsets']:.3f} px RMS with the offsets, "
               f"{rms['none']:.3f} px with the per-pose FK model ({FOLDS}-fold cross-validation, paired t "
               f"{cv['t']:+.1f} over {cv['captures']} captures)")
    if chosen == "none":
        note = (f"robot: joint zero offsets were tried and predict no clearly better ({figures}): the per-pose FK "
                "model is kept (--estimate-kinematics joint-offsets uses them anyway)")
        return replace(per_pose, settings={**used, "kinematics_selection": record}, notes=per_pose.notes + (note,))
    note = (f"robot: the arm departs from its forward kinematics as joint zero offsets do, so they are estimated "
            f"(the robot section; --estimate-kinematics none keeps the per-pose FK model): {figures}")
    settings = {**offsets.settings, "kinematics": "auto", "kinematics_used": "joint-offsets",
                "kinematics_selection": record}
    return replace(offsets, settings=settings, notes=offsets.notes + (note,))
