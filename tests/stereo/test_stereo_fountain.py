"""fountain-P11 (Strecha), two neighbouring views with their ground-truth cameras: the two-view stereo
depth of 0005.jpg (paired with 0006.jpg) against recon's dense stage (CPU PatchMatch with sources
0004 and 0006, photometric then geometric pass and filtering), both at the same size and depth range.
The figure is the share of the pixels both give a depth whose depths agree within 1 %."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import recon

log = logging.getLogger(__name__)

LEFT, RIGHT, OTHER = "0005.jpg", "0006.jpg", "0004.jpg"
DEPTH_RANGE = (4.0, 25.0)  # the fountain and its wall stand 6-9 m from these cameras


@pytest.fixture(scope="module")
def fountain() -> Path:
    root = recon.datasets_root() / "fountain_p11"
    if not root.is_dir():
        pytest.skip(f"fountain_p11 absent: {root} (set RECON_DATASETS)")
    return root


def patchmatch_depth(root: Path, work: Path, size: int) -> np.ndarray:
    """recon.mvs's geometric depth map of LEFT (longest side ``size``) with the true cameras."""
    from recon.eval.groundtruth import load_cameras
    from recon.mvs.colmap_io import read_depth_map
    from recon.mvs.options import MVSOptions
    from recon.mvs.stereo import geometric_view, photometric_view
    from recon.mvs.views import Problem, ViewCamera

    cams = load_cameras(root / "gt" / "gt_dense_cameras")
    names = (OTHER, LEFT, RIGHT)
    views = {n: ViewCamera(n, cams[n].K, cams[n].R, cams[n].t, cams[n].width, cams[n].height) for n in names}
    (work / "images").symlink_to(root / "images")
    options = MVSOptions(max_image_size=size)
    problems = {n: Problem(n, tuple(m for m in names if m != n), *DEPTH_RANGE, views) for n in names}
    for name in names:  # every view's photometric map, then the reference's geometric pass
        photometric_view(work, problems[name], options, work / "stereo")
    return read_depth_map(geometric_view(work, problems[LEFT], options, work / "stereo"))


def stereo_depth_of(root: Path, size: int):
    from recon.eval.groundtruth import load_cameras
    from recon.imaging.intrinsics import Intrinsics
    from recon.stereo import StereoOptions, from_poses, stereo_depth

    cams = load_cameras(root / "gt" / "gt_dense_cameras")

    def camera(name):  # Strecha's K taken as given, as recon.mvs does
        c = cams[name]
        return Intrinsics.pinhole(c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], c.width, c.height), (c.R, c.t)

    (left_cam, left_pose), (right_cam, right_pose) = camera(LEFT), camera(RIGHT)
    calib = from_poses(left_cam, left_pose, right_cam, right_pose)
    left, right = (np.asarray(Image.open(root / "images" / n).convert("RGB")) for n in (LEFT, RIGHT))
    return stereo_depth(left, right, calib, StereoOptions(max_image_size=size), DEPTH_RANGE)


def compare(root: Path, work: Path, size: int) -> dict:
    start = time.perf_counter()
    reference = patchmatch_depth(root, work, size)
    patchmatch_seconds = time.perf_counter() - start
    start = time.perf_counter()
    result = stereo_depth_of(root, size)
    stereo_seconds = time.perf_counter() - start
    assert result.depth.shape == reference.shape
    both = (result.depth > 0) & (reference > 0)
    error = np.abs(result.depth[both] - reference[both]) / reference[both]
    figures = {"size": result.figures["size"], "agree_1pc": float((error < 0.01).mean()),
               "agree_2pc": float((error < 0.02).mean()), "shared": float(both.mean()),
               "stereo_coverage": result.coverage, "patchmatch_coverage": float((reference > 0).mean()),
               "stereo_s": round(stereo_seconds, 1), "patchmatch_s": round(patchmatch_seconds, 1)}
    log.info("fountain %s", figures)
    return figures


@pytest.mark.datasets
def test_fountain_quick(fountain, tmp_path):
    """The same at 512x341 (measured: 96 % agree within 1 %, 61 % of the pixels shared)."""
    figures = compare(fountain, tmp_path, 512)
    assert figures["agree_1pc"] >= 0.90, figures
    assert figures["shared"] >= 0.4, figures


@pytest.mark.slow
@pytest.mark.datasets
def test_fountain_agrees_with_patchmatch(fountain, tmp_path):
    figures = compare(fountain, tmp_path, 1536)
    assert figures["size"] == "1536x1024"
    assert figures["agree_1pc"] >= 0.90, figures
    assert figures["stereo_coverage"] >= 0.5 and figures["shared"] >= 0.4, figures
