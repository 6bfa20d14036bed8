"""Progress bars with counts and an ETA, drawn by rich, for a person watching a terminal.

Whether bars are drawn is decided once, by the command line (:func:`recon.logs.setup_console`):
stderr is an interactive terminal and the run is not ``--quiet``. Everywhere else (CI logs, pipes,
files, recon used as a library) no bar is drawn and :class:`recon.stage.Progress` logs plain lines.
One bar is live at a time; starting a new one finishes the previous one.
"""

from __future__ import annotations

import atexit
import sys
import threading

_enabled = False
_lock = threading.Lock()
_active: Bar | None = None


def enable_bars(enabled: bool) -> None:
    """Draw bars from now on (only when stderr is a terminal), or stop drawing them."""
    global _enabled
    _enabled = bool(enabled) and sys.stderr.isatty()


def bars_enabled() -> bool:
    return _enabled


class Bar:
    """A live bar ``desc ━━━━━━━╸━━━ 12/40 0:00:05 ETA 0:00:11`` on stderr until ``total`` is reached."""

    def __init__(self, desc: str, total: int):
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        global _active
        with _lock:
            if _active is not None:
                _active.close()
            self._progress = Progress(
                TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                TextColumn("ETA"), TimeRemainingColumn(),
                console=Console(file=sys.stderr), transient=False, redirect_stderr=True, redirect_stdout=False)
            self._task = self._progress.add_task(desc, total=total)
            self._progress.start()
            self.closed = False
            _active = self

    def advance(self, n: int = 1) -> None:
        self._progress.advance(self._task, n)
        task = self._progress.tasks[0]
        if task.total is not None and task.completed >= task.total:
            self.close()

    def close(self) -> None:
        """Draw the final state and release the terminal (idempotent)."""
        global _active
        if self.closed:
            return
        self.closed = True
        self._progress.stop()
        if _active is self:
            _active = None


@atexit.register
def _close_active() -> None:  # never leave the terminal's cursor hidden
    if _active is not None:
        _active.close()
