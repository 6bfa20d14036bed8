"""Depth maps against the true surface: the truth scores perfect, wrong depths and sky depths are caught."""

import dataclasses

import numpy as np
import pytest

from recon.eval.depth import depth_map_metrics
from recon.geometry.transforms import Similarity
from recon.synth import render_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return render_scene(tmp_path_factory.mktemp("depth") / "scene", views=6, width=160, height=120, seed=3)


def _figures(scene, depth, to_gt=None):
    name = scene.image_names[0]
    cam = scene.cameras()[name]
    to_gt = to_gt or Similarity(1.0, np.eye(3), np.zeros(3))
    return depth_map_metrics(depth, cam.K, cam.R, cam.t, scene.depth(name), to_gt, scene)


def test_true_depth_scores_perfect(scene):
    truth = scene.depth(scene.image_names[0])
    m = _figures(scene, truth)
    assert m["accuracy@0.002"] > 0.999 and m["completeness@0.002"] > 0.999
    assert m["background"] == 0.0 and m["kept"] == pytest.approx(np.mean(truth > 0))


def test_depths_two_percent_off_fail_and_sky_depths_are_counted(scene):
    truth = scene.depth(scene.image_names[0])
    assert (truth == 0).any(), "the scene's sky must show in the view"
    m = _figures(scene, truth * 1.02)
    assert m["accuracy@0.002"] < 0.2 and m["completeness@0.002"] < 0.2
    invented = np.where(truth > 0, truth, np.median(truth[truth > 0]))
    m = _figures(scene, invented)
    assert m["background"] == pytest.approx(np.mean(truth == 0))
    assert m["completeness@0.002"] > 0.999 and m["accuracy@0.002"] < 1 - 0.9 * np.mean(truth == 0)


def test_the_model_frame_is_moved_onto_the_truth(scene):
    # a model twice the size, shifted: its cameras and depths in its own frame, and the similarity back
    name = scene.image_names[0]
    cam = scene.cameras()[name]
    to_model = Similarity(2.0, np.eye(3), np.array([1.0, -2.0, 0.5]))
    R, t = to_model.apply_to_pose(cam.R, cam.t)
    m = depth_map_metrics(scene.depth(name) * 2.0, cam.K, R, t, scene.depth(name), to_model.inverse(), scene)
    assert m["accuracy@0.002"] > 0.999 and m["completeness@0.002"] > 0.999


def test_a_distorted_view_is_scored_in_the_depth_maps_undistorted_frame(tmp_path):
    """A depth map is computed in its view's undistorted (pinhole) frame; the truth of a photo taken through
    a lens with distortion is on the photo's own pixels. A perfect undistorted depth map scores perfect."""
    from recon.synth.render import Renderer
    from recon.synth.scene import assemble
    from recon.synth.zoo import render_zoo, zoo_setup

    info = render_zoo("wide_lens", tmp_path / "wide", views=3, width=160, height=120, holdout=0)
    setup = zoo_setup("wide_lens")
    name = info.image_names[0]
    cam = info.cameras()[name]
    assert cam.distorted
    pinhole = dataclasses.replace(cam, radial=(0.0, 0.0))
    depth = Renderer(assemble(setup.parts), setup.background).render(pinhole)[1]
    assert (depth == 0).mean() > 0.05  # sky in view, so the surface's outline counts
    same = Similarity(1.0, np.eye(3), np.zeros(3))
    m = depth_map_metrics(depth, cam.K, cam.R, cam.t, info.depth(name), same, info, truth_camera=cam)
    assert m["accuracy@0.002"] > 0.999 and m["completeness@0.002"] > 0.995 and m["background"] < 0.002
    # read as if the photo had no distortion, the outline is off by pixels
    m = depth_map_metrics(depth, cam.K, cam.R, cam.t, info.depth(name), same, info)
    assert m["background"] > 0.005
