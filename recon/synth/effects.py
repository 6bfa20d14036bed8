"""What a real camera does to a photo, applied to rendered views: motion blur, exposure and white
balance that change from view to view (as phones' auto-exposure does), vignetting, sensor noise.

Applied in linear light (the rendered values are taken as sRGB-like, gamma 2.2), in the order light
meets them: blur while the shutter is open, gains, lens fall-off, then noise on the sensor reading.
JPEG compression is set by the writer (``Capture.jpeg_quality``). Each view's draws come from
(seed, view index), so a view looks the same whatever else is rendered.
"""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

GAMMA = 2.2


@dataclasses.dataclass(frozen=True)
class Effects:
    exposure_stops: float = 0.0  # per-view exposure offset drawn from U(-s, s) stops
    white_balance: float = 0.0  # per-view red and blue gains drawn from U(1 - w, 1 + w)
    vignetting: float = 0.0  # share of light lost in the image corners (quadratic fall-off from the centre)
    noise: float = 0.0  # sensor noise std in grey levels at mid-grey (signal-dependent: shot noise + read noise)
    blur_every: int = 0  # every n-th view (1st, n+1-th, ...) is motion blurred; 0: none
    blur_px: float = 0.0  # length of the blur streak in pixels (centred: the pose is mid-exposure)

    def apply(self, rgb: np.ndarray, index: int, seed: int) -> np.ndarray:
        """The photo (uint8 HxWx3) of rendered view ``index`` (uint8 HxWx3)."""
        rng = np.random.default_rng([seed, 7, index])
        stops, red, blue, angle = (rng.uniform(-1, 1) for _ in range(4))
        lin = (rgb.astype(np.float32) / 255.0) ** GAMMA
        if self.blur_every and self.blur_px > 0 and index % self.blur_every == 0:
            lin = cv2.filter2D(lin, -1, streak(self.blur_px, np.pi * angle), borderType=cv2.BORDER_REFLECT)
        gain = 2.0 ** (self.exposure_stops * stops) * np.array(
            [1.0 + self.white_balance * red, 1.0, 1.0 + self.white_balance * blue], np.float32)
        lin = lin * gain
        if self.vignetting:
            h, w = lin.shape[:2]
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
            r2 = ((xx + 0.5 - w / 2) ** 2 + (yy + 0.5 - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
            lin = lin * (1.0 - self.vignetting * r2)[..., None]
        out = np.clip(lin, 0.0, 1.0) ** (1.0 / GAMMA) * 255.0
        if self.noise:
            sigma = self.noise * np.sqrt(0.25 + 0.75 * out / 128.0)
            out = out + sigma * rng.standard_normal(out.shape).astype(np.float32)
        return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def streak(length: float, angle: float) -> np.ndarray:
    """A normalised line kernel ``length`` pixels long at ``angle`` (radians), centred on its middle
    pixel, drawn with sub-pixel weights."""
    size = 2 * int(np.ceil(length / 2)) + 1
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    for s in np.linspace(-length / 2, length / 2, 8 * size):
        x, y = c + s * np.cos(angle), c + s * np.sin(angle)
        x0, y0 = int(np.floor(x)), int(np.floor(y))
        fx, fy = x - x0, y - y0
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            if 0 <= x0 + dx < size and 0 <= y0 + dy < size:
                kernel[y0 + dy, x0 + dx] += wgt
    return kernel / kernel.sum()
