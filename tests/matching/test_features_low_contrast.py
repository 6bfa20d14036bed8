"""A photo of low-contrast texture is extracted again, more sensitively (recon.sparse.features)."""

from __future__ import annotations

import cv2
import numpy as np

from recon.sparse.features import FeaturesConfig, extract_photo, load_features


def texture(path, contrast: float, seed: int = 0):
    """640x480 grey photo: band-passed noise of ``contrast`` grey levels (std) around mid-grey."""
    noise = np.random.default_rng(seed).normal(size=(480, 640)).astype(np.float32)
    band = cv2.GaussianBlur(noise, (0, 0), 1.5) - cv2.GaussianBlur(noise, (0, 0), 4.0)
    img = 128 + band * (contrast / band.std())
    cv2.imwrite(str(path), np.clip(img, 0, 255).astype(np.uint8))
    return path


def features(photo, out, **config):
    dest = out / f"{photo.stem}-{'-'.join(f'{k}{v}' for k, v in config.items()) or 'default'}.npz"
    count = extract_photo((photo, dest, FeaturesConfig(**config).settings(), None))
    keypoints, _ = load_features(dest)
    assert count == len(keypoints)
    return keypoints


def test_a_low_contrast_photo_gets_enough_features(tmp_path):
    photo = texture(tmp_path / "plaster.png", contrast=3.0)
    once = features(photo, tmp_path, min_num_features=0)
    again = features(photo, tmp_path)
    assert len(once) < 100 and len(again) >= FeaturesConfig().min_num_features


def test_a_textured_photo_is_extracted_once(tmp_path):
    photo = texture(tmp_path / "gravel.png", contrast=30.0)
    once = features(photo, tmp_path, min_num_features=0)
    assert len(once) >= FeaturesConfig().min_num_features
    np.testing.assert_array_equal(features(photo, tmp_path), once)
