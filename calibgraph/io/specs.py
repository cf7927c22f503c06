"""Reading target spec files (``datasets/targets/*.yaml``)."""

from __future__ import annotations

from calibgraph.core.targets import Target
from calibgraph.io.files import read_yaml


def load_target(path) -> Target:
    """Read a target spec YAML file (keys as in ``Target``)."""

    d = read_yaml(path, "target spec")
    return Target.from_dict(d.get("target", d))
