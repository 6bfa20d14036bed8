"""Console and file logging for runs, and COLMAP's own (glog) log lines routed into the workspace log."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from pathlib import Path


def setup_console(verbosity: int = 0) -> None:
    """INFO lines on stderr (WARNING with --quiet, DEBUG with --verbose); progress bars when stderr is
    an interactive terminal and the run is not --quiet."""
    from recon.progress import enable_bars

    level = {-1: logging.WARNING, 0: logging.INFO}.get(verbosity, logging.DEBUG)
    root = logging.getLogger("recon")
    root.setLevel(logging.DEBUG)
    for handler in [h for h in root.handlers if getattr(h, "_recon_console", False)]:
        root.removeHandler(handler)
    handler = _StderrHandler()
    handler.setLevel(level)
    handler.setFormatter(logging.Formatter("%(message)s" if level > logging.DEBUG
                                           else "%(asctime)s %(name)s: %(message)s"))
    handler._recon_console = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.propagate = False
    enable_bars(verbosity >= 0)


class _StderrHandler(logging.StreamHandler):
    """Writes to whatever ``sys.stderr`` is at the time: while a progress bar is live, rich points it
    at a proxy that prints lines above the bar instead of through it."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # StreamHandler.__init__ assigns it; the property ignores that
        pass

    def format(self, record: logging.LogRecord) -> str:
        """The line with what cannot be written escaped (``\\udce9``): a file name that is not UTF-8
        carries surrogates, which a strict stream (a redirected or wrapped stderr) refuses with a
        logging traceback."""
        return super().format(record).encode("utf-8", "backslashreplace").decode("utf-8")


def quiet_colmap(log_file: Path | None = None) -> None:
    """Send COLMAP's INFO/WARNING lines to files named ``log_file`` + a timestamp (or drop them);
    errors still reach stderr."""
    import pycolmap

    L = pycolmap.logging
    L.logtostderr = False
    L.alsologtostderr = False
    L.stderrthreshold = int(L.Level.ERROR)
    if log_file is not None:
        Path(log_file).parent.mkdir(parents=True, exist_ok=True)
        L.minloglevel = int(L.Level.INFO)
        L.set_log_destination(L.Level.INFO, str(log_file))
    else:
        L.minloglevel = int(L.Level.ERROR)


@contextlib.contextmanager
def native_stderr_to(path: Path):
    """Route what C/C++ code writes to file descriptor 2 (COLMAP's glog lines, Ceres reports) into
    ``path``, while Python's own ``sys.stderr`` (log lines, progress bars) still reaches the terminal.

    pycolmap switches glog's "also log to stderr" on inside some calls (bundle adjustment), so the
    glog flags alone cannot keep those lines off the terminal.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(AttributeError, ValueError):
        sys.stderr.flush()
    saved = os.dup(2)
    swap = _is_fd2(sys.stderr)
    original = sys.stderr
    try:
        with open(path, "ab") as sink:
            os.dup2(sink.fileno(), 2)
        if swap:
            sys.stderr = os.fdopen(os.dup(saved), "w", buffering=1, encoding=original.encoding,
                                   errors="backslashreplace")
        yield
    finally:
        if swap:
            sys.stderr.flush()
            sys.stderr.close()
            sys.stderr = original
        os.dup2(saved, 2)
        os.close(saved)


def _is_fd2(stream) -> bool:
    try:
        return stream.fileno() == 2
    except (AttributeError, OSError, ValueError):
        return False


def file_handler(path: Path) -> logging.FileHandler:
    """A handler appending to the workspace log ``path`` in UTF-8, escaping what UTF-8 cannot hold
    (the surrogates of a file name that is not UTF-8) instead of failing with a logging traceback."""
    return logging.FileHandler(path, encoding="utf-8", errors="backslashreplace")


def log_file() -> Path | None:
    """The workspace log file the current run writes to (where ``recon`` points for a traceback)."""
    handlers = [h for h in logging.getLogger("recon").handlers if isinstance(h, logging.FileHandler)]
    return Path(handlers[-1].baseFilename) if handlers else None
