"""Depth for the untextured regions of a depth map, from the plane of the depths around them.

PatchMatch matches windows of texture. Where a window has none (a wall or a box face in flat paint),
its matching cost carries no information; the filter then removes whatever depth the pixel held
(:func:`recon.mvs.patchmatch.own_texture`), and the surface has a hole there in every view. ACMP (Xu
and Tao, AAAI 2020) fills such regions with planes triangulated between confident pixels, weighed
against the photometric cost. Here most of these pixels lie below the matcher's variance floor (on
the zoo's plain_boxes, 78-92 % of the true planes of the pixels the filter calls untextured cost the
maximum: no correlation is defined there), so no photometric term can test a plane; the depths
measured around a region are the only evidence. So the fill works per region, and asks that
evidence to be unambiguous:

- a region is a connected set (4-neighbours) of pixels of one shade whose own side of the window is
  untextured (``own_texture`` below ``min_texture``, the filter's own test), of at least
  :data:`MIN_AREA` px (:func:`regions`);
- it must not touch the image border: sky, a black background and a floor running out of the frame
  do, and what lies beyond the border is unknown;
- its rim (the pixels within :data:`RIM` px outside it) must hold depths on at least
  :data:`RIM_COVERAGE` of its pixels, and a plane must fit at least :data:`PLANE_INLIERS` of those
  within the filter's relative depth error (``filter_max_depth_error``), found by RANSAC;
- the plane's inliers must surround the region (some in :data:`SURROUND` of the 8 directions from its
  centroid), so a plane seen along one side is not carried across;
- the inliers must not be seen edge-on: the limb of an untextured ball is a planar circle, but there the
  surface turns away from the camera, and the inliers' own normals lie across their rays (the median
  cosine between them under :data:`EDGE_ON`). A box face's rim is its edges, where the depths and
  normals are those of the faces around it, seen from the front: their normals say nothing of the
  face's own (zoo, docs/DECISIONS.md);
- the plane must face the camera at no grazing angle (cosine at least :data:`MIN_COS` at every
  filled pixel).

Then each pixel of the region without a depth takes the plane's depth and normal. The fill is per
view; fusion then keeps a point where enough views' depths agree, as for any depth.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

#: smallest region filled (px at the working resolution); smaller holes cost the surface little
MIN_AREA = 16
#: intensity step (in [0, 1], between neighbours after a 1 px Gaussian blur) that separates two regions
SHADE_STEP = 0.004
#: width of a region's rim (px), where the depths that decide its plane are read
RIM = 4
#: share of the rim's pixels that must hold a depth
RIM_COVERAGE = 0.5
#: share of the rim's depths the plane must fit
PLANE_INLIERS = 0.7
#: of the 8 directions from a region's centroid, how many must hold some of its plane's inliers: 6 admits
#: a face between two measured edges whose other sides border untextured faces, not a plane seen on one side
SURROUND = 6
#: the median cosine between the inliers' normals and their rays under which the rim is a limb seen edge-on
EDGE_ON = 0.1
#: smallest cosine between the plane's normal and a filled pixel's ray
MIN_COS = 0.1
#: RANSAC draws per region (seeded by the region: the same maps give the same fill)
DRAWS = 64


def regions(image: np.ndarray, untextured: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Connected untextured regions of one shade (``cv2.connectedComponentsWithStats``' count, labels, stats
    and centroids): untextured pixels where the lightly smoothed image steps by more than :data:`SHADE_STEP`
    to a neighbour separate them. Two faces of a box in one flat paint are untextured up to the edge
    between them, but lit from different angles they differ in shade; one region each, each has one plane."""
    smooth = cv2.GaussianBlur(image.astype(np.float32), (5, 5), 1.0)
    step = np.zeros(image.shape, bool)
    dx = np.abs(np.diff(smooth, axis=1)) > SHADE_STEP
    dy = np.abs(np.diff(smooth, axis=0)) > SHADE_STEP
    step[:, 1:] |= dx
    step[:, :-1] |= dx
    step[1:] |= dy
    step[:-1] |= dy
    return cv2.connectedComponentsWithStats((untextured & ~step).astype(np.uint8), connectivity=4)


def fill_untextured(image: np.ndarray, untextured: np.ndarray, depth: np.ndarray, normal: np.ndarray,
                    kinv: np.ndarray, max_depth_error: float) -> int:
    """Fill, in place, the pixels without depth of each untextured region (:func:`regions` of the grey
    ``image`` in [0, 1] and the bool ``untextured``, both the depth map's shape) that passes the module's
    tests with the plane of its rim's depths; ``normal`` (H, W, 3, camera frame, facing the camera) gets
    the plane's normal there. ``kinv`` is the inverse intrinsics at the map's resolution (pixel centres at
    +0.5). Returns how many pixels were filled."""
    height, width = depth.shape
    count, labels, stats, centroids = regions(image, untextured)
    kernel = np.ones((2 * RIM + 1, 2 * RIM + 1), np.uint8)
    filled = 0
    for label in range(1, count):
        x, y, w, h, area = (int(v) for v in stats[label])
        if area < MIN_AREA or x == 0 or y == 0 or x + w == width or y + h == height:
            continue
        x0, y0 = max(x - RIM, 0), max(y - RIM, 0)
        x1, y1 = min(x + w + RIM, width), min(y + h + RIM, height)
        region = labels[y0:y1, x0:x1] == label
        rim = cv2.dilate(region.astype(np.uint8), kernel).astype(bool) & ~region
        crop = depth[y0:y1, x0:x1]
        measured = rim & (crop > 0)
        if np.count_nonzero(measured) < max(RIM_COVERAGE * np.count_nonzero(rim), 3):
            continue
        rows, cols = np.nonzero(measured)
        plane = _rim_plane(cols + x0, rows + y0, crop[rows, cols], normal[y0:y1, x0:x1][rows, cols],
                           centroids[label], kinv, max_depth_error, seed=label)
        if plane is None:
            continue
        n, q = plane
        rows, cols = np.nonzero(region & (crop <= 0))
        rays = _rays(cols + x0, rows + y0, kinv)
        along = rays @ n
        cos = -along / np.linalg.norm(rays, axis=1)
        if np.any(cos < MIN_COS):
            continue
        crop[rows, cols] = q / along
        normal[y0:y1, x0:x1][rows, cols] = n
        filled += len(rows)
    return filled


def _rays(xs: np.ndarray, ys: np.ndarray, kinv: np.ndarray) -> np.ndarray:
    """(N, 3) rays (z = 1) through the centres of pixels (xs, ys)."""
    pixels = np.stack([xs + 0.5, ys + 0.5, np.ones(len(xs))], axis=1)
    return pixels @ kinv.T


def _rim_plane(xs, ys, depths, normals, centroid, kinv, max_depth_error, seed):
    """The plane (n, q) with n . X = q, n facing the camera, that the rim's depths decide, or None
    (module doc)."""
    rays = _rays(xs, ys, kinv)
    points = rays * depths[:, None]
    rng = np.random.default_rng(seed)
    a, b, c = (points[i] for i in rng.integers(0, len(points), size=(3, DRAWS)))
    candidates = np.cross(b - a, c - a)
    norms = np.linalg.norm(candidates, axis=1)
    drawn = norms > 1e-12 * np.max(np.abs(points)) ** 2
    if not np.any(drawn):
        return None
    candidates = candidates[drawn] / norms[drawn, None]
    fits = _fits(candidates.T, np.sum(candidates * a[drawn], axis=1), rays, depths, max_depth_error)
    best = fits[:, np.argmax(np.count_nonzero(fits, axis=0))]  # the inliers of the draw that fits most
    if np.count_nonzero(best) < PLANE_INLIERS * len(points):
        return None
    centre = points[best].mean(axis=0)
    n = np.linalg.svd(points[best] - centre, full_matrices=False)[2][2]  # least squares over the inliers
    q = float(n @ centre)
    inliers = _fits(n, q, rays, depths, max_depth_error)
    if np.count_nonzero(inliers) < PLANE_INLIERS * len(points):
        return None
    if n @ (kinv @ np.array([centroid[0] + 0.5, centroid[1] + 0.5, 1.0])) > 0:
        n, q = -n, -q
    directions = np.arctan2(ys[inliers] - centroid[1], xs[inliers] - centroid[0])
    if len(np.unique(np.floor((directions + math.pi) / (math.pi / 4)).astype(int) % 8)) < SURROUND:
        return None
    facing = np.abs(np.sum(normals[inliers] * rays[inliers], axis=1)) / np.linalg.norm(rays[inliers], axis=1)
    if np.median(facing) < EDGE_ON:
        return None
    return n, q


def _fits(n, q, rays, depths, max_depth_error):
    """Which rim depths lie within ``max_depth_error`` (relative) of the plane n . X = q along their ray;
    with n (3, K) and q (K,), one column per plane."""
    along = rays @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        plane_depth = q / along
    depths = depths if np.ndim(along) == 1 else depths[:, None]
    return np.abs(plane_depth - depths) <= max_depth_error * depths
