"""Blocks of pairs matched and verified in a worker (recon.sparse.matcher)."""

from __future__ import annotations

import numpy as np

from recon.sparse.database import image_ids, read_keypoints, read_only
from recon.sparse.matcher import Block, PairOptions, _colmap_keypoints, match_block, read_block


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
        out = match_block(Block(str(database), pairs, options, str(tmp_path / f"{guided}.pkl")))
        results = read_block(out)
        assert sorted(results) == sorted(pairs)
        inliers[guided] = np.array([len(geometry.inlier_matches) for _, geometry in results.values()])
    assert (inliers[False] >= 15).all()
    assert (inliers[True] >= inliers[False]).all() and inliers[True].sum() > inliers[False].sum()
