"""Parts of localization on the shared sparse reconstruction: matching, retrieval, intrinsics choice."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from recon.geometry.transforms import rotation_angle_deg
from recon.localize import LocalizeOptions, Photo, PhotoCamera, load_reference
from recon.localize.correspondences import correspondences
from recon.localize.intrinsics import choose_intrinsics
from recon.localize.pose import place
from recon.localize.retrieval import retrieve
from recon.sparse.sift_match import sift_matches


@pytest.fixture(scope="module")
def reference(sparse_workspace):
    return load_reference(sparse_workspace / "sparse" / "0", sparse_workspace / "database.db")


def test_reference_holds_descriptors_and_tracks(reference):
    rec = reference.reconstruction
    assert reference.image_ids == sorted(rec.reg_image_ids()) and len(reference.image_ids) == 16
    for image_id in reference.image_ids:
        tracks = reference.point3D_ids[image_id]
        assert len(reference.descriptors[image_id]) == len(tracks) == rec.image(image_id).num_points2D()
        assert np.count_nonzero(tracks >= 0) == rec.image(image_id).num_points3D
    some = reference.point3D_ids[reference.image_ids[0]]
    some = some[some >= 0][:5]
    assert np.allclose(reference.points3D(some), [rec.point3D(int(i)).xyz for i in some])


@pytest.mark.parametrize("cross_check", [True, False])
def test_sift_matches_equal_colmaps_matcher(reference, cross_check):
    options = pycolmap.FeatureMatchingOptions()
    options.num_threads = 1
    options.sift.cpu_brute_force_matcher = True
    options.sift.cross_check = cross_check
    colmap = pycolmap.FeatureMatcher.create(options, pycolmap.Device.cpu)
    ids = reference.image_ids
    a = reference.descriptors[ids[0]]
    for other in (ids[1], ids[8]):  # a neighbour (many matches) and the far side of the orbit (few)
        b = reference.descriptors[other]
        expected = np.asarray(colmap.match(
            None, pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT, a),
            None, pycolmap.FeatureDescriptors(pycolmap.FeatureExtractorType.SIFT, b)))
        ours = sift_matches(a, b, cross_check=cross_check)
        assert {tuple(m) for m in ours} == {tuple(m) for m in expected}
    assert len(sift_matches(a, reference.descriptors[ids[1]])) > 200
    assert sift_matches(a, a[:0]).shape == (0, 2)


def test_correspondences_follow_tracks(reference):
    ids = reference.image_ids
    query = reference.descriptors[ids[0]]  # an image against its neighbours: its own tracks come back
    kp, points = correspondences(reference, [ids[1], ids[2]], query, LocalizeOptions())
    assert len(kp) > 100 and len(np.unique(np.column_stack([kp, points]), axis=0)) == len(kp)
    own = reference.point3D_ids[ids[0]][kp]
    assert np.mean(own == points) > 0.9


def test_retrieval_ranks_the_image_itself_and_its_neighbours_first(reference):
    ids = reference.image_ids
    ranked = retrieve(reference, [reference.descriptors[ids[5]], reference.descriptors[ids[11]]], neighbours=3)
    assert ranked[0][0] == ids[5] and ranked[1][0] == ids[11]
    assert set(ranked[0][1:]) <= {ids[4], ids[6], ids[3], ids[7]}
    assert len(ranked[0]) == 3


def test_intrinsics_choice(reference):
    ref_cam = reference.reconstruction.camera(reference.reconstruction.image(reference.image_ids[0]).camera_id)
    f = ref_cam.mean_focal_length()
    auto = LocalizeOptions()
    same = choose_intrinsics(PhotoCamera(320, 240, f * 1.05, True), reference, auto)
    assert same.source.startswith("reference camera") and not same.estimate_focal
    assert np.array_equal(same.camera.params, ref_cam.params)
    doubled = choose_intrinsics(PhotoCamera(640, 480, f * 2.0, True), reference, auto)  # rescaled to the size
    assert doubled.source.startswith("reference camera") and np.isclose(doubled.camera.mean_focal_length(), 2 * f)
    zoomed = choose_intrinsics(PhotoCamera(320, 240, f * 1.5, True), reference, auto)
    assert zoomed.source == "photo EXIF focal" and zoomed.camera.mean_focal_length() == f * 1.5
    assert not zoomed.estimate_focal
    square = choose_intrinsics(PhotoCamera(300, 300, 360.0, False), reference, auto)
    assert square.source == "photo, focal guessed" and square.estimate_focal
    refused = choose_intrinsics(PhotoCamera(300, 300, 360.0, False), reference, LocalizeOptions(intrinsics="reference"))
    assert isinstance(refused, str) and "aspect ratio" in refused
    never = choose_intrinsics(PhotoCamera(300, 300, 360.0, False), reference, LocalizeOptions(estimate_focal="never"))
    assert not never.estimate_focal


def _as_photo(reference, image_id):
    """A registered reference image as a new photo: its keypoints and descriptors, EXIF-like focal."""
    image = reference.reconstruction.image(image_id)
    camera = reference.reconstruction.camera(image.camera_id)
    keypoints = np.array([p.xy for p in image.points2D], dtype=np.float32)
    return Photo(f"new_{image.name}", PhotoCamera(camera.width, camera.height, camera.mean_focal_length(), True),
                 keypoints, reference.descriptors[image_id])


def test_place_recovers_a_reference_pose_and_reports_refusals(reference):
    ids = reference.image_ids
    photo = _as_photo(reference, ids[4])
    placed = place(photo, reference, [ids[3], ids[5]], LocalizeOptions())
    assert placed.placed and placed.reason == "" and placed.inliers > 100
    truth = reference.reconstruction.image(ids[4]).cam_from_world()
    assert rotation_angle_deg(placed.R, truth.rotation.matrix()) < 0.05
    spread = np.linalg.norm(reference.reconstruction.image(ids[3]).projection_center()
                            - reference.reconstruction.image(ids[5]).projection_center())
    assert np.linalg.norm(placed.centre - reference.reconstruction.image(ids[4]).projection_center()) < 0.01 * spread
    strict = place(photo, reference, [ids[3], ids[5]], LocalizeOptions(min_inlier_ratio=0.9999))
    assert not strict.placed and strict.reason.startswith("inlier ratio too low") and strict.R is None
    few = place(photo, reference, [ids[3], ids[5]], LocalizeOptions(min_inliers=placed.matches + 1))
    assert not few.placed and few.reason.startswith("too few 2D-3D matches")
    unseen = place(photo, reference, [ids[12]], LocalizeOptions())  # the far side of the orbit
    assert not unseen.placed and unseen.matches < 30
