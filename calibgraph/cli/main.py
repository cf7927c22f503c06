"""Command-line interface: ``calibgraph <command> ...``.

Each command lives in its own module ``calibgraph/cli/<command>.py`` exposing
``add_parser(subparsers)`` and ``run(args) -> int``; heavy imports happen inside ``run`` so
``calibgraph --help`` stays fast. Known errors (:class:`CalibgraphError`) become one line on
stderr and exit code 2; no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from calibgraph.core.errors import CalibgraphError
from calibgraph.core.version import __version__

COMMANDS = ("demo", "sim", "capture", "detect", "intrinsics", "solve", "check", "target", "report", "view", "export", "verify",
            "import")
# a command whose name is a Python keyword lives in <name>_.py
MODULES = {"import": "import_"}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="calibgraph", description="Multi-camera hand-eye calibration on a factor graph.")
    p.add_argument("--version", action="version", version=f"calibgraph {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        mod = importlib.import_module(f"calibgraph.cli.{MODULES.get(name, name)}")
        sp = mod.add_parser(sub)
        sp.set_defaults(_run=mod.run)
    return p


def error_text(command: str, e: Exception) -> str:
    """The message of a known error without a leading '<command>: ' (the engine names its stage; the
    line already starts 'calibgraph <command>: error: ')."""
    msg = str(e)
    return msg[len(command) + 2:] if msg.startswith(f"{command}: ") else msg


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 1
    try:
        return int(args._run(args) or 0)
    except CalibgraphError as e:
        print(f"calibgraph {args.command}: error: {error_text(args.command, e)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"calibgraph {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
