"""Screenshot the simulated demo's commissioning report in headless Chromium (scripts/results/report_demo.png).

Runs ``calibgraph demo --out OUT`` (a few minutes, niced) unless ``--report`` names a report.html
already made, then has Chromium draw the top of the page (the verdict, what would improve the
calibration, the summary, the notes on the whole cell and the first camera's section).

    MUJOCO_GL=egl python scripts/report_screenshot.py [--out-dir /tmp/demo_shot] [--report R.html]
        [--png scripts/results/report_demo.png] [--height 2300]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out-dir", type=Path, default=Path(tempfile.gettempdir()) / "calibgraph_demo_shot")
    ap.add_argument("--report", type=Path, default=None, help="an existing report.html (skips the demo)")
    ap.add_argument("--png", type=Path, default=REPO / "scripts" / "results" / "report_demo.png")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=2300)
    a = ap.parse_args()
    exe = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
    if exe is None:
        print("chromium is not installed (apt-get install chromium)", file=sys.stderr)
        return 2
    report = a.report
    if report is None:
        if a.out_dir.exists():
            print(f"{a.out_dir} exists: give another --out-dir, or --report {a.out_dir / 'report.html'}", file=sys.stderr)
            return 2
        env = dict(os.environ, PYTHONPATH=str(REPO), MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
        subprocess.run([sys.executable, "-m", "calibgraph", "demo", "--out", str(a.out_dir)], cwd=REPO, env=env, check=True)
        report = a.out_dir / "report.html"
    with tempfile.TemporaryDirectory() as prof:
        subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
                        f"--user-data-dir={prof}", f"--screenshot={a.png.resolve()}",
                        f"--window-size={a.width},{a.height}", report.resolve().as_uri()],
                       capture_output=True, timeout=120, check=True)
    print(f"wrote {a.png} from {report}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
