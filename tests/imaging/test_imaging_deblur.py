"""Deblurring (criterion 3): PSNR gains on a blurred, noisy photo, with given and estimated kernels."""

import cv2
import numpy as np
import pytest
import skimage.data
from scipy.ndimage import gaussian_filter

from recon.imaging.deblur import (
    RICHARDSON_LUCY,
    WIENER,
    RichardsonLucyOptions,
    WienerOptions,
    estimate_gaussian_sigma,
    motion_kernel,
)

SIGMA, NOISE = 2.0, 0.005  # blur in pixels; noise std as a fraction of the range (~1.3 levels of 255)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    err = (a.astype(np.float64) - b.astype(np.float64)) / 255.0
    return float(10 * np.log10(1.0 / np.mean(err**2)))


@pytest.fixture(scope="module")
def sharp() -> np.ndarray:
    return skimage.data.astronaut()[30:286, 150:406]  # 256x256 RGB crop: face, suit, flag


def _degrade(sharp: np.ndarray, blurred: np.ndarray, seed: int = 0) -> np.ndarray:
    noisy = blurred + np.random.default_rng(seed).normal(0, NOISE, blurred.shape)
    return np.clip(np.rint(noisy * 255), 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def gaussian_blurred(sharp) -> np.ndarray:
    return _degrade(sharp, gaussian_filter(sharp / 255.0, (SIGMA, SIGMA, 0), mode="reflect"))


def test_wiener_and_richardson_lucy_gain_3db_with_the_kernel_given(sharp, gaussian_blurred):
    before = _psnr(gaussian_blurred, sharp)
    wiener, _ = WIENER.apply(gaussian_blurred, None, WienerOptions(kernel="gaussian", sigma=SIGMA))
    rl, _ = RICHARDSON_LUCY.apply(gaussian_blurred, None, RichardsonLucyOptions(sigma=SIGMA, iterations=100))
    gain_w, gain_rl = _psnr(wiener, sharp) - before, _psnr(rl, sharp) - before
    print(f"blurred {before:.2f} dB; Wiener +{gain_w:.2f} dB; Richardson-Lucy +{gain_rl:.2f} dB")
    assert wiener.dtype == rl.dtype == np.uint8 and wiener.shape == sharp.shape
    assert gain_w >= 3.0 and gain_rl >= 3.0


def test_estimated_gaussian_kernel(sharp, gaussian_blurred):
    sigma = estimate_gaussian_sigma(gaussian_blurred)
    sharp_reading = estimate_gaussian_sigma(sharp)
    before = _psnr(gaussian_blurred, sharp)
    wiener, _ = WIENER.apply(gaussian_blurred, None, WienerOptions(sigma=0.0))
    gain = _psnr(wiener, sharp) - before
    print(f"estimated sigma {sigma:.2f} (true {SIGMA}; the sharp photo reads {sharp_reading:.2f}); "
          f"Wiener with it +{gain:.2f} dB")
    assert abs(sigma - SIGMA) < 0.3 and sharp_reading < 1.0
    assert gain > 2.0


def test_motion_kernel_deblurring(sharp):
    psf = motion_kernel(9.0, 30.0)
    assert abs(psf.sum() - 1) < 1e-12 and psf.shape[0] % 2 == 1
    blurred = _degrade(sharp, cv2.filter2D(sharp / 255.0, -1, psf, borderType=cv2.BORDER_REFLECT), seed=1)
    before = _psnr(blurred, sharp)
    options = dict(kernel="motion", length=9.0, angle=30.0)
    wiener, _ = WIENER.apply(blurred, None, WienerOptions(**options, balance=0.03))
    rl, _ = RICHARDSON_LUCY.apply(blurred, None, RichardsonLucyOptions(**options, iterations=50))
    gain_w, gain_rl = _psnr(wiener, sharp) - before, _psnr(rl, sharp) - before
    print(f"motion blur: blurred {before:.2f} dB; Wiener +{gain_w:.2f}; Richardson-Lucy +{gain_rl:.2f}")
    assert gain_w > 2.3 and gain_rl > 3.0  # a streak's spectral zeros cap the linear filter


def test_borders_do_not_ring(sharp, gaussian_blurred):
    """The 12-px frame gains like the whole image: padding keeps wrap-around and zero borders out."""
    wiener, _ = WIENER.apply(gaussian_blurred, None, WienerOptions(sigma=SIGMA))
    rl, _ = RICHARDSON_LUCY.apply(gaussian_blurred, None, RichardsonLucyOptions(sigma=SIGMA, iterations=30))
    frame = np.ones(sharp.shape[:2], bool)
    frame[12:-12, 12:-12] = False
    for out in (wiener, rl):
        gain = _psnr(out[frame], sharp[frame]) - _psnr(gaussian_blurred[frame], sharp[frame])
        assert gain > 1.5, gain


def test_uint16_gray_is_supported(sharp):
    gray16 = (skimage.color.rgb2gray(sharp) * 65535).astype(np.uint16)
    blurred = (gaussian_filter(gray16 / 65535.0, SIGMA) * 65535).astype(np.uint16)
    out, _ = WIENER.apply(blurred, None, WienerOptions(sigma=SIGMA))
    assert out.dtype == np.uint16 and out.shape == gray16.shape
    err_before = np.abs(blurred.astype(float) - gray16).mean()
    assert np.abs(out.astype(float) - gray16).mean() < 0.7 * err_before
