"""Screenshots of a run report in headless Chromium: the top (verdict), the footprint map, the QC table.

    python bench/report_screenshots.py demo_output/run/report/index.html --out screenshots \
        [--small docs/screenshots] [--chromium chromium]

Needs a Chromium (Debian: ``apt-get install chromium``) and Pillow (a matplotlib dependency). The page
is rendered once at full height; the sections are cut out at the offsets of their headings (read from
the DOM after layout). ``--small`` also writes reduced copies (half size, 64-colour PNG) for the docs.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

WIDTH = 1200
SECTIONS = {"top": ("verdict", -160, 1150), "footprints": ("map", -10, 860), "qc_table": ("qc", -10, 1000),
            "check_points": ("check_table", -10, 760), "timings": ("timings", -10, 420)}

_PROBE = """<script>
window.addEventListener('load', () => {
  const out = {height: document.documentElement.scrollHeight};
  document.querySelectorAll('h2[id]').forEach(h => out[h.id] = h.getBoundingClientRect().top + window.scrollY);
  const pre = document.createElement('pre'); pre.id = 'offsets'; pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def _chromium(exe: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", *args],
                          capture_output=True, text=True, timeout=300)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("page")
    ap.add_argument("--out", default="screenshots")
    ap.add_argument("--small", help="folder for reduced copies")
    ap.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser") or "chromium")
    args = ap.parse_args(argv)
    from PIL import Image

    page = Path(args.page).resolve()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe.html"
        probe.write_text(page.read_text(encoding="utf-8").replace("</body>", _PROBE + "</body>"), encoding="utf-8")
        dom = _chromium(args.chromium, f"--window-size={WIDTH},1000", "--virtual-time-budget=5000", "--dump-dom",
                        probe.as_uri()).stdout
        m = re.search(r'<pre id="offsets">(.*?)</pre>', dom)
        if not m:
            print("could not read the page's layout", file=sys.stderr)
            return 1
        offsets = json.loads(m.group(1).replace("&quot;", '"'))
        full = Path(tmp) / "full.png"
        _chromium(args.chromium, f"--window-size={WIDTH},{int(offsets['height']) + 20}", "--virtual-time-budget=5000",
                  f"--screenshot={full}", page.as_uri())
        img = Image.open(full)
        for name, (anchor, before, height) in SECTIONS.items():
            if anchor not in offsets:
                continue
            top = max(0, int(offsets[anchor]) + before)
            part = img.crop((0, top, WIDTH, min(img.height, top + height)))
            part.save(out / f"report_{name}.png")
            print(f"{out / f'report_{name}.png'}: {part.size[0]} x {part.size[1]} from y = {top}")
            if args.small:
                small = Path(args.small)
                small.mkdir(parents=True, exist_ok=True)
                s = part.resize((part.width // 2, part.height // 2), Image.LANCZOS).convert("RGB")
                s = s.quantize(colors=64)
                s.save(small / f"report_{name}.png", optimize=True)
                print(f"  small copy {small / f'report_{name}.png'}: {(small / f'report_{name}.png').stat().st_size} B")
    return 0


if __name__ == "__main__":
    sys.exit(main())
