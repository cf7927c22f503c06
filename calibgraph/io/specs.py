"""Reading target spec files (``datasets/targets/*.yaml``)."""

from __future__ import annotations

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.io.files import read_yaml


def load_target(path) -> Target:
    """Read a target spec YAML file (keys as in ``Target``)."""

    d = read_yaml(path, "target spec")
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
