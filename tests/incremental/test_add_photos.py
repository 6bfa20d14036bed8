"""Per-item reuse across stage keys (issue 18): features per photo and verified matches per pair
come from the workspace's item store whatever else changed; sfm continues the previous model."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pycolmap
import pytest

import recon
from recon.files import read_json

REPO = Path(__file__).resolve().parents[2]
SPARSE = REPO / "tests" / "sparse_test.yaml"


def manifests(ws: Path, stage: str) -> list[dict]:
    """The manifests of every completed output of ``stage``, oldest first."""
    found = [read_json(p) for p in (ws / ".recon" / "cache" / stage).glob("*/manifest.json")]
    return sorted(found, key=lambda m: m["finished"])


def matches_table(database: Path) -> dict[tuple[str, str], tuple]:
    """Pair of image names -> (matches, inliers, configuration, F, E, H) as stored in a COLMAP database."""
    con = sqlite3.connect(database)
    names = {i: n for n, i in con.execute("SELECT name, image_id FROM images")}
    pair = lambda pid: tuple(names[i] for i in pycolmap.pair_id_to_image_pair(pid))  # noqa: E731
    matches = {pair(pid): data for pid, data in con.execute("SELECT pair_id, data FROM matches")}
    table = {pair(pid): (matches[pair(pid)], *rest) for pid, *rest in
             con.execute("SELECT pair_id, data, config, F, E, H FROM two_view_geometries")}
    con.close()
    return table


def test_a_matching_option_reuses_every_feature_and_matches_every_pair_again(copy_workspace, small_scene):
    result = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace),
                       until="matching", matching={"max_ratio": 0.75})
    assert result.ran == ["matching"] and "features" in result.cached
    assert len(manifests(copy_workspace, "features")) == 1
    summary = manifests(copy_workspace, "matching")[-1]["summary"]
    assert summary["reused_pairs"] == 0 and summary["matched_pairs"] == summary["pairs"] == 120


def test_pairs_in_the_store_are_not_matched_again(copy_workspace, sparse_workspace, small_scene):
    """The matching output lost, the same config runs matching again: every pair comes from the
    store, and the database is the one matching wrote from scratch."""
    (done,) = manifests(copy_workspace, "matching")
    shutil.rmtree(copy_workspace / ".recon" / "cache" / "matching" / done["key"][:16])
    rows = {r.name: r for r in recon.api.status(SPARSE, images=str(small_scene / "images"),
                                                 workspace=str(copy_workspace))}
    assert rows["matching"].reuse == "reuses 120 of 120 pairs (exhaustive)"
    result = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace), until="matching")
    assert result.ran == ["matching"]
    assert result.summaries["matching"]["reused_pairs"] == 120 and result.summaries["matching"]["matched_pairs"] == 0
    assert matches_table(copy_workspace / "database.db") == matches_table(sparse_workspace / "database.db")


def test_a_forced_stage_reuses_nothing(copy_workspace, small_scene):
    result = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace),
                       until="matching", force=["matching"], matching={"chunk_pairs": 200})
    assert result.summaries["matching"]["reused_pairs"] == 0 and result.summaries["matching"]["matched_pairs"] == 120


def test_a_changed_lens_model_maps_the_same_photos_again(copy_workspace, small_scene):
    """No photo added, the camera model changed: sfm maps from scratch with the new model (continuing
    the previous SIMPLE_RADIAL model stopped COLMAP with a model-mismatch check)."""
    result = recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace),
                       until="sfm", ingest={"camera_model": "SIMPLE_PINHOLE"})
    assert "sfm" in result.ran and result.summaries["sfm"]["mapping"] == "from scratch"
    rec = pycolmap.Reconstruction(str(copy_workspace / "sparse" / "0"))
    assert {c.model.name for c in rec.cameras.values()} == {"SIMPLE_PINHOLE"}
    assert rec.num_reg_images() == 16


def centres(model: Path) -> dict[str, np.ndarray]:
    rec = pycolmap.Reconstruction(str(model))
    return {image.name: image.projection_center() for image in rec.images.values() if image.has_pose}


@pytest.mark.slow
def test_added_photos_reuse_features_and_pairs_and_continue_the_model(small_scene, sparse_workspace, tmp_path):
    """12 photos, then the 4 others added to the folder and the same command run again: the 12
    photos' features and their 66 pairs are reused, the previous model is continued and stays in
    its frame, and the result matches a from-scratch run on all 16 (same matches, same accuracy)."""
    from recon.eval.groundtruth import load_cameras
    from recon.eval.poses import pose_metrics

    images, ws = tmp_path / "images", tmp_path / "ws"
    images.mkdir()
    photos = sorted((small_scene / "images").iterdir())
    for photo in photos[:12]:
        shutil.copy(photo, images)
    recon.run(SPARSE, images=str(images), workspace=str(ws), until="sfm", executor="serial")
    before = centres(ws / "sparse" / "0")
    for photo in photos[12:]:
        shutil.copy(photo, images)
    rows = {r.name: r for r in recon.api.status(SPARSE, images=str(images), workspace=str(ws))}
    assert rows["features"].state == "stale" and rows["features"].reuse == "reuse known once preprocess has run"
    result = recon.run(SPARSE, images=str(images), workspace=str(ws), until="sfm", executor="serial")
    s = result.summaries
    assert (s["features"]["reused"], s["features"]["extracted"]) == (12, 4)
    assert (s["matching"]["reused_pairs"], s["matching"]["matched_pairs"]) == (66, 54)
    assert s["sfm"]["mapping"] == "continued" and s["sfm"]["registered"] == 16
    assert matches_table(ws / "database.db") == matches_table(sparse_workspace / "database.db")
    # the previous photos stay where they were: the model is kept in the previous frame
    after = centres(ws / "sparse" / "0")
    spread = np.linalg.norm(np.array(list(before.values())) - np.mean(list(before.values()), axis=0), axis=1).mean()
    moved = np.array([np.linalg.norm(after[n] - before[n]) for n in before])
    assert moved.max() < 0.01 * spread
    gt = load_cameras(small_scene)

    def auc5(model: Path) -> float:
        rec = pycolmap.Reconstruction(str(model))
        poses = {i.name: (i.cam_from_world().rotation.matrix(), i.cam_from_world().translation)
                 for i in rec.images.values() if i.has_pose}
        return pose_metrics(poses, gt)["auc@5"]

    assert auc5(ws / "sparse" / "0") >= auc5(sparse_workspace / "sparse" / "0") - 1.0
