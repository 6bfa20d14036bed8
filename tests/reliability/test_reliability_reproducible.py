"""The same config and seed give the same sparse model.

Measured on this machine (pycolmap 4.2.1): features (SIFT, one thread per photo) and the content
of the matching database are identical on every run, whatever the executor; the database file's
bytes are not (COLMAP's matcher threads write pairs in the order they finish). With
``sfm.deterministic: true`` (single-threaded mapping and bundle adjustment, the tests' config) the
model files are identical byte for byte; multi-threaded bundle adjustment sums in scheduling
order, so by default runs agree to 1e-3 of the cameras' spread. A fresh workspace interrupted in
every stage gives the same files too: test_reliability_runs.py.
"""

from __future__ import annotations

import filecmp

import pytest
from reliability_checks import SPARSE, assert_same_reconstruction, cli, complete_outputs


def test_sfm_runs_again_to_the_same_model(copy_workspace, sparse_workspace, small_scene):
    """From the same matches: identical files single-threaded; multi-threaded, within tolerance."""
    args = ["run", SPARSE, "--images", small_scene / "images", "--workspace", copy_workspace]
    for extra in (["--force", "sfm"], ["-o", "sfm.deterministic=false"]):
        again = cli(*args, *extra)
        assert again.returncode == 0, again.stderr[-3000:]
        assert again.stdout.startswith("recon: ran sfm, export;")
        assert_same_reconstruction(copy_workspace, sparse_workspace, exact="--force" in extra)


@pytest.mark.slow
def test_same_config_and_seed_give_the_same_files_in_a_fresh_workspace(tmp_path, small_scene, sparse_workspace):
    fresh = tmp_path / "fresh"
    done = cli("run", SPARSE, "--images", small_scene / "images", "-o", "executor=serial", "--workspace", fresh)
    assert done.returncode == 0, done.stderr[-3000:]
    features, = complete_outputs(fresh, "features")
    reference, = complete_outputs(sparse_workspace, "features")
    assert features.name == reference.name  # the same cache key
    npz = sorted(p.relative_to(reference) for p in reference.rglob("*.npz"))
    assert len(npz) == 16 and sorted(p.relative_to(features) for p in features.rglob("*.npz")) == npz
    _, mismatch, errors = filecmp.cmpfiles(reference, features, [str(p) for p in npz], shallow=False)
    assert mismatch == [] and errors == []
    assert_same_reconstruction(fresh, sparse_workspace)
