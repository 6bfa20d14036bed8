"""Panoramas from photos taken by a camera rotating about its centre.

:func:`register` matches the photos (features, pairwise homographies with RANSAC), estimates each
photo's rotation and focal length and refines them by bundle adjustment on rays; :func:`compose`
warps them onto a sphere, a cylinder or a plane, compensates exposure, finds seams and blends; a
full 360 deg set wraps exactly (width = 2 pi x focal). :func:`stitch` does both. OpenCV's stitching
module does the work; what it lacks (closing a 360 deg ring, wrap-aware exposure) is here.

    from recon.panorama import PanoramaOptions, stitch
    pano = stitch(images, PanoramaOptions(projection="cylindrical"))
    pano.image                                   # HxWx3 uint8 RGB
    pano.model.to_pixel(directions, camera=0)    # where directions in photo 0's frame land
"""

from __future__ import annotations

import numpy as np

from recon.panorama.compose import Panorama, compose
from recon.panorama.model import PanoramaModel
from recon.panorama.options import PanoramaOptions
from recon.panorama.register import Pair, PanoramaError, Registration, register

__all__ = ["Pair", "Panorama", "PanoramaError", "PanoramaModel", "PanoramaOptions", "Registration", "compose",
           "register", "stitch"]


def stitch(images: list[np.ndarray], options: PanoramaOptions = PanoramaOptions(),
           focal_priors: list[float | None] | None = None, names: list[str] | None = None) -> Panorama:
    """Register RGB uint8 photos and compose them into one panorama (see the module doc and
    :func:`register` for the arguments)."""
    return compose(images, register(images, options, focal_priors, names), options)
