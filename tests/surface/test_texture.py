import importlib
from dataclasses import replace

import numpy as np
import pytest
from surface_scene import with_gains

from recon.eval.texture import masked_psnr, render, seam_jump
from recon.imaging.pixels import sample_bilinear
from recon.surface.options import TextureOptions
from recon.surface.raycast import render_ids, scene_of
from recon.surface.texture import texture_mesh


def _holdout_psnr(scene, textured, vertex_colors=False):
    out = []
    for cam, gt in zip(scene.holdout_cameras, scene.holdout_images, strict=True):
        image, mask = render(textured, cam, gt.shape[1], gt.shape[0], vertex_colors=vertex_colors)
        out.append(masked_psnr(image, gt, mask))
    return float(np.mean(out))


def test_holdout_views_beat_vertex_colours(small_scene, mesh):
    textured = texture_mesh(mesh, small_scene.images, small_scene.cameras)
    psnr = _holdout_psnr(small_scene, textured)
    assert psnr >= 28
    assert psnr >= _holdout_psnr(small_scene, textured, vertex_colors=True) + 2
    seen = textured.face_view >= 0
    assert seen.mean() > 0.9  # the ground's far corners and the objects' bottoms are all that is unseen
    assert textured.uv.min() >= 0 and textured.uv.max() <= 1


def test_levelling_halves_seam_jumps(small_scene, mesh):
    photos = with_gains(small_scene.images)

    def jump(**options) -> float:  # photometric calibration off: levelling alone against the gains
        return seam_jump(texture_mesh(mesh, photos, small_scene.cameras,
                                      TextureOptions(colour_calibration=False, **options)))

    raw = jump(levelling=False, seam_blending=False)
    global_only = jump(levelling=True, seam_blending=False)
    levelled = jump(levelling=True)
    assert global_only < 0.6 * raw
    assert levelled < 0.5 * raw and levelled < global_only


def test_calibration_evens_out_seam_jumps_as_levelling_did(small_scene, mesh):
    photos = with_gains(small_scene.images)
    raw = seam_jump(texture_mesh(mesh, photos, small_scene.cameras,
                                 TextureOptions(colour_calibration=False, seam_blending=False)))
    calibrated = seam_jump(texture_mesh(mesh, photos, small_scene.cameras, TextureOptions(seam_blending=False)))
    assert calibrated < 0.5 * raw


def test_seams_shorter_than_two_texels_are_not_blended(small_scene, mesh):
    # at a tenth of a texel per photo pixel the faces are smaller than the texels: what a seam's two
    # lookups differ by there is no seam point's colour difference (recon.surface.texture.blending)
    photos = with_gains(small_scene.images)
    coarse = TextureOptions(colour_calibration=False, texel_scale=0.1)
    blended = texture_mesh(mesh, photos, small_scene.cameras, coarse)
    plain = texture_mesh(mesh, photos, small_scene.cameras, replace(coarse, seam_blending=False))
    assert np.array_equal(blended.texture, plain.texture)
    fine = TextureOptions(colour_calibration=False)
    assert not np.array_equal(texture_mesh(mesh, photos, small_scene.cameras, fine).texture,
                              texture_mesh(mesh, photos, small_scene.cameras, replace(fine, seam_blending=False)).texture)


@pytest.mark.parametrize(("texel_scale", "mix_ratio", "min_psnr"), [(1.0, 0.0, 38), (1.5, 0.0, 41), (1.5, 0.5, 37.5)])
def test_texture_reproduces_the_photos(small_scene, mesh, texel_scale, mix_ratio, min_psnr):
    """Rendered into one of its own views, the texture gives back that photo where it was used; also where
    the atlas resamples the photos and mixes in others (recon.surface.texture.bake; with bilinear lookups
    37.7 dB at 1.5 texels per pixel, 36.9 mixed)."""
    textured = texture_mesh(mesh, small_scene.images, small_scene.cameras,
                            TextureOptions(levelling=False, seam_blending=False, mix_ratio=mix_ratio,
                                           texel_scale=texel_scale))
    k = 3
    cam, photo = small_scene.cameras[k], small_scene.images[k]
    image, mask = render(textured, cam, photo.shape[1], photo.shape[0])
    ids = render_ids(scene_of(textured.vertices, textured.faces), cam, photo.shape[1], photo.shape[0])
    own = mask & (textured.face_view[np.maximum(ids["face"], 0)] == k)
    assert own.sum() > 1000
    assert masked_psnr(image, photo, own) > min_psnr


def test_small_atlas_limit_scales_charts_down(small_scene, mesh):
    full = texture_mesh(mesh, small_scene.images, small_scene.cameras, TextureOptions(seam_blending=False))
    assert max(full.texture.shape[:2]) > 600
    small = texture_mesh(mesh, small_scene.images, small_scene.cameras,
                         TextureOptions(max_texture_size=512, seam_blending=False))
    assert max(small.texture.shape[:2]) <= 512
    assert _holdout_psnr(small_scene, small) > 26  # about 4 dB below the full-size atlas (33 dB)


def test_unseen_faces_are_filled_from_their_neighbours(small_scene, mesh):
    """Faces no photo sees (the objects' undersides) show the exact linear interpolation of their vertex
    colours."""
    textured = texture_mesh(mesh, small_scene.images[:4], small_scene.cameras[:4])
    unseen = np.flatnonzero(textured.face_view < 0)
    assert len(unseen) > 100
    h, w = textured.texture.shape[:2]
    for bary in ([1 / 3, 1 / 3, 1 / 3], [0.6, 0.3, 0.1], [0.05, 0.05, 0.9]):
        uv = np.einsum("k,nkc->nc", bary, textured.uv[unseen])
        tex = sample_bilinear(textured.texture.astype(np.float32), uv[:, 0] * w, (1 - uv[:, 1]) * h)
        expected = np.einsum("k,nkc->nc", bary, textured.vertex_colors[textured.faces[unseen]].astype(float))
        assert np.abs(tex - expected).mean() < 1.0


def test_mixing_views_averages_out_sensor_noise(small_scene, mesh):
    """Photos with independent sensor noise: each texel averaged over the views that see its face nearly
    as well as the chosen one is less noisy in held-out views than the chosen photo alone."""
    rng = np.random.default_rng(3)
    noisy = [np.clip(im + rng.normal(0, 12, im.shape), 0, 255).astype(np.uint8) for im in small_scene.images]

    def psnr(ratio):
        return _holdout_psnr(small_scene, texture_mesh(mesh, noisy, small_scene.cameras,
                                                       TextureOptions(mix_ratio=ratio)))

    alone, mixed = psnr(0.0), psnr(0.5)
    assert mixed > alone + 1.0


def test_mixing_in_blocks_gives_the_same_atlas(small_scene, mesh, monkeypatch):
    bake = importlib.import_module("recon.surface.texture.bake")  # the package exports the function of that name
    whole = texture_mesh(mesh, small_scene.images, small_scene.cameras, TextureOptions(seam_blending=False))
    monkeypatch.setattr(bake, "_MIX_BLOCK", 997)
    blocks = texture_mesh(mesh, small_scene.images, small_scene.cameras, TextureOptions(seam_blending=False))
    assert np.array_equal(whole.texture, blocks.texture)
