"""Anti-aliased resize, pyramid and the intrinsics that go with it (acceptance criterion 1)."""

import numpy as np
import pytest

from recon.imaging.intrinsics import Intrinsics
from recon.imaging.resize import RESIZE, ResizeOptions, output_size, pyramid, resize_to

N, SCALE = 512, 0.25
M = int(N * SCALE)
FREQ = np.fft.fftfreq(N)


def _zone_plate() -> np.ndarray:
    """cos(pi r^2 / N): local frequency r / N cycles per pixel, 0 at the centre to 0.5 at r = N/2."""
    y, x = np.mgrid[0:N, 0:N] + 0.5 - N / 2
    r2 = x * x + y * y
    return np.cos(np.pi * r2 / N) * np.clip((N / 2 - np.sqrt(r2)) / 16, 0, 1)


def _split(image: np.ndarray, fmax: float) -> tuple[np.ndarray, np.ndarray]:
    """(content with both |fx|, |fy| < fmax, the rest), as float32 images."""
    spectrum = np.fft.fft2(image)
    low = (np.abs(FREQ)[None, :] < fmax) & (np.abs(FREQ)[:, None] < fmax)
    parts = (np.fft.ifft2(np.where(low, spectrum, 0)), np.fft.ifft2(np.where(low, 0, spectrum)))
    return tuple(np.real(p).astype(np.float32) for p in parts)


def _ideal_downsample(band_limited: np.ndarray) -> np.ndarray:
    """Exact samples of a band-limited image at the output pixel centres: source x = 4j + 1.5."""
    shift = np.exp(2j * np.pi * FREQ * (0.5 / SCALE - 0.5))
    spectrum = np.fft.fftshift(np.fft.fft2(band_limited) * shift[None, :] * shift[:, None])
    c = N // 2
    crop = spectrum[c - M // 2:c + M // 2, c - M // 2:c + M // 2]
    return np.real(np.fft.ifft2(np.fft.ifftshift(crop))) * (M * M) / (N * N)


def _energy(a: np.ndarray) -> float:
    return float(np.sum(a.astype(np.float64) ** 2))


def test_antialiasing_removes_aliasing_energy_10x_better_than_decimation():
    """Energy that content above the new Nyquist frequency (s/2 cycles/px) puts into the output.

    The zone plate is split (FFT) into its part representable on the output grid (|fx|, |fy| < s/2)
    and the rest; an ideal resampler maps the rest to zero, so the energy of resize(rest) is exactly
    the aliasing the resampler lets through (resize is linear on float input). Decimation keeps all
    of it (folded). A passband check makes sure the pre-filter does not simply blur everything away.
    """
    _, high = _split(_zone_plate(), SCALE / 2)
    alias_decimation = _energy(high[1::4, 1::4])
    alias_ours = _energy(resize_to(high, M, M))
    ratio = alias_decimation / alias_ours
    print(f"aliased energy: decimation {alias_decimation:.1f}, ours {alias_ours:.2f}, ratio {ratio:.0f}x")
    assert ratio >= 10.0

    low, _ = _split(_zone_plate(), SCALE / 4)  # well inside the new passband
    ideal, ours = _ideal_downsample(low), resize_to(low, M, M)
    corr = np.corrcoef(ours.ravel(), ideal.ravel())[0, 1]
    gain = np.sqrt(_energy(ours) / _energy(ideal))
    print(f"passband (f < s/4): correlation {corr:.4f}, amplitude gain {gain:.3f}")
    assert corr > 0.98 and gain > 0.75


@pytest.mark.parametrize("shape", [(401, 601), (480, 640)])
def test_intrinsics_scale_with_the_pixel_centre_convention(shape):
    """A blob at a known sub-pixel position lands where the scaled camera projects it (< 0.05 px)."""
    h, w = shape
    cam = Intrinsics.pinhole(700.0, 710.0, 0.52 * w, 0.47 * h, w, h)
    points = np.array([[-0.2, -0.15, 1.0], [0.25, 0.1, 1.0], [0.05, 0.2, 1.0]])
    uv = cam.project(points)
    yy, xx = np.mgrid[0:h, 0:w] + 0.5  # COLMAP pixel centres
    image = np.zeros((h, w), np.float32)
    for u, v in uv:
        image += np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 6.0**2))
    image16 = np.round(image / image.max() * 65535).astype(np.uint16)

    small, small_cam = RESIZE.apply(image16, cam, ResizeOptions(scale=1 / 3))
    assert small.dtype == np.uint16 and small.shape == (round(h / 3), round(w / 3))
    assert (small_cam.width, small_cam.height) == (small.shape[1], small.shape[0])
    sy, sx = np.mgrid[0:small.shape[0], 0:small.shape[1]] + 0.5
    for u, v in small_cam.project(points):
        win = (np.abs(sx - u) < 8) & (np.abs(sy - v) < 8)
        weight = small.astype(np.float64) * win
        cu, cv = (weight * sx).sum() / weight.sum(), (weight * sy).sum() / weight.sum()
        assert abs(cu - u) < 0.05 and abs(cv - v) < 0.05, (cu, u, cv, v)


def test_output_size_rules():
    assert output_size(4000, 3000, ResizeOptions(max_size=2000)) == (2000, 1500)
    assert output_size(1000, 800, ResizeOptions(max_size=2000)) == (1000, 800)
    assert output_size(1000, 800, ResizeOptions(max_size=2000, upscale=True)) == (2000, 1600)
    assert output_size(1001, 801, ResizeOptions(scale=0.5)) == (500, 400)


def test_resize_keeps_dtype_channels_and_mask_alignment():
    rgb = np.random.default_rng(0).integers(0, 256, (100, 150, 3), dtype=np.uint8)
    out, cam = RESIZE.apply(rgb, None, ResizeOptions(max_size=60))
    assert out.shape == (40, 60, 3) and out.dtype == np.uint8 and cam is None
    mask = np.zeros((100, 150), bool)
    mask[:, 75:] = True
    small_mask = RESIZE.apply_mask(mask, None, ResizeOptions(max_size=60))
    assert small_mask.shape == (40, 60) and small_mask.dtype == bool
    assert not small_mask[:, :29].any() and small_mask[:, 31:].all()


def test_pyramid_halves_each_level_and_keeps_mean():
    image = np.full((97, 130, 3), 100, np.uint8)
    image[::2] = 200  # finest possible stripes: must average out, not alias
    levels = pyramid(image, 4)
    assert [lv.shape[:2] for lv in levels] == [(97, 130), (48, 65), (24, 32), (12, 16)]
    for lv in levels[1:]:
        assert np.abs(lv.astype(int)[2:-2, 2:-2] - 150).max() <= 3
