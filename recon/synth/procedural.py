"""Procedural textures for the zoo's scenes: seamless (periodic) RGB uint8 images, sides multiples of 32.

Everything starts from :func:`noise`, white noise shaped by a 1/f^beta spectrum in the Fourier
domain: periodic by construction, so tiled textures show no seams. ``plaster`` with a small
amplitude is the weak-texture case (a painted wall: a standard deviation of a grey level or two).
"""

from __future__ import annotations

import cv2
import numpy as np


def noise(width: int, height: int, rng: np.random.Generator, beta: float = 1.8, cutoff: float = 1.0) -> np.ndarray:
    """Periodic fractal noise (height, width) float32 with zero mean and unit standard deviation:
    amplitude spectrum 1/f^beta (1 is like natural images, larger is smoother); wavelengths below
    ``cutoff`` texels are removed."""
    fy = np.fft.fftfreq(height)[:, None]
    fx = np.fft.rfftfreq(width)[None, :]
    f = np.sqrt(fx**2 + fy**2)
    amp = np.where(f > 0, np.maximum(f, 1e-9) ** -beta, 0.0) * (f <= 1.0 / max(cutoff, 1.0))
    spectrum = (rng.standard_normal(f.shape) + 1j * rng.standard_normal(f.shape)) * amp
    field = np.fft.irfft2(spectrum, s=(height, width))
    return ((field - field.mean()) / (field.std() + 1e-12)).astype(np.float32)


def to_rgb(values: np.ndarray) -> np.ndarray:
    """float RGB in grey levels (H, W, 3) to uint8."""
    return np.clip(values + 0.5, 0, 255).astype(np.uint8)


def plaster(width: int, height: int, colour, amplitude: float, rng: np.random.Generator,
            beta: float = 1.2) -> np.ndarray:
    """A painted surface: ``colour`` (RGB 0-255) with noise of ``amplitude`` grey levels (std)."""
    n = noise(width, height, rng, beta)[..., None]
    return to_rgb(np.asarray(colour, np.float32) * (1.0 + amplitude * n / max(np.mean(colour), 1.0)))


def mottled(width: int, height: int, colours, rng: np.random.Generator, contrast: float = 0.25,
            beta: float = 1.0) -> np.ndarray:
    """Ground, rock, rust: a blend of two colours by one smooth noise, with detail from a second."""
    a, b = (np.asarray(c, np.float32) for c in colours)
    mix = (np.clip(noise(width, height, rng, 2.6) * 0.5 + 0.5, 0, 1))[..., None]
    detail = noise(width, height, rng, beta)[..., None]
    return to_rgb((a * mix + b * (1 - mix)) * (1.0 + contrast * detail))


def bricks(width: int, height: int, rng: np.random.Generator, size=(64, 32), mortar: int = 4,
           colour=(150, 72, 52), spread: float = 0.18) -> np.ndarray:
    """Running-bond bricks of ``size`` texels with per-brick colour variation, grainy faces, light mortar.
    ``width`` and ``height`` must be multiples of the brick size (so the pattern tiles)."""
    bw, bh = size
    rows, cols = height // bh, width // bw
    tone = 1.0 + spread * rng.standard_normal((rows, cols + 1, 3)).astype(np.float32) * [1.0, 0.8, 0.8]
    yy, xx = np.mgrid[0:height, 0:width]
    row = yy // bh
    shifted = (xx + (row % 2) * (bw // 2)) % width
    col = shifted // bw
    img = np.asarray(colour, np.float32) * tone[row, col]
    grain = noise(width, height, rng, 1.0)[..., None]
    img = img * (1.0 + 0.12 * grain)
    joint = ((yy % bh) < mortar) | ((shifted % bw) < mortar)
    img[joint] = np.array([190, 185, 175], np.float32) * (1.0 + 0.08 * grain[joint])
    return to_rgb(img)


def planks(width: int, height: int, rng: np.random.Generator, colour=(150, 105, 65), plank: int = 64) -> np.ndarray:
    """Wooden boards along x, ``plank`` texels wide, with grain streaks and dark gaps."""
    streak = noise(width, height, rng, 1.4)
    streak = cv2.blur(np.tile(streak, (1, 3)), (61, 1))[:, width : 2 * width]  # stretched along the boards
    tone = 1.0 + 0.12 * rng.standard_normal(height // plank + 1)
    yy = np.arange(height)[:, None]
    img = np.asarray(colour, np.float32) * (tone[yy // plank] * (1.0 + 0.5 * streak))[..., None]
    img[(yy % plank < 3).repeat(width, 1)] *= 0.45
    return to_rgb(img)


def tiles(width: int, height: int, rng: np.random.Generator, tile: int = 64, palette=None, grout: int = 3,
          spread: float = 0.1) -> np.ndarray:
    """Square tiles (paving, floor): each tile a colour from ``palette`` (or one colour varied), grainy,
    with dark grout lines."""
    palette = np.asarray(palette if palette is not None else [(128, 124, 118)], np.float32)
    rows, cols = height // tile, width // tile
    pick = palette[rng.integers(0, len(palette), (rows, cols))]
    pick = pick * (1.0 + spread * rng.standard_normal((rows, cols, 1)))
    yy, xx = np.mgrid[0:height, 0:width]
    img = pick[yy // tile, xx // tile] * (1.0 + 0.15 * noise(width, height, rng, 1.0)[..., None])
    img[((yy % tile) < grout) | ((xx % tile) < grout)] *= 0.5
    return to_rgb(img)


def patchwork(width: int, height: int, rng: np.random.Generator, fields: int = 14) -> np.ndarray:
    """Fields seen from the air: periodic Voronoi cells, each a crop colour with furrows in its own
    direction, and earth tracks on the borders."""
    palette = np.array([(92, 128, 58), (150, 150, 74), (118, 96, 62), (70, 104, 52), (176, 160, 104),
                        (104, 120, 80)], np.float32)
    seeds = rng.uniform(0, 1, (fields, 2)) * [width, height]
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    best = np.full((height, width), np.inf, np.float32)
    second = best.copy()
    label = np.zeros((height, width), np.int32)
    for i, (sx, sy) in enumerate(seeds):
        for ox in (-width, 0, width):
            for oy in (-height, 0, height):
                d = np.hypot(xx - sx - ox, yy - sy - oy)
                closer = d < best
                second = np.where(closer, best, np.minimum(second, d))
                label = np.where(closer, i, label)
                best = np.minimum(best, d)
    colour = palette[rng.integers(0, len(palette), fields)][label]
    angle = rng.uniform(0, np.pi, fields)[label]
    furrow = np.sin((xx * np.cos(angle) + yy * np.sin(angle)) * (2 * np.pi / 7.0))
    img = colour * (1.0 + 0.08 * furrow[..., None] + 0.1 * noise(width, height, rng, 1.3)[..., None])
    border = (second - best) < 3.0
    img[border] = np.array([140, 120, 96], np.float32)
    return to_rgb(img)


def windows(width: int, height: int, rng: np.random.Generator, wall, cell=(128, 160), pane=(64, 96)) -> np.ndarray:
    """A facade: a wall texture (H, W, 3 uint8) with a grid of windows (dark sky-reflecting glass in a
    light frame with a sill) in cells of ``cell`` texels."""
    img = np.asarray(wall, np.float32).copy()
    cw, ch = cell
    pw, ph = pane
    for y0 in range(0, height - ch + 1, ch):
        for x0 in range(0, width - cw + 1, cw):
            x1, y1 = x0 + (cw - pw) // 2, y0 + (ch - ph) // 2
            img[y1 - 6 : y1 + ph + 6, x1 - 6 : x1 + pw + 6] = (214, 210, 200)
            grad = np.linspace(0.9, 0.5, ph)[:, None, None] * np.array([70, 92, 118], np.float32)
            glass = grad * (1.0 + 0.25 * noise(pw, ph, rng, 2.2)[..., None])
            img[y1 : y1 + ph, x1 : x1 + pw] = glass
            img[y1 : y1 + ph, x1 + pw // 2 - 2 : x1 + pw // 2 + 2] = (200, 196, 186)
            img[y1 + ph + 6 : y1 + ph + 12, x1 - 10 : x1 + pw + 10] = (150, 146, 140)
    return to_rgb(img)
