"""Synthetic panorama sets: pinhole views from a camera at the origin turning through 360 degrees.

The environment is a function of direction only (there is no parallax, as for a camera rotating
about its centre): an equirectangular texture made of real photographs (``skimage.data``) around
the horizon, with ground and sky beyond the visible band, and magenta markers at known azimuths on
the horizon. Its every direction is known exactly, so a panorama can be checked against it.

World frame: x right, y down, z forward (camera 0 without jitter looks along +z). A direction's
azimuth is ``atan2(x, z)`` (growing to the right), its elevation ``asin(-y)`` (up is positive).
Texel (u, v) of the equirectangular texture spans azimuth ``2 pi (u / W - 1/2)`` and elevation
``pi (1/2 - v / H)``. Views follow COLMAP: ``x_cam = R @ X`` (t = 0), pixel = ``K @ x_cam / z`` with
the top-left pixel's centre at (0.5, 0.5). Each view is multiplied by its own exposure gain.
"""

from __future__ import annotations

import dataclasses
import functools
import json
from pathlib import Path

import numpy as np
from PIL import Image

from recon.geometry.transforms import apply_matrix
from recon.synth.textures import Texture, fit, grid_cells, ground_texture, make_texture, photo, sample

TEX_WIDTH = 4608  # 733 texels per radian: a little more than the views' ~690 pixels per radian
TEX_HEIGHT = TEX_WIDTH // 2
BAND_DEG = 24.0  # photos cover elevations in [-BAND_DEG, BAND_DEG]; the views see less than +-23 deg
COLUMNS = 12  # photo cells around the horizon, two rows (above and below it)
MARKERS = 20
MARKER_OFFSET_DEG = 7.0  # marker k sits at azimuth MARKER_OFFSET_DEG + 360 k / MARKERS
MARKER_RADIUS = 5.0  # texels: a magenta disc ...
MARKER_RING = 2.0  # ... inside a black ring
MAGENTA = np.array([255, 0, 255], np.float32)
#: the photos around the horizon (those with the fewest flat areas), grey ones with a tint
_PHOTOS = (("immunohistochemistry", None), ("gravel", (1.0, 0.85, 0.7)), ("chelsea", None), ("coffee", None),
           ("coins", (0.8, 0.9, 1.0)), ("motorcycle", None), ("grass", (0.7, 0.95, 0.6)), ("astronaut", None),
           ("camera", (1.0, 0.95, 0.8)), ("hubble_deep_field", None), ("brick", (1.0, 0.8, 0.75)),
           ("page", (0.85, 0.85, 1.0)))


@dataclasses.dataclass(frozen=True)
class PanoramaViews:
    """Rendered views and their ground truth."""

    images: list[np.ndarray]  # RGB uint8, HxWx3
    K: np.ndarray  # 3x3 intrinsics, COLMAP pixel convention, the same for every view
    rotations: list[np.ndarray]  # world-to-camera 3x3 rotations
    gains: np.ndarray  # the exposure gain each view was multiplied by

    @property
    def names(self) -> list[str]:
        return [f"view_{i:02d}.png" for i in range(len(self.images))]


def direction(azimuth_deg, elevation_deg=0.0) -> np.ndarray:
    """Unit world directions (..., 3) of azimuths / elevations in degrees."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    az, el = np.broadcast_arrays(az, el)
    return np.stack([np.sin(az) * np.cos(el), -np.sin(el), np.cos(az) * np.cos(el)], axis=-1)


def azimuth_deg(dirs: np.ndarray) -> np.ndarray:
    """Azimuths in degrees, in [0, 360), of directions (..., 3)."""
    return np.degrees(np.arctan2(dirs[..., 0], dirs[..., 2])) % 360.0


def marker_azimuths() -> np.ndarray:
    """Azimuths (degrees) of the markers, all on the horizon (elevation 0)."""
    return MARKER_OFFSET_DEG + 360.0 * np.arange(MARKERS) / MARKERS


@functools.cache
def environment() -> Texture:
    """The equirectangular environment texture (cached; treat it as read-only)."""
    img = np.empty((TEX_HEIGHT, TEX_WIDTH, 3), np.uint8)
    band = round(TEX_HEIGHT * BAND_DEG / 180.0)
    top, mid = TEX_HEIGHT // 2 - band, TEX_HEIGHT // 2
    cell_w = TEX_WIDTH // COLUMNS
    halves = [grid_cells(_tinted(name, tint), 2, 1, (cell_w, band)) for name, tint in _PHOTOS]
    for c in range(COLUMNS):
        # the two halves of a photo go to different rows, five columns apart: no repeated content
        img[top:mid, c * cell_w:(c + 1) * cell_w] = halves[c][0]
        img[mid:mid + band, c * cell_w:(c + 1) * cell_w] = halves[(c + 5) % COLUMNS][1]
    img[:top] = fit(photo("hubble_deep_field"), TEX_WIDTH, top)
    img[mid + band:] = fit(ground_texture(1024), TEX_WIDTH, TEX_HEIGHT - mid - band)
    _draw_markers(img)
    return make_texture(img, wrap=True)


def _tinted(name: str, tint: tuple[float, float, float] | None) -> np.ndarray:
    img = photo(name)
    return img if tint is None else np.round(img * np.asarray(tint, np.float32)).astype(np.uint8)


def _draw_markers(img: np.ndarray) -> None:
    """Anti-aliased magenta discs in black rings, centred exactly on the markers' directions."""
    r = MARKER_RADIUS + MARKER_RING + 1.0
    for az in marker_azimuths():
        cu = (az / 360.0 + 0.5) * TEX_WIDTH % TEX_WIDTH  # texel coordinates (texel i spans [i, i+1))
        cv = TEX_HEIGHT / 2.0
        u0, v0 = int(np.floor(cu - r)), int(np.floor(cv - r))
        n = int(2 * r) + 2
        uu, vv = np.meshgrid(np.arange(u0, u0 + n) + 0.5, np.arange(v0, v0 + n) + 0.5)
        dist = np.hypot(uu - cu, vv - cv)
        disc = np.clip(MARKER_RADIUS + 0.5 - dist, 0.0, 1.0)[..., None]
        ring = np.clip(MARKER_RADIUS + MARKER_RING + 0.5 - dist, 0.0, 1.0)[..., None]
        cols = np.arange(u0, u0 + n) % TEX_WIDTH
        patch = img[v0:v0 + n][:, cols].astype(np.float32)
        patch = patch * (1.0 - ring) + MAGENTA * disc  # black ring, then the disc over it
        img[v0:v0 + n, cols] = np.clip(np.round(patch), 0, 255).astype(np.uint8)


def environment_colour(dirs: np.ndarray, footprint: np.ndarray | float) -> np.ndarray:
    """RGB float32 in [0, 1] (N, 3) seen along world directions ``dirs`` (N, 3), filtered over
    ``footprint`` radians (the angle one output pixel spans, scalar or (N,))."""
    dirs = np.asarray(dirs, np.float64)
    norm = np.linalg.norm(dirs, axis=1)
    az = np.arctan2(dirs[:, 0], dirs[:, 2])
    el = np.arcsin(np.clip(-dirs[:, 1] / norm, -1.0, 1.0))
    uv = np.column_stack([(az / (2 * np.pi) + 0.5) * TEX_WIDTH, (0.5 - el / np.pi) * TEX_HEIGHT])
    # texels per output pixel: the larger of the two axes (azimuth texels shrink by cos(elevation))
    per_rad = TEX_WIDTH / (2 * np.pi)
    texels = np.asarray(footprint, np.float64) * per_rad / np.maximum(np.cos(el), 0.05)
    level = np.log2(np.maximum(texels, 1.0))
    return sample(environment(), uv, np.broadcast_to(level, (len(uv),)).astype(np.float32))


def render_view(R: np.ndarray, K: np.ndarray, width: int, height: int, gain: float = 1.0) -> np.ndarray:
    """The RGB uint8 view of a camera at the origin with world-to-camera rotation ``R``."""
    jj, ii = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pix = np.stack([jj, ii, np.ones_like(jj)], axis=-1).reshape(-1, 3)
    rays = apply_matrix(np.asarray(R).T @ np.linalg.inv(K), pix)
    # angle a pixel spans along its ray: 1/f at the centre, cos^2 of the off-axis angle elsewhere
    cos2 = 1.0 / (1.0 + ((pix[:, 0] - K[0, 2]) ** 2 + (pix[:, 1] - K[1, 2]) ** 2) / K[0, 0] ** 2)
    rgb = environment_colour(rays, cos2 / K[0, 0]) * np.float32(255.0 * gain)
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8).reshape(height, width, 3)


def rotation(yaw_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """World-to-camera rotation of a camera turned by yaw (to the right), then pitch (up), then roll."""
    def axis(k, a):
        c, s = np.cos(np.radians(a)), np.sin(np.radians(a))
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        M = np.eye(3)
        M[i, i], M[i, j], M[j, i], M[j, j] = c, -s, s, c
        return M

    cam_to_world = axis(1, yaw_deg) @ axis(0, pitch_deg) @ axis(2, roll_deg)
    return cam_to_world.T


def render_views(views: int = 12, width: int = 640, height: int = 480, hfov_deg: float = 50.0,
                 gain_range: tuple[float, float] = (0.85, 1.15), jitter_deg: float = 1.5,
                 seed: int = 0) -> PanoramaViews:
    """``views`` views evenly spaced in yaw over 360 degrees (view 0 at yaw 0, views turning right),
    each with yaw, pitch and roll jitter up to ``jitter_deg`` and an exposure gain drawn uniformly
    from ``gain_range``."""
    rng = np.random.default_rng(seed)
    f = width / 2.0 / np.tan(np.radians(hfov_deg) / 2.0)
    K = np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
    rotations, images = [], []
    gains = rng.uniform(*gain_range, size=views)
    for i in range(views):
        jitter = rng.uniform(-jitter_deg, jitter_deg, size=3)
        R = rotation(360.0 * i / views + jitter[0], jitter[1], jitter[2])
        rotations.append(R)
        images.append(render_view(R, K, width, height, gains[i]))
    return PanoramaViews(images, K, rotations, gains)


def write_views(out: Path, views: PanoramaViews) -> Path:
    """Write ``images/view_NN.png`` (lossless) and ``gt.json`` (K, world-to-camera R, gains) into
    ``out``; returns the images folder."""
    folder = Path(out) / "images"
    folder.mkdir(parents=True, exist_ok=True)
    for name, img in zip(views.names, views.images):
        Image.fromarray(img).save(folder / name)
    gt = {"K": views.K.tolist(), "gains": views.gains.tolist(),
          "frames": [{"name": n, "R": R.tolist()} for n, R in zip(views.names, views.rotations)]}
    (Path(out) / "gt.json").write_text(json.dumps(gt, indent=1))
    return folder


def marker_mask(img: np.ndarray, threshold: float = 120.0) -> np.ndarray:
    """Where an RGB uint8 image shows marker magenta: min(R, B) - G above ``threshold``."""
    rgb = img.astype(np.float32)
    return (np.minimum(rgb[..., 0], rgb[..., 2]) - rgb[..., 1]) > threshold
