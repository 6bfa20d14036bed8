"""The fused point cloud as COLMAP writes it: a binary PLY of points with normals and colours
(``fused.ply``), and its visibility record (``fused.ply.vis``: for each point, the indices of the images
that saw it, which COLMAP's Delaunay mesher reads)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4"),
                    ("red", "u1"), ("green", "u1"), ("blue", "u1")])


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


def write_cloud(ply: Path, xyz: np.ndarray, normals: np.ndarray, colours: np.ndarray) -> None:
    """Write points (N, 3), unit normals (N, 3) and RGB colours (N, 3, uint8) as COLMAP's fused.ply."""
    vertices = np.empty(len(xyz), _VERTEX)
    for axis, name in enumerate("xyz"):
        vertices[name] = xyz[:, axis]
        vertices["n" + name] = normals[:, axis]
    for channel, name in enumerate(("red", "green", "blue")):
        vertices[name] = colours[:, channel]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(xyz)}"]
    header += [f"property {'uchar' if _VERTEX[name].kind == 'u' else 'float'} {name}" for name in _VERTEX.names]
    ply.write_bytes(("\n".join(header + ["end_header"]) + "\n").encode("ascii") + vertices.tobytes())


def write_visibility(vis: Path, view_counts: np.ndarray, views: np.ndarray) -> None:
    """Write COLMAP's fused.ply.vis: the point count (uint64), then per point its view count and that many
    image indices (uint32); ``views`` holds the indices point after point."""
    count = len(view_counts)
    records = np.empty(count + len(views), "<u4")
    starts = np.arange(count) + np.concatenate([[0], np.cumsum(view_counts)[:-1]]).astype(np.int64)
    records[starts] = view_counts
    is_view = np.ones(len(records), bool)
    is_view[starts] = False
    records[is_view] = views
    vis.write_bytes(np.array([count & 0xFFFFFFFF, count >> 32], "<u4").tobytes() + records.tobytes())
