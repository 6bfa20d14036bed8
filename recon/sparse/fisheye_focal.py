"""A fisheye camera's focal length from its photos, for when no EXIF gives it.

COLMAP estimates no two-view geometry between fisheye photos without a focal length prior (it marks
such pairs degenerate), so with no focal nothing registers; with a wrong one, little does. But the
pairs themselves tell focal lengths apart: with the right rays, a pair's essential matrix explains
the most matches at a tight threshold. So: match a few pairs of photos taken one after the other
(names in capture order) once; count their essential-matrix inliers (COLMAP's LO-RANSAC on the
camera's rays) for candidate focal lengths spread over the plausible fields of view, then around the
best; the vertex of a parabola through the best three (in log focal) is the estimate. The sfm stage
refines it in bundle adjustment.

Candidates are equidistant fisheyes (image radius = f x angle, which every COLMAP fisheye model is
at zero distortion) from FOV_RANGE_DEG[0] to FOV_RANGE_DEG[1] across the image diagonal; the upper
end covers circular fisheyes, whose image circle lies inside the frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from recon.sparse.sift_match import sift_matches

FOV_RANGE_DEG = (100.0, 300.0)
COARSE_STEP = 1.1  # ratio between neighbouring coarse candidates
FINE_STEP = 1.03
ANCHORS = 8  # pairs (i, i+1) and (i, i+2) for this many photos i spread over the set
MIN_MATCHES = 30  # a pair with fewer SIFT matches is left out


@dataclass(frozen=True)
class FocalEstimate:
    """The focal length found (pixels), its diagonal field of view as an equidistant fisheye, the
    pairs scored, and every candidate tried with its summed inlier count."""

    focal: float
    diagonal_fov_deg: float
    pairs: int
    scores: tuple[tuple[float, int], ...]


def estimate_focal(camera, count: int, features: Callable[[int], tuple[np.ndarray, np.ndarray]],
                   threshold: float = 0.5, seed: int = 0) -> FocalEstimate | None:
    """The focal length of fisheye ``camera`` (a pycolmap Camera: model, size, principal point and
    distortion are kept) from its ``count`` photos in capture order; ``features(i)``: photo i's
    keypoints (N x 2+, photo pixels) and SIFT descriptors (N x 128), read for the pairs scored only.
    ``threshold``: RANSAC inlier threshold in photo pixels. None when no pair has MIN_MATCHES matches."""
    import pycolmap

    matched = []
    for a, b in _pairs(count):
        (kp_a, desc_a), (kp_b, desc_b) = features(a), features(b)
        m = sift_matches(desc_a, desc_b, 0.8, 0.7, True)
        if len(m) >= MIN_MATCHES:
            matched.append((kp_a[m[:, 0], :2].astype(np.float64), kp_b[m[:, 1], :2].astype(np.float64)))
    if not matched:
        return None
    ransac = pycolmap.RANSACOptions()
    ransac.max_error = threshold
    ransac.random_seed = seed
    ransac.min_num_trials = 200  # COLMAP's 1000 costs 4x the time for the same estimate (synthetic orbit)
    scores: dict[float, int] = {}

    def score(focal: float) -> int:
        if focal not in scores:
            params = np.array(camera.params, np.float64)
            params[list(camera.focal_length_idxs())] = focal
            cam = pycolmap.Camera(model=camera.model, width=camera.width, height=camera.height, params=params)
            found = (pycolmap.estimate_essential_matrix(x1, x2, cam, cam, ransac) for x1, x2 in matched)
            scores[focal] = sum(r["num_inliers"] for r in found if r)
        return scores[focal]

    half_diagonal = np.hypot(camera.width, camera.height) / 2
    f_max = half_diagonal / np.radians(FOV_RANGE_DEG[0] / 2)
    f_min = half_diagonal / np.radians(FOV_RANGE_DEG[1] / 2)
    coarse = f_min * COARSE_STEP ** np.arange(int(np.ceil(np.log(f_max / f_min) / np.log(COARSE_STEP))) + 1)
    best = max(coarse, key=score)
    fine = [best / FINE_STEP, best, best * FINE_STEP]
    best = max(fine, key=score)
    if best != fine[1]:  # moved: centre the three fine points on it
        fine = [best / FINE_STEP, best, best * FINE_STEP]
        best = max(fine, key=score)
    focal = _vertex(fine, [score(f) for f in fine]) if best == fine[1] else best
    return FocalEstimate(float(focal), float(np.degrees(2 * half_diagonal / focal)), len(matched),
                         tuple(sorted((float(f), s) for f, s in scores.items())))


def _pairs(n: int) -> list[tuple[int, int]]:
    """Photos (i, i+1) and (i, i+2) for ANCHORS photos i spread over ``n``."""
    anchors = np.unique(np.linspace(0, max(n - 2, 0), ANCHORS).round().astype(int))
    return sorted({(int(i), int(j)) for i in anchors for j in (i + 1, i + 2) if j < n})


def _vertex(focals: list[float], scores: list[int]) -> float:
    """The top of the parabola through three (log focal, score) points equally spaced in log focal,
    the middle one the highest; kept within the outer two."""
    left, mid, right = scores
    curvature = left - 2 * mid + right
    if curvature >= 0:
        return focals[1]
    offset = 0.5 * (left - right) / curvature  # in steps, within [-0.5, 0.5] as the middle is highest
    return float(focals[1] * FINE_STEP ** offset)
