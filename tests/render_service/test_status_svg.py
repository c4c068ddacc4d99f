"""The status page's skyline plot keeps every label inside the SVG (issue 13 point 6: a tick label was clipped).

Checked twice: with matplotlib's font metrics (DejaVu Sans, the fallback sans-serif here; fast, always) and,
when chromium is installed, with the browser's own layout (``getBBox`` of every ``<text>``)."""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from render_service.api.routes.ui import skyline_svg

AZ = np.arange(360.0)
#: elevation ranges whose old labels (np.linspace ticks such as "33.25°") ran past the left edge
CASES = {"wide": np.linspace(-12.3, 47.8, 360), "negative": -30.0 + 5 * np.sin(np.radians(AZ)),
         "flat": np.full(360, 0.2), "steep": 88.0 * np.sin(np.radians(AZ / 2))}


def _boxes_matplotlib(svg: str) -> list[tuple[str, float, float, float, float]]:
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import TextToPath

    t2p = TextToPath()
    out = []
    for t in ET.fromstring(svg).iter("{http://www.w3.org/2000/svg}text"):
        size = float(t.get("font-size"))
        w, h, d = t2p.get_text_width_height_descent(t.text, FontProperties(family="DejaVu Sans", size=size),
                                                     ismath=False)
        x, y = float(t.get("x")), float(t.get("y"))
        x0 = {"start": x, "middle": x - w / 2, "end": x - w}[t.get("text-anchor", "start")]
        out.append((t.text, x0, y - (h - d), w, h))
    return out


@pytest.mark.parametrize("case", sorted(CASES))
def test_every_label_lies_inside_the_svg(case):
    svg = skyline_svg(AZ, CASES[case], title="job x: horizon at grid centre (0.0, 0.0) m")
    root = ET.fromstring(svg)
    width, height = float(root.get("width")), float(root.get("height"))
    for text, x, y, w, h in _boxes_matplotlib(svg):
        assert x >= 2 and x + w <= width - 2 and y >= 0 and y + h <= height, (case, text, x, w)
    ylabels = [t.text for t in root.iter("{http://www.w3.org/2000/svg}text") if t.get("text-anchor") == "end"]
    assert len(ylabels) >= 3 and all(re.fullmatch(r"-?\d+(\.5)?°", s) for s in ylabels), ylabels  # round ticks


def test_labels_inside_in_chromium(tmp_path):
    exe = shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("chromium is not installed (apt install chromium)")
    svgs = {k: skyline_svg(AZ, v, title="t") for k, v in CASES.items()}
    page = tmp_path / "p.html"
    page.write_text("<!doctype html><html><body>" + "".join(f'<div id="{k}">{s}</div>' for k, s in svgs.items()) +
                    "<script>const r = {}; for (const d of document.querySelectorAll('div')) { r[d.id] = "
                    "[...d.querySelectorAll('text')].map(t => { const b = t.getBBox(); "
                    "return [t.textContent, b.x, b.y, b.width, b.height]; }); }"
                    "document.body.setAttribute('data-boxes', JSON.stringify(r));</script></body></html>")
    args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-dev-shm-usage", f"--user-data-dir={tmp_path / 'profile'}", "--dump-dom", page.as_uri()]
    dom = subprocess.run(args, capture_output=True, text=True, timeout=90,
                         env={**os.environ, "HOME": str(tmp_path)}).stdout
    m = re.search(r"data-boxes=\"([^\"]*)\"", dom)
    assert m, dom[:1000]
    boxes = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    for case, items in boxes.items():
        for text, x, y, w, h in items:
            assert x >= 0 and x + w <= 720 and y >= 0 and y + h <= 240, (case, text, x, w)
