"""Options of the two-view stereo (rectification + semi-global matching)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from recon.options import opt


@dataclass(frozen=True)
class StereoOptions:
    """Disparity by OpenCV's StereoSGBM on the rectified pair, a left-right check, depth = f B / d."""

    max_image_size: int = opt(1536, "longest side of the left photo at which depth is computed (px); larger "
                                    "photos are downscaled with an area filter; 0 = full size", ge=0)
    depth_min: float = opt(0.0, "nearest depth searched (left camera z, in the unit of the cameras' "
                                "translation); 0 = from the sparse points when known", ge=0.0)
    depth_max: float = opt(0.0, "farthest depth searched; 0 = from the sparse points when known", ge=0.0)
    depth_margin: float = opt(0.25, "depth range from the sparse points: 1st percentile / (1 + margin) to "
                                    "the 99th x (1 + margin)", ge=0.0, le=4.0)
    min_disparity: int = opt(0, "smallest disparity f B / z searched (px at the working size) when "
                                "num_disparities is set", ge=0)
    num_disparities: int = opt(0, "disparities searched (px at the working size, rounded up to a multiple "
                                  "of 16); 0 = from the depth range, or a quarter of the image width "
                                  "when no depth range is known", ge=0)
    block_size: Literal[1, 3, 5, 7, 9, 11, 13, 15] = opt(5, "side of the matched block (px, odd)")
    p1: int = opt(0, "SGM penalty for a 1 px disparity change between neighbours; 0 = 8 x 3 x block_size^2",
                  ge=0)
    p2: int = opt(0, "SGM penalty for larger changes (must exceed p1); 0 = 32 x 3 x block_size^2", ge=0)
    uniqueness: int = opt(10, "the best matching cost must beat the second best by this percentage",
                          ge=0, le=100)
    speckle_window: int = opt(100, "disparity regions smaller than this (px) are removed as speckles; "
                                   "0 = no speckle filter", ge=0)
    speckle_range: int = opt(2, "largest disparity step (px) inside one speckle region", ge=1)
    pre_filter_cap: int = opt(63, "clip of the x-derivative prefilter (OpenCV's preFilterCap)", ge=1, le=63)
    min_texture: float = opt(0.003, "pixels whose grey level (0..1) varies less than this (standard deviation) "
                                   "over the block get no depth: blank sky and walls match anywhere", ge=0.0)
    lr_max_diff: float = opt(1.0, "left-right check: a pixel is kept when the right view's disparity at its "
                                  "match differs by at most this (px); 0 = exact agreement", ge=0.0)
    mode: Literal["sgbm", "3way", "hh", "hh4"] = opt(
        "sgbm", "SGBM variant: sgbm (5 paths, one pass), 3way (faster), hh (8 paths, full-size "
                "buffers: memory W x H x disparities), hh4")
