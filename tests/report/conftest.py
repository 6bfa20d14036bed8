"""Fixtures for the report: a sparse run with its report, and headless Chromium driven over the
Chrome DevTools Protocol (``--remote-debugging-pipe``: JSON messages on fds 3 and 4, no extra package).

Chromium comes from Debian's ``chromium`` package (/usr/bin/chromium); tests that need it skip when absent.
"""

from __future__ import annotations

import base64
import fcntl
import io
import json
import os
import queue
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import recon

REPO = Path(__file__).resolve().parents[2]
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  # WebGL on the CPU (SwiftShader): the viewer needs it and the machine has no GPU
                  "--enable-unsafe-swiftshader", "--remote-debugging-pipe"]


def _run_report(images: Path, workspace: Path, overrides: list[str] | None = None):
    """Run pipelines/sparse.yaml (its sparse stages are the session sparse run's, cached when present:
    the same options, single-threaded mapping) and so its report into ``workspace``."""
    return recon.run(REPO / "pipelines" / "sparse.yaml", images=str(images), workspace=str(workspace),
                     overrides=["sfm.deterministic=true", *(overrides or [])])


@pytest.fixture(scope="session")
def run_report():
    return _run_report


@pytest.fixture(scope="session")
def report_workspace(sparse_workspace, small_scene, tmp_path_factory) -> Path:
    """A copy of the session's sparse run plus its report (with evaluation against the scene's ground truth)."""
    ws = tmp_path_factory.mktemp("report") / "ws"
    shutil.copytree(sparse_workspace, ws, symlinks=True)
    _run_report(small_scene / "images", ws, [f"report.gt={small_scene}"])
    return ws


def chromium_path() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


class Browser:
    """One headless Chromium with one page, driven over the DevTools protocol."""

    def __init__(self, executable: str, width: int = 1280, height: int = 900):
        self.profile = tempfile.mkdtemp(prefix="recon-chromium-")
        cmd_r, self._cmd_w = os.pipe()
        self._resp_r, resp_w = os.pipe()
        cmd_r, resp_w = _above(cmd_r, 10), _above(resp_w, 10)  # clear of the fds 3 and 4 they move to
        # bash puts our pipe ends on fds 3 (commands in) and 4 (answers out), as Chromium expects
        self.proc = subprocess.Popen(
            ["/bin/bash", "-c", f'exec "$0" "$@" 3<&{cmd_r} 4>&{resp_w}', executable, *CHROMIUM_FLAGS,
             f"--user-data-dir={self.profile}", "about:blank"],
            pass_fds=(cmd_r, resp_w), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        os.close(cmd_r)
        os.close(resp_w)
        self._next_id = 0
        self._answers: dict[int, queue.Queue] = {}
        self.events: list[dict] = []
        self._lock = threading.Lock()
        threading.Thread(target=self._read, daemon=True).start()
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self.call(f"{domain}.enable", session=True)
        self.call("Emulation.setDeviceMetricsOverride", session=True, width=width, height=height,
                  deviceScaleFactor=1, mobile=False)

    def _read(self) -> None:
        buf = b""
        with os.fdopen(self._resp_r, "rb", buffering=0) as pipe:
            while chunk := pipe.read(1 << 16):
                buf += chunk
                while b"\0" in buf:
                    raw, buf = buf.split(b"\0", 1)
                    msg = json.loads(raw)
                    if "id" in msg and msg["id"] in self._answers:
                        self._answers[msg["id"]].put(msg)
                    else:
                        with self._lock:
                            self.events.append(msg)

    def call(self, method: str, session: bool = False, timeout: float = 60, **params) -> dict:
        self._next_id += 1
        ident = self._next_id
        answers = self._answers[ident] = queue.Queue()
        msg = {"id": ident, "method": method, "params": params}
        if session:
            msg["sessionId"] = self.session
        os.write(self._cmd_w, json.dumps(msg).encode() + b"\0")
        try:
            answer = answers.get(timeout=timeout)
        finally:
            del self._answers[ident]
        if "error" in answer:
            raise RuntimeError(f"{method}: {answer}")
        return answer.get("result", {})

    def evaluate(self, expression: str):
        result = self.call("Runtime.evaluate", session=True, expression=expression, returnByValue=True,
                           awaitPromise=True)
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def open(self, url: str, timeout: float = 60) -> None:
        with self._lock:
            self.events.clear()
        self.call("Page.navigate", session=True, url=url)
        self.wait_for("document.readyState === 'complete'", timeout)

    def wait_for(self, expression: str, timeout: float = 60) -> None:
        end = time.monotonic() + timeout
        while not self.evaluate(expression):
            if time.monotonic() > end:
                raise TimeoutError(expression)
            time.sleep(0.1)

    def errors(self) -> list[str]:
        """Console errors, uncaught exceptions and browser log errors since the page was opened."""
        found = []
        with self._lock:
            for event in self.events:
                method, params = event.get("method"), event.get("params", {})
                if method == "Runtime.exceptionThrown":
                    found.append(json.dumps(params["exceptionDetails"])[:500])
                elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
                    found.append(" ".join(str(a.get("value", a.get("description"))) for a in params["args"]))
                elif method == "Log.entryAdded" and params["entry"]["level"] == "error":
                    found.append(params["entry"]["text"])
        return found

    def screenshot(self, selector: str) -> np.ndarray:
        """RGB pixels of the element matched by ``selector``, scrolled into view (the clip is in page
        coordinates)."""
        from PIL import Image

        rect = self.evaluate(f"""(() => {{ const el = document.querySelector({json.dumps(selector)});
            el.scrollIntoView({{block: 'center'}}); const r = el.getBoundingClientRect();
            return {{x: r.x + window.scrollX, y: r.y + window.scrollY, width: r.width, height: r.height}}; }})()""")
        time.sleep(0.3)
        shot = self.call("Page.captureScreenshot", session=True, format="png",
                         clip={**rect, "scale": 1})
        return np.asarray(Image.open(io.BytesIO(base64.b64decode(shot["data"]))).convert("RGB"))

    def drag(self, selector: str, dx: float, dy: float, steps: int = 10) -> None:
        """Press the left button at the element's centre, move by (dx, dy), release."""
        c = self.evaluate(f"""(() => {{ const r = document.querySelector({json.dumps(selector)})
            .getBoundingClientRect(); return [r.x + r.width / 2, r.y + r.height / 2]; }})()""")
        x, y = c
        self.call("Input.dispatchMouseEvent", session=True, type="mousePressed", x=x, y=y, button="left",
                  buttons=1, clickCount=1)
        for k in range(1, steps + 1):
            self.call("Input.dispatchMouseEvent", session=True, type="mouseMoved", x=x + dx * k / steps,
                      y=y + dy * k / steps, button="left", buttons=1)
        self.call("Input.dispatchMouseEvent", session=True, type="mouseReleased", x=x + dx, y=y + dy,
                  button="left", buttons=0, clickCount=1)

    def close(self) -> None:
        try:
            self.call("Browser.close", timeout=10)
        except (RuntimeError, queue.Empty, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._cmd_w)
        shutil.rmtree(self.profile, ignore_errors=True)


def _above(fd: int, low: int) -> int:
    moved = fcntl.fcntl(fd, fcntl.F_DUPFD, low)
    os.close(fd)
    return moved


@pytest.fixture(scope="session")
def browser():
    executable = chromium_path()
    if executable is None:
        pytest.skip("headless Chromium absent: install Debian's package (apt-get install -y chromium)")
    b = Browser(executable)
    yield b
    b.close()
