"""Contrast enhancement on lightness only: CLAHE and global histogram equalisation.

Colour images are converted to CIELAB; only L changes and a*, b* are kept, so hues and chroma stay
those of the photo (equalising R, G and B separately would shift colours). uint8 lightness is
processed at 8 bits with OpenCV's CLAHE; uint16 at 16 bits with scikit-image's (OpenCV's 16-bit
CLAHE uses 65536-bin histograms whose clip limit collapses on small tiles), with the clip limit
translated so both mean the same thing: a histogram bin is clipped at ``clip_limit`` times the
average bin count of its tile.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from recon.imaging.intrinsics import Intrinsics
from recon.imaging.operation import Operation
from recon.imaging.pixels import check_image, lab_lightness, with_lab_lightness
from recon.options import opt

_CLAHE_BINS = 256


@dataclass(frozen=True)
class ClaheOptions:
    clip_limit: float = opt(2.0, "histogram bins are clipped at this multiple of the mean bin count "
                                 "(1 = no enhancement, larger = stronger, more noise)", ge=1.0, le=40.0)
    tiles: int = opt(8, "tiles per image side over which local histograms are taken", ge=1, le=64)


def clahe(image: np.ndarray, camera: Intrinsics | None, options: ClaheOptions):
    check_image(image)
    lightness, lab = lab_lightness(image)
    if image.dtype == np.uint8:
        l8 = np.rint(lightness * 255.0).astype(np.uint8)
        tool = cv2.createCLAHE(clipLimit=options.clip_limit, tileGridSize=(options.tiles, options.tiles))
        new = tool.apply(l8).astype(np.float32) / 255.0
    else:
        h, w = lightness.shape
        kernel = (max(1, h // options.tiles), max(1, w // options.tiles))
        from skimage.exposure import equalize_adapthist  # scikit-image is slow to import

        new = equalize_adapthist(lightness, kernel_size=kernel, clip_limit=options.clip_limit / _CLAHE_BINS,
                                 nbins=_CLAHE_BINS).astype(np.float32)
    return with_lab_lightness(new, lab, image.dtype), camera


@dataclass(frozen=True)
class EqualizeOptions:
    pass


def equalize(image: np.ndarray, camera: Intrinsics | None, options: EqualizeOptions):
    """Global histogram equalisation of lightness, at the image's own bit depth."""
    check_image(image)
    lightness, lab = lab_lightness(image)
    levels = 256 if image.dtype == np.uint8 else 65536
    quantised = np.rint(lightness * (levels - 1)).astype(np.int64)
    cdf = np.cumsum(np.bincount(quantised.ravel(), minlength=levels)).astype(np.float64)
    lowest = cdf[cdf > 0][0]
    span = max(cdf[-1] - lowest, 1.0)
    lut = np.clip((cdf - lowest) / span, 0.0, 1.0).astype(np.float32)
    return with_lab_lightness(lut[quantised], lab, image.dtype), camera


CLAHE = Operation(name="clahe", Options=ClaheOptions, geometric=False, apply=clahe,
                  doc="contrast-limited adaptive histogram equalisation of lightness (colours kept)")
EQUALIZE = Operation(name="equalize", Options=EqualizeOptions, geometric=False, apply=equalize,
                     doc="global histogram equalisation of lightness (colours kept)")
