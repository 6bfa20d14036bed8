"""Pixel-type rules shared by the 2D operations.

Images at the API surface are uint8 or uint16, HxW (gray) or HxWx3 (RGB). Kernels work on float32
in [0, 1]; :func:`to_float` and :func:`from_float` are the one conversion in each direction.
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
