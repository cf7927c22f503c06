"""The package is layered in data-flow order and imports point one way only.

core → io → detect → solve → plan → acquire → report, with sim and cli at the edge. A module may
import calibgraph modules of its own stage or an earlier one, never a later one, wherever the
import statement stands (module level or inside a function). Outside ``cli`` no calibgraph import
hides inside a function: such an import could only be there to dodge a cycle (lazy imports of heavy
third-party packages such as MuJoCo, rerun or cv2 are fine and not checked here). Nothing imports
the package root, which re-exports the public API and so sits above every stage.

The solver's stage is itself rooms on floors (issue 48): it holds no flat modules, only subpackages,
each with an opening docstring saying what it owns, and a room imports only its own modules and
those of rooms on lower floors (``SOLVER_FLOORS``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parents[1] / "calibgraph"
STAGES = ("core", "io", "detect", "solver", "plan", "acquire", "report", "sim", "cli")
LAZY_OK = {"cli"}  # commands import their stage lazily so that `calibgraph --help` stays fast
# the solver's rooms, ground floor first (a floor may hold several rooms, which then do not import each other)
SOLVER_FLOORS = (("output",), ("terms",), ("robot",), ("fit",), ("camera",), ("uncertainty",), ("changes",), ("solve",))
SOLVER_ROOMS = tuple(r for floor in SOLVER_FLOORS for r in floor)


def _module_name(path: Path) -> str:
    rel = path.relative_to(path.parents[len(path.parts) - 1 - path.parts.index("calibgraph")]).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imports(path: Path):
    """(imported module, line, at module level) for every calibgraph import in ``path``."""
    tree = ast.parse(path.read_text(), str(path))
    top = {id(n) for n in tree.body}
    me = _module_name(path).split(".")
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = me if is_pkg else me[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            names = [mod]
            if mod == "calibgraph" or mod.endswith(tuple("." + s for s in STAGES)):
                names = [f"{mod}.{a.name}" if mod != "calibgraph" else f"calibgraph.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for m in names:
            if m == "calibgraph" or m.startswith("calibgraph."):
                yield m, node.lineno, id(node) in top


def _stage(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in STAGES else None


def layering_violations(pkg: Path = PKG) -> list[str]:
    out = []
    for path in sorted(pkg.rglob("*.py")):
        me = _module_name(path)
        my_stage = _stage(me)
        if my_stage is None:  # the package root and __main__: above every stage
            continue
        for mod, line, at_top in _imports(path):
            where = f"{path.relative_to(pkg.parent).as_posix()}:{line}"
            target = _stage(mod)
            if target is None:
                out.append(f"{where}: imports the package root ({mod}); import from its stage instead")
                continue
            if STAGES.index(target) > STAGES.index(my_stage):
                out.append(f"{where}: {my_stage} imports {mod} from the later stage {target}")
            if not at_top and my_stage not in LAZY_OK:
                out.append(f"{where}: function-level import of {mod}; import it at module level")
    return out


def test_imports_point_one_way():
    bad = layering_violations()
    assert not bad, "layering violations:\n" + "\n".join(bad)


def test_the_check_catches_an_upward_import(tmp_path):
    """The check is not vacuous: an injected upward import (core → solver) is reported."""
    import shutil

    copy = tmp_path / "calibgraph"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    target = copy / "core" / "transforms.py"
    target.write_text(target.read_text() + "\nfrom calibgraph.solver.output.result import Result  # injected\n")
    bad = layering_violations(copy)
    assert any("core/transforms.py" in b and "later stage solver" in b for b in bad), bad


@pytest.mark.parametrize("stage", STAGES)
def test_every_stage_is_a_package(stage):
    assert (PKG / stage / "__init__.py").is_file()


def private_imports(root: Path = PKG) -> list:
    """``module: imports _name from calibgraph.x`` for every private name (one leading underscore, not a
    dunder) a module of ``root`` or of drivers/ imports from another calibgraph module (issue 48)."""
    out = []
    for f in sorted(list(root.rglob("*.py")) + list((root.parent / "drivers").rglob("*.py"))):
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("calibgraph"):
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        out.append(f"{f.relative_to(root.parent)}:{node.lineno}: imports {a.name} from {node.module}")
    return out


def test_no_private_name_is_imported_across_modules():
    bad = private_imports()
    assert not bad, "private names imported across modules (make them public where they are shared):\n" + "\n".join(bad)


def test_the_private_import_check_catches_one(tmp_path):
    import shutil

    copy = tmp_path / "calibgraph"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "drivers").mkdir()
    target = copy / "report" / "live_view.py"
    target.write_text(target.read_text() + "\nfrom calibgraph.solver.terms.factors import _injected  # noqa\n")
    bad = private_imports(copy)
    assert any("live_view.py" in b and "_injected" in b for b in bad), bad


def _room(module: str) -> str | None:
    parts = module.split(".")
    return parts[2] if len(parts) > 2 and parts[1] == "solver" and parts[2] in SOLVER_ROOMS else None


def room_violations(pkg: Path = PKG) -> list[str]:
    """Imports between the solver's rooms that point at the same or a higher floor (or at the solver
    package itself rather than a room)."""
    floor = {r: i for i, rooms in enumerate(SOLVER_FLOORS) for r in rooms}
    out = []
    for path in sorted((pkg / "solver").rglob("*.py")):
        me = _room(_module_name(path))
        if me is None:  # solver/__init__.py: the stage's docstring, no imports
            continue
        for mod, line, _ in _imports(path):
            if _stage(mod) != "solver":
                continue
            where = f"{path.relative_to(pkg.parent).as_posix()}:{line}"
            target = _room(mod)
            if target is None:
                out.append(f"{where}: imports {mod}, not a module of one of the solver's rooms")
            elif target != me and floor[target] >= floor[me]:
                out.append(f"{where}: the room {me} imports {mod} from the room {target}, not on a lower floor")
    return out


def test_the_solver_holds_rooms_only():
    solver = PKG / "solver"
    flat = sorted(p.name for p in solver.glob("*.py") if p.name != "__init__.py")
    assert not flat, f"flat modules in calibgraph/solver/ (put each in a room): {flat}"
    rooms = sorted(p.name for p in solver.iterdir() if p.is_dir() and p.name != "__pycache__")
    assert rooms == sorted(SOLVER_ROOMS), f"the solver's rooms {rooms} are not SOLVER_FLOORS' {sorted(SOLVER_ROOMS)}"


@pytest.mark.parametrize("room", SOLVER_ROOMS)
def test_every_solver_room_is_a_package_that_says_what_it_owns(room):
    path = PKG / "solver" / room / "__init__.py"
    assert path.is_file(), f"solver/{room} is not a package"
    tree = ast.parse(path.read_text(), str(path))
    doc = ast.get_docstring(tree)
    assert doc and 2 <= len(doc.strip().splitlines()) <= 5, f"solver/{room}/__init__.py: an opening docstring of 2-5 lines"
    assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))], \
        f"solver/{room}/__init__.py imports something: a room's package imports nothing"
    nested = [p.name for p in (PKG / "solver" / room).iterdir() if p.is_dir() and p.name != "__pycache__"]
    assert not nested, f"solver/{room} holds folders {nested}: a room is one level of modules"


def test_solver_rooms_import_down_only():
    bad = room_violations()
    assert not bad, "solver room violations:\n" + "\n".join(bad)


def test_the_room_check_catches_an_upward_import(tmp_path):
    """The room check is not vacuous: terms importing the solve room, and a room importing the
    solver package, are both reported."""
    import shutil

    copy = tmp_path / "calibgraph"
    shutil.copytree(PKG, copy, ignore=shutil.ignore_patterns("__pycache__"))
    target = copy / "solver" / "terms" / "keys.py"
    target.write_text(target.read_text() + "\nfrom calibgraph.solver.solve.batch import solve  # injected\n"
                      "import calibgraph.solver  # injected\n")
    bad = room_violations(copy)
    assert any("terms/keys.py" in b and "room terms imports calibgraph.solver.solve.batch" in b for b in bad), bad
    assert any("terms/keys.py" in b and "imports calibgraph.solver, not a module" in b for b in bad), bad
