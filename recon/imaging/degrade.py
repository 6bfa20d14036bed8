"""Synthetic degradations of photos, to test and benchmark what the operations undo."""

from __future__ import annotations

import numpy as np


def low_light(image: np.ndarray, gain: float = 2.0**-2.5, gamma: float = 1.5, noise: float = 1.5,
              seed: int = 0) -> np.ndarray:
    """A dark, low-contrast, noisy copy of a uint8 photo: ``255 gain (x/255)^gamma`` plus Gaussian noise.

    ``noise`` is the standard deviation in 8-bit levels; the result is rounded and clipped to uint8
    (the quantisation of a dark 8-bit photo is part of what makes it hard). The defaults compress
    the photo's range about 6x (2.5 stops) and darken mid-tones further.
    """
    x = image.astype(np.float32) / 255.0
    y = 255.0 * gain * x**gamma + np.random.default_rng(seed).normal(0.0, noise, image.shape)
    return np.clip(np.rint(y), 0, 255).astype(np.uint8)
