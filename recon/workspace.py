"""The workspace: owns every path on disk, atomic writes, the run lock and the stage cache.

Layout (DESIGN.md, "Workspace on disk")::

    <workspace>/
      database.db, sparse/0/, points.ply, transforms.json, dense/, ...   user-facing, COLMAP-readable
      .recon/
        lock                      held (flock) by the running `recon run`; holds its pid
        state.json                the key each stage last completed with
        hashes.json               content hashes of input files, keyed by (path, size, mtime)
        recon.log                 the full log of every run
        cache/<stage>/<key>/      a completed stage output, with manifest.json
        cache/<stage>/<key>.partial/   an output being written (kept across kills: per-item resume)

User-facing paths are relative symbolic links into the cache, so a file the user opens is always
the output of the stage's current key, and COLMAP, MeshLab or Blender read them in place.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

CACHE_DIR = ".recon"
MANIFEST = "manifest.json"


class WorkspaceError(RuntimeError):
    """A workspace problem worded for the user."""


class Workspace:
    """One reconstruction's folder on disk."""

    def __init__(self, root: Path | str):
        self.root = Path(root).absolute()
        self.meta = self.root / CACHE_DIR
        self._lock_fd: int | None = None

    # -- creation and locking ---------------------------------------------------------------
    def create(self) -> None:
        try:
            (self.meta / "cache").mkdir(parents=True, exist_ok=True)
        except PermissionError:
            raise WorkspaceError(f"{self.root}: workspace folder is not writable; "
                                 "choose another --workspace or fix its permissions") from None
        except OSError as exc:
            raise WorkspaceError(f"{self.root}: cannot create the workspace ({exc.strerror})") from None
        if not os.access(self.meta, os.W_OK):
            raise WorkspaceError(f"{self.root}: workspace folder is not writable; "
                                 "choose another --workspace or fix its permissions")

    @contextlib.contextmanager
    def locked(self):
        """Hold the workspace's run lock; a second run gets 'in use by pid N'."""
        self.create()
        path = self.meta / "lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            other = os.pread(fd, 64, 0).decode(errors="replace").strip() or "?"
            os.close(fd)
            raise WorkspaceError(f"{self.root}: workspace is in use by pid {other} (another recon run); "
                                 "wait for it to finish or stop it") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._lock_fd = fd
        try:
            yield self
        finally:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
            os.close(fd)
            self._lock_fd = None

    # -- cache folders ---------------------------------------------------------------------
    def stage_dir(self, stage: str) -> Path:
        return self.meta / "cache" / stage

    def output_dir(self, stage: str, key: str) -> Path:
        return self.stage_dir(stage) / key[:16]

    def partial_dir(self, stage: str, key: str) -> Path:
        return self.stage_dir(stage) / f"{key[:16]}.partial"

    def is_complete(self, stage: str, key: str) -> bool:
        return (self.output_dir(stage, key) / MANIFEST).is_file()

    def manifest(self, stage: str, key: str) -> dict | None:
        path = self.output_dir(stage, key) / MANIFEST
        return read_json(path) if path.is_file() else None

    def manifests(self, stage: str) -> list[dict]:
        """Manifests of every completed output of ``stage``, oldest first."""
        found = []
        for path in sorted(self.stage_dir(stage).glob(f"*/{MANIFEST}")):
            if not path.parent.name.endswith(".partial"):
                data = read_json(path)
                if data:
                    found.append(data)
        return sorted(found, key=lambda m: m.get("finished", 0))

    def begin(self, stage: str, key: str) -> Path:
        """The temporary output folder for ``stage``: kept from an interrupted run with the same key."""
        partial = self.partial_dir(stage, key)
        partial.mkdir(parents=True, exist_ok=True)
        return partial

    def commit(self, stage: str, key: str, manifest: dict) -> Path:
        """Write the manifest and atomically move the finished output into place."""
        partial = self.partial_dir(stage, key)
        write_json(partial / MANIFEST, manifest)
        final = self.output_dir(stage, key)
        if final.exists():  # a --force re-run replaces the previous complete output
            trash = final.with_name(final.name + f".old-{os.getpid()}")
            os.rename(final, trash)
            shutil.rmtree(trash, ignore_errors=True)
        os.rename(partial, final)
        _fsync_dir(final.parent)
        return final

    # -- state ------------------------------------------------------------------------------
    def state(self) -> dict[str, str]:
        return read_json(self.meta / "state.json") or {}

    def set_state(self, stage: str, key: str) -> None:
        state = self.state()
        state[stage] = key
        write_json(self.meta / "state.json", state)

    # -- user-facing links ---------------------------------------------------------------
    def publish(self, target: Path, link: str) -> None:
        """Point ``<workspace>/<link>`` at ``target`` with a relative symlink (atomic replace)."""
        dest = self.root / link
        dest.parent.mkdir(parents=True, exist_ok=True)
        if dest.exists() and not dest.is_symlink():
            if dest.is_dir():
                shutil.rmtree(dest)
            else:
                dest.unlink()
        rel = os.path.relpath(target, dest.parent)
        tmp = dest.with_name(f".{dest.name}.link-{os.getpid()}")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(rel, tmp)
        os.replace(tmp, dest)


# -----------------------------------------------------------------------------------------
# Small file helpers used across recon


def write_json(path: Path, data: Any) -> None:
    """Atomically write JSON (temp file in the same folder, fsync, rename)."""
    write_bytes(path, (json.dumps(data, indent=2, sort_keys=False, default=str) + "\n").encode())


def write_bytes(path: Path, data: bytes) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
            raise WorkspaceError(f"{path.parent}: no space left on the device; completed stages are "
                                 "kept; free some space and run again") from None
        raise


def read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text())
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def atomic_path(path: Path) -> Path:
    """A temp sibling of ``path`` to write to, then ``os.replace`` onto ``path``."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def file_digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


class HashCache:
    """Content hashes of input files, recomputed only when a file's size or mtime changes."""

    def __init__(self, workspace: Workspace):
        self.path = workspace.meta / "hashes.json"
        self.table: dict[str, list] = read_json(self.path) or {}
        self.dirty = False

    def digest(self, path: Path) -> str:
        st = path.stat()
        key = str(path.absolute())
        cached = self.table.get(key)
        if cached and cached[0] == st.st_size and cached[1] == st.st_mtime_ns:
            return cached[2]
        digest = file_digest(path)
        self.table[key] = [st.st_size, st.st_mtime_ns, digest]
        self.dirty = True
        return digest

    def save(self) -> None:
        if self.dirty:
            write_json(self.path, self.table)
            self.dirty = False
