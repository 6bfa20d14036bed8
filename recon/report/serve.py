"""Serve a workspace's report.html on localhost (``recon view``).

Only the report is served: it is one self-contained page (its figures, data and viewer are inlined,
see :mod:`recon.report.page`), so nothing else of the workspace (``.recon/`` with its log, config and
hashes, the photos, folder listings) is reachable. Requests must name this server in their Host
header (``127.0.0.1:PORT``, ``localhost:PORT`` or ``[::1]:PORT``): a web page elsewhere that points its
own domain at 127.0.0.1 (DNS rebinding) sends its own name and is refused.
"""

from __future__ import annotations

import http.server
from pathlib import Path

#: the path the report is served at; ``/`` leads there
REPORT = "/report.html"
LOCAL_NAMES = ("127.0.0.1", "localhost", "[::1]")


class ReportServer(http.server.ThreadingHTTPServer):
    """Serves one file, ``report``, to requests addressed to a local name and this server's port."""

    def __init__(self, report: Path, address: tuple[str, int]):
        super().__init__(address, _ReportHandler)
        self.report = report
        port = self.server_address[1]
        self.hosts = {f"{name}:{port}" for name in LOCAL_NAMES} | (set(LOCAL_NAMES) if port == 80 else set())


class _ReportHandler(http.server.BaseHTTPRequestHandler):
    server: ReportServer

    def do_GET(self) -> None:  # noqa: N802  (the stdlib's name)
        self._answer(body=True)

    def do_HEAD(self) -> None:  # noqa: N802
        self._answer(body=False)

    def _answer(self, body: bool) -> None:
        if self.headers.get("Host", "").lower() not in self.server.hosts:
            return self._refuse(421, "this server answers only to 127.0.0.1, localhost and [::1] on its port")
        path = self.path.split("?", 1)[0].split("#", 1)[0]
        if path == "/":
            self.send_response(302)
            self.send_header("Location", REPORT)
            self.send_header("Content-Length", "0")
            self.end_headers()
            return None
        if path != REPORT:
            return self._refuse(404, "only /report.html is served")
        try:
            data = self.server.report.read_bytes()
        except OSError:
            return self._refuse(404, "report.html is gone; run the report stage again")
        self.send_response(200)
        self.send_header("Content-Type", "text/html; charset=utf-8")
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        if body:
            self.wfile.write(data)
        return None

    def _refuse(self, code: int, why: str) -> None:
        data = f"{code}: {why}\n".encode()
        self.send_response(code)
        self.send_header("Content-Type", "text/plain; charset=utf-8")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(data)

    def log_message(self, format, *args) -> None:  # noqa: A002  (the stdlib's name)
        pass


def report_server(workspace: Path, port: int = 8000) -> tuple[ReportServer, str]:
    """A server on 127.0.0.1 for the workspace's report (not yet serving: call ``serve_forever``) and
    the report's address. Port 0 picks a free port. Raises FileNotFoundError when there is no
    report.html."""
    report = Path(workspace).absolute() / "report.html"
    if not report.is_file():
        raise FileNotFoundError(report)
    server = ReportServer(report, ("127.0.0.1", port))
    return server, f"http://127.0.0.1:{server.server_address[1]}{REPORT}"
