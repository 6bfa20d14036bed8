"""Localization: where was a new photo taken, in an existing reconstruction (COLMAP's image
registrator, hloc's localization)?

For each new photo: SIFT features (:mod:`recon.sparse.features`, with the reference's settings),
the most similar registered reference images (:mod:`.retrieval`, VLAD), 2D-3D correspondences
through the model's tracks (:mod:`.correspondences`), intrinsics (:mod:`.intrinsics`), and the pose
by RANSAC and refinement, or the reason it is refused (:mod:`.pose`). :mod:`.model` adds the placed
photos to the reference model and writes ``poses.json``.

    ref = load_reference(Path("ws/sparse/0"), Path("ws/database.db"))
    placements = localize(ref, photos, LocalizeOptions())
"""

from __future__ import annotations

from collections.abc import Callable

from recon.localize.intrinsics import PhotoCamera
from recon.localize.model import add_placed, poses_json
from recon.localize.options import LocalizeOptions
from recon.localize.pose import Photo, Placement, place
from recon.localize.reference import Reference, load_reference
from recon.localize.retrieval import retrieve

__all__ = ["LocalizeOptions", "Photo", "PhotoCamera", "Placement", "Reference", "add_placed", "load_reference",
           "localize", "poses_json"]


def localize(reference: Reference, photos: list[Photo], options: LocalizeOptions, seed: int = 0,
             done: Callable[[Placement], None] | None = None) -> list[Placement]:
    """Place each photo in ``reference``; ``done`` is called with each result as it is ready."""
    retrieved = retrieve(reference, [p.descriptors for p in photos], options.neighbours, options.vocabulary_words,
                         seed)
    out = []
    for photo, ids in zip(photos, retrieved):
        out.append(place(photo, reference, ids, options, seed))
        if done is not None:
            done(out[-1])
    return out
