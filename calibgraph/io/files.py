"""Reading input files with one clear error instead of a parser traceback, and the one way
calibgraph writes a file: atomically, and only onto a regular file or a new path."""

from __future__ import annotations

import errno
import glob
import hashlib
import os
import stat
from pathlib import Path
from typing import Callable

from calibgraph.core.errors import CalibgraphError, InputError
from calibgraph.core.inputs import read_input_bytes, read_input_text  # noqa: F401  (the one reader of input files)


def read_yaml(path, what: str, mapping: bool = True, empty_ok: bool = False):
    """Parse ``path``; on an unreadable or malformed file raise ``InputError`` naming it and ``what``.

    With ``mapping`` the document must be a YAML mapping (``{}`` for an empty file when ``empty_ok``).
    """
    return parse_yaml(read_input_bytes(path, what), path, what, mapping, empty_ok)


def parse_yaml(raw: bytes, path, what: str, mapping: bool = True, empty_ok: bool = False):
    """:func:`read_yaml` of bytes already read from ``path``."""
    import yaml

    p = Path(path)
    try:
        d = yaml.safe_load(raw.decode("utf-8"))
    except UnicodeDecodeError as e:
        raise InputError(f"{p}: cannot read {what}: {e}") from None
    except yaml.YAMLError as e:
        raise InputError(f"{p}: cannot read {what}: {yaml_error_line(e)}") from None
    if d is None and empty_ok:
        d = {}
    if mapping and not isinstance(d, dict):
        raise InputError(f"{p}: {what} must be a YAML mapping.")
    return d


def image_size(path):
    """(width, height) of an image file from its header (PNG, or anything OpenCV decodes), or None
    for a file that cannot be read or decoded (a FIFO or a device is not waited on)."""
    try:
        head = read_input_bytes(path, "image file", limit=24)
    except InputError:
        return None
    if head[:8] == b"\x89PNG\r\n\x1a\n" and len(head) >= 24 and head[12:16] == b"IHDR":
        wh = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        return wh if min(wh) > 0 else None  # a damaged header: the detector names the file, and it costs one view
    import cv2
    import numpy as np

    try:
        img = cv2.imdecode(np.frombuffer(read_input_bytes(path, "image file"), np.uint8), cv2.IMREAD_UNCHANGED)
    except (InputError, cv2.error):
        return None
    return None if img is None else (img.shape[1], img.shape[0])


def is_opencv_storage(raw: bytes) -> bool:
    """True when ``raw`` is an OpenCV FileStorage document, which a YAML parser cannot read: XML, YAML
    with OpenCV 3/4's ``%YAML:1.0`` header, or YAML with its ``!!opencv-matrix`` nodes (OpenCV 5)."""
    head = raw.lstrip()[:32]
    return head.startswith((b"%YAML:", b"<?xml", b"<opencv_storage>")) or b"!!opencv-" in raw


def _error_line(e: BaseException) -> str:
    """The last line of an exception's message (of its cause when it wraps one), without OpenCV's
    source location."""
    cause = e.__cause__ or e
    text = str(cause).strip()
    return text.splitlines()[-1].split(" error: ")[-1] if text else type(cause).__name__


def read_opencv_storage(path, what: str, raw: bytes | None = None) -> dict:
    """The top-level nodes of an OpenCV FileStorage file (YAML or XML) as a dict: strings, ints,
    reals, and matrices as numpy arrays. ``raw``: its bytes when already read."""
    import cv2

    p = Path(path)
    raw = read_input_bytes(p, what) if raw is None else raw
    out, fs = {}, None
    try:
        fs = cv2.FileStorage(raw.decode("utf-8"), cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
        if not fs.isOpened():
            raise InputError(f"{p}: cannot read {what} as an OpenCV FileStorage file.")
        for key in fs.root().keys():
            node = fs.getNode(key)
            if node.isString():
                out[key] = node.string()
            elif node.isInt():
                out[key] = int(node.real())
            elif node.isReal():
                out[key] = node.real()
            elif node.isSeq():  # a plain list of numbers
                out[key] = [node.at(i).real() for i in range(node.size())]
            else:  # a matrix (None for anything else)
                out[key] = node.mat()
    except (cv2.error, SystemError, UnicodeDecodeError) as e:  # OpenCV 5 wraps its parse error in a SystemError
        raise InputError(f"{p}: cannot read {what} as an OpenCV FileStorage file: {_error_line(e)}") from None
    finally:
        if fs is not None:
            fs.release()
    return out


def yaml_error_line(e) -> str:
    """A YAML parser error in one line: what and where (line, column)."""
    mark = getattr(e, "problem_mark", None)
    what = getattr(e, "problem", None) or str(e).splitlines()[0]
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    ctx = getattr(e, "context", None)
    return f"not valid YAML{where}: {what}" + (f" ({ctx})" if ctx else "")


def _pathconf(path: Path, name: str, default: int) -> int:
    """``os.pathconf`` of the nearest existing folder at or above ``path`` (``default`` when unknown)."""
    p = Path(os.path.abspath(path))
    for a in (p, *p.parents):
        try:
            if a.is_dir():
                v = os.pathconf(a, name)
                return int(v) if v and v > 0 else default
        except (OSError, ValueError):
            continue
    return default


def name_max(path) -> int:
    """The longest file name (bytes) the file system at ``path`` allows (255 on Linux file systems)."""
    return _pathconf(Path(path), "PC_NAME_MAX", 255)


def shown_path(path, n: int = 60) -> str:
    """A path short enough for a one-line message: its start and its end."""
    s = str(path)
    return s if len(s) <= 2 * n else f"{s[:n]}…{s[-n:]}"


def check_path_limits(path, what: str = "output path") -> None:
    """Refuse, before any work, a path the file system cannot hold: longer than its path limit
    (PATH_MAX, 4096 bytes on Linux) or with a name longer than its name limit (NAME_MAX, 255 bytes);
    one :class:`InputError` naming the limit (the write would otherwise fail after the work, or every
    look at the path raise)."""
    a = os.fsencode(os.path.abspath(path))
    # asked of a folder the path starts in (a 5,000-byte path has no folder the system can look at)
    limit = _pathconf(Path(os.path.dirname(os.fsdecode(a[:1024])) or "/"), "PC_PATH_MAX", 4096)
    if len(a) >= limit:
        raise InputError(f"{shown_path(path)}: the path is {len(a)} bytes long and the file system allows {limit - 1}; "
                         f"choose a shorter {what} (nothing was changed).")
    most = name_max(path)
    for part in Path(os.fsdecode(a)).parts:
        n = len(os.fsencode(part))
        if n > most:
            raise InputError(f"{shown_path(path)}: the name {shown_path(part, 20)} is {n} bytes long and the file system "
                             f"allows {most} per name; choose a shorter {what} (nothing was changed).")


def symlink_loop(path, what: str = "output path") -> InputError:
    """The refusal of a path that is, or lies under, a symlink loop."""
    try:
        own = Path(path).is_symlink()
    except OSError:
        own = False
    where = "is a symlink loop" if own else "lies under a symlink loop"
    return InputError(f"{shown_path(path)}: {where} (following its links comes back to them); remove the link or "
                      f"choose another {what} (nothing was changed).")


def writable_target(path, example: str = "result.json") -> Path:
    """The file that writing ``path`` should replace: ``path`` itself, or the file a symlink points
    to (the link is kept). Refuses, with the fix, a path the file system cannot hold
    (:func:`check_path_limits`), a directory, a device or any other non-regular file (judged by what
    ``path`` opens, so ``/proc/self/fd/1`` on a pipe is a pipe), a symlink loop, and a parent that is
    not a directory."""
    if str(path) == "":
        raise InputError("an empty output path was given; name a file.")
    check_path_limits(path)
    p = Path(path)
    try:
        st = os.stat(p)  # what the path opens: a symlink's target, a /proc link's pipe
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise InputError(f"{path}: a parent of this path is a file, not a folder; choose another output path.") from None
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise symlink_loop(path) from None
        raise InputError(f"{path}: cannot write here ({e.strerror}); choose another output path.") from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise InputError(f"{path}: is a folder; name a file inside it (e.g. {Path(path) / example}).")
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: is not a regular file (device, pipe or socket); "
                         "calibgraph writes only regular files, choose another output path.")
    if p.is_symlink():
        try:
            p = p.resolve()
        except (RuntimeError, OSError):  # a loop (RuntimeError before Python 3.13)
            raise symlink_loop(path) from None
        if st is None:  # a dangling link is written through: its target must fit the file system too
            check_path_limits(p)
    return p


def output_file(path, what: str = "output file", example: str = "result.json") -> Path:
    """Check, before any work is done, that ``path`` can be written by :func:`atomic_write_via`:
    a regular file or a new path (a symlink is written through: the file it points to is replaced,
    the link kept), in a folder that exists or can be created and is writable. Raises
    :class:`InputError` with the fix; returns ``path``."""
    target = writable_target(path, example)
    parent = target.parent
    while not parent.exists() and not parent.is_symlink() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise InputError(f"{path}: {parent} is a file, not a folder; choose another {what}.")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{path}: the folder {parent} is not writable (read-only); fix its permissions or choose "
                         f"another {what}.")
    return Path(path)


def output_folder(path, what: str = "output folder", empty: bool = False) -> Path:
    """Make sure ``path`` is a folder calibgraph may write files into, creating it when missing.

    Refuses, with the fix, an existing file (or device) at ``path``, a parent that is a file, a
    folder that cannot be created or written (read-only), and, with ``empty``, a folder that already
    holds files. Returns ``path``.
    """
    p = Path(path)
    if str(path) == "":
        raise InputError(f"an empty {what} was given; name a folder.")
    if p.exists() and not p.is_dir():
        kind = "a file" if p.is_file() else "a device, pipe or socket"
        raise InputError(f"{path}: is {kind}, not a folder; the {what} must be a folder "
                         f"(e.g. {p.with_suffix('')}_out); nothing was written.")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{path}: a parent of this path is a file, not a folder; choose another {what}.") from None
    except OSError as e:
        raise InputError(f"{path}: cannot create the {what} ({e.strerror}); choose another one.") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise InputError(f"{path}: the {what} is not writable (read-only); fix its permissions or choose another one.")
    if empty and any(p.iterdir()):
        raise InputError(f"{path}: exists and is not empty; give a new {what}.")
    return p


def _short_stem(name: str) -> str:
    """A short stand-in for a file name in its temporary's name (a hash of it)."""
    return "cg" + hashlib.sha256(os.fsencode(name)).hexdigest()[:16]


def temporary_name(target: Path, pid: int | None = None, suffix: str = "") -> str:
    """The hidden name of ``target``'s temporary file while it is written: ``.NAME.tmpPID`` (+
    ``suffix``), or, where that would pass the file system's name limit (a valid 250-byte NAME),
    ``.cgHASH.tmpPID`` with a hash of NAME, in the same folder."""
    pid = os.getpid() if pid is None else pid
    name = f".{target.name}.tmp{pid}{suffix}"
    if len(os.fsencode(name)) <= name_max(target.parent):
        return name
    return f".{_short_stem(target.name)}.tmp{pid}{suffix}"


def _remove_stale_temporaries(target: Path) -> None:
    """Temporary files of ``target`` left by a writer that was killed (its process is gone) are removed."""
    import re

    stems = [target.name, _short_stem(target.name)]
    leftovers = []
    for stem in stems:
        try:
            leftovers += list(target.parent.glob(f".{glob.escape(stem)}.tmp*"))
        except (OSError, ValueError):
            continue
    for p in leftovers:
        m = next((m for m in (re.match(rf"\.{re.escape(stem)}\.tmp(\d+)", p.name) for stem in stems) if m), None)
        if not m or int(m.group(1)) == os.getpid():
            continue
        try:
            os.kill(int(m.group(1)), 0)
            continue  # its writer is still running
        except ProcessLookupError:
            pass
        except OSError:
            continue
        try:
            p.unlink()
        except OSError:
            pass


def atomic_write_via(path, write: Callable[[Path], None], tmp_suffix: str = "") -> Path:
    """Write ``path`` so that a crash or a failed write leaves either the old or the new content.

    ``write(tmp)`` writes the new content to a temporary file beside the target, which is then
    fsynced and renamed over it. The temporary name (:func:`temporary_name`) is hidden, fits the
    file system's name limit and does not end like the target (a reader globbing
    ``captures/*.json`` never sees one left by a kill), unless a writer needs
    an extension to pick its format (``tmp_suffix``, e.g. ``.yaml`` for OpenCV's FileStorage). Errors of the file system become one ``InputError`` naming the
    path; the temporary file never stays behind. Returns the path written.
    """
    tmp = begin_atomic_write(path, tmp_suffix)
    try:
        write(tmp)
    except OSError as e:
        _discard(tmp)
        raise InputError(f"{shown_path(path)}: cannot write ({e.strerror or e}); nothing was changed there.") from None
    except BaseException:
        _discard(tmp)
        raise
    return finish_atomic_write(tmp, path)


def begin_atomic_write(path, tmp_suffix: str = "") -> Path:
    """The temporary file (:func:`temporary_name`) a writer that streams into ``path`` over time (a
    recording) writes, its folder made and a killed writer's leftovers removed; :func:`finish_atomic_write`
    moves it into place (:func:`atomic_write_via` is both, for a writer done in one call)."""
    target = writable_target(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{path}: a parent of this path is a file, not a folder; choose another output path.") from None
    except OSError as e:
        raise InputError(f"{path}: cannot create its folder ({e.strerror}); choose another output path.") from None
    _remove_stale_temporaries(target)
    return target.with_name(temporary_name(target, suffix=tmp_suffix))


def finish_atomic_write(tmp: Path, path) -> Path:
    """``tmp`` (from :func:`begin_atomic_write`) fsynced and renamed over ``path``; an error of the file
    system is one ``InputError`` naming the path, and the temporary file never stays behind."""
    try:
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, writable_target(path))
    except OSError as e:
        raise InputError(f"{shown_path(path)}: cannot write ({e.strerror or e}); nothing was changed there.") from None
    finally:
        _discard(tmp)
    return Path(path)


def _discard(tmp: Path) -> None:
    try:
        tmp.unlink()
    except OSError:  # replaced already (or never made)
        pass


def atomic_write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_write_via`)."""
    return atomic_write_via(path, lambda tmp: tmp.write_bytes(data))


def atomic_write_png(path, image) -> Path:
    """Encode ``image`` (a numpy array) as PNG and write it to ``path`` atomically."""
    import cv2
    import numpy as np

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image))
    if not ok:
        raise CalibgraphError(f"{path}: could not encode the image as PNG.")
    return atomic_write_bytes(Path(path), buf.tobytes())


def atomic_write_text(path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_write_via`)."""
    return atomic_write_bytes(path, text.encode("utf-8"))
