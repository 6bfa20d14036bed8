"""The operation registry, chains, masks, and the photometric operations' contracts."""

import dataclasses

import cv2
import numpy as np
import pytest
import skimage.data

from recon.imaging.contrast import CLAHE, EQUALIZE, ClaheOptions, EqualizeOptions
from recon.imaging.denoise import BILATERAL, NL_MEANS, BilateralOptions, NLMeansOptions, noise_sigma
from recon.imaging.intrinsics import Intrinsics
from recon.imaging.masks import load_mask, mask_path, save_mask
from recon.imaging.ops import OPS, apply_chain
from recon.imaging.resize import ResizeOptions
from recon.imaging.undistort import UndistortOptions

CAMERA = Intrinsics("OPENCV", 512, 512, (450.0, 450.0, 256.0, 256.0, -0.1, 0.01, 0.0, 0.0))


def _psnr(a, b):
    return 10 * np.log10(1 / np.mean(((a.astype(float) - b.astype(float)) / 255.0) ** 2))


def test_registry_entries_are_typed_and_documented():
    assert set(OPS) == {"resize", "undistort", "bilateral", "nl_means", "clahe", "equalize", "wiener",
                        "richardson_lucy"}
    for name, op in OPS.items():
        assert op.name == name and op.doc
        assert dataclasses.is_dataclass(op.Options) and op.Options.__dataclass_params__.frozen
        for field in dataclasses.fields(op.Options):
            assert field.metadata.get("doc"), f"{name}.{field.name} has no doc"
        assert op.geometric == (name in ("resize", "undistort"))


@pytest.mark.parametrize("name", ["bilateral", "nl_means", "clahe", "equalize", "wiener", "richardson_lucy"])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("color", [True, False])
def test_photometric_ops_keep_dtype_shape_and_camera(name, dtype, color):
    image = skimage.data.astronaut()[100:164, 100:164]
    if not color:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    image = image.astype(dtype) * (257 if dtype == np.uint16 else 1)
    op = OPS[name]
    options = op.Options(sigma=1.0) if name in ("wiener", "richardson_lucy") else op.Options()
    out, camera = op.apply(image, CAMERA, options)
    assert out.dtype == dtype and out.shape == image.shape and camera is CAMERA


def test_chain_updates_camera_and_mask():
    image = skimage.data.astronaut()
    mask = np.zeros((512, 512), bool)
    mask[:, :256] = True
    steps = [("undistort", UndistortOptions(alpha=0.0)), ("resize", ResizeOptions(max_size=256)),
             ("clahe", ClaheOptions())]
    out, camera, out_mask = apply_chain(image, CAMERA, steps, mask=mask)
    assert out.shape == (256, 256, 3) and out_mask.shape == (256, 256)
    assert camera.model == "PINHOLE" and (camera.width, camera.height) == (256, 256)
    # The mask's edge stays on the principal point's column through both warps.
    column = out_mask.mean(axis=0)
    edge = int(np.argmax(column < 0.5))
    assert abs(edge - camera.cx) <= 1.0
    with pytest.raises(ValueError):
        apply_chain(image, CAMERA, [("sharpen", ResizeOptions())])
    with pytest.raises(TypeError):
        apply_chain(image, CAMERA, [("resize", ClaheOptions())])


def test_contrast_changes_lightness_only():
    """CLAHE and equalisation lift a dull image's contrast and keep each pixel's hue."""
    image = skimage.data.coffee()
    dull = (64 + image.astype(np.float32) * 0.35).astype(np.uint8)
    hue_before = cv2.cvtColor(dull, cv2.COLOR_RGB2HSV_FULL)[..., 0].astype(int)
    for op, options in ((CLAHE, ClaheOptions()), (EQUALIZE, EqualizeOptions())):
        out, _ = op.apply(dull, None, options)
        lightness = cv2.cvtColor(out, cv2.COLOR_RGB2LAB)[..., 0]
        assert lightness.std() > 1.5 * cv2.cvtColor(dull, cv2.COLOR_RGB2LAB)[..., 0].std()
        hsv = cv2.cvtColor(out, cv2.COLOR_RGB2HSV_FULL)
        saturated = (hsv[..., 1] > 60) & (hsv[..., 2] > 40) & (hsv[..., 2] < 250)
        diff = np.abs(hsv[..., 0].astype(int) - hue_before)
        diff = np.minimum(diff, 256 - diff)[saturated]
        assert np.median(diff) <= 3, op.name


def test_equalize_flattens_the_lightness_histogram():
    gray = np.clip(np.random.default_rng(0).normal(100, 10, (200, 200)), 0, 255).astype(np.uint8)
    out, _ = EQUALIZE.apply(gray, None, EqualizeOptions())
    counts = np.histogram(out, bins=8, range=(0, 256))[0]
    assert counts.min() > 0.5 * counts.mean()


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_denoisers_raise_psnr(dtype):
    clean = skimage.data.astronaut()[:256, :256]
    noisy = np.clip(clean / 255.0 + np.random.default_rng(0).normal(0, 0.04, clean.shape), 0, 1)
    top = 255 if dtype == np.uint8 else 65535
    noisy = np.rint(noisy * top).astype(dtype)
    assert abs(noise_sigma(noisy) - 0.04) < 0.005
    before = _psnr(noisy / (top / 255), clean)
    for op, options in ((BILATERAL, BilateralOptions()), (NL_MEANS, NLMeansOptions())):
        out, _ = op.apply(noisy, None, options)
        gain = _psnr(out / (top / 255), clean) - before
        assert gain > 3.0, (op.name, gain)


def test_masks_follow_colmap_naming(tmp_path):
    mask = np.zeros((6, 8), bool)
    mask[2:, 3:] = True
    path = save_mask(tmp_path, "sub/IMG_1.jpg", mask)
    assert path == mask_path(tmp_path, "sub/IMG_1.jpg") == tmp_path / "sub" / "IMG_1.jpg.png"
    assert np.array_equal(load_mask(tmp_path, "sub/IMG_1.jpg", shape=(6, 8)), mask)
    assert load_mask(tmp_path, "other.jpg") is None
    with pytest.raises(ValueError):
        load_mask(tmp_path, "sub/IMG_1.jpg", shape=(8, 6))
