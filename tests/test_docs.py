"""The documentation against the code it describes: every command and flag of the CLI is in
docs/cli.md, the README keeps the two commands CI and a new user run, and every relative link of
the README and docs/ points at a file (and heading) that exists."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from calibgraph.cli.main import COMMANDS, build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"
INSTALL_AND_DEMO = 'pip install -e ".[all]" -c constraints.txt && MUJOCO_GL=egl calibgraph demo --out demo_out'
TEST_COMMAND = "python -m pytest -q tests"  # .ci/run runs the README's test command


def _subparsers(parser: argparse.ArgumentParser):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            yield from action.choices.items()


def _flags(parser: argparse.ArgumentParser, path: str) -> list:
    """(command path, option string) of every option of ``parser`` and of its sub-commands."""
    out = [(path, s) for a in parser._actions for s in a.option_strings
           if s.startswith("--") and s != "--help"]
    for name, sub in _subparsers(parser):
        out += _flags(sub, f"{path} {name}")
    return out


def test_every_command_and_flag_is_in_the_cli_reference():
    text = (DOCS / "cli.md").read_text()
    commands = dict(_subparsers(build_parser()))
    assert set(commands) == set(COMMANDS)
    missing_sections = [c for c in commands if not re.search(rf"^## {re.escape(c)}\s*$", text, re.M)]
    assert not missing_sections, f"docs/cli.md has no '## <command>' section for {missing_sections}"
    flags = [f for name, sub in commands.items() for f in _flags(sub, name)]
    assert len(flags) > 60  # the walk found the flags (solve alone has over a dozen)
    missing = sorted({f"{path}: {flag}" for path, flag in flags if f"`{flag}`" not in text})
    assert not missing, "flags missing from docs/cli.md (add them, in backticks): " + ", ".join(missing)


def test_readme_keeps_the_two_commands_and_stays_a_guide():
    lines = README.read_text().splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines; move detail into docs/"
    assert INSTALL_AND_DEMO in lines, "README.md lost the install + demo command"
    assert TEST_COMMAND in lines, "README.md lost the test command that .ci/run runs"
    assert TEST_COMMAND in (ROOT / ".ci" / "run").read_text()
    # the install the README's figures were made with is the one CI runs
    assert 'pip install -q -e ".[all]" -c constraints.txt' in (ROOT / ".ci" / "run").read_text()
    assert (ROOT / "constraints.txt").is_file()


def _slug(heading: str) -> str:
    """GitHub's anchor of a markdown heading."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def _anchors(md: Path) -> set:
    text = re.sub(r"```.*?```", "", md.read_text(), flags=re.S)
    return {_slug(m) for m in re.findall(r"^#{1,6} (.+)$", text, re.M)}


def test_relative_links_resolve():
    pages = [README, *sorted(DOCS.glob("*.md"))]
    assert len(pages) >= 4
    broken = []
    for page in pages:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue  # http(s), mailto: not checked here
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                broken.append(f"{page.name}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                broken.append(f"{page.name}: {target} (no such heading)")
    assert not broken, "broken links: " + "; ".join(broken)
