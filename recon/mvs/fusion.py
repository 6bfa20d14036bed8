"""Fusion of the final depth maps into one point cloud: COLMAP's algorithm, with the merge radius set apart
from the agreement test.

COLMAP's stereo fusion (``pycolmap.stereo_fusion``, Schönberger et al. 2016) takes the views in turn; each
pixel not yet used seeds a point, and the pixel the seed projects to in each overlapping view joins the
point when that view's depth, normal and pixel agree with the seed's within the tolerances. The point is the
median of what joined, and every pixel that joined is used up. So one number, the reprojection error,
sets both how strictly views must agree and how much of each view one point uses up, which is how far
apart the cloud's points lie. Below a pixel, a stricter test loses far and grazing surface (a view's pixel
no longer finds its partner); above it, the cloud is as sparse as the threshold users judge it at.
Measured on the zoo at 640x480 (docs/DECISIONS.md): COLMAP at 0.35 px lifts turntable_black and sinks
far_field. Here a pixel that agrees within ``reproj_px`` joins the point, and it is used up only within
``merge_px``; the others seed points of their own later.

Two more differences, both measured:

* Depth at pixel (col, row) lies along the ray through (col + 0.5, row + 0.5), recon's and COLMAP's
  sparse convention, which COLMAP's fusion reads through (col, row), half a pixel aside. Read at the
  centre, far_field's fused F@0.2 % rose .928 -> .932 and turntable_black's .923 -> .950.
* A point gathers the pixels its seed projects to (COLMAP's ``max_traversal_depth`` 2; COLMAP goes on
  from each joined pixel up to 100 steps, re-testing what it finds against the seed). On three zoo scenes
  the clouds were as good or better (F@0.2 % +.0002 to +.0010) and fusion 3.5 times faster.

With ``merge_px == reproj_px`` and ``pixel_centre`` 0 it is COLMAP's fusion at traversal depth 2:
``tests/mvs/test_fusion.py`` compares it with ``pycolmap.stereo_fusion``. Like COLMAP's, it holds every
view's maps at once: ``BYTES_PER_PIXEL`` (20) a working pixel (200 views at 1536x1152: 7 GB); a run that
would need more than the machine has free stops with a line saying so.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pycolmap
import scipy.sparse
from numba import njit

from recon.mvs.colmap_io import map_size, read_depth_map, read_normal_map
from recon.mvs.views import ViewCamera, observations, scaled_to, view_camera

log = logging.getLogger(__name__)

#: views that share the most sparse points with a view are the ones its points look for partners in
#: (COLMAP's ``check_num_images``)
OVERLAPPING_VIEWS = 50
#: what fusion holds per pixel of every view's maps at once: depth (4 bytes), normal (12), colour (3) and
#: whether the pixel is used up (1)
BYTES_PER_PIXEL = 20


class Tolerances(NamedTuple):
    """How closely a view's pixel must agree with a point's seed to join it, and within what
    reprojection error it is then used up (``merge_px`` <= ``reproj_px``)."""

    reproj_px: float
    merge_px: float
    depth: float  # relative
    normal_degrees: float


@dataclass(frozen=True)
class FusionViews:
    """The views' final maps at their working resolution, padded to the largest, in the model's order."""

    cameras: list[ViewCamera]  # at the depth maps' resolution
    depth: np.ndarray  # (n, H, W) float32, 0 where there is none
    normal: np.ndarray  # (n, H, W, 3) float32, camera frame
    colour: np.ndarray  # (n, H, W, 3) uint8 RGB at each depth pixel's centre
    overlap: np.ndarray  # (n, m) int32: for each view, the others by shared sparse points, -1 after the last
    model_indices: np.ndarray  # (n,) each view's index among the model's registered images (COLMAP's)

    def depth_maps(self):
        """(camera, its depth map) for each view."""
        return [(cam, self.depth[i, :cam.height, :cam.width]) for i, cam in enumerate(self.cameras)]


class FusedPoints(NamedTuple):
    """A fused cloud with, for each point, the views its pixels came from."""

    xyz: np.ndarray  # (N, 3) float32
    normals: np.ndarray  # (N, 3) float32, unit
    colours: np.ndarray  # (N, 3) uint8
    view_counts: np.ndarray  # (N,) int32: how many views each point's pixels came from
    views: np.ndarray  # the views' indices, point after point (FusionViews order)

    def subset(self, keep: np.ndarray) -> FusedPoints:
        """The points where ``keep`` (N,) is True."""
        return FusedPoints(self.xyz[keep], self.normals[keep], self.colours[keep], self.view_counts[keep],
                           self.views[np.repeat(keep, self.view_counts)])


def read_views(images: Path, model: Path, stereo: Path) -> FusionViews:
    """The registered views of the undistorted ``model`` that have final depth and normal maps in
    ``stereo`` (COLMAP's layout), with their colours from ``images``. ValueError, naming what to do, where
    a map is damaged or the maps do not fit in the memory this machine has free."""
    rec = pycolmap.Reconstruction(str(model))
    found = []  # (index among the registered images, image, depth map, normal map, map size)
    for index, image_id in enumerate(rec.reg_image_ids()):
        image = rec.image(image_id)
        depth_path = stereo / "depth_maps" / f"{image.name}.geometric.bin"
        normal_path = stereo / "normal_maps" / f"{image.name}.geometric.bin"
        if not (depth_path.exists() and normal_path.exists()):
            log.warning("fusion: %s has no final depth and normal maps; left out", image.name)
            continue
        found.append((index, image, depth_path, normal_path, _size(depth_path, image.name)))
    _check_memory([size for *_, size in found])
    ids, indices, cameras, depths, normals = [], [], [], [], []
    for index, image, depth_path, normal_path, _ in found:
        try:
            depth, normal = read_depth_map(depth_path), read_normal_map(normal_path)
        except ValueError as exc:
            raise _damaged(image.name, exc) from exc
        ids.append(image.image_id)
        indices.append(index)
        depths.append(depth)
        normals.append(normal)
        cameras.append(scaled_to(view_camera(image, rec.camera(image.camera_id)), depth.shape[1], depth.shape[0]))
    n = len(cameras)
    height = max((d.shape[0] for d in depths), default=0)
    width = max((d.shape[1] for d in depths), default=0)
    depth = np.zeros((n, height, width), np.float32)
    normal = np.zeros((n, height, width, 3), np.float32)
    colour = np.zeros((n, height, width, 3), np.uint8)
    for i, cam in enumerate(cameras):  # (np.zeros takes memory as it is written: freeing as we go holds one copy)
        depth[i, :cam.height, :cam.width], depths[i] = depths[i], None
        normal[i, :cam.height, :cam.width], normals[i] = normals[i], None
        colour[i, :cam.height, :cam.width] = _colours_at_pixels(images / cam.name, cam.width, cam.height)
    return FusionViews(cameras, depth, normal, colour, _overlap(rec, ids), np.array(indices, np.int32))


def _damaged(name: str, exc: Exception) -> ValueError:
    return ValueError(f"fusion: cannot read the final depth or normal map of {name} ({exc}); run again with "
                      "--force mvs")


def _size(path: Path, name: str) -> tuple[int, int]:
    try:
        return map_size(path)
    except (ValueError, OSError) as exc:
        raise _damaged(name, exc) from exc


def _check_memory(sizes: list[tuple[int, int]]) -> None:
    """ValueError where every view's maps, padded to the largest and held at once, need more memory than this
    machine has free: the kernel would otherwise kill the run without a word."""
    if not sizes:
        return
    width, height = max(w for w, _ in sizes), max(h for _, h in sizes)
    need = len(sizes) * width * height * BYTES_PER_PIXEL
    free = _available_memory()
    if free is not None and need > free:
        raise ValueError(f"fusion: the final maps of {len(sizes)} views at {width}x{height} need {need / 1e9:.1f} GB "
                         f"held at once and this machine has {free / 1e9:.1f} GB free; lower mvs.max_image_size "
                         "(the memory goes with its square), or free memory, and run again")


def _available_memory() -> int | None:
    """Bytes of memory free for a new allocation (Linux's MemAvailable; None where it cannot be read)."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _colours_at_pixels(path: Path, width: int, height: int) -> np.ndarray:
    """The photo's RGB at the centre of each of ``width`` x ``height`` pixels (nearest, as COLMAP reads it)."""
    photo = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if photo is None:
        raise ValueError(f"fusion: cannot read the undistorted image {path}; run again with --force undistort")
    rows = np.minimum(((np.arange(height) + 0.5) * photo.shape[0] / height).astype(int), photo.shape[0] - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * photo.shape[1] / width).astype(int), photo.shape[1] - 1)
    return photo[rows][:, cols, ::-1]


def _overlap(rec: pycolmap.Reconstruction, ids: list[int]) -> np.ndarray:
    """For each of the images ``ids``, the others (indices into ``ids``) by how many sparse points they
    share, most first, at most OVERLAPPING_VIEWS, none that shares no point."""
    xyz, point_of, view_of = observations(rec, ids)
    seen = scipy.sparse.csr_matrix((np.ones(len(point_of)), (point_of, view_of)), shape=(len(xyz), len(ids)))
    seen.data[:] = 1  # a view observing a point twice counts once
    shared = (seen.T @ seen).toarray()
    np.fill_diagonal(shared, 0)
    overlap = np.full((len(ids), max(1, min(OVERLAPPING_VIEWS, len(ids) - 1))), -1, np.int32)
    for i in range(len(ids)):
        ranked = np.argsort(-shared[i], kind="stable")[:overlap.shape[1]]
        ranked = ranked[shared[i, ranked] > 0]
        overlap[i, :len(ranked)] = ranked
    return overlap


def _order(overlap: np.ndarray) -> np.ndarray:
    """The views in the order they seed points: from the first, each time the next view the last one
    overlaps most that is not done, else the first not done (COLMAP's order)."""
    done = np.zeros(len(overlap), bool)
    order = []
    view = 0 if len(overlap) else -1
    while view >= 0:
        order.append(view)
        done[view] = True
        following = [j for j in overlap[view] if j >= 0 and not done[j]]
        rest = np.flatnonzero(~done)
        view = following[0] if following else (int(rest[0]) if len(rest) else -1)
    return np.array(order, np.int32)


def fuse(views: FusionViews, within: Tolerances, min_pixels: int, pixel_centre: float = 0.5,
         progress: Callable[[], None] | None = None) -> FusedPoints:
    """Points where at least ``min_pixels`` views' pixels agree ``within`` the tolerances. Depth at pixel
    (col, row) lies along the ray through (col + pixel_centre, row + pixel_centre). ``progress`` is called
    after each view has seeded its points."""
    n = len(views.cameras)
    P = np.zeros((n, 3, 4))
    K_inv = np.zeros((n, 3, 3))
    R = np.zeros((n, 3, 3))
    t = np.zeros((n, 3))
    sizes = np.zeros((n, 2), np.int32)
    for i, cam in enumerate(views.cameras):
        K = cam.K.copy()
        K[:2, 2] -= pixel_centre  # pixel (col, row) at (col, row) in K's frame
        P[i] = K @ np.hstack([cam.R, cam.t[:, None]])
        K_inv[i] = np.linalg.inv(K)
        R[i], t[i] = cam.R, cam.t
        sizes[i] = cam.width, cam.height
    used = np.zeros(views.depth.shape, np.bool_)
    done = np.zeros(n, np.bool_)
    parts = []
    for ref in _order(views.overlap):
        parts.append(_fuse_view(ref, views.depth, views.normal, views.colour, sizes, P, K_inv, R, t, views.overlap,
                                used, done, min_pixels, within.reproj_px ** 2, within.merge_px ** 2, within.depth,
                                math.cos(math.radians(within.normal_degrees))))
        done[ref] = True
        if progress is not None:
            progress()
    if not parts:
        return FusedPoints(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8),
                           np.zeros(0, np.int32), np.zeros(0, np.int32))
    return FusedPoints(*(np.concatenate(arrays) for arrays in zip(*parts)))


@njit(cache=True)
def _median(values, count):  # pragma: no cover - numba
    return np.median(values[:count])


@njit(cache=True)
def _fuse_view(ref, depth, normal, colour, sizes, P, K_inv, R, t, overlap, used, done, min_pixels, agree_sq,
               merge_sq, max_depth_error, min_cos):  # pragma: no cover - numba
    """The points view ``ref``'s unused pixels seed (COLMAP's fusion at traversal depth 2, a joining pixel
    used up within ``merge_sq``; see the module): xyz, normals, colours, view counts, views."""
    most = overlap.shape[1] + 1
    member = np.empty((9, most), np.float32)  # x y z nx ny nz r g b of each joined pixel
    member_view = np.empty(most, np.int32)
    capacity = sizes[ref, 0] * sizes[ref, 1]  # a point per pixel at most
    xyz = np.empty((capacity, 3), np.float32)
    normals = np.empty((capacity, 3), np.float32)
    colours = np.empty((capacity, 3), np.uint8)
    counts = np.empty(capacity, np.int32)
    views = np.empty(capacity * 4, np.int32)
    points = 0
    entries = 0
    for row in range(sizes[ref, 1]):
        for col in range(sizes[ref, 0]):
            if used[ref, row, col]:
                continue
            used[ref, row, col] = True
            d = depth[ref, row, col]
            if d <= 0.0:
                continue
            _join(ref, row, col, d, normal, colour, K_inv, R, t, member, member_view, 0)
            joined = 1
            X = member[0, 0]
            Y = member[1, 0]
            Z = member[2, 0]
            for k in range(overlap.shape[1]):
                other = overlap[ref, k]
                if other < 0:
                    break
                if done[other]:
                    continue
                qx = P[other, 0, 0] * X + P[other, 0, 1] * Y + P[other, 0, 2] * Z + P[other, 0, 3]
                qy = P[other, 1, 0] * X + P[other, 1, 1] * Y + P[other, 1, 2] * Z + P[other, 1, 3]
                qz = P[other, 2, 0] * X + P[other, 2, 1] * Y + P[other, 2, 2] * Z + P[other, 2, 3]
                if qz <= 0.0:
                    continue
                u = qx / qz
                v = qy / qz
                c = int(math.floor(u + 0.5))
                r = int(math.floor(v + 0.5))
                if c < 0 or r < 0 or c >= sizes[other, 0] or r >= sizes[other, 1] or used[other, r, c]:
                    continue
                d_other = depth[other, r, c]
                if d_other <= 0.0 or abs(qz - d_other) > max_depth_error * d_other:
                    continue
                error_sq = (u - c) ** 2 + (v - r) ** 2
                if error_sq > agree_sq:
                    continue
                nx = normal[other, r, c, 0]
                ny = normal[other, r, c, 1]
                nz = normal[other, r, c, 2]
                cos = ((R[other, 0, 0] * nx + R[other, 1, 0] * ny + R[other, 2, 0] * nz) * member[3, 0]
                       + (R[other, 0, 1] * nx + R[other, 1, 1] * ny + R[other, 2, 1] * nz) * member[4, 0]
                       + (R[other, 0, 2] * nx + R[other, 1, 2] * ny + R[other, 2, 2] * nz) * member[5, 0])
                if cos < min_cos:
                    continue
                _join(other, r, c, d_other, normal, colour, K_inv, R, t, member, member_view, joined)
                joined += 1
                if error_sq <= merge_sq:
                    used[other, r, c] = True
            if joined < min_pixels:
                continue
            mx = _median(member[3], joined)
            my = _median(member[4], joined)
            mz = _median(member[5], joined)
            length = math.sqrt(mx * mx + my * my + mz * mz)
            if length < 1.1920929e-07:
                continue
            if entries + joined > views.shape[0]:
                grown = np.empty(views.shape[0] * 2, np.int32)
                grown[:entries] = views[:entries]
                views = grown
            for a in range(3):
                xyz[points, a] = _median(member[a], joined)
                colours[points, a] = min(255, max(0, int(math.floor(_median(member[6 + a], joined) + 0.5))))
            normals[points, 0] = mx / length
            normals[points, 1] = my / length
            normals[points, 2] = mz / length
            counts[points] = joined
            views[entries:entries + joined] = member_view[:joined]
            entries += joined
            points += 1
    return xyz[:points].copy(), normals[:points].copy(), colours[:points].copy(), counts[:points].copy(), \
        views[:entries].copy()


@njit(cache=True)
def _join(view, row, col, d, normal, colour, K_inv, R, t, member, member_view, k):  # pragma: no cover
    """Store pixel (col, row) of ``view`` at depth ``d`` as the ``k``-th member: its point, world normal
    and colour."""
    cx = d * (K_inv[view, 0, 0] * col + K_inv[view, 0, 1] * row + K_inv[view, 0, 2]) - t[view, 0]
    cy = d * (K_inv[view, 1, 0] * col + K_inv[view, 1, 1] * row + K_inv[view, 1, 2]) - t[view, 1]
    cz = d * (K_inv[view, 2, 0] * col + K_inv[view, 2, 1] * row + K_inv[view, 2, 2]) - t[view, 2]
    for a in range(3):  # x = R^T (x_cam - t)
        member[a, k] = R[view, 0, a] * cx + R[view, 1, a] * cy + R[view, 2, a] * cz
        member[3 + a, k] = (R[view, 0, a] * normal[view, row, col, 0] + R[view, 1, a] * normal[view, row, col, 1]
                            + R[view, 2, a] * normal[view, row, col, 2])
        member[6 + a, k] = colour[view, row, col, a]
    member_view[k] = view
