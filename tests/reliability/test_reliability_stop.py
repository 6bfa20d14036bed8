"""A stopped run does not wait for the items its workers are computing (a PatchMatch view can take
minutes): seen once as a SIGTERM'd run that said it had stopped and held its workspace's lock for
ten minutes more. Items are written atomically, so the ones in flight are redone by the next run."""

from __future__ import annotations

import time

from recon.executor import Executor


def test_a_stopping_run_kills_its_workers_instead_of_waiting():
    executor = Executor("processes:1")
    future = executor.pool.submit(time.sleep, 120)
    deadline = time.monotonic() + 30
    while not future.running() and time.monotonic() < deadline:
        time.sleep(0.1)
    workers = list(executor.pool._processes.values())
    start = time.monotonic()
    executor.shutdown(abandon=True)
    assert time.monotonic() - start < 10
    for worker in workers:
        worker.join(10)
        assert not worker.is_alive()
