"""Console and file logging for runs, and COLMAP's own (glog) log lines routed into the workspace log."""

from __future__ import annotations

import logging
import sys
from pathlib import Path


def setup_console(verbosity: int = 0) -> None:
    """INFO lines on stderr (WARNING with --quiet, DEBUG with --verbose)."""
    level = {-1: logging.WARNING, 0: logging.INFO}.get(verbosity, logging.DEBUG)
    root = logging.getLogger("recon")
    root.setLevel(logging.DEBUG)
    for handler in [h for h in root.handlers if getattr(h, "_recon_console", False)]:
        root.removeHandler(handler)
    handler = logging.StreamHandler(sys.stderr)
    handler.setLevel(level)
    handler.setFormatter(logging.Formatter("%(message)s" if level > logging.DEBUG
                                           else "%(asctime)s %(name)s: %(message)s"))
    handler._recon_console = True  # type: ignore[attr-defined]
    root.addHandler(handler)
    root.propagate = False


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
