"""calibrate: intrinsics from rendered chessboard views, and SfM keeping them fixed (criterion 2)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pycolmap
import pytest
from PIL import Image

import recon
from recon.eval.groundtruth import Camera
from recon.eval.poses import pose_metrics
from recon.files import read_json
from recon.imaging.calibration import Chessboard, render_board_views
from recon.imaging.intrinsics import Intrinsics
from recon.imaging.undistort import undistorted_camera
from recon.sparse.database import opened, private_copy
from recon.synth import scene_cameras
from recon.synth.render import Renderer
from recon.synth.scene import build_scene

# The scene camera at the calibration photos' size: 0.9 x width focal (as recon.synth), barrel distortion.
TRUE = Intrinsics("OPENCV", 640, 480, (576.0, 576.0, 320.0, 240.0, -0.12, 0.03, 0.0005, -0.0004))
BOARD = Chessboard(columns=9, rows=6, square_size=1.0)


def output(ws: Path, stage: str) -> Path:
    return ws / ".recon" / "cache" / stage / read_json(ws / ".recon" / "state.json")[stage][:16]


@pytest.fixture(scope="module")
def boards(tmp_path_factory) -> Path:
    """12 noisy 640x480 photos of a 9x6 chessboard seen by TRUE from 12-15 squares away."""
    rng = np.random.default_rng(1)
    poses = []
    for _ in range(12):
        R = cv2.Rodrigues(np.array([*rng.uniform(-0.5, 0.5, 2), rng.uniform(-0.3, 0.3)]))[0]
        t = np.array([*rng.uniform(-1.0, 1.0, 2), rng.uniform(12.0, 15.0)]) - R @ np.array([5.0, 3.5, 0.0])
        poses.append((R, t))
    folder = tmp_path_factory.mktemp("boards")
    for i, view in enumerate(render_board_views(BOARD, TRUE, poses, supersample=3)):
        noisy = np.clip(view + rng.normal(0, 2.0, view.shape), 0, 255).astype(np.uint8)
        Image.fromarray(noisy).save(folder / f"board_{i:02d}.png")
    return folder


def _errors(cam: Intrinsics) -> dict[str, float]:
    errors = {n: abs(getattr(cam, n) - getattr(TRUE, n)) / getattr(TRUE, n) for n in ("fx", "fy", "cx", "cy")}
    errors["k1"] = abs(cam.param("k1") - TRUE.param("k1"))
    return errors


def test_calibrate_stage_recovers_the_camera(boards, tmp_path):
    ws = tmp_path / "ws"
    result = recon.run({"stages": ["calibrate"], "calibrate": {"images": str(boards)}}, workspace=str(ws))
    assert result.ran == ["calibrate"] and result.summaries["calibrate"]["views"] == 12
    data = read_json(output(ws, "calibrate") / "intrinsics.json")
    cam = Intrinsics(data["model"], data["width"], data["height"], data["params"])
    errors = _errors(cam)
    print(f"calibrate stage: rms {data['rms']:.3f} px; relative errors fx/fy/cx/cy and |dk1|: "
          f"{ {k: round(v, 5) for k, v in errors.items()} }")
    assert cam.model == "OPENCV" and data["use"] == "fixed"
    assert max(errors[n] for n in ("fx", "fy", "cx", "cy")) < 0.005 and errors["k1"] < 0.01


def test_without_board_photos_calibrate_writes_nothing(tmp_path):
    result = recon.run({"stages": ["calibrate"]}, workspace=str(tmp_path / "ws"))
    assert result.summaries["calibrate"] == {"calibrated": False}
    assert sorted(p.name for p in output(tmp_path / "ws", "calibrate").iterdir()) == ["manifest.json"]


@pytest.mark.parametrize("use", ["fixed", "prior"])
def test_calibration_reaches_the_database_scaled_to_the_photos(boards, small_scene, tmp_path, use):
    """320x240 photos, 640x480 calibration photos: the camera is the calibration at half size."""
    ws = tmp_path / "ws"
    recon.run({"until": "features", "calibrate": {"images": str(boards), "use": use}},
              images=str(small_scene / "images"), workspace=str(ws))
    calibrated = read_json(output(ws, "calibrate") / "intrinsics.json")
    expected = Intrinsics(calibrated["model"], 640, 480, calibrated["params"]).scaled(320, 240)
    cam = read_json(output(ws, "preprocess") / "images.json")["cameras"]
    assert len(cam) == 1 and cam[0]["fixed"] == (use == "fixed") and cam[0]["prior_focal"]
    assert (cam[0]["model"], cam[0]["width"], cam[0]["height"]) == ("OPENCV", 320, 240)
    assert cam[0]["params"] == pytest.approx(list(expected.params))
    with private_copy(output(ws, "features") / "database.db") as copy, opened(copy) as db:
        (camera,) = db.read_all_cameras()
    assert camera.model.name == "OPENCV" and camera.has_prior_focal_length
    assert list(camera.params) == pytest.approx(list(expected.params))


def _distorted_scene(folder: Path, views: int = 16) -> dict:
    """The synthetic scene photographed at 320x240 through TRUE's lens (TRUE at half size); GT cameras.

    Each view is rendered through an ideal camera at 640x480 with a wider field (f = 480), then
    resampled where the distorted camera's pixels look (their rays: the inverse distortion).
    """
    lens = TRUE.scaled(320, 240)
    wide = np.array([[480.0, 0.0, 320.0], [0.0, 480.0, 240.0], [0.0, 0.0, 1.0]])
    gx, gy = np.meshgrid(np.arange(320) + 0.5, np.arange(240) + 0.5)
    rays = lens.undistort_pixels(np.stack([gx.ravel(), gy.ravel()], axis=1))
    map_x = (rays[:, 0] * wide[0, 0] + wide[0, 2] - 0.5).reshape(240, 320).astype(np.float32)
    map_y = (rays[:, 1] * wide[1, 1] + wide[1, 2] - 0.5).reshape(240, 320).astype(np.float32)
    cameras, _ = scene_cameras(views=views, width=320, height=240, image_format="png")
    renderer = Renderer(build_scene(0))
    folder.mkdir(parents=True)
    for name, cam in cameras.items():
        rgb, _, _ = renderer.render(Camera(wide, cam.R, cam.t, 640, 480))
        Image.fromarray(cv2.remap(rgb, map_x, map_y, cv2.INTER_LINEAR)).save(folder / name)
    return cameras


@pytest.mark.slow
def test_sfm_keeps_the_calibrated_undistorted_camera_fixed(boards, tmp_path):
    gt = _distorted_scene(tmp_path / "photos")
    ws = tmp_path / "ws"
    result = recon.run({"until": "sfm", "calibrate": {"images": str(boards)},
                        "preprocess": {"ops": [{"op": "undistort"}]}},
                       images=str(tmp_path / "photos"), workspace=str(ws))
    cameras = read_json(output(ws, "preprocess") / "images.json")["cameras"]
    assert len(cameras) == 1 and cameras[0]["model"] == "PINHOLE" and cameras[0]["fixed"]
    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    (camera,) = rec.cameras.values()
    assert camera.model.name == "PINHOLE"
    assert list(camera.params) == pytest.approx(cameras[0]["params"], rel=1e-12)  # BA left it alone
    ideal = undistorted_camera(TRUE.scaled(320, 240), 0.0)
    est = {i.name: (i.cam_from_world().rotation.matrix(), i.cam_from_world().translation)
           for i in rec.images.values() if i.has_pose}
    poses = pose_metrics(est, gt)
    focal_error = abs(camera.params[0] - ideal.fx) / ideal.fx
    print(f"registered {rec.num_reg_images()}/{len(gt)}, fixed fx {camera.params[0]:.2f} (ideal {ideal.fx:.2f}, "
          f"{100 * focal_error:.2f}%), AUC@1/5 {poses['auc@1']:.1f}/{poses['auc@5']:.1f}, "
          f"reprojection {result.summaries['sfm']['mean_reproj_error']} px")
    assert rec.num_reg_images() == len(gt)
    assert focal_error < 0.005
    assert poses["auc@5"] > 90.0
