"""``matching.method: spatial`` end to end: a small GPS-tagged synthetic scene (two photos without GPS)
through the sparse pipeline registers every view, from fewer pairs than exhaustive matching; more
neighbours later reuse the pairs already matched."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pycolmap

import recon
from recon.synth import load_scene
from recon.synth.geotags import geotag_photos

REPO = Path(__file__).resolve().parents[2]
SPARSE_TEST = REPO / "tests" / "sparse_test.yaml"
ORIGIN = (47.3769, 8.5417, 430.0)
UNTAGGED = ("view_003.jpg", "view_011.jpg")


def test_spatial_matching_registers_every_view(small_scene, tmp_path):
    scene = load_scene(small_scene)
    photos = tmp_path / "photos"
    shutil.copytree(scene.images_dir, photos)
    cameras = {name: cam for name, cam in scene.cameras().items() if name not in UNTAGGED}
    geotag_photos(photos, {n: c.center for n, c in cameras.items()}, 0.05, 0, ORIGIN)  # the scene's units taken for metres: a 7 m orbit
    ws = tmp_path / "ws"
    matching = {"method": "spatial", "spatial_neighbors": 4, "spatial_retrieval": 1, "neighbors": 4}
    features = {"min_image_size": 640}  # SIFT on 640 px, not 1024: a shorter test, matches to spare
    result = recon.run(SPARSE_TEST, images=str(photos), workspace=str(ws), matching=matching, features=features)
    summary = result.summaries["matching"]
    n = len(scene.cameras())
    assert summary["method"] == "spatial"
    assert summary["pairs"] < n * (n - 1) / 4  # under half of exhaustive's 120
    tried, = (ws / ".recon").rglob("pairs.txt")  # matching's list of the pairs it matched
    pairs = [line.split() for line in tried.read_text().splitlines()]
    for name in UNTAGGED:  # paired by appearance, with their 4 most similar photos at least
        assert sum(name in pair for pair in pairs) >= 4
    model = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    registered = {img.name for img in model.images.values() if img.has_pose}
    assert registered == set(scene.cameras())
    # the GPS tags were read: the model is georeferenced, its centres within centimetres of the truth
    georef = json.loads((ws / "georeference.json").read_text())
    assert georef["georeferenced"], georef.get("reason")
    assert georef["residuals_m"]["median"] < 0.15
    assert np.isfinite(georef["scale_relative_std"])

    # per-pair reuse: with one more neighbour each, only the new pairs are matched
    again = recon.run(SPARSE_TEST, images=str(photos), workspace=str(ws), until="matching",
                      matching={**matching, "spatial_neighbors": 5}, features=features)
    grown = again.summaries["matching"]
    assert grown["reused_pairs"] == summary["pairs"]
    assert 0 < grown["matched_pairs"] == grown["pairs"] - summary["pairs"]
