"""COLMAP's fused point cloud as files: the binary PLY (``fused.ply``) and its visibility record
(``fused.ply.vis``: for each point, the indices of the images that saw it), read and filtered in place
of each other so that the two stay aligned point for point."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "<i2", "ushort": "<u2", "int": "<i4", "uint": "<u4",
              "float": "<f4", "double": "<f8"}


def vertex_count(ply: Path) -> int:
    """The vertex count a PLY file's header declares (0 for a missing or empty file)."""
    try:
        with open(ply, "rb") as f:
            for line in f:
                if line.startswith(b"element vertex"):
                    return int(line.split()[2])
                if line.strip() == b"end_header":
                    break
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _read(ply: Path) -> tuple[list[bytes], np.ndarray]:
    """Header lines and vertices of a binary little-endian PLY holding vertices only (as COLMAP writes)."""
    data = ply.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].splitlines(keepends=True)
    fields = [(line.split()[2].decode(), _PLY_TYPES[line.split()[1].decode()])
              for line in header if line.startswith(b"property ")]
    if not any(line.startswith(b"format binary_little_endian") for line in header):
        raise ValueError(f"{ply}: not a binary little-endian PLY")
    count = next(int(line.split()[2]) for line in header if line.startswith(b"element vertex"))
    return header, np.frombuffer(data, dtype=np.dtype(fields), count=count, offset=end)


def read_points(ply: Path) -> np.ndarray:
    """The (N, 3) float64 vertex positions of a fused cloud."""
    vertices = _read(ply)[1]
    return np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=1).astype(np.float64)


def keep_points(ply: Path, keep: np.ndarray) -> None:
    """Rewrite the fused cloud ``ply`` with only the vertices where ``keep`` is True."""
    header, vertices = _read(ply)
    header = [b"element vertex %d\n" % int(keep.sum()) if line.startswith(b"element vertex") else line
              for line in header]
    ply.write_bytes(b"".join(header) + vertices[keep].tobytes())


def keep_visibility(vis: Path, keep: np.ndarray) -> None:
    """Rewrite COLMAP's ``fused.ply.vis`` (uint64 count, then per point a uint32 count and that many
    uint32 image indices) with only the points where ``keep`` is True."""
    words = np.frombuffer(vis.read_bytes(), dtype="<u4")
    count = int(words[0]) | (int(words[1]) << 32)
    if count != len(keep):
        raise ValueError(f"{vis}: {count} points, the cloud has {len(keep)}")
    lengths = np.diff(_record_starts(words, count))
    records = words[2:2 + int(lengths.sum())][np.repeat(np.asarray(keep, bool), lengths)]
    kept = int(np.count_nonzero(keep))
    vis.write_bytes(np.concatenate([np.array([kept & 0xFFFFFFFF, kept >> 32], "<u4"), records]).tobytes())


@njit(cache=True)
def _record_starts(words, count):  # pragma: no cover - numba
    """Where each point's record (its view count, then its views) starts in ``words``, and where the
    last one ends: each start depends on the previous count, a walk numpy cannot vectorise."""
    starts = np.empty(count + 1, np.int64)
    at = 2
    for index in range(count):
        starts[index] = at
        at += 1 + words[at]
    starts[count] = at
    return starts
