"""Which image pairs to match.

Exhaustive matching costs n(n-1)/2 full matches, most of them between photos that share nothing.
``retrieval`` ranks images by a global descriptor (VLAD over a vocabulary learned from the images'
own descriptors, so no vocabulary file is needed) and matches each with its most similar ones.
``sequential`` pairs each frame with the next ones (video, ordered walks) and adds loop-closure
candidates from the same retrieval ranking.
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


def retrieval_pairs(similarity: np.ndarray, neighbors: int) -> list[Pair]:
    """Each image with its ``neighbors`` most similar images (by global descriptor)."""
    n = len(similarity)
    sim = similarity.copy()
    np.fill_diagonal(sim, -np.inf)
    keep = set()
    for i in range(n):
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
