"""Which image pairs to match.

Exhaustive matching costs n(n-1)/2 full matches, most of them between photos that share nothing.
``retrieval`` ranks images by a global descriptor (VLAD over a vocabulary learned from the images'
own descriptors, so no vocabulary file is needed) and matches each with its most similar ones.
``sequential`` pairs each frame with the next ones (video, ordered walks) and adds loop-closure
candidates from the same retrieval ranking. ``spatial`` pairs each photo with the photos nearest to
where its GPS tag says it was taken; retrieval adds pairs for photos without GPS and a few
appearance neighbours per photo (a tilted view of something far away, a wrong GPS tag).
Every method but exhaustive gives at most a fixed number of pairs per photo: linear in n.
"""

from __future__ import annotations

import numpy as np

Pair = tuple[int, int]  # indices into the sorted image list, i < j


def exhaustive_pairs(n: int) -> list[Pair]:
    return [(i, j) for i in range(n) for j in range(i + 1, n)]


def sequential_pairs(n: int, overlap: int, quadratic: bool = True) -> list[Pair]:
    """Each image with its ``overlap`` successors, and (quadratic) with successors at 2^k offsets."""
    pairs = set()
    for i in range(n):
        for d in range(1, overlap + 1):
            if i + d < n:
                pairs.add((i, i + d))
        if quadratic:
            for k in range(overlap):
                d = 2 ** k
                if d > overlap and i + d < n:
                    pairs.add((i, i + d))
    return sorted(pairs)


def global_descriptors(descriptors: list[np.ndarray], words: int = 64, seed: int = 0,
                       sample: int = 20000) -> np.ndarray:
    """One VLAD vector per image (Jegou et al. 2010), over a vocabulary learned from the images' own
    RootSIFT descriptors; intra-normalised and power-law normalised, unit length. n x (words*128)."""
    import cv2

    roots = [_rootsift(d) for d in descriptors]
    rng = np.random.default_rng(seed)
    per_image = max(1, sample // max(1, len(roots)))
    pool = np.concatenate([r[rng.choice(len(r), min(len(r), per_image), replace=False)] for r in roots if len(r)])
    words = min(words, len(pool))
    cv2.setRNGSeed(seed)
    criteria = (cv2.TERM_CRITERIA_MAX_ITER + cv2.TERM_CRITERIA_EPS, 20, 1e-4)
    _, _, centres = cv2.kmeans(pool, words, None, criteria, 1, cv2.KMEANS_PP_CENTERS)
    norms = (centres ** 2).sum(axis=1)
    out = np.zeros((len(roots), words * pool.shape[1]), np.float32)
    for i, r in enumerate(roots):
        if not len(r):
            continue
        assign = (norms - 2.0 * r @ centres.T).argmin(axis=1)
        vlad = np.zeros_like(centres)
        np.add.at(vlad, assign, r - centres[assign])
        vlad /= np.maximum(np.linalg.norm(vlad, axis=1, keepdims=True), 1e-6)
        v = vlad.ravel()
        v = np.sign(v) * np.sqrt(np.abs(v))
        out[i] = v / max(float(np.linalg.norm(v)), 1e-6)
    return out


def _rootsift(d: np.ndarray) -> np.ndarray:
    d = d.astype(np.float32)
    return np.sqrt(d / np.maximum(d.sum(axis=1, keepdims=True), 1e-6))


def retrieval_pairs(similarity: np.ndarray, neighbors: int, images=None) -> list[Pair]:
    """Each of ``images`` (indices; default all) with its ``neighbors`` most similar images (by
    global descriptor)."""
    n = len(similarity)
    sim = similarity.copy()
    np.fill_diagonal(sim, -np.inf)
    keep = set()
    for i in range(n) if images is None else map(int, images):
        for j in np.argsort(-sim[i], kind="stable")[:neighbors]:
            keep.add((min(i, int(j)), max(i, int(j))))
    return sorted(keep)


def loop_pairs(similarity: np.ndarray, exclude_within: int, per_image: int) -> list[Pair]:
    """For sequences: each image's ``per_image`` most similar images farther than ``exclude_within`` frames."""
    n = len(similarity)
    keep = set()
    for i in range(n):
        candidates = [int(j) for j in np.argsort(-similarity[i], kind="stable") if abs(int(j) - i) > exclude_within]
        keep.update((min(i, j), max(i, j)) for j in candidates[:per_image])
    return sorted(keep)


def gps_positions(images: list[dict], names: list[str]) -> np.ndarray:
    """East-North-Up metres (n, 3) of the photos ``names`` from their ``gps`` records in an
    ``images.json`` list (NaN rows: no GPS). Heights count only when every tagged photo has an
    altitude; otherwise positions are horizontal (up = 0), so a photo without altitude is not
    placed at sea level among photos tagged 400 m above it."""
    from recon.geometry.gps import enu_from_wgs84

    tags = {img["name"]: img["gps"] for img in images if img.get("gps")}
    out = np.full((len(names), 3), np.nan)
    tagged = [k for k, name in enumerate(names) if name in tags]
    if not tagged:
        return out
    with_alt = all(tags[names[k]].get("alt") is not None for k in tagged)
    lla = np.array([[tags[names[k]]["lat"], tags[names[k]]["lon"],
                     tags[names[k]]["alt"] if with_alt else 0.0] for k in tagged], dtype=float)
    enu = enu_from_wgs84(lla, tuple(lla[0]))
    if not with_alt:
        enu[:, 2] = 0.0
    out[tagged] = enu
    return out


def spatial_pairs(positions: np.ndarray, neighbors: int, max_distance: float = 0.0) -> list[Pair]:
    """Each image with a position (rows of ``positions``; NaN: none) with its ``neighbors`` nearest
    positioned images, leaving out those farther than ``max_distance`` when it is > 0."""
    from scipy.spatial import cKDTree

    placed = np.flatnonzero(np.isfinite(positions).all(axis=1))
    if len(placed) < 2 or neighbors < 1:
        return []
    k = min(neighbors + 1, len(placed))  # + itself
    bound = max_distance if max_distance > 0 else np.inf
    dist, idx = cKDTree(positions[placed]).query(positions[placed], k=k, distance_upper_bound=bound)
    keep = set()
    for row, (d_row, i_row) in enumerate(zip(dist, idx)):
        others = [int(placed[j]) for d, j in zip(d_row, i_row) if np.isfinite(d) and j != row]
        i = int(placed[row])
        keep.update((min(i, j), max(i, j)) for j in others[:neighbors])
    return sorted(keep)


def spatial_matching_pairs(positions: np.ndarray, similarity: np.ndarray | None, nearest: int,
                           max_distance: float, neighbors: int, appearance: int) -> list[Pair]:
    """``spatial`` matching: each photo with a position with its ``nearest`` nearest
    (:func:`spatial_pairs`), each photo without one with its ``neighbors`` most similar, and every
    photo with its ``appearance`` most similar; ``similarity`` may be None when no photo needs it."""
    found = set(spatial_pairs(positions, nearest, max_distance))
    without = np.flatnonzero(~np.isfinite(positions).all(axis=1))
    if len(without) or appearance:
        found.update(retrieval_pairs(similarity, neighbors, images=without))
        found.update(retrieval_pairs(similarity, appearance))
    return sorted(found)


def neighbor_distance(positions: np.ndarray, neighbors: int) -> float:
    """The median, over positioned images, of the distance to their ``neighbors``-th nearest one:
    how far apart the photos that spatial matching pairs are (0 with fewer than 2 positions)."""
    from scipy.spatial import cKDTree

    placed = positions[np.isfinite(positions).all(axis=1)]
    if len(placed) < 2:
        return 0.0
    k = min(neighbors + 1, len(placed))
    dist, _ = cKDTree(placed).query(placed, k=k)
    return float(np.median(dist[:, -1]))
