"""Reading YAML input files with one clear error instead of a parser traceback."""

from __future__ import annotations

from pathlib import Path

from .errors import InputError


def read_yaml(path, what: str, mapping: bool = True, empty_ok: bool = False):
    """Parse ``path``; on an unreadable or malformed file raise ``InputError`` naming it and ``what``.

    With ``mapping`` the document must be a YAML mapping (``{}`` for an empty file when ``empty_ok``).
    """
    import yaml

    p = Path(path)
    try:
        d = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise InputError(f"{p}: cannot read {what}: {e}") from None
    if d is None and empty_ok:
        d = {}
    if mapping and not isinstance(d, dict):
        raise InputError(f"{p}: {what} must be a YAML mapping.")
    return d
