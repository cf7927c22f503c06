"""A run owns its dataset: what made it is recorded, ``--resume`` continues only that, one process at a time.

``dataset.yaml`` of a captured dataset records what made it::

    made_by:
      mode: auto                      # sim | trajectory | auto | verify
      calibgraph: 0.1.0
      world_sha256: 9f2c...           # content hashes of the inputs the run used (those it had):
      workcell_sha256: 41ab...        #   workcell_sha256, world_sha256 (the simulated world),
      trajectory_sha256: 77e0...      #   trajectory_sha256 (Trajectory.sha256), result_sha256 (verify)
      workcell_file: /cell/cell.yaml  # where the workcell (or simulated world) was read from: the file
                                      #   the advice names (never checked: a resume may read a copy)

A YAML input is hashed by its content (the parsed mapping as canonical JSON: comments and layout
do not count), a result file by its bytes, a trajectory by :meth:`Trajectory.sha256`.

:func:`claim_dataset` opens a run on a dataset folder:

- a folder with a ``dataset.yaml`` is refused without ``resume``;
- with ``resume`` the dataset must have been made by a run of the same kind (``accept``) with the
  same inputs, else it is refused in one line and nothing is touched. A dataset without
  ``made_by`` (written before it was recorded) is continued only when it holds the journal of
  that kind of run (``acquisition.json`` for the trajectory runs, ``plan_log.json`` for
  ``--auto``); a folder holding captures but no ``dataset.yaml`` is never written into;
- a lock file ``.calibgraph.lock`` (the holder's pid, host, mode and start time, under an
  exclusive ``flock``) keeps a second process out while the run lasts. The kernel drops the
  ``flock`` when its process dies, however it dies, so a lock file left by a killed run is
  recognised as stale, said, and taken over. The lock is removed at the end of the run.

Claims nest within one process: the command line claims a dataset with every input it knows,
and the capture loop it calls claims it again with what the loop knows (the trajectory); the
inner claim checks its inputs against the record and adds them.
"""

from __future__ import annotations

import hashlib
import json
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from calibgraph.core.camera import Intrinsics
from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.core.version import __version__
from calibgraph.io.dataset import write_header
from calibgraph.io.files import output_folder, read_input_bytes, read_yaml
from calibgraph.io.lock import LOCK_NAME, RUN_NAMES, lock_folder, unlock_folder

__all__ = ["Claim", "claim_dataset", "content_sha256", "file_sha256", "write_or_check_header", "LOCK_NAME",
           "TRAJECTORY_RUNS"]

TRAJECTORY_RUNS = ("trajectory", "sim", "verify")  # the runs of a fixed trajectory (journal: acquisition.json)
INPUT_NAMES = {"workcell_sha256": "workcell", "world_sha256": "simulated world", "trajectory_sha256": "trajectory",
               "result_sha256": "stored result", "camera_files_sha256": "--intrinsics camera files"}
# inputs whose absence is a value: a run recorded without them was made without them (an --intrinsics
# file given to a resume of a run that had none changes the cameras' intrinsics as much as another file)
EXACT_INPUTS = ("camera_files_sha256",)
JOURNALS = {"auto": "plan_log.json", "trajectory": "acquisition.json"}


def _plain(x):
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def content_sha256(obj) -> str:
    """SHA-256 of a parsed mapping (or list) as canonical JSON."""
    text = json.dumps(_plain(obj), sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def file_sha256(path) -> str:
    """SHA-256 of a file's bytes."""
    return hashlib.sha256(read_input_bytes(path, "input file")).hexdigest()


class Claim:
    """A run's hold on its dataset folder: the lock and the ``made_by`` record to write.

    Attributes:
        out: the dataset folder.
        made_by: what ``dataset.yaml`` records (or will record) about the run that made it.
        recorded: the record found on disk (None for a new dataset or one that predates it).
    """

    def __init__(self, out: Path, mode: str, inputs: dict, recorded: dict | None):
        self.out, self.recorded = out, recorded
        self.made_by = dict(recorded) if recorded else {"mode": mode, "calibgraph": __version__}
        self.require(inputs)

    def require(self, inputs: dict) -> None:
        """Check ``inputs`` (key -> SHA-256) against the record and add the ones it lacks. An input of
        ``EXACT_INPUTS`` is checked even when None (not given) against a dataset that has a record."""
        for k, v in (inputs or {}).items():
            if k in EXACT_INPUTS and self.recorded is not None and self.recorded.get(k) != v:
                raise InputError(f"{self.out}: {_camera_files_change(self.recorded.get(k), v)}; resume with the same "
                                 "--intrinsics files as the run that started it, or choose a new --out (nothing was "
                                 "changed).")
            if v is None:
                continue
            if self.recorded and self.recorded.get(k) not in (None, v):
                raise InputError(f"{self.out}: this dataset was captured with a different {INPUT_NAMES.get(k, k)} "
                                 f"({k} differs); resume with the original one, or choose a new --out (nothing was "
                                 "changed).")
            self.made_by.setdefault(k, v)


    def record(self, files: dict | None) -> None:
        """Record where inputs were read from (name -> path; resolved), where the record has none."""
        for k, v in (files or {}).items():
            if v is not None:
                self.made_by.setdefault(k, str(Path(v).resolve()))


def _camera_files_change(recorded, given) -> str:
    if recorded is None:
        return "this dataset was captured without --intrinsics camera files, and this run gives some"
    if given is None:
        return "this dataset was captured with --intrinsics camera files, and this run gives none"
    return "this dataset was captured with other --intrinsics camera files (their intrinsics differ)"


_HELD: dict = {}  # resolved dataset folder -> the Claim this process holds on it


def _recorded(out: Path, mode: str, accept: tuple, resume: bool) -> dict | None:
    """The ``made_by`` record of the dataset in ``out`` when this run may continue it (None: a new
    dataset, or one that predates the record); :class:`InputError` when it may not."""
    head = out / "dataset.yaml"
    if not head.exists():
        if any(p.is_file() for d in ("captures", "images") for p in (out / d).glob("**/*")):
            raise InputError(f"{out}: holds captures or images but no dataset.yaml; it is not a capture this command "
                             "can continue: choose a new --out (nothing was changed).")
        return None
    if not resume:
        raise InputError(f"{out}: a dataset already exists here; pass --resume to continue it or choose a new --out.")
    d = read_yaml(head, "dataset header")
    rec = d.get("made_by")
    want = RUN_NAMES.get(mode, mode)
    if rec is None:
        journal = JOURNALS["auto" if "auto" in accept else "trajectory"]
        other = JOURNALS["trajectory" if "auto" in accept else "auto"]
        if (out / journal).is_file() and not (out / other).is_file():
            return None
        raise InputError(f"{out}: this dataset does not say which run made it and holds no {journal} of a {want} "
                         "run; --resume continues only a run of the same kind: choose a new --out (nothing was "
                         "changed).")
    if not isinstance(rec, dict) or rec.get("mode") not in accept:
        made = RUN_NAMES.get(rec.get("mode"), repr(rec.get("mode"))) if isinstance(rec, dict) else "an unknown run"
        raise InputError(f"{out}: this dataset was made by {made}; --resume continues only a run of the same kind "
                         f"({want}) with the same inputs: choose a new --out (nothing was changed).")
    return {str(k): v for k, v in rec.items()}


@contextmanager
def claim_dataset(out_dir, mode: str, inputs: dict | None = None, resume: bool = False, log=None,
                  accept: tuple | None = None, files: dict | None = None):
    """Hold the dataset folder ``out_dir`` for a run of ``mode`` (see the module docstring).

    Args:
        mode: 'sim' | 'trajectory' | 'auto' | 'verify', recorded for a new dataset.
        inputs: input name (``workcell_sha256``, ...) -> content hash, checked and recorded.
        resume: continue the dataset there (refused unless made by an accepted run with these inputs).
        log: receives the line saying that a stale lock was taken over.
        accept: the recorded modes this run may continue (default: ``mode`` only).
        files: record name (``workcell_file``) -> the input file's path, recorded (resolved) where the
            record has none and never checked.
    Yields:
        the :class:`Claim` (its ``made_by`` goes into ``dataset.yaml``).
    """
    out = Path(out_dir)
    accept = tuple(accept or (mode,))
    key = out.resolve()
    held = _HELD.get(key)
    if held is not None:  # claimed further out in this process: check and add what this level knows
        held.require(inputs or {})
        held.record(files)
        yield held
        return
    _recorded(out, mode, accept, resume)  # refuse before touching anything
    existed = out.exists()
    output_folder(out, "dataset folder")
    fd = lock_folder(out, mode, log or (lambda s: None))
    try:
        claim = Claim(out, mode, inputs or {}, _recorded(out, mode, accept, resume))  # again, under the lock
        claim.record(files)
        _HELD[key] = claim
        try:
            yield claim
        finally:
            _HELD.pop(key, None)
    finally:
        unlock_folder(out, fd)
        if not existed:
            try:
                out.rmdir()  # a run that wrote nothing leaves no empty folder behind
            except OSError:
                pass


def write_or_check_header(out: Path, target: Target, intr: dict, mode: str, claim: Claim) -> None:
    """Write ``dataset.yaml`` (with the claim's ``made_by``), or check that the existing one matches
    the target and the cameras' intrinsics, adding cameras new to it."""
    head = out / "dataset.yaml"
    if not head.exists():
        write_header(out, target, intr, mode=mode, extra={"made_by": claim.made_by})
        return
    d = read_yaml(head, "dataset header")
    old_t = Target.from_dict(d.get("target", {}))
    if old_t != target:
        raise InputError(f"{head}: the dataset was captured with target {old_t.to_dict()}, not {target.to_dict()}; "
                         "use the original target or a new --out.")
    cams = {c: Intrinsics.from_dict(v) for c, v in (d.get("cameras") or {}).items()}
    new = {}
    for c, k in intr.items():
        if c not in cams:
            new[c] = k  # a camera that was lost at the first start joins now
        elif not (np.allclose(cams[c].K, k.K, rtol=1e-6, atol=1e-6) and cams[c].width_px == k.width_px
                  and cams[c].height_px == k.height_px):
            raise InputError(f"{head}: camera {c!r} now reports different intrinsics than when the dataset was started "
                             "(another --intrinsics file than its run's, or its resolution or device changed): resume "
                             "with what the run started with, or start a new dataset (nothing was changed).")
    if new:
        extra = {k: v for k, v in d.items() if k not in ("format", "mode", "units", "frame_convention", "target",
                                                          "cameras", "solver")}
        extra.setdefault("made_by", claim.made_by)
        write_header(out, target, {**cams, **new}, mode=d.get("mode", mode), solver=d.get("solver"), extra=extra)
