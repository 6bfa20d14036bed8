"""The Stage contract and the stage registry.

A stage is a small class with a ``name``, a ``version`` (bump it when its output would change for
the same inputs), a ``Config`` dataclass (every field declared with :func:`recon.options.opt`), the
products it ``requires`` (and reads when present: ``optional``), the product it ``produces`` (whose
class owns the file names and the workspace links, :mod:`recon.products`), and ``run(ctx, cfg)``,
which reads its inputs through ``ctx.input(Product)`` and writes only into ``ctx.out``. The pipeline decides whether it runs, from its cache key (docs/ARCHITECTURE.md, "Stages").
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterable
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, TypeVar

from recon.executor import Executor
from recon.products import Product
from recon.progress import Bar, bars_enabled
from recon.workspace import HashCache, Workspace

P = TypeVar("P", bound=Product)


class StageError(RuntimeError):
    """A stage failed for a reason the user can act on; the message says what to do."""


class Stage:
    name: ClassVar[str]
    version: ClassVar[int] = 1
    Config: ClassVar[type]
    #: the products it reads: the stages that make them run before it and their keys join its key
    requires: ClassVar[tuple[type[Product], ...]] = ()
    #: products it also reads when their stages are part of the run
    optional: ClassVar[tuple[type[Product], ...]] = ()
    #: the product it writes into its output folder
    produces: ClassVar[type[Product]]
    #: whether the run's seed changes this stage's output (then it is part of the key)
    uses_seed: ClassVar[bool] = False
    summary: ClassVar[str] = ""

    @property
    def publish(self) -> dict[str, str]:
        """Output-relative path -> workspace link (the product's)."""
        return self.produces.publish

    @property
    def upstream(self) -> tuple[str, ...]:
        """The stages whose outputs it reads: the producers of its required, then optional, products."""
        return tuple(producer(p) for p in (*self.requires, *self.optional))

    @property
    def needs(self) -> tuple[str, ...]:
        """The stages that must run before it: the producers of its required products."""
        return tuple(producer(p) for p in self.requires)

    def fingerprint(self, ctx: StageContext, cfg: Any) -> Any:
        """Extra cache-key material (ingest: the input files' content). None for most stages."""
        return None

    def run(self, ctx: StageContext, cfg: Any) -> dict:
        """Do the work; return a small summary (counts, figures) recorded in the manifest."""
        raise NotImplementedError

    def reusable(self, ctx: StageContext, cfg: Any) -> str | None:
        """What a run would take from earlier runs' per-item results (:mod:`recon.items`), in a few
        words, given its inputs (``ctx`` as in :meth:`run`, but nothing is written): ``recon status``.
        None for stages that keep no such results."""
        return None


REGISTRY: dict[str, Stage] = {}


def register(cls: type[Stage]) -> type[Stage]:
    """Class decorator: add a stage to the registry (registration order = pipeline order)."""
    other = next((s.name for s in REGISTRY.values() if s.produces is cls.produces and s.name != cls.name), None)
    if other is not None:
        raise TypeError(f"stages {other} and {cls.name} both produce {cls.produces.__name__}")
    REGISTRY[cls.name] = cls()
    return cls


def producer(product: type[Product]) -> str:
    """The name of the stage that makes ``product``."""
    for name, stage in REGISTRY.items():
        if stage.produces is product:
            return name
    raise KeyError(f"no stage produces {product.__name__}")


def resolve_path(base: Path, value: str | os.PathLike) -> Path:
    """A path from a config: ``~`` and ``$VARS`` expanded, relative to ``base`` (the config's folder)."""
    return (Path(base) / os.path.expandvars(os.path.expanduser(os.fspath(value)))).resolve()


@dataclass
class StageContext:
    """What a stage sees. While the cache key is computed (:meth:`Stage.fingerprint`) ``out`` is not
    yet made, ``executor`` is None and ``upstream`` holds only the stages planned in this run (where
    their outputs will be); while it runs, ``out`` is its temporary output folder."""

    name: str
    out: Path
    workspace: Workspace
    images: Path | None
    seed: int
    executor: Executor | None
    base: Path  # the folder that relative config paths are resolved against
    hashes: HashCache
    video: Path | None = None
    upstream: dict[str, Path] = field(default_factory=dict)
    #: the whole run's resolved config as plain data (what the report shows)
    settings: dict[str, Any] = field(default_factory=dict)
    #: whether per-item results of earlier runs (:mod:`recon.items`) may be reused; not when forced
    reuse: bool = True

    @property
    def log(self) -> logging.Logger:
        return logging.getLogger(f"recon.{self.name}")

    def resolve(self, value: str | os.PathLike) -> Path:
        """A path option of the config as an absolute path (see :func:`resolve_path`)."""
        return resolve_path(self.base, value)

    def user_path(self, option: str, value: str | os.PathLike | None, hint: str, folder: bool = False) -> Path | None:
        """The user's file (or ``folder``) a path option of this stage names, resolved; None when the
        option is unset; a one-line error naming the option and ``hint`` (what to give) when the
        path is not one."""
        if value is None:
            return None
        path = self.resolve(value)
        if not (path.is_dir() if folder else path.is_file()):
            raise StageError(f"{self.name}.{option}: {path} is not a {'folder' if folder else 'file'}; {hint}")
        return path

    def digest(self, path: Path) -> str:
        """The content hash of an input file (remembered across runs)."""
        return self.hashes.digest(path)

    def input(self, product: type[P]) -> P:
        """An upstream product (typed as ``product``), from the completed output of its stage."""
        stage = producer(product)
        try:
            return product(self.upstream[stage])
        except KeyError:
            raise StageError(f"{self.name}: needs the output of stage '{stage}', which this run "
                             "does not include; add it to `stages`") from None

    def has(self, product: type[Product]) -> bool:
        """Whether an optional upstream product is part of this run."""
        return producer(product) in self.upstream

    @property
    def output(self) -> Any:
        """This stage's own product, rooted at its temporary output folder."""
        return REGISTRY[self.name].produces(self.out)

    def map(self, fn: Callable, items: Iterable, *, desc: str, done: Callable[[Any], bool] | None = None,
            size: Callable[[Any], int] | None = None) -> list:
        """Run ``fn(item)`` for each item through the executor, one task per item.

        Items for which ``done(item)`` is true were finished by an earlier, interrupted run and are
        skipped (their result is None): per-item resume. ``fn`` writes its own output atomically.
        Progress counts items, or ``size(item)`` units per item (e.g. the pairs of a block of pairs).
        """
        items = list(items)
        todo = [i for i, item in enumerate(items) if done is None or not done(item)]
        results: list = [None] * len(items)
        if len(todo) < len(items):
            self.log.info("%s: %d of %d already done, resuming", desc, len(items) - len(todo), len(items))
        size = size or (lambda item: 1)
        progress = Progress(self.log, desc, sum(size(items[i]) for i in todo))
        if len(todo) <= 1 or self.executor.spec == "serial":
            try:
                for i in todo:
                    results[i] = fn(items[i])
                    progress.advance(size(items[i]))
            finally:
                progress.close()
            return results
        pool = self.executor.pool
        futures = {pool.submit(fn, items[i]): i for i in todo}
        try:
            for future in _as_completed(futures):
                results[futures[future]] = future.result()
                progress.advance(size(items[futures[future]]))
        except BaseException as exc:  # the pipeline stops the executor (Executor.shutdown(abandon=True))
            progress.close()
            if isinstance(exc, BrokenProcessPool):
                raise StageError(f"{desc}: a worker process died (out of memory, or a crash in native code; a "
                                 "Python script that calls recon.run must do so under `if __name__ == "
                                 "\"__main__\":`, since each worker imports the script); what is finished is "
                                 "kept: run again to resume") from None
            raise
        return results


def _as_completed(futures):
    import concurrent.futures as cf

    try:
        yield from cf.as_completed(futures)
    except TypeError:  # dask futures
        from dask.distributed import as_completed

        yield from as_completed(list(futures))


class Progress:
    """Counts and ETA for long work: a progress bar on an interactive terminal (:mod:`recon.progress`),
    else a log line at most every few seconds (CI logs, pipes, ``--quiet``, library use)."""

    def __init__(self, log: logging.Logger, desc: str, total: int, every: float = 5.0):
        self.log, self.desc, self.total, self.every = log, desc, total, every
        self.done = 0
        self.start = self.last = time.monotonic()
        self.bar = Bar(desc, total) if bars_enabled() and total > 0 else None

    def advance(self, n: int = 1) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.advance(n)
        now = time.monotonic()
        if self.done >= self.total or now - self.last >= self.every:
            self.last = now
            elapsed = now - self.start
            eta = elapsed / self.done * (self.total - self.done) if self.done else 0.0
            tail = f", ETA {eta:.0f} s" if self.done < self.total else f" in {elapsed:.1f} s"
            # with a bar on screen the line goes to the log file only
            level = logging.DEBUG if self.bar is not None else logging.INFO
            self.log.log(level, "%s: %d/%d%s", self.desc, self.done, self.total, tail)

    def close(self) -> None:
        """Take the bar off the terminal if the work stopped early (an error)."""
        if self.bar is not None:
            self.bar.close()
