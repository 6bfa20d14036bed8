"""The workspace: owns every path on disk, atomic writes, the run lock and the stage cache.

Layout (docs/ARCHITECTURE.md, "The workspace")::

    <workspace>/
      database.db, sparse/0/, points.ply, transforms.json, dense/, ...   user-facing, COLMAP-readable
      .recon/
        lock                      held (flock) by the running `recon run`; holds its pid
        state.json                the key each stage last completed with
        hashes.json               content hashes of input files, keyed by (path, inode, size, mtime, ctime)
        recon.log                 the full log of every run
        cache/<stage>/<key>/      a completed stage output, with manifest.json
        cache/<stage>/<key>.partial/   an output being written (kept across kills: per-item resume)
        items/<kind>/<key>.*      per-item results reused across stage keys (recon.items)

User-facing paths are relative symbolic links into the cache, so a file the user opens is always
the output of the stage's current key, and COLMAP, MeshLab or Blender read them in place.

Whose files are whose (docs/ARCHITECTURE.md, "The workspace"): recon's own paths are `.recon/` and
the links it published, which all point into `.recon/cache/`; a link into our own cache is made by
no one else, so that is the test (:meth:`Workspace.owns`). Anything else in the workspace is the
user's and is never replaced or deleted: :meth:`Workspace.clashes` finds it before any work starts.

A completed output's manifest records the size, mtime and SHA-256 of each of its files
(:func:`file_table`); :meth:`Workspace.verify` checks them before the output is reused, so a
truncated database or a deleted model file makes the stage stale instead of feeding later stages.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import stat
from pathlib import Path

from recon.files import file_digest, read_json, write_json

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

    def items_dir(self, kind: str) -> Path:
        """The folder of the per-item results of ``kind`` (:mod:`recon.items`), shared by every key."""
        return self.meta / "items" / kind

    def is_complete(self, stage: str, key: str) -> bool:
        return (self.output_dir(stage, key) / MANIFEST).is_file()

    def verify(self, stage: str, key: str, full: bool = False) -> str | None:
        """Why the complete output of ``stage`` cannot be reused (a file deleted or changed since it was
        written), or None when it can. Sizes are always checked; contents where cheap (small files),
        where the modification time moved, or everywhere with ``full``."""
        manifest = self.manifest(stage, key)
        if manifest is None:
            return "output missing"
        return verify_files(self.output_dir(stage, key), manifest.get("files"), full)

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
        """Record the output's files in the manifest, write it, and atomically move the output into place."""
        partial = self.partial_dir(stage, key)
        write_json(partial / MANIFEST, {**manifest, "files": file_table(partial)})
        final = self.output_dir(stage, key)
        if final.exists():  # a --force re-run replaces the previous complete output
            trash = final.with_name(final.name + f".old-{os.getpid()}")
            os.rename(final, trash)
            shutil.rmtree(trash, ignore_errors=True)
        os.rename(partial, final)
        _fsync_dir(final.parent)
        return final

    # -- state ------------------------------------------------------------------------------
    def save_config(self, base: str, config: dict) -> None:
        """The run's resolved config (and the folder its relative paths are from), which `recon status
        WS` and `recon clean WS` read back; written once the run's inputs are known to be there."""
        write_json(self.meta / "config.json", {"base": base, "config": config})

    def saved_config(self) -> tuple[str, dict] | None:
        """(base, config) of the last run that started, or None."""
        data = read_json(self.meta / "config.json")
        return (data["base"], data["config"]) if data else None

    def state(self) -> dict[str, str]:
        return read_json(self.meta / "state.json") or {}

    def set_state(self, stage: str, key: str) -> None:
        state = self.state()
        state[stage] = key
        write_json(self.meta / "state.json", state)

    # -- user-facing links ---------------------------------------------------------------
    def owns(self, path: Path) -> bool:
        """Whether recon made ``path``: a link into this workspace's cache, or anything in ``.recon/``."""
        path = Path(path)
        if _is_under(path, self.meta):
            return True
        try:
            target = os.readlink(path)
        except OSError:  # absent, or not a link
            return False
        return _is_under(Path(os.path.normpath(path.parent / target)), self.meta / "cache")

    def clashes(self, links: list[str], keep: list[Path]) -> tuple[list[Path], list[Path]]:
        """Of the workspace paths ``links`` that outputs would be published at: those holding something
        recon did not make (never to be replaced), and those that are, or hold, one of the folders
        ``keep`` (the photo folder: its link is not needed, the photos are there)."""
        clash, kept = [], []
        real_keep = [Path(os.path.realpath(k)) for k in keep]
        for link in dict.fromkeys(links):
            dest = self.root / link
            real = Path(os.path.realpath(dest))
            if any(k == real or _is_under(k, real) for k in real_keep):
                kept.append(dest)
                continue
            folders = [self.root / p for p in reversed(Path(link).parents) if p != Path(".")]
            blocker = next((p for p in folders if os.path.lexists(p) and not p.is_dir()), None)
            if blocker is None and os.path.lexists(dest) and not self.owns(dest):
                blocker = dest
            if blocker is not None:
                clash.append(blocker)
        return clash, kept

    def publish(self, target: Path, link: str) -> None:
        """Point ``<workspace>/<link>`` at ``target`` with a relative symlink (atomic replace). Only a link
        recon made is ever replaced; a path of the user's there raises WorkspaceError (the pipeline
        checks :meth:`clashes` before any work, so this is the last guard, not the message users see)."""
        dest = self.root / link
        if os.path.lexists(dest) and not self.owns(dest):
            raise WorkspaceError(f"{dest}: exists and recon did not make it; recon never replaces it: "
                                 "move it away or choose another --workspace")
        dest.parent.mkdir(parents=True, exist_ok=True)
        rel = os.path.relpath(target, dest.parent)
        tmp = dest.with_name(f".{dest.name}.link-{os.getpid()}")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        os.symlink(rel, tmp)
        os.replace(tmp, dest)

    def unpublish(self, link: str) -> None:
        """Remove the link ``<workspace>/<link>`` if recon made it; anything else there is left alone."""
        dest = self.root / link
        if dest.is_symlink() and self.owns(dest):
            dest.unlink()


def _is_under(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or inside it (lexically: links are not followed)."""
    return Path(os.path.abspath(path)).is_relative_to(os.path.abspath(folder))


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


#: files up to this size are hashed whenever a cached output is checked; larger ones when their
#: modification time moved (or with --verify)
SMALL_FILE = 1 << 20


def file_table(folder: Path) -> dict[str, list]:
    """Every file under ``folder`` (but the manifest): ``[size, mtime_ns, sha256]`` for a regular
    file, ``["link", target]`` for a symbolic link (never followed: ingest links the user's photos)."""
    table: dict[str, list] = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if rel == MANIFEST:
            continue
        st = path.lstat()
        if stat.S_ISLNK(st.st_mode):
            table[rel] = ["link", os.readlink(path)]
        elif stat.S_ISREG(st.st_mode):
            table[rel] = [st.st_size, st.st_mtime_ns, file_digest(path)]
    return table


def verify_files(folder: Path, table: dict[str, list] | None, full: bool = False) -> str | None:
    """The first way the files under ``folder`` differ from ``table`` (:func:`file_table`), or None."""
    if table is None:  # written before outputs recorded their files: nothing to check against
        return None
    for rel, entry in table.items():
        path = folder / rel
        try:
            st = path.lstat()
        except OSError:
            return f"{rel} was deleted since it was written"
        if entry[0] == "link":
            if not stat.S_ISLNK(st.st_mode) or os.readlink(path) != entry[1]:
                return f"{rel} changed since it was written"
            continue
        size, mtime_ns, digest = entry
        if not stat.S_ISREG(st.st_mode) or st.st_size != size:
            return f"{rel} changed since it was written (size {size} -> {st.st_size} bytes)"
        if (full or size <= SMALL_FILE or st.st_mtime_ns != mtime_ns) and file_digest(path) != digest:
            return f"{rel} changed since it was written (content)"
    return None


class HashCache:
    """Content hashes of input files. A hash is remembered under the file's (inode, size, mtime_ns,
    ctime_ns): writing a file (even restoring its mtime afterwards) moves its ctime, and replacing
    it changes its inode, so a photo swapped for another of the same size and mtime is re-read."""

    def __init__(self, workspace: Workspace):
        self.path = workspace.meta / "hashes.json"
        self.table: dict[str, list] = read_json(self.path) or {}
        self.dirty = False

    def digest(self, path: Path) -> str:
        st = path.stat()
        key = str(path.absolute())
        stamp = [st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns]
        cached = self.table.get(key)
        if cached and cached[:-1] == stamp:
            return cached[-1]
        digest = file_digest(path)
        self.table[key] = [*stamp, digest]
        self.dirty = True
        return digest

    def save(self) -> None:
        if self.dirty:
            write_json(self.path, self.table)
            self.dirty = False
