"""The final bundle adjustment keeps distortion and principal points only where the observations call
for them (recon.sparse.mapping.final_bundle_adjustment), on exactly known synthetic models."""

import numpy as np
import pycolmap
import pytest

from recon.sparse.mapping import drop_loose_points, final_bundle_adjustment
from recon.stages.sfm import SfmConfig

WIDTH, HEIGHT, FOCAL = 640, 480, 576.0
NOISE_PX = 0.3


def _look_at(centre: np.ndarray) -> np.ndarray:
    """World-to-camera rotation of a camera at ``centre`` looking at the origin, y down."""
    z = -centre / np.linalg.norm(centre)
    x = np.cross([0.0, 0.0, -1.0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def _model(k1: float, spread: float, seed: int = 0, principal=(WIDTH / 2, HEIGHT / 2)) -> pycolmap.Reconstruction:
    """20 views on an orbit of radius 4 round points in a ball of radius ``spread`` (1.2 fills most
    of each photo, 0.35 its middle), seen through one SIMPLE_RADIAL camera with distortion ``k1`` and
    principal point ``principal``; observations are the exact projections plus Gaussian noise of
    NOISE_PX. The model starts from the truth but with the distortion at zero and the principal point
    at the centre, as a mapper's model would after refining it to the noise: a bundle adjustment moves
    it from there."""
    rng = np.random.default_rng(seed)
    truth = pycolmap.Camera(model="SIMPLE_RADIAL", width=WIDTH, height=HEIGHT,
                            params=[FOCAL, *principal, k1], camera_id=1)
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="SIMPLE_RADIAL", width=WIDTH, height=HEIGHT,
                                                    params=[FOCAL, WIDTH / 2, HEIGHT / 2, 0.0], camera_id=1))
    xyz = rng.normal(size=(600, 3))
    xyz *= spread * rng.uniform(0, 1, (600, 1)) ** (1 / 3) / np.linalg.norm(xyz, axis=1, keepdims=True)
    tracks = [pycolmap.Track() for _ in xyz]
    for image_id in range(1, 21):
        angle = 2 * np.pi * image_id / 20
        centre = np.array([4 * np.cos(angle), 4 * np.sin(angle), 0.6 * np.sin(3 * angle)])
        R = _look_at(centre)
        t = -R @ centre
        uv = truth.img_from_cam(xyz @ R.T + t)
        uv += rng.normal(scale=NOISE_PX, size=uv.shape)
        inside = np.nonzero((uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] < WIDTH) & (uv[:, 1] < HEIGHT))[0]
        image = pycolmap.Image(name=f"view_{image_id:02d}.jpg", camera_id=1, image_id=image_id)
        image.points2D = pycolmap.Point2DList([pycolmap.Point2D(uv[p]) for p in inside])
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R), t))
        for idx, p in enumerate(inside):
            tracks[p].add_element(image_id, idx)
    for point, track in zip(xyz, tracks):
        rec.add_point3D(point, track)
    return rec


def _final(rec, k1_start: float):
    cfg = SfmConfig(final_refine_principal_point=False)
    return final_bundle_adjustment(rec, cfg, {1: np.array([FOCAL, WIDTH / 2, HEIGHT / 2, k1_start])})


def test_distortion_the_photos_show_is_kept():
    rec = _final(_model(k1=-0.08, spread=1.2), 0.0)
    assert rec.cameras[1].params[3] == pytest.approx(-0.08, abs=0.005)


def test_distortion_fitted_to_noise_in_the_middle_of_the_photos_is_left_out():
    """Points in the middle of each photo: a refined k1 trades off against the focal length and fits
    the noise, gaining almost nothing; the model keeps the distortion it started from."""
    model = _model(k1=0.0, spread=0.35)
    refined = pycolmap.Reconstruction(model)
    pycolmap.bundle_adjustment(refined)  # what a plain BA makes of it: some k1, not zero
    assert refined.cameras[1].params[3] != 0.0
    rec = _final(model, 0.0)
    assert rec.cameras[1].params[3] == 0.0
    assert rec.cameras[1].params[0] == pytest.approx(FOCAL, rel=0.01)


def test_a_calibrated_distortion_is_where_it_is_held():
    rec = _final(_model(k1=-0.05, spread=0.35), -0.05)
    assert rec.cameras[1].params[3] == -0.05


def test_principal_points_are_refined_unless_that_leaves_the_exif_focal_length():
    """The true principal point 30 and 20 px off centre: held at the centre, the focal length comes out
    0.35 % long; refined, both come back to the truth. With an EXIF focal length at the truth the
    refinement is kept; with one on the long side, refining would take the focal length away from it,
    and the principal point stays at the centre."""
    model = _model(k1=0.0, spread=1.2, principal=(350.0, 260.0))
    cfg = SfmConfig(refine_extra_params=False)

    def final(exif_focal: float):
        return final_bundle_adjustment(pycolmap.Reconstruction(model), cfg,
                                       {1: np.array([exif_focal, WIDTH / 2, HEIGHT / 2, 0.0])}, frozenset({1}))

    kept = final(FOCAL).cameras[1].params
    assert kept[1:3] == pytest.approx([350.0, 260.0], abs=1.0)
    assert kept[0] == pytest.approx(FOCAL, rel=0.001)
    left = final(1.01 * FOCAL).cameras[1].params
    assert list(left[1:3]) == [WIDTH / 2, HEIGHT / 2]
    assert left[0] > 1.002 * FOCAL
    without_exif = final_bundle_adjustment(pycolmap.Reconstruction(model), cfg,
                                           {1: np.array([1.01 * FOCAL, WIDTH / 2, HEIGHT / 2, 0.0])})
    assert without_exif.cameras[1].params[1:3] == pytest.approx([350.0, 260.0], abs=1.0)


def test_one_observation_far_off_does_not_decide_a_refinement():
    """The simpler model places one observation of 12,000 some 9,000 px off (as a point seen side-on,
    which only a refined k1's fold brings into the photo): capped at the mapper's 4 px, the fuller model
    gains too little to be kept; the plain mean would read 1.1 px against 0.37 and keep it."""
    from recon.sparse.mapping import _explains_better, capped_mean_error

    fuller = _model(k1=0.0, spread=0.35)
    simpler = pycolmap.Reconstruction(fuller)
    observation = simpler.image(1).points2D[0]
    observation.xy = observation.xy + np.array([9000.0, 0.0])
    before, after = capped_mean_error(simpler), capped_mean_error(fuller)
    assert after == pytest.approx(NOISE_PX * np.sqrt(np.pi / 2), rel=0.05)  # mean of a 2-D Gaussian's radius
    assert 0 < before - after <= 4.0 / fuller.compute_num_observations()
    assert not _explains_better(simpler, fuller, "distortion")


def test_observations_left_far_off_are_dropped_from_the_model_kept():
    from recon.sparse.mapping import outlier_px

    model = _model(k1=0.0, spread=0.35)
    observation = model.image(3).points2D[5]
    observation.xy = observation.xy + np.array([0.0, 700.0])
    count = model.compute_num_observations()
    rec = _final(model, 0.0)
    assert rec.compute_num_observations() == count - 1
    assert not rec.image(3).points2D[5].has_point3D()
    rec.update_point_3d_errors()
    assert max(rec.point3D(p).error for p in rec.point3D_ids()) < outlier_px()


def test_points_several_times_the_median_error_off_are_dropped():
    """30 of 600 points whose observations scatter 1.5 px about where the point projects (a highlight's
    virtual image, seen from each view somewhere else) go; points with the keypoints' noise alone stay."""
    rec = _model(k1=0.0, spread=1.2)
    rng = np.random.default_rng(1)
    loose = sorted(rec.points3D)[:30]
    for point_id in loose:
        for element in rec.points3D[point_id].track.elements:
            observation = rec.image(element.image_id).points2D[element.point2D_idx]
            observation.xy = observation.xy + rng.normal(scale=1.5, size=2)
    assert drop_loose_points(rec) == 30
    assert not set(loose) & set(rec.points3D) and rec.num_points3D() == 570
    assert drop_loose_points(rec) == 0  # the noise alone stays within 3 times the median
