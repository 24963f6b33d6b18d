"""Open a report in real headless Chromium (Debian's ``chromium``) and measure what a reader sees.

Used by the report and CLI tests; they skip when no chromium binary is installed.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

#: Flags of every launch: no network, no updates, no profile state between runs.
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run")

_PROBE = """<script>
window.addEventListener("load", function () {
  var imgs = Array.from(document.images);
  var broken = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); })
                   .map(function (i) { return i.alt || i.src.slice(0, 60); });
  var s = document.getElementById("summary");
  var r = s ? s.getBoundingClientRect() : null;
  var firstTable = document.querySelector("table");
  var out = {images: imgs.length, broken: broken, scrollWidth: document.documentElement.scrollWidth,
             innerWidth: window.innerWidth, innerHeight: window.innerHeight,
             summaryTop: r ? r.top : null, summaryBottom: r ? r.bottom : null,
             firstTableInSummary: !!(s && firstTable && s.contains(firstTable))};
  var pre = document.createElement("pre"); pre.id = "vesselid-probe"; pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def chromium_binary() -> str | None:
    """Path of a chromium executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def probe(html_path: Path, width: int = 1280, height: int = 800) -> dict:
    """Load a copy of ``html_path`` (with a measuring script) and return what it measured.

    The copy goes to a fresh temporary folder with nothing beside it, so an image that is only
    linked, not embedded, shows up as broken.
    """
    exe = chromium_binary()
    page = Path(html_path).read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>")
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "page" / "report.html"
        copy.parent.mkdir()
        copy.write_text(page, encoding="utf-8")
        res = subprocess.run([exe, *FLAGS, f"--user-data-dir={tmp}/profile", f"--window-size={width},{height}",
                              "--virtual-time-budget=10000", "--dump-dom", copy.as_uri()],
                             capture_output=True, text=True, timeout=180)
    m = re.search(r'<pre id="vesselid-probe">(.*?)</pre>', res.stdout, re.S)
    assert m, f"chromium gave no measurement (exit {res.returncode}): {res.stderr[-500:]}"
    return json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
