"""Anti-aliased resizing, image pyramids, and the intrinsics that go with them.

Downscaling by s < 1 first low-passes the image with a Gaussian, then samples it bilinearly; plain
decimation (or bilinear/nearest sampling alone) folds every frequency above the new Nyquist limit
(s/2 cycles per source pixel) back into the image as aliasing (moire, crawling edges, spurious
SIFT features). The Gaussian's sigma, in source pixels, is

    sigma = 0.5 * sqrt(1/s**2 - 1)

the blur that, added in quadrature to the nominal 0.5 px blur of a camera image (the assumption
SIFT makes of its input), gives the output the same nominal 0.5 px blur in *its* pixels: the result
looks like a photo taken at the lower resolution, and s -> 1 needs no blur. At the new Nyquist
frequency the Gaussian keeps exp(-pi^2 sigma^2 s^2 / 2) ~= 0.3 of the amplitude (for s << 1), at
the frequency that would alias onto the output's DC (f = s) it keeps ~= 0.007.

Sampling uses OpenCV's half-pixel-centre mapping (dst + 0.5) = (src + 0.5) * s, which is the
COLMAP convention ``x' = x * s`` for continuous coordinates with pixel centres at +0.5; so the
intrinsics scale exactly as :meth:`Intrinsics.scaled` says.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from recon.imaging.intrinsics import Intrinsics
from recon.imaging.operation import Operation
from recon.imaging.pixels import from_float, to_float
from recon.options import opt


def antialias_sigma(scale: float) -> float:
    """Gaussian pre-filter sigma (source pixels) for resampling by ``scale``; 0 when not shrinking."""
    if scale >= 1.0:
        return 0.0
    return 0.5 * math.sqrt(1.0 / (scale * scale) - 1.0)


def _gaussian_kernel_size(sigma: float) -> int:
    return 1 if sigma <= 0 else 2 * math.ceil(4.0 * sigma) + 1


def resize_to(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize ``image`` to ``width`` x ``height`` with anti-aliasing; keeps dtype and channels.

    Works on uint8/uint16 (rounded and clipped back) and on float arrays (kept in their float
    dtype, unclipped, so the operation stays linear for analysis).
    """
    h, w = image.shape[:2]
    if (w, h) == (width, height):
        return image.copy()
    sx, sy = width / w, height / h
    data = to_float(image)
    sigma_x, sigma_y = antialias_sigma(sx), antialias_sigma(sy)
    if sigma_x > 0 or sigma_y > 0:
        ksize = (_gaussian_kernel_size(sigma_x), _gaussian_kernel_size(sigma_y))
        data = cv2.GaussianBlur(data, ksize, sigmaX=sigma_x, sigmaY=sigma_y, borderType=cv2.BORDER_REFLECT_101)
    shrinking = sx < 1.0 or sy < 1.0
    out = cv2.resize(data, (width, height), interpolation=cv2.INTER_LINEAR if shrinking else cv2.INTER_CUBIC)
    return from_float(out, image.dtype)


def resize_mask(mask: np.ndarray, width: int, height: int) -> np.ndarray:
    """Resize a boolean mask with nearest-neighbour sampling (same pixel mapping as :func:`resize_to`)."""
    return cv2.resize(mask.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST).astype(bool)


def pyramid(image: np.ndarray, levels: int) -> list[np.ndarray]:
    """``levels`` images, level 0 being ``image`` and each next one half the size (anti-aliased)."""
    if levels < 1:
        raise ValueError("a pyramid has at least one level")
    out = [image]
    for _ in range(levels - 1):
        h, w = out[-1].shape[:2]
        out.append(resize_to(out[-1], max(1, round(w / 2)), max(1, round(h / 2))))
    return out


@dataclass(frozen=True)
class ResizeOptions:
    max_size: int = opt(0, "longest image side in pixels after resizing; 0 = use `scale` instead", ge=0)
    scale: float = opt(1.0, "scale factor applied to both sides when max_size is 0 (0.5 halves them)",
                       gt=0.0, le=8.0)
    upscale: bool = opt(False, "let max_size enlarge images already smaller than it")


def output_size(width: int, height: int, options: ResizeOptions) -> tuple[int, int]:
    """The (width, height) the resize operation gives an image of ``width`` x ``height``."""
    if options.max_size > 0:
        scale = options.max_size / max(width, height)
        if scale > 1.0 and not options.upscale:
            scale = 1.0
    else:
        scale = options.scale
    return max(1, round(width * scale)), max(1, round(height * scale))


def _apply(image: np.ndarray, camera: Intrinsics | None, options: ResizeOptions):
    h, w = image.shape[:2]
    width, height = output_size(w, h, options)
    return resize_to(image, width, height), (camera.scaled(width, height) if camera is not None else None)


def _apply_mask(mask: np.ndarray, camera: Intrinsics | None, options: ResizeOptions) -> np.ndarray:
    h, w = mask.shape[:2]
    return resize_mask(mask, *output_size(w, h, options))


RESIZE = Operation(
    name="resize",
    Options=ResizeOptions,
    geometric=True,
    apply=_apply,
    apply_mask=_apply_mask,
    doc="resize with a Gaussian anti-aliasing pre-filter (never plain decimation); intrinsics scaled",
)
