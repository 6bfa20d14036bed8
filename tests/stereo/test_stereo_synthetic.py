"""Two-view stereo on rendered pairs with exact depth: accuracy (share of depth pixels within 1 % of the
truth on textured surface) and coverage, for a rectified pair, a turned (unrectified) one, the right
camera on the left, a vertical baseline and distorted photos."""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest
from stereo_pairs import BASELINE, depth_scores, pinhole

from recon.imaging.intrinsics import Intrinsics
from recon.stereo import StereoOptions, from_poses, stereo_depth

log = logging.getLogger(__name__)


def run_pair(pair, left_cam=None, right_cam=None, left_image=None, right_image=None, **options):
    left_cam, right_cam = left_cam or pinhole(pair.left), right_cam or pinhole(pair.right)
    calib = from_poses(left_cam, (pair.left.R, pair.left.t), right_cam, (pair.right.R, pair.right.t))
    truth = pair.left_depth[pair.left_depth > 0]
    depth_range = (float(truth.min()) / 1.25, float(truth.max()) * 1.25)  # as from sparse points
    return stereo_depth(pair.left_image if left_image is None else left_image,
                        pair.right_image if right_image is None else right_image,
                        calib, StereoOptions(**options), depth_range)


def check(result, pair, truth=None, image=None, label=""):
    scores = depth_scores(result.depth, pair.left_depth if truth is None else truth,
                          pair.left_image if image is None else image)
    log.info("%s: %.1f%% within 1%%, coverage %.1f%%, sky with depth %.1f%%, %s", label, 100 * scores["within"],
             100 * scores["coverage"], 100 * scores["sky_with_depth"], result.figures["seconds"])
    assert scores["within"] >= 0.90, scores
    assert scores["coverage"] >= 0.75, scores
    assert scores["sky_with_depth"] < 0.05, scores
    return scores


def test_rectified_pair(render_pair):
    pair = render_pair()
    result = run_pair(pair)
    scores = check(result, pair, label="rectified pair")
    assert result.figures["rectified_size"] == "640x480" and result.figures["stereo"] == "horizontal"
    assert result.depth.shape == pair.left_depth.shape and result.depth.dtype == np.float32
    assert scores["within"] >= 0.95  # measured 98.1 %


def test_unrectified_pair(render_pair):
    """The right camera turned by ~3.5 degrees and a little above: rectification does the work."""
    pair = render_pair(offset=(BASELINE, -0.02, 0.01), rotation_deg=(1.0, 3.0, 1.5))
    result = run_pair(pair)
    check(result, pair, label="turned pair")
    assert result.figures["rectified_size"] != "640x480"


@pytest.mark.parametrize("offset,stereo", [((-BASELINE, 0.0, 0.0), "horizontal"), ((0.0, BASELINE, 0.0), "vertical")],
                         ids=["right-camera-on-the-left", "vertical-baseline"])
def test_other_baselines(render_pair, offset, stereo):
    pair = render_pair(offset=offset, rotation_deg=(0.0, 1.0, 0.5))
    result = run_pair(pair)
    check(result, pair, label=stereo)
    assert result.figures["stereo"] == stereo


def test_without_depth_range_searches_a_quarter_width(render_pair):
    pair = render_pair()
    calib = from_poses(pinhole(pair.left), (pair.left.R, pair.left.t), pinhole(pair.right),
                       (pair.right.R, pair.right.t))
    result = stereo_depth(pair.left_image, pair.right_image, calib)
    assert result.figures["disparities"] == [-1, 175]  # 0..160 (640 / 4), a pixel to spare: 176 = 11 x 16
    check(result, pair, label="no depth range")


def distort(image: np.ndarray, truth: np.ndarray, cam: Intrinsics, k1: float):
    """The photo and true depth a camera with radial distortion ``k1`` (OPENCV model) would take from
    the pinhole camera ``cam``'s viewpoint: each distorted pixel samples the pinhole image where its
    undistorted ray meets it (pincushion, k1 > 0, stays inside the pinhole view)."""
    distorted = Intrinsics("OPENCV", cam.width, cam.height, (cam.fx, cam.fy, cam.cx, cam.cy, k1, 0.0, 0.0, 0.0))
    cols, rows = np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5)
    xy = distorted.undistort_pixels(np.column_stack([cols.ravel(), rows.ravel()]))
    mx = (xy[:, 0] * cam.fx + cam.cx - 0.5).reshape(cols.shape).astype(np.float32)  # cv2 pixel coordinates
    my = (xy[:, 1] * cam.fy + cam.cy - 0.5).reshape(cols.shape).astype(np.float32)
    photo = cv2.remap(image, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
    depth = cv2.remap(truth, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT)
    return photo, depth, distorted


def test_distorted_photos(render_pair):
    pair = render_pair(rotation_deg=(0.0, 2.0, 0.0))
    left, truth, left_cam = distort(pair.left_image, pair.left_depth, pinhole(pair.left), 0.08)
    right, _, right_cam = distort(pair.right_image, pair.right_depth, pinhole(pair.right), 0.05)
    result = run_pair(pair, left_cam, right_cam, left, right)
    check(result, pair, truth, left, label="distorted photos")
    # ignoring the distortion misplaces depth away from the centre
    plain = run_pair(pair, pinhole(pair.left), pinhole(pair.right), left, right)
    assert depth_scores(plain.depth, truth, left)["within"] < depth_scores(result.depth, truth, left)["within"] - 0.1


def test_working_size_and_options(render_pair):
    pair = render_pair()
    result = run_pair(pair, max_image_size=320, lr_max_diff=0.5)
    assert result.depth.shape == (240, 320)
    assert result.camera.width == 320 and result.camera.K[0, 0] == pytest.approx(pair.left.K[0, 0] / 2)
    truth = cv2.resize(pair.left_depth, (320, 240), interpolation=cv2.INTER_NEAREST)
    image = cv2.resize(pair.left_image, (320, 240), interpolation=cv2.INTER_AREA)
    scores = depth_scores(result.depth, truth, image, tolerance=0.02)  # half the disparities: 2 %
    assert scores["within"] >= 0.9 and scores["coverage"] >= 0.6, scores
    strict = run_pair(pair, max_image_size=320, lr_max_diff=0.0)
    assert np.count_nonzero(strict.depth) < np.count_nonzero(result.depth)
