"""`ushape view`: the report folder served on the loopback interface, and refused without a report."""

import threading
import urllib.request

import pytest

from ushape.errors import InputError
from ushape.reconstruction.serve import report_server


def test_the_folder_is_served_on_localhost_only(tmp_path):
    (tmp_path / "report.html").write_text("<html>the report</html>")
    server = report_server(tmp_path, port=0)
    host, port = server.server_address
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/report.html", timeout=10) as response:
            assert response.read() == b"<html>the report</html>"
    finally:
        server.shutdown()
        server.server_close()
    assert host == "127.0.0.1"
    with pytest.raises(InputError, match="holds no report.html"):
        report_server(tmp_path / "elsewhere", port=0)
