"""Serve a workspace's report.html on localhost (``recon view``)."""

from __future__ import annotations

import functools
import http.server
from pathlib import Path


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format, *args) -> None:  # noqa: A002  (the stdlib's name)
        pass


def report_server(workspace: Path, port: int = 8000, host: str = "127.0.0.1") -> tuple[http.server.HTTPServer, str]:
    """A server for the workspace folder (not yet serving: call ``serve_forever``) and the report's
    address. Port 0 picks a free port. Raises FileNotFoundError when there is no report.html."""
    workspace = Path(workspace).absolute()
    if not (workspace / "report.html").is_file():
        raise FileNotFoundError(workspace / "report.html")
    handler = functools.partial(_QuietHandler, directory=str(workspace))
    server = http.server.ThreadingHTTPServer((host, port), handler)
    return server, f"http://{host}:{server.server_address[1]}/report.html"
