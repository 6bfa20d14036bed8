"""Issue 16, "Done when" 5: the zoo's walk round a building (29 phone photos, GPS tags 3 m off) with
the default sparse options puts at least 95 % of the photos in one model, through the mapper
fallback: the incremental mapper alone splits the walk into a model per facade. The kept model is
checked against the true cameras and, georeferenced, against the true positions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pycolmap
import pytest

import recon
from recon.eval.workspace import evaluate
from recon.geometry.gps import enu_from_wgs84, wgs84_from_enu
from recon.products import SparseModel
from recon.synth.geotags import ORIGIN
from recon.synth.zoo import render_zoo

SPARSE_PIPELINE = Path(__file__).resolve().parents[2] / "pipelines" / "sparse.yaml"
FULL_PIPELINE = SPARSE_PIPELINE.with_name("full.yaml")
PHOTOS = 29


@pytest.fixture(scope="module")
def walkaround(tmp_path_factory):
    return render_zoo("walkaround", tmp_path_factory.mktemp("walkaround") / "scene", width=512, height=384)


def _report(ws: Path) -> dict:
    """The sfm stage's models.json (the published sparse/ links into that stage's output)."""
    return SparseModel((ws / "sparse").resolve().parent).report()


@pytest.mark.slow
def test_default_options_register_the_walk_through_the_global_fallback(walkaround, tmp_path):
    ws = tmp_path / "ws"
    recon.run(SPARSE_PIPELINE, images=str(walkaround.images_dir), workspace=str(ws), until="sfm")
    report = _report(ws)
    model = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    assert model.num_reg_images() >= 0.95 * PHOTOS
    incremental, fallback = report["mapper"]["attempts"]
    assert incremental["mapper"] == "incremental" and incremental["registered"] < 0.95 * PHOTOS  # it fell short
    assert incremental["models"] > 1  # measured: 9 + 8 + 6 + 6 photos, one model per facade
    assert fallback["mapper"] == "global" and report["mapper"]["used"] == "global"
    assert report["mapper"]["why"].startswith(f"the incremental mapper's largest model holds {incremental['registered']}")
    assert "warning" not in report
    # pairs matched across opposite facades through look-alike windows bend the global mapper's first
    # model; it ran again without the pairs that model contradicts (recon.sparse.mapping._global_mapping),
    # which the report lists. Measured: 27 contradicted, 24 left out in the model kept
    assert report["mapper"]["false_pairs"]
    poses = evaluate(ws, walkaround.root)["poses"]  # measured: AUC@5 94.8, centres 0.15 % of the scene off
    assert poses["auc@5"] > 75 and poses["median_center_error_rel"] < 0.01
    # each facade is tied to the next by a corner pair sharing 0-14 points: the model says so
    joins = report["weak_joins"]
    assert sorted(len(g) for g in joins["groups"]) == [6, 6, 8, 9]
    assert joins["warning"].startswith("the model's photos fall into 4 groups")

    georef = json.loads((ws / "georeference.json").read_text())
    assert georef["georeferenced"]
    # the groups' placement rests on few points: coarse GPS (3 m) is used as a prior to place them
    assert georef["gps_prior"]["used"] and georef["gps_prior"]["why"].startswith("the model's photos fall into 4 groups")
    origin = (georef["origin"]["lat"], georef["origin"]["lon"], georef["origin"]["alt"])
    truth = {name: cam.center for name, cam in walkaround.cameras().items()}
    errors = [np.linalg.norm(image.projection_center() - enu_from_wgs84(wgs84_from_enu(truth[image.name], ORIGIN),
                                                                           origin)[0])
              for image in model.images.values()]
    assert np.median(errors) < 3.0  # GPS sigma 3 m per axis on each of the 29 photos

    recon.run(FULL_PIPELINE, images=str(walkaround.images_dir), workspace=str(ws), until="undistort")
    log = (ws / ".recon" / "recon.log").read_text()
    assert "undistort: dense work on the largest model: the model's photos fall into 4 groups" in log  # repeated


@pytest.mark.slow
def test_without_the_fallback_the_walk_splits_and_the_run_says_so(walkaround, tmp_path):
    ws = tmp_path / "ws"
    recon.run(SPARSE_PIPELINE, images=str(walkaround.images_dir), workspace=str(ws), until="sfm",
              sfm={"mapper_fallback": False})
    report = _report(ws)
    assert [a["mapper"] for a in report["mapper"]["attempts"]] == ["incremental"]
    registered = report["models"][0]["registered"]
    assert registered < 0.75 * PHOTOS
    assert report["warning"].startswith(f"only {registered} of {PHOTOS} photos are in the largest model")
    assert "sfm.mapper: global" in report["warning"]
    log = (ws / ".recon" / "recon.log").read_text()
    assert f"sfm: only {registered} of {PHOTOS} photos" in log


@pytest.mark.slow
def test_a_match_set_whose_false_pairs_bend_the_global_model_far_is_mended(tmp_path):
    """At 640x480 with ``seed`` 4 the verified pairs hold 14 false ones (look-alike windows on opposite
    facades), and the global mapper's first model contradicted 25 pairs, 14 of them true: with 6 runs
    of the search without contradicted pairs it kept a bent model (pose AUC@5 12.9); the right one came
    with 9 of the strongest put back (recon.sparse.mapping._global_mapping; measured 95.9)."""
    scene = render_zoo("walkaround", tmp_path / "scene", width=640, height=480)
    ws = tmp_path / "ws"
    recon.run(FULL_PIPELINE, images=str(scene.images_dir), workspace=str(ws), until="sfm", overrides=["seed=4"])
    assert _report(ws)["mapper"]["used"] == "global"
    assert evaluate(ws, scene.root)["poses"]["auc@5"] > 90
