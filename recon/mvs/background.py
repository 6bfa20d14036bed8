"""No depth on the sky or a backdrop beside a surface's edge.

A pixel of a flat sky just above the horizon gets the ground's depth: its matching window reaches
over the edge, the ground's texture in it matches at the ground's plane in every view, and the plane
runs on past the edge. :func:`recon.mvs.patchmatch.own_texture` drops such a pixel where its own side
of the window (the samples of its shade) is flat; the few pixels nearest the edge keep some
variation there (JPEG's ringing around the edge: 0.006-0.013 against the 0.005 floor on the zoo's
clean skies) and keep their depth. Seen at a grazing angle, as a horizon always is, those few pixels
are a long strip in space: on the zoo's ground squares against a flat sky, the mesh ran on past the
ground's edge, up to a tenth of its area (fence_poles, noisy_phone, transient_car).

So a depth map loses its depths within the matching window's radius of the background where the
pixel's intensity lies within ``sigma_color / 2`` of the nearest background pixel's (the shade
``own_texture`` counts as the pixel's own side). A surface's own pixels at its edge differ from the
sky in shade and keep theirs. The background is the regions of one shade
(:func:`recon.mvs.planar_fill.regions`) that run out of the photo and cover at least
:data:`MIN_SHARE` of it: sky, a backdrop. The planar fill leaves such regions alone for the same
reason: what lies beyond the photo's border is unknown. They are found twice:

- among the pixels the filter calls untextured;
- among the pixels untextured once the photo is smoothed by :data:`NOISE_SIGMA` px.

Either way, a region counts only where the filter left depth on at most :data:`MAX_MEASURED` of
its pixels (the first kind holds none: the filter drops untextured pixels' depths). Sensor noise
gives a sky texture at the filter's scale (noisy_phone: 0.0047-0.0074 against the 0.005 floor), so
its sky is crumbs, none of them 1 % of the photo. Smoothed, a fine-grained wall is flat too, but its
depths were measured: on walkaround, the smoothed regions without the share took 6 % of the correct
depths, with it 0.05 %, as the first kind alone does.
"""

from __future__ import annotations

import cv2
import numpy as np

from recon.mvs.options import MVSOptions
from recon.mvs.patchmatch import untextured as untextured_pixels
from recon.mvs.planar_fill import regions

#: smallest share of the map a region running out of it must cover to count as background; smaller ones
#: (a gap between two walls at the photo's edge) may be a surface's own flat paint
MIN_SHARE = 0.01
#: Gaussian sigma (px at the working resolution) that takes sensor noise out of the photo
NOISE_SIGMA = 1.0
#: largest share of a region's pixels holding a depth for it to count as background
MAX_MEASURED = 0.05


def _running_out(image: np.ndarray, flat: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Bool mask of the :func:`regions` of ``image`` among its ``flat`` pixels that run out of the photo,
    cover :data:`MIN_SHARE` of it and hold a depth on at most :data:`MAX_MEASURED` of their pixels."""
    height, width = image.shape
    count, labels, stats, _ = regions(image, flat)
    x, y, w, h, area = (stats[:, i] for i in range(5))
    measured = np.bincount(labels.ravel(), weights=(depth > 0).ravel(), minlength=count)
    chosen = (x == 0) | (y == 0) | (x + w == width) | (y + h == height)
    chosen &= (area >= MIN_SHARE * height * width) & (measured <= MAX_MEASURED * area)
    chosen[0] = False  # the textured pixels
    return chosen[labels]


def background(image: np.ndarray, untextured: np.ndarray, depth: np.ndarray, options: MVSOptions) -> np.ndarray:
    """Bool mask of the background (module doc) of the grey ``image`` in [0, 1] with its ``untextured``
    pixels (:func:`recon.mvs.patchmatch.untextured`) and its filtered ``depth``."""
    smooth = cv2.GaussianBlur(image, (0, 0), NOISE_SIGMA)
    return _running_out(image, untextured, depth) | _running_out(smooth, untextured_pixels(smooth, options), depth)


def background_reach(image: np.ndarray, untextured: np.ndarray, depth: np.ndarray,
                     options: MVSOptions) -> np.ndarray:
    """Bool mask of the background (:func:`background`) and of the pixels within ``options.window_radius``
    px of it whose intensity lies within ``options.sigma_color / 2`` of the nearest background pixel's:
    the pixels the matching window may have given a surface's depth (module doc). Empty without a
    background."""
    sky = background(image, untextured, depth, options)
    if not sky.any():
        return sky
    distance, nearest = cv2.distanceTransformWithLabels((~sky).astype(np.uint8), cv2.DIST_L2, 5,
                                                        labelType=cv2.DIST_LABEL_PIXEL)
    rows, cols = np.nonzero(sky)
    shade_of = np.zeros(int(nearest.max()) + 1, np.float32)
    shade_of[nearest[rows, cols]] = image[rows, cols]
    return (distance <= options.window_radius) & (np.abs(image - shade_of[nearest]) <= options.sigma_color / 2)


def clear_background(image: np.ndarray, untextured: np.ndarray, depth: np.ndarray, normal: np.ndarray,
                     options: MVSOptions) -> int:
    """Zero, in place, the depths and normals of :func:`background_reach`. Returns how many went."""
    drop = (depth > 0) & background_reach(image, untextured, depth, options)
    depth[drop] = 0
    normal[drop] = 0
    return int(np.count_nonzero(drop))
