"""The ``calibgraph`` command: one thin module per sub-command (the edge; imports any stage)."""

from calibgraph.cli.main import main

__all__ = ["main"]
