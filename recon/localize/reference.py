"""The reference a photo is localized against: a COLMAP model and the database its features are in.

recon's sparse pipeline writes ``database.db`` (keypoints and SIFT descriptors of every photo) and
``sparse/0`` (the model); an image's ``points2D[i]`` is its database keypoint ``i``, so a matched
keypoint of a registered image leads through its ``point3D_id`` to a 3D point of the model.

The database is read with SQLite in read-only mode: ``pycolmap.Database.open`` rewrites the file
even when only reading, which would change the reference's content hash (and a cached output of
the reference's workspace).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.sparse.database import image_ids, read_descriptors, read_only


@dataclass
class Reference:
    """A loaded reference: ``reconstruction`` (pycolmap), and per registered image (by id, sorted)
    its SIFT descriptors and the 3D point id of each keypoint (-1 where it has none)."""

    reconstruction: object
    image_ids: list[int]
    descriptors: dict[int, np.ndarray]
    point3D_ids: dict[int, np.ndarray]

    def name(self, image_id: int) -> str:
        return self.reconstruction.image(image_id).name

    def points3D(self, ids: np.ndarray) -> np.ndarray:
        """World coordinates (N, 3) of 3D points ``ids``."""
        rec = self.reconstruction
        return np.array([rec.point3D(int(i)).xyz for i in ids], dtype=np.float64).reshape(-1, 3)


def load_reference(model: Path, database: Path) -> Reference:
    """Read the model folder (``cameras.bin``...) and the descriptors of its registered images from
    ``database`` (matched by image name, so the database may hold more images than the model)."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    registered = sorted(i for i in rec.reg_image_ids())
    if not registered:
        raise ValueError(f"{model}: the model has no registered image")
    descriptors, tracks = {}, {}
    with read_only(database) as db:
        by_name = image_ids(db)
        for image_id in registered:
            image = rec.image(image_id)
            if image.name not in by_name:
                raise ValueError(f"{database}: holds no image named {image.name!r} of the model {model}")
            desc = read_descriptors(db, by_name[image.name])
            if len(desc) != image.num_points2D():
                raise ValueError(f"{database}: {image.name} has {len(desc)} descriptors but the model "
                                 f"{image.num_points2D()} keypoints: the database is not the model's")
            descriptors[image_id] = desc
            tracks[image_id] = np.array([p.point3D_id if p.has_point3D() else -1 for p in image.points2D],
                                        dtype=np.int64)
    return Reference(rec, registered, descriptors, tracks)
