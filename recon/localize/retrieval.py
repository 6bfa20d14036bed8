"""Which registered reference images a new photo is matched with: the most similar by VLAD.

The global descriptor is the matching stage's (:func:`recon.sparse.pairs.global_descriptors`: VLAD
over a vocabulary learned from the images' own RootSIFT descriptors, no vocabulary file). It is
learned here from the reference's registered images and the new photos together, as the matching
stage learns it from all photos of a run.
"""

from __future__ import annotations

import numpy as np

from recon.localize.reference import Reference
from recon.sparse.pairs import global_descriptors


def retrieve(reference: Reference, descriptors: list[np.ndarray], neighbours: int, words: int = 64,
             seed: int = 0) -> list[list[int]]:
    """For each new photo (its SIFT descriptors), the ids of its ``neighbours`` most similar
    registered reference images, most similar first."""
    if not descriptors:
        return []
    ids = reference.image_ids
    vlad = global_descriptors([reference.descriptors[i] for i in ids] + list(descriptors), words=words, seed=seed)
    similarity = vlad[len(ids):] @ vlad[: len(ids)].T
    order = np.argsort(-similarity, axis=1, kind="stable")[:, :neighbours]
    return [[ids[j] for j in row] for row in order]
