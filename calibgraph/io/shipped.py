"""The files calibgraph ships (``datasets/``: target specs, workcells, tolerances), found from any folder.

A wheel carries them as package data (``calibgraph/datasets/<folder>/*.yaml``, see setup.py); a
clone or an editable install reads the clone's own ``datasets/``. Wherever a command takes one of
these files it also takes its shipped *name* (``a4_7x10_25mm``, ``default``), an alias of it
(``a4_54``), or its documented path (``datasets/targets/a4_7x10_25mm.yaml``), which works from any
folder: a path that exists is always read as given (a user's own file wins), and only a path that
does not exist is looked up among the shipped files.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

from calibgraph.core.errors import InputError
from calibgraph.core.targets import Target
from calibgraph.io.files import read_yaml

__all__ = ["KINDS", "ALIASES", "shipped_root", "shipped_names", "shipped_path", "resolve_shipped",
           "canonical_name", "target_name"]

# kind -> folder under datasets/
KINDS = {"target": "targets", "workcell": "workcells", "tolerances": "tolerances"}

# kind -> {alias: shipped name}; the names of each board before it had one
ALIASES = {
    "target": {"a4_54": "a4_7x10_25mm", "a4": "a4_7x10_25mm", "54": "a4_7x10_25mm",
               "thesis": "thesis_5x4_46mm", "thesis_46": "thesis_5x4_46mm", "5x4": "thesis_5x4_46mm"},
    "workcell": {},
    "tolerances": {},
}

_PACKAGE = Path(__file__).resolve().parents[1]  # calibgraph/


def _is_root(d: Path) -> bool:
    return all((d / f).is_dir() for f in KINDS.values()) and (d / "targets" / "a4_7x10_25mm.yaml").is_file()


def shipped_root() -> Path:
    """The folder holding the shipped ``targets/``, ``workcells/`` and ``tolerances/``: the wheel's
    package data, else the clone's ``datasets/`` beside the package."""
    for d in (_PACKAGE / "datasets", _PACKAGE.parent / "datasets"):
        if _is_root(d):
            return d
    raise InputError("calibgraph's shipped files (targets, workcells, tolerances) are missing from this "
                     f"installation (looked in {_PACKAGE / 'datasets'}); reinstall calibgraph.")


def shipped_names(kind: str) -> list:
    """The shipped names of ``kind`` (file stems), sorted."""
    return sorted(p.stem for p in (shipped_root() / KINDS[kind]).glob("*.yaml"))


def canonical_name(kind: str, name: str) -> str | None:
    """The shipped name ``name`` stands for (itself, an alias, ``NAME.yaml``, a documented
    ``datasets/<folder>/NAME.yaml`` path), or None."""
    s = str(name).strip().replace("\\", "/")
    folder = KINDS[kind]
    for prefix in (f"datasets/{folder}/", f"{folder}/"):
        i = s.rfind(prefix)
        if i >= 0 and (i == 0 or s[i - 1] == "/"):
            s = s[i + len(prefix):]
            break
    if "/" in s:
        return None
    stem = s[:-5] if s.lower().endswith(".yaml") else s[:-4] if s.lower().endswith(".yml") else s
    stem = ALIASES[kind].get(stem.lower(), stem)
    return stem if stem in shipped_names(kind) else None


def shipped_path(kind: str, name: str) -> Path:
    """The shipped file of ``name`` (see :func:`canonical_name`); InputError listing the names otherwise."""
    n = canonical_name(kind, name)
    if n is None:
        raise InputError(f"{name}: no such file, nor a shipped {kind} (shipped: {', '.join(shipped_names(kind))}"
                         + ("; calibgraph target list shows them" if kind == "target" else "") + ").")
    return shipped_root() / KINDS[kind] / f"{n}.yaml"


def resolve_shipped(path, kind: str) -> Path:
    """``path`` as given when it exists (or names no shipped file), else the shipped file it names.

    A path that neither exists nor names a shipped file is returned unchanged, so the caller's
    reader says what it always said about a missing file."""
    p = Path(path)
    if p.exists() or p.is_symlink():
        return p
    n = canonical_name(kind, str(path))
    return p if n is None else shipped_root() / KINDS[kind] / f"{n}.yaml"


@lru_cache(maxsize=1)
def _shipped_specs() -> tuple:
    out = []
    for n in shipped_names("target"):
        try:
            d = read_yaml(shipped_root() / "targets" / f"{n}.yaml", "target spec")
            out.append((n, Target.from_dict(d.get("target", d)).to_dict()))
        except InputError:
            continue
    return tuple(out)


def target_name(target) -> str | None:
    """The shipped name of a :class:`~calibgraph.core.targets.Target` with exactly this spec, or None."""
    want = target.to_dict()
    return next((n for n, d in _shipped_specs() if d == want), None)
