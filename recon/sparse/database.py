"""Writing and reading COLMAP's ``database.db`` (one writer: the process that runs the stage)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable
from pathlib import Path

import numpy as np


def camera_params(model: str, width: int, height: int, focal: float) -> list[float]:
    """Initial COLMAP parameters of ``model``: the focal prior, principal point at the centre, no distortion."""
    cx, cy = width / 2.0, height / 2.0
    return {
        "SIMPLE_PINHOLE": [focal, cx, cy],
        "PINHOLE": [focal, focal, cx, cy],
        "SIMPLE_RADIAL": [focal, cx, cy, 0.0],
        "RADIAL": [focal, cx, cy, 0.0, 0.0],
        "OPENCV": [focal, focal, cx, cy, 0.0, 0.0, 0.0, 0.0],
    }[model]


@contextlib.contextmanager
def opened(path: Path):
    import pycolmap

    db = pycolmap.Database.open(str(path))
    try:
        yield db
    finally:
        db.close()


def write_database(path: Path, cameras: list[dict], images: list[dict],
                   features: Iterable[tuple[str, np.ndarray, np.ndarray]]) -> dict[str, int]:
    """Create ``path`` with cameras, images, keypoints and descriptors; returns image name -> id.

    ``cameras`` and ``images`` are ingest's records; ``features`` yields (name, keypoints, descriptors)
    in the order of ``images``, so image ids follow the photos' sorted order on every run.
    """
    import pycolmap

    tmp = path.with_name(f".{path.name}.tmp")
    tmp.unlink(missing_ok=True)
    ids: dict[str, int] = {}
    with opened(tmp) as db:
        cam_ids = {}
        for cam in cameras:
            camera = pycolmap.Camera(model=cam["model"], width=cam["width"], height=cam["height"],
                                     params=camera_params(cam["model"], cam["width"], cam["height"], cam["focal"]))
            camera.has_prior_focal_length = bool(cam["prior_focal"])
            cam_ids[cam["id"]] = db.write_camera(camera)
        by_name = {img["name"]: img for img in images}
        for name, keypoints, descriptors in features:
            image_id = db.write_image(pycolmap.Image(name=name, camera_id=cam_ids[by_name[name]["camera"]]))
            db.write_keypoints(image_id, keypoints)
            db.write_descriptors(image_id, pycolmap.FeatureDescriptors(
                pycolmap.FeatureExtractorType.SIFT, descriptors))
            ids[name] = image_id
    tmp.replace(path)
    return ids


def image_ids(path: Path) -> dict[str, int]:
    with opened(path) as db:
        return {img.name: img.image_id for img in db.read_all_images()}


def verified_pairs(path: Path) -> dict[tuple[int, int], int]:
    """Inlier match counts of every geometrically verified pair, keyed by (image_id1, image_id2)."""
    import pycolmap

    with opened(path) as db:
        pair_ids, geometries = db.read_two_view_geometries()
        counts = {}
        for pair_id, geom in zip(pair_ids, geometries):
            n = len(geom.inlier_matches)
            if n:
                counts[tuple(pycolmap.pair_id_to_image_pair(pair_id))] = n
        return counts
