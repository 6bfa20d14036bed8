"""Rectification of a stereo pair and the "matching frame" SGBM works in.

cv2.stereoRectify gives the rotations ``R1``/``R2`` that make both image planes one plane with
epipolar lines along its rows (or columns, when the baseline is mostly vertical). The rectified
cameras get the left photo's focal length and the rectified images cover the left photo's footprint
(rows shared with the right photo's): no resolution is lost, and no pixel spent on the empty border
that OpenCV's ``alpha`` framing of both photos leaves between turned views. The right image is
shifted along the epipolar lines (:meth:`Rectification.aligned`) so that the scene's lowest
disparity is near 0: a point at depth z has disparity f B / z + ``offset``.

SGBM wants the match of left pixel x at x - d in the right image. The matching frame is the
rectified frame transposed when the stereo is vertical, then mirrored left-right when the right
camera sits on the left's left (its match is then at x + d): :meth:`Rectification.to_matching` and
:meth:`Rectification.from_matching` move arrays between the two frames.

Pixel coordinates of cv2 (here and in ``P1``/``P2``) put the top-left pixel's centre at (0, 0).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass

import cv2
import numpy as np

from recon.geometry.transforms import apply_matrix
from recon.imaging.intrinsics import Intrinsics
from recon.stereo.calibration import StereoCalibration

log = logging.getLogger(__name__)

#: the rectified images' longest side is at most this many times the left photo's
MAX_GROWTH = 2.0
#: fewest share of the baseline across the viewing direction for planar rectification
MIN_LATERAL = 0.5


@dataclass(frozen=True, eq=False)
class Rectification:
    """Rectifying rotations ``R1``/``R2`` (unrectified -> rectified camera frame), rectified
    projections ``P1``/``P2`` (3x4, cv2 pixel convention, ``P2`` in the left rectified frame), the
    rectified size (width, height) of both images, the remap tables of both photos, and the matching
    frame: ``vertical``, ``mirrored`` and ``offset`` (matching-frame disparity at infinite depth)."""

    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    size: tuple[int, int]
    maps_left: tuple[np.ndarray, np.ndarray]
    maps_right: tuple[np.ndarray, np.ndarray]
    vertical: bool
    mirrored: bool
    offset: float

    @property
    def focal(self) -> float:
        """Focal length of the rectified cameras (px)."""
        return float(self.P1[0, 0])

    @property
    def baseline(self) -> float:
        """Distance between the camera centres, in the calibration's unit."""
        axis = 1 if self.vertical else 0
        return float(abs(self.P2[axis, 3]) / self.P2[axis, axis])

    def depth_of(self, disparity: np.ndarray) -> np.ndarray:
        """Rectified-frame depth of matching-frame disparities (NaN where there is none)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.focal * self.baseline / (disparity - self.offset)

    def to_matching(self, image: np.ndarray) -> np.ndarray:
        """A rectified array (H x W [x C]) in the matching frame."""
        if self.vertical:
            image = image.swapaxes(0, 1)
        if self.mirrored:
            image = image[:, ::-1]
        return np.ascontiguousarray(image)

    def from_matching(self, image: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`to_matching`."""
        if self.mirrored:
            image = image[:, ::-1]
        if self.vertical:
            image = image.swapaxes(0, 1)
        return np.ascontiguousarray(image)

    def matching_coords(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified pixel coordinates (cv2 convention) -> matching-frame coordinates."""
        if self.vertical:
            x, y = y, x
        if self.mirrored:
            width = self.size[1] if self.vertical else self.size[0]
            x = (width - 1) - x
        return x, y

    def aligned(self, calib: StereoCalibration, disparity: float) -> Rectification:
        """The same rectification with the right image shifted along the epipolar lines so that a
        point of disparity f B / z = ``disparity`` has matching-frame disparity 0. SGBM leaves the
        first (minDisparity + numDisparities) columns without a match, so the search range, starting
        near the scene's lowest disparity, should start near 0."""
        axis = 1 if self.vertical else 0
        P2 = self.P2.copy()
        P2[axis, 2] = self.P1[axis, 2] + (-disparity if self.mirrored else disparity)
        maps_right = cv2.initUndistortRectifyMap(calib.right.opencv_K(), calib.right.opencv_distortion(), self.R2,
                                                 P2[:, :3], self.size, cv2.CV_32FC1)
        return dataclasses.replace(self, P2=P2, maps_right=maps_right, offset=-float(disparity))

    def rectify_left(self, image: np.ndarray) -> np.ndarray:
        return cv2.remap(image, *self.maps_left, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def rectify_right(self, image: np.ndarray) -> np.ndarray:
        return cv2.remap(image, *self.maps_right, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def rectify(calib: StereoCalibration) -> Rectification:
    """Rectify the pair ``calib`` (photos at its intrinsics' sizes). A ValueError when the baseline runs
    mostly along the viewing direction (no planar rectification keeps the overlap), or when the
    rectified photos share no row."""
    R, T = np.asarray(calib.R, dtype=np.float64), np.asarray(calib.T, dtype=np.float64).reshape(3, 1)
    centre = -R.T @ T.ravel()  # the right camera's centre in the left camera's frame
    lateral = math.hypot(centre[0], centre[1]) / np.linalg.norm(centre)
    if lateral < MIN_LATERAL:
        raise ValueError(f"the baseline runs mostly along the viewing direction (only {100 * lateral:.0f}% of it "
                         "across): a forward-moving pair cannot be rectified; pick photos taken side by side")
    K1, D1 = calib.left.opencv_K(), calib.left.opencv_distortion()
    K2, D2 = calib.right.opencv_K(), calib.right.opencv_distortion()
    R1, R2, _, P2_cv, *_ = cv2.stereoRectify(K1, D1, K2, D2, (calib.left.width, calib.left.height), R, T)
    vertical = bool(abs(P2_cv[1, 3]) > abs(P2_cv[0, 3]))
    axis = 1 if vertical else 0
    t_rect = R2 @ T.ravel()  # the left centre in the right rectified frame: along one axis only
    focal = float(calib.left.fx if not vertical else calib.left.fy)
    boxes = [_footprint(calib.left, R1), _footprint(calib.right, R2)]  # normalised (x0, y0, x1, y1)
    across = 1 - axis  # the axis both images share (rows for horizontal stereo)
    low = max(b[across] for b in boxes)
    high = min(b[across + 2] for b in boxes)
    if not high > low:
        raise ValueError("the rectified photos share no " + ("row" if not vertical else "column") +
                         ": they do not overlap")
    extent = max(high - low, boxes[0][axis + 2] - boxes[0][axis])
    longest = max(calib.left.width, calib.left.height)
    focal = min(focal, MAX_GROWTH * longest / extent)
    start = [boxes[0][0], boxes[0][1]]  # the left footprint's corner: rectified pixel (0, 0)
    start[across] = low
    size_along = math.ceil(focal * (boxes[0][axis + 2] - boxes[0][axis])) + 1
    size_across = math.ceil(focal * (high - low)) + 1
    size = (size_along, size_across) if not vertical else (size_across, size_along)
    P1 = np.array([[focal, 0, -focal * start[0], 0], [0, focal, -focal * start[1], 0], [0, 0, 1, 0]])
    P2 = P1.copy()  # same principal point: disparity f B / z (offset 0) until aligned()
    P2[axis, 3] = focal * t_rect[axis]
    mirrored = bool(t_rect[axis] > 0)
    maps_left = cv2.initUndistortRectifyMap(K1, D1, R1, P1[:, :3], size, cv2.CV_32FC1)
    maps_right = cv2.initUndistortRectifyMap(K2, D2, R2, P2[:, :3], size, cv2.CV_32FC1)
    rect = Rectification(R1, R2, P1, P2, size, maps_left, maps_right, vertical, mirrored, 0.0)
    log.debug("rectified %dx%d -> %dx%d, focal %.1f px, baseline %.4g, %s%s", calib.left.width, calib.left.height,
              *size, focal, rect.baseline, "vertical" if vertical else "horizontal", ", mirrored" if mirrored else "")
    return rect


def _footprint(cam: Intrinsics, rotation: np.ndarray, samples: int = 32) -> tuple[float, float, float, float]:
    """Bounding box (x0, y0, x1, y1) in normalised rectified coordinates of the photo's pixel centres
    seen through ``rotation`` (its border sampled, distortion undone)."""
    s = np.linspace(0.0, 1.0, samples)
    u = np.concatenate([s, s, np.zeros(samples), np.ones(samples)]) * (cam.width - 1) + 0.5
    v = np.concatenate([np.zeros(samples), np.ones(samples), s, s]) * (cam.height - 1) + 0.5
    rays = apply_matrix(rotation, np.column_stack([cam.undistort_pixels(np.column_stack([u, v])),
                                                   np.ones(len(u))]))
    if not (rays[:, 2] > 0).all():
        raise ValueError("the cameras turn too far from each other for planar rectification")
    x, y = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
    return float(x.min()), float(y.min()), float(x.max()), float(y.max())


def disparity_bounds(rect: Rectification, calib: StereoCalibration, depth_min: float,
                     depth_max: float) -> tuple[float, float]:
    """The disparities f B / z (px, without the rectification's offset) of left-camera depths
    ``depth_min``..``depth_max`` over the whole left photo: the rectified depth of a point differs from
    its left-camera depth by the factor (R1 ray)_z / ray_z, taken at its extremes over the photo."""
    cam = calib.left
    u, v = np.meshgrid(np.linspace(0, cam.width, 17), np.linspace(0, cam.height, 17))
    rays = cam.undistort_pixels(np.column_stack([u.ravel(), v.ravel()]))
    ratio = apply_matrix(rect.R1, np.column_stack([rays, np.ones(len(rays))]))[:, 2]
    fb = rect.focal * rect.baseline
    return fb / (depth_max * float(ratio.max())), fb / (depth_min * float(ratio.min()))
