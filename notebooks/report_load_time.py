"""How long a report.html takes to show its mesh in a real browser: headless Chromium, real time (no virtual clock).

    python notebooks/report_load_time.py REPORT.html [--repeats 3]

The page writes `performance.now()` (ms since navigation started) into `document.body.dataset.loadedMs` when
<model-viewer> fires `load`, i.e. when the first scene's mesh is drawn; this script opens the page in Chromium
with its DevTools port, polls that value over the DevTools protocol and prints it with the folder's size
(the page, its viewer script and whatever else the folder holds for the page). Needs Chromium on the PATH
and aiohttp (installed with lightning).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import socket
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import aiohttp

FLAGS = os.environ.get(
    "REPORT_FLAGS", "--headless=new --no-sandbox --disable-gpu --enable-unsafe-swiftshader --use-angle=swiftshader"
).split()


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def loaded_ms(ws_url: str, timeout_s: float) -> float | None:
    """Poll the page's data-loaded-ms over the DevTools protocol; None if it never appears."""
    async with aiohttp.ClientSession() as session, session.ws_connect(ws_url, max_msg_size=0) as ws:
        deadline, ident = time.monotonic() + timeout_s, 0
        while time.monotonic() < deadline:
            ident += 1
            expression = "document.body ? document.body.dataset.loadedMs || '' : ''"
            await ws.send_json({"id": ident, "method": "Runtime.evaluate", "params": {"expression": expression}})
            while True:
                reply = json.loads((await ws.receive()).data)
                if reply.get("id") == ident:
                    break
            value = reply.get("result", {}).get("result", {}).get("value")
            if value:
                return float(value)
            await asyncio.sleep(0.05)
    return None


def measure(page: Path, timeout_s: float = 60.0) -> float | None:
    browser = next(
        (shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None
    )
    if browser is None:
        raise SystemExit("no Chromium on the PATH (apt-get install chromium)")
    port = free_port()
    # Chromium's helper processes may still write into the profile after the browser exits.
    with tempfile.TemporaryDirectory(ignore_cleanup_errors=True) as profile:
        args = [browser, *FLAGS, f"--remote-debugging-port={port}", f"--user-data-dir={profile}", page.as_uri()]
        process = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            for _ in range(200):  # the DevTools endpoint comes up with the browser
                try:
                    with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=1) as reply:
                        targets = [t for t in json.load(reply) if t.get("type") == "page"]
                    if targets:
                        break
                except OSError:
                    pass
                time.sleep(0.1)
            else:
                raise SystemExit("Chromium's DevTools port did not come up")
            return asyncio.run(loaded_ms(targets[0]["webSocketDebuggerUrl"], timeout_s))
        finally:
            process.terminate()
            process.wait(timeout=10)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("page", type=Path)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    page = args.page.resolve()
    size = sum(p.stat().st_size for p in page.parent.iterdir() if p.is_file() and p.suffix in (".html", ".js"))
    times = [measure(page) for _ in range(args.repeats)]
    shown = ", ".join("never" if t is None else f"{t:.0f} ms" for t in times)
    print(f"{page}: mesh drawn after {shown} (navigation to <model-viewer> load); page + viewer {size / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
