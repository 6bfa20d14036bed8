"""Per-image masks in COLMAP's convention: ``<mask_dir>/<image_name>.png``, zero = ignore.

``image_name`` is the image's path relative to the image folder, extension included
(``a/IMG_1.jpg`` -> ``<mask_dir>/a/IMG_1.jpg.png``). In memory a mask is a boolean HxW array,
True where the image is to be used. Geometric operations warp masks with their images
(:attr:`recon.imaging.operation.Operation.apply_mask`, nearest-neighbour).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image


def mask_path(mask_dir: str | Path, image_name: str) -> Path:
    return Path(mask_dir) / f"{image_name}.png"


def load_mask(mask_dir: str | Path, image_name: str, shape: tuple[int, int] | None = None) -> np.ndarray | None:
    """The mask of ``image_name`` (True = use), or None when it has no mask file.

    Any non-zero value (in any channel) means use. With ``shape`` (height, width) given, a mask of
    another size is an error: masks must be made for the images they go with.
    """
    path = mask_path(mask_dir, image_name)
    if not path.is_file():
        return None
    with Image.open(path) as image:
        data = np.asarray(image)
    mask = data.any(axis=2) if data.ndim == 3 else data != 0
    if shape is not None and mask.shape != tuple(shape):
        raise ValueError(f"mask {path} is {mask.shape[1]}x{mask.shape[0]}, its image {shape[1]}x{shape[0]}")
    return mask


def save_mask(mask_dir: str | Path, image_name: str, mask: np.ndarray) -> Path:
    """Write ``mask`` (True = use) as an 8-bit PNG with 255 = use, 0 = ignore; returns its path."""
    path = mask_path(mask_dir, image_name)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.where(mask, 255, 0).astype(np.uint8)).save(path)
    return path


def inside_mask(mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    """For each point (N, 2: x, y in COLMAP pixel coordinates), whether it falls on a used mask pixel.

    Pixel (row i, column j) covers [j, j+1) x [i, i+1); points outside the image count as not used.
    """
    cols = np.floor(points[:, 0]).astype(np.int64)
    rows = np.floor(points[:, 1]).astype(np.int64)
    h, w = mask.shape
    valid = (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h)
    keep = np.zeros(len(points), bool)
    keep[valid] = mask[rows[valid], cols[valid]]
    return keep


def resample_mask(mask: np.ndarray, source, target) -> np.ndarray:
    """``mask`` of an image of the pycolmap camera ``source`` as seen by the camera ``target`` (same
    centre and orientation: an undistorted or resized view), nearest neighbour; pixels that fall
    outside the source image are masked out."""
    from recon.imaging.pixels import seen_pixels

    return inside_mask(mask, seen_pixels(source, target)).reshape(target.height, target.width)


def mask_at(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    """``mask`` for the same view at another resolution (depth maps are computed smaller)."""
    if mask.shape == (height, width):
        return mask
    rows = np.minimum(((np.arange(height) + 0.5) * mask.shape[0] / height).astype(np.int64), mask.shape[0] - 1)
    cols = np.minimum(((np.arange(width) + 0.5) * mask.shape[1] / width).astype(np.int64), mask.shape[1] - 1)
    return mask[np.ix_(rows, cols)]
