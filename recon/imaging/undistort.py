"""Undistortion: resample an image of a distorted camera into an ideal PINHOLE camera.

The output keeps the input size; ``alpha`` chooses the new focal lengths and principal point the
way OpenCV's getOptimalNewCameraMatrix does (0: every output pixel sees the source, nothing black;
1: every source pixel is kept, black corners). Pixels outside the source are 0 in the image and
False (= ignore) in a warped mask.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from recon.imaging.intrinsics import Intrinsics
from recon.imaging.operation import Operation
from recon.imaging.pixels import from_float, to_float
from recon.options import opt


@dataclass(frozen=True)
class UndistortOptions:
    alpha: float = opt(0.0, "0 = crop so every output pixel is valid; 1 = keep all source pixels "
                            "(black borders); in between blends", ge=0.0, le=1.0)


def undistorted_camera(camera: Intrinsics, alpha: float) -> Intrinsics:
    """The PINHOLE camera that :func:`undistort` produces for ``camera``."""
    size = (camera.width, camera.height)
    if not camera.has_distortion:
        return Intrinsics.pinhole(camera.fx, camera.fy, camera.cx, camera.cy, *size)
    K, _ = cv2.getOptimalNewCameraMatrix(camera.opencv_K(), camera.opencv_distortion(), size, alpha, size)
    return Intrinsics.from_opencv(K, None, *size)


def undistortion_maps(camera: Intrinsics, target: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """float32 (map_x, map_y) for cv2.remap: source pixel (OpenCV index coordinates) of each target pixel."""
    return cv2.initUndistortRectifyMap(camera.opencv_K(), camera.opencv_distortion(), None,
                                       target.opencv_K(), (target.width, target.height), cv2.CV_32FC1)


def _require_camera(camera: Intrinsics | None) -> Intrinsics:
    if camera is None:
        raise ValueError("undistortion needs the camera intrinsics of the image")
    return camera


def _check_size(image: np.ndarray, camera: Intrinsics) -> None:
    if image.shape[:2] != (camera.height, camera.width):
        raise ValueError(f"image is {image.shape[1]}x{image.shape[0]} but its camera is "
                         f"{camera.width}x{camera.height}")


def undistort(image: np.ndarray, camera: Intrinsics, options: UndistortOptions) -> tuple[np.ndarray, Intrinsics]:
    """Undistorted image (same dtype) and its PINHOLE camera."""
    camera = _require_camera(camera)
    _check_size(image, camera)
    target = undistorted_camera(camera, options.alpha)
    map_x, map_y = undistortion_maps(camera, target)
    # Replicate the border so pixels next to the edge are not darkened by interpolation, then blank
    # the pixels whose source lies outside the image (the same pixels a warped mask drops).
    out = cv2.remap(to_float(image), map_x, map_y, interpolation=cv2.INTER_CUBIC,
                    borderMode=cv2.BORDER_REPLICATE)
    h, w = image.shape[:2]
    outside = (map_x < -0.5) | (map_x > w - 0.5) | (map_y < -0.5) | (map_y > h - 0.5)
    out[outside] = 0.0
    return from_float(np.clip(out, 0.0, 1.0), image.dtype), target


def _undistort_mask(mask: np.ndarray, camera: Intrinsics | None, options: UndistortOptions) -> np.ndarray:
    camera = _require_camera(camera)
    _check_size(mask, camera)
    map_x, map_y = undistortion_maps(camera, undistorted_camera(camera, options.alpha))
    out = cv2.remap(mask.astype(np.uint8), map_x, map_y, interpolation=cv2.INTER_NEAREST,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return out.astype(bool)


UNDISTORT = Operation(
    name="undistort",
    Options=UndistortOptions,
    geometric=True,
    apply=undistort,
    apply_mask=_undistort_mask,
    doc="resample to an ideal PINHOLE camera from the radial/tangential (OpenCV) distortion coefficients",
)
