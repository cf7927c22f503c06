"""The package version, in its own module so that any layer can read it without importing the package root,
and how a file format's version compares with the one this version reads."""

from __future__ import annotations

__version__ = "0.1.0"


def format_age(fmt: str, current: str) -> str | None:
    """'older' or 'newer' when ``fmt`` is another version of the file format ``current`` ('name/N',
    N an integer: 'calibgraph-result/1'), else None (not a version of it)."""
    name, _, n = current.rpartition("/")
    head, _, m = str(fmt).rpartition("/")
    if head != name or not m.isdigit() or not n.isdigit() or int(m) == int(n):
        return None
    return "older" if int(m) < int(n) else "newer"
