"""A dataset folder's lock: one calibgraph process writes a dataset at a time.

The lock file ``.calibgraph.lock`` in the folder holds the holder's pid, host, run and start time
under an exclusive ``flock``. A second process that wants the folder (a capture, a ``--resume``,
a solve, an import) is refused in one line naming the holder. The kernel drops the ``flock`` when
its process dies, however it dies, so a lock file left by a killed run is recognised as stale,
said, and taken over. The lock file is removed when its holder lets go.

:func:`dataset_lock` is the context manager; the capture runs hold it through
:func:`calibgraph.acquire.claim.claim_dataset`, ``solve`` directly.
"""

from __future__ import annotations

import json
import os
import socket
import time
from contextlib import contextmanager
from pathlib import Path

from calibgraph.core.errors import InputError

try:  # POSIX; elsewhere (or on a file system without flock) the holder's pid decides, see _held_by_another
    import fcntl
except ImportError:  # pragma: no cover - not on the platforms calibgraph runs on
    fcntl = None

LOCK_NAME = ".calibgraph.lock"
# a refused run waits up to this long (tries x seconds) for a holder that has the flock but has not yet
# written its details (two runs started together), so the refusal can name it
HOLDER_WAIT_TRIES, HOLDER_WAIT_S = 100, 0.02
RUN_NAMES = {"sim": "`calibgraph sim`", "trajectory": "a trajectory capture (`calibgraph capture --trajectory`)",
             "auto": "`calibgraph capture --auto`", "verify": "`calibgraph capture --verify`",
             "solve": "`calibgraph solve`", "import": "`calibgraph import`"}


def _holder(fd: int) -> dict:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        return json.loads(os.read(fd, 4096).decode() or "{}")
    except (OSError, ValueError):
        return {}


def _describe(h: dict) -> str:
    if not h:
        return "a run that is just starting and has not yet written who it is"
    when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(h["started_unix_s"])) if "started_unix_s" in h else "?"
    return (f"process {h.get('pid', '?')} on {h.get('host', '?')}, {RUN_NAMES.get(h.get('mode'), 'a capture')}, "
            f"started {when}")


def _held_by_another(fd: int) -> bool:
    """Take the exclusive flock on the lock file ``fd``; True when another process holds it. Where
    flock is unavailable, the recorded holder's pid decides (held while that process lives)."""
    if fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return False
        except BlockingIOError:
            return True
        except OSError:  # a file system without flock: fall back on the pid
            pass
    h = _holder(fd)
    if h.get("pid") in (None, os.getpid()):  # a new lock file, or ours
        return False
    if h.get("host") != socket.gethostname():  # held from another machine: whether it lives cannot be told
        return True
    try:
        os.kill(int(h["pid"]), 0)
        return True
    except ProcessLookupError:
        return False
    except (OSError, ValueError):
        return True


def lock_folder(out: Path, mode: str, log=None) -> int:
    """Take the dataset's lock (see the module docstring); the open descriptor that holds it."""
    path, log = out / LOCK_NAME, log or (lambda s: None)
    for _ in range(20):
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        if _held_by_another(fd):
            h = _holder(fd)
            for _ in range(HOLDER_WAIT_TRIES):  # the holder is between its flock and writing who it is
                if h:
                    break
                time.sleep(HOLDER_WAIT_S)
                h = _holder(fd)
            os.close(fd)
            raise InputError(f"{out}: another calibgraph run is writing this dataset ({_describe(h)}); wait for it to "
                             "end (or stop it), then run again (nothing was changed).")
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if not same:  # the previous holder removed the file between our open and our lock: take the new one
            os.close(fd)
            continue
        old = _holder(fd)
        if old.get("pid") is not None:
            log(f"{out}: taking over the lock left by {_describe(old)}, which is no longer running")
        me = {"pid": os.getpid(), "host": socket.gethostname(), "mode": mode, "started_unix_s": time.time()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(me).encode(), 0)
        os.fsync(fd)
        return fd
    raise InputError(f"{out}: could not take the dataset's lock {path} (it keeps being replaced); try again.")


def unlock_folder(out: Path, fd: int) -> None:
    path = out / LOCK_NAME
    try:
        if os.stat(path).st_ino == os.fstat(fd).st_ino:
            path.unlink()
    except OSError:
        pass
    os.close(fd)  # closing drops the flock


@contextmanager
def dataset_lock(folder, mode: str, log=None):
    """Hold the lock of the existing folder ``folder`` for a run of ``mode`` (a key of
    :data:`RUN_NAMES`) while the block runs; :class:`InputError` naming the holder when another
    process has it. A folder this user cannot write is not locked (nothing can be written there,
    by this process or another of this user)."""
    out = Path(folder)
    fd = None
    if os.access(out, os.W_OK | os.X_OK):
        try:
            fd = lock_folder(out, mode, log)
        except PermissionError:  # writable by its mode bits, yet not here (a read-only mount, an ACL)
            fd = None
    try:
        yield
    finally:
        if fd is not None:
            unlock_folder(out, fd)
