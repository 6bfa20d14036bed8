"""Dense workspaces for images with known cameras, to test and benchmark the stereo without SfM.

The sparse model the stereo needs (for view selection and depth ranges) comes either from
ground-truth depth maps (points sampled on the true surface, observed wherever they are visible) or
from SIFT matches triangulated with the known poses (pycolmap's triangulation, as COLMAP's
``point_triangulator``). ``pycolmap.undistort_images`` then writes the COLMAP dense layout.
"""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pycolmap

from recon.mvs.views import ViewCamera
from recon.products import SparseModel

log = logging.getLogger(__name__)


def posed_reconstruction(cameras: list[ViewCamera],
                         ids: dict[str, tuple[int, int]] | None = None) -> pycolmap.Reconstruction:
    """A reconstruction with a PINHOLE camera and a posed image per view, and no points; ``ids`` maps
    an image name to its (image_id, camera_id) (default: 1, 2, ... for both)."""
    rec = pycolmap.Reconstruction()
    for number, cam in enumerate(cameras, start=1):
        image_id, camera_id = ids[cam.name] if ids else (number, number)
        rec.add_camera_with_trivial_rig(pinhole_camera(cam, camera_id))
        pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(cam.R, dtype=np.float64)),
                                np.asarray(cam.t, dtype=np.float64))
        rec.add_image_with_trivial_frame(
            pycolmap.Image(name=cam.name, camera_id=camera_id, image_id=image_id), pose)
    return rec


def pinhole_camera(cam: ViewCamera, camera_id: int) -> pycolmap.Camera:
    K = cam.K
    return pycolmap.Camera(model="PINHOLE", width=cam.width, height=cam.height,
                           params=[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], camera_id=camera_id)


def points_from_depths(cameras: list[ViewCamera], depths: list[np.ndarray], points_per_image: int = 400,
                       seed: int = 0, depth_tolerance: float = 0.005) -> pycolmap.Reconstruction:
    """A sparse model whose points are sampled on ground-truth depth maps (camera z, 0 = no surface):
    each point is observed by every view where it projects inside the image and is not occluded
    (its depth agrees with that view's depth map within ``depth_tolerance``, relative)."""
    rng = np.random.default_rng(seed)
    points = []
    for cam, depth in zip(cameras, depths, strict=True):
        ys, xs = np.nonzero(depth > 0)
        pick = rng.choice(len(xs), size=min(points_per_image, len(xs)), replace=False)
        uv = np.stack([xs[pick] + 0.5, ys[pick] + 0.5, np.ones(len(pick))])
        x_cam = (np.linalg.inv(cam.K) @ uv) * depth[ys[pick], xs[pick]]
        points.append((cam.R.T @ (x_cam - cam.t[:, None])).T)
    xyz = np.concatenate(points)
    tracks: list[list[tuple[int, np.ndarray]]] = [[] for _ in range(len(xyz))]
    for image_id, (cam, depth) in enumerate(zip(cameras, depths, strict=True), start=1):
        x_cam = cam.R @ xyz.T + cam.t[:, None]
        z = x_cam[2]
        uv = (cam.K @ x_cam)[:2] / np.where(z > 0, z, 1)
        col, row = np.floor(uv).astype(int)
        inside = (z > 0) & (col >= 0) & (row >= 0) & (col < cam.width) & (row < cam.height)
        seen = np.zeros(len(xyz), bool)
        seen[inside] = np.abs(depth[row[inside], col[inside]] - z[inside]) <= depth_tolerance * z[inside]
        for p in np.nonzero(seen)[0]:
            tracks[p].append((image_id, uv[:, p]))
    rec = posed_reconstruction(cameras)
    keypoints: dict[int, list[np.ndarray]] = {image_id: [] for image_id in rec.images}
    kept = []
    for p, track in enumerate(tracks):
        if len(track) >= 2:
            elements = []
            for image_id, uv in track:
                elements.append((image_id, len(keypoints[image_id])))
                keypoints[image_id].append(uv)
            kept.append((xyz[p], elements))
    _set_keypoints(rec, keypoints)
    for point, elements in kept:
        track = pycolmap.Track()
        for image_id, idx in elements:
            track.add_element(image_id, idx)
        rec.add_point3D(point, track)
    return rec


def _set_keypoints(rec: pycolmap.Reconstruction, keypoints: dict[int, list[np.ndarray]]) -> None:
    """Replace each image's (empty) 2D points with the given keypoints."""
    for image_id, uvs in keypoints.items():
        image = rec.images[image_id]
        image.points2D = pycolmap.Point2DList([pycolmap.Point2D(np.asarray(uv, dtype=np.float64)) for uv in uvs])


def points_from_matches(cameras: list[ViewCamera], image_dir: str | Path, work_dir: str | Path,
                        max_image_size: int = 1600) -> pycolmap.Reconstruction:
    """A sparse model triangulated from SIFT matches (exhaustive) with the known poses."""
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    database = work_dir / "database.db"
    database.unlink(missing_ok=True)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = max_image_size
    pycolmap.extract_features(database, image_dir, image_names=[cam.name for cam in cameras],
                              camera_mode=pycolmap.CameraMode.PER_IMAGE, extraction_options=extraction)
    by_name = {cam.name: cam for cam in cameras}
    db = pycolmap.Database.open(database)
    try:
        ids = {image.name: (image.image_id, image.camera_id) for image in db.read_all_images()}
        for name, (_, camera_id) in ids.items():  # the known intrinsics replace the guessed ones
            db.update_camera(pinhole_camera(by_name[name], camera_id))
    finally:
        db.close()
    pycolmap.match_exhaustive(database)
    sparse = work_dir / SparseModel.MODELS
    sparse.mkdir(exist_ok=True)
    return pycolmap.triangulate_points(posed_reconstruction(cameras, ids), database, image_dir, sparse)


def make_dense_workspace(reconstruction: pycolmap.Reconstruction, image_dir: str | Path,
                         dense_dir: str | Path, work_dir: str | Path) -> Path:
    """``dense_dir`` in COLMAP's undistorted layout (images, sparse, stereo) for a PINHOLE model."""
    sparse = Path(work_dir) / "sparse_for_undistortion"
    if sparse.exists():
        shutil.rmtree(sparse)
    sparse.mkdir(parents=True)
    reconstruction.write(sparse)
    pycolmap.undistort_images(dense_dir, sparse, image_dir)
    return Path(dense_dir)
