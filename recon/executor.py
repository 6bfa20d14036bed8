"""Where per-image and per-pair work runs: a local process pool by default, a Dask cluster on request.

Both are ``concurrent.futures.Executor``s (Dask's through ``Client.get_executor``), so stages submit
work one way whatever runs it (docs/ARCHITECTURE.md, "Parallel and distributed"). The executor is created
lazily: a run whose stages are all cached starts no worker.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import os
import re
import signal
import threading
import time

from recon.config import ConfigError

_SPEC = re.compile(r"^(local|serial|processes:(\d+)|dask-local:(\d+)|dask://\S+|tcp://\S+)$")


def check_spec(spec: str) -> str:
    if not _SPEC.match(spec):
        raise ConfigError(f"executor: '{spec}' is not one of local | serial | processes:N | "
                          "dask://host:port | dask-local:N")
    return spec


class Executor:
    """A lazily started ``concurrent.futures`` executor for a run."""

    def __init__(self, spec: str = "local"):
        self.spec = check_spec(spec)
        self._pool: cf.Executor | None = None
        self._cluster = None
        self._client = None

    @property
    def workers(self) -> int:
        m = re.match(r"(processes|dask-local):(\d+)", self.spec)
        if m:
            return max(1, int(m.group(2)))
        if self.spec == "serial":
            return 1
        if self.spec == "local":
            return max(1, len(os.sched_getaffinity(0)))
        _ = self.pool  # a remote cluster's size is known once connected
        return max(1, sum(self._client.nthreads().values()))

    @property
    def pool(self) -> cf.Executor:
        if self._pool is None:
            self._pool = self._start()
        return self._pool

    def _start(self) -> cf.Executor:
        if self.spec == "serial":
            return _SerialExecutor()
        if self.spec == "local" or self.spec.startswith("processes:"):
            # forkserver: workers start from a clean process, so threads the parent may hold
            # (BLAS, COLMAP's thread pools) cannot deadlock a forked child.
            ctx = multiprocessing.get_context("forkserver")
            # the server imports the heavy libraries once, so each worker starts in milliseconds
            ctx.set_forkserver_preload(["recon", "numpy", "cv2", "pycolmap", "recon.sparse.features", "recon.logs"])
            _start_forkserver()
            return cf.ProcessPoolExecutor(max_workers=self.workers, mp_context=ctx, initializer=_worker_setup,
                                          initargs=(os.getpid(),))
        from dask.distributed import Client, LocalCluster

        if self.spec.startswith("dask-local:"):
            self._cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1,
                                         processes=True, dashboard_address=None)
            self._client = Client(self._cluster)
        else:
            address = self.spec.replace("dask://", "tcp://", 1)
            self._client = Client(address, timeout="20s")
        return self._client.get_executor(pure=False)

    def shutdown(self, abandon: bool = False) -> None:
        """Stop the workers. ``abandon``: the run is stopping (Ctrl-C, SIGTERM, an error), so the items
        in flight are not waited for: a PatchMatch view can take minutes (seen: a SIGTERM'd run that
        held its workspace for ten more minutes), and every item is written atomically, so they are
        simply redone by the next run. Local workers are killed; the pool then fails the futures it
        still holds (nothing reads them), so none may be cancelled before (Python 3.11 raises on
        failing a cancelled future)."""
        if self._pool is not None:
            if isinstance(self._pool, cf.ProcessPoolExecutor):
                workers = list((self._pool._processes or {}).values()) if abandon else []  # no public handle
                self._pool.shutdown(wait=not abandon, cancel_futures=not abandon)
                for worker in workers:
                    worker.kill()
            else:  # Dask's executor: shutdown(wait=False) cancels what is not done
                self._pool.shutdown(wait=not abandon)
            self._pool = None
        if self._client is not None:
            self._client.close()
            self._client = None
        if self._cluster is not None:
            self._cluster.close()
            self._cluster = None


#: BLAS thread counts, read once when numpy loads
_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def _start_forkserver() -> None:
    """Start the forkserver (which preloads numpy) with one BLAS thread per process, as Dask does for
    its workers: the processes are the parallelism, and BLAS threads on top oversubscribe the cores
    (matching temple_ring on 2 cores: 7.5 s with two BLAS threads per worker, 3.2 s with one)."""
    import multiprocessing.forkserver

    saved = {name: os.environ.get(name) for name in _BLAS_THREADS}
    os.environ.update({name: "1" for name in _BLAS_THREADS})
    try:
        multiprocessing.forkserver.ensure_running()
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value


def _worker_setup(main_pid: int) -> None:
    """Pool workers ignore Ctrl-C (which the terminal sends to every process of the run): the main
    process stops the run and the pool lets each worker finish its item, so no traceback is printed
    and no item in flight is lost. They exit when the main process dies (``kill -9``, the OOM
    killer): an orphaned pool would otherwise idle forever, holding memory and the terminal.
    SIGTERM ends a worker quietly: the handler pycolmap installs (glog's) would print a native
    stack dump first."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    threading.Thread(target=_exit_with, args=(main_pid,), daemon=True, name="recon-orphan-watch").start()


def _exit_with(pid: int, every: float = 1.0) -> None:
    import psutil

    try:
        main = psutil.Process(pid)
        while main.is_running() and main.status() != psutil.STATUS_ZOMBIE:
            time.sleep(every)
    except psutil.NoSuchProcess:
        pass
    os._exit(1)


class _SerialExecutor(cf.Executor):
    """Runs each task in the calling process (debugging, and tiny inputs)."""

    def submit(self, fn, /, *args, **kwargs):
        future: cf.Future = cf.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # delivered through the future like a pool would
            future.set_exception(exc)
        return future
