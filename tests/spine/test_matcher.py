"""Blocks of pairs matched and verified in a worker (recon.sparse.matcher)."""

from __future__ import annotations

import numpy as np
import pytest

from recon.sparse.database import image_ids, read_keypoints, read_only
from recon.sparse.matcher import (
    Block,
    BlockError,
    PairOptions,
    _colmap_keypoints,
    match_block,
    read_block,
    write_block,
)


def test_keypoint_rows_become_colmap_keypoints_with_their_scale_and_orientation():
    rows = np.array([[10.0, 20.0, 2.5, 0.3], [1.0, 2.0, 1.0, -2.0]], np.float32)
    keypoints = _colmap_keypoints(rows)
    assert [(k.x, k.y) for k in keypoints] == [(10.0, 20.0), (1.0, 2.0)]
    assert np.allclose([k.compute_scale() for k in keypoints], [2.5, 1.0], atol=1e-5)
    assert np.allclose([k.compute_orientation() for k in keypoints], [0.3, -2.0], atol=1e-5)


def test_guided_matching_finds_more_inliers(sparse_workspace, tmp_path):
    database = sparse_workspace / "database.db"
    with read_only(database) as db:
        ids = sorted(image_ids(db).values())
        assert read_keypoints(db, ids[0]).shape[1] in (2, 4, 6)
    pairs = ((ids[0], ids[1]), (ids[0], ids[2]), (ids[1], ids[3]))
    inliers = {}
    for guided in (False, True):
        options = PairOptions(0.8, 0.7, True, guided, 4.0, 15, 0)
        out = match_block(Block(str(database), pairs, options, str(tmp_path / f"{guided}.npz")))
        results = read_block(out)
        assert sorted(results) == sorted(pairs)
        inliers[guided] = np.array([len(geometry.inlier_matches) for _, geometry in results.values()])
    assert (inliers[False] >= 15).all()
    assert (inliers[True] >= inliers[False]).all() and inliers[True].sum() > inliers[False].sum()


def plain(value):
    """A geometry's ``todict()`` as plain values (comparable with ==; arrays keep their dtype)."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return value.dtype.str, value.tolist()
    return value


def test_block_files_give_back_every_field_of_the_geometry(tmp_path):
    """Written as plain arrays and read back: the same matches and the same geometry, field for
    field (pose, cameras, E/F/H present or absent), whatever COLMAP's estimator filled in."""
    import pycolmap

    full = pycolmap.TwoViewGeometry()
    full.config = int(pycolmap.TwoViewGeometryConfiguration.CALIBRATED)
    full.E, full.F, full.H = (np.arange(9, dtype=float).reshape(3, 3) + k for k in range(3))
    full.cam2_from_cam1 = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([0.1, 0.2, 0.3, 0.9])), np.array([1.0, -2, 3]))
    full.camera1 = pycolmap.Camera(model="OPENCV", width=640, height=480, params=np.arange(8.0) + 0.5, camera_id=4)
    full.camera2 = pycolmap.Camera(model="SIMPLE_RADIAL", width=320, height=200, params=[300.0, 160, 100, 0.01],
                                   camera_id=7)
    full.camera2.has_prior_focal_length = True
    full.tri_angle = 0.25
    full.inlier_matches = np.array([[0, 1], [5, 7]], np.uint32)
    bare = pycolmap.TwoViewGeometry()
    bare.config = int(pycolmap.TwoViewGeometryConfiguration.DEGENERATE)
    results = [(1, 2, np.array([[0, 1], [5, 7], [9, 3]], np.uint32), full), (1, 3, np.zeros((0, 2), np.uint32), bare)]
    write_block(tmp_path / "b.npz", results)
    back = read_block(tmp_path / "b.npz")
    assert list(back) == [(1, 2), (1, 3)]
    for a, b, matches, geometry in results:
        got_matches, got = back[(a, b)]
        assert got_matches.dtype == np.uint32 and np.array_equal(got_matches, matches)
        assert plain(got.todict()) == plain(geometry.todict())
    write_block(tmp_path / "none.npz", [])
    assert read_block(tmp_path / "none.npz") == {}


class RunsCode:
    """Unpickling this makes the folder ``marker``: what a hostile block file would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        import os

        return os.mkdir, (self.marker,)


def test_a_block_file_that_would_run_code_is_refused_unread(tmp_path):
    """A pickle (the old block format) or an archive holding a pickled array is refused: read as
    data, it raises BlockError; the code in it never runs."""
    import pickle

    marker = tmp_path / "pwned"
    assert pickle.loads(pickle.dumps(RunsCode(marker))) is None and marker.is_dir()  # the payload works
    marker.rmdir()
    (tmp_path / "pickle.npz").write_bytes(pickle.dumps([(1, 2, RunsCode(marker), RunsCode(marker))]))
    np.savez(tmp_path / "object.npz", pairs=np.array([RunsCode(marker)], dtype=object))
    (tmp_path / "cut.npz").write_bytes((tmp_path / "object.npz").read_bytes()[:40])
    for name in ("pickle.npz", "object.npz", "cut.npz"):
        with pytest.raises(BlockError, match=f"^{name} is not a block of matches"):
            read_block(tmp_path / name)
    assert not marker.exists()
