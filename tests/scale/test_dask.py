"""Per-image and per-pair work on a Dask cluster gives the same model as the local process pool."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap

import recon
from recon.sparse.database import opened, private_copy

REPO = Path(__file__).resolve().parents[2]


def test_dask_local_cluster_gives_the_same_sparse_model(small_scene, sparse_workspace, tmp_path):
    ws = tmp_path / "ws"
    result = recon.run(REPO / "tests" / "sparse_test.yaml", images=str(small_scene / "images"), workspace=str(ws),
                       executor="dask-local:2")
    assert result.ran == ["ingest", "calibrate", "preprocess", "features", "matching", "sfm", "export"]
    a = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    b = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    names_a = {img.name: img for img in a.images.values() if img.has_pose}
    names_b = {img.name: img for img in b.images.values() if img.has_pose}
    assert sorted(names_a) == sorted(names_b)
    ca = np.array([names_a[n].projection_center() for n in sorted(names_a)])
    cb = np.array([names_b[n].projection_center() for n in sorted(names_b)])
    spread = np.linalg.norm(cb - cb.mean(0), axis=1).mean()
    assert np.abs(ca - cb).max() <= 1e-6 * spread
    # the features themselves are identical whichever executor computed them
    # through copies: pycolmap writes to a database it opens, and these are cached outputs
    with private_copy(ws / "database.db") as a, private_copy(sparse_workspace / "database.db") as b, \
            opened(a) as da, opened(b) as db:
        for img in da.read_all_images():
            other = db.read_image_with_name(img.name)
            assert np.array_equal(da.read_descriptors(img.image_id).data, db.read_descriptors(other.image_id).data)
