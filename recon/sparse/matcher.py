"""SIFT matching and geometric verification of blocks of image pairs, as executor tasks.

COLMAP's ``match_image_pairs`` matches and verifies in threads of one process, writing into the
database as it goes. Here one task takes a block of pairs, reads the keypoints and descriptors it
needs from the features database (read only, so many workers, on any machine that sees the
workspace, read it at once), matches them as COLMAP's SIFT matcher does
(:mod:`recon.sparse.sift_match`), verifies them with COLMAP's
two-view geometry estimator (and re-matches guided by that geometry when asked), and pickles the
results into one file, written atomically. The matching stage, the database's only writer, then
puts every pair into ``database.db`` in the order of the pair list, so the database is the same
whatever the executor; pairs in block files on disk are done (resume, whatever the block size).
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from recon.sparse.database import read_camera, read_descriptors, read_keypoints, read_only, sift_descriptors
from recon.sparse.sift_match import sift_matches
from recon.workspace import write_bytes


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
    write_bytes(Path(block.out), pickle.dumps(results, protocol=pickle.HIGHEST_PROTOCOL))
    return block.out


def read_block(path: Path) -> dict[tuple[int, int], tuple]:
    """A block's results: (image_id1, image_id2) -> (matches, two-view geometry)."""
    return {(a, b): (matches, geometry) for a, b, matches, geometry in pickle.loads(Path(path).read_bytes())}


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
