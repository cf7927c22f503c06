"""Reading target spec files (``datasets/targets/*.yaml``)."""

from __future__ import annotations

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.io.files import read_yaml
from calibgraph.io.shipped import resolve_shipped, shipped_path


def load_target(path) -> Target:
    """Read a target spec YAML file (keys as in ``Target``); a shipped board's name or documented
    path (``a4_7x10_25mm``, ``a4_54``, ``datasets/targets/a4_7x10_25mm.yaml``) reads the shipped
    file from any folder (:mod:`calibgraph.io.shipped`)."""
    p = resolve_shipped(path, "target")
    if not p.exists() and not p.is_symlink():
        shipped_path("target", str(path))  # raises: no such file, nor a shipped board (naming them)
    d = read_yaml(p, "target spec")
    return Target.from_dict(d.get("target", d))


def target_option(path, flag: str = "--target") -> Target | None:
    """The board a command's ``--target SPEC.yaml`` gives (None when not given), its errors naming the flag."""
    if path is None:
        return None
    try:
        return load_target(path)
    except InputError as e:
        msg = str(e)
        raise InputError(msg if msg.startswith(str(path)) else f"{flag} {path}: {msg}") from None
