"""A fisheye focal length from the photos alone (no EXIF): the prior that verifies best."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from recon.sparse.features import FeaturesConfig, extract_sift
from recon.sparse.fisheye_focal import estimate_focal
from recon.synth.wide import fisheye_params, render_fisheye_orbit


@pytest.mark.parametrize("fov", [176.0, pytest.param(140.0, marks=pytest.mark.slow)])
def test_focal_found_within_three_percent(tmp_path, fov):
    scene = render_fisheye_orbit(tmp_path / "fisheye", views=10, width=320, height=240, diagonal_fov_deg=fov)
    settings = FeaturesConfig().settings()
    features = [extract_sift(scene.images_dir / name, settings) for name in scene.image_names]
    truth = fisheye_params(320, 240, fov)[0]
    # start from a focal far off: the estimate must not depend on it
    camera = pycolmap.Camera(model="OPENCV_FISHEYE", width=320, height=240, params=[900, 900, 160, 120, 0, 0, 0, 0])
    est = estimate_focal(camera, len(features), features.__getitem__)
    assert est is not None and est.pairs >= 8
    assert est.focal == pytest.approx(truth, rel=0.03)
    assert est.diagonal_fov_deg == pytest.approx(fov, rel=0.03)
    scores = dict(est.scores)  # the scores peak inside the range, not at an end
    assert max(scores.values()) > max(scores[min(scores)], scores[max(scores)])


def test_no_estimate_without_matches():
    rng = np.random.default_rng(0)
    noise = [(rng.uniform(0, 320, (50, 4)).astype(np.float32), rng.integers(0, 255, (50, 128), dtype=np.uint8))
             for _ in range(4)]
    camera = pycolmap.Camera(model="OPENCV_FISHEYE", width=320, height=240, params=[100, 100, 160, 120, 0, 0, 0, 0])
    assert estimate_focal(camera, len(noise), noise.__getitem__) is None
