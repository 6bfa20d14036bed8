"""Test helpers: pinhole views 160 x 120 px, centred on the plane z = 0 and looking along +z, and a texture for the planes they see."""

from __future__ import annotations

import numpy as np

from recon.mvs.patchmatch import Camera

W, H, FOCAL = 160, 120, 150.0


def camera(x: float, y: float) -> Camera:
    """The view whose centre is (x, y, 0)."""
    K = np.array([[FOCAL, 0, W / 2], [0, FOCAL, H / 2], [0, 0, 1]])
    return Camera(K, np.eye(3), -np.array([x, y, 0.0]))


def texture(x: np.ndarray, y: np.ndarray, seed: int) -> np.ndarray:
    """A smooth random pattern on a plane, features a few pixels across."""
    rng = np.random.default_rng(seed)
    value = np.zeros_like(x)
    for _ in range(8):
        fx, fy = rng.uniform(-40, 40, 2)
        value += np.sin(fx * x + fy * y + rng.uniform(0, 2 * np.pi))
    return (0.5 + 0.06 * value).astype(np.float32)
