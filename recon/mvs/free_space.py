"""Free-space test of fused points: a point that more views see through than agree with is dropped.

An object standing in some photos only (a car parked for a while, a passer-by) is matched consistently
by the views that show it, so fusion keeps it, and the mesh and texture then show it from every side.
The views without it see the surface behind it: the fused point lies in the free space in front of
their depth maps. That conflict between the depth maps is the evidence visibility-based fusion uses
(Merrell et al. 2007, "Real-time visibility-based fusion of depth maps": free-space violations;
OpenMVS's Delaunay graph cut weighs the same rays). Counting it per point after COLMAP's fusion keeps
fusion itself COLMAP's.

A view *sees through* a point when the point projects into its depth map in front of the camera and
every pixel of the 3x3 neighbourhood it falls in holds a depth beyond the point's by more than
``margin`` (relative): the whole neighbourhood, so that a point on a thin pole or at an object's edge,
half a pixel off in some view, is not condemned by the background beside it. A view *agrees* when its
depth at that pixel is within ``agree`` (relative) of the point's. A pixel without a depth (sky,
masked, untextured) counts for neither; a view that sees a nearer surface there (the point is hidden
from it) counts for neither.

The mesh stage applies the same test to its faces' centres (``mesh.free_space``,
:mod:`recon.surface.seen_through`): Poisson extends and closes the surface where the fused points stop,
and the depth maps tell where the views saw nothing there.

On the zoo's transient_car (a car in 8 of 24 photos) this drops the car, 9 % of the points, and fused
accuracy at 0.2 % of the extent rises from 90.7 % to 99.7 %; on the other 14 scenes it drops 0.01-0.3 %
of the points and lowers no F-score (docs/DECISIONS.md).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable

import numpy as np
from numba import njit, prange

from recon.mvs.views import ViewCamera

log = logging.getLogger(__name__)

#: relative depth difference within which a view agrees with a point (fusion's max_depth_error)
AGREE = 0.01
#: relative depth beyond the point at which a view's surface shows it sees through the point
MARGIN = 0.03


@njit(cache=True, parallel=True)
def _count_view(points, R, t, K, depth, agree, margin, agreeing, seeing_through):  # pragma: no cover - numba
    h, w = depth.shape
    for i in prange(points.shape[0]):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        x = R[0, 0] * px + R[0, 1] * py + R[0, 2] * pz + t[0]
        y = R[1, 0] * px + R[1, 1] * py + R[1, 2] * pz + t[1]
        z = R[2, 0] * px + R[2, 1] * py + R[2, 2] * pz + t[2]
        if z <= 0.0:
            continue
        col = int(math.floor((K[0, 0] * x + K[0, 1] * y) / z + K[0, 2]))
        row = int(math.floor(K[1, 1] * y / z + K[1, 2]))
        if col < 0 or row < 0 or col >= w or row >= h:
            continue
        d = depth[row, col]
        if d > 0.0 and abs(d - z) <= agree * z:
            agreeing[i] += 1
            continue
        if col < 1 or row < 1 or col >= w - 1 or row >= h - 1:
            continue
        nearest = math.inf
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                nearest = min(nearest, depth[row + dy, col + dx])  # 0 (no depth) anywhere: not seen through
        if nearest > z * (1.0 + margin):
            seeing_through[i] += 1


def _count(points: np.ndarray, cam: ViewCamera, depth: np.ndarray, agree: float, margin: float,
           agreeing: np.ndarray, seeing_through: np.ndarray) -> None:
    h, w = depth.shape
    K = np.diag([w / cam.width, h / cam.height, 1.0]) @ cam.K
    _count_view(points, np.ascontiguousarray(cam.R), np.ascontiguousarray(cam.t), K,
                np.ascontiguousarray(depth, dtype=np.float32), agree, margin, agreeing, seeing_through)


def free_space_counts(points: np.ndarray, views: Iterable[tuple[ViewCamera, np.ndarray]],
                      agree: float, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """For ``points`` (N, 3): how many of ``views`` (camera, its depth map; the camera at any resolution)
    agree with each point, and how many see through it."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    agreeing = np.zeros(len(points), np.int32)
    seeing_through = np.zeros(len(points), np.int32)
    for cam, depth in views:
        _count(points, cam, depth, agree, margin, agreeing, seeing_through)
    return agreeing, seeing_through


def agreeing_points(points: np.ndarray, cam: ViewCamera, depth: np.ndarray, agree: float) -> np.ndarray:
    """Per point of ``points`` (N, 3): whether ``cam``'s depth map (at any resolution) agrees with it."""
    agreeing = np.zeros(len(points), np.int32)
    _count(np.ascontiguousarray(points, dtype=np.float64), cam, depth, agree, math.inf, agreeing,
           np.zeros(len(points), np.int32))
    return agreeing > 0


def in_free_space(points: np.ndarray, views: Iterable[tuple[ViewCamera, np.ndarray]],
                  agree: float, margin: float) -> np.ndarray:
    """True for the points that more views see through than agree with."""
    agreeing, seeing_through = free_space_counts(points, views, agree, margin)
    return seeing_through > agreeing
