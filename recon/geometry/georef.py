"""Georeferencing: the similarity that takes a model's camera centres onto their photos' GPS positions,
or its points onto surveyed ground control points (:func:`align_to_control`).

RANSAC over minimal sets of three photos (MSAC cost), each photo's inlier threshold set by its own
GPS accuracy, then least squares (Umeyama, :func:`recon.geometry.transforms.umeyama`) on the inliers,
repeated until the inlier set no longer changes. How well the GPS fixes the scale and the cameras
is measured by a bootstrap over the inlier photos: the spread of the scale and of each aligned
camera centre over fits to resampled photo sets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recon.geometry.transforms import Similarity, umeyama, weighted_umeyama

#: 99 % quantile of the length of a 3D vector of independent N(0, 1) components (chi, 3 degrees of
#: freedom): a camera centre farther than this many GPS sigmas from its GPS position is an outlier
CHI3_99 = 3.368
#: the positions must spread across their main line by this many GPS sigmas (RMS), or the rotation
#: about that line is set by GPS noise alone
MIN_SPREAD_SIGMAS = 2.0


class GeorefError(ValueError):
    """The positions cannot fix a similarity: too few, or along a line."""


@dataclass(frozen=True, eq=False)
class Alignment:
    """A fitted model -> GPS similarity and how well each photo agrees with it (lengths in metres)."""

    similarity: Similarity  # model coordinates -> GPS frame
    aligned: np.ndarray  # (N, 3) the camera centres in the GPS frame
    residuals: np.ndarray  # (N,) |similarity(centre) - gps|
    inliers: np.ndarray  # (N,) bool: residual within the photo's threshold
    thresholds: np.ndarray  # (N,) CHI3_99 x the photo's GPS sigma
    scale_std: float  # relative standard deviation of the scale (bootstrap over inlier photos)
    position_std: float  # median over photos of the bootstrap spread (RMS) of the aligned centre

    @property
    def median(self) -> float:
        """Median residual of the inlier photos."""
        return float(np.median(self.residuals[self.inliers]))

    @property
    def p90(self) -> float:
        """90th percentile of the inlier photos' residuals."""
        return float(np.percentile(self.residuals[self.inliers], 90))


def align_to_gps(centres: np.ndarray, gps: np.ndarray, sigma: np.ndarray | float, *, seed: int = 0,
                 max_iterations: int = 2000, confidence: float = 0.999, bootstrap: int = 200) -> Alignment:
    """Robust similarity with ``gps ~ s R centres + t`` for paired positions (N, 3), N >= 3.

    ``gps`` in metres (a local ENU frame); ``sigma``: GPS accuracy per photo (or one for all); a photo is an
    inlier while its residual is at most ``CHI3_99 * sigma``. Raises :class:`GeorefError` when the
    positions cannot fix a similarity (fewer than 3, along a line). Whether enough photos agree is
    the caller's judgement: with fewer than 3 inliers the best minimal-set fit is returned as is.
    """
    centres = np.asarray(centres, dtype=float).reshape(-1, 3)
    gps = np.asarray(gps, dtype=float).reshape(-1, 3)
    n = len(gps)
    thresholds = CHI3_99 * np.broadcast_to(np.asarray(sigma, dtype=float), (n,)).copy()
    if n < 3 or len(centres) != n:
        raise GeorefError(f"{n} photo(s) with GPS: at least 3 are needed")
    _check_spread(gps, thresholds)
    rng = np.random.default_rng(seed)
    best = _ransac(centres, gps, thresholds, rng, max_iterations, confidence)
    if best is None:
        raise GeorefError("no three photos with GPS span a triangle wider than the GPS error")
    sim, inliers = best, None
    for _ in range(20):  # least squares on the inliers until the inlier set is stable
        residuals = np.linalg.norm(sim.apply(centres) - gps, axis=1)
        current = residuals <= thresholds
        if (inliers is not None and np.array_equal(current, inliers)) or current.sum() < 3:
            inliers = current
            break
        inliers = current
        sim = umeyama(centres[inliers], gps[inliers])
    aligned = sim.apply(centres)
    scale_std, position_std = _bootstrap(centres, gps, inliers, sim, rng, bootstrap)
    return Alignment(sim, aligned, np.linalg.norm(aligned - gps, axis=1), inliers, thresholds, scale_std,
                     position_std)


def _check_spread(gps: np.ndarray, thresholds: np.ndarray) -> None:
    """Refuse positions that lie along a line (within the GPS noise): a walk down one street, a
    single drone strip. The rotation about the line would be noise."""
    sigma = float(np.median(thresholds)) / CHI3_99
    spread = np.linalg.svd(gps - gps.mean(0), compute_uv=False) / math.sqrt(len(gps))
    if spread[1] < MIN_SPREAD_SIGMAS * sigma:
        raise GeorefError(f"the photos' GPS positions lie along a line (spread across it {spread[1]:.2g} m, "
                          f"GPS accuracy {sigma:.2g} m): the rotation about that line cannot be fixed")


def _ransac(centres, gps, thresholds, rng, max_iterations: int, confidence: float):
    """Best minimal-set similarity by MSAC cost (residuals over thresholds, truncated at 1)."""
    n = len(gps)
    best, best_cost, needed, it = None, math.inf, max_iterations, 0
    while it < min(needed, max_iterations):
        it += 1
        idx = rng.choice(n, 3, replace=False)
        a, b, c = gps[idx]
        longest = max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b))
        height = np.linalg.norm(np.cross(b - a, c - a)) / max(longest, 1e-300)
        if height < thresholds[idx].max() / CHI3_99:
            continue  # a sliver: its rotation is set by GPS noise
        sim = umeyama(centres[idx], gps[idx])
        residuals = np.linalg.norm(sim.apply(centres) - gps, axis=1)
        cost = float(np.minimum((residuals / thresholds) ** 2, 1.0).sum())
        if cost < best_cost:
            best, best_cost = sim, cost
            share = np.count_nonzero(residuals <= thresholds) / n
            if share >= 1.0:
                needed = 0
            elif share > 0:
                needed = math.ceil(math.log(1 - confidence) / math.log(1 - share**3))
    return best


def _bootstrap(centres, gps, inliers, sim: Similarity, rng, samples: int) -> tuple[float, float]:
    """Relative std of the scale, and the median RMS spread of the aligned centres, over Umeyama fits
    to inlier photos drawn with replacement."""
    idx = np.flatnonzero(inliers)
    if samples <= 0 or len(idx) < 4:
        return math.nan, math.nan
    scales, placed = [], []
    for _ in range(samples):
        draw = rng.choice(idx, len(idx), replace=True)
        if len(np.unique(draw)) < 3:
            continue
        fit = umeyama(centres[draw], gps[draw])
        scales.append(fit.s)
        placed.append(fit.apply(centres))
    spread = np.sqrt(np.stack(placed).var(axis=0).sum(axis=1))
    return float(np.std(scales) / sim.s), float(np.median(spread))


@dataclass(frozen=True, eq=False)
class ControlAlignment:
    """A fitted model -> frame similarity from control points (and optionally GPS anchors)."""

    similarity: Similarity
    residuals: np.ndarray  # (N, 3) similarity(point) - target, per control point
    inliers: np.ndarray  # (N,) bool: used in the final fit
    checks: np.ndarray  # (N,) leave-one-out distance: the point's error in a fit without it (NaN: not possible)
    scale_std: float  # relative standard error of the scale: jackknife over the inliers (NaN below 3 fits)


def align_to_control(points: np.ndarray, targets: np.ndarray, sigma: float,
                     anchors: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> ControlAlignment:
    """Similarity ``targets ~ s R points + t`` from control points (N, 3) known to ``sigma`` (metres),
    jointly with ``anchors`` (source (M, 3), target (M, 3), sigma (M,)): e.g. cameras and their GPS
    positions, which fix what fewer than 3 control points cannot. Each correspondence is weighted by
    1 / sigma^2. The control point farthest from its target beyond ``CHI3_99 * sigma`` is left out
    and the fit repeated, while enough remain (3 without anchors, 1 with).

    Raises :class:`GeorefError` when the points cannot fix a similarity (too few, along a line)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    targets = np.asarray(targets, dtype=float).reshape(-1, 3)
    n, least = len(points), 3 if anchors is None else 1
    if n < least:
        raise GeorefError(f"{n} control point(s): at least {least} are needed" +
                          (" without GPS" if anchors is None else ""))
    if anchors is None:
        _check_spread(targets, np.full(n, CHI3_99 * sigma))
    inliers = np.ones(n, bool)
    while True:
        sim = _control_fit(points, targets, sigma, anchors, inliers)
        residuals = sim.apply(points) - targets
        distance = np.where(inliers, np.linalg.norm(residuals, axis=1), -1.0)
        worst = int(np.argmax(distance))
        if distance[worst] <= CHI3_99 * sigma or inliers.sum() <= least:
            break
        inliers[worst] = False
    checks, scales = np.full(n, math.nan), []
    for k in range(n):  # leave-one-out: each point's error when it does not pull the fit
        others = inliers.copy()
        others[k] = False
        if others.sum() >= least and (anchors is not None or _spans(targets[others], sigma)):
            fit = _control_fit(points, targets, sigma, anchors, others)
            checks[k] = float(np.linalg.norm(fit.apply(points[k]) - targets[k]))
            if inliers[k]:
                scales.append(fit.s)
    m = len(scales)
    scale_std = float(np.sqrt((m - 1) / m * np.sum((np.array(scales) - np.mean(scales)) ** 2)) / sim.s) \
        if m >= 3 else math.nan
    return ControlAlignment(sim, residuals, inliers, checks, scale_std)


def _control_fit(points, targets, sigma: float, anchors, use: np.ndarray) -> Similarity:
    src, dst, w = points[use], targets[use], np.full(int(use.sum()), sigma**-2.0)
    if anchors is not None:
        a_src, a_dst, a_sigma = (np.asarray(a, dtype=float) for a in anchors)
        src, dst = np.vstack([src, a_src.reshape(-1, 3)]), np.vstack([dst, a_dst.reshape(-1, 3)])
        w = np.concatenate([w, np.broadcast_to(a_sigma, (len(a_src),)) ** -2.0])
    return weighted_umeyama(src, dst, w)


def _spans(targets: np.ndarray, sigma: float) -> bool:
    try:
        _check_spread(targets, np.full(len(targets), CHI3_99 * sigma))
    except GeorefError:
        return False
    return len(targets) >= 3
