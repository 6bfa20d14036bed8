"""`recon view`: serves the workspace's report on localhost and prints the address."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import urllib.request


def test_view_serves_the_report(report_workspace):
    proc = subprocess.Popen([sys.executable, "-m", "recon.cli", "view", str(report_workspace), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
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
