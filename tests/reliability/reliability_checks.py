"""What the reliability tests check again and again: the CLI's one-line errors, and that two
workspaces hold the same reconstruction."""

from __future__ import annotations

import contextlib
import filecmp
import shutil
import signal
import sqlite3
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
#: pipelines/sparse.yaml with single-threaded (bit-identical) SfM: the config of the sparse_workspace fixture
SPARSE = REPO / "tests" / "sparse_test.yaml"
INTERRUPTED = "recon: interrupted; finished stages and items are kept: run the same command again to resume"
SPARSE_STAGES = ["ingest", "calibrate", "preprocess", "features", "matching", "sfm", "export"]
#: the user-facing files of a sparse run that must be identical byte for byte on a re-run
MODEL_FILES = ["sparse/0/cameras.bin", "sparse/0/images.bin", "sparse/0/points3D.bin", "sparse_text/cameras.txt",
               "sparse_text/images.txt", "sparse_text/points3D.txt", "points.ply", "transforms.json"]


def ctrl_c_reaches_it() -> None:
    """A shell that runs CI in the background ignores SIGINT in its children (POSIX), and Python then
    installs no KeyboardInterrupt handler: give the child a terminal's default, as a user's shell does."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def cli(*args: str, timeout: float = 300, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "recon.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, **kwargs)


def assert_one_line_error(proc: subprocess.CompletedProcess, starts: str) -> str:
    """The run failed with exit code 2, one ``recon: error:`` line (the last) and no traceback."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    lines = [line for line in proc.stderr.splitlines() if line.startswith("recon:")]
    assert len(lines) == 1 and lines[0] == proc.stderr.strip().splitlines()[-1], proc.stderr[-2000:]
    assert lines[0].startswith(f"recon: error: {starts}"), lines[0]
    return lines[0]


def database_rows(path: Path) -> dict[str, list]:
    """Every table of a COLMAP database, rows sorted: its content whatever order they were written in.
    Read from a copy: opening a WAL database, even read-only, leaves -wal/-shm files beside it."""
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(shutil.copyfile(path, Path(tmp) / "copy.db"))
        with contextlib.closing(sqlite3.connect(copy)) as con:
            tables = [t for (t,) in con.execute("SELECT name FROM sqlite_master WHERE type='table'")]
            return {t: sorted(con.execute(f"SELECT * FROM {t}").fetchall(), key=repr) for t in tables}


def assert_same_reconstruction(ws: Path, reference: Path, exact: bool = True) -> None:
    """The same database content and the same sparse model: identical files (``exact``, what
    ``sfm.deterministic`` promises), else the same photos registered with camera centres within
    1e-3 of the cameras' spread (multi-threaded bundle adjustment sums in scheduling order)."""
    assert database_rows(ws / "database.db") == database_rows(reference / "database.db")
    if exact:
        for rel in MODEL_FILES:
            assert filecmp.cmp(ws / rel, reference / rel, shallow=False), f"{rel} differs"
        return
    a, b = centres(ws), centres(reference)
    assert sorted(a) == sorted(b)
    ca, cb = (np.array([c[n] for n in sorted(a)]) for c in (a, b))
    spread = np.linalg.norm(cb - cb.mean(0), axis=1).mean()
    assert np.abs(ca - cb).max() <= 1e-3 * spread
    for rel in MODEL_FILES[3:]:
        assert (ws / rel).is_file() and (ws / rel).stat().st_size > 0, rel


def centres(ws: Path) -> dict[str, np.ndarray]:
    """Camera centres of the registered photos of ``sparse/0``, by name."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    return {img.name: img.projection_center() for img in rec.images.values() if img.has_pose}


def cache_dir(ws: Path, stage: str) -> Path:
    return ws / ".recon" / "cache" / stage


def complete_outputs(ws: Path, stage: str) -> list[Path]:
    return sorted(p.parent for p in cache_dir(ws, stage).glob("*/manifest.json") if not p.parent.name.endswith(".partial"))


def partial_outputs(ws: Path, stage: str) -> list[Path]:
    return sorted(cache_dir(ws, stage).glob("*.partial"))
