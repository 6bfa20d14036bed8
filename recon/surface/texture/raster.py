"""Triangle rasterisation into texel grids (pixel centres at +0.5, as in COLMAP); bilinear lookups are
:func:`recon.imaging.pixels.sample_bilinear`."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _rasterize(tri, ids, face_map, bary):
    h, w = face_map.shape
    for k in range(tri.shape[0]):
        x0, y0 = tri[k, 0, 0], tri[k, 0, 1]
        x1, y1 = tri[k, 1, 0], tri[k, 1, 1]
        x2, y2 = tri[k, 2, 0], tri[k, 2, 1]
        den = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
        if abs(den) < 1e-12:
            continue
        xa = max(int(np.floor(min(x0, x1, x2) - 0.5)), 0)
        xb = min(int(np.ceil(max(x0, x1, x2) - 0.5)), w - 1)
        ya = max(int(np.floor(min(y0, y1, y2) - 0.5)), 0)
        yb = min(int(np.ceil(max(y0, y1, y2) - 0.5)), h - 1)
        for y in range(ya, yb + 1):
            py = y + 0.5
            for x in range(xa, xb + 1):
                px = x + 0.5
                b0 = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / den
                b1 = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / den
                b2 = 1.0 - b0 - b1
                if b0 >= -1e-6 and b1 >= -1e-6 and b2 >= -1e-6:
                    face_map[y, x] = ids[k]
                    bary[y, x, 0] = b0
                    bary[y, x, 1] = b1
                    bary[y, x, 2] = b2


def rasterize(tri: np.ndarray, ids: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Texels whose centre lies in a triangle: ``tri`` (N, 3, 2) corner positions in texel coordinates,
    ``ids`` (N,) written to a face map (H, W; -1 where empty) with barycentrics (H, W, 3)."""
    face_map = np.full((height, width), -1, np.int64)
    bary = np.zeros((height, width, 3), np.float32)
    if len(tri):
        _rasterize(np.ascontiguousarray(tri, np.float64), np.ascontiguousarray(ids, np.int64), face_map, bary)
    return face_map, bary
