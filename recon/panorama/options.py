"""Options of the panorama stitcher (they are also the `panorama:` section of a run config)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from recon.options import opt


@dataclass(frozen=True)
class PanoramaOptions:
    projection: Literal["spherical", "cylindrical", "plane"] = opt(
        "spherical", "surface the photos are projected onto: spherical or cylindrical for wide views (a full "
                     "360 deg set wraps), plane for narrow ones (straight lines stay straight)")
    features: Literal["sift", "orb"] = opt("sift", "feature detector and descriptor used to match the photos")
    max_features: int = opt(2000, "most features kept per photo", ge=100)
    registration_megapix: float = opt(0.6, "photos are resized to about this many megapixels to find features "
                                           "and register them", gt=0)
    match_conf: float = opt(0.3, "nearest-neighbour ratio test: a match is kept when its distance is below "
                                 "(1 - match_conf) x the second nearest", gt=0, lt=1)
    match_window: int = opt(0, "0 = match every pair of photos; k > 0 = each photo with the k next in file "
                               "order, cyclically (so the last and the first are matched)", ge=0)
    pair_confidence: float = opt(1.0, "two photos are linked when inliers / (8 + 0.3 matches) reaches this", gt=0)
    focal: Literal["estimate", "prior"] = opt(
        "estimate", "initial focal length, refined by the bundle adjustment: estimate = from the pairwise "
                    "homographies; prior = the photos' EXIF focal where known (others are estimated)")
    wave_correct: Literal["horizontal", "vertical", "auto", "none"] = opt(
        "horizontal", "straighten the panorama: horizontal for a camera turned about the vertical axis")
    full_circle: bool | None = opt(None, "treat the photos as a closed 360 deg ring whose panorama wraps "
                                         "(null = decide from their coverage); spherical/cylindrical only")
    exposure: Literal["gain", "channels", "none"] = opt(
        "gain", "exposure compensation: one gain per photo, one gain per photo and colour channel, or none")
    seam: Literal["graphcut", "dp", "voronoi", "none"] = opt(
        "graphcut", "seam finder: where, in each overlap, one photo gives way to the next")
    seam_megapix: float = opt(0.1, "seams are found on warped photos of about this many megapixels", gt=0)
    blend: Literal["multiband", "feather", "none"] = opt(
        "multiband", "blending across the seams: multi-band (Laplacian pyramids), feather, or none")
    blend_bands: int = opt(5, "pyramid levels of the multi-band blender", ge=1, le=10)
    max_width: int = opt(8000, "widest panorama written; a wider one is composed at a lower scale "
                               "(0 = the photos' full resolution)", ge=0)
