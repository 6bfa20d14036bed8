"""Spatial pair selection (``matching.method: spatial``) on synthetic GPS positions, and ``auto``'s choice."""

from __future__ import annotations

import numpy as np
import pytest

from recon.geometry.gps import wgs84_from_enu
from recon.sparse import pairs as pairing
from recon.stages.matching import MatchingConfig, auto_method

ORIGIN = (47.3769, 8.5417, 430.0)


def _survey(n: int, rng: np.random.Generator, along: float = 8.0, across: float = 15.0) -> np.ndarray:
    """``n`` camera positions on flight lines of 20 (ENU metres), 35 m up, with 1 m of jitter."""
    k = np.arange(n)
    xy = np.column_stack([(k // 20) * across, (k % 20) * along]) + rng.normal(0, 1.0, (n, 2))
    return np.column_stack([xy, 35.0 + rng.normal(0, 0.5, n)])


def _listing(positions: np.ndarray, sigma: float = 3.0) -> tuple[list[str], list[dict]]:
    """Names and ``images.json`` records carrying ``positions`` (NaN rows: no GPS) as GPS tags."""
    names = [f"p{i:04d}.jpg" for i in range(len(positions))]
    images = []
    for name, enu in zip(names, positions):
        gps = None
        if np.isfinite(enu).all():
            lat, lon, alt = wgs84_from_enu(enu, ORIGIN)[0]
            gps = {"lat": lat, "lon": lon, "alt": alt, "dop": None, "horizontal_error": sigma}
        images.append({"name": name, "gps": gps})
    return names, images


def test_gps_positions_read_back_the_enu_layout():
    positions = _survey(30, np.random.default_rng(0))
    positions[[3, 17]] = np.nan
    names, images = _listing(positions)
    found = pairing.gps_positions(images, names)
    assert np.isnan(found[[3, 17]]).all()
    tagged = np.isfinite(positions).all(axis=1)
    # the frame is at the first tagged photo: distances are those of the layout, to the millimetre
    d_true = np.linalg.norm(positions[tagged][:, None] - positions[tagged][None], axis=2)
    d_found = np.linalg.norm(found[tagged][:, None] - found[tagged][None], axis=2)
    assert np.abs(d_true - d_found).max() < 1e-3


def test_spatial_pairs_are_the_nearest_neighbours():
    rng = np.random.default_rng(1)
    positions = rng.uniform(0, 500, (120, 3))
    k = 6
    pairs = set(pairing.spatial_pairs(positions, k))
    d = np.linalg.norm(positions[:, None] - positions[None], axis=2)
    np.fill_diagonal(d, np.inf)
    for i in range(len(positions)):
        nearest = np.argsort(d[i])[:k]
        assert all((min(i, j), max(i, j)) in pairs for j in nearest)
    # and nothing else: every pair is among the k nearest of one of its photos
    for i, j in pairs:
        assert d[i, j] <= max(np.sort(d[i])[k - 1], np.sort(d[j])[k - 1])


def test_spatial_pairs_respect_max_distance():
    positions = _survey(60, np.random.default_rng(2))
    pairs = pairing.spatial_pairs(positions, 12, max_distance=20.0)
    d = [np.linalg.norm(positions[i] - positions[j]) for i, j in pairs]
    assert pairs and max(d) <= 20.0
    assert len(pairs) < len(pairing.spatial_pairs(positions, 12))  # the bound removed some


def test_spatial_pairs_grow_linearly_with_the_photos():
    rng = np.random.default_rng(3)
    counts = {n: len(pairing.spatial_pairs(_survey(n, rng), 10)) for n in (100, 200, 400, 800)}
    per_photo = [counts[n] / n for n in counts]
    assert all(c <= 10 * n for n, c in counts.items())
    assert max(per_photo) - min(per_photo) < 0.1 * min(per_photo)  # quadratic would double each time


def test_photos_without_gps_are_paired_by_appearance():
    rng = np.random.default_rng(4)
    positions = _survey(40, rng)
    missing = [5, 22, 31]
    positions[missing] = np.nan
    similarity = rng.uniform(0, 1, (40, 40))
    similarity = (similarity + similarity.T) / 2
    pairs = pairing.spatial_matching_pairs(positions, similarity, nearest=6, max_distance=0.0, neighbors=5,
                                           appearance=0)
    for i in missing:
        partners = {a if b == i else b for a, b in pairs if i in (a, b)}
        order = np.argsort(-np.where(np.arange(40) == i, -np.inf, similarity[i]), kind="stable")
        assert set(order[:5].tolist()) <= partners  # its 5 most similar photos
    # the appearance neighbours of every photo come on top of the spatial ones
    more = pairing.spatial_matching_pairs(positions, similarity, nearest=6, max_distance=0.0, neighbors=5,
                                          appearance=2)
    assert set(pairs) < set(more)
    assert set(pairing.retrieval_pairs(similarity, 2)) <= set(more)


def test_spatial_matching_without_retrieval_needs_no_similarity():
    positions = _survey(50, np.random.default_rng(5))
    pairs = pairing.spatial_matching_pairs(positions, None, nearest=8, max_distance=0.0, neighbors=15,
                                           appearance=0)
    assert pairs == pairing.spatial_pairs(positions, 8)


@pytest.mark.parametrize("case, expected", [
    ("survey", "spatial"),
    ("few_tagged", "retrieval"),
    ("small_object", "retrieval"),
    ("video", "sequential"),
    ("few_photos", "exhaustive"),
])
def test_auto_picks_spatial_for_gps_tagged_sets(case, expected):
    rng = np.random.default_rng(6)
    n = 30 if case == "few_photos" else 120
    positions = _survey(n, rng)
    if case == "few_tagged":
        positions[rng.choice(n, n // 4, replace=False)] = np.nan  # 75 % tagged
    if case == "small_object":  # photos around a 2 m object with 3 m GPS noise
        angle = np.linspace(0, 2 * np.pi, n, endpoint=False)
        positions = np.column_stack([2 * np.cos(angle), 2 * np.sin(angle), np.zeros(n)]) + rng.normal(0, 3, (n, 3))
    names, images = _listing(positions)
    found = pairing.gps_positions(images, names)
    method, why = auto_method(MatchingConfig(), n, case == "video", found, images)
    assert method == expected, why
