"""Progress bars: drawn (counts, ETA) on an interactive terminal, never in piped output or with --quiet."""

from __future__ import annotations

import fcntl
import os
import pty
import re
import select
import shutil
import struct
import subprocess
import sys
import termios
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
RECON = [sys.executable, "-m", "recon.cli"]
BAR = "━"  # rich's bar glyph
ANSI = re.compile(r"\x1b\[[0-9;?]*[A-Za-z]")


@pytest.fixture
def photos(small_scene, tmp_path) -> Path:
    """Six photos of the small scene: enough for features and matching, quick."""
    folder = tmp_path / "photos"
    folder.mkdir()
    for k in range(6):
        shutil.copy(small_scene / "images" / f"view_{k:03d}.jpg", folder)
    return folder


def _command(photos: Path, ws: Path, *extra: str) -> list[str]:
    # serial: the same progress reporting as with the process pool, without its start-up time
    return [*RECON, *extra, "run", str(REPO / "pipelines" / "sparse.yaml"), "--images", str(photos),
            "--workspace", str(ws), "--until", "matching", "-o", "executor=serial"]


def _env() -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("NO_COLOR", "TERM", "COLUMNS", "LINES")}
    env["TERM"] = "xterm-256color"
    return env


def run_in_terminal(cmd: list[str], timeout: float = 180) -> tuple[int, str]:
    """Run ``cmd`` on a pseudo-terminal (120 x 40) and return its exit status and everything it wrote."""
    pid, fd = pty.fork()
    if pid == 0:  # the child: its stdin/stdout/stderr are the terminal
        try:
            os.execve(cmd[0], cmd, _env())
        finally:
            os._exit(127)
    fcntl.ioctl(fd, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    chunks, end = [], time.monotonic() + timeout
    try:
        while time.monotonic() < end:
            ready, _, _ = select.select([fd], [], [], 1.0)
            if ready:
                try:
                    data = os.read(fd, 65536)
                except OSError:  # the child closed the terminal
                    break
                if not data:
                    break
                chunks.append(data)
    finally:
        _, status = os.waitpid(pid, 0)
        os.close(fd)
    return os.waitstatus_to_exitcode(status), b"".join(chunks).decode(errors="replace")


def test_bars_with_counts_on_a_terminal(photos, tmp_path):
    code, out = run_in_terminal(_command(photos, tmp_path / "ws"))
    assert code == 0, out[-2000:]
    plain = ANSI.sub("", out)
    assert BAR in plain
    # each bar's last frame: description, the bar, done/total, elapsed and the ETA column
    assert re.search(r"features\s+━+\s+6/6\s+\d+:\d\d:\d\d\s+ETA", plain), plain[-3000:]
    assert re.search(r"matching pairs\s+━+\s+15/15\s+\d+:\d\d:\d\d\s+ETA", plain), plain[-3000:]
    assert "features: done" in plain  # log lines still reach the terminal, above the bars


def test_quiet_terminal_has_no_bars(photos, tmp_path):
    code, out = run_in_terminal(_command(photos, tmp_path / "ws", "--quiet"))
    assert code == 0, out[-2000:]
    assert BAR not in out and "features: " not in out  # neither bars nor info lines


def test_piped_output_has_plain_lines_only(photos, tmp_path):
    proc = subprocess.run(_command(photos, tmp_path / "ws"), capture_output=True, text=True, env=_env(),
                          timeout=180, stdin=subprocess.DEVNULL)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = proc.stdout + proc.stderr
    assert BAR not in out and "\x1b[" not in out and "\r" not in out
    assert "features: 6/6 in" in out and "matching pairs: 15/15 in" in out
