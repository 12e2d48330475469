"""`ushape view FOLDER`: serve a reconstruction's (or an active sequence's) folder to a browser.

report.html opens from disk as it is; this is for a folder on a remote machine: the page is served on
this machine's loopback interface only, and reached over SSH port forwarding
(`ssh -L 8765:localhost:8765 host`, then http://localhost:8765/report.html).
"""

from __future__ import annotations

import argparse
import functools
import sys
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Sequence

from ushape.errors import InputError
from ushape.reconstruction.report_page import REPORT_FILE


class QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args) -> None:  # one line per request would drown the URL
        pass


def report_server(folder: str | Path, port: int = 8765) -> ThreadingHTTPServer:
    """An HTTP server of `folder` on 127.0.0.1:port (0: any free port); an InputError if it holds no report."""
    folder = Path(folder)
    if not (folder / REPORT_FILE).is_file():
        raise InputError(f"{folder} holds no {REPORT_FILE}: pass a folder written by reconstruct.py or active.py")
    handler = functools.partial(QuietHandler, directory=str(folder))
    return ThreadingHTTPServer(("127.0.0.1", port), handler)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Serve a reconstruction's report.html on localhost.")
    parser.add_argument("folder", help="a folder holding report.html (reconstruct.py's --out, active.py's)")
    parser.add_argument("--port", type=int, default=8765, help="port on 127.0.0.1 (default 8765)")
    args = parser.parse_args(argv)
    try:
        server = report_server(args.folder, args.port)
    except OSError as err:
        print(f"error: cannot serve on 127.0.0.1:{args.port} ({err}): pass another --port", file=sys.stderr)
        return 2
    port = server.server_address[1]
    print(f"serving {args.folder}: open http://localhost:{port}/{REPORT_FILE}")
    print(f"from another machine: ssh -L {port}:localhost:{port} <this host>, then the same address; Ctrl+C stops")
    try:
        server.serve_forever()
    finally:
        server.server_close()
    return 0
