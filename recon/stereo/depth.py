"""Two-view depth: rectify, match both ways, keep consistent disparities, depth = f B / d, and the
depth expressed per pixel of the LEFT photo (unrectified, at the working size) as camera z.

The left photo's pixel (col, row) looks along the ray through (col + 0.5, row + 0.5) (COLMAP's
convention, distortion undone); that ray meets the rectified left image at a point where the
disparity is read (bilinear where the four neighbours agree within 1 px, else the nearest one), so
the depth map lines up pixel for pixel with any other depth map of that photo at that size.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from recon.geometry.transforms import apply_matrix
from recon.imaging.intrinsics import Intrinsics
from recon.stereo.calibration import StereoCalibration
from recon.stereo.disparity import consistent_disparity, search_range
from recon.stereo.options import StereoOptions
from recon.stereo.rectify import Rectification, disparity_bounds, rectify

log = logging.getLogger(__name__)

#: neighbours further apart than this (px of disparity) are not interpolated between (a depth edge)
INTERPOLATION_STEP = 1.0


@dataclass
class StereoDepth:
    """Depth of the left photo at the working size and what produced it.

    ``depth``: H x W float32 camera z of the left camera (0 = none); ``image``: the left photo at that
    size (uint8 RGB); ``camera``: its intrinsics (COLMAP convention); ``figures``: sizes, disparity
    range, pixel counts and seconds per step.
    """

    depth: np.ndarray
    image: np.ndarray
    camera: Intrinsics
    figures: dict = field(default_factory=dict)

    @property
    def coverage(self) -> float:
        """Share of the left photo's pixels with a depth."""
        return float(np.count_nonzero(self.depth) / self.depth.size)


def working_scale(calib: StereoCalibration, max_image_size: int) -> float:
    """Resize factor of both photos: the left photo's longest side down to ``max_image_size`` (0 = 1)."""
    longest = max(calib.left.width, calib.left.height)
    return 1.0 if not max_image_size or longest <= max_image_size else max_image_size / longest


def _resize(image: np.ndarray, cam: Intrinsics) -> np.ndarray:
    if image.shape[:2] == (cam.height, cam.width):
        return image
    return cv2.resize(image, (cam.width, cam.height), interpolation=cv2.INTER_AREA)


def stereo_depth(left: np.ndarray, right: np.ndarray, calib: StereoCalibration,
                 options: StereoOptions = StereoOptions(),
                 depth_range: tuple[float, float] | None = None) -> StereoDepth:
    """Depth of the ``left`` photo (uint8 RGB at ``calib.left``'s size) from the pair with ``right``.

    The disparities searched come from, in this order: ``options.num_disparities`` (with
    ``min_disparity``), ``options.depth_min``/``depth_max`` when both are set, ``depth_range``
    (left-camera z, e.g. from sparse points), or 0 to a quarter of the image width.
    """
    for image, cam, side in ((left, calib.left, "left"), (right, calib.right, "right")):
        if image.shape[:2] != (cam.height, cam.width):
            raise ValueError(f"the {side} photo is {image.shape[1]}x{image.shape[0]}, its calibration "
                             f"{cam.width}x{cam.height}")
    times = {}
    start = time.perf_counter()
    scale = working_scale(calib, options.max_image_size)
    if scale < 1.0:
        calib = calib.scaled(scale)
        left, right = _resize(left, calib.left), _resize(right, calib.right)
    rect = rectify(calib)
    if (options.depth_min > 0) != (options.depth_max > 0):
        raise ValueError("depth_min and depth_max go together: set both, or neither")
    if options.depth_min > 0:
        depth_range = (options.depth_min, options.depth_max)
    if depth_range is not None and not 0 < depth_range[0] < depth_range[1]:
        raise ValueError(f"depth range {depth_range[0]:.4g}..{depth_range[1]:.4g} is empty or not positive")
    bounds = disparity_bounds(rect, calib, *depth_range) if depth_range is not None else None
    if options.num_disparities or bounds is not None:
        rect = rect.aligned(calib, options.min_disparity if options.num_disparities else bounds[0])
    rect_left, rect_right = rect.rectify_left(left), rect.rectify_right(right)
    times["rectify"] = time.perf_counter() - start
    match_left, match_right = rect.to_matching(rect_left), rect.to_matching(rect_right)
    low, count = search_range(bounds, rect.offset, match_left.shape[1], options)

    start = time.perf_counter()
    disparity, counts = consistent_disparity(match_left, match_right, options, low, count)
    disparity = _inside_both(disparity, rect, calib, options.block_size // 2)
    if options.min_texture > 0:
        disparity[~textured(match_left, options.block_size, options.min_texture)] = np.nan
    times["match"] = time.perf_counter() - start

    start = time.perf_counter()
    depth = left_depth(disparity, rect, calib.left)
    times["depth"] = time.perf_counter() - start
    figures = {
        "size": f"{calib.left.width}x{calib.left.height}",
        "rectified_size": f"{rect.size[0]}x{rect.size[1]}",
        "stereo": "vertical" if rect.vertical else "horizontal",
        "focal_px": round(rect.focal, 2), "baseline": float(f"{rect.baseline:.6g}"),
        "disparities": [low, low + count], "disparity_offset": round(rect.offset, 2),
        "depth_range": [float(f"{v:.6g}") for v in depth_range] if depth_range is not None else None,
        "matched_pixels": counts["matched"], "consistent_pixels": counts["consistent"],
        "depth_pixels": int(np.count_nonzero(depth)),
        "coverage": round(float(np.count_nonzero(depth) / depth.size), 4),
        "seconds": {k: round(v, 3) for k, v in times.items()},
    }
    log.info("stereo depth %s: %.1f%% of pixels (rectify %.1f s, match %.1f s, depth %.1f s)", figures["size"],
             100 * figures["coverage"], times["rectify"], times["match"], times["depth"])
    return StereoDepth(depth, left, calib.left, figures)


def _inside_both(disparity: np.ndarray, rect: Rectification, calib: StereoCalibration, margin: int) -> np.ndarray:
    """Drop disparities whose left pixel or right match falls outside the photos in the rectified
    images (or within ``margin`` px of their edges): there SGBM matched the black borders."""
    def inside(warp, cam: Intrinsics) -> np.ndarray:
        mask = warp(np.full((cam.height, cam.width), 255, np.uint8)) == 255
        if margin:
            mask = cv2.erode(mask.astype(np.uint8), np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)) > 0
        return rect.to_matching(mask)

    left_in, right_in = inside(rect.rectify_left, calib.left), inside(rect.rectify_right, calib.right)
    h, w = disparity.shape
    match = np.rint(np.arange(w)[None, :] - np.nan_to_num(disparity, nan=-1e6)).astype(np.int64)
    ok = np.isfinite(disparity) & left_in & (match >= 0) & (match < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    ok[ok] = right_in[rows[ok], match[ok]]
    return np.where(ok, disparity, np.nan).astype(np.float32)


def textured(image: np.ndarray, block_size: int, min_std: float) -> np.ndarray:
    """Pixels whose grey level (0..1) has a standard deviation of at least ``min_std`` over the
    ``block_size`` square around them (at least 3 x 3)."""
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    grey = grey.astype(np.float32) / 255.0
    side = (max(3, block_size),) * 2
    mean = cv2.blur(grey, side)
    variance = cv2.blur(grey * grey, side) - mean * mean
    return variance >= min_std * min_std


def left_depth(disparity: np.ndarray, rect: Rectification, cam: Intrinsics) -> np.ndarray:
    """Camera z (float32, 0 = none) at each pixel of the left photo (intrinsics ``cam``) from the
    matching-frame ``disparity`` (NaN = none): z_rect = f B / (d - offset) on the pixel's ray, and as
    the ray is the same in both frames, z = z_rect / (R1 ray)_z for the ray with z = 1."""
    cols, rows = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    rays = cam.undistort_pixels(np.column_stack([cols.ravel(), rows.ravel()]))
    rays = apply_matrix(rect.R1, np.column_stack([rays, np.ones(len(rays))]))  # in the rectified frame
    pixels = apply_matrix(rect.P1[:, :3], rays)
    x, y = rect.matching_coords(pixels[:, 0] / pixels[:, 2], pixels[:, 1] / pixels[:, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        z = rect.depth_of(sample_disparity(disparity, x, y)) / rays[:, 2]
    z[~(np.isfinite(z) & (z > 0))] = 0.0
    return z.reshape(cam.height, cam.width).astype(np.float32)


def sample_disparity(disparity: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``disparity`` (NaN = none; pixel centres at integer coordinates) at points (x, y): bilinear
    where the four neighbours have a disparity within INTERPOLATION_STEP of each other, else the
    nearest pixel's; NaN outside."""
    h, w = disparity.shape
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    x0, y0 = x0.astype(np.int64), y0.astype(np.int64)
    corners = []
    for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1)):
        xi, yi = x0 + dx, y0 + dy
        ok = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        value = np.full(x.shape, np.nan, np.float64)
        value[ok] = disparity[yi[ok], xi[ok]]
        corners.append(value)
    d00, d01, d10, d11 = corners
    with np.errstate(invalid="ignore"):
        smooth = np.ptp(np.stack(corners), axis=0) <= INTERPOLATION_STEP  # False where any is NaN
    bilinear = (d00 * (1 - fx) + d01 * fx) * (1 - fy) + (d10 * (1 - fx) + d11 * fx) * fy
    nearest = np.select([(fy < 0.5) & (fx < 0.5), fy < 0.5, fx < 0.5], [d00, d01, d10], d11)
    return np.where(smooth, bilinear, nearest)
