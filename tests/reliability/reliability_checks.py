"""What the reliability tests check again and again: the CLI's one-line errors, and that two
workspaces hold the same reconstruction."""

from __future__ import annotations

import filecmp
import sqlite3
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
SPARSE = REPO / "pipelines" / "sparse.yaml"
INTERRUPTED = "recon: interrupted; finished stages and items are kept: run the same command again to resume"
SPARSE_STAGES = ["ingest", "calibrate", "preprocess", "features", "matching", "sfm", "export"]
#: the user-facing files of a sparse run that must be identical byte for byte on a re-run
MODEL_FILES = ["sparse/0/cameras.bin", "sparse/0/images.bin", "sparse/0/points3D.bin", "sparse_text/cameras.txt",
               "sparse_text/images.txt", "sparse_text/points3D.txt", "points.ply", "transforms.json"]


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
    """Every table of a COLMAP database, rows sorted: its content whatever order they were written in."""
    with sqlite3.connect(f"file:{path}?mode=ro", uri=True) as con:
        tables = [t for (t,) in con.execute("SELECT name FROM sqlite_master WHERE type='table'")]
        return {t: sorted(con.execute(f"SELECT * FROM {t}").fetchall(), key=repr) for t in tables}


def assert_same_reconstruction(ws: Path, reference: Path) -> None:
    """Same sparse model and exports (identical files) and the same database content."""
    for rel in MODEL_FILES:
        assert filecmp.cmp(ws / rel, reference / rel, shallow=False), f"{rel} differs"
    assert database_rows(ws / "database.db") == database_rows(reference / "database.db")


def cache_dir(ws: Path, stage: str) -> Path:
    return ws / ".recon" / "cache" / stage


def complete_outputs(ws: Path, stage: str) -> list[Path]:
    return sorted(p.parent for p in cache_dir(ws, stage).glob("*/manifest.json") if not p.parent.name.endswith(".partial"))


def partial_outputs(ws: Path, stage: str) -> list[Path]:
    return sorted(cache_dir(ws, stage).glob("*.partial"))
