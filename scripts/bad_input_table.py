"""Write scripts/results/bad_input_corpus.md: every case of tests/test_bad_input.py and what calibgraph
says for it (the test run itself writes the table when CALIBGRAPH_BAD_INPUT_TABLE is set).

    python scripts/bad_input_table.py [--out scripts/results/bad_input_corpus.md]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "scripts" / "results" / "bad_input_corpus.md")
    a = ap.parse_args()
    env = dict(os.environ, CALIBGRAPH_BAD_INPUT_TABLE=str(a.out.resolve()), PYTHONPATH=str(REPO))
    rc = subprocess.call([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/test_bad_input.py"],
                         cwd=REPO, env=env)
    if a.out.exists():
        print(a.out.read_text())
        print(f"wrote {a.out}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
