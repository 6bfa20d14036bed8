"""Disparity of a rectified pair in the matching frame: OpenCV's StereoSGBM both ways and a left-right
consistency check done here (cv2.ximgproc, which has one, is not in opencv-python-headless).

The right view's disparity comes from SGBM on the mirrored pair (mirrored right image as the left
one): in the mirrored frame the right view's matches sit at x - d, as SGBM wants. Disparities are
SGBM's fixed-point values with 4 fractional bits (sub-pixel by a parabola through the costs).
"""

from __future__ import annotations

import logging
import math
import time

import cv2
import numpy as np

from recon.stereo.options import StereoOptions

log = logging.getLogger(__name__)

_MODES = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY,
          "hh": cv2.STEREO_SGBM_MODE_HH, "hh4": cv2.STEREO_SGBM_MODE_HH4}


def search_range(bounds: tuple[float, float] | None, offset: float, width: int,
                 options: StereoOptions) -> tuple[int, int]:
    """SGBM's (minDisparity, numDisparities) in the matching frame, whose disparities are f B / z +
    ``offset``: around the options' range when num_disparities is set, else ``bounds`` (lowest and
    highest f B / z), else 0 to a quarter of the ``width``; a pixel to spare each side, the count a
    multiple of 16 and at most the width."""
    if options.num_disparities:
        low, high = options.min_disparity, options.min_disparity + options.num_disparities
    elif bounds is not None:
        low, high = bounds
    else:
        low, high = 0, width / 4
    first = math.floor(low + offset) - 1
    count = 16 * max(1, math.ceil((math.ceil(high + offset) + 1 - first) / 16))
    cap = 16 * max(1, width // 16)
    if count > cap:
        log.warning("disparity search %d..%d px is wider than the image (%d px): cut to %d", first,
                    first + count, width, cap)
        count = cap
    return int(first), int(count)


def matcher(options: StereoOptions, min_disparity: int, num_disparities: int, channels: int):
    """The cv2.StereoSGBM object for these options (its own left-right check off: done here)."""
    area = channels * options.block_size ** 2
    p1 = options.p1 or 8 * area
    p2 = options.p2 or 32 * area
    if p2 <= p1:
        raise ValueError(f"p2 ({p2}) must exceed p1 ({p1})")
    return cv2.StereoSGBM.create(
        minDisparity=min_disparity, numDisparities=num_disparities, blockSize=options.block_size, P1=p1, P2=p2,
        disp12MaxDiff=-1, preFilterCap=options.pre_filter_cap, uniquenessRatio=options.uniqueness,
        speckleWindowSize=options.speckle_window, speckleRange=options.speckle_range, mode=_MODES[options.mode])


def sgbm(left: np.ndarray, right: np.ndarray, options: StereoOptions, min_disparity: int,
         num_disparities: int) -> np.ndarray:
    """Disparity (float32 px, NaN = none) of each left pixel, its match at x - d in ``right``.

    SGBM gives no disparity to the first minDisparity + numDisparities columns, even to pixels whose
    match is inside the image; both images are padded on the left by that many black columns so that
    every pixel is matched."""
    pad = max(0, min_disparity + num_disparities)
    channels = 1 if left.ndim == 2 else left.shape[2]
    left, right = (cv2.copyMakeBorder(im, 0, 0, pad, 0, cv2.BORDER_CONSTANT, value=0) for im in (left, right))
    raw = matcher(options, min_disparity, num_disparities, channels).compute(left, right)[:, pad:]
    disparity = raw.astype(np.float32) / cv2.StereoMatcher_DISP_SCALE
    disparity[raw < min_disparity * cv2.StereoMatcher_DISP_SCALE] = np.nan
    return disparity


def left_right_check(left_disp: np.ndarray, right_disp: np.ndarray, max_diff: float) -> np.ndarray:
    """Mask of the left pixels whose match x - d (rounded) has a right disparity within ``max_diff``."""
    h, w = left_disp.shape
    x = np.arange(w, dtype=np.float32)[None, :]
    match = np.rint(x - np.nan_to_num(left_disp, nan=-1e6)).astype(np.int64)
    inside = np.isfinite(left_disp) & (match >= 0) & (match < w)
    rows = np.broadcast_to(np.arange(h)[:, None], (h, w))
    back = np.full((h, w), np.nan, np.float32)
    back[inside] = right_disp[rows[inside], match[inside]]
    with np.errstate(invalid="ignore"):
        return inside & (np.abs(left_disp - back) <= max_diff)


def consistent_disparity(left: np.ndarray, right: np.ndarray, options: StereoOptions, min_disparity: int,
                         num_disparities: int) -> tuple[np.ndarray, dict]:
    """Left disparity (NaN = none) of a pair in the matching frame, kept where the left-right check
    passes; with counts: pixels SGBM matched and pixels the check kept."""
    start = time.perf_counter()
    left_disp = sgbm(left, right, options, min_disparity, num_disparities)
    mid = time.perf_counter()
    right_disp = sgbm(right[:, ::-1], left[:, ::-1], options, min_disparity, num_disparities)[:, ::-1]
    end = time.perf_counter()
    keep = left_right_check(left_disp, right_disp, options.lr_max_diff)
    matched = int(np.isfinite(left_disp).sum())
    log.info("SGBM %dx%d, disparities %d..%d: left %.1f s, right %.1f s; left-right check keeps %d of %d "
             "matched pixels", left.shape[1], left.shape[0], min_disparity, min_disparity + num_disparities,
             mid - start, end - mid, int(keep.sum()), matched)
    return np.where(keep, left_disp, np.nan).astype(np.float32), {
        "matched": matched, "consistent": int(keep.sum()), "sgbm_seconds": round(end - start, 3)}
