"""Localization of held-out views of the synthetic scene against a reconstruction of its regular views.

The reference is the shared sparse run on the 16-view scene (``sparse_workspace``); the same scene
rendered with 3 hold-out views (between regular ones, same world) gives the new photos and their
ground truth. A photo of something else (a scikit-image photo the scene's textures do not use) must
be refused with a reason.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pycolmap
import pytest
from PIL import Image

from recon import api
from recon.geometry.transforms import align_similarity, camera_center, qvec_to_rotmat, rotation_angle_deg
from recon.synth import render_scene


@pytest.fixture(scope="module")
def holdout_scene(tmp_path_factory):
    """The conftest's small scene (16 views, 320x240, seed 0) with 3 hold-out views."""
    return render_scene(tmp_path_factory.mktemp("holdout") / "scene", views=16, width=320, height=240, seed=0,
                        holdout=3)


@pytest.fixture(scope="module")
def unrelated(tmp_path_factory):
    """Photos of other things: the astronaut at the reference's photo size, the rocket at its own."""
    import skimage.data

    folder = tmp_path_factory.mktemp("unrelated")
    Image.fromarray(skimage.data.astronaut()).resize((320, 240)).save(folder / "astronaut.jpg", quality=95)
    Image.fromarray(skimage.data.rocket()).save(folder / "rocket.png")
    return [folder / "astronaut.jpg", folder / "rocket.png"]


@pytest.fixture(scope="module")
def localized(sparse_workspace, holdout_scene, unrelated, tmp_path_factory):
    photos = [holdout_scene.holdout_images_dir / n for n in holdout_scene.holdout_names] + unrelated
    return api.localize(sparse_workspace, photos, tmp_path_factory.mktemp("loc") / "out")


def _model_to_gt(sparse_workspace, holdout_scene):
    """Similarity from the reference model's world to the ground truth's, fitted on the registered views."""
    rec = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    gt = holdout_scene.cameras()
    names = sorted(rec.image(i).name for i in rec.reg_image_ids())
    src = np.array([rec.find_image_with_name(n).projection_center() for n in names])
    return align_similarity(src, np.array([gt[n].center for n in names]), robust=True)[0]


def test_holdout_views_placed_accurately(localized, sparse_workspace, holdout_scene):
    by_name = {p["name"]: p for p in localized["photos"]}
    sim = _model_to_gt(sparse_workspace, holdout_scene)
    gt = holdout_scene.cameras(holdout=True)
    target = np.mean([holdout_scene.bbox_min, holdout_scene.bbox_max], axis=0)
    for name, cam in gt.items():
        p = by_name[name]
        assert p["placed"], p["reason"]
        assert p["inliers"] >= 30 and p["inliers"] <= p["matches"]
        assert p["intrinsics"].startswith("reference camera")  # same size, EXIF focal agrees
        R, t = sim.apply_to_pose(qvec_to_rotmat(p["qvec"]), p["tvec"])
        assert np.allclose(camera_center(R, t), sim.apply(np.array(p["centre"])))
        rot = rotation_angle_deg(R, cam.R)
        pos = np.linalg.norm(camera_center(R, t) - cam.center) / np.linalg.norm(cam.center - target)
        assert rot < 0.5, (name, rot)
        assert pos < 0.01, (name, pos)


def test_unrelated_photos_refused_with_reason(localized):
    by_name = {p["name"]: p for p in localized["photos"]}
    for name in ("astronaut.jpg", "rocket.png"):
        p = by_name[name]
        assert not p["placed"] and "qvec" not in p
        assert p["reason"].startswith(("too few", "inlier ratio", "no pose", "implausible")), p["reason"]
    assert localized["placed"] == 3 and localized["total"] == 5


def test_output_model_adds_photos_and_keeps_reference_unchanged(localized, sparse_workspace):
    ref_dir = sparse_workspace / "sparse" / "0"
    ref = pycolmap.Reconstruction(str(ref_dir))
    out_dir = Path(localized["workspace"]) / "sparse" / "0"
    out = pycolmap.Reconstruction(str(out_dir))
    assert out.num_reg_images() == ref.num_reg_images() + 3
    for image_id, image in ref.images.items():
        new = out.image(image_id)
        assert new.name == image.name and new.camera_id == image.camera_id
        assert np.array_equal(new.cam_from_world().matrix(), image.cam_from_world().matrix())
    for camera_id, camera in ref.cameras.items():
        assert np.array_equal(out.camera(camera_id).params, camera.params)
    assert (out_dir / "points3D.bin").read_bytes() == (ref_dir / "points3D.bin").read_bytes()
    placed = {p["name"]: p for p in localized["photos"] if p["placed"]}
    for name, p in placed.items():
        image = out.find_image_with_name(name)
        assert image.image_id == p["image_id"] and image.has_pose and image.image_id not in ref.images
        assert image.camera_id not in ref.cameras
        assert image.num_points2D() > 100 and image.num_points3D == 0
        assert np.allclose(image.projection_center(), p["centre"])
        assert np.allclose(out.camera(image.camera_id).params, p["camera"]["params"])
    on_disk = json.loads((Path(localized["workspace"]) / "poses.json").read_text())
    assert on_disk["placed"] == 3 and len(on_disk["photos"]) == 5


def test_focal_estimated_when_photo_has_no_exif(sparse_workspace, holdout_scene, tmp_path):
    name = holdout_scene.holdout_names[1]
    png = tmp_path / "photos" / "noexif.png"
    png.parent.mkdir()
    Image.open(holdout_scene.holdout_images_dir / name).save(png)  # PNG: no EXIF focal
    extra = tmp_path / "photos" / "other.png"  # ingest needs two photos
    Image.open(holdout_scene.holdout_images_dir / holdout_scene.holdout_names[0]).save(extra)
    result = api.localize(sparse_workspace, png.parent, tmp_path / "out", intrinsics="photo")
    p = next(p for p in result["photos"] if p["name"] == "noexif.png")
    assert p["placed"] and p["intrinsics"] == "photo, focal guessed"
    true_focal = holdout_scene.cameras(holdout=True)[name].K[0, 0]
    assert abs(p["camera"]["params"][0] / true_focal - 1) < 0.02  # from 1.2 x 320 = 384 px to the truth


def test_reference_untouched_and_its_change_makes_localize_stale(sparse_workspace, holdout_scene, tmp_path):
    from recon.files import file_digest

    reference = tmp_path / "ref"  # a copy: the shared workspace must not change
    shutil.copytree(sparse_workspace, reference, ignore=shutil.ignore_patterns(".recon"))
    before = {p: file_digest(p) for p in [reference / "database.db", *(reference / "sparse" / "0").glob("*.bin")]}
    photos = [holdout_scene.holdout_images_dir / n for n in holdout_scene.holdout_names[:2]]
    out = tmp_path / "out"
    assert api.localize(reference, photos, out)["placed"] == 2
    assert {p: file_digest(p) for p in before} == before  # read only
    assert {r.name: r.state for r in api.status(out)} == {"ingest": "done", "localize": "done"}
    rec = pycolmap.Reconstruction(str(reference / "sparse" / "0"))
    point = next(iter(rec.points3D.values()))
    point.xyz = point.xyz + 1e-3
    rec.write(str(reference / "sparse" / "0"))
    row = {r.name: r for r in api.status(out)}["localize"]
    assert row.state == "stale" and row.why == "input files changed"


def test_cli_errors_are_one_line(tmp_path, holdout_scene):
    photo = str(holdout_scene.holdout_images_dir / holdout_scene.holdout_names[0])
    not_ws = tmp_path / "empty"
    not_ws.mkdir()
    cases = [([str(tmp_path / "absent"), photo], "no such folder"),
             ([str(not_ws), photo, photo], "several photos are named"),
             ([str(not_ws), photo, str(tmp_path)], "is not a photo file"),
             ([str(not_ws), photo, str(holdout_scene.images_dir / "view_000.jpg")], "has no sparse/0/images.bin")]
    for args, message in cases:
        proc = subprocess.run([sys.executable, "-m", "recon.cli", "-q", "localize", *args,
                               "--out", str(tmp_path / "out")], capture_output=True, text=True)
        assert proc.returncode == 2, proc.stderr
        assert proc.stderr.count("\n") == 1 and message in proc.stderr, proc.stderr
