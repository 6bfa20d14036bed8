"""Pixel-type rules shared by the 2D operations.

Images at the API surface are uint8 or uint16, HxW (gray) or HxWx3 (RGB). Kernels work on float32
in [0, 1]; :func:`to_float` and :func:`from_float` are the one conversion in each direction.
:func:`sample_bilinear` is the bilinear lookup at continuous pixel coordinates that array code shares
(texturing, the depth maps' silhouette check, evaluation; numba kernels inline their own);
:func:`sample_lanczos` the sharper one that copies photo colours into a texture. :func:`seen_pixels`
maps one camera's pixels into another's at the same centre (an undistorted or resized view).
"""

from __future__ import annotations

import cv2
import numpy as np

SUPPORTED_DTYPES = (np.uint8, np.uint16)


def check_image(image: np.ndarray) -> None:
    """Raise ValueError unless ``image`` is a uint8/uint16 gray (HxW) or RGB (HxWx3) array."""
    if image.dtype not in SUPPORTED_DTYPES:
        raise ValueError(f"images must be uint8 or uint16, got {image.dtype}")
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)):
        raise ValueError(f"images must be HxW or HxWx3, got shape {image.shape}")


def max_value(dtype: np.dtype) -> int:
    return int(np.iinfo(dtype).max)


def to_float(image: np.ndarray) -> np.ndarray:
    """float32 copy in [0, 1] of a uint8/uint16 image (float input is returned as float32)."""
    if np.issubdtype(image.dtype, np.floating):
        return image.astype(np.float32, copy=False)
    return image.astype(np.float32) / np.float32(max_value(image.dtype))


def from_float(image: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """Round and clip a float image in [0, 1] to ``dtype`` (float dtypes are passed through)."""
    if np.issubdtype(dtype, np.floating):
        return image.astype(dtype, copy=False)
    top = max_value(dtype)
    return np.clip(np.rint(image * top), 0, top).astype(dtype)


def to_gray(image: np.ndarray) -> np.ndarray:
    """Single-channel version of an RGB image (same dtype); gray images are returned as they are."""
    if image.ndim == 2:
        return image
    return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def lab_lightness(image: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Split an image into CIELAB lightness in [0, 1] (float32) and the Lab array to rebuild it.

    Gray images are their own lightness (returns ``(to_float(image), None)``).
    """
    rgb = to_float(image)
    if rgb.ndim == 2:
        return rgb, None
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB)
    return lab[..., 0] / np.float32(100.0), lab


def with_lab_lightness(lightness: np.ndarray, lab: np.ndarray | None, dtype: np.dtype) -> np.ndarray:
    """Rebuild an image of ``dtype`` from new lightness in [0, 1] and the a*, b* kept in ``lab``."""
    if lab is None:
        return from_float(lightness, dtype)
    lab = lab.copy()
    lab[..., 0] = np.clip(lightness, 0.0, 1.0) * np.float32(100.0)
    return from_float(np.clip(cv2.cvtColor(lab, cv2.COLOR_LAB2RGB), 0.0, 1.0), dtype)


def sample_bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear lookup of ``image`` (H, W[, C]) at continuous pixel coordinates (pixel centres at +0.5);
    coordinates outside are clamped to the border."""
    h, w = image.shape[:2]
    fx = np.clip(np.asarray(x, np.float64) - 0.5, 0, w - 1)
    fy = np.clip(np.asarray(y, np.float64) - 0.5, 0, h - 1)
    x0 = np.minimum(np.floor(fx).astype(np.int64), w - 2 if w > 1 else 0)
    y0 = np.minimum(np.floor(fy).astype(np.int64), h - 2 if h > 1 else 0)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    ax, ay = fx - x0, fy - y0
    if image.ndim == 3:
        ax, ay = ax[..., None], ay[..., None]
    img = image.astype(np.float32, copy=False)
    top = img[y0, x0] * (1 - ax) + img[y0, x1] * ax
    bottom = img[y1, x0] * (1 - ax) + img[y1, x1] * ax
    return top * (1 - ay) + bottom * ay


_REMAP_ROW = 4096  # lookups per row of the maps handed to OpenCV (its maps are images)


def sample_lanczos(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Lanczos (8 x 8 pixels) lookup of ``image`` (H, W[, C]) at continuous pixel coordinates (pixel
    centres at +0.5), through OpenCV's remap, as float32; the border is replicated. Unlike bilinear
    interpolation it keeps a photo's finest detail between pixel centres; next to hard edges it may
    overshoot the range of ``image``, so clip what it gives where that matters."""
    n = len(x)
    if n == 0:
        return np.zeros((0,) + image.shape[2:], np.float32)
    rows = -(-n // _REMAP_ROW)
    maps = np.zeros((2, rows * _REMAP_ROW), np.float32)
    maps[0, :n] = np.asarray(x, np.float64) - 0.5
    maps[1, :n] = np.asarray(y, np.float64) - 0.5
    out = cv2.remap(np.asarray(image, np.float32), maps[0].reshape(rows, -1), maps[1].reshape(rows, -1),
                    cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape((rows * _REMAP_ROW,) + image.shape[2:])[:n]


def seen_pixels(source, target) -> np.ndarray:
    """Pixels (N, 2; COLMAP's convention, centres at +0.5) of the pycolmap camera ``source`` seen by the
    pixel centres of the camera ``target``, row by row: both at one centre and orientation (an
    undistorted or resized view of the same photo)."""
    u, v = np.meshgrid(np.arange(target.width) + 0.5, np.arange(target.height) + 0.5)
    rays = target.cam_from_img(np.stack([u.ravel(), v.ravel()], axis=1))
    return np.asarray(source.img_from_cam(np.column_stack([rays, np.ones(len(rays))]), check_cheirality=False),
                      np.float64)
