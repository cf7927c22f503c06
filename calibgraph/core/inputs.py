"""Reading an input file: only a regular file is read, never waited on.

Every reader of a user's file (captures, camera files, results, images, workcells, trajectories,
journals) goes through :func:`read_input_bytes`: a pipe (FIFO), a device, a socket or a folder
given where a file is expected is refused in one :class:`InputError` instead of hanging the run
or reading a stream forever. It lives in ``core`` so that every stage can use it (``io.files``
re-exports it).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from calibgraph.core.errors import InputError


def read_input_bytes(path, what: str, limit: int | None = None) -> bytes:
    """The content of the input file ``path`` (its first ``limit`` bytes when given). Only a regular
    file is read: a folder, a pipe (FIFO), a device or a socket is refused with one
    :class:`InputError`, never waited on (the file is opened non-blocking and checked before
    anything is read)."""
    p = Path(path)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except OSError as e:
        raise InputError(f"{p}: cannot read {what}: {e}") from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise InputError(f"{p}: cannot read {what}: it is a folder, not a file.")
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{p}: cannot read {what}: not a regular file (a pipe, a device or a socket); give the "
                             f"{what} as a file.")
        chunks, n = [], 0
        while limit is None or n < limit:
            b = os.read(fd, 1 << 20 if limit is None else min(1 << 20, limit - n))
            if not b:
                break
            chunks.append(b)
            n += len(b)
        return b"".join(chunks)
    except OSError as e:
        raise InputError(f"{p}: cannot read {what}: {e}") from None
    finally:
        os.close(fd)


def read_input_text(path, what: str) -> str:
    """:func:`read_input_bytes` decoded as UTF-8 (an undecodable file is one :class:`InputError`)."""
    try:
        return read_input_bytes(path, what).decode("utf-8")
    except UnicodeDecodeError as e:
        raise InputError(f"{Path(path)}: cannot read {what}: not UTF-8 text ({e.reason} at byte {e.start}).") from None
