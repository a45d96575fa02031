"""Memory the review page's object layers hold, frame-sized overlays against box-sized ones.

Run: ``PYTHONPATH=. .venv/bin/python bench/review_layers_memory.py [--counts 1 5 20 50]``.
In Chromium (``/usr/bin/chromium``, headless, through Playwright), a page imports the review
page's ``mask.js`` and makes N spatter objects on a 1280×800 frame (discs of radius 12 to 40 px
at random places), each with its mask and its overlay painted: ``MaskOverlay`` (a canvas and an
image of the frame's size per object, as the page held them before) or ``ObjectOverlay`` (as
big as the object's box, as it holds them now). For each, a fresh renderer process: the bytes
the objects hold as the code counts them (mask, canvas, image), and the renderer's
proportional set size (PSS, from ``/proc``) less the same page with no objects.
"""

from __future__ import annotations

import argparse
import functools
import http.server
import tempfile
import threading
from pathlib import Path

from results import REPO, Table, record

W, H = 1280, 800
PAGE = b"""<!doctype html><meta charset=utf-8><body><script type=module>
import { Mask, MaskOverlay, ObjectOverlay } from "/static/js/review/mask.js";
window.make = (n, boxed) => {
  let seed = 7;
  const rand = () => ((seed = (seed * 16807) %% 2147483647) / 2147483647);
  window.kept = [];
  let bytes = 0;
  for (let k = 0; k < n; k++) {
    const mask = new Mask(%(w)d, %(h)d);
    mask.stamp(60 + rand() * %(w_in)d, 60 + rand() * %(h_in)d, 12 + rand() * 28, 1);
    const overlay = boxed ? new ObjectOverlay("#e64980") : new MaskOverlay(%(w)d, %(h)d, "#e64980");
    overlay.paint(mask);
    window.kept.push([mask, overlay]);
    bytes += mask.data.byteLength + overlay.bytes;
  }
  return bytes;
};
window.ready = true;
</script>"""


def _pss_kib(pids: list[int]) -> int:
    total = 0
    for pid in pids:
        try:
            text = Path(f"/proc/{pid}/smaps_rollup").read_text()
        except OSError:
            continue
        total += next(int(line.split()[1]) for line in text.splitlines() if line.startswith("Pss:"))
    return total


def _renderers(user_dir: str) -> list[int]:
    """The renderer processes of the Chromium started with ``user_dir``."""
    parents, commands = {}, {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            commands[int(entry.name)] = (entry / "cmdline").read_bytes().replace(b"\0", b" ")
            parents[int(entry.name)] = int(
                (entry / "stat").read_text().rsplit(")", 1)[1].split()[1]
            )
        except (OSError, IndexError, ValueError):
            continue
    roots = {p for p, c in commands.items() if user_dir.encode() in c and b"--type=" not in c}

    def under(pid: int) -> bool:
        while pid > 1:
            if pid in roots:
                return True
            pid = parents.get(pid, 0)
        return False

    return [p for p, c in commands.items() if b"--type=renderer" in c and under(p)]


class _Handler(http.server.SimpleHTTPRequestHandler):
    def do_GET(self) -> None:
        if self.path == "/":
            body = PAGE % {b"w": W, b"h": H, b"w_in": W - 120, b"h_in": H - 120}
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.end_headers()
            self.wfile.write(body)
            return
        super().do_GET()

    def log_message(self, *args: object) -> None:
        pass


def measure(counts: list[int]) -> list[list[str]]:
    from playwright.sync_api import sync_playwright

    handler = functools.partial(_Handler, directory=str(REPO))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    url = f"http://127.0.0.1:{server.server_address[1]}/"
    rows = []
    with sync_playwright() as pw, tempfile.TemporaryDirectory() as user_dir:
        context = pw.chromium.launch_persistent_context(
            user_dir,
            executable_path="/usr/bin/chromium",
            args=["--no-sandbox", "--js-flags=--expose-gc"],
            headless=True,
        )
        for n in counts:
            row = [str(n)]
            for boxed in (False, True):
                page = context.new_page()
                page.goto(url)
                page.wait_for_function("window.ready === true")
                page.evaluate("gc()")
                page.wait_for_timeout(300)
                before = _pss_kib(_renderers(user_dir))
                held = page.evaluate("([n, boxed]) => make(n, boxed)", [n, boxed])
                page.evaluate("gc()")
                page.wait_for_timeout(300)
                after = _pss_kib(_renderers(user_dir))
                row += [f"{held / 2**20:.1f}", f"{(after - before) / 1024:.1f}"]
                page.close()
            rows.append(row)
        context.close()
    server.shutdown()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--counts", type=int, nargs="+", default=[1, 5, 20, 50])
    args = parser.parse_args()
    rows = measure(args.counts)
    table = Table(
        f"Spatter objects on a {W}×{H} frame",
        [
            "objects",
            "frame-sized: held MiB",
            "frame-sized: renderer PSS MiB",
            "box-sized: held MiB",
            "box-sized: renderer PSS MiB",
        ],
        rows,
    )
    print(table.markdown())
    command = "PYTHONPATH=. .venv/bin/python bench/review_layers_memory.py"
    print(f"written to {record('bench/review_layers_memory.py', [table], command)}")


if __name__ == "__main__":
    main()
