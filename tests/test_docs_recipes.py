"""Every shell block of README.md and docs/guide.md runs verbatim on the simulated cell, and the
figures the README's tour and docs/accuracy.md print are those scripts/tour_figures.py saved.

A block runs in a fresh folder (``datasets/`` and ``scripts/`` linked in) with ``bash -e``; nothing
but an exit code of 0 passes. An HTML comment right before a block says what it needs
(``<!-- docs-test: ... -->``, visible in the docs' source):

- ``needs NAME ...``: files the recipe leaves to the user, made here from the simulated default
  cell (3 x L515 at 3 m): ``cell.yaml`` (its workcell file), ``DATASET`` (a 12-pose simulated
  capture), ``traj.yaml`` (the trajectory that capture followed), ``session/`` (close-range
  images per camera, ``calibgraph sim --intrinsics-session``);
- ``continues``: runs in the previous block's folder (the tour's solve reads the sim's output);
- ``skip NAME: why``: not run (a real robot or camera, a viewer window, the suite itself); the
  skipped names are listed here, so a new one is a deliberate change;
- ``cheap NAME: `A` -> `B` ; ...``: run with A replaced by B, a smaller equivalent of a block that takes
  minutes on the demo's cell (the README's 30-pose tour takes 3 min on a loaded 2-core machine);
  scripts/tour_figures.py runs those verbatim for the figures.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import require_sim

ROOT = Path(__file__).resolve().parents[1]
PAGES = (ROOT / "README.md", ROOT / "docs" / "guide.md")
FIGURES = ROOT / "scripts" / "results" / "tour_figures.json"
SKIPPED = {  # name -> why (the docs' markers say the same)
    "suite": "the test suite itself",
    "own-cell-capture": "a real robot (Franka) and cameras",
    "own-cell-verify": "a real robot (Franka) and cameras",
    "capture-franka": "a real robot (Franka) and cameras",
    "capture-auto-franka": "a real robot (Franka) and cameras",
    "verify-franka": "a real robot (Franka) and cameras",
    "view": "opens the rerun viewer (a window)",
    "intrinsics-live-camera": "a real camera",
    "rosbag": "a ROS 2 recording of a real cell (tests/test_rosbag2.py imports synthetic ones)",
}

pytestmark = [pytest.mark.sim, pytest.mark.slow]


def blocks(page: Path) -> list:
    """(name, shell text, directives) of every ```bash block of ``page``, in order."""
    text = page.read_text()
    out = []
    for m in re.finditer(r"((?:^[ \t]*<!-- docs-test:[^\n]*-->\n)*)^[ \t]*```bash\n(.*?)^[ \t]*```", text, re.M | re.S):
        directives = re.findall(r"<!-- docs-test: (.*?) -->", m.group(1))
        line = text[:m.start(2)].count("\n") + 1
        body = "\n".join(s.strip() if i == 0 else s for i, s in enumerate(_dedent(m.group(2)).splitlines()))
        name = f"{page.name}:{line}"
        for d in directives:
            k = re.match(r"(skip|cheap) ([\w-]+):", d)
            if k:
                name = k.group(2)
        out.append((name, body, directives))
    return out


def _dedent(s: str) -> str:
    lines = s.splitlines()
    pad = min((len(x) - len(x.lstrip()) for x in lines if x.strip()), default=0)
    return "\n".join(x[pad:] for x in lines)


ALL = [(p, *b) for p in PAGES for b in blocks(p)]


def test_every_skipped_block_is_named_and_every_bash_block_is_seen():
    names = [b[1] for b in ALL]
    skipped = {n for _, n, _, ds in ALL for d in ds if d.startswith("skip ")}
    assert skipped == set(SKIPPED), f"skipped in the docs {sorted(skipped)}, listed here {sorted(SKIPPED)}"
    assert len(names) == len(set(names))
    fences = sum(p.read_text().count("```bash") for p in PAGES)
    assert len(ALL) == fences, "a ```bash block the parser did not see"


def _env() -> dict:
    return dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"),
                PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))


def _sh(script: str, cwd: Path, timeout: float = 900) -> subprocess.CompletedProcess:
    bindir = cwd.parent / "_bin"  # `calibgraph` of this checkout, whatever is installed
    if not (bindir / "calibgraph").exists():
        bindir.mkdir(exist_ok=True)
        (bindir / "calibgraph").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m calibgraph "$@"\n')
        (bindir / "calibgraph").chmod(0o755)
        (bindir / "python").symlink_to(sys.executable)
    env = _env()
    env["PATH"] = f"{bindir}{os.pathsep}{env['PATH']}"
    return subprocess.run(["bash", "-e", "-o", "pipefail", "-c", script], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """The user's files the recipes assume, made once from the simulated default cell."""
    require_sim()
    base = tmp_path_factory.mktemp("docs_inputs")
    _link(base)
    r = _sh("calibgraph sim --workcell datasets/workcells/default.yaml --poses 12 --out DATASET --quiet\n"
            "cp DATASET/planned_trajectory.yaml traj.yaml\n"
            "cp datasets/workcells/default.yaml cell.yaml\n"
            "calibgraph sim --workcell datasets/workcells/default.yaml --intrinsics-session 12 --out session --quiet",
            base)
    assert r.returncode == 0, r.stderr[-3000:]
    return base


def _link(folder: Path) -> None:
    for d in ("datasets", "scripts"):
        if not (folder / d).exists():
            (folder / d).symlink_to(ROOT / d)


@pytest.mark.parametrize("page,name,body,directives", ALL, ids=[b[1] for b in ALL])
def test_block_runs_verbatim(page, name, body, directives, made, tmp_path_factory):
    if any(d.startswith("skip ") for d in directives):
        pytest.skip(f"{name}: {SKIPPED[name]}")
    for d in directives:
        for a, b in re.findall(r"`([^`]+)` -> `([^`]*)`", d) if d.startswith("cheap ") else ():
            assert a in body, (name, a)
            body = body.replace(a, b)
    if "continues" in directives:
        assert "cwd" in _STATE, f"{name} continues a block that did not run (run the whole file)"
        cwd = _STATE["cwd"]
    else:
        cwd = tmp_path_factory.mktemp("docs_block")
        _link(cwd)
    for d in directives:
        for n in d.split()[1:] if d.startswith("needs ") else ():
            src, dst = made / n.rstrip("/"), cwd / n.rstrip("/")
            if not dst.exists():
                (shutil.copytree if src.is_dir() else shutil.copy)(src, dst)
    _STATE["cwd"] = cwd
    r = _sh(body, cwd)
    assert r.returncode == 0, f"{page.name} block {name} exited {r.returncode}:\n{body}\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"


_STATE: dict = {}


def _figures() -> dict:
    return json.loads(FIGURES.read_text())


def test_tour_table_and_demo_figures_are_the_saved_ones():
    """The README's tour table and docs/accuracy.md's tour and demo tables are the rows
    scripts/tour_figures.py saved; the README's console excerpt is lines of the saved solve output."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        from tour_figures import accuracy_rows, tour_rows
    finally:
        sys.path.pop(0)
    f = _figures()
    readme, accuracy = (ROOT / "README.md").read_text(), (ROOT / "docs" / "accuracy.md").read_text()
    for row in tour_rows(f["tour"]):
        assert row in readme.splitlines(), f"README's tour table lacks {row!r} (run scripts/tour_figures.py)"
    for key in ("tour", "demo", "demo_auto"):
        for row in accuracy_rows(f[key]):
            assert row in accuracy.splitlines(), f"docs/accuracy.md lacks the {key} row {row!r}"
    solve_out = {line.strip() for line in f["runs"]["solve"]["stdout"].splitlines()}
    excerpt = re.search(r"calibgraph solve tour_ds[^\n]*\n```\n\n```\n(.*?)```", readme, re.S).group(1)
    for line in excerpt.splitlines():
        if line.strip() and line.strip() != "...":
            assert line.strip() in solve_out, f"README's solve excerpt line not in the saved output: {line!r}"
