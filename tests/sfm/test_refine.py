"""Camera refinement after mapping (recon.sparse.refine): which pairs it matches, which matches it keeps,
and that it brings the small scene's cameras closer to the truth."""

from itertools import combinations
from pathlib import Path

import numpy as np
import pycolmap
import pytest

import recon
from recon.products import Published
from recon.sparse.mapping import camera_start
from recon.sparse.pose_check import epipolar_px
from recon.sparse.refine import MIN_SHARED_POINTS, overlapping_pairs, refinable, refine
from recon.stages.sfm import SfmConfig

SPARSE_TEST = Path(__file__).resolve().parents[1] / "sparse_test.yaml"


def _two_views() -> pycolmap.Reconstruction:
    """Two 640x480 pinhole views (focal 500) 1 unit apart, both looking down +z at points 4-6 units away."""
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=640, height=480,
                                                    params=[500.0, 500.0, 320.0, 240.0], camera_id=1))
    for image_id, x in ((1, 0.0), (2, 1.0)):
        image = pycolmap.Image(name=f"v{image_id}.jpg", camera_id=1, image_id=image_id)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(np.eye(3)), [-x, 0.1 * x, 0.0]))
    return rec


def test_epipolar_distance_is_zero_on_the_geometry_and_measures_pixels_off_it():
    rec = _two_views()
    rng = np.random.default_rng(0)
    xyz = np.column_stack([rng.uniform(-1, 2, 50), rng.uniform(-1, 1, 50), rng.uniform(4, 6, 50)])
    camera = rec.camera(1)
    a = camera.img_from_cam(xyz @ np.eye(3).T + rec.image(1).cam_from_world().translation)
    b = camera.img_from_cam(xyz + rec.image(2).cam_from_world().translation)
    assert np.max(epipolar_px(rec, 1, 2, a, b)) < 1e-6
    # the views differ by a translation along (1, -0.1, 0): epipolar lines run along it, so a shift along
    # the line keeps a match on the geometry; a shift of 2 px across it in one photo puts the match 2 / sqrt(2)
    # px off (Sampson's distance shares the error between the two photos, whose lines run alike here)
    along = np.array([1.0, -0.1]) / np.hypot(1.0, 0.1)
    across = np.array([0.1, 1.0]) / np.hypot(1.0, 0.1)
    assert np.max(epipolar_px(rec, 1, 2, a, b + 3 * along)) < 1e-6
    off = epipolar_px(rec, 1, 2, a, b + 2 * across)
    assert np.allclose(off, np.sqrt(2), atol=0.01)
    assert epipolar_px(rec, 1, 1, a, a) is None  # one centre: no epipolar geometry


def _model(workspace):
    return pycolmap.Reconstruction(str(Published(workspace).model()))


def test_overlapping_pairs_are_those_sharing_enough_points_with_each_photos_best(sparse_workspace):
    rec = _model(sparse_workspace)
    seen = {i: {p.point3D_id for p in rec.image(i).points2D if p.has_point3D()} for i in rec.reg_image_ids()}
    shared = {(a, b): len(seen[a] & seen[b]) for a, b in combinations(sorted(seen), 2)}
    assert set(overlapping_pairs(rec, partners=len(seen))) == {p for p, n in shared.items() if n >= MIN_SHARED_POINTS}
    pairs = set(overlapping_pairs(rec, partners=3))
    for a, b in combinations(sorted(seen), 2):  # kept: among the 3 that share the most with a, or with b
        best = [sorted((shared[tuple(sorted((i, j)))] for j in seen if j != i), reverse=True)[2] for i in (a, b)]
        wanted = shared[a, b] >= MIN_SHARED_POINTS and (shared[a, b] >= best[0] or shared[a, b] >= best[1])
        if shared[a, b] not in best:  # (a tie at the third place may go either way)
            assert ((a, b) in pairs) == wanted


def test_only_photos_smaller_than_the_size_are_refined(sparse_workspace):
    rec = _model(sparse_workspace)  # 320x240 photos
    assert refinable(rec, 1280) is None
    assert "320 px" in refinable(rec, 320)


def test_features_that_explain_less_leave_the_model_as_it_was(sparse_workspace):
    rec = _model(sparse_workspace)
    # each photo's first 40 keypoints of the model's own: far fewer observations than the model holds
    features = {}
    for image_id in rec.reg_image_ids():
        points = np.array([p.xy for p in rec.image(image_id).points2D][:40], np.float32)
        features[image_id] = (np.column_stack([points, np.ones((len(points), 2), np.float32)]),
                              np.random.default_rng(image_id).integers(0, 128, (len(points), 128), dtype=np.uint8))
    kept = refine(rec, features, sparse_workspace / "images", SfmConfig(),
                  *camera_start(sparse_workspace / "database.db"))
    assert kept is rec


def _rotation_error(rec, truth) -> float:
    """Median relative rotation error (degrees) over all pairs of registered photos."""
    est = {image.name: image.cam_from_world().rotation.matrix() for image in rec.images.values() if image.has_pose}
    names = sorted(set(est) & set(truth))
    errors = []
    for a, b in combinations(names, 2):
        relative = est[a] @ est[b].T @ (truth[a].R @ truth[b].R.T).T
        errors.append(np.degrees(np.arccos(np.clip((np.trace(relative) - 1) / 2, -1, 1))))
    return float(np.median(errors))


@pytest.mark.slow
def test_refinement_brings_the_cameras_closer_to_the_truth(small_scene, copy_workspace):
    from recon.synth import load_scene

    truth = load_scene(small_scene).cameras()
    before = _model(copy_workspace)
    recon.run(SPARSE_TEST, images=str(small_scene / "images"), workspace=str(copy_workspace),
              overrides=["sfm.refine_image_size=1280"])
    after = _model(copy_workspace)
    assert after.num_reg_images() == before.num_reg_images()
    assert after.num_points3D() > before.num_points3D()
    assert _rotation_error(after, truth) < 0.8 * _rotation_error(before, truth)
