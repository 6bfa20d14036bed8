"""SIFT matching and geometric verification of blocks of image pairs, as executor tasks.

COLMAP's ``match_image_pairs`` matches and verifies in threads of one process, writing into the
database as it goes. Here one task takes a block of pairs, reads the keypoints and descriptors it
needs from the features database (read only, so many workers, on any machine that sees the
workspace, read it at once), matches them as COLMAP's SIFT matcher does
(:mod:`recon.sparse.sift_match`), verifies them with COLMAP's
two-view geometry estimator (and re-matches guided by that geometry when asked), and writes the
results into one ``.npz`` file of plain arrays, atomically. The matching stage, the database's only
writer, then puts every pair into ``database.db`` in the order of the pair list, so the database is
the same whatever the executor; pairs in block files on disk are done (resume, whatever the block
size).

Block files are data, never code: a workspace may come from someone else (a shared file system, an
unpacked archive), and numpy reads them with ``allow_pickle=False``. A file that is not a block
raises :class:`BlockError`, so the stage matches its pairs again.
"""

from __future__ import annotations

import os
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.sparse.database import read_camera, read_descriptors, read_keypoints, read_only, sift_descriptors
from recon.sparse.sift_match import sift_matches


class BlockError(ValueError):
    """A block file that cannot be read as one (truncated, foreign, or holding pickled objects)."""


@dataclass(frozen=True)
class PairOptions:
    """What matching and verification depend on (the matching stage's options, flattened)."""

    max_ratio: float
    max_distance: float
    cross_check: bool
    guided_matching: bool
    max_error: float
    min_inliers: int
    seed: int
    num_threads: int = 1


@dataclass(frozen=True)
class Block:
    """A task: match ``pairs`` (image id pairs) of ``database``, results into ``out``."""

    database: str
    pairs: tuple[tuple[int, int], ...]
    options: PairOptions
    out: str


def colmap_options(options: PairOptions):
    """pycolmap's matching and two-view geometry options for ``options``."""
    import pycolmap

    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = options.num_threads
    mo.guided_matching = options.guided_matching
    mo.sift.max_ratio = options.max_ratio
    mo.sift.max_distance = options.max_distance
    mo.sift.cross_check = options.cross_check
    vo = pycolmap.TwoViewGeometryOptions()
    vo.min_num_inliers = options.min_inliers
    vo.ransac.max_error = options.max_error
    vo.ransac.random_seed = options.seed
    return mo, vo


def match_block(block: Block) -> str:
    """Match and verify the block's pairs; returns the path of the results file."""
    import pycolmap

    o = block.options
    mo, vo = colmap_options(o)
    config = pycolmap.TwoViewGeometryConfiguration
    guidable = (config.CALIBRATED, config.UNCALIBRATED, config.PLANAR, config.PANORAMIC, config.PLANAR_OR_PANORAMIC)
    needed = sorted({i for pair in block.pairs for i in pair})
    with read_only(Path(block.database)) as db:
        cameras = {i: read_camera(db, i) for i in needed}
        keypoints = {i: read_keypoints(db, i) for i in needed}
        descriptors = {i: read_descriptors(db, i) for i in needed}
    if o.guided_matching:  # COLMAP's own types, made once per image of the block
        matcher = pycolmap.FeatureMatcher.create(mo, pycolmap.Device.cpu)
        guided = {i: (_colmap_keypoints(keypoints[i]), sift_descriptors(descriptors[i])) for i in needed}
    results = []
    for a, b in block.pairs:
        matches = sift_matches(descriptors[a], descriptors[b], o.max_ratio, o.max_distance,
                               o.cross_check).astype(np.uint32)
        geometry = pycolmap.estimate_two_view_geometry(
            cameras[a], keypoints[a][:, :2].astype(np.float64), cameras[b],
            keypoints[b][:, :2].astype(np.float64), matches, vo)
        if o.guided_matching and geometry.config in guidable:
            matcher.match_guided(o.max_error, *guided[a], cameras[a], *guided[b], cameras[b], geometry)
        results.append((a, b, matches, geometry))
    write_block(Path(block.out), results)
    return block.out


#: the 3 x 3 matrices of a two-view geometry, each absent for some configurations
_MATRICES = ("E", "F", "H")
#: the cameras a two-view geometry may carry (COLMAP stores them in the database too)
_CAMERAS = ("camera1", "camera2")


def write_block(path: Path, results: list[tuple]) -> None:
    """Write (image_id1, image_id2, matches, two-view geometry) tuples as plain arrays, atomically
    (a kill never leaves a half-written block). Every field of the geometry is kept, absent ones
    marked absent, so :func:`read_block` gives back what COLMAP's estimator returned."""
    geometries = [g for *_, g in results]
    arrays = {
        "pairs": np.array([(a, b) for a, b, *_ in results], np.int64).reshape(-1, 2),
        "config": np.array([int(g.config) for g in geometries], np.int64),
        "tri_angle": np.array([g.tri_angle for g in geometries], np.float64),
    }
    poses = [g.cam2_from_cam1 for g in geometries]
    arrays |= _optional("cam2_from_cam1", [None if p is None else [*p.rotation.quat, *p.translation] for p in poses],
                        (7,))
    for name in _MATRICES:
        arrays |= _optional(name, [getattr(g, name) for g in geometries], (3, 3))
    for name in _CAMERAS:
        cameras = [getattr(g, name) for g in geometries]
        arrays |= _optional(name, [None if c is None else [c.camera_id, int(c.model), c.width, c.height,
                                                           c.has_prior_focal_length] for c in cameras], (5,))
        arrays |= _ragged(f"{name}_params", [[] if c is None else c.params for c in cameras], np.float64, ())
    arrays |= _ragged("matches", [m for _, _, m, _ in results], np.uint32, (2,))
    arrays |= _ragged("inlier_matches", [g.inlier_matches for g in geometries], np.uint32, (2,))
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as handle:
            np.savez(handle, **arrays)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _optional(name: str, values: list, shape: tuple[int, ...]) -> dict[str, np.ndarray]:
    """Values that may be None: one array of them (zeros where None) and a mask of which are set."""
    return {f"has_{name}": np.array([v is not None for v in values], bool),
            name: np.array([np.zeros(shape) if v is None else v for v in values], np.float64).reshape(-1, *shape)}


def _ragged(name: str, values: list, dtype, row: tuple[int, ...]) -> dict[str, np.ndarray]:
    """Arrays of different lengths: concatenated, and the length of each."""
    parts = [np.asarray(v, dtype).reshape(-1, *row) for v in values]
    return {f"{name}_count": np.array([len(v) for v in parts], np.int64),
            name: np.concatenate(parts) if parts else np.zeros((0, *row), dtype)}


def read_block(path: Path) -> dict[tuple[int, int], tuple]:
    """A block's results: (image_id1, image_id2) -> (matches, two-view geometry). Raises
    :class:`BlockError` for a file that is not a whole block written by :func:`write_block`."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
        return _results(arrays)
    except (OSError, EOFError, AttributeError, KeyError, IndexError, TypeError, ValueError,
            zipfile.BadZipFile) as exc:
        raise BlockError(f"{Path(path).name} is not a block of matches ({type(exc).__name__}: {exc})") from None


def _results(arrays: dict[str, np.ndarray]) -> dict[tuple[int, int], tuple]:
    import pycolmap

    n = len(arrays["pairs"])
    ragged = {}
    for name in ("matches", "inlier_matches", *(f"{c}_params" for c in _CAMERAS)):
        counts = arrays[f"{name}_count"]
        if len(counts) != n or (counts < 0).any() or counts.sum() != len(arrays[name]):
            raise ValueError(f"{name}: lengths do not add up")
        ragged[name] = np.split(arrays[name], np.cumsum(counts)[:-1]) if n else []
    results = {}
    for i, (a, b) in enumerate(arrays["pairs"].tolist()):
        geometry = pycolmap.TwoViewGeometry()
        geometry.config = int(arrays["config"][i])
        geometry.tri_angle = float(arrays["tri_angle"][i])
        for name in _MATRICES:
            if arrays[f"has_{name}"][i]:
                setattr(geometry, name, arrays[name][i])
        if arrays["has_cam2_from_cam1"][i]:
            pose = arrays["cam2_from_cam1"][i]
            geometry.cam2_from_cam1 = pycolmap.Rigid3d(pycolmap.Rotation3d(pose[:4]), pose[4:])
        for name in _CAMERAS:
            if arrays[f"has_{name}"][i]:
                camera_id, model, width, height, prior = (int(v) for v in arrays[name][i])
                camera = pycolmap.Camera(model=pycolmap.CameraModelId(model), width=width, height=height,
                                         params=ragged[f"{name}_params"][i], camera_id=camera_id)
                camera.has_prior_focal_length = bool(prior)
                setattr(geometry, name, camera)
        geometry.inlier_matches = ragged["inlier_matches"][i]
        results[(a, b)] = (ragged["matches"][i], geometry)
    return results


def _colmap_keypoints(rows: np.ndarray):
    """pycolmap FeatureKeypoints from database rows: (x, y), (x, y, scale, orientation) or the affine
    (x, y, a11, a12, a21, a22), as COLMAP stores them."""
    import pycolmap

    rows = rows.astype(float)
    if rows.shape[1] == 6:
        affine = rows[:, 2:]
    else:
        scale = rows[:, 2] if rows.shape[1] == 4 else np.ones(len(rows))
        angle = rows[:, 3] if rows.shape[1] == 4 else np.zeros(len(rows))
        c, s = scale * np.cos(angle), scale * np.sin(angle)
        affine = np.column_stack([c, -s, s, c])
    keypoints = pycolmap.FeatureKeypoints()
    for (x, y), (a11, a12, a21, a22) in zip(rows[:, :2], affine):
        keypoints.append(pycolmap.FeatureKeypoint(x=x, y=y, a11=a11, a12=a12, a21=a21, a22=a22))
    return keypoints
