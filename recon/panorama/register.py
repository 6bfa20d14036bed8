"""Registration of photos from a camera rotating about its centre: features, pairwise homographies
with RANSAC, initial rotations and focal lengths from them, bundle adjustment on rays, wave
correction. All of it is OpenCV's stitching module (``cv2.detail``); this module drives it, keeps the
photos that connect, and measures how well the cameras agree with the matches.

Two things OpenCV does that a panorama tool must not:

- ``BestOf2NearestMatcher`` zeroes the confidence of pairs with more than ~3x the inliers its
  confidence formula expects ("too similar" images). Clean, well-overlapping photos hit that, which
  would cut a ring in pieces; the confidence is restored from the inlier and match counts.
- ``leaveBiggestComponent`` edits its arguments in place in C++, which Python does not see; the
  connected subset is rebuilt here with re-indexed matches.

Pair residuals: for the RANSAC inliers of a linked pair, the angle between the two photos' rays
under the current cameras, in pixels (times the focal length). Before the bundle adjustment the
cameras come from chaining homographies along a spanning tree, so the pair that closes a 360 deg
ring shows the drift accumulated around it; after it, every pair should be at the noise level.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import cv2
import numpy as np

from recon.panorama.options import PanoramaOptions

log = logging.getLogger(__name__)


class PanoramaError(ValueError):
    """The photos cannot be made into a panorama; the message says why, in one line."""


@dataclasses.dataclass(frozen=True)
class Pair:
    """A matched pair of photos (indices into the input list)."""

    i: int
    j: int
    matches: int
    inliers: int
    confidence: float
    residual_before: float  # median angle between its inliers' rays x focal (full-resolution px), before BA
    residual_after: float  # the same after bundle adjustment


@dataclasses.dataclass(frozen=True)
class Registration:
    """The cameras of the photos that connect, in input order."""

    connected: list[int]  # input indices of the stitched photos
    dropped: dict[int, str]  # input index -> why it could not be connected
    rotations: np.ndarray  # (n, 3, 3) camera-to-panorama, for the connected photos
    focals: np.ndarray  # (n,) pixels at full resolution
    principal: np.ndarray  # (n, 2) COLMAP convention, full resolution
    pairs: list[Pair]  # the linked pairs (confidence >= options.pair_confidence)
    timings: dict[str, float]


def register(images: list[np.ndarray], options: PanoramaOptions = PanoramaOptions(),
             focal_priors: list[float | None] | None = None, names: list[str] | None = None) -> Registration:
    """Register RGB uint8 photos taken by a camera rotating about its centre. ``focal_priors`` (pixels,
    None where unknown) are used with ``options.focal == "prior"``; ``names`` label the photos in
    messages."""
    n = len(images)
    names = names or [f"photo {k}" for k in range(n)]
    if n < 2:
        raise PanoramaError(f"a panorama needs at least 2 photos, got {n}")
    timings: dict[str, float] = {}
    sizes = [(img.shape[1], img.shape[0]) for img in images]

    t = time.perf_counter()
    scales = [min(1.0, np.sqrt(options.registration_megapix * 1e6 / (w * h))) for w, h in sizes]
    finder = cv2.SIFT_create(nfeatures=options.max_features) if options.features == "sift" \
        else cv2.ORB_create(nfeatures=options.max_features)
    features = []
    for img, scale in zip(images, scales):
        small = img if scale == 1.0 else cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        features.append(cv2.detail.computeImageFeatures2(finder, small))
    timings["features"] = time.perf_counter() - t
    counts = [len(f.keypoints) for f in features]
    log.info("features: %d photos, %d-%d %s keypoints (median %d), %.2f s", n, min(counts), max(counts),
             options.features, int(np.median(counts)), timings["features"])

    t = time.perf_counter()
    matches = _match(features, options)
    timings["matching"] = time.perf_counter() - t
    all_pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
    linked = sum(matches[i * n + j].confidence >= options.pair_confidence for i, j in all_pairs)
    log.info("matching: %d pairs compared, %d linked (confidence >= %g), %.2f s",
             _pairs_compared(n, options), linked, options.pair_confidence, timings["matching"])
    if not linked:
        i, j = max(all_pairs, key=lambda p: matches[p[0] * n + p[1]].confidence)
        best = matches[i * n + j]
        raise PanoramaError(f"no two of the {n} photos overlap enough to be stitched (best pair: {names[i]} "
                            f"and {names[j]}, {best.num_inliers} inliers, confidence {best.confidence:.2f} < "
                            f"{options.pair_confidence:g}); are they from one viewpoint?")
    keep = [int(k) for k in cv2.detail.leaveBiggestComponent(features, matches, options.pair_confidence)]
    dropped = {k: _why_dropped(k, matches, names, options) for k in range(n) if k not in keep}
    for k, why in dropped.items():
        log.warning("%s not stitched: %s", names[k], why)
    sub_features, sub_matches = _subset(features, matches, keep, n)

    t = time.perf_counter()
    ok, cameras = cv2.detail_HomographyBasedEstimator().apply(sub_features, sub_matches, None)
    if not ok:
        raise PanoramaError("the pairwise homographies do not give consistent camera rotations; "
                            "the photos may not share one viewpoint")
    for cam, k in zip(cameras, keep):
        w, h = features[k].img_size
        cam.R = cam.R.astype(np.float32)
        cam.ppx, cam.ppy = (w - 1) / 2.0, (h - 1) / 2.0  # the centre (OpenCV's pixel-index convention)
        prior = focal_priors[k] if focal_priors is not None else None
        if options.focal == "prior" and prior:
            cam.focal = prior * scales[k]
    timings["estimate"] = time.perf_counter() - t
    before = [_residual(cameras, sub_features, sub_matches, a, b) for a, b in _linked(keep, sub_matches, options)]

    t = time.perf_counter()
    adjuster = cv2.detail_BundleAdjusterRay()  # rotations and each photo's focal (it has no refinement mask)
    adjuster.setConfThresh(options.pair_confidence)
    ok, cameras = adjuster.apply(sub_features, sub_matches, cameras)
    if not ok:
        raise PanoramaError("bundle adjustment of the camera rotations failed; the matches are inconsistent")
    timings["bundle_adjustment"] = time.perf_counter() - t
    after = [_residual(cameras, sub_features, sub_matches, a, b) for a, b in _linked(keep, sub_matches, options)]

    t = time.perf_counter()
    rotations = [np.asarray(cam.R, np.float32) for cam in cameras]
    if options.wave_correct != "none" and len(rotations) > 1:
        kind = {"horizontal": cv2.detail.WAVE_CORRECT_HORIZ, "vertical": cv2.detail.WAVE_CORRECT_VERT,
                "auto": cv2.detail.WAVE_CORRECT_AUTO}[options.wave_correct]
        rotations = list(cv2.detail.waveCorrect(rotations, kind))
    timings["wave_correct"] = time.perf_counter() - t

    ratio = [sizes[k][0] / features[k].img_size[0] for k in keep]  # full / registration resolution
    focals = np.array([cam.focal * r for cam, r in zip(cameras, ratio)])
    principal = np.array([[(cam.ppx + 0.5) * r, (cam.ppy + 0.5) * r] for cam, r in zip(cameras, ratio)])
    f = float(np.median(focals))
    before, after = np.array(before) * f, np.array(after) * f
    pairs = []
    for (a, b), res0, res1 in zip(_linked(keep, sub_matches, options), before, after):
        m = sub_matches[a * len(keep) + b]
        pairs.append(Pair(keep[a], keep[b], len(m.matches), int(m.num_inliers), float(m.confidence),
                          float(res0), float(res1)))
    log.info("cameras: %d of %d photos connected, focal %.1f px (%.1f-%.1f); pair residual median/max "
             "%.2f/%.2f px before bundle adjustment (%.2f s), %.2f/%.2f px after (%.2f s)",
             len(keep), n, f, focals.min(), focals.max(), np.median(before),
             np.max(before), timings["estimate"], np.median(after), np.max(after), timings["bundle_adjustment"])
    return Registration(keep, dropped, np.array([np.asarray(R, np.float64) for R in rotations]),
                        focals, principal, pairs, timings)


def _pairs_compared(n: int, options: PanoramaOptions) -> int:
    if options.match_window == 0 or options.match_window >= n - 1:
        return n * (n - 1) // 2
    return int(_window_mask(n, options.match_window).sum())


def _window_mask(n: int, window: int) -> np.ndarray:
    """Upper-triangular mask of the pairs (i, i + 1..window), cyclically."""
    mask = np.zeros((n, n), np.uint8)
    for i in range(n):
        for step in range(1, window + 1):
            j = (i + step) % n
            if i != j:
                mask[min(i, j), max(i, j)] = 1
    return mask


def _match(features: list, options: PanoramaOptions) -> list:
    """All n x n pairwise matches (entry i * n + j: photo i to photo j), confidences restored."""
    n = len(features)
    matcher = cv2.detail_BestOf2NearestMatcher(False, options.match_conf)
    if options.match_window == 0 or options.match_window >= n - 1:
        matches = matcher.apply2(features)
    else:
        matches = matcher.apply2(features, _window_mask(n, options.match_window))
    for m in matches:
        if m.src_img_idx >= 0 and m.num_inliers > 0 and m.confidence == 0:
            m.confidence = m.num_inliers / (8 + 0.3 * len(m.matches))  # undo the "too similar" zeroing
    return matches


def _why_dropped(k: int, matches: list, names: list[str], options: PanoramaOptions) -> str:
    n = len(names)
    best = max((j for j in range(n) if j != k), key=lambda j: matches[k * n + j].confidence)
    m = matches[k * n + best]
    if m.confidence >= options.pair_confidence:
        return (f"it links only to photos outside the largest connected group (best: {names[best]}, "
                f"{m.num_inliers} inliers)")
    return (f"no overlap found with the other photos (best: {names[best]}, {m.num_inliers} inliers, "
            f"confidence {m.confidence:.2f} < {options.pair_confidence:g})")


def _subset(features: list, matches: list, keep: list[int], n: int) -> tuple[list, list]:
    """Features and n' x n' matches of the kept photos, re-indexed 0..n'-1."""
    sub_features = []
    for a, k in enumerate(keep):
        features[k].img_idx = a
        sub_features.append(features[k])
    sub_matches = []
    for a, i in enumerate(keep):
        for b, j in enumerate(keep):
            m = matches[i * n + j]
            if m.src_img_idx >= 0:
                m.src_img_idx, m.dst_img_idx = a, b
            sub_matches.append(m)
    return sub_features, sub_matches


def _linked(keep: list[int], matches: list, options: PanoramaOptions) -> list[tuple[int, int]]:
    m = len(keep)
    return [(a, b) for a in range(m) for b in range(a + 1, m) if matches[a * m + b].confidence >= options.pair_confidence]


def _residual(cameras: list, features: list, matches: list, a: int, b: int) -> float:
    """Median angle (radians) between the rays of pair (a, b)'s RANSAC inliers under the cameras."""
    m = matches[a * len(features) + b]
    inl = np.asarray(m.inliers_mask, bool).ravel()
    pairs = [d for d, keep in zip(m.matches, inl) if keep]
    if not pairs:
        return float("nan")
    pa = np.array([features[a].keypoints[d.queryIdx].pt for d in pairs])
    pb = np.array([features[b].keypoints[d.trainIdx].pt for d in pairs])

    def rays(cam, p):
        r = np.column_stack([(p[:, 0] - cam.ppx) / cam.focal, (p[:, 1] - cam.ppy) / (cam.focal * cam.aspect),
                             np.ones(len(p))]) @ np.asarray(cam.R, np.float64).T
        return r / np.linalg.norm(r, axis=1, keepdims=True)

    ra, rb = rays(cameras[a], pa), rays(cameras[b], pb)
    angle = 2 * np.arcsin(np.clip(np.linalg.norm(ra - rb, axis=1) / 2, 0, 1))
    return float(np.median(angle))
