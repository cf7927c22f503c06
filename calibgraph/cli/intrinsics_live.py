"""``calibgraph intrinsics --live --camera NAME --workcell CELL.yaml --out CAM.yaml [--target T.yaml]``:
a guided intrinsics session at the camera (:mod:`calibgraph.acquire.live_session`).

The camera's device is the one the workcell names (the device registry,
:mod:`calibgraph.acquire.devices`: RealSense, Kinect V2, a ROS 2 topic); a simulated camera of a
simulated workcell is watched by a simulated hand-held board (:class:`calibgraph.sim.handheld.HandheldBoardCamera`)
rendering the workcell's board with the camera's true intrinsics, held by a user who does what the
hints say (``follows_hints``). CAM.yaml is the file
``calibgraph intrinsics IMAGES_DIR`` writes, from the views the session took.
"""

from __future__ import annotations

import sys
from pathlib import Path

EXIT_NOT_MET = 3
EXIT_INTERRUPTED = 130


def _device(args, spec, board):
    """The camera device of ``args.camera`` in the workcell ``spec`` (opened)."""
    from calibgraph.core.errors import InputError

    name = args.camera
    entry = spec.cameras.get(name)
    driver = (entry or {}).get("driver", "sim") if isinstance(entry, dict) or entry is None else None
    if driver != "sim":
        from calibgraph.acquire.devices import open_camera

        return open_camera(name, entry, spec.where)
    if not spec.has_placements:
        raise InputError(f"{spec.where}: camera {name!r} is not in this workcell (cameras: {', '.join(sorted(spec.cameras)) or 'none'}); "
                         "a camera needs its driver (realsense, kinect, ros2) or a simulated placement.")
    from calibgraph.sim.handheld import HandheldBoardCamera, camera_seed
    from calibgraph.sim.workcell import workcell_from_dict

    cell = workcell_from_dict(spec.sim_world(), spec.where)
    if name not in cell.camera_names:
        raise InputError(f"{spec.where}: no camera {name!r}; its cameras are {', '.join(cell.camera_names)}.")
    return HandheldBoardCamera(name, cell.camera(name).intrinsics, cell.target, reported=cell.reported_intrinsics(name),
                               realism=cell.realism, seed=camera_seed(cell.seed, name), follows_hints=True)


class _Console:
    """The one live line: rewritten in place on a terminal, a plain line per change otherwise."""

    def __init__(self, fx_px: float, quiet: bool, stream=None):
        stream = sys.stderr if stream is None else stream
        self.fx_px, self.quiet, self.stream = fx_px, quiet, stream
        self.tty = hasattr(stream, "isatty") and stream.isatty()
        self.last = None
        self.width = 0

    def __call__(self, status) -> None:
        if self.quiet:
            return
        line = status.line(self.fx_px)
        if self.tty:
            self.stream.write("\r" + line.ljust(self.width))
            self.width = len(line)
            self.stream.flush()
            return
        key = status.views  # a plain line per taken view (and the first frame's)
        if key != self.last:
            print(line, file=self.stream, flush=True)
            self.last = key

    def note(self, line: str) -> None:
        """A line said once (the goal set or changed), on its own line."""
        if self.quiet:
            return
        if self.tty and self.width:
            self.stream.write("\r" + " " * self.width + "\r")
            self.width = 0
        print(line, file=self.stream, flush=True)

    def end(self) -> None:
        if self.tty and not self.quiet and self.width:
            self.stream.write("\n")
            self.stream.flush()


def run_live(args) -> int:
    from calibgraph.acquire.live_session import ADVICE_SESSION_VIEWS, default_goal_px, run_live_session
    from calibgraph.solver.camera.intrinsics_session import MIN_VIEWS
    from calibgraph.solver.camera.session_plan import SESSION_PIXEL_SIGMA_PX
    from calibgraph.acquire.workcell import read_workcell
    from calibgraph.core.errors import InputError
    from calibgraph.io.camera_file import write_camera_file
    from calibgraph.io.files import atomic_write_png
    from calibgraph.io.output_guard import check_output_file, check_output_folder, write_keeping_previous
    from calibgraph.io.specs import load_target

    if args.images is not None:
        raise InputError("intrinsics --live reads frames from the camera; give no IMAGES_DIR (or drop --live to "
                         "calibrate from a folder of images).")
    if not args.camera or args.workcell is None:
        raise InputError("intrinsics --live needs --camera NAME and --workcell CELL.yaml (the file naming the "
                         "camera's device).")
    inputs = [args.workcell] + ([args.target] if args.target is not None else [])
    out = check_output_file(args.out, "camera file", "camera file", "camera.yaml", inputs=inputs)
    views_dir = check_output_folder(args.save_views, "views folder", empty=True) if args.save_views else None
    rrd = None
    if args.rrd is not None or args.view:
        from calibgraph.report.live_view import has_display

        if args.rrd is not None or not has_display():
            rrd = check_output_file(args.rrd or out.with_suffix(".rrd"), "recording", "recording file", "calibgraph.rrd",
                                    inputs=inputs + [out])
    spec = read_workcell(args.workcell)
    target = load_target(args.target) if args.target is not None else spec.target
    cam = _device(args, spec, target)
    view = None
    try:
        intr = cam.intrinsics()
        fx = float(intr.K[0, 0])
        if args.goal_fx_percent is not None:
            if not args.goal_fx_percent > 0:
                raise InputError(f"--goal-fx-percent must be > 0, got {args.goal_fx_percent}.")
            goal = args.goal_fx_percent / 100.0 * fx
            stated = f"goal fx 1-sigma {goal:.3f} px ({args.goal_fx_percent:g} %, --goal-fx-percent)"
        else:
            goal, bound = None, default_goal_px(intr, target, args.model)[0]
            stated = (f"goal: the fx 1-sigma the error budget's advice assumes, a {ADVICE_SESSION_VIEWS}-view session "
                      f"at this camera's own corner noise (at most {SESSION_PIXEL_SIGMA_PX:g} px, so at most "
                      f"{bound:.2f} px, {100 * bound / fx:.3f} %), set once the first calibration ({MIN_VIEWS} views) "
                      "measures the noise")
        say = (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr, flush=True))
        say(f"live intrinsics of {args.camera} ({intr.width_px}x{intr.height_px}, fx {fx:.1f} px as the device "
            f"reports): {stated}; hold the {target.kind} ({target.rows}x{target.cols}) still in each pose the hint "
            "names; Ctrl-C stops and writes what it has")
        console = _Console(float(intr.K[0, 0]), args.quiet)

        def keep(name, image):
            if views_dir is not None:
                atomic_write_png(views_dir / name, image)

        if args.view or rrd is not None:
            from calibgraph.report.live_view import LiveView

            view = LiveView(args.camera, intr.width_px, intr.height_px, float(intr.K[0, 0]), rrd)
        o = run_live_session(cam, target, goal_px=goal, model=args.model, on_status=console, on_take=keep,
                             on_frame=view, on_note=console.note)
        console.end()
    finally:
        cam.close()
        if view is not None:
            written = view.close()
            if written is not None:
                print(f"wrote {written} (open with: rerun {written})")
    if o.result is None:
        print(f"calibgraph intrinsics --live: {o.reason}; {len(o.views)} views taken, too few to calibrate"
              f"{' (' + o.error + ')' if o.error else ''}; nothing written to {out}.", file=sys.stderr)
        return EXIT_INTERRUPTED if o.reason == "interrupted" else EXIT_NOT_MET
    r = o.result
    kept = write_keeping_previous(out, lambda: write_camera_file(out, r.to_dict(target)))
    if kept is not None:
        print(f"kept the previous camera file as {kept}")
    s = r.sigma
    print(f"wrote {out}: {o.reason} after {o.frames} frames; {len(r.views_used)} of {len(o.views)} views used, "
          f"RMS {r.rms_px:.3f} px, fx {r.intrinsics.K[0, 0]:.2f} ± {s['fx']:.2f} px "
          f"({100 * s['fx'] / r.intrinsics.K[0, 0]:.3f} %, goal {o.goal_px:.3f} px)"
          + (f"; views saved in {views_dir}" if views_dir is not None else ""))
    for w in r.warnings:
        print(f"  warning: {w}")
    if o.goal_met:
        return 0
    return EXIT_INTERRUPTED if o.reason == "interrupted" else EXIT_NOT_MET
