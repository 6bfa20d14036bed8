"""A stopped run does not wait for the items its workers are computing (a PatchMatch view can take
minutes): seen once as a SIGTERM'd run that said it had stopped and held its workspace's lock for
ten minutes more. Items are written atomically, so the ones in flight are redone by the next run."""

from __future__ import annotations

import subprocess
import sys
import time

import psutil

STOPPED = """
import sys, time
from recon.executor import Executor

executor = Executor("processes:1")
future = executor.pool.submit(time.sleep, 120)
while not future.running():
    time.sleep(0.1)
print(" ".join(str(p.pid) for p in executor.pool._processes.values()), flush=True)
import recon.cli

def run(args):  # Ctrl-C while the worker computes its item, as pipeline.run meets it
    try:
        raise KeyboardInterrupt
    except BaseException:
        executor.shutdown(abandon=True)
        raise

recon.cli._dispatch = run
sys.exit(recon.cli.main(["stages"]))
"""


def test_a_stopped_run_exits_at_once_and_its_workers_follow():
    start = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", STOPPED], capture_output=True, text=True, timeout=60)
    assert time.monotonic() - start < 30, "the item in flight (120 s) was waited for"
    assert proc.returncode == 130, proc.stderr
    assert proc.stderr.strip() == ("recon: interrupted; finished stages and items are kept: run the same "
                                   "command again to resume"), proc.stderr
    workers = [int(pid) for pid in proc.stdout.split()]
    deadline = time.monotonic() + 10
    while any(psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE for pid in workers):
        assert time.monotonic() < deadline, "a worker outlived the run"
        time.sleep(0.2)
