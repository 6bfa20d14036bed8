"""Read and write COLMAP dense depth and normal maps (``stereo/{depth,normal}_maps/*.bin``).

The format is an ASCII header ``W&H&C&`` followed by little-endian float32 values stored channel by
channel: COLMAP's ``mvs::Mat<float>`` reads the bytes into ``data`` and reads a value as
``data[c * H * W + row * W + col]``. A depth map (C = 1) is plain row-major H x W; a normal map
(C = 3) is three H x W planes, turned here into the H x W x 3 arrays recon uses. Depth is camera z
(0 = no depth); normals are unit vectors in the camera frame, facing the camera (0 = no normal).

pycolmap 4.2.1's ``NormalMap.from_array`` / ``to_array`` copy an H x W x 3 array's bytes as they are
(pixel-interleaved), so a normal map written by ``NormalMap.from_array(n).write`` is misread by
COLMAP's own stereo fusion (the tests show it); this module writes the layout the C++ code reads.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from recon.files import atomic


def _header(data: bytes) -> tuple[int, int, int, int]:
    """Width, height, channels and where the values start, from the bytes of a map (ValueError where
    they hold no header)."""
    fields, pos = [], 0
    for _ in range(3):
        end = data.index(b"&", pos)
        fields.append(int(data[pos:end]))
        pos = end + 1
    return fields[0], fields[1], fields[2], pos


def map_size(path: str | os.PathLike) -> tuple[int, int]:
    """Width and height of a COLMAP ``.bin`` map, from its header alone."""
    with open(path, "rb") as f:
        width, height, _, _ = _header(f.read(64))
    return width, height


def read_map(path: str | os.PathLike) -> np.ndarray:
    """A COLMAP ``.bin`` map as float32: H x W when it has one channel, else H x W x C."""
    data = Path(path).read_bytes()
    width, height, channels, pos = _header(data)
    values = np.frombuffer(data, dtype="<f4", count=width * height * channels, offset=pos)
    planes = values.reshape(channels, height, width).astype(np.float32)
    return planes[0] if channels == 1 else np.ascontiguousarray(planes.transpose(1, 2, 0))


def write_map(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Write an H x W (depth) or H x W x C (normal) array in COLMAP's format, atomically."""
    array = np.asarray(array, dtype=np.float32)
    if array.ndim == 2:
        array = array[:, :, None]
    if array.ndim != 3:
        raise ValueError(f"expected an H x W or H x W x C array, got shape {array.shape}")
    height, width, channels = array.shape
    header = f"{width}&{height}&{channels}&".encode("ascii")
    payload = np.ascontiguousarray(array.transpose(2, 0, 1), dtype="<f4").tobytes()
    with atomic(path) as tmp:  # no fsync: a kill leaves the old file or none, and maps are many
        tmp.write_bytes(header + payload)
    return Path(path)


def read_depth_map(path: str | os.PathLike) -> np.ndarray:
    """An H x W float32 depth map (camera z; 0 where there is none)."""
    depth = read_map(path)
    if depth.ndim != 2:
        raise ValueError(f"{path}: expected one channel, got {depth.shape[2]}")
    return depth


def read_normal_map(path: str | os.PathLike) -> np.ndarray:
    """An H x W x 3 float32 normal map (camera frame, facing the camera)."""
    normals = read_map(path)
    if normals.ndim != 3 or normals.shape[2] != 3:
        raise ValueError(f"{path}: expected three channels, got shape {normals.shape}")
    return normals
