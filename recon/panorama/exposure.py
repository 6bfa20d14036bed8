"""Exposure compensation: one gain per photo (or per photo and channel) that makes overlaps agree.

The model is OpenCV's ``GainCompensator`` (Brown and Lowe 2007): minimise over gains g

    sum over overlapping pairs (i, j) of N_ij [ (g_i I_ij - g_j I_ji)^2 / sigma_n^2
                                              + ((1 - g_i)^2 + (1 - g_j)^2) / sigma_g^2 ]

with N_ij the overlap's pixel count and I_ij photo i's mean intensity there. It is solved here
rather than by OpenCV because OpenCV sees the warped photos on a plane: in a 360 deg panorama the
overlap between the last photo and the first one (across the wrap) is invisible to it, so gains
could drift around the ring and step at the wrap. The composer lays the wrapping photos out twice
(see compose.py); this solver takes each physical overlap once and ties a photo's copies to one gain.

Two departures from OpenCV's constants and data, both measured on the synthetic 360 deg set (view
gains 0.85-1.15): OpenCV's sigma_n = 10, sigma_g = 0.1 pull the gains so hard towards 1 that the
residual spread of gain x true exposure was 0.88-1.09, and overlaps on dark content (a starfield at
~20 grey levels) barely tied their photos; with sigma_n = sigma_g = 1 the prior only fixes the
overall level and the spread fell to 0.981-0.988. Pixels at or near 255 in either photo are left out
of the means, since clipping hides their exposure.
"""

from __future__ import annotations

import numpy as np

SIGMA_N = 1.0  # intensity noise, grey levels
SATURATED = 250.0  # pixels this bright in either photo are left out: clipping hides their exposure
SIGMA_G = 1.0  # prior spread of the gains around 1: weak, it only fixes the overall level


def solve_gains(images: list[np.ndarray], masks: list[np.ndarray], corners: list[tuple[int, int]],
                owners: list[int], count: int, per_channel: bool, max_column: int | None = None) -> np.ndarray:
    """Gains (count, 3) for photos laid out as ``images`` (HxWx3 float32, 0-255) with ``masks`` (HxW
    bool) at ``corners`` (x, y); ``owners[k]`` is the photo that layout item k shows (a photo may
    appear more than once). Overlaps are counted only left of ``max_column``, so that a periodic
    layout counts each overlap once."""
    channels = 3 if per_channel else 1
    N = np.zeros((count, count))
    I = np.zeros((count, count, channels))  # noqa: E741  I[i, j]: mean of photo i over its overlap with j
    for a in range(len(images)):
        for b in range(a + 1, len(images)):
            i, j = owners[a], owners[b]
            if i == j:
                continue
            (xa, ya), (xb, yb) = corners[a], corners[b]
            ha, wa = masks[a].shape
            hb, wb = masks[b].shape
            x0, y0 = max(xa, xb), max(ya, yb)
            x1, y1 = min(xa + wa, xb + wb), min(ya + ha, yb + hb)
            if max_column is not None:
                x1 = min(x1, max_column)
            if x1 <= x0 or y1 <= y0:
                continue
            pa = images[a][y0 - ya:y1 - ya, x0 - xa:x1 - xa]
            pb = images[b][y0 - yb:y1 - yb, x0 - xb:x1 - xb]
            both = masks[a][y0 - ya:y1 - ya, x0 - xa:x1 - xa] & masks[b][y0 - yb:y1 - yb, x0 - xb:x1 - xb]
            both &= (pa.max(axis=2) < SATURATED) & (pb.max(axis=2) < SATURATED)
            n = int(both.sum())
            if n == 0:
                continue
            pa, pb = pa[both], pb[both]
            if not per_channel:
                pa, pb = pa.mean(axis=1, keepdims=True), pb.mean(axis=1, keepdims=True)
            # pool overlaps of the same two photos (a photo's copies): pixel-weighted means
            for p, q, values in ((i, j, pa), (j, i, pb)):
                I[p, q] = (I[p, q] * N[p, q] + values.sum(axis=0)) / (N[p, q] + n)
            N[i, j] += n
            N[j, i] += n
    gains = np.ones((count, 3))
    for c in range(channels):
        A = np.zeros((count, count))
        b = np.zeros(count)
        for i in range(count):
            for j in range(count):
                if N[i, j] == 0:
                    continue
                A[i, i] += N[i, j] * (I[i, j, c] ** 2 / SIGMA_N**2 + 1.0 / SIGMA_G**2)
                A[i, j] -= N[i, j] * I[i, j, c] * I[j, i, c] / SIGMA_N**2
                b[i] += N[i, j] / SIGMA_G**2
        solvable = np.diag(A) > 0  # a photo with no overlap keeps gain 1
        g = np.ones(count)
        g[solvable] = np.linalg.solve(A[np.ix_(solvable, solvable)], b[solvable])
        if per_channel:
            gains[:, c] = g
        else:
            gains[:] = g[:, None]
    return gains
