"""The issue's acceptance figures on the demo-sized synthetic scene (24 views of 640 x 480, 4 hold-out
views), with points and depth maps from the ground truth."""

import numpy as np
import pytest
from surface_scene import load_arrays, with_gains

from recon.eval.surface import surface_metrics
from recon.eval.texture import masked_psnr, render, seam_jump
from recon.surface.cleanup import clean_mesh
from recon.surface.options import MeshOptions, TextureOptions
from recon.surface.poisson import poisson_mesh
from recon.surface.texture import texture_mesh
from recon.surface.tsdf import tsdf_mesh
from recon.synth import render_scene

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo_scene(tmp_path_factory):
    return load_arrays(render_scene(tmp_path_factory.mktemp("demo"), views=24, width=640, height=480, holdout=4))


def _psnr(scene, textured, vertex_colors=False):
    return float(np.mean([masked_psnr(*_render(textured, cam, gt, vertex_colors))
                          for cam, gt in zip(scene.holdout_cameras, scene.holdout_images, strict=True)]))


def _render(textured, cam, gt, vertex_colors):
    image, mask = render(textured, cam, gt.shape[1], gt.shape[0], vertex_colors=vertex_colors)
    return image, gt, mask


@pytest.fixture(scope="module")
def poisson_result(demo_scene):
    pts, nrm, col = demo_scene.points(step=2)
    mesh = clean_mesh(poisson_mesh(pts, nrm, col))
    return mesh, texture_mesh(mesh, demo_scene.images, demo_scene.cameras)


def test_poisson_mesh_accuracy(demo_scene, poisson_result):
    m = surface_metrics(poisson_result[0], demo_scene.info)
    assert m["fscore@0.002"] >= 93 and m["fscore@0.005"] >= 95


def test_tsdf_mesh_accuracy(demo_scene):
    mesh = clean_mesh(tsdf_mesh(demo_scene.depths, demo_scene.images, demo_scene.cameras, MeshOptions(method="tsdf")))
    m = surface_metrics(mesh, demo_scene.info)
    assert m["fscore@0.002"] >= 90 and m["fscore@0.005"] >= 95


def test_holdout_psnr(demo_scene, poisson_result):
    textured = poisson_result[1]
    psnr = _psnr(demo_scene, textured)
    assert psnr >= 28
    assert psnr >= _psnr(demo_scene, textured, vertex_colors=True) + 2


def test_seam_levelling(demo_scene, poisson_result):
    photos = with_gains(demo_scene.images)
    mesh = poisson_result[0]
    uncalibrated = TextureOptions(colour_calibration=False, seam_blending=False)
    raw = seam_jump(texture_mesh(mesh, photos, demo_scene.cameras, uncalibrated))
    assert seam_jump(texture_mesh(mesh, photos, demo_scene.cameras, TextureOptions(colour_calibration=False,
                                                                                    levelling=True))) < 0.5 * raw
    assert seam_jump(texture_mesh(mesh, photos, demo_scene.cameras)) < 0.5 * raw  # the default: calibrated

