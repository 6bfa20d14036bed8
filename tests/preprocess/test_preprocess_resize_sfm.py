"""Resize through the whole sparse pipeline: SfM on the downsized scene keeps every view and the scaled focal."""

from __future__ import annotations

import pycolmap
import pytest
from PIL import Image

import recon
from recon.eval.groundtruth import load_cameras
from recon.eval.poses import pose_metrics
from recon.files import read_json


@pytest.mark.slow
def test_sfm_on_resized_photos_registers_all_with_the_scaled_focal(small_scene, tmp_path):
    ws = tmp_path / "ws"
    result = recon.run({"until": "export", "preprocess": {"ops": [{"op": "resize", "max_size": 240}]}},
                       images=str(small_scene / "images"), workspace=str(ws))
    gt = load_cameras(small_scene)
    gt_focal = next(iter(gt.values())).K[0, 0] * 240 / 320
    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    (camera,) = rec.cameras.values()
    est = {i.name: (i.cam_from_world().rotation.matrix(), i.cam_from_world().translation)
           for i in rec.images.values() if i.has_pose}
    poses = pose_metrics(est, gt)
    error = abs(camera.focal_length - gt_focal) / gt_focal
    print(f"resized to {camera.width}x{camera.height}: registered {rec.num_reg_images()}/{len(gt)}, focal "
          f"{camera.focal_length:.2f} vs scaled GT {gt_focal:.2f} ({100 * error:.2f}%), AUC@5 {poses['auc@5']:.1f}")
    assert (camera.width, camera.height) == (240, 180)
    assert rec.num_reg_images() == len(gt) == 16
    assert error < 0.01
    assert poses["auc@5"] > 90.0
    # the workspace's images are the ones the model describes (resized, original colours)
    transforms = read_json(ws / "transforms.json")
    assert transforms["w"] == 240 and len(transforms["frames"]) == 16
    with Image.open(ws / transforms["frames"][0]["file_path"]) as image:
        assert image.size == (240, 180)
    assert result.summaries["preprocess"]["size"] == "240x180"
