"""PatchMatch multi-view stereo on the CPU: per-pixel slanted planes estimated by numba kernels.

The variant follows Gipuma (Galliani et al., ICCV 2015) and ACMH/ACMM (Xu and Tao, CVPR 2019):

* every reference pixel holds a plane hypothesis, a depth (camera z) and a unit normal in the reference
  camera frame facing the camera, initialised at random (depth uniform in inverse depth);
* red-black checkerboard sweeps: one colour is updated while it reads only the other, so a sweep is
  parallel over rows and its result does not depend on the thread count;
* propagation uses ACMH's adaptive checkerboard sampling: four V-shaped near regions and four long
  far strips around the pixel; from each region the neighbour with the lowest current cost is taken
  and its plane is tested at the pixel (the plane is intersected with the pixel's ray, as in Gipuma);
* refinement tests perturbed depth/normal combinations (and, at the coarsest level, random ones), the
  perturbation range halving every sweep (Gipuma, ACMM); in the photometric pass also the best plane
  turned to the ground's normal, where it is known (:mod:`recon.mvs.ground_normal`);
* the photometric cost is 1 - NCC with bilateral weights (COLMAP, ACMM) over a window sampled with a
  stride (ACMM's 11 x 11 window read every second pixel), warped to each source view through the
  plane-induced homography, linearised at the window centre (one affine warp per window: a departure
  that saves a division per sample and is negligible unless the plane is seen nearly edge-on);
* with ``narrow_sigma``, the window's spatial weight narrows, per pixel, where the window is textured
  well above the photo's noise (:func:`matching_spread`): a plane fitted over a window leans behind a
  curved surface by about half its curvature times the window's second moment, and that lean, not the
  search, is what keeps curved objects' depths off (turntable_black's vase, clutter's balls); off by
  default, as the narrower window loses far ground seen at grazing angles (docs/DECISIONS.md, sessions
  43, 48 and 53);
* multi-view aggregation is the mean of the K best source costs (Gipuma's "best K"); this departs from
  ACMM's probabilistic per-pixel view-selection weights, which cost more per hypothesis; a source the
  plane projects outside of counts as an uncorrelated window (:data:`UNSEEN_COST`), and the filter
  leaves it out (:func:`seen_cost`), so that a pixel only one source sees can pass;
* coarse to fine (ACMM's multi-scale scheme without its detail restorer): each finer level starts from
  the coarser planes re-intersected with its own pixel rays, then runs a few sweeps; there, each
  pixel is matched only against the K sources that were best for its upsampled plane (a cheap form
  of view selection: it divides the cost of the fine levels by about S / K), a neighbour's plane also
  against the neighbour's K (its sources travel with it, and replace the pixel's where it wins: the
  views are propagated as the planes are), and the finest level
  propagates from the four near regions only; a candidate equal to the pixel's plane, or to a
  neighbour's plane already tested at the pixel (neighbours often share one), is skipped;
* a hypothesis is abandoned as soon as the costs of the sources matched so far prove that it cannot
  beat the pixel's best (where all of a pixel's sources count in its mean): the same planes win;
* geometric consistency (COLMAP's geom_consistency, ACMM's ACMM+geom): a second pass adds to each
  source's cost the capped forward-backward reprojection error through that source's depth map;
* filtering keeps a pixel when its photometric cost is low and enough source depth maps agree with it
  (reprojection error, and distance from the pixel's plane relative to depth, below thresholds), and
  when the pixels of its window that share its own intensity have texture (:func:`own_texture`): a
  pixel of a uniform region beside an edge (sky beside a pole) matches on the edge alone and takes its
  depth (foreground fattening), which no multi-view test catches, since every view sees the same halo.

The kernels are plain loops over arrays (no Python objects inside), and random numbers come from a
counter-based hash of (seed, sweep, pixel), so the same code can be ported to numba-cuda.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from numba import njit, prange

from recon.mvs.options import MVSOptions

log = logging.getLogger(__name__)

MAX_COST = 2.0
#: photometric cost of a source the pixel's plane projects outside of: an uncorrelated window (NCC 0), not
#: the worst match, so that a wrong plane carried out of every source's image does not beat the true
#: plane seen by few. The filter leaves these terms out (:func:`seen_cost`)
UNSEEN_COST = 1.0
#: the view-mask modes of :func:`evaluate`
ALL_VIEWS, SELECT_VIEWS, KEEP_VIEWS, KEEP_AND_CONFIRMING, NARROW_VIEWS = 0, 1, 2, 3, 4
_MIN_COS = 0.05  # hypotheses whose plane is seen at a grazing angle (|cos| below this) are rejected
NO_NORMALS = np.zeros((0, 3))  # no normals known beforehand (propagate_and_refine's ``normals``)


@dataclass(frozen=True)
class Camera:
    """A pinhole view at the resolution of its image array: x_cam = R @ X + t, pixel = K @ x_cam / z."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray

    def scaled(self, sx: float, sy: float) -> Camera:
        """The same view for an image resized by (sx, sy): exact with the pixel-centre-at-0.5 convention."""
        return Camera(np.diag([sx, sy, 1.0]) @ self.K, self.R, self.t)


@dataclass(frozen=True)
class ViewGeometry:
    """Arrays the kernels use to move between the reference view and each source view s.

    A source pixel of a reference pixel p on the plane (n, d) is ~ (A[s] + b[s] m^T) p with
    m = K_ref^-T n / (n . X); a source pixel q with source depth z maps back to ~ z M[s] q + c[s].
    """

    kinv: np.ndarray  # (3, 3) inverse reference intrinsics
    A: np.ndarray  # (S, 3, 3) K_s R_rs K_ref^-1
    b: np.ndarray  # (S, 3) K_s t_rs
    M: np.ndarray  # (S, 3, 3) K_ref R_rs^T K_s^-1
    c: np.ndarray  # (S, 3) -K_ref R_rs^T t_rs


def view_geometry(ref: Camera, sources: list[Camera]) -> ViewGeometry:
    """Relative geometry of each source view seen from the reference view."""
    kinv = np.linalg.inv(ref.K)
    A, b, M, c = [], [], [], []
    for src in sources:
        R_rs = src.R @ ref.R.T
        t_rs = src.t - R_rs @ ref.t
        A.append(src.K @ R_rs @ kinv)
        b.append(src.K @ t_rs)
        M.append(ref.K @ R_rs.T @ np.linalg.inv(src.K))
        c.append(-ref.K @ R_rs.T @ t_rs)
    return ViewGeometry(kinv, np.array(A), np.array(b), np.array(M), np.array(c))


def stack_images(images: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Zero-padded (S, H, W) float32 stack and the (S, 2) int32 (width, height) of each image."""
    height = max(im.shape[0] for im in images)
    width = max(im.shape[1] for im in images)
    stack = np.zeros((len(images), height, width), np.float32)
    dims = np.zeros((len(images), 2), np.int32)
    for i, im in enumerate(images):
        stack[i, : im.shape[0], : im.shape[1]] = im
        dims[i] = (im.shape[1], im.shape[0])
    return stack, dims


def window_grid(radius: int, step: int) -> np.ndarray:
    """The matching window as int64 (start, step, count): samples at offsets start + i * step
    (i < count) on both axes, symmetric about the pixel."""
    ticks = np.arange(-radius, radius + 1, step)
    ticks = ticks - (ticks[0] + ticks[-1]) // 2
    return np.array([ticks[0], step, len(ticks)], np.int64)


def _region_offsets() -> tuple[np.ndarray, np.ndarray]:
    """ACMH's adaptive checkerboard regions: 4 V-shaped near regions and 4 far strips, opposite colour."""
    near = [(0, -1)] + [(sx * i, -(1 + i)) for i in (1, 2, 3) for sx in (-1, 1)]
    far = [(0, -(3 + 2 * i)) for i in range(11)]
    offsets = np.zeros((8, 11, 2), np.int32)
    counts = np.zeros(8, np.int32)
    for r, (pattern, rotation) in enumerate([(p, k) for p in (near, far) for k in range(4)]):
        for i, (dx, dy) in enumerate(pattern):
            for _ in range(rotation):  # rotate by 90 degrees
                dx, dy = -dy, dx
            offsets[r, i] = (dx, dy)
        counts[r] = len(pattern)
    return offsets, counts


REGION_OFFSETS, REGION_COUNTS = _region_offsets()


# --- random numbers: a counter-based hash, identical on any thread (or GPU) -----------------------

@njit(cache=True)
def _hash32(x):
    x = x & 0xFFFFFFFF
    x ^= x >> 16
    x = (x * 0x7FEB352D) & 0xFFFFFFFF
    x ^= x >> 15
    x = (x * 0x846CA68B) & 0xFFFFFFFF
    x ^= x >> 16
    return x


@njit(cache=True)
def _uniform(key, k):
    """The k-th uniform number in [0, 1) of the stream ``key``."""
    return _hash32(key + 0x9E3779B9 * (k + 1)) * (1.0 / 4294967296.0)


def sweep_key(seed: int, sweep: int) -> int:
    """Random stream of one sweep; pixels derive their own stream from it."""
    return int(_hash32(_hash32(seed) ^ _hash32(sweep * 0x632BE5AB + 1)))


# --- geometry helpers ---------------------------------------------------------------------------

@njit(cache=True, fastmath=True)
def _ray(kinv, x, y):
    """Ray (z = 1 in the camera frame) through the centre of pixel (x, y)."""
    px = x + 0.5
    py = y + 0.5
    return (kinv[0, 0] * px + kinv[0, 1] * py + kinv[0, 2],
            kinv[1, 0] * px + kinv[1, 1] * py + kinv[1, 2],
            kinv[2, 0] * px + kinv[2, 1] * py + kinv[2, 2])


@njit(cache=True, fastmath=True)
def _random_depth(dmin, dmax, u):
    """Depth uniform in inverse depth between dmin and dmax."""
    return 1.0 / (1.0 / dmax + u * (1.0 / dmin - 1.0 / dmax))


@njit(cache=True, fastmath=True)
def _random_normal(rx, ry, rz, u, v):
    """Unit normal uniform on the half sphere facing the ray (rx, ry, rz)."""
    nz = 1.0 - 2.0 * u
    r = math.sqrt(max(0.0, 1.0 - nz * nz))
    phi = 2.0 * math.pi * v
    nx = r * math.cos(phi)
    ny = r * math.sin(phi)
    if nx * rx + ny * ry + nz * rz > 0.0:
        return -nx, -ny, -nz
    return nx, ny, nz


@njit(cache=True, fastmath=True)
def _perturbed_normal(n0, n1, n2, rx, ry, rz, scale, u0, u1, u2):
    """The normal moved by a random vector of components in [-scale, scale], kept facing the ray."""
    a = n0 + scale * (2.0 * u0 - 1.0)
    b = n1 + scale * (2.0 * u1 - 1.0)
    c = n2 + scale * (2.0 * u2 - 1.0)
    norm = math.sqrt(a * a + b * b + c * c)
    if norm < 1e-12 or a * rx + b * ry + c * rz >= 0.0:
        return n0, n1, n2
    return a / norm, b / norm, c / norm


@njit(cache=True, fastmath=True)
def _plane_depth_at(kinv, depth, n0, n1, n2, xn, yn, x, y):
    """Depth at pixel (x, y) of the plane through pixel (xn, yn) at ``depth`` with normal n."""
    ax, ay, az = _ray(kinv, xn, yn)
    bx, by, bz = _ray(kinv, x, y)
    denom = n0 * bx + n1 * by + n2 * bz
    if denom > -1e-9:
        return depth
    return depth * (n0 * ax + n1 * ay + n2 * az) / denom


# --- matching cost ------------------------------------------------------------------------------

@njit(cache=True, fastmath=True)
def _bilinear(srcs, s, u, v, width, height):
    """Image s of the stack sampled at continuous pixel coordinates (u, v) (pixel centres at .5),
    clamped to the image."""
    x = u - 0.5
    y = v - 0.5
    if not x > 0.0:  # also catches NaN
        x = 0.0
    elif x > width - 1.001:
        x = width - 1.001
    if not y > 0.0:
        y = 0.0
    elif y > height - 1.001:
        y = height - 1.001
    return _interpolate(srcs, s, x, y)


@njit(cache=True, fastmath=True)
def _interpolate(srcs, s, x, y):
    """Bilinear interpolation of image s at array coordinates (x, y) >= 0 inside the image.

    Indices are unsigned so that no negative-index handling enters the innermost loops; the stack is
    indexed directly (taking ``srcs[s]`` would create an array view, whose reference counting costs
    more than the interpolation when two threads share the array).
    """
    ix = np.uintp(x)
    iy = np.uintp(y)
    ax = x - ix
    ay = y - iy
    one = np.uintp(1)
    top = srcs[s, iy, ix] + ax * (srcs[s, iy, ix + one] - srcs[s, iy, ix])
    bottom = srcs[s, iy + one, ix] + ax * (srcs[s, iy + one, ix + one] - srcs[s, iy + one, ix])
    return top + ay * (bottom - top)


@njit(cache=True, fastmath=True)
def reference_patch(ref, x, y, window, spread, sigma_color, weights, centred):
    """Bilateral weights of the window around (x, y) and its weighted, mean-free intensities; the
    spatial weight of a sample at distance r is exp(-r^2 * spread[y, x]) (:func:`matching_spread`).

    Fills ``weights`` (summing to 1) and ``centred`` (weight * (intensity - weighted mean)), sample
    k = row * count + column; returns the weighted intensity variance.
    """
    height, width = ref.shape
    start, step, count = window[0], window[1], window[2]
    centre = ref[y, x]
    inv_s = spread[y, x]
    inv_c = 0.5 / (sigma_color * sigma_color)
    total = 0.0
    k = 0
    for j in range(count):
        dy = start + j * step
        yy = min(max(y + dy, 0), height - 1)
        for i in range(count):
            dx = start + i * step
            xx = min(max(x + dx, 0), width - 1)
            value = ref[yy, xx]
            diff = value - centre
            w = math.exp(-(dx * dx + dy * dy) * inv_s - diff * diff * inv_c)
            weights[k] = w
            centred[k] = value
            total += w
            k += 1
    mean = 0.0
    square = 0.0
    for k in range(count * count):
        w = weights[k] / total
        weights[k] = w
        mean += w * centred[k]
        square += w * centred[k] * centred[k]
    for k in range(count * count):
        centred[k] = weights[k] * (centred[k] - mean)
    return square - mean * mean


@njit(cache=True, fastmath=True)
def _mean_of_best(costs, mask, k, scratch):
    """Mean of the k smallest costs[s] over the sources s in the bit ``mask``."""
    n = 0
    for s in range(costs.shape[0]):
        if (mask >> s) & 1:
            v = costs[s]
            j = n - 1
            while j >= 0 and scratch[j] > v:  # insertion sort: a handful of entries
                scratch[j + 1] = scratch[j]
                j -= 1
            scratch[j + 1] = v
            n += 1
    k = min(k, n)
    if k == 0:
        return MAX_COST
    total = 0.0
    for i in range(k):
        total += scratch[i]
    return total / k


@njit(cache=True)
def _best_views(costs, mask, k):
    """Bit mask of the k sources of the bit ``mask`` with the lowest costs."""
    best_mask = 0
    for _ in range(k):
        best = -1
        for s in range(costs.shape[0]):
            if (mask >> s) & 1 and not (best_mask >> s) & 1 and (best < 0 or costs[s] < costs[best]):
                best = s
        if best < 0:
            break
        best_mask |= 1 << best
    return best_mask


@njit(cache=True, fastmath=True)
def _warped_sums(srcs, s, cu, cv, dudx, dudy, dvdx, dvdy, window, weights, centred, width, height):
    """Weighted sums (s, s^2, centred-reference * s) over the window of source s around (cu, cv)
    whose sample at window offset (dx, dy) sits at (cu, cv) + J (dx, dy); bounds are checked once
    per window unless it touches the image border."""
    start, step, count = window[0], window[1], window[2]
    radius = max(-start, start + step * (count - 1))
    reach_u = (abs(dudx) + abs(dudy)) * radius
    reach_v = (abs(dvdx) + abs(dvdy)) * radius
    inside = (cu - reach_u >= 0.5 and cv - reach_v >= 0.5 and cu + reach_u < width - 0.5
              and cv + reach_v < height - 0.5)
    step_u = dudx * step
    step_v = dvdx * step
    sum_s = 0.0
    sum_ss = 0.0
    sum_rs = 0.0
    k = 0
    for j in range(count):
        dy = start + j * step
        u = cu + dudx * start + dudy * dy
        v = cv + dvdx * start + dvdy * dy
        for _ in range(count):
            if inside:
                value = _interpolate(srcs, s, u - 0.5, v - 0.5)
            else:
                value = _bilinear(srcs, s, u, v, width, height)
            w = weights[k]
            sum_s += w * value
            sum_ss += w * value * value
            sum_rs += centred[k] * value
            u += step_u
            v += step_v
            k += 1
    return sum_s, sum_ss, sum_rs


@njit(cache=True, fastmath=True)
def _plane_row(kinv, q, n0, n1, n2):
    """n^T K^-1 / q for the plane with normal n at n . X = q: the row that makes the plane's homography
    to a source A + b m (:func:`view_geometry`)."""
    return ((kinv[0, 0] * n0 + kinv[1, 0] * n1 + kinv[2, 0] * n2) / q,
            (kinv[0, 1] * n0 + kinv[1, 1] * n1 + kinv[2, 1] * n2) / q,
            (kinv[0, 2] * n0 + kinv[1, 2] * n1 + kinv[2, 2] * n2) / q)


@njit(cache=True, fastmath=True)
def _homography(A, b, s, m0, m1, m2):
    """The plane-induced homography A[s] + b[s] m from reference to source ``s`` pixels, row by row."""
    return (A[s, 0, 0] + b[s, 0] * m0, A[s, 0, 1] + b[s, 0] * m1, A[s, 0, 2] + b[s, 0] * m2,
            A[s, 1, 0] + b[s, 1] * m0, A[s, 1, 1] + b[s, 1] * m1, A[s, 1, 2] + b[s, 1] * m2,
            A[s, 2, 0] + b[s, 2] * m0, A[s, 2, 1] + b[s, 2] * m1, A[s, 2, 2] + b[s, 2] * m2)


@njit(cache=True, fastmath=True)
def hypothesis_cost(x, y, depth, n0, n1, n2, mask, weights, centred, ref_var, window, kinv, A, b,
                    srcs, dims, src_depth, M, c, geo_weight, geo_max, top_k, min_var, costs, scratch,
                    bound=-1.0):
    """Cost of the plane (depth, n) at pixel (x, y): mean of the top_k costs of the sources in the
    bit ``mask``, whose costs are left in ``costs[s]`` (``scratch`` is work space of length S).

    A source's cost is 1 - NCC of the bilateral-weighted window warped by the plane's homography,
    plus ``geo_weight`` times the capped forward-backward reprojection error through the source's
    depth map when ``geo_weight`` > 0.

    A hypothesis that can no longer cost less than ``bound`` (>= 0; negative: none) is abandoned,
    returning a cost above ``bound`` and leaving the rest of ``costs`` unset, as soon as the costs
    summed so far prove it. That holds when the mask has at most top_k sources (every one counts in
    the mean, and no cost is negative): above the coarsest level, where each pixel keeps its top_k.
    Propagation and refinement pass the pixel's best cost, so they keep exactly the planes they would
    keep without it.
    """
    n_views = 0
    if bound >= 0.0:  # (not an infinite default: fastmath assumes no infinities)
        for s in range(A.shape[0]):
            n_views += (mask >> s) & 1
        if n_views > top_k:  # a source not yet matched could still push a costly one out of the mean
            bound = -1.0
    limit = bound * n_views * (1.0 + 1e-6)  # (the margin covers the summation order)
    total = 0.0
    px = x + 0.5
    py = y + 0.5
    rx, ry, rz = _ray(kinv, x, y)
    cos = n0 * rx + n1 * ry + n2 * rz
    worst = MAX_COST + geo_weight * geo_max
    unseen = UNSEEN_COST + geo_weight * geo_max
    if cos > -_MIN_COS * math.sqrt(rx * rx + ry * ry + rz * rz):
        return worst
    m0, m1, m2 = _plane_row(kinv, depth * cos, n0, n1, n2)
    for s in range(A.shape[0]):
        if not (mask >> s) & 1:
            continue
        if bound >= 0.0 and total > limit:
            return total / n_views
        h00, h01, h02, h10, h11, h12, h20, h21, h22 = _homography(A, b, s, m0, m1, m2)
        width = dims[s, 0]
        height = dims[s, 1]
        cz = h20 * px + h21 * py + h22
        if not cz > 1e-6:  # behind (or at) the source camera; also keeps the warp finite
            costs[s] = worst
            total += worst
            continue
        cu = (h00 * px + h01 * py + h02) / cz
        cv = (h10 * px + h11 * py + h12) / cz
        if not (cu >= 0.0 and cv >= 0.0 and cu < width and cv < height):
            costs[s] = unseen
            total += unseen
            continue
        # the homography is linearised at the window centre: over a window a few pixels wide the
        # second-order (perspective) term is negligible unless the plane is seen nearly edge-on
        inv = 1.0 / cz
        dudx = (h00 - cu * h20) * inv
        dudy = (h01 - cu * h21) * inv
        dvdx = (h10 - cv * h20) * inv
        dvdy = (h11 - cv * h21) * inv
        sum_s, sum_ss, sum_rs = _warped_sums(srcs, s, cu, cv, dudx, dudy, dvdx, dvdy, window,
                                             weights, centred, width, height)
        var_s = sum_ss - sum_s * sum_s
        if var_s < min_var:
            cost = MAX_COST
        else:
            cost = 1.0 - sum_rs / math.sqrt(ref_var * var_s)
            cost = min(max(cost, 0.0), MAX_COST)
        if geo_weight > 0.0:
            cost += geo_weight * min(_reprojection_error(src_depth, s, cu, cv, px, py, M, c), geo_max)
        costs[s] = cost
        total += cost
    return _mean_of_best(costs, mask, top_k, scratch)


@njit(parallel=True, cache=True, fastmath=True)
def remove_geometric_term(dims, kinv, A, b, src_depth, M, c, geo_weight, geo_max, depth, normal, views, cost):
    """Turn the geometric-consistency costs of the current hypotheses (``cost``, as :func:`evaluate`
    and the sweeps leave them with ``src_depth``) into their photometric costs over each pixel's
    view mask, by subtracting the mean reprojection term: what evaluate(KEEP_VIEWS) without the
    geometric term would compute, without matching a window again (the filter needs the
    photometric cost; matching is most of the work of a pass).

    Exact only while each pixel's mask holds at most top_k sources, so that its cost is the plain
    mean over the mask (masks chosen by SELECT_VIEWS or KEEP_AND_CONFIRMING); pixels whose window is
    untextured or whose plane is seen edge-on get MAX_COST, as evaluate gives them. An untextured window
    is known by its cost: evaluate gives it the worst cost, MAX_COST plus the capped term, and the
    sweeps skip it.
    """
    height, width = cost.shape
    worst = np.float32(MAX_COST + geo_weight * geo_max)  # (as the float32 cost map holds it)
    for y in prange(height):
        for x in range(width):
            n0, n1, n2 = normal[y, x, 0], normal[y, x, 1], normal[y, x, 2]
            rx, ry, rz = _ray(kinv, x, y)
            cos = n0 * rx + n1 * ry + n2 * rz
            if cost[y, x] >= worst or cos > -_MIN_COS * math.sqrt(rx * rx + ry * ry + rz * rz):
                cost[y, x] = MAX_COST
                continue
            m0, m1, m2 = _plane_row(kinv, depth[y, x] * cos, n0, n1, n2)
            px = x + 0.5
            py = y + 0.5
            term = 0.0
            n_views = 0
            for s in range(A.shape[0]):
                if not (views[y, x] >> s) & 1:
                    continue
                n_views += 1
                cu, cv, where = _centre_in_source(A, b, dims, s, m0, m1, m2, px, py)
                error = geo_max
                if where == _INSIDE:
                    error = min(_reprojection_error(src_depth, s, cu, cv, px, py, M, c), geo_max)
                term += geo_weight * error
            cost[y, x] = cost[y, x] - term / n_views if n_views else MAX_COST


@njit(parallel=True, cache=True, fastmath=True)
def seen_cost(depth, normal, kinv, A, b, dims, views, cost, top_k, out):
    """``cost`` (photometric: the mean of the top_k best sources of each pixel's view mask) without the
    terms of the sources its plane projects outside of (each :data:`UNSEEN_COST`): the matching cost
    over the sources that see the pixel, which :func:`filter_depth` tests. A pixel seen by one source
    alone (ground at the edge of a survey that two photos share) otherwise averages at least
    (top_k - 1) / top_k * UNSEEN_COST over its top_k sources, above a useful ``filter_max_cost``.

    Exact for masks of at most top_k sources (SELECT_VIEWS: the mean is over the whole mask); for a
    larger mask, the unseen sources are taken to be among its best top_k only where fewer than top_k
    sources see the plane (as they are while every seen source costs less than UNSEEN_COST). A pixel
    no source sees gets MAX_COST.
    """
    height, width = depth.shape
    for y in prange(height):
        for x in range(width):
            out[y, x] = cost[y, x]
            if not depth[y, x] > 0.0 or cost[y, x] >= MAX_COST:
                continue
            n0, n1, n2 = normal[y, x, 0], normal[y, x, 1], normal[y, x, 2]
            rx, ry, rz = _ray(kinv, x, y)
            m0, m1, m2 = _plane_row(kinv, depth[y, x] * (n0 * rx + n1 * ry + n2 * rz), n0, n1, n2)
            px = x + 0.5
            py = y + 0.5
            n_views = 0
            unseen = 0
            for s in range(A.shape[0]):
                if not (views[y, x] >> s) & 1:
                    continue
                n_views += 1
                # (behind the camera costs MAX_COST, not UNSEEN_COST)
                unseen += _centre_in_source(A, b, dims, s, m0, m1, m2, px, py)[2] == _OUTSIDE
            k = min(top_k, n_views)
            counted = max(0, unseen - (n_views - k))
            if counted == 0:
                continue
            out[y, x] = (k * cost[y, x] - counted * UNSEEN_COST) / (k - counted) if k > counted else MAX_COST


_BEHIND, _OUTSIDE, _INSIDE = 0, 1, 2  # where a plane carries a pixel's centre in a source: _centre_in_source


@njit(cache=True, fastmath=True)
def _centre_in_source(A, b, dims, s, m0, m1, m2, px, py):
    """(cu, cv, where): the point of source ``s`` to which the plane (m0, m1, m2) carries reference pixel
    (px, py), and whether it lies _INSIDE the source's image, _OUTSIDE it, or the plane's point is
    _BEHIND (or at) the source camera (cu, cv then 0)."""
    h00, h01, h02, h10, h11, h12, h20, h21, h22 = _homography(A, b, s, m0, m1, m2)
    cz = h20 * px + h21 * py + h22
    if not cz > 1e-6:
        return 0.0, 0.0, _BEHIND
    cu = (h00 * px + h01 * py + h02) / cz
    cv = (h10 * px + h11 * py + h12) / cz
    inside = cu >= 0.0 and cv >= 0.0 and cu < dims[s, 0] and cv < dims[s, 1]
    return cu, cv, _INSIDE if inside else _OUTSIDE


@njit(cache=True, fastmath=True)
def _reprojection_error(src_depth, s, u, v, px, py, M, c):
    """Distance (px) between (px, py) and the back-projection of source pixel (u, v) at its depth."""
    z = src_depth[s, int(v), int(u)]
    if not z > 0.0:
        return 1e6
    bx = z * (M[s, 0, 0] * u + M[s, 0, 1] * v + M[s, 0, 2]) + c[s, 0]
    by = z * (M[s, 1, 0] * u + M[s, 1, 1] * v + M[s, 1, 2]) + c[s, 1]
    bz = z * (M[s, 2, 0] * u + M[s, 2, 1] * v + M[s, 2, 2]) + c[s, 2]
    if bz <= 0.0:
        return 1e6
    ex = bx / bz - px
    ey = by / bz - py
    return math.sqrt(ex * ex + ey * ey)


@njit(cache=True, fastmath=True)
def _confirming_source(kinv, A, b, dims, src_depth, M, c, geo_max, x, y, depth, n0, n1, n2):
    """The source whose depth map best confirms the plane (depth, n) at pixel (x, y): the least
    reprojection error, if under ``geo_max``; -1 when none does (or the plane is seen edge-on)."""
    rx, ry, rz = _ray(kinv, x, y)
    cos = n0 * rx + n1 * ry + n2 * rz
    if cos > -_MIN_COS * math.sqrt(rx * rx + ry * ry + rz * rz):
        return -1
    m0, m1, m2 = _plane_row(kinv, depth * cos, n0, n1, n2)
    best, least = -1, geo_max
    for s in range(A.shape[0]):
        cu, cv, where = _centre_in_source(A, b, dims, s, m0, m1, m2, x + 0.5, y + 0.5)
        if where == _INSIDE:
            error = _reprojection_error(src_depth, s, cu, cv, x + 0.5, y + 0.5, M, c)
            if error < least:
                best, least = s, error
    return best


# --- the PatchMatch steps -----------------------------------------------------------------------

@njit(parallel=True, cache=True, fastmath=True)
def initialise(depth, normal, kinv, dmin, dmax, key):
    """Random plane hypotheses: depth uniform in inverse depth, normal facing the camera."""
    height, width = depth.shape
    for y in prange(height):
        for x in range(width):
            pk = _hash32(key ^ _hash32(y * width + x))
            rx, ry, rz = _ray(kinv, x, y)
            depth[y, x] = _random_depth(dmin, dmax, _uniform(pk, 0))
            n0, n1, n2 = _random_normal(rx, ry, rz, _uniform(pk, 1), _uniform(pk, 2))
            normal[y, x, 0] = n0
            normal[y, x, 1] = n1
            normal[y, x, 2] = n2


@njit(parallel=True, cache=True, fastmath=True)
def upsample(depth_coarse, normal_coarse, views_coarse, kinv_coarse, kinv, depth, normal, views):
    """Fine hypotheses from coarse ones: each fine pixel takes its coarse pixel's plane, and as its
    view mask the union of the masks of the (up to four) coarse pixels nearest its centre: the sources
    chosen there, with those of the neighbour across the nearer edge of its coarse pixel, where a
    different surface may begin."""
    height, width = depth.shape
    hc, wc = depth_coarse.shape
    for y in prange(height):
        fy = (y + 0.5) * hc / height
        yc = min(int(fy), hc - 1)
        y0 = max(int(fy - 0.5), 0)
        y1 = min(int(fy + 0.5), hc - 1)
        for x in range(width):
            fx = (x + 0.5) * wc / width
            xc = min(int(fx), wc - 1)
            x0 = max(int(fx - 0.5), 0)
            x1 = min(int(fx + 0.5), wc - 1)
            mask = 0
            for yy in range(y0, y1 + 1):
                for xx in range(x0, x1 + 1):
                    mask |= views_coarse[yy, xx]
            views[y, x] = mask
            n0 = normal_coarse[yc, xc, 0]
            n1 = normal_coarse[yc, xc, 1]
            n2 = normal_coarse[yc, xc, 2]
            ax, ay, az = _ray(kinv_coarse, xc, yc)
            bx, by, bz = _ray(kinv, x, y)
            d = depth_coarse[yc, xc]
            denom = n0 * bx + n1 * by + n2 * bz
            if denom < -1e-9:
                d = d * (n0 * ax + n1 * ay + n2 * az) / denom
            depth[y, x] = d
            normal[y, x, 0] = n0
            normal[y, x, 1] = n1
            normal[y, x, 2] = n2


@njit(parallel=True, cache=True, fastmath=True)
def evaluate(ref, srcs, dims, kinv, A, b, src_depth, M, c, geo_weight, geo_max, window,
             spread, sigma_color, min_var, top_k, views_mode, depth, normal, cost, views):
    """The cost of every pixel's current hypothesis (after initialise or upsample).

    ``views_mode`` ALL_VIEWS: over all sources, and the view masks are reset to all sources;
    SELECT_VIEWS: over all sources, then each mask becomes the pixel's top_k best sources for this
    hypothesis (later sweeps match the pixel against those only); KEEP_VIEWS: over each pixel's mask;
    KEEP_AND_CONFIRMING (with ``src_depth``): over each pixel's mask and the source whose depth map best
    confirms the hypothesis (:func:`_confirming_source`), then the mask becomes the top_k best of those;
    NARROW_VIEWS: over each pixel's mask, then the mask becomes its top_k best.
    """
    height, width = ref.shape
    n = window[2] * window[2]
    everything = (1 << A.shape[0]) - 1
    for y in prange(height):
        weights = np.empty(n)
        centred = np.empty(n)
        costs = np.empty(A.shape[0])
        scratch = np.empty(A.shape[0])
        for x in range(width):
            if views_mode == ALL_VIEWS or views_mode == SELECT_VIEWS:
                views[y, x] = everything
            ref_var = reference_patch(ref, x, y, window, spread, sigma_color, weights, centred)
            if ref_var < min_var:
                cost[y, x] = MAX_COST + geo_weight * geo_max
                continue
            if views_mode == KEEP_AND_CONFIRMING:
                s = _confirming_source(kinv, A, b, dims, src_depth, M, c, geo_max, x, y, depth[y, x],
                                       normal[y, x, 0], normal[y, x, 1], normal[y, x, 2])
                if s >= 0:
                    views[y, x] |= 1 << s
            cost[y, x] = hypothesis_cost(x, y, depth[y, x], normal[y, x, 0], normal[y, x, 1],
                                         normal[y, x, 2], views[y, x], weights, centred, ref_var, window,
                                         kinv, A, b, srcs, dims, src_depth, M, c, geo_weight, geo_max,
                                         top_k, min_var, costs, scratch)
            if views_mode != ALL_VIEWS and views_mode != KEEP_VIEWS:
                views[y, x] = _best_views(costs, views[y, x], top_k)


@njit(cache=True, fastmath=True)
def _best_in_region(cost, x, y, region_offsets, r, count):
    """The in-image neighbour of region r with the lowest current cost (-1, -1 if none)."""
    height, width = cost.shape
    best = np.inf
    bx = -1
    by = -1
    for i in range(count):
        xx = x + region_offsets[r, i, 0]
        yy = y + region_offsets[r, i, 1]
        if xx >= 0 and yy >= 0 and xx < width and yy < height and cost[yy, xx] < best:
            best = cost[yy, xx]
            bx = xx
            by = yy
    return bx, by


@njit(cache=True, fastmath=True)
def _same_plane(d, n0, n1, n2, bd, b0, b1, b2):
    return abs(d - bd) <= 1e-6 * bd and n0 == b0 and n1 == b1 and n2 == b2


@njit(cache=True, fastmath=True)
def _tested_before(tested, n_tested, d, n0, n1, n2):
    """Whether the plane is one of the first ``n_tested`` rows of ``tested`` (depth, normal)."""
    for i in range(n_tested):
        if _same_plane(d, n0, n1, n2, tested[i, 0], tested[i, 1], tested[i, 2], tested[i, 3]):
            return True
    return False


@njit(parallel=True, cache=True, fastmath=True)
def propagate_and_refine(colour, ref, srcs, dims, kinv, A, b, src_depth, M, c, geo_weight, geo_max,
                         window, spread, sigma_color, min_var, top_k, depth, normal, cost, views,
                         dmin, dmax, perturbation, random_candidates, key, region_offsets, region_counts,
                         n_regions, normals):
    """One half sweep: every pixel of ``colour`` ((x + y) % 2) tests the planes of the best
    neighbours of the first ``n_regions`` regions (propagation), then perturbed and, with
    ``random_candidates``, random planes, then its best plane turned to each of ``normals`` (K, 3;
    reference camera frame) that faces the camera (refinement), keeping the cheapest. Each pixel is matched
    against the sources of its view mask; a neighbour's plane also against the neighbour's, and where
    it wins, the pixel's mask becomes the best top_k of the two masks' sources.

    A pixel's mask is chosen once per level, for its upsampled plane (:func:`evaluate`). Where that
    plane is wrong, the chosen source may not see the pixel's surface at all (a walk round a building:
    ground two photos share), and the right plane a neighbour holds, judged by that source alone, loses.
    Carried with the plane, the neighbour's source judges it as it judged it at the neighbour."""
    height, width = ref.shape
    n = window[2] * window[2]
    for y in prange(height):
        weights = np.empty(n)
        centred = np.empty(n)
        costs = np.empty(A.shape[0])
        scratch = np.empty(A.shape[0])
        tested = np.empty((n_regions, 4))  # (depth, normal) of the neighbours' planes tested at the pixel
        for x in range((y + colour) % 2, width, 2):
            ref_var = reference_patch(ref, x, y, window, spread, sigma_color, weights, centred)
            if ref_var < min_var:
                continue
            n_tested = 0
            mask = views[y, x]
            best = cost[y, x]
            bd = depth[y, x]
            b0 = normal[y, x, 0]
            b1 = normal[y, x, 1]
            b2 = normal[y, x, 2]
            # propagation
            for r in range(n_regions):
                xn, yn = _best_in_region(cost, x, y, region_offsets, r, region_counts[r])
                if xn < 0:
                    continue
                n0 = normal[yn, xn, 0]
                n1 = normal[yn, xn, 1]
                n2 = normal[yn, xn, 2]
                d = _plane_depth_at(kinv, depth[yn, xn], n0, n1, n2, xn, yn, x, y)
                if d < dmin or d > dmax or _same_plane(d, n0, n1, n2, bd, b0, b1, b2):
                    continue
                if _tested_before(tested, n_tested, d, n0, n1, n2):  # it lost then, it would lose now
                    continue
                tested[n_tested, 0] = d
                tested[n_tested, 1] = n0
                tested[n_tested, 2] = n1
                tested[n_tested, 3] = n2
                n_tested += 1
                with_views = mask | views[yn, xn]  # the neighbour's sources come with its plane
                h = hypothesis_cost(x, y, d, n0, n1, n2, with_views, weights, centred, ref_var, window,
                                    kinv, A, b, srcs, dims, src_depth, M, c, geo_weight, geo_max, top_k,
                                    min_var, costs, scratch, best)
                if h < best:
                    best = h
                    bd = d
                    b0 = n0
                    b1 = n1
                    b2 = n2
                    if with_views != mask:
                        mask = _best_views(costs, with_views, top_k)
            # refinement around the best plane found so far
            pk = _hash32(key ^ _hash32(y * width + x))
            rx, ry, rz = _ray(kinv, x, y)
            dp = bd * (1.0 + perturbation * (2.0 * _uniform(pk, 0) - 1.0))
            p0, p1, p2 = _perturbed_normal(b0, b1, b2, rx, ry, rz, perturbation * math.pi,
                                           _uniform(pk, 1), _uniform(pk, 2), _uniform(pk, 3))
            dr = _random_depth(dmin, dmax, _uniform(pk, 4))
            r0, r1, r2 = _random_normal(rx, ry, rz, _uniform(pk, 5), _uniform(pk, 6))
            n_candidates = 6 if random_candidates else 3
            d0 = bd
            c0 = b0
            c1 = b1
            c2 = b2
            for i in range(n_candidates + normals.shape[0]):
                if i >= n_candidates:  # the best plane so far, turned to a known normal facing the camera
                    k = i - n_candidates
                    d, n0, n1, n2 = bd, normals[k, 0], normals[k, 1], normals[k, 2]
                    if n0 * rx + n1 * ry + n2 * rz >= 0.0:
                        continue
                elif i == 0:  # perturbed depth, same normal
                    d, n0, n1, n2 = dp, c0, c1, c2
                elif i == 1:  # same depth, perturbed normal
                    d, n0, n1, n2 = d0, p0, p1, p2
                elif i == 2:  # both perturbed
                    d, n0, n1, n2 = dp, p0, p1, p2
                elif i == 3:  # random depth
                    d, n0, n1, n2 = dr, c0, c1, c2
                elif i == 4:  # random normal
                    d, n0, n1, n2 = d0, r0, r1, r2
                else:  # both random
                    d, n0, n1, n2 = dr, r0, r1, r2
                if d < dmin or d > dmax:
                    continue
                h = hypothesis_cost(x, y, d, n0, n1, n2, mask, weights, centred, ref_var, window, kinv,
                                    A, b, srcs, dims, src_depth, M, c, geo_weight, geo_max, top_k,
                                    min_var, costs, scratch, best)
                if h < best:
                    best = h
                    bd = d
                    b0 = n0
                    b1 = n1
                    b2 = n2
            depth[y, x] = bd
            normal[y, x, 0] = b0
            normal[y, x, 1] = b1
            normal[y, x, 2] = b2
            cost[y, x] = best
            views[y, x] = mask


@njit(parallel=True, cache=True, fastmath=True)
def consistent_views(depth, normal, kinv, A, b, src_depth, dims, M, c, max_reprojection, max_depth_error,
                     grazing_allowance):
    """Per pixel, how many source depth maps agree with its depth: the point projects into the
    source where the source's surface point lies within ``max_depth_error`` (relative to the source
    depth) of the pixel's plane, and maps back to within ``max_reprojection`` px of the pixel.

    The distance is measured across the plane (``normal``, reference camera frame), not along the
    source's ray: on a surface seen at a grazing angle, neighbouring pixels' rays meet it far apart
    and their depths differ by several per cent per pixel, so a depth difference of ``max_depth_error``
    along the ray rejects estimates that lie on the surface. The difference along the ray is
    multiplied by the cosine between the plane's normal and the source's ray, floored at
    1 / ``grazing_allowance`` (1: the plain relative depth difference), so that an uncertain normal
    widens the test by that factor at most. A plain ``max_depth_error`` where ``normal`` is zero."""
    height, width = depth.shape
    count = np.zeros((height, width), np.int32)
    least_cos = 1.0 / grazing_allowance
    for y in prange(height):
        for x in range(width):
            d = depth[y, x]
            if not d > 0.0:
                continue
            px = x + 0.5
            py = y + 0.5
            n0, n1, n2 = normal[y, x, 0], normal[y, x, 1], normal[y, x, 2]
            oriented = n0 != 0.0 or n1 != 0.0 or n2 != 0.0  # a plane to measure across
            for s in range(A.shape[0]):
                hz = d * (A[s, 2, 0] * px + A[s, 2, 1] * py + A[s, 2, 2]) + b[s, 2]
                if hz <= 0.0:
                    continue
                u = (d * (A[s, 0, 0] * px + A[s, 0, 1] * py + A[s, 0, 2]) + b[s, 0]) / hz
                v = (d * (A[s, 1, 0] * px + A[s, 1, 1] * py + A[s, 1, 2]) + b[s, 1]) / hz
                if not (u >= 0.0 and v >= 0.0 and u < dims[s, 0] and v < dims[s, 1]):
                    continue
                z = src_depth[s, int(v), int(u)]
                if not z > 0.0:
                    continue
                across = 1.0  # the share of the depth difference that lies across the plane
                if oriented:
                    r0, r1, r2 = _ray_of(kinv, M, s, u, v)
                    across = max(abs(n0 * r0 + n1 * r1 + n2 * r2) / math.sqrt(r0 * r0 + r1 * r1 + r2 * r2),
                                 least_cos)
                if abs(hz - z) * across > max_depth_error * z:
                    continue
                if _reprojection_error(src_depth, s, u, v, px, py, M, c) <= max_reprojection:
                    count[y, x] += 1
    return count


@njit(cache=True, fastmath=True)
def _ray_of(kinv, M, s, u, v):
    """Direction, in the reference camera frame, of source ``s``'s ray through its pixel (u, v)."""
    m0 = M[s, 0, 0] * u + M[s, 0, 1] * v + M[s, 0, 2]
    m1 = M[s, 1, 0] * u + M[s, 1, 1] * v + M[s, 1, 2]
    m2 = M[s, 2, 0] * u + M[s, 2, 1] * v + M[s, 2, 2]
    return (kinv[0, 0] * m0 + kinv[0, 1] * m1 + kinv[0, 2] * m2,
            kinv[1, 0] * m0 + kinv[1, 1] * m1 + kinv[1, 2] * m2,
            kinv[2, 0] * m0 + kinv[2, 1] * m1 + kinv[2, 2] * m2)


# --- drivers over a pyramid ---------------------------------------------------------------------

@dataclass
class Level:
    """The reference and source images of one pyramid level, with their geometry."""

    ref: np.ndarray
    srcs: np.ndarray
    dims: np.ndarray
    geometry: ViewGeometry
    _spreads: dict = field(default_factory=dict, repr=False)

    def spread(self, options: MVSOptions) -> np.ndarray:
        """The reference's :func:`matching_spread` under ``options``, computed once."""
        if options not in self._spreads:
            self._spreads[options] = matching_spread(self.ref, options)
        return self._spreads[options]


def make_level(ref: np.ndarray, srcs: list[np.ndarray], ref_cam: Camera, src_cams: list[Camera],
               scale: float = 1.0) -> Level:
    """A level at ``scale`` of the given images (area-resampled) and cameras."""
    def resized(im: np.ndarray) -> np.ndarray:
        if scale == 1.0:
            return np.ascontiguousarray(im, dtype=np.float32)
        size = (max(1, round(im.shape[1] * scale)), max(1, round(im.shape[0] * scale)))
        return cv2.resize(im, size, interpolation=cv2.INTER_AREA).astype(np.float32)

    def cam(im: np.ndarray, small: np.ndarray, camera: Camera) -> Camera:
        return camera.scaled(small.shape[1] / im.shape[1], small.shape[0] / im.shape[0])

    ref_small = resized(ref)
    src_small = [resized(im) for im in srcs]
    stack, dims = stack_images(src_small)
    geometry = view_geometry(cam(ref, ref_small, ref_cam),
                             [cam(im, sm, cm) for im, sm, cm in zip(srcs, src_small, src_cams)])
    return Level(ref_small, stack, dims, geometry)


@dataclass
class State:
    """Per-pixel plane hypotheses, their costs and the bit masks of the sources each pixel uses."""

    depth: np.ndarray
    normal: np.ndarray
    cost: np.ndarray
    views: np.ndarray

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> State:
        return cls(np.zeros(shape, np.float32), np.zeros(shape + (3,), np.float32),
                   np.zeros(shape, np.float32), np.zeros(shape, np.int64))


def _kernel_params(options: MVSOptions) -> tuple:
    window = window_grid(options.window_radius, options.window_step)
    sigma_spatial = options.sigma_spatial or float(options.window_radius)
    return window, sigma_spatial, options.sigma_color, options.min_texture ** 2, options.top_k


def _geo_args(level: Level, src_depth: np.ndarray | None, options: MVSOptions) -> tuple:
    if src_depth is None:
        return np.zeros((level.geometry.A.shape[0], 1, 1), np.float32), 0.0, options.geometric_max_error
    return src_depth, options.geometric_weight, options.geometric_max_error


def evaluate_state(level: Level, state: State, options: MVSOptions, views_mode: int,
                   src_depth: np.ndarray | None = None) -> None:
    """Recompute the costs of the current hypotheses (photometric, or with the geometric term when
    ``src_depth`` is given); ``views_mode`` as in :func:`evaluate`."""
    g = level.geometry
    window, _, sc, min_var, top_k = _kernel_params(options)
    depth_maps, weight, cap = _geo_args(level, src_depth, options)
    evaluate(level.ref, level.srcs, level.dims, g.kinv, g.A, g.b, depth_maps, g.M, g.c, weight, cap,
             window, level.spread(options), sc, min_var, top_k, views_mode, state.depth, state.normal, state.cost,
             state.views)


def sweeps(level: Level, state: State, options: MVSOptions, depth_range: tuple[float, float],
           iterations: int, perturbation: float, random_candidates: bool, far_regions: bool, seed: int,
           first_sweep: int, src_depth: np.ndarray | None = None, normals: np.ndarray = NO_NORMALS) -> None:
    """Run ``iterations`` red-black sweeps of propagation and refinement on ``state``; the
    perturbation halves every sweep. ``far_regions`` adds the four far strips to the four near
    regions of the propagation; each pixel also tests its plane turned to each of ``normals`` (K, 3;
    reference camera frame)."""
    g = level.geometry
    window, _, sc, min_var, top_k = _kernel_params(options)
    spread = level.spread(options)
    depth_maps, weight, cap = _geo_args(level, src_depth, options)
    for it in range(iterations):
        for colour in (0, 1):
            key = sweep_key(seed, 2 * (first_sweep + it) + colour)
            propagate_and_refine(colour, level.ref, level.srcs, level.dims, g.kinv, g.A, g.b,
                                 depth_maps, g.M, g.c, weight, cap, window, spread, sc, min_var, top_k,
                                 state.depth, state.normal, state.cost, state.views, depth_range[0],
                                 depth_range[1], perturbation * 0.5 ** it, random_candidates, key,
                                 REGION_OFFSETS, REGION_COUNTS, 8 if far_regions else 4, normals)


def pyramid_levels(shape: tuple[int, int], options: MVSOptions) -> int:
    """Number of levels for an image of ``shape``: at most ``pyramid_levels``, the coarsest keeping
    its longest side >= ``pyramid_min_size``."""
    levels = 1
    while levels < options.pyramid_levels and max(shape) * 0.5 ** levels >= options.pyramid_min_size:
        levels += 1
    return levels


def photometric_depth(ref: np.ndarray, srcs: list[np.ndarray], ref_cam: Camera, src_cams: list[Camera],
                      depth_range: tuple[float, float], options: MVSOptions, seed: int,
                      ground: np.ndarray | None = None) -> State:
    """Photometric PatchMatch, coarse to fine, for a float32 [0, 1] grey reference image.

    The coarsest level starts from random planes and matches every pixel against all sources, with
    random refinement candidates; each finer level starts from the coarser planes and (with
    ``options.view_subset``) matches each pixel against its top_k sources only, chosen among those of
    the nearest coarse pixels (:func:`upsample`): the level under the coarsest chooses among all, as
    the coarsest keeps all, and the finer ones spare matching every source at every pixel (on
    fountain-P11 at 1536 px, 0.79 of the pass's CPU: docs/DECISIONS.md, session 52). The finest level
    propagates from the near regions only. With ``ground`` (the ground's unit normal, world frame;
    :mod:`recon.mvs.ground_normal`), every level's refinement also tests each pixel's plane turned to it.
    """
    normals = NO_NORMALS if ground is None else np.array([ref_cam.R @ ground, -(ref_cam.R @ ground)])
    sweep = 0
    state = None
    previous = None
    for lvl in reversed(range(pyramid_levels(ref.shape, options))):
        start, cpu = time.perf_counter(), time.process_time()
        level = make_level(ref, srcs, ref_cam, src_cams, 0.5 ** lvl)
        fresh = State.empty(level.ref.shape)
        if state is None:
            initialise(fresh.depth, fresh.normal, level.geometry.kinv, depth_range[0], depth_range[1],
                       sweep_key(seed, 0x7FFFF))
            iterations, perturbation = options.iterations, options.perturbation
        else:
            upsample(state.depth, state.normal, state.views, previous.geometry.kinv, level.geometry.kinv,
                     fresh.depth, fresh.normal, fresh.views)
            iterations = options.fine_iterations if lvl == 0 else options.upper_iterations
            perturbation = options.perturbation * 0.25
        subset = state is not None and options.view_subset
        evaluate_state(level, fresh, options, NARROW_VIEWS if subset else ALL_VIEWS)
        sweeps(level, fresh, options, depth_range, iterations, perturbation,
               random_candidates=state is None, far_regions=lvl > 0, seed=seed, first_sweep=sweep,
               normals=normals)
        sweep += iterations
        state, previous = fresh, level
        log.debug("level %d (%dx%d): %d sweeps in %.2f s (%.2f s CPU)", lvl, level.ref.shape[1],
                  level.ref.shape[0], iterations, time.perf_counter() - start, time.process_time() - cpu)
    return state


@dataclass(frozen=True)
class Checked:
    """A view at full resolution with its sources' depth maps: what the geometric pass and filtering
    both read, built once for the two."""

    level: Level
    src_depth: np.ndarray  # (S, H, W) stack of the sources' photometric depth maps
    depth_dims: np.ndarray  # (S, 2) width and height of each


def checked(ref: np.ndarray, srcs: list[np.ndarray], ref_cam: Camera, src_cams: list[Camera],
            src_depths: list[np.ndarray]) -> Checked:
    """The full-resolution level of ``ref`` and its sources, and the sources' depth maps (each the size
    of its source image)."""
    return Checked(make_level(ref, srcs, ref_cam, src_cams), *stack_images(src_depths))


def geometric_depth(view: Checked, initial: State, depth_range: tuple[float, float], options: MVSOptions,
                    seed: int, keep_views: bool = False) -> State:
    """Geometric-consistency pass: sweeps whose cost adds the reprojection error through the source
    depth maps, starting from the photometric ``initial``. The returned state's costs are the
    photometric part alone, the matching cost :func:`filter_depth` tests.

    With ``options.view_subset`` and ``keep_views``, each pixel chooses its top_k among the sources of
    its mask in ``initial.views`` (the photometric pass's choice) and the source whose depth map best
    confirms its plane; without ``keep_views``, among all sources, which matches every source's window
    at every pixel. On fountain-P11 at 1536 px the pass takes 0.81 of the CPU with ``keep_views`` (0.70
    with the photometric choice alone, which lost more quality on the zoo's worst scenes:
    docs/DECISIONS.md, session 51)."""
    level, src_depth = view.level, view.src_depth
    state = State(initial.depth.copy(), initial.normal.copy(), np.zeros_like(initial.cost),
                  initial.views.copy() if keep_views else np.zeros_like(initial.depth, dtype=np.int64))
    mode = (KEEP_AND_CONFIRMING if keep_views else SELECT_VIEWS) if options.view_subset else ALL_VIEWS
    evaluate_state(level, state, options, mode, src_depth)
    sweeps(level, state, options, depth_range, options.geometric_iterations,
           options.perturbation * 0.125, random_candidates=False, far_regions=False, seed=seed,
           first_sweep=1000, src_depth=src_depth)
    if options.view_subset:
        g = level.geometry
        remove_geometric_term(level.dims, g.kinv, g.A, g.b, src_depth, g.M, g.c, options.geometric_weight,
                              options.geometric_max_error, state.depth, state.normal, state.views, state.cost)
    else:  # each pixel's cost is the mean of its best top_k among all sources: match again
        evaluate_state(level, state, options, KEEP_VIEWS)
    return state


def photometric_costs(view: Checked, state: State, options: MVSOptions) -> State:
    """``state`` with the photometric costs of its hypotheses over its view masks (for
    :func:`filter_depth` when no geometric pass ran)."""
    photometric = State(state.depth, state.normal, np.zeros_like(state.cost), state.views.copy())
    evaluate_state(view.level, photometric, options, KEEP_VIEWS)
    return photometric


#: :func:`own_texture` judges a pixel's own side only where it holds at least this share of the window's
#: spatial weight; a pixel that few samples resemble (a texture's peak, an edge's blended pixel) varies
#: at its own scale and counts as textured
OWN_SIDE_MIN_SHARE = 0.25


@njit(parallel=True, cache=True, fastmath=True)
def own_texture(ref, window, sigma_spatial, sigma_color, out):
    """Per pixel, the bilateral-weighted intensity standard deviation over the window's samples within
    ``sigma_color / 2`` of the pixel's own intensity (into ``out``; 1, above any standard deviation of
    intensities in [0, 1], where those samples hold less than :data:`OWN_SIDE_MIN_SHARE` of the window's
    spatial weight).

    The matching cost's bilateral weights keep samples of another colour small but not zero, and where
    the pixel's own side of an edge is uniform its whole correlation comes from the other side: a sky
    pixel beside a pole matches at the pole's depth in every view. Counting only the pixel's own side
    tells it apart from a textured one."""
    height, width = ref.shape
    start, step, count = window[0], window[1], window[2]
    inv_s = 0.5 / (sigma_spatial * sigma_spatial)
    near = np.empty(count * count)  # the samples' spatial weights, the same around every pixel
    spatial = 0.0
    for j in range(count):
        for i in range(count):
            dy, dx = start + j * step, start + i * step
            near[j * count + i] = math.exp(-(dx * dx + dy * dy) * inv_s)
            spatial += near[j * count + i]
    least_own = OWN_SIDE_MIN_SHARE * spatial
    inv_c = 0.5 / (sigma_color * sigma_color)
    cut = 0.5 * sigma_color
    for y in prange(height):
        for x in range(width):
            centre = ref[y, x]
            own = 0.0
            total = 0.0
            mean = 0.0
            square = 0.0
            for j in range(count):
                yy = min(max(y + start + j * step, 0), height - 1)
                for i in range(count):
                    value = ref[yy, min(max(x + start + i * step, 0), width - 1)]
                    diff = value - centre
                    if abs(diff) > cut:
                        continue
                    own += near[j * count + i]
                    w = near[j * count + i] * math.exp(-diff * diff * inv_c)
                    total += w
                    mean += w * value
                    square += w * value * value
            if own < least_own:
                out[y, x] = 1.0
            else:
                mean /= total
                out[y, x] = math.sqrt(max(square / total - mean * mean, 0.0))


#: The Laplacian-like mask of Immerkaer's noise estimate (1996): it cancels any intensity ramp, and a
#: pixel's noise of standard deviation sigma gives it a standard deviation of 6 sigma
NOISE_MASK = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)


def noise_sigma(ref: np.ndarray) -> float:
    """The standard deviation of a grey image's pixel noise: the median absolute response to
    :data:`NOISE_MASK`, which texture and edges raise at few pixels, taken as a normal variable's."""
    response = cv2.filter2D(np.asarray(ref, np.float32), -1, NOISE_MASK)[1:-1, 1:-1]
    return float(np.median(np.abs(response))) / (0.6745 * 6.0)


@njit(parallel=True, cache=True, fastmath=True)
def _narrowed(ref, window, wide, narrow, sigma_color, min_var, out):
    """``out``: ``narrow`` where the window weighted with it has a variance of at least ``min_var`` and
    of at least half the variance it has weighted with ``wide``, else ``wide``."""
    n = window[2] * window[2]
    for y in prange(ref.shape[0]):
        weights = np.empty(n)
        centred = np.empty(n)
        for x in range(ref.shape[1]):
            out[y, x] = wide
            full = reference_patch(ref, x, y, window, out, sigma_color, weights, centred)
            out[y, x] = narrow
            if reference_patch(ref, x, y, window, out, sigma_color, weights, centred) < max(min_var, 0.5 * full):
                out[y, x] = wide


def matching_spread(ref: np.ndarray, options: MVSOptions) -> np.ndarray:
    """Per pixel of the grey ``ref``, 1 / (2 sigma^2) of its matching window's spatial weight: sigma
    ``options.narrow_sigma`` where the window's intensities, so weighted, vary by at least
    ``options.narrow_snr`` times the image's noise (:func:`noise_sigma`) and keep at least half the
    variance they have with the full weight, else ``sigma_spatial`` (the window radius).

    A plane fitted over a window lies behind a convex surface by about half its curvature times the
    window's weighted second moment (9.8 px^2 per axis for the default 11 x 11 window read every second
    pixel; 3.9 at sigma 2). Where the narrower weight still holds texture well above the noise (at
    ``narrow_snr`` 3, the noise alone costs a correlation of about 0.1), it matches as surely as the full
    window and leans less; elsewhere the full window's samples average the noise out. Where the texture
    lies at the window's edge (the rim of a flat region), the narrower weight would keep little of it,
    and resampling the sources' windows would disturb the match more than that texture decides it: the
    full weight stays."""
    window, wide, sigma_color, _, _ = _kernel_params(options)
    out = np.empty(ref.shape, np.float64)
    if options.narrow_sigma <= 0:
        out[:] = 0.5 / (wide * wide)
        return out
    floor = (options.narrow_snr * noise_sigma(ref)) ** 2
    _narrowed(ref, window, 0.5 / (wide * wide), 0.5 / options.narrow_sigma ** 2, sigma_color,
              max(floor, options.min_texture ** 2), out)
    return out


def untextured(ref: np.ndarray, options: MVSOptions) -> np.ndarray:
    """Where the pixel's own side of its window is untextured (:func:`own_texture` below
    ``min_texture``): no depth is kept there, and :mod:`recon.mvs.planar_fill` fills such regions."""
    window, sigma_spatial, sigma_color, _, _ = _kernel_params(options)
    texture = np.empty(ref.shape, np.float64)
    own_texture(ref, window, sigma_spatial, sigma_color, texture)
    return texture < options.min_texture


def filter_depth(view: Checked, state: State, options: MVSOptions, blank: np.ndarray | None = None) -> State:
    """Zero the pixels whose photometric cost over the sources that see them (:func:`seen_cost` of
    ``state.cost``, as :func:`geometric_depth` and :func:`photometric_costs` give it) is high, that
    fewer than ``filter_min_consistent`` source depth maps confirm unless that cost is at most
    ``filter_unconfirmed_cost``, or whose own side of the window is untextured (:func:`untextured`, or
    ``blank`` where the caller computed it already)."""
    level = view.level
    g = level.geometry
    count = consistent_views(state.depth, state.normal, g.kinv, g.A, g.b, view.src_depth, view.depth_dims, g.M, g.c,
                             options.filter_max_reprojection, options.filter_max_depth_error,
                             options.filter_grazing_allowance)
    cost = np.empty_like(state.cost)
    seen_cost(state.depth, state.normal, g.kinv, g.A, g.b, level.dims, state.views, state.cost, options.top_k, cost)
    confirmed = (count >= options.filter_min_consistent) | (cost <= options.filter_unconfirmed_cost)
    keep = (cost <= options.filter_max_cost) & confirmed
    keep &= state.depth > 0
    if options.min_texture > 0:
        keep &= ~(untextured(level.ref, options) if blank is None else blank)
    return State(np.where(keep, state.depth, 0).astype(np.float32),
                 np.where(keep[..., None], state.normal, 0).astype(np.float32),
                 np.where(keep, cost, MAX_COST).astype(np.float32), state.views)
