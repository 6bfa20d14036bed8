"""`recon view`: serves the workspace's report on localhost and prints the address."""

from __future__ import annotations

import http.client
import re
import signal
import subprocess
import sys
import urllib.request

import pytest


def ctrl_c_reaches_it() -> None:
    """A shell that runs CI in the background ignores SIGINT in its children (POSIX), and Python then
    installs no KeyboardInterrupt handler: give the child a terminal's default, as a user's shell does."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_view_serves_the_report(report_workspace):
    proc = subprocess.Popen([sys.executable, "-m", "recon.cli", "view", str(report_workspace), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=ctrl_c_reaches_it)
    try:
        line = proc.stdout.readline()
        url = re.search(r"http://127\.0\.0\.1:\d+/report\.html", line)
        assert url, line + proc.stderr.read() if proc.poll() is not None else line
        with urllib.request.urlopen(url.group(0), timeout=10) as answer:
            body = answer.read()
        assert answer.status == 200
        assert body == (report_workspace / "report.html").read_bytes()
    finally:
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=10)
    assert code == 0


def test_view_without_a_report_says_what_to_do(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "recon.cli", "view", str(tmp_path)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2
    assert "no report.html" in proc.stderr and "report" in proc.stderr.split("no report.html")[1]


@pytest.fixture
def served(tmp_path):
    """A workspace with a report and the private files beside it, served on a free port:
    yields ``(workspace, port)``."""
    import threading

    from recon.report.serve import report_server

    ws = tmp_path / "ws"
    (ws / ".recon" / "logs").mkdir(parents=True)
    (ws / "report.html").write_text("<!doctype html><title>report</title>REPORT")
    (ws / ".recon" / "recon.log").write_text("SECRET log line")
    (ws / ".recon" / "config.yaml").write_text("SECRET: config")
    (ws / "sparse" / "0").mkdir(parents=True)
    (ws / "sparse" / "0" / "cameras.txt").write_text("SECRET model")
    server, _ = report_server(ws, 0)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield ws, server.server_address[1]
    server.shutdown()
    server.server_close()


def fetch(port: int, path: str, host: str | None, method: str = "GET") -> tuple[int, dict, bytes]:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    try:
        connection.putrequest(method, path, skip_host=True)
        if host is not None:
            connection.putheader("Host", host)
        connection.endheaders()
        answer = connection.getresponse()
        return answer.status, dict(answer.getheaders()), answer.read()
    finally:
        connection.close()


def test_view_serves_only_the_report(served):
    """The report is one self-contained page: nothing else of the workspace is reachable, no
    folder is listed, whatever the path's spelling."""
    ws, port = served
    host = f"127.0.0.1:{port}"
    status, headers, body = fetch(port, "/report.html", host)
    assert status == 200 and body == (ws / "report.html").read_bytes()
    assert headers["Content-Type"] == "text/html; charset=utf-8"
    assert fetch(port, "/report.html", host, "HEAD")[::2] == (200, b"")
    status, headers, _ = fetch(port, "/", host)
    assert status == 302 and headers["Location"] == "/report.html"
    for path in ["/.recon/recon.log", "/.recon/config.yaml", "/.recon/", "/.recon", "/sparse/", "/sparse/0/cameras.txt",
                 "/report.html/../.recon/recon.log", "/%2erecon/recon.log", "/./.recon/recon.log", "//.recon/recon.log",
                 "/../../etc/passwd", "/report.html%00", "/REPORT.HTML"]:
        status, _, body = fetch(port, path, host)
        assert status == 404 and b"SECRET" not in body and b"REPORT" not in body, (path, status, body)


@pytest.mark.parametrize("name", ["127.0.0.1", "localhost", "[::1]", "LOCALHOST"])
def test_view_answers_to_local_names_on_its_port(served, name):
    ws, port = served
    status, _, body = fetch(port, "/report.html", f"{name}:{port}")
    assert status == 200 and body == (ws / "report.html").read_bytes()


@pytest.mark.parametrize("host", ["attacker.example", "attacker.example:{port}", "127.0.0.1", "127.0.0.1:1",
                                  "localhost.attacker.example:{port}", "127.0.0.1:{port}@attacker.example", "", None])
def test_view_refuses_other_host_headers(served, host):
    """DNS rebinding: a page on attacker.example whose name now points at 127.0.0.1 sends
    ``Host: attacker.example:PORT``; it gets no byte of the report."""
    _, port = served
    status, _, body = fetch(port, "/report.html", None if host is None else host.format(port=port))
    assert status == 421 and b"REPORT" not in body
