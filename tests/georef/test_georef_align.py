"""The georeferencing alignment on points with known truth: noise, gross outliers, degenerate layouts,
and whether its stated uncertainty matches the error it actually makes."""

from __future__ import annotations

import numpy as np
import pytest

from recon.geometry.georef import GeorefError, align_to_gps
from recon.geometry.gps import enu_from_wgs84, wgs84_from_enu
from recon.geometry.transforms import Similarity, umeyama
from recon.sparse.georeference import median_origin

SIGMA = 3.0  # metres, per axis
METRES_PER_UNIT = 40.0


def _orbit(n: int, rng) -> np.ndarray:
    """Camera centres of a 3.5-unit orbit at ~30 degrees elevation (recon.synth's), in model units."""
    azimuth = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(-0.02, 0.02, n)
    return np.column_stack([3.5 * np.cos(azimuth), 3.5 * np.sin(azimuth), 1.75 + rng.uniform(-0.1, 0.1, n)])


def _truth() -> Similarity:
    yaw = np.radians(37.0)
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    return Similarity(METRES_PER_UNIT, R, np.array([12.0, -30.0, 25.0]))


def _case(seed: int, n: int = 40, outliers=()):
    rng = np.random.default_rng(seed)
    centres = _orbit(n, rng)
    true_enu = _truth().apply(centres)
    gps = true_enu + rng.normal(0, SIGMA, (n, 3))
    for i in outliers:
        direction = rng.normal(size=3)
        gps[i] = true_enu[i] + 100.0 * direction / np.linalg.norm(direction)
    return centres, true_enu, gps


@pytest.mark.parametrize("outliers", [(), (3, 17, 29)])
def test_noisy_gps_with_gross_outliers(outliers):
    """Done-when figures of issue 16 at the library level: centres within 1.5 m (median) of the
    truth, scale within 1 %, the 100 m outliers named and nothing else."""
    centres, true_enu, gps = _case(seed=7, outliers=outliers)
    fit = align_to_gps(centres, gps, SIGMA, seed=0)
    assert sorted(np.flatnonzero(~fit.inliers)) == list(outliers)
    error = np.linalg.norm(fit.aligned - true_enu, axis=1)
    assert np.median(error) < 1.5
    assert abs(fit.similarity.s / METRES_PER_UNIT - 1) < 0.01
    # residuals against the (noisy) GPS: chi-3 with sigma 3: median ~4.6 m
    assert 2.5 < fit.median < 6.5 and fit.p90 < CHI3_99_TIMES_SIGMA
    assert all(fit.residuals[list(outliers)] > 80)


CHI3_99_TIMES_SIGMA = 3.368 * SIGMA


def test_stated_uncertainty_matches_the_error_made():
    """Over 40 independent noise draws, the bootstrap's scale and position spreads agree with the
    errors the fits actually make (within a factor 1.6): the reported uncertainty is honest."""
    scale_errors, scale_stds, position_errors, position_stds = [], [], [], []
    for seed in range(40):
        centres, true_enu, gps = _case(seed=100 + seed, n=30)
        fit = align_to_gps(centres, gps, SIGMA, seed=seed, bootstrap=100)
        scale_errors.append(fit.similarity.s / METRES_PER_UNIT - 1)
        scale_stds.append(fit.scale_std)
        position_errors.append(np.sqrt(np.mean(np.sum((fit.aligned - true_enu) ** 2, axis=1))))
        position_stds.append(fit.position_std)
    ratio_scale = np.sqrt(np.mean(np.square(scale_errors))) / np.mean(scale_stds)
    ratio_position = np.mean(position_errors) / np.mean(position_stds)
    assert 1 / 1.6 < ratio_scale < 1.6, ratio_scale
    assert 1 / 1.6 < ratio_position < 1.6, ratio_position


def test_per_photo_accuracy_sets_the_threshold():
    """A photo 20 m off is an outlier for 3 m GPS, an inlier when that photo states 10 m accuracy."""
    centres, _, gps = _case(seed=3, n=20)
    gps[5] += np.array([20.0, 0.0, 0.0])
    sigma = np.full(20, SIGMA)
    assert not align_to_gps(centres, gps, sigma).inliers[5]
    sigma[5] = 10.0
    assert align_to_gps(centres, gps, sigma).inliers[5]


def test_positions_along_a_line_are_refused():
    rng = np.random.default_rng(0)
    s = np.linspace(0, 10, 15)
    centres = np.column_stack([s, 0.01 * rng.normal(size=15), 0.01 * rng.normal(size=15)])
    gps = _truth().apply(centres) + rng.normal(0, SIGMA, (15, 3))
    with pytest.raises(GeorefError, match="along a line"):
        align_to_gps(centres, gps, SIGMA)


def test_too_few_photos_are_refused_and_disagreement_shows():
    centres, _, gps = _case(seed=1, n=8)
    with pytest.raises(GeorefError, match="at least 3"):
        align_to_gps(centres[:2], gps[:2], SIGMA)
    scrambled = gps[np.random.default_rng(2).permutation(8)]  # no consistent similarity exists
    assert align_to_gps(centres, scrambled, 0.5).inliers.sum() < 3  # the caller refuses it


def test_same_seed_same_result():
    centres, _, gps = _case(seed=11, outliers=(0, 1))
    a, b = (align_to_gps(centres, gps, SIGMA, seed=5) for _ in range(2))
    assert np.array_equal(a.aligned, b.aligned) and a.scale_std == b.scale_std


def test_enu_round_trip_and_origin():
    origin = (52.52, 13.405, 34.0)
    enu = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [0.0, 250.0, -5.0], [-40.0, 30.0, 12.0]])
    lla = wgs84_from_enu(enu, origin)
    assert lla[0] == pytest.approx(origin)
    assert lla[1, 1] > origin[1] and lla[2, 0] > origin[0]  # east is +lon, north is +lat
    assert enu_from_wgs84(lla, origin) == pytest.approx(enu, abs=1e-6)
    # 1e-5 degree of latitude is 1.11 m
    assert enu_from_wgs84([[origin[0] + 1e-5, origin[1], origin[2]]], origin)[0, 1] == pytest.approx(1.113, abs=2e-3)
    # the median position: a far-off fix does not move it
    fixes = wgs84_from_enu(np.array([[-10.0, -10, 0], [10, 10, 2], [2, -3, 1], [5000, 0, 0]]), origin)
    centre = median_origin([dict(zip(("lat", "lon", "alt"), f)) for f in fixes])
    assert enu_from_wgs84([centre], origin)[0] == pytest.approx([6.0, -1.5, 0.5], abs=0.01)  # the mean: x 1250


def test_umeyama_reference_for_the_least_squares_step():
    """Without noise or outliers the robust fit is the exact similarity."""
    centres, true_enu, _ = _case(seed=0, n=10)
    fit = align_to_gps(centres, true_enu, SIGMA)
    exact = umeyama(centres, true_enu)
    assert fit.similarity.s == pytest.approx(exact.s) and fit.aligned == pytest.approx(true_enu, abs=1e-9)
