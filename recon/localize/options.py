"""Options of localization: retrieval, 2D-3D matching, pose estimation and the refusal thresholds."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from recon.options import opt


@dataclass(frozen=True)
class LocalizeOptions:
    """How a new photo is placed in a reference model (defaults follow COLMAP's image registrator)."""

    neighbours: int = opt(10, "registered reference images retrieved (VLAD similarity) and matched per photo", ge=1)
    vocabulary_words: int = opt(64, "words of the VLAD vocabulary learned from the reference's and the photos' "
                                    "descriptors", ge=8)
    max_ratio: float = opt(0.8, "Lowe's ratio test threshold of the 2D-2D matches", gt=0, le=1)
    max_distance: float = opt(0.7, "largest descriptor distance of a match", gt=0, le=1)
    cross_check: bool = opt(True, "keep only mutual best matches")
    intrinsics: Literal["auto", "reference", "photo"] = opt(
        "auto", "reference: a reference camera of the photo's aspect ratio, rescaled to its size; photo: its EXIF "
                "focal (or a guess); auto: the reference camera unless the EXIF focal differs by more than "
                "`focal_tolerance`")
    focal_tolerance: float = opt(0.15, "auto: largest relative difference between EXIF and reference focal for "
                                       "the reference camera to be used", ge=0)
    estimate_focal: Literal["auto", "always", "never"] = opt(
        "auto", "estimate (P4Pf) and refine the focal length; auto: when it is the photo's own without an EXIF focal")
    max_error: float = opt(12.0, "RANSAC inlier threshold, pixels", gt=0)
    min_inliers: int = opt(30, "fewest 2D-3D inliers to place a photo", ge=6)
    min_inlier_ratio: float = opt(0.25, "smallest fraction of the 2D-3D matches that are inliers", ge=0, le=1)
