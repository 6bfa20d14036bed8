"""Writing and reading COLMAP's ``database.db`` (one writer: the process that runs the stage)."""

from __future__ import annotations

import contextlib
import shutil
import sqlite3
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from recon.files import atomic


def camera_params(model: str, width: int, height: int, focal: float) -> list[float]:
    """Initial COLMAP parameters of ``model``: the focal prior, principal point at the centre, no
    distortion (COLMAP's own initialisation; an EQUIRECTANGULAR camera's parameters are its size)."""
    import pycolmap

    return pycolmap.Camera.create_from_model_name(0, model, focal, width, height).params.tolist()


@contextlib.contextmanager
def read_only(path: Path):
    """A read-only SQLite connection to a finished COLMAP database. Readers use this, never
    ``pycolmap.Database.open``, which writes to the file it opens (a cached stage output must not
    change) and takes locks that concurrent workers would contend for. ``immutable``: COLMAP's
    databases are in WAL mode, where even a read-only connection leaves -wal/-shm files behind."""
    con = sqlite3.connect(f"{Path(path).resolve().as_uri()}?mode=ro&immutable=1", uri=True)
    try:
        yield con
    finally:
        con.close()


@contextlib.contextmanager
def private_copy(path: Path):
    """A temporary copy of a finished COLMAP database, for the pycolmap calls that open it read-write
    (``Database.open`` and the mappers write to the file they open even when they only read: found
    by the cache's content check, a cached ``database.db`` changed when sfm ran)."""
    with tempfile.TemporaryDirectory(prefix="recon-db-") as scratch:
        copy = Path(scratch) / Path(path).name
        shutil.copyfile(path, copy)
        yield copy


def image_ids(con: sqlite3.Connection) -> dict[str, int]:
    """Image name -> image id."""
    return dict(con.execute("SELECT name, image_id FROM images"))


def read_descriptors(con: sqlite3.Connection, image_id: int) -> np.ndarray:
    """An image's SIFT descriptors (N x 128 uint8)."""
    row = con.execute("SELECT rows, cols, data FROM descriptors WHERE image_id = ?", (image_id,)).fetchone()
    if row is None or not row[0]:
        return np.zeros((0, 128), np.uint8)
    rows, cols, data = row
    if cols != 128 or len(data) != rows * cols:
        raise ValueError(f"image {image_id}: descriptors are not 128-byte SIFT ({rows} x {cols}, {len(data)} bytes)")
    return np.frombuffer(data, dtype=np.uint8).reshape(rows, cols).copy()


def read_keypoints(con: sqlite3.Connection, image_id: int) -> np.ndarray:
    """An image's keypoints as stored (N x 6 float32: x, y, a11, a12, a21, a22; or N x 2/4)."""
    row = con.execute("SELECT rows, cols, data FROM keypoints WHERE image_id = ?", (image_id,)).fetchone()
    if row is None or not row[0]:
        return np.zeros((0, 6), np.float32)
    rows, cols, data = row
    return np.frombuffer(data, dtype=np.float32).reshape(rows, cols).copy()


def read_inlier_matches(con: sqlite3.Connection, pair_id: int) -> np.ndarray:
    """A pair's verified inlier matches (M x 2 keypoint indices, first image then second)."""
    row = con.execute("SELECT rows, data FROM two_view_geometries WHERE pair_id = ?", (pair_id,)).fetchone()
    if row is None or not row[0]:
        return np.zeros((0, 2), np.uint32)
    rows, data = row
    return np.frombuffer(data, dtype=np.uint32).reshape(rows, 2).copy()


def stored_camera_params(con: sqlite3.Connection) -> dict[int, np.ndarray]:
    """Camera id -> its stored intrinsic parameters (where the mapper starts from)."""
    return {camera_id: np.frombuffer(params, dtype=np.float64).copy()
            for camera_id, params in con.execute("SELECT camera_id, params FROM cameras")}


def cameras_with_exif_focal(con: sqlite3.Connection) -> frozenset[int]:
    """Ids of the cameras whose stored focal length came from their photos' EXIF (COLMAP's
    ``prior_focal_length`` flag), not from a guess."""
    return frozenset(camera_id for camera_id, in con.execute("SELECT camera_id FROM cameras WHERE prior_focal_length"))


def read_camera(con: sqlite3.Connection, image_id: int):
    """The pycolmap camera of an image, with its focal-length prior flag (COLMAP verifies a pair with
    an essential matrix only when both cameras have one, and a fisheye pair not at all without)."""
    import pycolmap

    camera_id, model, width, height, params, prior = con.execute(
        "SELECT c.camera_id, c.model, c.width, c.height, c.params, c.prior_focal_length FROM cameras c "
        "JOIN images i ON c.camera_id = i.camera_id WHERE i.image_id = ?", (image_id,)).fetchone()
    camera = pycolmap.Camera(model=pycolmap.CameraModelId(model), width=width, height=height,
                             params=np.frombuffer(params, dtype=np.float64).copy(), camera_id=camera_id)
    camera.has_prior_focal_length = bool(prior)
    return camera


def sift_descriptors(rows: np.ndarray):
    """pycolmap's FeatureDescriptors of N x 128 uint8 SIFT descriptors."""
    import pycolmap

    return pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT, rows)


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

    ids: dict[str, int] = {}
    with atomic(path) as tmp, opened(tmp) as db:
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
            db.write_descriptors(image_id, sift_descriptors(descriptors))
            ids[name] = image_id
    return ids
