"""A run killed with SIGKILL mid-stage resumes where it stopped and gives the same model; a worker that dies
stops the stage with a one-line error, keeping what is finished."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pycolmap
import pytest

from recon.executor import Executor
from recon.stage import StageContext, StageError
from recon.workspace import HashCache, Workspace

REPO = Path(__file__).resolve().parents[2]
SPARSE = REPO / "tests" / "sparse_test.yaml"


def start_run(scene: Path, ws: Path, *overrides: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "recon.cli", "-q", "run", str(SPARSE), "--images", str(scene / "images"),
           "--workspace", str(ws), "-o", "executor=serial"]
    for o in overrides:
        cmd += ["-o", o]
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def kill_when(proc: subprocess.Popen, ready, timeout: float = 120) -> None:
    deadline = time.monotonic() + timeout
    while not ready():
        if proc.poll() is not None:
            raise AssertionError(f"run ended before the kill point: {proc.stderr.read()}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError("kill point not reached")
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def features_done(ws: Path) -> int:
    return len(list(ws.glob(".recon/cache/features/*.partial/features/*.npz")))


def matched_pairs(ws: Path) -> int:
    """Pairs in the matching stage's finished blocks (each block file is written atomically)."""
    return sum(len(np.load(p)["pairs"]) for p in ws.glob(".recon/cache/matching/*.partial/blocks/*.npz"))


def poses(ws: Path) -> dict[str, np.ndarray]:
    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    return {img.name: img.projection_center() for img in rec.images.values() if img.has_pose}


def assert_same_model(a: Path, b: Path) -> None:
    pa, pb = poses(a), poses(b)
    assert sorted(pa) == sorted(pb)
    ca = np.array([pa[n] for n in sorted(pa)])
    cb = np.array([pb[n] for n in sorted(pb)])
    spread = np.linalg.norm(ca - ca.mean(0), axis=1).mean()
    assert np.abs(ca - cb).max() < 1e-6 * spread + 1e-9


@pytest.mark.parametrize("stage", ["features", "matching"])
def test_sigkill_then_rerun_gives_the_same_model(stage, small_scene, sparse_workspace, tmp_path):
    ws = tmp_path / "ws"
    if stage == "features":
        proc = start_run(small_scene, ws)
        kill_when(proc, lambda: features_done(ws) >= 3)
        assert 3 <= features_done(ws) < 16, "the kill should land mid-stage"
    else:
        proc = start_run(small_scene, ws, "matching.chunk_pairs=5")
        kill_when(proc, lambda: matched_pairs(ws) >= 5)
        assert 5 <= matched_pairs(ws) < 120, "the kill should land mid-stage"
    assert not (ws / "sparse").exists()
    done = subprocess.run([sys.executable, "-m", "recon.cli", "run", str(SPARSE), "--images",
                           str(small_scene / "images"), "--workspace", str(ws), "-o", "executor=serial"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "already done, resuming" in done.stderr
    # COLMAP's own log lines (glog format) go to the workspace's log files, not the terminal
    assert not re.search(r"^[IWE]\d{8} ", done.stderr, re.MULTILINE), done.stderr[:500]
    assert list(ws.glob(".recon/logs/*"))
    assert_same_model(ws, sparse_workspace)


def test_a_worker_that_dies_stops_the_stage_with_a_one_line_error(tmp_path):
    """Out of memory, a native crash, or a user's script that calls recon.run unguarded (each worker
    imports it, runs it again and dies on the locked workspace): the stage names what to do, not the
    pool's BrokenProcessPool."""
    ws = Workspace(tmp_path / "ws")
    executor = Executor("processes:2")
    ctx = StageContext(name="demo", out=tmp_path, workspace=ws, images=None, seed=0, executor=executor,
                       base=tmp_path, hashes=HashCache(ws))
    try:
        with pytest.raises(StageError) as error:
            ctx.map(os._exit, [1, 1], desc="demo work")  # each worker exits at once
    finally:
        executor.shutdown(abandon=True)
    message = str(error.value)
    assert message.startswith("demo work: a worker process died") and "\n" not in message
    assert 'if __name__ == "__main__":' in message and "run again to resume" in message
