"""Calibration from rendered targets (criterion 2) and undistortion (criterion 7)."""

import cv2
import numpy as np
import pytest

from recon.imaging.calibration import CharucoTarget, Chessboard, calibrate, render_board_views
from recon.imaging.intrinsics import Intrinsics
from recon.imaging.undistort import UNDISTORT, UndistortOptions, undistorted_camera

TRUE = Intrinsics("OPENCV", 640, 480, (620.0, 615.0, 322.4, 236.9, -0.25, 0.08, 0.001, -0.0008))
BOARD = Chessboard(columns=9, rows=6, square_size=1.0)


def _poses(count: int, centre: np.ndarray, seed: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """Views of the board centre from 12-15 units away, tilted up to ~30 degrees each way."""
    rng = np.random.default_rng(seed)
    poses = []
    for _ in range(count):
        R = cv2.Rodrigues(np.array([*rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.3, 0.3)]))[0]
        t = np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(12.0, 15.0)]) - R @ centre
        poses.append((R, t))
    return poses


def _noisy(views: list[np.ndarray], sigma: float = 2.0) -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    return [np.clip(v + rng.normal(0, sigma, v.shape), 0, 255).astype(np.uint8) for v in views]


@pytest.fixture(scope="module")
def chessboard_views() -> list[np.ndarray]:
    return _noisy(render_board_views(BOARD, TRUE, _poses(12, np.array([5.0, 3.5, 0.0])), supersample=3))


def test_chessboard_calibration_recovers_intrinsics(chessboard_views):
    result = calibrate(chessboard_views, BOARD, model="OPENCV")
    cam = result.camera
    assert cam.model == "OPENCV" and (cam.width, cam.height) == (640, 480)
    assert len(result.used) == len(chessboard_views)
    rel = {name: abs(getattr(cam, name) - getattr(TRUE, name)) / getattr(TRUE, name)
           for name in ("fx", "fy", "cx", "cy")}
    dk1 = abs(cam.param("k1") - TRUE.param("k1"))
    print(f"rms {result.rms:.3f} px; relative errors {rel}; |dk1| {dk1:.4f}; "
          f"cx {cam.cx:.2f} (true {TRUE.cx}), cy {cam.cy:.2f} (true {TRUE.cy})")
    assert all(e < 0.005 for e in rel.values())
    assert dk1 < 0.01
    assert result.rms < 0.2
    # The pixel convention is right to a fraction of the 0.5 px OpenCV/COLMAP offset.
    assert abs(cam.cx - TRUE.cx) < 0.25 and abs(cam.cy - TRUE.cy) < 0.25


def test_constrained_model_estimates_only_its_parameters(chessboard_views):
    cam = calibrate(chessboard_views, BOARD, model="SIMPLE_RADIAL").camera
    assert cam.model == "SIMPLE_RADIAL" and len(cam.params) == 4
    assert abs(cam.fx - 617.5) / 617.5 < 0.02


def test_charuco_calibration_recovers_intrinsics():
    target = CharucoTarget(squares_x=9, squares_y=7, square_size=1.0, marker_size=0.7)
    views = _noisy(render_board_views(target, TRUE, _poses(12, np.array([4.5, 3.5, 0.0]), seed=3),
                                      supersample=3))
    result = calibrate(views, target, model="OPENCV")
    cam = result.camera
    print(f"charuco: {len(result.used)} views, rms {result.rms:.3f}, fx {cam.fx:.2f}, cx {cam.cx:.2f}, "
          f"k1 {cam.param('k1'):.4f}")
    assert len(result.used) >= 10 and result.rms < 0.2
    assert abs(cam.fx - TRUE.fx) / TRUE.fx < 0.005 and abs(cam.cx - TRUE.cx) / TRUE.cx < 0.005
    assert abs(cam.param("k1") - TRUE.param("k1")) < 0.01


def test_undistortion_matches_the_pinhole_projection_within_1px(chessboard_views):
    """Corners detected in the undistorted image sit where the output PINHOLE camera projects them."""
    R, t = _poses(1, np.array([5.0, 3.5, 0.0]), seed=11)[0]
    distorted = render_board_views(BOARD, TRUE, [(R, t)], supersample=3)[0]
    out, pinhole = UNDISTORT.apply(distorted, TRUE, UndistortOptions(alpha=0.0))
    assert pinhole.model == "PINHOLE" and out.shape == distorted.shape and out.dtype == np.uint8
    world = BOARD.object_points().astype(np.float64)
    expected = pinhole.project(world @ R.T + t)
    detected, _ = BOARD.detect(out)
    # Detection order may start at either end: compare each corner with its nearest prediction.
    nearest = np.linalg.norm(detected[:, None] - expected[None], axis=-1).min(axis=1)
    before, _ = BOARD.detect(distorted)
    before_err = np.linalg.norm(before[:, None] - expected[None], axis=-1).min(axis=1)
    print(f"undistorted corners vs pinhole projection: max {nearest.max():.3f} px, "
          f"mean {nearest.mean():.3f} px (distorted image: max {before_err.max():.1f} px)")
    assert nearest.max() < 1.0
    assert before_err.max() > 5.0  # the distortion was large enough to matter


def test_undistort_alpha_and_mask():
    keep_all = undistorted_camera(TRUE, 1.0)
    crop = undistorted_camera(TRUE, 0.0)
    assert keep_all.fx < crop.fx  # keeping every source pixel zooms out
    image = np.full((480, 640), 200, np.uint8)
    out, _ = UNDISTORT.apply(image, TRUE, UndistortOptions(alpha=1.0))
    mask = UNDISTORT.apply_mask(np.ones((480, 640), bool), TRUE, UndistortOptions(alpha=1.0))
    # Barrel distortion undistorts to a pincushion: at alpha 1 the middles of the edges see nothing.
    assert out[0, 320] == 0 and not mask[0, 320] and not mask[240, 0]
    assert mask[240, 320] and mask[0, 0]
    assert np.all(out[mask] == 200) and np.all(out[~mask] == 0)
    full = UNDISTORT.apply_mask(np.ones((480, 640), bool), TRUE, UndistortOptions(alpha=0.0))
    assert full.mean() > 0.995  # alpha 0: (almost) every output pixel sees the source
    with pytest.raises(ValueError):
        UNDISTORT.apply(image, None, UndistortOptions())
