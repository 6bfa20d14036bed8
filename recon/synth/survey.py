"""A large aerial survey with GPS tags, for matching at scale: the zoo's aerial grid (hills, fields,
houses, trees; nadir views on flight lines flown back and forth) grown to hundreds of views, each
photo carrying its true camera centre, plus a few metres of noise, as EXIF GPS.

Not a zoo scene: the zoo's scenes are all reconstructed densely by the quality bench, and a survey
of hundreds of views is for pair selection and sfm. The ground is tiled with fields of different
layouts, so no stretch of it repeats (a repeating texture pairs photos of different places).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.synth.dataset import Capture, SceneInfo, write_scene
from recon.synth.geotags import geotag_photos
from recon.synth.layouts import Grid, layout_cameras
from recon.synth.procedural import mottled, patchwork, plaster, tiles
from recon.synth.scene import assemble
from recon.synth.shapes import heightfield, sphere
from recon.synth.zoo_scenes import gable_house, tex

#: where the survey's world frame (metres, x east, y north, z up) is on the Earth (lat, lon, alt)
ORIGIN = (47.3769, 8.5417, 430.0)
HEIGHT = 35.0  # flying height, metres
FOCAL_FACTOR = 0.9  # focal length / image width
DENSITY = 14.0  # texels per metre
TILE = 80.0  # metres of ground per field layout (a 1536-texel layout spans 110 m)


def _hills(x, y):
    return 1.6 * np.sin(x / 17.0) * np.cos(y / 23.0) + 0.8 * np.sin((x + 2 * y) / 11.0)


def _grid(lines: int) -> Grid:
    return Grid((0.0, 0.0, 0.0), HEIGHT, lines=lines)


def survey_parts(views: int, lines: int, aspect: float, seed: int = 0) -> list:
    """Terrain, houses and trees under the whole footprint of ``views`` photos on ``lines`` flight
    lines (images ``aspect`` = height / width), with a margin."""
    rng = np.random.default_rng([seed, views, lines])
    grid = _grid(lines)
    ground_w, ground_h = HEIGHT / FOCAL_FACTOR, HEIGHT / FOCAL_FACTOR * aspect
    per_line = -(-views // lines)
    half_x = (lines - 1) / 2 * (1 - grid.side_overlap) * ground_w + ground_w
    half_y = (per_line - 1) / 2 * (1 - grid.forward_overlap) * ground_h + ground_h
    nx, ny = int(np.ceil(2 * half_x / TILE)), int(np.ceil(2 * half_y / TILE))
    xs, ys = np.linspace(-half_x, half_x, nx + 1), np.linspace(-half_y, half_y, ny + 1)
    parts = []
    for i in range(nx):
        for j in range(ny):
            cells = (int(np.ceil(xs[i + 1] - xs[i])), int(np.ceil(ys[j + 1] - ys[j])))  # about 1 m
            fields = tex(patchwork(1536, 1536, rng))
            parts.append(heightfield(f"terrain_{i}_{j}", (xs[i], xs[i + 1]), (ys[j], ys[j + 1]), cells, _hills,
                                     fields, DENSITY))
    roof = tex(tiles(256, 256, rng, 32, [(150, 70, 56), (110, 104, 100)], grout=2))
    wall = tex(plaster(256, 256, (214, 206, 190), 8.0, rng, beta=0.9))
    crown = tex(mottled(128, 128, [(50, 96, 40), (70, 120, 50)], rng, 0.4, beta=0.7))
    area = 4 * half_x * half_y
    for k in range(int(area / 1200)):  # the zoo's aerial grid: 9 houses on 110 m x 100 m
        cx, cy = rng.uniform(-half_x + 10, half_x - 10), rng.uniform(-half_y + 10, half_y - 10)
        size = (rng.uniform(6, 11), rng.uniform(5, 8), rng.uniform(3, 7))
        z0 = float(_hills(np.array(cx), np.array(cy))) - 0.5
        parts += gable_house(f"house_{k}", (cx, cy, z0), size, rng.uniform(0, np.pi), wall, roof, DENSITY,
                             rng.uniform(1.5, 3.0))
    for k in range(int(area / 900)):
        cx, cy = rng.uniform(-half_x, half_x), rng.uniform(-half_y, half_y)
        r = rng.uniform(1.5, 3.0)
        z = float(_hills(np.array(cx), np.array(cy)))
        parts.append(sphere(f"tree_{k}", np.array([cx, cy, z + r * 0.9]), r, crown, segments=24))
    return parts


def render_survey(out_dir: str | Path, views: int = 300, lines: int = 12, width: int = 480, height: int = 360,
                  seed: int = 0, gps_sigma: float = 3.0) -> SceneInfo:
    """Render the survey into ``out_dir`` (the layout of recon.synth.dataset, no hold-out views) and
    tag each photo with its camera centre plus N(0, ``gps_sigma``) metres per axis, placed on the
    Earth by :data:`ORIGIN`."""
    parts = survey_parts(views, lines, height / width, seed)
    regular, _ = layout_cameras(_grid(lines), views, 0, width, height, FOCAL_FACTOR, seed)
    info = write_scene(out_dir, assemble(parts), regular, {}, seed=seed, path="grid", name="survey",
                       capture=Capture())
    geotag_photos(info.images_dir, {n: c.center for n, c in regular.items()}, gps_sigma, seed, ORIGIN)
    return info
