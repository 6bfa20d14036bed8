"""Photographic textures for the synthetic scene, and trilinear (mip-mapped) texture lookup.

All textures are real photographs shipped inside scikit-image (``skimage.data`` items that load
offline): gravel and grass for the ground, and colour photos with dense detail (cells, a cluttered
garage, a cat, an espresso on wood, coins) for the objects. Their flat-area share was measured:
under 20 % of 16x16 patches have a standard deviation below 4 grey levels.

Lookups are trilinear: the mip level follows the footprint of a sample on the surface, so distant
and oblique surfaces are area-filtered instead of aliasing, which keeps the images photo-consistent
between views (the property dense stereo and texturing rely on).
"""

from __future__ import annotations

import dataclasses
import functools

import cv2
import numpy as np

MIP_LEVELS = 6
_ALIGN = 2 ** (MIP_LEVELS - 1)


@dataclasses.dataclass(frozen=True, eq=False)
class Texture:
    """An RGB texture with its mip pyramid (uint8, level 0 first) and how lookups treat its borders."""

    levels: tuple[np.ndarray, ...]
    wrap: bool

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of level 0 in texels."""
        h, w = self.levels[0].shape[:2]
        return w, h


def make_texture(image: np.ndarray, wrap: bool = False) -> Texture:
    """Build the pyramid of an RGB uint8 image whose sides are multiples of 2**(MIP_LEVELS-1)."""
    h, w = image.shape[:2]
    if h % _ALIGN or w % _ALIGN:
        raise ValueError(f"texture sides must be multiples of {_ALIGN}, got {w}x{h}")
    levels = [np.ascontiguousarray(image)]
    for _ in range(MIP_LEVELS - 1):
        # 2x2 box averages: texel j of a level covers texels 2j and 2j+1 of the one below, so all
        # levels stay aligned (a Gaussian pyrDown would shift each level by half a texel).
        prev = levels[-1]
        levels.append(cv2.resize(prev, (prev.shape[1] // 2, prev.shape[0] // 2), interpolation=cv2.INTER_AREA))
    return Texture(tuple(levels), wrap)


def sample(tex: Texture, uv: np.ndarray, level: np.ndarray) -> np.ndarray:
    """Trilinear lookup: RGB float32 in [0, 1] (N, 3) at texel coordinates ``uv`` (N, 2) of level 0
    (texel i spans [i, i+1)), blending the two mip levels around the fractional ``level`` (N,)."""
    n = len(uv)
    out = np.empty((n, 3), np.float32)
    if n == 0:
        return out
    level = np.clip(level, 0.0, MIP_LEVELS - 1.0)
    base = np.minimum(level.astype(np.int32), MIP_LEVELS - 2)
    frac = (level - base).astype(np.float32)[:, None]
    for lv in np.unique(base):
        sel = np.flatnonzero(base == lv)
        lo = _bilinear(tex, lv, uv[sel])
        hi = _bilinear(tex, lv + 1, uv[sel])
        out[sel] = lo + (hi - lo) * frac[sel]
    return out * np.float32(1.0 / 255.0)


_ROW = 4096  # cv2.remap maps must stay below 32767 columns: lay samples out in rows


def _bilinear(tex: Texture, level: int, uv: np.ndarray) -> np.ndarray:
    n = len(uv)
    rows = -(-n // _ROW)
    coords = np.zeros((rows * _ROW, 2), np.float32)
    coords[:n] = uv * (0.5**level) - 0.5  # texel centres sit at integer remap coordinates
    maps = coords.reshape(rows, _ROW, 2)
    border = cv2.BORDER_WRAP if tex.wrap else cv2.BORDER_REFLECT_101
    img = tex.levels[level]
    res = cv2.remap(img, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=border)
    return res.reshape(-1, 3)[:n].astype(np.float32)


@functools.cache
def photo(name: str) -> np.ndarray:
    """An RGB uint8 photograph from ``skimage.data`` (grey ones are returned as three equal channels)."""
    import skimage.data

    img = skimage.data.stereo_motorcycle()[0] if name == "motorcycle" else getattr(skimage.data, name)()
    img = np.asarray(img)
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return np.ascontiguousarray(img[:, :, :3].astype(np.uint8))


def fit(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """Centre-crop ``image`` to the aspect of width:height, then resize to exactly that size."""
    h, w = image.shape[:2]
    aspect = width / height
    if w / h > aspect:
        cw, ch = round(h * aspect), h
    else:
        cw, ch = w, round(w / aspect)
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    crop = image[y0 : y0 + ch, x0 : x0 + cw]
    interp = cv2.INTER_AREA if cw > width else cv2.INTER_CUBIC
    return cv2.resize(crop, (width, height), interpolation=interp)


def grid_cells(image: np.ndarray, cols: int, rows: int, cell: tuple[int, int]) -> list[np.ndarray]:
    """Split ``image`` into cols x rows disjoint cells, each resized to ``cell`` (width, height)."""
    h, w = image.shape[:2]
    out = []
    for r in range(rows):
        for c in range(cols):
            part = image[r * h // rows : (r + 1) * h // rows, c * w // cols : (c + 1) * w // cols]
            out.append(fit(part, *cell))
    return out


def ground_texture(size: int) -> np.ndarray:
    """A non-repeating ground texture of size x size texels: tinted gravel and grass photos, mirror-tiled
    at different scales and angles, blended by a smooth mask made from a third photo."""
    def layer(img, scale, angle, tint):
        g = img[:, :, 0].astype(np.float32)
        M = cv2.getRotationMatrix2D((0.0, 0.0), angle, scale)
        M[:, 2] = [37.0, 91.0]
        warped = cv2.warpAffine(g, M, (size, size), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                borderMode=cv2.BORDER_REFLECT_101)
        return warped[:, :, None] * np.asarray(tint, np.float32)

    gravel = layer(photo("gravel"), 1.0, 0.0, (1.0, 0.86, 0.68))
    grass = layer(photo("grass"), 0.8, 33.0, (0.62, 0.86, 0.46))
    small = cv2.resize(photo("camera")[:, :, 0], (64, 64), interpolation=cv2.INTER_AREA).astype(np.float32)
    mask = cv2.resize(cv2.GaussianBlur(small, (0, 0), 1.6), (size, size), interpolation=cv2.INTER_CUBIC) / 255.0
    mask = np.clip((mask - mask.mean()) * 3.0 + 0.5, 0.15, 0.85)[:, :, None]
    return np.clip(gravel * mask + grass * (1.0 - mask), 0, 255).astype(np.uint8)
