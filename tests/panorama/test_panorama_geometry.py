"""Panorama geometry: the 360 deg ring closes, the width is 2 pi f, and known directions land where
the estimated model says and where the image content shows them."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pano_eval as pe

from recon.panorama import PanoramaModel, PanoramaOptions, compose, register
from recon.synth import panorama as sp


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(2 * np.arcsin(min(1.0, np.linalg.norm(R - np.eye(3)) / (2 * np.sqrt(2))))))


def test_ring_registration_closes_the_loop(ring, ring_registration):
    reg = ring_registration
    n = len(ring.images)
    assert reg.connected == list(range(n)) and not reg.dropped
    linked = {(p.i, p.j) for p in reg.pairs}
    assert {(i, i + 1) for i in range(n - 1)} | {(0, n - 1)} <= linked  # neighbours, and last with first
    closing = next(p for p in reg.pairs if (p.i, p.j) == (0, n - 1))
    assert max(p.residual_after for p in reg.pairs) < 0.5  # px: every pair agrees after bundle adjustment
    assert closing.residual_after < 0.5
    f_true = ring.K[0, 0]
    assert np.abs(reg.focals / f_true - 1).max() < 0.005
    # estimated camera-to-panorama x true world-to-camera is one rotation for all photos
    frames = [R @ G for R, G in zip(reg.rotations, ring.rotations)]
    errors = [_angle_deg(F @ frames[0].T) for F in frames]
    assert max(errors) < 0.05, errors


def test_full_circle_is_exactly_2pi_focal_wide(ring_registration, ring_panorama):
    model = ring_panorama.model
    assert model.full_circle
    assert model.width == ring_panorama.image.shape[1] and model.height == ring_panorama.image.shape[0]
    assert abs(model.width - 2 * np.pi * model.scale) < 1e-9
    assert abs(model.scale - np.median(ring_registration.focals)) < 0.1  # only the rounding of the width
    assert ring_panorama.mask[:, [0, -1]].mean() > 0.9  # both ends are covered: nothing cut off at the wrap


def test_marker_columns_match_truth_and_content(ring, ring_panorama):
    """20 markers on the horizon: their columns by the estimated model, and their centroids found in
    the panorama, are within 2 px of azimuth x width / 360 (plus one global offset), and within
    1 px of each other (the mapping tells where the content is)."""
    cols = pe.marker_columns(ring_panorama, ring.rotations)
    assert not np.isnan(cols.found).any()
    print(f"mapped column error max {np.abs(cols.mapped_error).max():.2f} px, median "
          f"{np.median(np.abs(cols.mapped_error)):.2f}; found max {np.abs(cols.found_error).max():.2f}, "
          f"median {np.median(np.abs(cols.found_error)):.2f}; mapped vs found max {cols.content_error.max():.2f}")
    assert np.abs(cols.mapped_error).max() < 2.0
    assert np.abs(cols.found_error).max() < 2.0
    assert cols.content_error.max() < 1.0
    # the horizon is level: views are tilted up to 1.5 deg at random and wave correction levels their
    # average, so the horizon may tilt by ~0.1 deg (2 px up and down); up to 36 px without it
    assert np.ptp(cols.found[:, 1]) < 6.0


def test_a_lying_mapping_is_caught(ring, ring_panorama):
    """The content check is what makes the column test meaningful: a model shifted by 3 px still has
    its columns evenly spaced, but no longer points at the markers."""
    shifted = dataclasses.replace(ring_panorama, model=dataclasses.replace(ring_panorama.model,
                                                                           u0=ring_panorama.model.u0 + 3))
    cols = pe.marker_columns(shifted, ring.rotations)
    assert np.abs(cols.mapped_error).max() < 2.0
    assert np.nanmin(cols.content_error) > 2.0


def test_mapping_agrees_with_opencv_warper(ring_panorama):
    model = ring_panorama.model
    warper = cv2.PyRotationWarper(model.projection, model.scale)
    rng = np.random.default_rng(1)
    for k in range(len(model.rotations)):
        pts = rng.uniform([0, 0], [640, 480], size=(20, 2))
        ours = model.camera_pixel(k, pts)
        K = np.array([[model.focals[k], 0, model.principal[k][0] - 0.5],
                      [0, model.focals[k], model.principal[k][1] - 0.5], [0, 0, 1]], np.float32)
        R = model.rotations[k].astype(np.float32)
        theirs = np.array([warper.warpPoint((float(x) - 0.5, float(y) - 0.5), K, R) for x, y in pts])
        theirs = theirs - [model.u0, model.v0] + 0.5
        theirs[:, 0] %= model.width
        diff = np.abs(ours - theirs)
        diff[:, 0] = np.minimum(diff[:, 0], model.width - diff[:, 0])
        assert diff.max() < 0.02, (k, diff.max())


def test_direction_pixel_round_trip():
    rng = np.random.default_rng(2)
    dirs = rng.normal(size=(200, 3))
    dirs[:, 2] = np.abs(dirs[:, 2]) + 0.5  # in front, for the plane
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for proj, full in [("spherical", True), ("cylindrical", True), ("plane", False)]:
        model = PanoramaModel(proj, 500.0, 3142, 1000, -1571, 200, full, np.eye(3)[None], np.array([500.0]),
                              np.array([[320.0, 240.0]]))
        back = model.to_direction(model.to_pixel(dirs))
        assert np.abs(back - dirs).max() < 1e-9, proj


def test_partial_sets_do_not_wrap(ring):
    """Five consecutive views (150 deg): no wrap, the width is the views' extent, and markers still
    land where the mapping says; a plane projection of three views too."""
    for proj, views in [("cylindrical", [3, 4, 5, 6, 7]), ("plane", [8, 9, 10])]:
        images = [ring.images[k] for k in views]
        opts = PanoramaOptions(projection=proj, seam="voronoi")
        pano = compose(images, register(images, opts), opts)
        assert not pano.model.full_circle
        assert pano.model.width < 0.6 * 2 * np.pi * pano.model.scale
        rotations = [ring.rotations[k] for k in views]
        cols = pe.marker_columns(pano, rotations)
        x, y = np.nan_to_num(cols.mapped, nan=-1.0).astype(int).T  # NaN: behind the plane
        inside = (x > 15) & (x < pano.model.width - 15) & (y >= 0) & (y < pano.model.height)
        inside[inside] &= pano.mask[y[inside], x[inside]]
        assert inside.sum() >= 2, proj
        assert np.nanmax(cols.content_error[inside]) < 1.0, proj


def test_direction_of_world_markers_in_first_camera_frame(ring, ring_panorama):
    """The caller's use: a direction known in the first photo's frame -> panorama pixel."""
    az = sp.marker_azimuths()[[0, 7, 13]]
    d_cam0 = sp.direction(az) @ ring.rotations[0].T  # R0 @ d for each row
    px = ring_panorama.model.to_pixel(d_cam0, camera=0)
    found = np.array([pe.marker_centroid(ring_panorama.image, x, y, 12) for x, y in px])
    assert np.abs(found - px).max() < 1.0


def test_max_width_composes_at_a_lower_scale(ring, ring_registration):
    opts = PanoramaOptions(max_width=2000, seam="voronoi")
    pano = compose(ring.images, ring_registration, opts)
    assert pano.model.full_circle and pano.image.shape[1] == pano.model.width == 2000
    assert abs(pano.model.scale - 2000 / (2 * np.pi)) < 1e-9
    cols = pe.marker_columns(pano, ring.rotations)
    assert np.abs(cols.found_error).max() < 1.0 and cols.content_error.max() < 1.0
