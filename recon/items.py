"""A content-addressed store of per-item results: one photo's features, one pair's verified matches.

A stage's cache key covers its whole input, so a photo added to the folder changes every key and
every stage runs again. Most of the work is per item, and an item's result depends on far less
than the whole set: a photo's features on its pixels, its mask and the extraction options; a pair's
matches on the two photos' features, their cameras and the matching options. The store keeps each
such result as one file named by the SHA-256 of canonical JSON of what determines it
(:func:`item_key`), in ``.recon/items/<kind>/`` beside the stage cache, so a run with any other
stage key finds and reuses it; anything that changes the item changes its key, and it is computed
again (docs/ARCHITECTURE.md, "The cache").

Items are data, never code: they are read with NumPy's ``allow_pickle=False`` by their stages.
Each item has a record (``<key>.json``: size and SHA-256 of its content, written after the item)
and is handed out only while its content matches it, so a damaged item, or one changed through a
hard link from a stage output, is computed again rather than reused. The record may also hold the
item's ``meta``: what determined it that is not exact enough to hash (a depth map's cameras, which
every bundle adjustment moves a little), for the stage to compare within a tolerance.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from recon.files import atomic, file_digest, read_json


def item_key(material: Any) -> str:
    """The key of an item: SHA-256 of canonical JSON of what determines it (the stage cache's form)."""
    return hashlib.sha256(json.dumps(material, sort_keys=True, default=str).encode()).hexdigest()


class ItemStore:
    """The items of one kind: ``<folder>/<key><suffix>`` and their records ``<folder>/<key>.json``."""

    def __init__(self, folder: Path | str, suffix: str):
        self.folder = Path(folder)
        self.suffix = suffix

    def path(self, key: str) -> Path:
        return self.folder / f"{key}{self.suffix}"

    def _record(self, key: str) -> Path:
        return self.folder / f"{key}.json"

    def get(self, key: str) -> Path | None:
        """The item's file, or None when the store has no whole, unchanged item under ``key``."""
        path, record = self.path(key), read_json(self._record(key))
        if not isinstance(record, dict):
            return None
        try:
            if path.stat().st_size != record.get("size"):
                return None
        except OSError:
            return None
        return path if file_digest(path) == record.get("sha256") else None

    def meta(self, key: str) -> dict | None:
        """The ``meta`` recorded with the item ``key`` (None when none or no such record)."""
        record = read_json(self._record(key))
        return record.get("meta") if isinstance(record, dict) else None

    def link(self, key: str, dest: Path) -> bool:
        """Hard-link the item to ``dest`` (a stage's output file; copied where the file system refuses
        hard links). False, and nothing written, when the store has no such item."""
        path = self.get(key)
        if path is None:
            return False
        with atomic(dest) as tmp:
            _link_or_copy(path, tmp)
        return True

    def put(self, key: str, source: Path, meta: dict | None = None) -> Path:
        """Add a finished file as the item ``key`` (hard-linked, or copied), replacing any item there."""
        return self.write(key, lambda tmp: _link_or_copy(source, tmp), meta)

    def write(self, key: str, writer: Callable[[Path], None], meta: dict | None = None) -> Path:
        """Add the item ``key`` that ``writer(path)`` writes; atomically, then its record (with ``meta``)."""
        path = self.path(key)
        with atomic(path) as tmp:
            writer(tmp)
        record = {"size": path.stat().st_size, "sha256": file_digest(path), **({"meta": meta} if meta else {})}
        with atomic(self._record(key)) as tmp:  # not flushed to disk: a record torn by a crash fails the check
            tmp.write_text(json.dumps(record))
        return path


def _link_or_copy(source: Path, dest: Path) -> None:
    """Make ``dest`` (which may exist: a temporary name) the same file as ``source``: a hard link,
    never a symbolic one (stage outputs are verified by content), or a copy."""
    with contextlib.suppress(FileNotFoundError):
        dest.unlink()
    try:
        os.link(source, dest)
    except OSError:  # another file system, or one without hard links
        shutil.copyfile(source, dest)
