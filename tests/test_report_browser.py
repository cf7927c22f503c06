"""The commissioning report as a reader sees it in a real browser (headless Chromium): the text the
page renders (``innerText``: laid out, CSS applied) carries each camera's error budget, advice, notes
and intrinsics' source, the notes on the whole cell, a moved camera's displacement; and the budget's
bar is drawn. On a simulated cell with a knocked camera, and on the real ChArUco set (RCT), whose
FAIL the notes explain.

Skipped without Chromium (failed instead when CALIBGRAPH_BROWSER_REQUIRED=1, as in CI).
"""

import html
import json
import re

import numpy as np
from helpers import knocked_result, require_chromium, run_chromium

from calibgraph.report import findings
from calibgraph.report.html import write_report
from calibgraph.report.sections import BUDGET_COLOURS
from calibgraph.solver.output.result import load_result

GRAB_TEXT = """<script>(function(){const t=document.body.innerText;document.body.innerHTML='';
const p=document.createElement('pre');p.id='rendered-text';p.textContent=t;document.body.appendChild(p);})();</script>"""


def rendered_text(page, tmp_path) -> str:
    """The text Chromium renders for the HTML file ``page`` (its ``innerText``, whitespace folded)."""
    require_chromium()
    probe = tmp_path / f"{page.stem}.text.html"
    probe.write_text(page.read_text().replace("</body>", GRAB_TEXT + "</body>"))
    r = run_chromium(["--dump-dom", probe.resolve().as_uri()])
    m = re.search(r'<pre id="rendered-text">(.*?)</pre>', r.stdout, re.S)
    assert m, r.stdout[-1000:] + r.stderr[-1000:]
    return re.sub(r"\s+", " ", html.unescape(m.group(1)))


def section(text: str, start: str, end: str | None = None) -> str:
    tail = text.split(start, 1)[1]
    return tail.split(end, 1)[0] if end and end in tail else tail


def camera_section(text: str, names: list, n: str) -> str:
    """Camera ``n``'s section of the rendered text: from its heading ('cam0 PASS') to the next."""
    def head(m):
        return next(h for h in (f"{m} PASS", f"{m} FAIL") if h in text)

    i = names.index(n)
    return section(text, head(n), head(names[i + 1]) if i + 1 < len(names) else "Camera-to-camera poses")


def test_rendered_report_says_budget_advice_notes_and_intrinsics_source(tmp_path):
    res = knocked_result()  # cam0 knocked 5 mm after capture 18
    page = write_report(res, tmp_path / "report.html")
    text = rendered_text(page, tmp_path)
    top = section(text, "Overall:", "Summary")
    assert "What would improve this calibration" in top
    names = list(res.cameras)
    for n in names:
        c = res.cameras[n]
        cam = camera_section(text, names, n)
        assert findings.advice_for(n, c) in top, n
        assert "What its 1σ translation of" in cam and "is made of" in cam and "by noise source" in cam
        for src, share in c.error_budget["shares"].items():  # each share, in words and as a percentage
            assert f"{findings.source_label(src)} {findings.percent(share)}" in cam, (n, src)
        assert findings.advice_for(n, c) not in cam and "its advice in What would improve this calibration" in cam
        for note in res.camera_notes(n):
            assert note in cam, (n, note)
        assert findings.provenance_text(c, res.settings) in cam
        assert "source: factory values" in cam and "parameter given estimated 1σ estimated − given prior 1σ" in cam
    m = res.cameras["cam0"].moved
    cam0 = camera_section(text, names, "cam0")
    assert (f"Moved during capture, between captures {m['last_capture_before']} and {m['capture']}: "
            f"{m['displacement_mm']:.1f} ± {m['sigma_displacement_mm']:.1f} mm (1σ)") in cam0
    cell = section(text, "Notes on the whole cell", "Cameras")
    assert all(note in cell for note in res.cell_notes)
    # the bars are drawn: each camera's largest share's colour fills a strip of pixels
    import cv2

    png = tmp_path / "shot.png"
    run_chromium([f"--screenshot={png}", "--window-size=1280,1600", page.resolve().as_uri()])
    img = cv2.imread(str(png))
    assert img is not None
    biggest = {max(c.error_budget["shares"].items(), key=lambda kv: kv[1])[0] for c in res.cameras.values()}
    for src in biggest:
        rgb = [int(BUDGET_COLOURS[src][i:i + 2], 16) for i in (1, 3, 5)]
        hit = np.all(np.abs(img.reshape(-1, 3).astype(int) - rgb[::-1]) < 6, axis=1).sum()
        assert hit > 500, (src, hit)


def test_rendered_report_of_the_real_charuco_set_explains_its_fail(rct_dir, tmp_path):
    """The real ChArUco set fails its tolerances; the page says why: its given intrinsics rejected by
    the data (under the camera), the board's scale and the robot's accuracy (on the whole cell),
    each as the solver wrote it, and where the intrinsics came from."""
    from calibgraph.cli.main import main

    require_chromium()
    ds = rct_dir  # this module's own copy
    assert main(["solve", str(ds), "--quiet"]) == 0
    out = tmp_path / "report.html"
    main(["report", str(ds / "result.json"), "--out", str(out)])
    res = load_result(ds / "result.json")
    d = json.loads((ds / "result.json").read_text())
    text = rendered_text(out, tmp_path)
    assert "Overall: FAIL" in text
    k = len(res.cell_notes)
    assert f"The solver also left {k} notes on the whole cell (board, robot)" in section(text, "Overall:", "Summary")
    (n, c), = res.cameras.items()
    cam = camera_section(text, [n], n)
    intr_notes = [t for t in res.camera_notes(n) if "disagree with its given" in t]
    assert intr_notes and all(t in cam for t in intr_notes)  # 'cx -21.8 px' and the rest, under the camera
    cell = section(text, "Notes on the whole cell", "Cameras")
    assert any("board" in t and t in cell for t in res.cell_notes), res.cell_notes
    assert any(t.startswith("robot:") and t in cell for t in res.cell_notes), res.cell_notes
    assert findings.provenance_text(c, res.settings) in cam and "a calibration file" in cam
    assert d["cameras"][n]["intrinsics"]["source_used"] == "wide" and "used: estimated under a wide prior" in cam
    assert findings.advice_for(n, c) in section(text, "What would improve this calibration", "Summary")
